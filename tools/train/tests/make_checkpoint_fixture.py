#!/usr/bin/env python3
"""Writes small PyTorch-format checkpoints with the authors' key names (reference file §2) and the
streaming outputs of every net computed independently, in plain Python (no numpy, no torch).

The checkpoint is written in torch.save's zip + pickle layout by hand: `archive/data.pkl` holds an
OrderedDict of tensors rebuilt by `torch._utils._rebuild_tensor_v2` from persistent storages
`archive/data/<key>` (little-endian float32), plus `archive/version`. A stand-in `torch` module makes
pickle write those global names without torch installed.

Usage: make_checkpoint_fixture.py OUT_DIR   (writes {pip,globalpose}-small.pt and *-expected.json)
"""
import collections
import json
import math
import pickle
import random
import struct
import sys
import types
import zipfile

# --- stand-in torch names for pickle ---------------------------------------------------------------
torch = types.ModuleType("torch")
torch_utils = types.ModuleType("torch._utils")


def _rebuild_tensor_v2(*args):  # never called: only its name is pickled
    raise RuntimeError("stand-in")


_rebuild_tensor_v2.__module__ = "torch._utils"
_rebuild_tensor_v2.__qualname__ = "_rebuild_tensor_v2"
torch_utils._rebuild_tensor_v2 = _rebuild_tensor_v2


class FloatStorage:
    pass


FloatStorage.__module__ = "torch"
torch.FloatStorage = FloatStorage
torch._utils = torch_utils
sys.modules["torch"] = torch
sys.modules["torch._utils"] = torch_utils


class StorageRef:
    def __init__(self, key, numel):
        self.key, self.numel = key, numel


class TensorRef:
    def __init__(self, key, shape):
        self.key, self.shape = key, shape

    def __reduce__(self):
        numel = 1
        for d in self.shape:
            numel *= d
        stride, acc = [], 1
        for d in reversed(self.shape):
            stride.insert(0, acc)
            acc *= d
        return (_rebuild_tensor_v2, (StorageRef(self.key, numel), 0, tuple(self.shape),
                                     tuple(stride), False, collections.OrderedDict()))


class TorchPickler(pickle.Pickler):
    def persistent_id(self, obj):
        if isinstance(obj, StorageRef):
            return ("storage", FloatStorage, obj.key, "cpu", obj.numel)
        return None


def write_checkpoint(path, tensors):
    """tensors: ordered list of (name, shape, flat list of floats)."""
    import io
    state = collections.OrderedDict()
    blobs = {}
    for i, (name, shape, values) in enumerate(tensors):
        key = str(i)
        state[name] = TensorRef(key, shape)
        blobs[key] = struct.pack("<%df" % len(values), *values)
    buf = io.BytesIO()
    TorchPickler(buf, protocol=2).dump(state)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        z.writestr("archive/data.pkl", buf.getvalue())
        for key, blob in blobs.items():
            z.writestr("archive/data/" + key, blob)
        z.writestr("archive/version", "3\n")
        z.writestr("archive/byteorder", "little")


# --- the math, independently ------------------------------------------------------------------------
def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def matvec(w, rows, cols, x):
    return [sum(w[r * cols + c] * x[c] for c in range(cols)) for r in range(rows)]


def sig(v):
    return 1.0 / (1.0 + math.exp(-v))


