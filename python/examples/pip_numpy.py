"""PIP's kinematics networks in numpy: a Python kinematics stage running an imuflow weight file.

What a researcher plugging in their own network replaces: `load_safetensors` reads the weights,
`Rnn` is the LSTM block every PIP network is made of (PyTorch's parameter names and gate order),
and `PipNumpy.step` turns one calibrated IMU frame into one KinematicsFrame. It follows the Rust
kinematics stage (stages/kinematics/src/infer.rs) with `sensor_bones = "network"` and
`limb_joints = "free"`, so the two can be A/B-compared on identical input:

    [stages.pynet]
    exec = "python3"
    args = ["python/examples/pip_numpy.py"]
    inputs = { imu = "calib.body_imu" }
    outputs = { kinematics = "KinematicsFrame" }
    params = { weights = "models/pip.safetensors" }
"""

import json
import struct

import numpy as np

import imuflow

# SMPL's kinematic tree and PIP's joint sets (reference file §1).
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
LEAF_JOINTS = [7, 8, 12, 20, 21]
FULL_JOINTS = list(range(1, 24))
REDUCED_JOINTS = [1, 2, 3, 4, 5, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19]
ROOT_IMU = 5  # IMU order: left/right forearm, left/right lower leg, head, pelvis
PIP_VELOCITY_SCALE = 3.0  # PIP (reference §2.2): v_j = 3·R_root·out_j
G = 9.81
# rnn1's learned initial state starts from the leaf joints' positions relative to the root in the
# T-pose (m, root frame) of the body the weights were trained on: imuflow's body model at 1.75 m
# (a Rust test, stages/kinematics, checks these against its forward kinematics).
TPOSE_LEAF_POSITIONS_M = [
    [0.09057, -0.88195, 0.0], [-0.09057, -0.88195, 0.0], [0.0, 0.5479, 0.0],
    [0.75816, 0.50394, 0.0], [-0.75816, 0.50394, 0.0],
]


def load_safetensors(path):
    """name → float32 array, for a safetensors file of F32 tensors (imuflow's weight files)."""
    with open(path, "rb") as f:
        (length,) = struct.unpack("<Q", f.read(8))
        header = json.loads(f.read(length))
        data = f.read()
    header.pop("__metadata__", None)
    tensors = {}
    for name, entry in header.items():
        if entry["dtype"] != "F32":
            raise ValueError(f"{path}: tensor {name} is {entry['dtype']}, not F32")
        begin, end = entry["data_offsets"]
        tensors[name] = np.frombuffer(data[begin:end], "<f4").reshape(entry["shape"])
    return tensors


def sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


class Rnn:
    """[Linear + ReLU] → LSTM (L layers) → Linear, with an optional learned initial state
    (init_net: Linear, ReLU, Linear, ReLU, Linear → [h of each layer, c of each layer])."""

    def __init__(self, w, name):
        def get(key):
            return w.get(f"{name}.{key}")

        self.linear1 = (get("linear1.weight"), get("linear1.bias")) if get("linear1.weight") is not None else None
        self.layers = []
        while get(f"rnn.weight_ih_l{len(self.layers)}") is not None:
            k = len(self.layers)
            self.layers.append((get(f"rnn.weight_ih_l{k}").T.copy(), get(f"rnn.weight_hh_l{k}").T.copy(),
                                get(f"rnn.bias_ih_l{k}") + get(f"rnn.bias_hh_l{k}")))
        if not self.layers:
            raise ValueError(f"the weights have no network '{name}'")
        self.hidden = self.layers[0][1].shape[0]
        self.linear2 = (get("linear2.weight"), get("linear2.bias"))
        self.init_net = ([(get(f"init_net.{i}.weight"), get(f"init_net.{i}.bias")) for i in (0, 2, 4)]
                         if get("init_net.0.weight") is not None else None)

    def initial_state(self, init=None):
        """(2L, H): h of each layer, then c of each layer."""
        if self.init_net is None or init is None:
            return np.zeros((2 * len(self.layers), self.hidden), np.float32)
        x = np.asarray(init, np.float32)
        for i, (weight, bias) in enumerate(self.init_net):
            x = weight @ x + bias
            if i < 2:
                x = np.maximum(x, 0)
        return x.reshape(2 * len(self.layers), self.hidden)

    def step(self, x, state):
        """One frame; updates `state` in place."""
        if self.linear1 is not None:
            x = np.maximum(self.linear1[0] @ x + self.linear1[1], 0)
        n, h = len(self.layers), self.hidden
        for k, (w_ih_t, w_hh_t, bias) in enumerate(self.layers):
            gates = x @ w_ih_t + state[k] @ w_hh_t + bias  # PyTorch's order: i, f, g, o
            i, f, o = sigmoid(gates[:h]), sigmoid(gates[h:2 * h]), sigmoid(gates[3 * h:])
            c = f * state[n + k] + i * np.tanh(gates[2 * h:3 * h])
            state[k], state[n + k] = o * np.tanh(c), c
            x = state[k]
        return self.linear2[0] @ x + self.linear2[1]


def matrix_from_quaternion(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quaternion_from_matrix(m):
    """[w, x, y, z] of a rotation matrix (Shepperd's method: the largest component first)."""
    t = np.trace(m)
    if t > max(m[0, 0], m[1, 1], m[2, 2]):
        s = 2 * np.sqrt(1 + t)
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i], q[1 + j], q[1 + k] = s / 4, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    return np.array(q) / np.linalg.norm(q)


