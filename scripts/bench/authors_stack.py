#!/usr/bin/env python3
"""imuflow's PIP against the authors' own stack, side by side on the same frames (issue 50).

The authors' stack is what PIP's Python code runs per frame online: its five networks (built here
as ONNX graphs with PyPI `onnx`, layer for layer as the authors define them, run by `onnxruntime`
one frame at a time with the LSTM states carried, as their live loop steps its PyTorch modules) and
its dual-PD QP (set up with numpy the way their physics optimizer forms it and solved with PyPI
`quadprog`, as they solve it). Both stacks compute the same thing on the same frames:

- the networks carry imuflow's own trained weights (`models/pip.safetensors`) and start from the
  same learned initial state, and their outputs are checked against imuflow's kinematics stage;
- the QP is imuflow's optimizer's QP (same variables, cost, constraints and size), each frame's
  dynamics (M, h, Jacobians) taken from imuflow at the state imuflow's optimizer stood at, and
  quadprog's solution is checked against imuflow's.

Steps (all in one run, one machine):
 1. `imuflow run configs/pip.toml` offline on the bundled sample (without the judge and viewer),
    recording `calib.body_imu`, `kin.kinematics` and `contact.contacts`;
 2. `authors_stack_frames` (tools/eval/examples) on those frames: imuflow's networks and PIP step,
    timed per frame in process, and the data the authors' stack needs;
 3. the authors' networks in onnxruntime (one intra-op thread, and default threads; one ONNX graph
    for the cascade, and one per network as the authors' Python calls each module), checked and
    timed; also at the authors' sizes (H 256, random weights: timing only);
 4. the authors' QP with quadprog per frame, checked and timed (set-up + solve);
 5. imuflow's networks and PIP step timed again on the same frames (the ratios take the slower of
    its two passes, so a machine that slows down during the run counts against imuflow);
 6. imuflow's own benchmarks: `bench kinematics`, `bench physics`, `bench graph configs/pip.toml
    --seconds 15 --no-offline`;
 7. a table (stdout, `authors-stack.md`) and `authors-stack.json` in `--out`, with the share of
    the CPU time other processes and the hypervisor took in each step (a warning above 15 %).

Run it with the venv of `scripts/bench/requirements-authors-stack.txt`:

    python3 -m venv ~/.cache/imuflow/authors-venv
    ~/.cache/imuflow/authors-venv/bin/pip install -r scripts/bench/requirements-authors-stack.txt
    CARGO_INCREMENTAL=0 cargo build --release -p imuflow -p imuflow-eval --example authors_stack_frames
    ~/.cache/imuflow/authors-venv/bin/python scripts/bench/authors_stack.py [--out out/authors-stack]
"""

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
VENV_HINT = (
    "python3 -m venv ~/.cache/imuflow/authors-venv && "
    "~/.cache/imuflow/authors-venv/bin/pip install -r scripts/bench/requirements-authors-stack.txt, "
    "then run this script with ~/.cache/imuflow/authors-venv/bin/python"
)
BUILD_HINT = "CARGO_INCREMENTAL=0 cargo build --release -p imuflow -p imuflow-eval --example authors_stack_frames"
REQUIRED_MODULES = ["numpy", "onnx", "onnxruntime", "quadprog", "safetensors", "mcap"]


def fail(message):
    print(f"authors_stack: {message}", file=sys.stderr)
    sys.exit(2)


def check_python_packages():
    missing = []
    for name in REQUIRED_MODULES:
        try:
            __import__(name)
        except ImportError as e:
            missing.append(f"{name} ({e})")
    if missing:
        fail("missing Python packages: " + ", ".join(missing) + f".\nSet up the venv: {VENV_HINT}")


check_python_packages()

import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402
import quadprog  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from onnx import TensorProto, helper, numpy_helper  # noqa: E402
from safetensors import safe_open  # noqa: E402

WARMUP = 100  # untimed frames before each timed pass (the Rust side does the same)
# The tolerances the check holds the authors' stack to (see the journal for the measured values).
NET_TOL = {"joint_position_m": 1e-5, "joint_velocity_mps": 1e-4, "foot_contact_prob": 1e-5,
           "pose_deg": 1e-3}
INPUT_TOL = 1e-4  # the authors' numpy normalization against the kinematics stage's inputs
# quadprog's solution against imuflow's, per frame, the largest over all frames: q̈ relative
# (‖Δ‖/‖q̈‖), the objective at imuflow's solution above quadprog's optimum (relative; imuflow's
# interior point stops at a 1e-7 gap), the forces and torques relative (the four points of a
# contact square share its load almost freely: the cost is nearly flat there), imuflow's solution's
# largest constraint violation (N, m/s).
QP_TOL = {"qdd": 1e-4, "objective": 1e-4, "forces_torques": 1e-2, "infeasibility": 1e-6}

# SMPL's tree and PIP's joint sets (reference file §1).
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
REDUCED_JOINTS = [1, 2, 3, 4, 5, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19]
ROOT_IMU = 5
PIP_VELOCITY_SCALE = 3.0
NET_NAMES = ["rnn1", "rnn2", "rnn3", "rnn4", "rnn5"]


# ---------------------------------------------------------------------------------------------
# statistics


def stats(values):
    """mean, p50, p99, max of per-frame times (µs), the percentiles as `imuflow bench` takes them."""
    v = np.sort(np.asarray(values, dtype=np.float64))
    if len(v) == 0:
        return None
    pct = lambda p: float(v[int(round((len(v) - 1) * p))])  # noqa: E731
    return {"n": int(len(v)), "mean_us": float(v.mean()), "p50_us": pct(0.5), "p99_us": pct(0.99),
            "max_us": float(v[-1])}


# ---------------------------------------------------------------------------------------------
# preflight and imuflow's runs

BUSY_SHARE = 0.15  # of all cores' time, taken by others during a step: the numbers are suspect


def cpu_snapshot():
    """(wall s, machine busy s, hypervisor-stolen s, this process's and its waited children's s)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:9]]
    hz = os.sysconf("SC_CLK_TCK")
    t = os.times()
    return (time.monotonic(), (v[0] + v[1] + v[2] + v[5] + v[6]) / hz, v[7] / hz,
            t.user + t.system + t.children_user + t.children_system)


def machine_share(a, b):
    """Shares of all cores' time between two snapshots: taken by other processes, and stolen."""
    capacity = max(b[0] - a[0], 1e-9) * (os.cpu_count() or 1)
    others = (b[1] - a[1]) - (b[3] - a[3])
    return {"wall_s": b[0] - a[0], "others": max(0.0, others) / capacity, "steal": (b[2] - a[2]) / capacity}


LIBRARY_SOURCES = ["stages/kinematics/src", "stages/optimizer/src", "stages/contact/src", "libs/body/src",
                   "libs/contact/src"]


