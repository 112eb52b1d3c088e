#!/usr/bin/env python3
"""Look at an imuflow .rrd as a person would: open it in rerun's web viewer in headless Chromium
and save a PNG of the first screen (at a chosen frame).

usage: rrd_screenshot.py RRD OUT.png [--seq N] [--wait SECONDS] [--size 1600x1000]

Needs: the `rerun` command of rerun-sdk 0.36.3 (the verify venv has it), Chromium (`apt install
chromium`) and the `playwright` Python package (`pip install playwright`; it drives the system
Chromium, no browser download). WebGPU fails under SwiftShader on a machine without a GPU, so the
viewer is opened with `renderer=webgl`. Exits non-zero with a message when a piece is missing or the
viewer does not come up.
"""
import argparse
import os
import shutil
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rrd")
    ap.add_argument("out")
    ap.add_argument("--seq", type=int, default=None, help="frame to ask for (the `seq` timeline; the web viewer of rerun 0.36 ends a streamed recording at its last frame regardless: to show a moment, record up to it, e.g. --set stages.source.params.frames=640)")
    ap.add_argument("--wait", type=float, default=40.0, help="seconds to let the viewer load")
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
    )
    try:
        if not wait_for_http(f"http://127.0.0.1:{web}", 30):
            fail(f"the rerun web viewer did not come up on port {web}")
        source = f"rerun+http://127.0.0.1:{grpc}/proxy"
        if args.seq is not None:
            source += f"#when=seq@{args.seq}"
        url = f"http://127.0.0.1:{web}/?url={urllib.parse.quote(source, safe='')}&renderer=webgl"
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=args.chromium,
                args=["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                      "--ignore-gpu-blocklist"],
            )
            page = browser.new_page(viewport={"width": width, "height": height})
            page.goto(url)
            time.sleep(args.wait)
            page.screenshot(path=args.out)
            browser.close()
    finally:
        viewer.terminate()
        viewer.wait(timeout=10)
    print(f"rrd_screenshot: {args.out} ({args.rrd})")


if __name__ == "__main__":
    main()
