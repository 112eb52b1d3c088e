#!/usr/bin/env python3
"""Look at an imuflow .rrd as a person would: open it in rerun's web viewer in headless Chromium
and save a PNG of the first screen, at the last frame or at chosen frames.

usage: rrd_screenshot.py RRD OUT.png [--seq N [N ...]] [--wait SECONDS] [--size 1600x1000]

With one --seq the picture is OUT.png at that frame (the `seq` timeline); with several, one picture
per frame, named OUT-seqN.png. Without --seq: the frame the viewer opens on (a recording opens at
its end).

Needs: the `rerun` command of rerun-sdk 0.36.3 (the verify venv has it), Chromium (`apt install
chromium`) and the `playwright` Python package (`pip install playwright`; it drives the system
Chromium, no browser download). WebGPU fails under SwiftShader on a machine without a GPU, so the
viewer is opened with `renderer=webgl`. Exits non-zero with a message when a piece is missing or the
viewer does not come up. Every process it starts ends with it: the viewer runs in a process group
of its own, which is ended as a whole (the venv's `rerun` is a wrapper that starts the viewer as a
child; ending the wrapper alone left the viewer running).
"""
import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request


def fail(msg):
    print(f"rrd_screenshot: {msg}", file=sys.stderr)
    sys.exit(1)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_http(url, seconds):
    deadline = time.time() + seconds
    while time.time() < deadline:
        try:
            urllib.request.urlopen(url, timeout=2)
            return True
        except OSError:
            time.sleep(0.3)
    return False


def group_alive(pgid):
    """Whether a process of group `pgid` still runs (zombies, which only wait to be reaped by their
    parent, do not count)."""
    if not os.path.isdir("/proc"):
        try:
            os.killpg(pgid, 0)
            return True
        except ProcessLookupError:
            return False
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as f:
                # pid (comm) state ppid pgrp ...: comm may hold spaces, so split after its ')'.
                state, _, pgrp = f.read().rsplit(")", 1)[1].split()[:3]
        except OSError:
            continue
        if int(pgrp) == pgid and state != "Z":
            return True
    return False


def end_group(proc, seconds=10):
    """Ends the process group that `proc` leads (started with start_new_session): SIGTERM to every
    member, then SIGKILL to whatever still runs after `seconds`."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.time() + seconds
        while time.time() < deadline:
            proc.poll()  # reaps the leader
            if not group_alive(proc.pid):
                break
            time.sleep(0.2)
        if not group_alive(proc.pid):
            break
    proc.wait(timeout=seconds)


# The web viewer's `WebHandle` (rerun 0.36's index.html keeps it in a local variable): the page
# asks it `has_panicked()` every second, so a wrapper of that method catches it.
CATCH_HANDLE_JS = """() => {
    const proto = wasm_bindgen.WebHandle.prototype;
    const asked = proto.has_panicked;
    proto.has_panicked = function () { window.__rrd_screenshot_handle = this; return asked.call(this); };
}"""

# Moves the time cursor with playback paused. A streamed recording's URL fragment `#when=seq@N` is
# overridden by the viewer following the stream to its end, so the cursor is moved after loading.
SET_TIME_JS = """([timeline, seq]) => {
    const h = window.__rrd_screenshot_handle;
    if (!h) return "the viewer's handle was not caught";
    const rec = h.get_active_recording_id();
    if (!rec) return "no active recording";
    h.set_playing(rec, false);
    h.set_active_timeline(rec, timeline);
    h.set_time_for_timeline(rec, timeline, seq);
    return "";
}"""


def out_name(out, seq, several):
    if not several:
        return out
    stem, ext = os.path.splitext(out)
    return f"{stem}-seq{seq}{ext or '.png'}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rrd")
    ap.add_argument("out")
    ap.add_argument("--seq", type=int, nargs="+", default=None,
                    help="frame(s) to show (the `seq` timeline); several: one OUT-seqN.png each")
    ap.add_argument("--wait", type=float, default=40.0, help="seconds to let the viewer load")
    ap.add_argument("--settle", type=float, default=6.0,
                    help="seconds to let the views redraw after moving the time cursor")
    ap.add_argument("--size", default="1600x1000")
    ap.add_argument("--rerun", default=shutil.which("rerun") or os.path.expanduser(
        "~/.cache/imuflow/verify-venv/bin/rerun"))
    ap.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    args = ap.parse_args()
    if not os.path.isfile(args.rrd):
        fail(f"{args.rrd}: no such file")
    for what, path in [("rerun", args.rerun), ("chromium", args.chromium)]:
        if not (path and os.access(path, os.X_OK)):
            fail(f"no {what} executable at {path!r}")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        fail("the playwright package is missing: pip install playwright")
    width, height = (int(v) for v in args.size.split("x"))
    web, grpc = free_port(), free_port()
    viewer = subprocess.Popen(
        [args.rerun, args.rrd, "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "RERUN_ANALYTICS": "0"},
        start_new_session=True,
    )
    written = []
    try:
        if not wait_for_http(f"http://127.0.0.1:{web}", 30):
            fail(f"the rerun web viewer did not come up on port {web}")
        source = f"rerun+http://127.0.0.1:{grpc}/proxy"
        url = f"http://127.0.0.1:{web}/?url={urllib.parse.quote(source, safe='')}&renderer=webgl"
        # Playwright's context manager ends the browser and its driver, also on an error.
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=args.chromium,
                args=["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                      "--ignore-gpu-blocklist"],
            )
            try:
                page = browser.new_page(viewport={"width": width, "height": height})
                page.goto(url)
                time.sleep(args.wait)
                if args.seq:
                    page.evaluate(CATCH_HANDLE_JS)
                    time.sleep(2.5)
                if args.seq is None:
                    page.screenshot(path=args.out)
                    written.append(args.out)
                for seq in args.seq or []:
                    problem = page.evaluate(SET_TIME_JS, ["seq", seq])
                    if problem:
                        fail(f"cannot move the time cursor to seq {seq}: {problem}")
                    time.sleep(args.settle)
                    out = out_name(args.out, seq, len(args.seq) > 1)
                    page.screenshot(path=out)
                    written.append(out)
            finally:
                browser.close()
    finally:
        end_group(viewer)
    for out in written:
        print(f"rrd_screenshot: {out} ({args.rrd})")


if __name__ == "__main__":
    main()