def newest_source(folders):
    """The most recently modified Rust source file under `folders`."""
    newest = (0.0, None)
    for folder in folders:
        for path in (REPO / folder).rglob("*.rs"):
            newest = max(newest, (path.stat().st_mtime, path))
    return newest


def check_binaries(imuflow, example):
    missing = [str(p.relative_to(REPO)) for p in (imuflow, example) if not p.exists()]
    if missing:
        fail(f"missing release build: {', '.join(missing)}.\nBuild it: {BUILD_HINT}")
    for binary, folders in [(imuflow, LIBRARY_SOURCES), (example, LIBRARY_SOURCES + ["tools/eval/examples"])]:
        mtime, path = newest_source(folders)
        if binary.stat().st_mtime < mtime:
            print(f"warning: {binary.relative_to(REPO)} is older than {path.relative_to(REPO)}; rebuild for "
                  f"current numbers: {BUILD_HINT}", file=sys.stderr)
    for f in ["models/pip.safetensors", "models/sample/walk.mcap", "configs/pip.toml"]:
        if not (REPO / f).exists():
            fail(f"missing {f} (run from a full checkout)")


def run(cmd, env=None, timeout=None):
    """Run a command in the repository; its stdout (the command and stderr on failure)."""
    full_env = dict(os.environ, **(env or {}))
    proc = subprocess.run(cmd, cwd=REPO, env=full_env, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        fail(f"`{' '.join(map(str, cmd))}` exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc.stdout + proc.stderr


def record_sample(imuflow, work):
    """The pip graph offline on the sample, recording the frames both stacks start from."""
    mcap_path = work / "pip.mcap"
    cmd = [str(imuflow), "run", "configs/pip.toml", "--without", "val", "--without", "viz",
           "--set", f"stages.record.params.path={mcap_path}",
           "--set", "stages.record.inputs.body_imu=calib.body_imu",
           "--set", "stages.record.inputs.contact=contact.contacts"]
    run(cmd)
    return mcap_path, cmd


def dtype_from_layout(layout):
    scalars = {"u8": "<u1", "u16": "<u2", "u32": "<u4", "u64": "<u8", "i32": "<i4", "i64": "<i8",
               "f32": "<f4", "f64": "<f8"}
    names, formats, offsets = [], [], []
    for field in layout["fields"]:
        names.append(field["name"])
        shape = tuple(field.get("shape") or ())
        formats.append((scalars[field["type"]], shape) if shape else scalars[field["type"]])
        offsets.append(field["offset"])
    return np.dtype({"names": names, "formats": formats, "offsets": offsets,
                     "itemsize": int(layout["size"])})


def extract_topics(mcap_path, topics, work):
    """Each topic's frames (END_OF_STREAM left out) as raw bytes in `work/<file>` and as a
    structured array decoded through the layout the recording stores."""
    raw = {t: [] for t in topics}
    layouts = {}
    with open(mcap_path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=list(topics)):
            raw[channel.topic].append(message.data)
            layouts.setdefault(channel.topic, json.loads(schema.data))
    arrays = {}
    for topic, filename in topics.items():
        if not raw[topic]:
            fail(f"{mcap_path}: no messages on {topic}")
        dtype = dtype_from_layout(layouts[topic])
        frames = [m for m in raw[topic]
                  if not np.frombuffer(m, dtype, count=1)["header.flags"][0] & 1]  # END_OF_STREAM
        (work / filename).write_bytes(b"".join(frames))
        arrays[topic] = np.frombuffer(b"".join(frames), dtype)
    return arrays


def parse_bench_kinematics(text):
    m = re.search(r"^pip\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)", text, re.M)
    if not m:
        return None
    v = [float(x) for x in m.groups()]
    return {"step": {"mean_us": v[0], "p50_us": v[1], "p99_us": v[2], "max_us": v[3]},
            "nets": {"p50_us": v[4], "p99_us": v[5]}}


def parse_bench_physics(text):
    m = re.search(r"^pip\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)", text, re.M)
    q = re.search(r"QP alone: mean ([\d.]+) µs, p50 ([\d.]+), p99 ([\d.]+)", text)
    if not m:
        return None
    v = [float(x) for x in m.groups()]
    out = {"step": {"mean_us": v[0], "p50_us": v[1], "p99_us": v[2], "max_us": v[3]}, "fallbacks": int(v[4])}
    if q:
        out["qp"] = {"mean_us": float(q.group(1)), "p50_us": float(q.group(2)), "p99_us": float(q.group(3))}
    return out


def parse_bench_graph(text):
    m = re.search(r"^record\.motion\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)", text, re.M)
    if not m:
        return None
    return {"frames": int(m.group(1)), "p50_us": float(m.group(2)) * 1e3, "p99_us": float(m.group(3)) * 1e3,
            "max_us": float(m.group(4)) * 1e3}


# ---------------------------------------------------------------------------------------------
# the networks as ONNX graphs


def load_weights(path):
    with safe_open(str(path), framework="numpy") as f:
        meta = json.loads(f.metadata()["imuflow"])
        tensors = {k: f.get_tensor(k).astype(np.float32) for k in f.keys()}
    if meta.get("method") != "pip":
        fail(f"{path}: the weights are {meta.get('method')}'s, not pip's")
    return meta, tensors


def random_weights(specs, seed=0):
    """PyTorch-like uniform(±1/√H) weights for nets of the given sizes (timing only)."""
    rng = np.random.default_rng(seed)
    tensors = {}
    for s in specs:
        name, h, n_in, n_out = s["name"], s["hidden"], s["input"], s["output"]
        u = lambda *shape, fan: (rng.uniform(-1, 1, shape) / np.sqrt(fan)).astype(np.float32)  # noqa: E731
        tensors[f"{name}.linear1.weight"] = u(h, n_in, fan=n_in)
        tensors[f"{name}.linear1.bias"] = u(h, fan=n_in)
        for k in range(s["layers"]):
            tensors[f"{name}.rnn.weight_ih_l{k}"] = u(4 * h, h, fan=h)
            tensors[f"{name}.rnn.weight_hh_l{k}"] = u(4 * h, h, fan=h)
            tensors[f"{name}.rnn.bias_ih_l{k}"] = u(4 * h, fan=h)
            tensors[f"{name}.rnn.bias_hh_l{k}"] = u(4 * h, fan=h)
        tensors[f"{name}.linear2.weight"] = u(n_out, h, fan=h)
        tensors[f"{name}.linear2.bias"] = u(n_out, fan=h)
    return tensors


def gates_to_onnx(w, h):
    """PyTorch's LSTM gate blocks (i, f, g, o) in ONNX's order (i, o, f, c)."""
    i, f, g, o = (w[k * h:(k + 1) * h] for k in range(4))
    return np.concatenate([i, o, f, g], axis=0)


class GraphBuilder:
    """Nodes, initializers and graph inputs/outputs of one ONNX graph."""

    def __init__(self):
        self.nodes, self.inits, self.inputs, self.outputs = [], [], [], []

    def const(self, name, array):
        self.inits.append(numpy_helper.from_array(np.ascontiguousarray(array), name))
        return name

    def node(self, op, inputs, outputs, **attrs):
        self.nodes.append(helper.make_node(op, inputs, outputs, **attrs))
        return outputs[0] if len(outputs) == 1 else outputs

    def input(self, name, shape):
        self.inputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, shape))
        return name

    def output(self, name, shape):
        self.outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, shape))

    def model(self, name):
        graph = helper.make_graph(self.nodes, name, self.inputs, self.outputs, self.inits)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)],
                                  producer_name="imuflow scripts/bench/authors_stack.py")
        model.ir_version = 8
        onnx.checker.check_model(model)
        return model


