#!/usr/bin/env python3
"""The VMC receiver of `imuflow bench live`: an independent VMC implementation (PyPI vmcp on its
osc4py3 backend; no python-osc) receives the vmc stage's bundles and logs, per bundle, when it was
read and which moment its pose shows (`/imuflow/CaptureTime`, the stage's `capture_time`).

    pip install "vmcp[osc4py3]==1.0.6"
    python tools/live-bench/receive_vmc.py --port 0 --csv bundles.csv --summary summary.json

Prints `listening HOST:PORT` on stdout once its socket is bound (port 0: the kernel picks one), and
runs until SIGTERM / SIGINT or --seconds. Then it writes:

- the CSV: one row per bundle, in arrival order: `read_ns` (osc4py3's read time of the datagram,
  OSCARG_READTIME: `time.time()` taken right after the socket read, in the library's reader
  thread), `handled_ns` (`time.time_ns()` when the bundle's first message reached this script),
  `capture_ns` (the bundle's `/imuflow/CaptureTime`, empty when it had none), `bones` (bone
  messages), `root`, `ok` (`/VMC/Ext/OK` carried), `time_s` (`/VMC/Ext/T`), `messages`;
- the summary (JSON): bundles, messages, decode failures (messages vmcp's event classes refused,
  osc4py3's errors while decoding or dispatching a datagram: its decoder thread ends at the first,
  so the bundles after it go unseen), bundles missing bones, OK or the
  capture time, unknown addresses.

A bundle's messages are dispatched in order and share their datagram's read time, so a bundle is the
run of messages with one read time that starts at `/VMC/Ext/Root/Pos`.
"""
import argparse
import csv
import json
import logging
import signal
import sys
import threading
import time

from vmcp.events import (
    BoneTransformEvent,
    RelativeTimeEvent,
    RootTransformEvent,
    StateEvent,
)
from vmcp.osc import OSC
from vmcp.osc.backend.osc4py3 import as_comthreads as backend
from osc4py3 import oscchannel

CAPTURE_TIME = "/imuflow/CaptureTime"
CHANNEL = "imuflow-bench"


class ErrorCounter(logging.Handler):
    """Counts osc4py3's error records (a datagram it could not decode or dispatch)."""

    def __init__(self):
        super().__init__(level=logging.ERROR)
        self.count = 0
        self.first = None

    def emit(self, record):
        self.count += 1
        if self.first is None:
            self.first = record.getMessage()[:300]