class Net:
    """articulate RNN / RNNWithInit (reference §2.0) with PyTorch's LSTM equations."""

    def __init__(self, prefix, n_in, n_out, hidden, layers, input_linear, init_in, rng):
        self.p, self.H, self.L = prefix, hidden, layers
        self.n_in, self.n_out, self.lin, self.init_in = n_in, n_out, input_linear, init_in
        self.params = collections.OrderedDict()

        def add(name, shape, bound):
            n = 1
            for d in shape:
                n *= d
            self.params[prefix + "." + name] = (shape, [f32(rng.uniform(-bound, bound)) for _ in range(n)])

        h = hidden
        if input_linear:
            add("linear1.weight", [h, n_in], 1 / math.sqrt(n_in))
            add("linear1.bias", [h], 1 / math.sqrt(n_in))
        lstm_in = h if input_linear else n_in
        for k in range(layers):
            inp = lstm_in if k == 0 else h
            add("rnn.weight_ih_l%d" % k, [4 * h, inp], 1 / math.sqrt(h))
            add("rnn.weight_hh_l%d" % k, [4 * h, h], 1 / math.sqrt(h))
            add("rnn.bias_ih_l%d" % k, [4 * h], 1 / math.sqrt(h))
            add("rnn.bias_hh_l%d" % k, [4 * h], 1 / math.sqrt(h))
        add("linear2.weight", [n_out, h], 1 / math.sqrt(h))
        add("linear2.bias", [n_out], 1 / math.sqrt(h))
        if init_in:
            dims = [(h, init_in), (h * layers, h), (2 * layers * h, h * layers)]
            for i, (o, n) in zip([0, 2, 4], dims):
                add("init_net.%d.weight" % i, [o, n], 1 / math.sqrt(n))
                add("init_net.%d.bias" % i, [o], 1 / math.sqrt(n))

    def w(self, name):
        return self.params[self.p + "." + name][1]

    def linear(self, name, x, rows, cols):
        y = matvec(self.w(name + ".weight"), rows, cols, x)
        return [a + b for a, b in zip(y, self.w(name + ".bias"))]

    def initial_state(self, init):
        H, L = self.H, self.L
        if init is None:
            return [[0.0] * H for _ in range(L)], [[0.0] * H for _ in range(L)]
        a = [max(0.0, v) for v in self.linear("init_net.0", init, H, self.init_in)]
        b = [max(0.0, v) for v in self.linear("init_net.2", a, H * L, H)]
        v = self.linear("init_net.4", b, 2 * L * H, H * L)
        hs = [v[k * H:(k + 1) * H] for k in range(L)]
        cs = [v[(L + k) * H:(L + k + 1) * H] for k in range(L)]
        return hs, cs

    def step(self, x, state):
        H = self.H
        hs, cs = state
        if self.lin:
            x = [max(0.0, v) for v in self.linear("linear1", x, H, self.n_in)]
        for k in range(self.L):
            n = len(x)
            gi = matvec(self.w("rnn.weight_ih_l%d" % k), 4 * H, n, x)
            gh = matvec(self.w("rnn.weight_hh_l%d" % k), 4 * H, H, hs[k])
            g = [a + b + c + d for a, b, c, d in
                 zip(gi, gh, self.w("rnn.bias_ih_l%d" % k), self.w("rnn.bias_hh_l%d" % k))]
            i = [sig(v) for v in g[0:H]]
            f = [sig(v) for v in g[H:2 * H]]
            gg = [math.tanh(v) for v in g[2 * H:3 * H]]
            o = [sig(v) for v in g[3 * H:4 * H]]
            cs[k] = [fv * cv + iv * gv for fv, cv, iv, gv in zip(f, cs[k], i, gg)]
            hs[k] = [ov * math.tanh(cv) for ov, cv in zip(o, cs[k])]
            x = hs[k]
        return self.linear("linear2", x, self.n_out, H)


# (name, input, output, input_linear, init input) per method: the data flow fixes these (reference §2).
LINEUP = {
    "pip": [("rnn1", 72, 15, True, 15), ("rnn2", 87, 69, True, None), ("rnn3", 141, 90, True, None),
            ("rnn4", 141, 72, True, 72), ("rnn5", 141, 2, True, None)],
    "globalpose": [("plnet", 84, 18, False, 18), ("iknet.net1", 63, 72, False, None),
                   ("iknet.net2", 117, 90, False, None), ("vrnet", 243, 9, False, 9)],
}
SIZES = {"pip": (12, 2), "globalpose": (8, 3)}  # small hidden sizes keep the fixture small
FRAMES = 5


def main(out_dir):
    for method, nets in LINEUP.items():
        rng = random.Random(1234 if method == "pip" else 5678)
        hidden, layers = SIZES[method]
        tensors, expected = [], {}
        for name, n_in, n_out, lin, init_in in nets:
            h = max(4, hidden // 4) if name == "rnn5" else hidden
            net = Net(name, n_in, n_out, h, layers, lin, init_in, rng)
            for key, (shape, values) in net.params.items():
                tensors.append((key, shape, values))
            xs = [[f32(rng.gauss(0, 1)) for _ in range(n_in)] for _ in range(FRAMES)]
            init = [f32(rng.gauss(0, 1)) for _ in range(init_in)] if init_in else None
            state = net.initial_state(init)
            ys = [net.step(x, state) for x in xs]
            expected[name] = {"inputs": xs, "init": init, "outputs": ys}
        write_checkpoint("%s/%s-small.pt" % (out_dir, method), tensors)
        with open("%s/%s-small-expected.json" % (out_dir, method), "w") as f:
            json.dump({"method": method, "nets": expected}, f)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