def add_rnn(g, tensors, spec, x):
    """articulate's RNN with input_linear (reference §2.0): linear1 → ReLU → LSTM (L layers, one
    ONNX LSTM node each, as torch.onnx exports a stacked LSTM) → linear2. The state is one graph
    input and output per layer: `<net>.h<k>`, `<net>.c<k>` [1, 1, H]. Returns the output's name."""
    name, h = spec["name"], spec["hidden"]
    t = lambda key: tensors[f"{name}.{key}"]  # noqa: E731
    y = g.node("Gemm", [x, g.const(f"{name}.linear1.weight", t("linear1.weight")),
                        g.const(f"{name}.linear1.bias", t("linear1.bias"))], [f"{name}.l1"], transB=1)
    y = g.node("Relu", [y], [f"{name}.relu"])
    seq = g.node("Unsqueeze", [y, g.const(f"{name}.axis0", np.array([0], np.int64))], [f"{name}.seq"])
    for k in range(spec["layers"]):
        w = gates_to_onnx(t(f"rnn.weight_ih_l{k}"), h)[None]
        r = gates_to_onnx(t(f"rnn.weight_hh_l{k}"), h)[None]
        b = np.concatenate([gates_to_onnx(t(f"rnn.bias_ih_l{k}"), h),
                            gates_to_onnx(t(f"rnn.bias_hh_l{k}"), h)])[None]
        h_in, c_in = g.input(f"{name}.h{k}", [1, 1, h]), g.input(f"{name}.c{k}", [1, 1, h])
        _, h_out, c_out = g.node(
            "LSTM", [seq, g.const(f"{name}.W{k}", w), g.const(f"{name}.R{k}", r), g.const(f"{name}.B{k}", b),
                     "", h_in, c_in],
            [f"{name}.Y{k}", f"{name}.h{k}_out", f"{name}.c{k}_out"], hidden_size=h)
        g.output(h_out, [1, 1, h])
        g.output(c_out, [1, 1, h])
        seq = h_out  # [1 direction, 1 batch, H] is the next layer's [1 step, 1 batch, H]
    flat = g.node("Reshape", [seq, g.const(f"{name}.flat", np.array([1, h], np.int64))], [f"{name}.hflat"])
    return g.node("Gemm", [flat, g.const(f"{name}.linear2.weight", t("linear2.weight")),
                           g.const(f"{name}.linear2.bias", t("linear2.bias"))], [f"{name}.out"], transB=1)


def cascade_model(specs, tensors):
    """PIP's five networks in one graph (reference §2.2): x → rnn1 (leaf positions) → rnn2 (all
    joint positions, from [leaf, x]) → rnn3 (reduced r6d), rnn4 (joint velocities), rnn5 (foot
    contacts), each from [full, x]."""
    by = {s["name"]: s for s in specs}
    g = GraphBuilder()
    x = g.input("x", [1, 72])
    leaf = add_rnn(g, tensors, by["rnn1"], x)
    leaf_x = g.node("Concat", [leaf, x], ["leaf_x"], axis=1)
    full = add_rnn(g, tensors, by["rnn2"], leaf_x)
    full_x = g.node("Concat", [full, x], ["full_x"], axis=1)
    outs = [leaf, full] + [add_rnn(g, tensors, by[n], full_x) for n in ("rnn3", "rnn4", "rnn5")]
    for name, spec in zip(outs, [by["rnn1"], by["rnn2"], by["rnn3"], by["rnn4"], by["rnn5"]]):
        g.output(name, [1, spec["output"]])
    # Outputs in a fixed order: the five nets' outputs first, then the states.
    g.outputs = g.outputs[-5:] + g.outputs[:-5]
    return g.model("pip_cascade")


def single_model(spec, tensors):
    g = GraphBuilder()
    out = add_rnn(g, tensors, spec, g.input("x", [1, spec["input"]]))
    g.output(out, [1, spec["output"]])
    g.outputs = g.outputs[-1:] + g.outputs[:-1]
    return g.model(spec["name"])


def init_net_model(name, tensors):
    """RNNWithInit's init_net (reference §2.0): Linear, ReLU, Linear, ReLU, Linear → [h_l0 … c_l…]."""
    g = GraphBuilder()
    y = g.input("init", [1, tensors[f"{name}.init_net.0.weight"].shape[1]])
    for i in (0, 2, 4):
        y = g.node("Gemm", [y, g.const(f"w{i}", tensors[f"{name}.init_net.{i}.weight"]),
                            g.const(f"b{i}", tensors[f"{name}.init_net.{i}.bias"])], [f"y{i}"], transB=1)
        if i < 4:
            y = g.node("Relu", [y], [f"r{i}"])
    g.output(y, [1, tensors[f"{name}.init_net.4.weight"].shape[0]])
    return g.model(f"{name}_init")


def session(model, threads):
    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = threads
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def initial_states(specs, tensors, inits):
    """{net.h<k>/net.c<k>: [1, 1, H]}: learned for the nets with an init net and an init input
    (imuflow's Streamer: rnn1 from the start pose's leaf positions, rnn4 from zero velocity),
    zero otherwise (the authors' live loop starts every net from zeros)."""
    states = {}
    for s in specs:
        name, h, layers = s["name"], s["hidden"], s["layers"]
        init = inits.get(name)
        if init is not None and f"{name}.init_net.0.weight" in tensors:
            sess = session(init_net_model(name, tensors), 1)
            v = sess.run(None, {"init": np.asarray(init, np.float32)[None]})[0].reshape(2 * layers, h)
        else:
            v = np.zeros((2 * layers, h), np.float32)
        for k in range(layers):
            states[f"{name}.h{k}"] = v[k].reshape(1, 1, h).copy()
            states[f"{name}.c{k}"] = v[layers + k].reshape(1, 1, h).copy()
    return states


class CascadeRunner:
    """One session for the whole cascade: one `run` per frame."""

    def __init__(self, specs, tensors, threads):
        self.sess = session(cascade_model(specs, tensors), threads)
        outs = [o.name for o in self.sess.get_outputs()]
        self.state_names = [n[:-len("_out")] for n in outs[5:]]

    def step(self, x, state):
        feed = dict(state)
        feed["x"] = x
        outs = self.sess.run(None, feed)
        state.update(zip(self.state_names, outs[5:]))
        return outs[:5]


