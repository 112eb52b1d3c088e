"""Stages written in Python: imuflow-graph's Stage API on the iceoryx2 Python bindings.

A Python stage is an external stage (`exec = "python"`, `args = ["my_stage.py"]`) that the
launcher cannot tell from a Rust one: the same start handshake, heartbeats, alignment of inputs by
`seq`, END_OF_STREAM and summary line, over the same iceoryx2 services with the same frame types.

    import imuflow

    stage = imuflow.Stage.from_env()            # wiring from the launcher
    out = stage.output("kinematics")            # frame type from the graph
    stage.ready()                               # handshake: wait until every stage is up
    for step in stage:                          # one aligned set of input frames
        kin = step["kin"]                       # a read-only view of the frame in shared memory
        frame = out.loan(step)                  # a zeroed frame in shared memory
        frame["joint_position_m"] = kin["joint_position_m"]
        out.send(frame)
    stage.finish()                              # END_OF_STREAM downstream, summary up

Frames are numpy structured scalars whose dtype is built from the layouts the launcher writes
into the run folder (`wire.json`, the same layouts `imuflow stage --layouts` prints), so no
offset is written here. An input frame is a view of the sample in shared memory, valid until the
next step (`.copy()` what must outlive it); a loaned frame is the publisher's sample itself.

Everything about the transport (service names, buffer sizes, flags) comes from `wire.json` too;
what this module adds is the protocol's behaviour, which mirrors `graph/src/stage.rs`.
"""

import ctypes
import json
import os
import signal
import sys
import threading
import time

import numpy as np

from .layout import dtype_from_layout

ENV_RUN_DIR = "IMUFLOW_RUN_DIR"
ENV_RUN_ID = "IMUFLOW_RUN_ID"
ENV_STAGE_ID = "IMUFLOW_STAGE_ID"
ENV_RESTART = "IMUFLOW_RESTART"
ENV_RUN_SHM_PREFIX = "IMUFLOW_RUN_SHM_PREFIX"
GRAPH_JSON = "graph.json"
WIRE_JSON = "wire.json"

# Header flags (graph/src/frames.rs `flags`); checked against the launcher's wire.json.
END_OF_STREAM = 1 << 0
INVALID = 1 << 1
CALIBRATING = 1 << 2
FEEDBACK_INITIAL = 1 << 3
RESTARTED = 1 << 4
PRELUDE = 1 << 5
DEGRADED = 1 << 6
FLAGS = {
    "END_OF_STREAM": END_OF_STREAM,
    "INVALID": INVALID,
    "CALIBRATING": CALIBRATING,
    "FEEDBACK_INITIAL": FEEDBACK_INITIAL,
    "RESTARTED": RESTARTED,
    "PRELUDE": PRELUDE,
    "DEGRADED": DEGRADED,
}
U64_MAX = (1 << 64) - 1

# How long a blocked stage waits for a wake-up before re-checking its stop flag (iceoryx2's
# listener timeouts have a granularity of ~8 ms; a notification wakes it at once).
POLL_S = 0.02


class StageError(RuntimeError):
    """The stage cannot start or run: not started by the launcher, a port the graph does not
    have, a frame type that differs, bindings of another iceoryx2 version, ..."""


class Step:
    """One aligned set of input frames: the shared `seq`, `capture_ns` and propagated flags
    (INVALID, CALIBRATING, and RESTARTED on a restarted stage's first step), and each input's
    frame by name (`step["kin"]`)."""

    __slots__ = ("seq", "capture_ns", "flags", "_frames")

    def __init__(self, seq, capture_ns, flags, frames):
        self.seq = seq
        self.capture_ns = capture_ns
        self.flags = flags
        self._frames = frames

    def __getitem__(self, name):
        try:
            return self._frames[name]
        except KeyError:
            known = ", ".join(self._frames)
            raise StageError(f"this step has no input '{name}' (it has: {known})") from None

    def __repr__(self):
        return f"Step(seq={self.seq}, flags={self.flags:#x}, inputs={list(self._frames)})"