class Bundles:
    """Messages grouped into bundles by their datagram's read time."""

    def __init__(self):
        self.lock = threading.Lock()
        self.rows = []
        self.current = None
        self.messages = 0
        self.decode_failures = 0
        self.first_failure = None
        self.stray_messages = 0  # messages outside a bundle that began with Root/Pos

    def _fail(self, why):
        self.decode_failures += 1
        if self.first_failure is None:
            self.first_failure = why[:300]

    def _close(self):
        if self.current is not None:
            self.rows.append(self.current)
            self.current = None

    def message(self, readtime, address, data):
        handled_ns = time.time_ns()
        with self.lock:
            self.messages += 1
            if address == RootTransformEvent.ADDRESS_PATTERN or (
                self.current is not None and self.current["read"] != readtime
            ):
                self._close()
            if self.current is None:
                if address != RootTransformEvent.ADDRESS_PATTERN:
                    self.stray_messages += 1
                self.current = {
                    "read": readtime,
                    "read_ns": int(round(readtime * 1e9)),
                    "handled_ns": handled_ns,
                    "capture_ns": "",
                    "bones": 0,
                    "root": 0,
                    "ok": 0,
                    "time_s": "",
                    "messages": 0,
                }
            b = self.current
            b["messages"] += 1
            try:
                if address == BoneTransformEvent.ADDRESS_PATTERN:
                    BoneTransformEvent.from_message_data(CHANNEL, address, tuple(data))
                    b["bones"] += 1
                elif address == RootTransformEvent.ADDRESS_PATTERN:
                    RootTransformEvent.from_message_data(CHANNEL, address, tuple(data))
                    b["root"] += 1
                elif address == StateEvent.ADDRESS_PATTERN:
                    StateEvent.from_message_data(CHANNEL, address, tuple(data))
                    b["ok"] = 1
                elif address == RelativeTimeEvent.ADDRESS_PATTERN:
                    event = RelativeTimeEvent.from_message_data(CHANNEL, address, tuple(data))
                    b["time_s"] = repr(float(event.delta))
                elif address == CAPTURE_TIME:
                    if len(data) != 1 or not isinstance(data[0], str) or not data[0].isdigit():
                        raise ValueError(f"{CAPTURE_TIME}: not one decimal string: {data!r}")
                    b["capture_ns"] = int(data[0])
            except Exception as e:  # vmcp raises ValueError/TypeError/KeyError on bad arguments
                self._fail(f"{address}: {type(e).__name__}: {e}")

    def finish(self):
        with self.lock:
            self._close()
            return list(self.rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=39539, help="UDP port (0: any free one)")
    parser.add_argument("--csv", required=True, help="per-bundle CSV to write")
    parser.add_argument("--summary", required=True, help="summary JSON to write")
    parser.add_argument("--seconds", type=float, default=0.0, help="stop after this long (0: on a signal only)")
    args = parser.parse_args()

    # osc4py3 reads in one thread and decodes and dispatches in another: a short GIL switch
    # interval keeps the reader's time stamp from waiting on the decoder (the default is 5 ms).
    sys.setswitchinterval(0.0002)

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    logger = logging.getLogger("osc4py3-bench")
    logger.setLevel(logging.ERROR)  # info/debug records would cost time per datagram
    logger.propagate = False
    errors = ErrorCounter()
    logger.addHandler(errors)

    bundles = Bundles()
    osc = OSC(backend, logger)
    known = [
        RootTransformEvent.ADDRESS_PATTERN,
        BoneTransformEvent.ADDRESS_PATTERN,
        StateEvent.ADDRESS_PATTERN,
        RelativeTimeEvent.ADDRESS_PATTERN,
        CAPTURE_TIME,
    ]
    unknown = [0]

    def unknown_message(readtime, address, data):
        if address not in known:
            unknown[0] += 1

    scheme = backend.ARG_READTIME + backend.ARG_ADDRESS + backend.ARG_DATA
    started = time.monotonic()
    with osc.open():
        receiver = osc.create_receiver(args.host, args.port, CHANNEL).open()
        handlers = [receiver.register_handler(a, bundles.message, scheme) for a in known]
        handlers.append(receiver.register_handler("*", unknown_message, scheme))
        channel = oscchannel.get_channel(CHANNEL)
        host, port = channel.udpsock.getsockname()[:2]
        print(f"listening {host}:{port}", flush=True)
        while not stop.is_set():
            if args.seconds > 0 and time.monotonic() - started >= args.seconds:
                break
            osc.run()
            stop.wait(0.05)
        # Let the decoder finish what the reader took before the stop.
        time.sleep(0.2)
        osc.run()
        rows = bundles.finish()
        # vmcp 1.0.6's Receiver.close() unregisters while iterating its handler dict (a
        # RuntimeError): unregister them here first.
        for uuid in handlers:
            receiver.unregister_handler(uuid)
        receiver.close()

    with open(args.csv, "w", newline="") as f:
        w = csv.writer(f)
        fields = ["read_ns", "handled_ns", "capture_ns", "bones", "root", "ok", "time_s", "messages"]
        w.writerow(fields)
        for r in rows:
            w.writerow([r[k] for k in fields])
    summary = {
        "receiver": "vmcp (osc4py3 backend, as_comthreads)",
        "bundles": len(rows),
        "messages": bundles.messages,
        "decode_failures": bundles.decode_failures + errors.count,
        # osc4py3's decoder thread ends at its first error: bundles after it are not seen.
        "decoder_errors": errors.count,
        "first_decode_failure": bundles.first_failure or errors.first,
        "stray_messages": bundles.stray_messages,
        "unknown_addresses": unknown[0],
        "without_ok": sum(1 for r in rows if not r["ok"]),
        "without_capture_time": sum(1 for r in rows if r["capture_ns"] == ""),
        "bones_min": min((r["bones"] for r in rows), default=0),
        "bones_max": max((r["bones"] for r in rows), default=0),
        "seconds": time.monotonic() - started,
    }
    with open(args.summary, "w") as f:
        json.dump(summary, f, indent=1)
    print(f"received {len(rows)} bundles, {summary['decode_failures']} decode failures", flush=True)


if __name__ == "__main__":
    main()