class ModuleRunner:
    """One session per network, called in turn, as the authors' Python steps each module."""

    def __init__(self, specs, tensors, threads):
        self.sessions = []
        for s in specs:
            sess = session(single_model(s, tensors), threads)
            outs = [o.name for o in sess.get_outputs()]
            inputs = [i.name for i in sess.get_inputs() if i.name != "x"]
            self.sessions.append((sess, inputs, [n[:-len("_out")] for n in outs[1:]]))

    def _run(self, k, x, state):
        sess, inputs, names = self.sessions[k]
        feed = {n: state[n] for n in inputs}
        feed["x"] = x
        outs = sess.run(None, feed)
        state.update(zip(names, outs[1:]))
        return outs[0]

    def step(self, x, state):
        leaf = self._run(0, x, state)
        full = self._run(1, np.concatenate([leaf, x], axis=1), state)
        full_x = np.concatenate([full, x], axis=1)
        return [leaf, full] + [self._run(k, full_x, state) for k in (2, 3, 4)]


def time_networks(runner, x, init_state):
    """Per-frame µs of the networks' step (run + carried state), after WARMUP untimed frames,
    from the initial state; and the outputs of the timed pass."""
    state = {k: v.copy() for k, v in init_state.items()}
    for i in range(min(WARMUP, len(x))):
        runner.step(x[i:i + 1], state)
    state = {k: v.copy() for k, v in init_state.items()}
    times, outputs = np.empty(len(x)), []
    clock = time.perf_counter_ns
    for i in range(len(x)):
        xi = x[i:i + 1]
        t0 = clock()
        out = runner.step(xi, state)
        times[i] = (clock() - t0) * 1e-3
        outputs.append(out)
    return times, outputs


def quat_to_matrix(q):
    """(n, 4) wxyz unit quaternions (normalized here) → (n, 3, 3)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def authors_normalization(quat, acc):
    """PIP's 72 inputs of one frame from R_MB and the free accelerations (reference §2.2: TransPose's
    layout without its /30): root-relative accelerations and orientations in the root frame, the
    root's own acceleration and orientation absolute."""
    r = quat_to_matrix(quat.astype(np.float32))
    root = r[ROOT_IMU]
    a = acc - np.where(np.arange(6)[:, None] == ROOT_IMU, 0, acc[ROOT_IMU])
    ori = np.einsum("ji,njk->nik", root, r)
    ori[ROOT_IMU] = root
    return np.concatenate([(a @ root).ravel(), ori.ravel()]).astype(np.float32)


def rotation_from_r6d(v):
    a, b = v[:3].astype(np.float64), v[3:].astype(np.float64)
    c0 = a / np.linalg.norm(a)
    c1 = b - c0 * (c0 @ b)
    c1 /= np.linalg.norm(c1)
    m = np.stack([c0, c1, np.cross(c0, c1)], axis=1)
    return m if np.all(np.isfinite(m)) and np.linalg.det(m) > 0.5 else np.eye(3)


def papers_frame(out, x):
    """The kinematics frame of the papers' pose from the five outputs of one frame (reference §2.2:
    positions and velocities rotated by the root, ×3; contacts through a sigmoid; the pose from the
    reduced joints' r6d, ignored joints at identity, the root the pelvis sensor's)."""
    leaf, full, r6d, vel, contact = (o.reshape(-1).astype(np.float64) for o in out)
    root = x[63:72].astype(np.float64).reshape(3, 3)
    positions = np.zeros((24, 3))
    positions[1:] = full.reshape(23, 3) @ root.T
    velocities = vel.reshape(24, 3) @ root.T * PIP_VELOCITY_SCALE
    feet = 1 / (1 + np.exp(-contact[:2]))
    glob = [np.eye(3)] * 24
    for k, j in enumerate(REDUCED_JOINTS):
        glob[j] = rotation_from_r6d(r6d[6 * k:6 * k + 6])
    local = np.tile(np.eye(3), (24, 1, 1))
    for j in REDUCED_JOINTS:
        local[j] = glob[PARENTS[j]].T @ glob[j]
    local[0] = root
    return positions, velocities, feet, local


def angle_deg(a, b):
    """Angle between rotations per pair (…, 3, 3), degrees, from ‖a − b‖_F = 2√2·sin(θ/2): unlike
    the trace of a·bᵀ it stays exact for the root, which is the sensor's f32 matrix as published
    (orthonormal to 2e-7 only)."""
    d = np.linalg.norm(a - b, axis=(-2, -1))
    return np.degrees(2 * np.arcsin(np.minimum(1.0, d / (2 * np.sqrt(2)))))


def check_networks(outputs, x, imuflow_out, recorded, frame_index):
    """The authors' outputs against imuflow's Streamer (papers' pose) and the graph's recording."""
    n = len(outputs)
    per = imuflow_out.reshape(n, -1)
    ref_pos, ref_vel = per[:, :72].reshape(n, 24, 3), per[:, 72:144].reshape(n, 24, 3)
    ref_feet, ref_pose = per[:, 144:146], per[:, 146:].reshape(n, 24, 3, 3)
    pos, vel, feet, pose = zip(*(papers_frame(o, x[i]) for i, o in enumerate(outputs)))
    pos, vel, feet, pose = map(np.array, (pos, vel, feet, pose))
    result = {
        "vs_imuflow_streamer": {
            "joint_position_m": float(np.abs(pos - ref_pos).max()),
            "joint_velocity_mps": float(np.abs(vel - ref_vel).max()),
            "foot_contact_prob": float(np.abs(feet - ref_feet).max()),
            "pose_deg": float(angle_deg(pose, ref_pose).max()),
        }
    }
    rec = recorded[np.asarray(frame_index)]
    result["vs_graph_recording"] = {
        "joint_position_m": float(np.abs(pos - rec["joint_position_m"]).max()),
        "joint_velocity_mps": float(np.abs(vel - rec["joint_velocity_mps"]).max()),
        "foot_contact_prob": float(np.abs(feet - rec["foot_contact_prob"]).max()),
    }
    result["tolerance"] = NET_TOL
    result["within_tolerance"] = all(result["vs_imuflow_streamer"][k] <= NET_TOL[k] for k in NET_TOL) and all(
        result["vs_graph_recording"][k] <= NET_TOL[k] for k in result["vs_graph_recording"])
    return result


# ---------------------------------------------------------------------------------------------
# the QP