def _view(address, dtype, writable):
    """The frame at `address` as a numpy structured scalar, without copying."""
    buffer = (ctypes.c_char * dtype.itemsize).from_address(address)
    array = np.frombuffer(buffer, dtype=dtype)
    if not writable:
        array.flags.writeable = False
    return array[0]


def _payload_type(layout):
    """The ctypes type iceoryx2 sees for a frame: the Rust type's name, size and alignment (8:
    every frame starts with u64 fields and is `#[repr(C)]` without padding)."""
    size = int(layout["size"])
    if size % 8:
        raise StageError(f"{layout['type_name']}: size {size} is not a multiple of its alignment 8")
    name = layout["type_name"]
    return type(
        name.replace(".", "_"),
        (ctypes.Structure,),
        {"_fields_": [("raw", ctypes.c_uint64 * (size // 8))],
         "type_name": staticmethod(lambda: name)},
    )


class _ArrivalWaiter:
    """How a stage waits for its next input (graph/src/wait.rs, same tuning): block while nothing
    is due, spin briefly around the moment the next frame is expected. Waking a blocked process
    costs tens of microseconds per hop and iceoryx2's listener timeouts are coarse, while sources
    are periodic: learn the interval between arrivals and the stream's phase, sleep until shortly
    before the next frame is due, spin until it arrives or a short tail has passed, then block on
    the wake-up event."""

    SPIN_LEAD_S = 300e-6
    SPIN_TAIL_S = 800e-6
    SHORT_SPIN_S = 20e-6
    MAX_INTERVAL_S = 1.0
    EWMA_WEIGHT = 0.125
    LATE_PHASE_WEIGHT = 0.1
    SLEEP_SLICE_S = 1e-3

    def __init__(self):
        self.last_scheduled = None
        self.interval_s = None

    def expected(self):
        if self.last_scheduled is None or self.interval_s is None:
            return None
        return self.last_scheduled + self.interval_s

    def arrived(self, now):
        expected = self.expected()
        if expected is not None and 0 < now - expected < self.MAX_INTERVAL_S:
            scheduled = expected + (now - expected) * self.LATE_PHASE_WEIGHT
        else:
            scheduled = now
        if self.last_scheduled is not None:
            dt = scheduled - self.last_scheduled
            if 0 <= dt < self.MAX_INTERVAL_S:
                self.interval_s = dt if self.interval_s is None else (
                    self.interval_s + self.EWMA_WEIGHT * (dt - self.interval_s))
        self.last_scheduled = scheduled

    def wait(self, listener, timeout, ready):
        """Until `ready()` holds, or at most about `timeout` (an iceoryx2 Duration)."""
        if ready():
            listener.try_wait()
            return
        now = time.perf_counter()
        expected = self.expected()
        if expected is not None and expected + self.SPIN_TAIL_S > now:
            spin_from = expected - self.SPIN_LEAD_S
            while True:  # nothing due yet: sleep in slices until the spin window
                now = time.perf_counter()
                if now >= spin_from:
                    break
                time.sleep(min(spin_from - now, self.SLEEP_SLICE_S))
                if ready():
                    listener.try_wait()
                    return
            spin_until = expected + self.SPIN_TAIL_S
        else:  # overdue, or no rhythm yet
            spin_until = now + self.SHORT_SPIN_S
        while time.perf_counter() < spin_until:
            if ready():
                listener.try_wait()
                return
            os.sched_yield()  # a producer sharing the core still runs
        if not ready():
            listener.timed_wait(timeout)
        listener.try_wait()


class _Control:
    """The launcher's line protocol: `@imuflow ...` lines on the real stdout (kept for this
    alone; Python's stdout goes to stderr so a print() cannot break a control line), commands
    from stdin read by a thread of its own."""

    CONNECT, GO = 1, 2

    def __init__(self, prefix, stop):
        self.prefix = prefix
        self.stop = stop
        self.command = 0
        self.ended_stages = []
        self.news = threading.Event()
        self._lock = threading.Lock()
        sys.stdout.flush()
        self._out = os.fdopen(os.dup(1), "w", buffering=1)
        os.dup2(2, 1)
        sys.stdout = sys.stderr
        threading.Thread(target=self._read, name="imuflow-control", daemon=True).start()

    def send(self, text):
        with self._lock:
            self._out.write(self.prefix + text + "\n")
            self._out.flush()

    def _read(self):
        for line in sys.stdin:
            line = line.strip()
            if line == "connect":
                self.command = max(self.command, self.CONNECT)
            elif line == "go":
                self.command = max(self.command, self.GO)
            elif line == "stop":
                self.stop.set()
            elif line.startswith("ended "):
                self.ended_stages.append(line[len("ended "):].strip())
                self.news.set()
        self.stop.set()  # stdin closed: the launcher is gone

    def wait_for(self, command):
        while self.command < command:
            if self.stop.is_set():
                return False
            time.sleep(0.001)
        return True

    def heartbeat(self, position, interval_s):
        def beat():
            while True:
                try:
                    self.send(f"alive {position()}")
                except (OSError, ValueError):
                    return
                time.sleep(interval_s)

        threading.Thread(target=beat, name="imuflow-heartbeat", daemon=True).start()


class _Stats:
    """What the summary line reports (graph/src/stats.rs `StageSummary`)."""

    def __init__(self):
        self.frames_in = self.frames_out = self.dropped = self.unmatched = 0
        self.detail = ""
        self.processing_us = []
        self.latency_us = []
        self.from_capture_us = {}

    def summary(self, wall_s):
        def pct(values, p):
            if not values:
                return 0.0
            ordered = sorted(values)
            rank = int(np.ceil(p * len(ordered)))
            return float(ordered[min(max(rank, 1), len(ordered)) - 1])

        busy_s = sum(self.processing_us) * 1e-6
        return {
            "frames_in": self.frames_in,
            "frames_out": self.frames_out,
            "dropped": self.dropped,
            "unmatched": self.unmatched,
            "mean_us": float(np.mean(self.processing_us)) if self.processing_us else 0.0,
            "p99_us": pct(self.processing_us, 0.99),
            "max_us": max(self.processing_us, default=0.0),
            "wall_s": wall_s,
            "busy_fraction": busy_s / wall_s if wall_s > 0 else 0.0,
            "latency_p50_us": pct(self.latency_us, 0.5),
            "latency_p99_us": pct(self.latency_us, 0.99),
            "detail": self.detail,
            "from_capture": [
                {"input": name, "frames": len(v), "p50_us": pct(v, 0.5), "p99_us": pct(v, 0.99),
                 "max_us": max(v)}
                for name, v in sorted(self.from_capture_us.items())
            ],
        }


class _Input:
    def __init__(self, name, edge, dtype, subscriber, service):
        self.name = name
        self.from_stage = edge["from_stage"]
        self.feedback = bool(edge.get("feedback", False))
        self.frame_type = edge["frame"]
        self.dtype = dtype
        self.subscriber = subscriber
        self.service = service
        self.sample = None  # the held iceoryx2 sample (None: nothing, or a local initial frame)
        self.view = None
        self.last_seq = None
        self.ended = False
        self.source_gone = False  # the launcher stopped the producer's branch

    def hold(self, sample):
        self.release()
        self.sample = sample
        self.view = _view(sample.payload_ptr, self.dtype, writable=False)

    def release(self):
        if self.sample is not None:
            self.sample.delete()
        self.sample = None
        self.view = None

    def seq(self):
        return int(self.view["header.seq"])

    def header_flags(self):
        return int(self.view["header.flags"])


class Output:
    """An output port: loans frames in shared memory, sends them and wakes the readers."""

    def __init__(self, stage, port, frame_type, dtype, publisher, service, notifiers):
        self._stage = stage
        self.port = port
        self.frame_type = frame_type
        self.dtype = dtype
        self._publisher = publisher
        self._service = service
        self._notifiers = notifiers
        self._loaned = None  # (sample, view, header)
        self.sent = 0
        self.ended = False

    def loan(self, step=None, *, seq=None, capture_ns=None, flags=0):
        """A zeroed frame in the publisher's shared memory, to fill and `send`. Its header comes
        from `step` (a transform) or from `seq`/`capture_ns` (a source); `flags` are added."""
        if self._loaned is not None:
            raise StageError(f"output '{self.port}': the previous loaned frame was not sent")
        if step is not None:
            seq, capture_ns, flags = step.seq, step.capture_ns, step.flags | flags
        if seq is None:
            raise StageError(f"output '{self.port}': loan(step) or loan(seq=..., capture_ns=...)")
        sample = self._publisher.loan_uninit()
        ctypes.memset(sample.payload_ptr, 0, self.dtype.itemsize)
        view = _view(sample.payload_ptr, self.dtype, writable=True)
        self._loaned = (sample, view, (int(seq), int(capture_ns or 0), int(flags)))
        return view

    def send(self, frame=None):
        """Sends the loaned frame: the header is written last (seq, capture time, flags of the
        step plus any the stage set in `header.flags`, e.g. INVALID; publish time now)."""
        if self._loaned is None:
            raise StageError(f"output '{self.port}': send() without a loaned frame")
        sample, view, (seq, capture_ns, flags) = self._loaned
        if frame is not None and frame is not view:
            raise StageError(f"output '{self.port}': send() takes the frame loan() returned")
        self._loaned = None
        view["header.seq"] = seq
        view["header.capture_ns"] = capture_ns
        view["header.flags"] = flags | int(view["header.flags"])
        view["header.restarts"] = self._stage.restarts
        view["header.publish_ns"] = time.time_ns()
        started = time.perf_counter()
        sample.assume_init().send()
        self._stage._waited_s += time.perf_counter() - started
        self.sent += 1
        for notifier in self._notifiers:
            try:
                notifier.notify()
            except Exception:  # a reader that already exited has no listener
                pass
        if not flags & END_OF_STREAM:
            self._stage._produced(seq, capture_ns)

    def publish(self, step=None, *, seq=None, capture_ns=None, flags=0, **fields):
        """`loan`, copy `fields` in (`local_pose_wxyz=q`, ...), `send`."""
        frame = self.loan(step, seq=seq, capture_ns=capture_ns, flags=flags)
        try:
            for name, value in fields.items():
                frame[name] = value
        except (KeyError, ValueError) as e:
            sample, _, _ = self._loaned
            self._loaned = None
            sample.delete()
            raise StageError(f"output '{self.port}' ({self.frame_type}): {e}") from None
        self.send(frame)

    def forward(self, step, frame):
        """Sends a copy of `frame` (an input frame of this output's type) with `step`'s header:
        a pass-through."""
        if frame.dtype != self.dtype:
            raise StageError(f"output '{self.port}' carries {self.frame_type}; cannot forward a "
                             f"frame of {len(frame.dtype.names)} fields of another type")
        view = self.loan(step)
        ctypes.memmove(self._loaned[0].payload_ptr, frame.tobytes(), self.dtype.itemsize)
        view["header.flags"] = 0  # the step's flags are set by send
        self.send(view)

    def _end(self, seq, capture_ns):
        if self.ended:
            return
        if self._loaned is not None:  # loaned and never sent: given back
            self._loaned[0].delete()
            self._loaned = None
        frame = self.loan(seq=seq, capture_ns=capture_ns, flags=END_OF_STREAM)
        self.send(frame)
        self.ended = True


class Stage:
    """A stage's connection to its graph and its launcher (see the module doc)."""

    @classmethod
    def from_env(cls):
        """Connects to the run that started this process (`imuflow run GRAPH`)."""
        missing = [v for v in (ENV_RUN_DIR, ENV_RUN_ID, ENV_STAGE_ID) if v not in os.environ]
        if missing:
            raise StageError(f"{missing[0]} is not set: stages are started by `imuflow run GRAPH`, "
                             "not by hand")
        return cls(os.environ[ENV_RUN_DIR], os.environ[ENV_RUN_ID], os.environ[ENV_STAGE_ID])

    def __init__(self, run_dir, run_id, stage_id):
        self.run_dir = run_dir
        self.run_id = run_id
        graph = _read_json(os.path.join(run_dir, GRAPH_JSON), "the run's graph")
        wire = _read_json(os.path.join(run_dir, WIRE_JSON), "the launcher's wire contract")
        iox2 = _import_bindings(wire)
        _check_flags(wire)
        self._iox2 = iox2
        self._wire = wire
        self._transport = wire["transport"]
        self.graph = graph
        try:
            self.node_spec = graph["stages"][stage_id]
        except KeyError:
            raise StageError(f"stage '{stage_id}' is not in the run's graph") from None
        self.id = stage_id
        self.params = self.node_spec.get("params", {})
        self.mode = graph["mode"]
        self.restarts = int(os.environ.get(ENV_RESTART, "0") or 0)
        self._restart_flag_pending = self.restarts > 0
        self._dtypes = {name: dtype_from_layout(l) for name, l in wire["layouts"].items()}
        self._payload_types = {name: _payload_type(l) for name, l in wire["layouts"].items()}

        self._stop = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self._stop.set())
        self._control = _Control(wire["control_prefix"], self._stop)

        config = iox2.config.default()
        prefix = os.environ.get(ENV_RUN_SHM_PREFIX)
        if prefix:
            config.global_cfg.prefix = iox2.FileName.new(prefix)
        try:
            self._node = (iox2.NodeBuilder.new()
                          .name(iox2.NodeName.new(stage_id))
                          .config(config)
                          .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
                          .create(iox2.ServiceType.Ipc))
        except Exception as e:
            raise StageError(f"cannot create the shared-memory node for stage '{stage_id}': {e!r}") from None
        self._listener = None
        self._wake_service = None
        if self.node_spec["inputs"]:
            name = self._service_name("wake", stage=stage_id)
            self._wake_service = self._open_event(name)
            self._listener = self._wake_service.listener_builder().create()
        self._inputs = []
        for name, edge in self.node_spec["inputs"].items():
            producer = graph["stages"].get(edge["from_stage"], {})
            readers = len(producer.get("readers", {}).get(edge["from_port"], [])) or 1
            service_name = self._service_name("output", stage=edge["from_stage"], port=edge["from_port"])
            service = self._open_pubsub(service_name, edge["frame"], readers)
            subscriber = service.subscriber_builder().create()
            slot = _Input(name, edge, self._dtypes[edge["frame"]], subscriber, service)
            if slot.feedback:
                slot.view = self._initial_feedback_frame(edge["frame"])
            self._inputs.append(slot)
        self._outputs = {}
        self._wake_services = []  # the readers' wake-up services the outputs notify
        self._stats = _Stats()
        self._waited_s = 0.0
        self._step_started = None
        self._last_step = None  # (seq, capture_ns)
        self._position = 0
        self._started = time.perf_counter()
        self._waiter = _ArrivalWaiter()
        self._poll = iox2.Duration.from_secs_f64(POLL_S)

    # --- the graph's view of this stage -------------------------------------------------------

    @property
    def input_names(self):
        return [s.name for s in self._inputs]

    def input(self, name, frame_type=None):
        """Checks that the graph gives this stage input `name` (of `frame_type`, a struct name
        such as "KinematicsFrame", when given); returns its frame type's struct name."""
        slot = next((s for s in self._inputs if s.name == name), None)
        if slot is None:
            raise StageError(f"stage '{self.id}': the graph has no input '{name}' for this stage "
                             f"(it has: {', '.join(self.input_names) or 'none'})")
        return self._check_type("input", name, slot.frame_type, frame_type)

    def output(self, port, frame_type=None):
        """Opens output `port` (of `frame_type` when given, checked against the graph)."""
        outputs = self.node_spec["outputs"]
        if port not in outputs:
            raise StageError(f"stage '{self.id}': the graph has no output '{port}' for this stage "
                             f"(it has: {', '.join(outputs) or 'none'})")
        if port in self._outputs:
            return self._outputs[port]
        frame = outputs[port]
        self._check_type("output", port, frame, frame_type)
        iox2 = self._iox2
        readers = self.node_spec.get("readers", {}).get(port, [])
        name = self._service_name("output", stage=self.id, port=port)
        service = self._open_pubsub(name, frame, len(readers))
        strategy = (iox2.BackpressureStrategy.RetryUntilDelivered if self.mode == "offline"
                    else iox2.BackpressureStrategy.DiscardData)
        publisher = service.publisher_builder().backpressure_strategy(strategy).create()
        notifiers = []
        for reader in sorted({r["stage"] for r in readers}):  # one wake-up per reading stage
            event = self._open_event(self._service_name("wake", stage=reader))
            self._wake_services.append(event)
            notifiers.append(event.notifier_builder().create())
        out = Output(self, port, _struct_name(frame), self._dtypes[frame], publisher, service, notifiers)
        self._outputs[port] = out
        return out

    @property
    def should_stop(self):
        """Set on SIGTERM/SIGINT, the launcher's `stop`, or the launcher gone."""
        return self._stop.is_set()

    def run_file(self, name):
        """A file of this stage in the run's folder (removed when the run ends): where a stage
        keeps what a restart of it should find."""
        return os.path.join(self.run_dir, f"{self.id}.{name}")

    def set_summary_detail(self, line):
        """One line of this stage's own result, printed under the run summary."""
        self._stats.detail = str(line)

    def progress(self, done, total=0):
        """A source's progress for the launcher's progress bar (`total` 0: unknown)."""
        self._control.send(f"progress {int(done)} {int(total)}")

    # --- lifecycle -----------------------------------------------------------------------------

    def ready(self):
        """The start handshake: ports exist (`ready`), readers connected once every stage's
        ports exist (`connected`), then wait for `go`. False if told to stop instead."""
        self._control.send("ready")
        if not self._control.wait_for(_Control.CONNECT):
            return False
        for slot in self._inputs:
            slot.subscriber.has_samples()  # connects to every publisher of the edge
        self._control.send("connected")
        if not self._control.wait_for(_Control.GO):
            return False
        self._started = time.perf_counter()
        self._control.heartbeat(lambda: self._position, self._wire["heartbeat_ms"] / 1000.0)
        return True

    def __iter__(self):
        while True:
            step = self.next()
            if step is None:
                return
            yield step

    def next(self):
        """The next aligned set of input frames; None when every input ended or on stop."""
        self._record_work()
        for slot in self._inputs:
            if not slot.feedback:
                slot.release()
        while True:
            if self.should_stop:
                return None
            self._take_ended_sources()
            self._fill_inputs()
            if any(not s.feedback and s.source_gone and s.view is None for s in self._inputs):
                return None  # a stopped branch fed this input and all it delivered is used
            step = self._aligned_step()
            if step is not None:
                seq, capture_ns, flags = step
                if flags & END_OF_STREAM:
                    return None
                return self._begin_step(seq, capture_ns, flags)
            if self._listener is None:
                return None
            # Only a frame that can complete the step ends the wait (graph/src/stage.rs,
            # `next_step`): a forward input that already holds its frame may have the next ones
            # queued while this stage waits for its feedback, and waking on those is a poll loop.
            self._waiter.wait(self._listener, self._poll,
                              lambda: any((s.feedback or s.view is None)
                                          and s.subscriber.has_samples() for s in self._inputs))

    def finish(self):
        """Ends the stage: END_OF_STREAM on every output, the summary to the launcher, the
        shared memory released."""
        self._record_work()
        seq, capture_ns = (0, 0) if self._last_step is None else (self._last_step[0] + 1,
                                                                   self._last_step[1])
        for out in self._outputs.values():
            sent_before = out.sent
            try:
                out._end(seq, capture_ns)
            except Exception as e:  # after a stop a reader may be gone
                if not self.should_stop:
                    raise StageError(f"output '{out.port}': cannot end the stream: {e!r}") from None
            self._stats.frames_out += sent_before
        wall_s = time.perf_counter() - self._started
        summary = self._stats.summary(wall_s)
        self._control.send("summary " + json.dumps(summary))
        self.close()
        return summary

    def close(self):
        """Releases every port and the node (finish does this)."""
        for slot in self._inputs:
            slot.release()
            slot.subscriber.delete()
        self._inputs = []
        for out in self._outputs.values():
            if out._loaned is not None:
                out._loaned[0].delete()
            for n in out._notifiers:
                n.delete()
            out._publisher.delete()
        self._outputs = {}
        if self._listener is not None:
            self._listener.delete()
            self._listener = None
        self._wake_services = []
        self._wake_service = None
        self._node = None
        import gc

        gc.collect()

    # --- internals ----------------------------------------------------------------------------

    def _service_name(self, kind, **names):
        return self._wire["services"][kind].format(run_id=self.run_id, **names)

    def _open_pubsub(self, name, frame, readers):
        iox2, t = self._iox2, self._transport
        if self.mode == "offline":
            buffer, overflow = t["offline_buffer"], False
        elif _struct_name(frame) == "RawImuFrame":
            buffer, overflow = t["live_raw_buffer"], True
        else:
            buffer, overflow = t["live_buffer"], True
        try:
            return (self._node.service_builder(iox2.ServiceName.new(name))
                    .publish_subscribe(self._payload_types[frame])
                    .subscriber_max_buffer_size(buffer)
                    .subscriber_max_borrowed_samples(t["max_borrowed"])
                    .enable_safe_overflow(overflow)
                    .history_size(0)
                    .max_publishers(t["max_publishers"])
                    .max_subscribers(readers + t["spare_subscribers"])
                    .open_or_create())
        except Exception as e:
            raise StageError(f"cannot open service '{name}' ({_struct_name(frame)}): {e!r}; "
                             "a frame type that differs between the stages?") from None

    def _open_event(self, name):
        iox2, t = self._iox2, self._transport
        try:
            return (self._node.service_builder(iox2.ServiceName.new(name)).event()
                    .max_notifiers(t["max_notifiers"])
                    .max_listeners(t["max_listeners"])
                    .open_or_create())
        except Exception as e:
            raise StageError(f"cannot open service '{name}': {e!r}") from None

    def _check_type(self, direction, port, graph_frame, wanted):
        struct = _struct_name(graph_frame)
        if wanted is not None and wanted not in (struct, graph_frame):
            raise StageError(f"stage '{self.id}': {direction} '{port}' carries {struct} in the "
                             f"graph but the stage uses {wanted}")
        return struct

    def _initial_feedback_frame(self, frame):
        dtype = self._dtypes[frame]
        array = np.zeros(1, dtype=dtype)
        array["header.seq"] = U64_MAX
        array["header.flags"] = FEEDBACK_INITIAL | INVALID
        array.flags.writeable = False
        return array[0]

    def _take_ended_sources(self):
        if not self._control.news.is_set():
            return
        self._control.news.clear()
        ended = set(self._control.ended_stages)
        for slot in self._inputs:
            if not slot.source_gone and slot.from_stage in ended:
                print(f"stage '{slot.from_stage}' was stopped (its branch failed); input "
                      f"'{slot.name}' ends here", file=sys.stderr)
                slot.source_gone = True

    def _fill_inputs(self):
        for slot in self._inputs:
            if slot.feedback:
                while (sample := slot.subscriber.receive()) is not None:
                    header = _view(sample.payload_ptr, slot.dtype, writable=False)
                    slot.last_seq = int(header["header.seq"])
                    if int(header["header.flags"]) & END_OF_STREAM:
                        slot.ended = True
                        sample.delete()
                    else:
                        slot.hold(sample)
                slot.ended |= slot.source_gone
                continue
            if slot.view is not None:
                continue
            sample = slot.subscriber.receive()
            if sample is None:
                continue
            slot.hold(sample)
            seq = slot.seq()
            missed = seq if slot.last_seq is None else max(seq - slot.last_seq - 1, 0)
            if missed:
                self._stats.dropped += missed
                if self.mode == "offline":
                    print(f"input '{slot.name}': {missed} frame(s) before {seq} never arrived",
                          file=sys.stderr)
            slot.last_seq = seq

    def _aligned_step(self):
        forward = [s for s in self._inputs if not s.feedback]
        if any(s.view is None for s in forward):
            return None
        target = max(s.seq() for s in forward)
        stale = [s for s in forward if s.seq() < target]
        if stale:
            for s in stale:
                s.release()
            self._stats.unmatched += len(stale)
            return None
        capture_ns = max(int(s.view["header.capture_ns"]) for s in forward)
        flags = 0
        for s in forward:
            flags |= s.header_flags()
        # Offline: a feedback input must hold the previous frame (its producer cannot be ahead).
        if self.mode == "offline" and target > 0 and not flags & END_OF_STREAM:
            for s in self._inputs:
                if s.feedback and not s.ended and (s.last_seq is None or s.last_seq + 1 < target):
                    return None
        return target, capture_ns, flags

    def _begin_step(self, seq, capture_ns, flags):
        forward = [s for s in self._inputs if not s.feedback]
        self._stats.frames_in += 1
        now = time.time_ns()
        published = max(int(s.view["header.publish_ns"]) for s in forward)
        if published:
            self._stats.latency_us.append(max(now - published, 0) / 1e3)
        if self.mode == "live" and capture_ns:
            for s in forward:
                self._stats.from_capture_us.setdefault(s.name, []).append(
                    max(now - capture_ns, 0) / 1e3)
        self._last_step = (seq, capture_ns)
        self._position = max(self._position, seq + 1)
        self._step_started = time.perf_counter()
        self._waiter.arrived(self._step_started)
        self._waited_s = 0.0
        step_flags = flags & (INVALID | CALIBRATING)
        if self._restart_flag_pending:
            self._restart_flag_pending = False
            step_flags |= RESTARTED
        return Step(seq, capture_ns, step_flags, {s.name: s.view for s in self._inputs})

    def _produced(self, seq, capture_ns):
        """A source's bookkeeping, done by `Output.send` (a transform's happens in `next`)."""
        if self._inputs or (seq < self._position):
            return
        if self._step_started is not None:
            self._record_work()
        self._stats.frames_in += 1
        self._last_step = (seq, capture_ns)
        self._position = seq + 1
        self._step_started = time.perf_counter()

    def _record_work(self):
        if self._step_started is None:
            return
        elapsed = time.perf_counter() - self._step_started - self._waited_s
        self._stats.processing_us.append(max(elapsed, 0.0) * 1e6)
        self._step_started = None
        self._waited_s = 0.0


def _struct_name(frame):
    """A frame type as graph.json spells it ("Kinematics") to its struct name."""
    return frame if frame.endswith("Frame") else frame + "Frame"


def _read_json(path, what):
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        hint = (" (a launcher older than this package: update imuflow)"
                if path.endswith(WIRE_JSON) else "")
        raise StageError(f"cannot read {what} {path}: no such file{hint}") from None
    except (OSError, ValueError) as e:
        raise StageError(f"cannot read {what} {path}: {e}") from None


def _import_bindings(wire):
    """The iceoryx2 bindings, of the version the launcher's iceoryx2 speaks (the shared-memory
    layout changes between minor versions)."""
    wanted = str(wire["iceoryx2"])
    try:
        import iceoryx2
        from importlib.metadata import version

        have = version("iceoryx2")
    except ImportError:
        raise StageError(f"the iceoryx2 Python bindings are not installed: pip install "
                         f"'iceoryx2=={_minor(wanted)}.*'") from None
    if _minor(have) != _minor(wanted):
        raise StageError(f"the iceoryx2 Python bindings are {have} but the launcher speaks iceoryx2 "
                         f"{wanted}: pip install 'iceoryx2=={_minor(wanted)}.*'")
    return iceoryx2


def _minor(version):
    return ".".join(version.split(".")[:2])


def _check_flags(wire):
    theirs = {name: int(bit) for name, bit in wire["flags"].items()}
    if theirs != FLAGS:
        raise StageError(f"the launcher's frame flags {theirs} differ from this package's {FLAGS}: "
                         "install the imuflow Python package of the same version")