def rotation_from_r6d(v):
    """The 6D rotation representation (the first two columns) to a matrix; identity when the
    network's output is degenerate."""
    a, b = v[:3].astype(np.float64), v[3:].astype(np.float64)
    c0 = a / np.linalg.norm(a)
    c1 = b - c0 * (c0 @ b)
    c1 /= np.linalg.norm(c1)
    m = np.stack([c0, c1, np.cross(c0, c1)], axis=1)
    return m if np.all(np.isfinite(m)) and np.linalg.det(m) > 0.5 else np.eye(3)


class PipNumpy:
    """PIP's five networks with their streaming state (reference §2.2)."""

    def __init__(self, weights_path):
        w = load_safetensors(weights_path)
        self.nets = [Rnn(w, f"rnn{k}") for k in range(1, 6)]
        self.states = None

    def reset(self):
        self.states = None

    def step(self, orientation, acceleration, angular_velocity):
        """One frame of calibrated IMU data (R_MB (6, 3, 3), free acceleration and angular
        velocity (6, 3) in M) → the KinematicsFrame's fields."""
        if self.states is None:
            inits = [np.ravel(TPOSE_LEAF_POSITIONS_M), None, None, np.zeros(72), None]
            self.states = [net.initial_state(init) for net, init in zip(self.nets, inits)]
        root = orientation[ROOT_IMU]
        # PIP's inputs (TransPose's layout, without its scaling): root-relative accelerations and
        # orientations, the root's own in world axes.
        acc = (acceleration - np.where(np.arange(6)[:, None] == ROOT_IMU, 0, acceleration[ROOT_IMU])) @ root
        ori = np.einsum("ji,njk->nik", root, orientation)
        ori[ROOT_IMU] = root
        x = np.concatenate([acc.ravel(), ori.reshape(-1)]).astype(np.float32)
        run = [lambda inp, k=k: self.nets[k].step(inp, self.states[k]) for k in range(5)]
        leaf = run[0](x)
        full = run[1](np.concatenate([leaf, x]))
        full_x = np.concatenate([full, x])
        r6d, velocity, contact = run[2](full_x), run[3](full_x), run[4](full_x)

        global_in_root = [np.eye(3)] * 24
        for k, j in enumerate(REDUCED_JOINTS):
            global_in_root[j] = rotation_from_r6d(r6d[6 * k:6 * k + 6])
        local = [np.eye(3)] * 24
        for j in REDUCED_JOINTS:
            local[j] = global_in_root[PARENTS[j]].T @ global_in_root[j]
        local[0] = root
        positions = np.zeros((24, 3))
        positions[FULL_JOINTS] = full.reshape(23, 3).astype(np.float64) @ root.T
        velocities = velocity.reshape(24, 3).astype(np.float64) @ root.T * PIP_VELOCITY_SCALE
        feet = sigmoid(contact[:2].astype(np.float64))
        return {
            "local_pose_wxyz": np.array([quaternion_from_matrix(m) for m in local]),
            "joint_position_m": positions,
            "joint_velocity_mps": velocities,
            "foot_contact_prob": feet,
            "stationary_prob": [0.0, feet[0], feet[1], 0.0, 0.0],
            "root_velocity_mps": velocities[0],
            "gravity_in_root_mps2": root.T @ np.array([0.0, -G, 0.0]),
        }


START = {  # what goes out while calibrating: the T-pose, standing still
    "local_pose_wxyz": np.tile([1.0, 0.0, 0.0, 0.0], (24, 1)),
    "foot_contact_prob": [1.0, 1.0],
    "stationary_prob": [1.0] * 5,
    "gravity_in_root_mps2": [0.0, -G, 0.0],
}


def main():
    stage = imuflow.Stage.from_env()
    stage.input("imu", "BodyImuFrame")
    out = stage.output("kinematics", "KinematicsFrame")
    net = PipNumpy(stage.params.get("weights", "models/pip.safetensors"))
    if not stage.ready():
        stage.finish()
        return
    held = {"R": np.zeros((6, 3, 3)), "a": np.zeros((6, 3)), "w": np.zeros((6, 3)), "seen": 0}
    for step in stage:
        imu = step["imu"]
        mask = int(imu["valid_mask"])
        for i in range(6):  # each sensor's last valid sample
            q, a, w = imu["bone_orientation_wxyz"][i], imu["free_acceleration_mps2"][i], imu["angular_velocity_radps"][i]
            if mask >> i & 1 and np.all(np.isfinite([*q, *a, *w])) and 0.5 < np.linalg.norm(q) < 1.5:
                held["R"][i] = matrix_from_quaternion(q / np.linalg.norm(q))
                held["a"][i], held["w"][i] = a, w
                held["seen"] |= 1 << i
        flags = 0
        if step.flags & imuflow.CALIBRATING or held["seen"] != 0b111111:
            net.reset()
            fields, flags = START, imuflow.INVALID
        else:
            fields = net.step(held["R"], held["a"], held["w"])
            flags = imuflow.INVALID if mask != 0b111111 else 0
        out.publish(step, flags=flags, **fields)
    stage.finish()


if __name__ == "__main__":
    main()