def read_qp_records(path, dofs, jac):
    """The records `authors_stack_frames` writes (tools/eval/examples/authors_stack_frames.rs,
    `write_qp_record`)."""
    data = np.fromfile(path, dtype="<f8")
    records, at = [], 0
    n = dofs

    def take(count, shape=None):
        nonlocal at
        v = data[at:at + count]
        at += count
        return v.reshape(shape) if shape else v

    while at < len(data):
        frame, npts, nbodies, _ = take(4)
        npts, nbodies = int(npts), int(nbodies)
        r = {"frame": int(frame), "npts": npts, "nbodies": nbodies}
        r["M"] = take(n * n, (n, n))
        r["h"] = take(n)
        r["v"] = take(n)
        r["e_rot"] = take(n - 3)
        pos = [take(jac + 9) for _ in range(20)]
        r["J_pos"] = np.stack([p[:jac].reshape(3, n) for p in pos])
        r["vel_pos"] = np.stack([p[jac:jac + 3] for p in pos])
        r["jdv_pos"] = np.stack([p[jac + 3:jac + 6] for p in pos])
        r["vref_pos"] = np.stack([p[jac + 6:jac + 9] for p in pos])
        bones = [take(jac + 4) for _ in range(10)]
        r["J_bone"] = np.stack([b[:jac].reshape(3, n) for b in bones])
        r["want_bone"] = np.stack([b[jac:jac + 3] for b in bones])
        r["w_bone"] = np.array([b[jac + 3] for b in bones])
        feet = [take(jac + 5) for _ in range(2)]
        r["J_foot"] = np.stack([f[:jac].reshape(3, n) for f in feet])
        r["vel_foot"] = np.stack([f[jac:jac + 3] for f in feet])
        r["height_foot"] = np.array([f[jac + 3] for f in feet])
        r["c_foot"] = np.array([f[jac + 4] for f in feet])
        pts = [take(jac + 1) for _ in range(npts)]
        r["J_pt"] = np.stack([p[:jac].reshape(3, n) for p in pts]) if npts else np.zeros((0, 3, n))
        r["height_pt"] = np.array([p[jac] for p in pts])
        bods = [take(jac + 3) for _ in range(nbodies)]
        r["J_body"] = np.stack([b[:jac].reshape(3, n) for b in bods]) if nbodies else np.zeros((0, 3, n))
        r["vel_body"] = np.stack([b[jac:jac + 3] for b in bods]) if nbodies else np.zeros((0, 3))
        r["sol_vdot"] = take(n)
        r["sol_force"] = take(3 * npts)
        r["sol_tau"] = take(n)
        r["sol_stats"] = take(3)
        records.append(r)
    return records


def authors_qp_setup(r, c):
    """PIP's QP of one frame as the authors form it (reference §5.2; paper Eq. 3-13): x = [q̈ (75),
    λ (3 per contact point), τ (75)]; each cost term a block ½‖A·x_block − b‖², P = blockdiag(ΣAᵀA)
    and q = −ΣAᵀb; the equation of motion as equalities; friction pyramid and velocity bounds as
    inequalities G·x ≤ h. imuflow's cost has the paper's terms and its six sensor-bone and four
    limb-bone orientation rows (stages/optimizer), added here as more rows of the q̈ block, so the
    two solve the same problem. Returns quadprog's (G, a, C, b, meq)."""
    n = len(r["h"])
    npts = r["npts"]
    nl = 3 * npts
    dt = c["dt"]
    # Cost on q̈: joint-rotation PD (every joint, the root's rotation included), joint-position PD
    # from the networks' velocities, imuflow's bone-orientation rows.
    a_rot = np.hstack([np.zeros((n - 3, 3)), np.eye(n - 3)])
    b_rot = c["kp_rotation"] * r["e_rot"] - c["kd_rotation"] * r["v"][3:]
    w = c["coeff_joint_velocity"]
    a_pos = r["J_pos"].reshape(-1, n) * w
    b_pos = (c["kp_position"] * dt * r["vref_pos"] - c["kd_position"] * r["vel_pos"] - r["jdv_pos"]).ravel() * w
    wb = np.repeat(r["w_bone"], 3)
    a_bone = r["J_bone"].reshape(-1, n) * wb[:, None]
    b_bone = r["want_bone"].ravel() * wb
    a_q = np.vstack([a_rot, a_pos, a_bone])
    b_q = np.concatenate([b_rot, b_pos, b_bone])
    # Force penalty ("Signorini", coeff_lambda·max(height, 0.005)·λ) and torque regulariser.
    a_lam = np.diag(np.repeat(c["coeff_lambda"] * np.maximum(r["height_pt"], c["lambda_min_height_m"]), 3))
    a_tau = np.diag([c["coeff_root_virtual"]] * 6 + [c["coeff_joint_torque"]] * (n - 6))
    size = 2 * n + nl
    p = np.zeros((size, size))
    p[:n, :n] = a_q.T @ a_q
    p[n:n + nl, n:n + nl] = a_lam.T @ a_lam
    p[n + nl:, n + nl:] = a_tau.T @ a_tau
    q = np.zeros(size)
    q[:n] = -a_q.T @ b_q
    # Equation of motion M·q̈ + h = τ + Σ J_kᵀλ_k.
    jc = r["J_pt"].reshape(nl, n)
    a_eq = np.hstack([r["M"], -jc.T, -np.eye(n)])
    b_eq = -r["h"]
    # Inequalities: friction pyramid per point, velocity bounds on the feet (always) and on the other
    # contact bodies, on v⁺ = v + dt·J·q̈.
    g_rows, h_rows = [], []
    mu, s2 = c["friction"], np.sqrt(2.0)
    pyramid = np.array([[s2, -mu, 0], [-s2, -mu, 0], [0, -mu, s2], [0, -mu, -s2]])
    for k in range(npts):
        rows = np.zeros((4, size))
        rows[:, n + 3 * k:n + 3 * k + 3] = pyramid
        g_rows.append(rows)
        h_rows.append(np.zeros(4))

    def velocity_rows(jac, vel, bounds):
        for i, (lo, hi) in enumerate(bounds):
            for sign, bound in ((1.0, hi), (-1.0, -lo)):
                if np.isinf(bound) and bound > 0:
                    continue
                row = np.zeros((1, size))
                row[0, :n] = sign * dt * jac[i]
                g_rows.append(row)
                h_rows.append(np.array([bound - sign * vel[i]]))

    lock = c["foot_lock_probability"]
    for k in range(2):
        prob = r["c_foot"][k]
        with np.errstate(divide="ignore"):
            th = -np.log(min(prob, lock - 1e-5) / lock)
        th = np.inf if np.isnan(th) else th
        th_y = -r["height_foot"][k] / dt
        velocity_rows(r["J_foot"][k], r["vel_foot"][k], [(-th, th), (th_y, max(th, th_y) + 1e-6), (-th, th)])
    slide, rise = c["contact_body_slide_mps"], c["contact_body_rise_mps"]
    for k in range(r["nbodies"]):
        velocity_rows(r["J_body"][k], r["vel_body"][k], [(-slide, slide), (0.0, rise), (-slide, slide)])
    g = np.vstack(g_rows) if g_rows else np.zeros((0, size))
    hv = np.concatenate(h_rows) if h_rows else np.zeros(0)
    # quadprog: min ½xᵀGx − aᵀx s.t. Cᵀx ≥ b, the first meq rows equalities.
    qp_g = 0.5 * (p + p.T)
    qp_a = -q
    qp_c = -np.vstack([a_eq, g]).T
    qp_b = -np.concatenate([b_eq, hv])
    return qp_g, qp_a, qp_c, qp_b, n, (a_eq, b_eq)


def authors_qp_frame(r, c):
    """One frame as the authors' live loop does it: set up, solve with quadprog; on a failure or a
    solution with ‖x‖ > 1e4 (PIP's threshold) re-solve without the inequalities (PIP livedemo).
    Returns (quadprog's result of the first solve or None, the problem, whether it fell back,
    solve-only µs)."""
    problem = authors_qp_setup(r, c)
    qp_g, qp_a, qp_c, qp_b, meq, (a_eq, b_eq) = problem
    t0 = time.perf_counter_ns()
    try:
        result = quadprog.solve_qp(qp_g, qp_a, qp_c, qp_b, meq)
    except ValueError:
        result = None
    solve_us = (time.perf_counter_ns() - t0) * 1e-3
    fell_back = result is None or np.linalg.norm(result[0]) > 1e4
    if fell_back:
        t0 = time.perf_counter_ns()
        try:
            quadprog.solve_qp(qp_g, qp_a, -a_eq.T, -b_eq, meq)
        except ValueError:
            pass
        solve_us += (time.perf_counter_ns() - t0) * 1e-3
    return result, problem, fell_back, solve_us


def run_qp(records, c):
    """Per-frame µs of the authors' QP (set-up + solve, and solve alone) after WARMUP untimed
    frames, and the check of quadprog's solution against imuflow's: the accelerations q̈ (what the
    motion is integrated from), the objective at both solutions, the forces and torques (weakly
    determined: see QP_TOL), imuflow's solution's feasibility."""
    for r in records[:WARMUP]:
        authors_qp_frame(r, c)
    total, solve, fallbacks, failed, sizes = [], [], 0, 0, []
    err = {"qdd": [], "forces_torques": [], "objective": [], "infeasibility": []}
    clock = time.perf_counter_ns
    for r in records:
        t0 = clock()
        result, problem, fell_back, solve_us = authors_qp_frame(r, c)
        total.append((clock() - t0) * 1e-3)
        solve.append(solve_us)
        fallbacks += int(fell_back)
        n, nl = len(r["h"]), 3 * r["npts"]
        sizes.append(2 * n + nl)
        if result is None:
            failed += 1
            continue
        x, value = result[0], result[1]
        qp_g, qp_a, qp_c, qp_b = problem[:4]
        ref = np.concatenate([r["sol_vdot"], r["sol_force"], r["sol_tau"]])
        rel = lambda a, b: np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12)  # noqa: E731
        err["qdd"].append(rel(x[:n], ref[:n]))
        err["forces_torques"].append(rel(x[n:], ref[n:]))
        ref_value = 0.5 * ref @ qp_g @ ref - qp_a @ ref
        err["objective"].append((ref_value - value) / max(abs(value), 1e-12))
        err["infeasibility"].append(max(0.0, -float(np.min(qp_c.T @ ref - qp_b))))
    summary = {}
    for key, values in err.items():
        v = np.asarray(values)
        summary[key] = {"p50": float(np.median(v)), "p99": float(np.percentile(v, 99)),
                        "max": float(np.abs(v).max())} if len(v) else None
    check = {
        "frames": len(records),
        "quadprog_failed": failed,
        "pip_fallback_resolves": fallbacks,
        "relative_error": summary,
        "tolerance": QP_TOL,
        "variables_min_max": [int(min(sizes)), int(max(sizes))],
        "contact_points_max": int(max(r["npts"] for r in records)),
    }
    check["within_tolerance"] = failed == 0 and all(
        summary[k] is not None and summary[k]["max"] <= QP_TOL[k] for k in QP_TOL)
    return np.array(total), np.array(solve), check


# ---------------------------------------------------------------------------------------------
# report


def fmt_ms(us):
    return f"{us / 1000:.3f}"


def summarize(rows):
    lines = ["| what | frames | p50 ms | p99 ms | mean ms |", "|---|---|---|---|---|"]
    for label, s in rows:
        if s is None:
            lines.append(f"| {label} | – | – | – | – |")
            continue
        mean = fmt_ms(s["mean_us"]) if "mean_us" in s else "–"
        lines.append(f"| {label} | {s.get('n', '')} | {fmt_ms(s['p50_us'])} | {fmt_ms(s['p99_us'])} | {mean} |")
    return "\n".join(lines)


def cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/authors-stack", help="where the table and JSON go")
    ap.add_argument("--imuflow", default="target/release/imuflow")
    ap.add_argument("--example", default="target/release/examples/authors_stack_frames")
    ap.add_argument("--graph-seconds", type=int, default=15, help="bench graph --seconds (0: skip)")
    ap.add_argument("--skip-imuflow-bench", action="store_true",
                    help="leave out bench kinematics/physics/graph (the same-frames numbers stay)")
    ap.add_argument("--keep", action="store_true", help="keep the work folder (recording and dumps)")
    args = ap.parse_args()

    imuflow, example = REPO / args.imuflow, REPO / args.example
    check_binaries(imuflow, example)
    out_dir = REPO / args.out
    out_dir.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="authors-stack-"))
    started = datetime.datetime.now(datetime.timezone.utc)
    commands, load = {}, {}
    current = {}

    def phase(name):
        """Print a step; close the previous one with the share of the machine's CPU time that
        other processes (not this script and the commands it ran) and the hypervisor took."""
        now = cpu_snapshot()
        if current:
            load[current["name"]] = machine_share(current["at"], now)
        current.update(name=name, at=now)
        if name:
            print(name + " ...", flush=True)

    try:
        phase("1/7 recording the pip graph on the sample")
        mcap_path, cmd = record_sample(imuflow, work)
        commands["record"] = " ".join([args.imuflow] + [c.replace(str(work), "$WORK") for c in cmd[1:]])
        arrays = extract_topics(mcap_path, {"calib.body_imu": "body_imu.bin", "kin.kinematics": "kinematics.bin",
                                            "contact.contacts": "contacts.bin"}, work)
        seqs = [a["header.seq"] for a in arrays.values()]
        if any(len(s) != len(seqs[0]) or np.any(s != seqs[0]) for s in seqs):
            fail("the recording's body_imu, kinematics and contact frames do not pair up by seq")

        phase("2/7 imuflow's networks and QP on those frames (authors_stack_frames)")
        run([str(example), str(work), "models/pip.safetensors"], env={"RAYON_NUM_THREADS": "1"})
        commands["imuflow_same_frames"] = f"RAYON_NUM_THREADS=1 {args.example} $WORK models/pip.safetensors"
        meta = json.loads((work / "meta.json").read_text())
        nets_meta, phys = meta["networks"], meta["physics"]

        phase("3/7 the authors' networks in onnxruntime")
        wmeta, tensors = load_weights(REPO / "models/pip.safetensors")
        specs = wmeta["nets"]
        x = np.fromfile(work / "net_input.f32", dtype="<f4").reshape(-1, 72)
        inits = {"rnn1": nets_meta["rnn1_init_input"], "rnn4": nets_meta["rnn4_init_input"]}
        init_state = initial_states(specs, tensors, inits)
        imuflow_out = np.fromfile(work / "net_output.f64", dtype="<f8")
        # The authors' input normalization from the recorded calibrated frames (numpy), checked
        # against the kinematics stage's inputs and timed per frame.
        body = arrays["calib.body_imu"][np.asarray(nets_meta["frame_index"])]
        quat, acc = body["bone_orientation_wxyz"], body["free_acceleration_mps2"]
        norm_us, norm_err = np.empty(len(x)), 0.0
        for i in range(len(x)):
            t0 = time.perf_counter_ns()
            xi = authors_normalization(quat[i], acc[i])
            norm_us[i] = (time.perf_counter_ns() - t0) * 1e-3
            norm_err = max(norm_err, float(np.abs(xi - x[i]).max()))
        net_runs, net_check = {}, None
        for label, runner_cls in [("one graph", CascadeRunner), ("a graph per network", ModuleRunner)]:
            for threads, tlabel in [(1, "1 thread"), (0, "default threads")]:
                runner = runner_cls(specs, tensors, threads)
                times, outputs = time_networks(runner, x, init_state)
                net_runs[f"{label}, {tlabel}"] = times
                if net_check is None:
                    net_check = check_networks(outputs, x, imuflow_out, arrays["kin.kinematics"],
                                               nets_meta["frame_index"])
                    net_check["normalization_max_abs"] = norm_err
                    net_check["within_tolerance"] &= norm_err <= INPUT_TOL
        # PIP's own sizes (reference §2.2: H 256, the contact net 64), random weights: timing only.
        full_specs = [dict(s, hidden=64 if s["name"] == "rnn5" else 256) for s in specs]
        full_tensors = random_weights(full_specs)
        full_state = initial_states(full_specs, full_tensors, {})
        full_runs = {}
        for threads, tlabel in [(1, "1 thread"), (0, "default threads")]:
            times, _ = time_networks(CascadeRunner(full_specs, full_tensors, threads), x, full_state)
            full_runs[f"one graph, {tlabel}"] = times

        phase("4/7 the authors' QP with quadprog")
        records = read_qp_records(work / "qp.f64", phys["dofs"], phys["jacobian_values"])
        qp_total, qp_solve, qp_check = run_qp(records, phys["config"])

        phase("5/7 imuflow's networks and QP on those frames again (timing only)")
        run([str(example), str(work), "models/pip.safetensors", "--timing-only"], env={"RAYON_NUM_THREADS": "1"})
        meta_after = json.loads((work / "meta.json").read_text())

        bench = {}
        if not args.skip_imuflow_bench:
            phase("6/7 imuflow's own benchmarks")
            env1 = {"RAYON_NUM_THREADS": "1"}
            for key, cmd, env, parse in [
                ("kinematics", [str(imuflow), "bench", "kinematics"], env1, parse_bench_kinematics),
                ("physics", [str(imuflow), "bench", "physics"], env1, parse_bench_physics),
                ("graph", [str(imuflow), "bench", "graph", "configs/pip.toml", "--seconds", str(args.graph_seconds),
                           "--no-offline"], {}, parse_bench_graph),
            ]:
                if key == "graph" and args.graph_seconds <= 0:
                    continue
                text = run(cmd, env=env, timeout=600)
                shown = ("RAYON_NUM_THREADS=1 " if env else "") + " ".join([args.imuflow] + cmd[1:])
                bench[key] = {"command": shown, "parsed": parse(text), "output": text[-4000:]}
                if bench[key]["parsed"] is None:
                    print(f"warning: could not read the numbers of `{shown}`; its output is in the JSON",
                          file=sys.stderr)
    finally:
        if args.keep:
            print(f"work folder kept: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)

    phase("")
    print("7/7 report", flush=True)
    # Per-frame sums on the frames both have: networks of frame i + the QP of frame i.
    net_frames = np.asarray(nets_meta["frame_index"])
    qp_frames = np.array([r["frame"] for r in records])
    net_at = {f: i for i, f in enumerate(net_frames)}
    both = [(net_at[f], k) for k, f in enumerate(qp_frames) if f in net_at]
    ni, qi = (np.array(v) for v in zip(*both))
    # imuflow's per-frame times, timed before and after the authors' stack: the ratios take the
    # slower of the two passes (a machine that slowed down during the run then counts against
    # imuflow, not for it).
    passes = {}
    for name, pm in [("before", meta), ("after", meta_after)]:
        nets_us = np.asarray(pm["networks"]["imuflow_nets_us"])
        pip_us = np.asarray(pm["physics"]["imuflow_step_us"])
        if len(pip_us) != len(records):
            print(f"warning: {len(pip_us)} timed physics frames but {len(records)} QP records "
                  "(degraded frames); the sums pair them by position", file=sys.stderr)
        passes[name] = {"nets": nets_us, "step": np.asarray(pm["networks"]["imuflow_step_us"]), "pip": pip_us,
                        "solve": np.asarray(pm["physics"]["imuflow_solve_us"])}
    m = min(min(len(p["pip"]) for p in passes.values()), len(records))
    qi_ok = qi < m
    ni, qi = ni[qi_ok], qi[qi_ok]

    authors_nets_key = "one graph, 1 thread"
    results = {
        "networks": {
            **{f"authors onnxruntime, {k}": stats(v) for k, v in net_runs.items()},
            **{f"authors onnxruntime at PIP's sizes (H 256), {k}": stats(v) for k, v in full_runs.items()},
            "authors normalization (numpy)": stats(norm_us),
        },
        "qp": {
            "authors set-up + quadprog": stats(qp_total),
            "authors quadprog alone": stats(qp_solve),
        },
        "both": {},
    }
    for name, p in passes.items():
        results["networks"][f"imuflow networks (same frames, {name})"] = stats(p["nets"])
        results["networks"][f"imuflow kinematics step (same frames, {name})"] = stats(p["step"])
        results["qp"][f"imuflow PIP step (same frames, {name})"] = stats(p["pip"])
        results["qp"][f"imuflow QP solve alone (same frames, {name})"] = stats(p["solve"])
    for k, v in net_runs.items():
        results["both"][f"authors: onnxruntime {k} + set-up + quadprog"] = stats(v[ni] + qp_total[qi])
    for k, v in full_runs.items():
        results["both"][f"authors at PIP's sizes (H 256): onnxruntime {k} + set-up + quadprog"] = \
            stats(v[ni] + qp_total[qi])
    for name, p in passes.items():
        results["both"][f"imuflow: networks + PIP step ({name})"] = stats(p["nets"][ni] + p["pip"][qi])
        results["both"][f"imuflow: networks + QP solve alone ({name})"] = stats(p["nets"][ni] + p["solve"][qi])
    slower = max(passes, key=lambda name: results["both"][f"imuflow: networks + PIP step ({name})"]["p50_us"])
    ratios = {}
    ref = results["both"][f"imuflow: networks + PIP step ({slower})"]
    for k in net_runs:
        a = results["both"][f"authors: onnxruntime {k} + set-up + quadprog"]
        ratios[f"onnxruntime {k}"] = {"p50": a["p50_us"] / ref["p50_us"], "p99": a["p99_us"] / ref["p99_us"]}
    for k in full_runs:
        a = results["both"][f"authors at PIP's sizes (H 256): onnxruntime {k} + set-up + quadprog"]
        ratios[f"at PIP's sizes (H 256, random weights): onnxruntime {k}"] = {
            "p50": a["p50_us"] / ref["p50_us"], "p99": a["p99_us"] / ref["p99_us"]}
    # Per-part ratios of the headline configuration.
    part = lambda a, b: {"p50": a["p50_us"] / b["p50_us"], "p99": a["p99_us"] / b["p99_us"]}  # noqa: E731
    ratios["networks alone (one graph, 1 thread / imuflow networks)"] = part(
        results["networks"][f"authors onnxruntime, {authors_nets_key}"],
        results["networks"][f"imuflow networks (same frames, {slower})"])
    ratios["QP (set-up + quadprog / imuflow PIP step)"] = part(
        results["qp"]["authors set-up + quadprog"], results["qp"][f"imuflow PIP step (same frames, {slower})"])
    busy = {k: v for k, v in load.items() if v["others"] > BUSY_SHARE or v["steal"] > BUSY_SHARE}
    if busy:
        print("warning: other processes or the hypervisor took the CPU during: " + "; ".join(
            f"{k} ({v['others']:.0%} others, {v['steal']:.0%} stolen)" for k, v in busy.items())
            + ". Rerun on a quiet machine.", file=sys.stderr)

    report = {
        "format": "imuflow-authors-stack/1",
        "started_utc": started.isoformat(timespec="seconds"),
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(),
                    "numpy": np.__version__, "onnx": onnx.__version__, "onnxruntime": ort.__version__,
                    "quadprog": importlib.metadata.version("quadprog")},
        "frames": {"recording": meta["frames"], "networks": int(len(x)), "qp": len(records), "paired": int(len(ni)),
                   "start_pose": nets_meta["start_pose"], "imuflow_pip_fallbacks": phys["fallbacks"]},
        "weights": {"file": "models/pip.safetensors", "nets": specs},
        "checks": {"networks": net_check, "qp": qp_check},
        "results": results,
        "ratios_authors_over_imuflow": ratios,
        "ratios_against_imuflow_pass": slower,
        "cpu_share_taken_by_others_per_step": load,
        "imuflow_bench": bench,
        "commands": commands,
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "authors-stack.json").write_text(json.dumps(report, indent=1))

    rows = []
    for section, entries in results.items():
        for label, s in entries.items():
            rows.append((f"{section}: {label}", s))
    for key, label in [("kinematics", "imuflow `bench kinematics`, pip nets (synthetic sway)"),
                       ("physics", "imuflow `bench physics`, pip step (synthetic march)"),
                       ("graph", "imuflow `bench graph --no-offline`, capture → record.motion")]:
        b = bench.get(key, {}).get("parsed")
        if b is None:
            continue
        s = b.get("nets", b.get("step", b)) if key != "graph" else b
        rows.append((label, s))
        if key == "physics" and "qp" in b:
            rows.append(("imuflow `bench physics`, QP alone (synthetic march)", b["qp"]))
    lines = [
        f"# imuflow's PIP against the authors' stack ({started:%Y-%m-%d %H:%M} UTC, {cpu_model()}, "
        f"{os.cpu_count()} cores)", "",
        f"Frames: the bundled sample through configs/pip.toml: {len(x)} network frames, {len(records)} QP frames, "
        f"{len(ni)} paired.", "",
        summarize(rows), "",
        "Ratios, authors' stack (networks + QP set-up + quadprog) / imuflow (networks + PIP step, the slower "
        f"of its two passes: {slower}), per frame:", "",
        "| authors' networks | p50 | p99 |", "|---|---|---|",
    ]
    for k, v in ratios.items():
        lines.append(f"| {k} | {v['p50']:.1f}× | {v['p99']:.1f}× |")
    nc, qc = net_check, qp_check
    qe = qc["relative_error"]
    lines += [
        "", "Checks:",
        f"- networks vs imuflow (max abs over all frames): positions {nc['vs_imuflow_streamer']['joint_position_m']:.2e} m, "
        f"velocities {nc['vs_imuflow_streamer']['joint_velocity_mps']:.2e} m/s, contacts "
        f"{nc['vs_imuflow_streamer']['foot_contact_prob']:.2e}, pose {nc['vs_imuflow_streamer']['pose_deg']:.2e}°; "
        f"vs the graph's recording: positions {nc['vs_graph_recording']['joint_position_m']:.2e} m; inputs "
        f"{nc['normalization_max_abs']:.2e}; within tolerance: {nc['within_tolerance']}",
        f"- QP vs imuflow (largest over all frames): q̈ {qe['qdd']['max']:.2e} relative (p99 {qe['qdd']['p99']:.2e}), "
        f"objective {qe['objective']['max']:.2e} relative, forces and torques {qe['forces_torques']['max']:.2e} "
        f"relative (p99 {qe['forces_torques']['p99']:.2e}), imuflow's constraint violation "
        f"{qe['infeasibility']['max']:.1e}; quadprog failed {qc['quadprog_failed']}, PIP re-solves "
        f"{qc['pip_fallback_resolves']}; {qc['variables_min_max'][0]}-{qc['variables_min_max'][1]} variables; "
        f"within tolerance: {qc['within_tolerance']}",
    ]
    lines.append("- CPU time other processes / the hypervisor took, per step: " + ", ".join(
        f"{k.split(' ', 1)[0]} {v['others']:.0%}/{v['steal']:.0%}" for k, v in load.items()))
    text = "\n".join(lines) + "\n"
    (out_dir / "authors-stack.md").write_text(text)
    print(text)
    print(f"wrote {(out_dir / 'authors-stack.json').relative_to(REPO) if out_dir.is_relative_to(REPO) else out_dir}")
    if not (nc["within_tolerance"] and qc["within_tolerance"]):
        print("warning: a check is outside its tolerance (see above): the stacks may not compute the same thing",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
