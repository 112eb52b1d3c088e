"""The field's real-IMU benchmarks as imuflow recordings: DIP-IMU and TotalCapture.

    from imuflow.datasets import convert_dip, convert_totalcapture
    convert_dip("DIP_IMU/s_09/01.pkl", "out/dip/s_09/01.mcap")
    convert_totalcapture("TotalCapture_DIP/s1_acting1.pkl", "out/tc/s1_acting1.mcap",
                         translation_txt="TotalCapture/official")   # or the .txt itself

or `python -m imuflow.convert dip|totalcapture INPUT OUTPUT` (imuflow/convert.py). Each file becomes
one recording as the recorder stage writes it (imuflow/writer.py): the six IMUs on `source.imu`
(ImuFrame) and the SMPL truth on `source.truth` (MotionFrame), seq = frame index, capture time
seq · 10⁹ / 60 ns, which `imuflow compare --input` and the imu-source stage's `replay` mode read.

The input formats are those the papers' public code reads (facts from the project's reference
notes on the original implementations, §1 "IMU order" and §3 "Test-set preprocessing"):

- DIP-IMU (Huang et al. 2018), one pickle per sequence (`s_01/01.pkl`, written by Python 2: read
  with latin1): `imu_ori` (N, 17, 3, 3), `imu_acc` (N, 17, 3), `gt` (N, 72) SMPL axis-angle, 60 Hz,
  NaN where a sensor dropped out. The six sensors are [7, 8, 11, 12, 0, 2] of the 17 (left and
  right elbow, left and right knee, head, pelvis).
- TotalCapture as DIP preprocessed it (one pickle per sequence, `s1_acting1.pkl`): `ori`
  (N, 6, 3, 3), `acc` (N, 6, 3) and, where DIP computed poses, `gt` (N, 72); the six are reordered
  by [2, 3, 0, 1, 4, 5]. The translation is not in them: it comes from the official
  `gt_skel_gbl_pos.txt` (inches × 0.0254, x and z negated, relative to frame 0).

The frames. Both datasets ship calibrated orientations: each matrix is already the orientation of
the sensor's bone in the SMPL model frame M (x left, y up, z forward), so the sensor frame S is the
bone frame and the inertial frame I is M; the graph's calibration stage must use
`method = "none"` (R_MB = R_IS). Both ship accelerations in M with gravity removed (DIP's
read_TC_data.py subtracts it from TotalCapture's; for DIP-IMU's, PNP's preprocessing adds it
back, reference §3). An ImuFrame carries
what an accelerometer measures, the specific force in S, so each becomes f_S = Rᵀ(a − g) with
g = (0, −9.81, 0): the gravity the calibration stage adds back (`a_M = R_IS·f_S + g_M`,
imuflow_body's GRAVITY_IN_MODEL_MPS2), so the graph sees the dataset's accelerations exactly.
(GlobalPose's and PNP's preprocessing uses 9.798 here and 9.8 at run time; 9.81 keeps the round
trip exact instead.)

Neither dataset has gyroscope readings in these files; the angular rate is synthesized from
consecutive orientations as PNP's and GlobalPose's preprocessing does (ω_S = log(R_tᵀ·R_{t+1})·60),
with the backward difference for the last frame and for a frame whose successor is missing.

Missing samples are not interpolated: a sensor whose orientation or acceleration is NaN (or whose
matrix is no rotation) in a frame gets its `valid_mask` bit cleared, identity and zeros in its
fields, and the frame is flagged INVALID; the graph's stages then treat it as a dropout (the
kinematics holds the sensor's last sample, scores skip INVALID frames). The papers' evaluations
instead fill such samples (nearest neighbour: TransPose/PIP; Slerp: PNP/GlobalPose) and TransPose/
PIP also trim 6 frames at each end of a DIP-IMU sequence: neither is done here.

The truth: per frame, the 24 SMPL joints' local rotations (root included, relative to M) from the
axis-angle `gt`, and the root position: zero for DIP-IMU (it has no translation), the official
TotalCapture translation when given (else zero). The MotionFrame's other fields are zero. A frame
whose pose is NaN is flagged INVALID with identity rotations.
"""

import os
import pickle
from dataclasses import dataclass, field

import numpy as np

from .writer import Stream, empty_frames, packaged_layout, write_recording

RATE_HZ = 60  # DIP-IMU and TotalCapture (the preprocessed files) are 60 Hz
# The model frame's gravity as the calibration stage adds it back (libs/body GRAVITY_IN_MODEL_MPS2).
GRAVITY_IN_MODEL_MPS2 = np.array([0.0, -9.81, 0.0])
# The six of DIP-IMU's 17 sensors, in imuflow's IMU order (reference §1).
DIP_SENSORS = (7, 8, 11, 12, 0, 2)
# DIP's TotalCapture files hold the six in another order (reference §1).
TOTALCAPTURE_ORDER = (2, 3, 0, 1, 4, 5)
INCH_M = 0.0254
TRANSLATION_FILE = "gt_skel_gbl_pos.txt"
# The official skeleton's joint whose path is the translation: 'Hips' (the pelvis, where SMPL's
# root is; PNP/GlobalPose) or 'Spine' (TransPose/PIP).
DEFAULT_TRANSLATION_JOINT = "Hips"
SENSOR_NAMES = ("left_forearm", "right_forearm", "left_lower_leg", "right_lower_leg", "head",
                "pelvis")
IMU_TOPIC, TRUTH_TOPIC = "source.imu", "source.truth"
INVALID = 1 << 1  # graph/src/frames.rs flags::INVALID
ALL_VALID = (1 << len(SENSOR_NAMES)) - 1
# A stored orientation further than this from orthonormal (largest entry of RᵀR − I) is no
# rotation: float32 storage is good to 1e-6, so anything this far off is damage, not rounding.
ROTATION_TOLERANCE = 0.02


class DatasetError(ValueError):
    """A dataset file that cannot be converted; the message names the file (and key or line)."""


@dataclass
class Conversion:
    """What one conversion wrote."""
    source: str
    output: str
    frames: int
    invalid_frames: int  # frames flagged INVALID (a sensor missing)
    missing_per_sensor: list  # per IMU, frames without a usable sample
    truth_frames: int  # 0: no truth channel
    truth_invalid_frames: int
    root_position: str  # where the truth's root position comes from
    notes: list = field(default_factory=list)

    def summary(self):
        parts = [f"{self.frames} frames ({self.frames / RATE_HZ:.1f} s)"]
        if self.invalid_frames:
            missing = ", ".join(f"{name} {count}" for name, count
                                in zip(SENSOR_NAMES, self.missing_per_sensor) if count)
            parts.append(f"{self.invalid_frames} flagged INVALID "
                         f"(frames without a sample: {missing})")
        if self.truth_frames:
            truth = f"truth {self.truth_frames} frames, root position {self.root_position}"
            if self.truth_invalid_frames:
                truth += f", {self.truth_invalid_frames} INVALID (NaN pose)"
            parts.append(truth)
        else:
            parts.append("no truth")
        return "; ".join(parts + self.notes)


# ---------------------------------------------------------------------------------------------
# Converters


def convert_dip(pkl_path, out_mcap):
    """One DIP-IMU sequence (`s_01/01.pkl`) → recording `out_mcap`; returns a `Conversion`."""
    pkl_path = str(pkl_path)
    data = load_pickle(pkl_path)
    ori = _array(data, "imu_ori", pkl_path, (17, 3, 3))[:, list(DIP_SENSORS)]
    acc = _array(data, "imu_acc", pkl_path, (17, 3))[:, list(DIP_SENSORS)]
    pose = _pose(data, "gt", pkl_path)
    n, notes = _common_length(pkl_path, {"imu_ori": ori, "imu_acc": acc, "gt": pose})
    return _convert("DIP-IMU", pkl_path, out_mcap, ori[:n], acc[:n], pose[:n], None,
                    "zero (DIP-IMU has no translation)", notes)


def convert_totalcapture(pkl_path, out_mcap, translation_txt=None,
                         translation_joint=DEFAULT_TRANSLATION_JOINT):
    """One TotalCapture sequence as DIP preprocessed it (`s1_acting1.pkl`) → recording `out_mcap`.

    `translation_txt`: the official `gt_skel_gbl_pos.txt` of the sequence, or the folder of the
    official ground truth (`S1/acting1/gt_skel_gbl_pos.txt`, ...) to find it in by the pickle's
    name; None: the truth's root stays at zero. Returns a `Conversion`."""
    pkl_path = str(pkl_path)
    data = load_pickle(pkl_path)
    order = list(TOTALCAPTURE_ORDER)
    ori = _array(data, "ori", pkl_path, (6, 3, 3))[:, order]
    acc = _array(data, "acc", pkl_path, (6, 3))[:, order]
    pose = _pose(data, "gt", pkl_path) if "gt" in data else None
    series = {"ori": ori, "acc": acc}
    notes, root, origin = [], None, "zero (no translation file given)"
    if pose is not None:
        series["gt"] = pose
    else:
        notes.append("the file has no 'gt' pose: no truth channel")
    if translation_txt is not None:
        txt = find_translation(translation_txt, pkl_path)
        if pose is not None:
            root = read_translation(txt, translation_joint)
            series[TRANSLATION_FILE] = root
            origin = f"from {TRANSLATION_FILE} ('{translation_joint}', relative to frame 0)"
        else:
            notes.append(f"{TRANSLATION_FILE} not used (no pose to go with it)")
    n, length_notes = _common_length(pkl_path, series)
    pose = None if pose is None else pose[:n]
    root = None if root is None else root[:n]
    return _convert("TotalCapture", pkl_path, out_mcap, ori[:n], acc[:n], pose, root, origin,
                    notes + length_notes)


def _convert(source, pkl_path, out_mcap, ori, acc, pose, root, origin, notes):
    imu_layout = packaged_layout("ImuFrame")
    imu, missing = imu_frames(imu_layout, ori, acc)
    streams = [Stream(IMU_TOPIC, "imu", imu_layout, imu)]
    truth = None
    if pose is not None:
        motion_layout = packaged_layout("MotionFrame")
        truth = truth_frames(motion_layout, pose, root)
        streams.append(Stream(TRUTH_TOPIC, "truth", motion_layout, truth))
    metadata = {
        "rate_hz": str(RATE_HZ),
        "source": source,
        "source_file": os.path.basename(pkl_path),
        "calibration": "none (orientations are bone orientations in M)",
        "specific_force": "f_S = R^T (a - g), g = (0, -9.81, 0) m/s^2",
        "angular_rate": "from consecutive orientations: log(R_t^T R_t+1) * 60",
        "root_position": origin,
        "missing_samples": "not interpolated: valid_mask bit cleared, frame flagged INVALID",
    }
    write_recording(out_mcap, streams, metadata)
    return Conversion(source=str(pkl_path), output=str(out_mcap), frames=len(imu),
                      invalid_frames=_flagged(imu), missing_per_sensor=missing,
                      truth_frames=0 if truth is None else len(truth),
                      truth_invalid_frames=0 if truth is None else _flagged(truth),
                      root_position=origin, notes=notes)


def _flagged(frames):
    return int(np.count_nonzero(frames["header.flags"] & INVALID))


# ---------------------------------------------------------------------------------------------
# Frames


def imu_frames(layout, ori, acc, rate_hz=RATE_HZ):
    """ImuFrames from bone orientations in M (N, 6, 3, 3) and free accelerations in M (N, 6, 3);
    returns (frames, frames without a usable sample per sensor)."""
    n = len(ori)
    usable = np.isfinite(ori).all(axis=(-1, -2)) & np.isfinite(acc).all(axis=-1)
    rotation = np.where(usable[..., None, None], ori, np.eye(3))
    usable &= is_rotation(rotation)
    q = np.where(usable[..., None], quat_from_matrix(rotation), [1.0, 0.0, 0.0, 0.0])
    # Through the quaternion's own matrix: exactly what the calibration stage will rotate back by.
    free = np.where(usable[..., None], acc, 0.0) - GRAVITY_IN_MODEL_MPS2
    force = np.einsum("...ji,...j->...i", matrix_from_quat(q), free)
    force[~usable] = 0.0
    frames = empty_frames(layout, n)
    _header(frames)
    # The six fill the frame's first six slots (the six-site set's); the other sites' stay empty.
    six = q.shape[1]
    frames["orientation_wxyz"][:, :six] = q
    frames["specific_force_mps2"][:, :six] = force
    frames["angular_rate_radps"][:, :six] = angular_rate(q, usable, rate_hz)
    mask = (usable.astype(np.uint32) << np.arange(usable.shape[1], dtype=np.uint32)).sum(axis=1)
    frames["valid_mask"] = mask
    frames["header.flags"] = np.where(mask == ALL_VALID, 0, INVALID)
    return frames, [int(c) for c in (~usable).sum(axis=0)]


def truth_frames(layout, pose_axis_angle, root_position_m=None):
    """MotionFrames from SMPL axis-angle poses (N, 24, 3) (local rotations, the root's relative
    to M) and root positions in M (N, 3; None: zero). Other fields zero."""
    n = len(pose_axis_angle)
    root = np.zeros((n, 3)) if root_position_m is None else root_position_m
    usable = np.isfinite(pose_axis_angle).all(axis=(1, 2)) & np.isfinite(root).all(axis=1)
    frames = empty_frames(layout, n)
    _header(frames)
    frames["local_pose_wxyz"] = quat_from_axis_angle(np.where(usable[:, None, None],
                                                              pose_axis_angle, 0.0))
    frames["root_position_m"] = np.where(usable[:, None], root, 0.0)
    frames["header.flags"] = np.where(usable, 0, INVALID)
    return frames


def _header(frames):
    n = len(frames)
    frames["header.seq"] = np.arange(n, dtype=np.uint64)
    # As the synthesizing source stamps offline frames: seq · 10⁹ / rate, truncated to ns.
    frames["header.capture_ns"] = (np.arange(n, dtype=np.float64) * 1e9 / RATE_HZ).astype(np.uint64)


def angular_rate(q, usable, rate_hz=RATE_HZ):
    """Angular rate in the sensor frame (N, 6, 3) from orientations (N, 6, 4): log(R_tᵀ·R_{t+1})
    times the rate, the backward difference where frame t + 1 has no sample (the last frame too),
    zero where neither neighbour has one."""
    rate = np.zeros(q.shape[:-1] + (3,))
    if len(q) < 2:
        return rate
    # step[t]: the rotation from frame t to t + 1, usable where both frames have a sample.
    step = rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:])) * rate_hz
    pair = usable[:-1] & usable[1:]
    forward = np.zeros(usable.shape, bool)
    forward[:-1] = pair
    backward = np.zeros(usable.shape, bool)
    backward[1:] = pair & ~forward[1:]
    rate[forward] = step[pair]
    rate[backward] = step[backward[1:]]
    return rate


# ---------------------------------------------------------------------------------------------
# Rotations (quaternions w, x, y, z; matrices act on column vectors)


def quat_from_axis_angle(r):
    """(…, 3) axis-angle vectors → (…, 4) unit quaternions."""
    r = np.asarray(r, dtype=np.float64)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = angle / 2
    # sin(θ/2)/θ, with its series near 0 (1/2 − θ²/48) so the identity stays exact.
    small = angle < 1e-8
    scale = np.where(small, 0.5 - angle**2 / 48, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half), r * scale], axis=-1)


def quat_from_matrix(m):
    """(…, 3, 3) rotation matrices → (…, 4) unit quaternions with w ≥ 0 (Shepperd's method: the
    largest of w, x, y, z is computed from the diagonal, the others from the off-diagonal)."""
    m = np.asarray(m, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    d21, d02, d10 = (m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                     m[..., 1, 0] - m[..., 0, 1])
    s01, s02, s12 = (m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0],
                     m[..., 1, 2] + m[..., 2, 1])
    candidates = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22,
                           1 - m00 - m11 + m22], axis=-1)
    pick = np.argmax(candidates, axis=-1)
    largest = np.take_along_axis(candidates, pick[..., None], -1)[..., 0]
    big = np.sqrt(np.maximum(largest, 1e-300)) / 2
    k = 1 / (4 * big)
    options = np.stack([
        np.stack([big, d21 * k, d02 * k, d10 * k], axis=-1),
        np.stack([d21 * k, big, s01 * k, s02 * k], axis=-1),
        np.stack([d02 * k, s01 * k, big, s12 * k], axis=-1),
        np.stack([d10 * k, s02 * k, s12 * k, big], axis=-1),
    ], axis=-2)
    q = np.take_along_axis(options, pick[..., None, None], -2)[..., 0, :]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def matrix_from_quat(q):
    """(…, 4) unit quaternions → (…, 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def quat_conjugate(q):
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_multiply(a, b):
    """Hamilton product a ⊗ b (the rotation b, then a)."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([w, aw * bv + bw * av + np.cross(av, bv)], axis=-1)


def rotvec_from_quat(q):
    """(…, 4) unit quaternions → (…, 3) rotation vectors (angle in [0, π])."""
    q = np.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2 * np.arctan2(s, w)
    # angle / sin(angle/2), → 2 as the angle → 0.
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0 / np.maximum(w, 1e-12))
    return v * scale[..., None]


def is_rotation(m, tolerance=ROTATION_TOLERANCE):
    """Whether each (…, 3, 3) matrix is a proper rotation to `tolerance`."""
    gram = np.einsum("...ki,...kj->...ij", m, m)
    orthonormal = np.abs(gram - np.eye(3)).max(axis=(-1, -2)) <= tolerance
    return orthonormal & (np.linalg.det(m) > 0)


# ---------------------------------------------------------------------------------------------
# Files


# The globals a pickle of numpy arrays refers to (Python 2's numpy, numpy 1 and numpy 2); nothing
# else is loaded, since unpickling may call whatever a file names.
_PICKLE_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
    ("numpy", "ndarray"), ("numpy", "dtype"), ("_codecs", "encode"),
    ("copyreg", "_reconstructor"), ("builtins", "object"), ("collections", "OrderedDict"),
}


class _ArrayUnpickler(pickle.Unpickler):
    def __init__(self, f, path):
        # latin1: the datasets were pickled by Python 2, whose byte strings (numpy's raw data)
        # must come back byte for byte.
        super().__init__(f, encoding="latin1")
        self.path = path

    def find_class(self, module, name):
        if (module, name) not in _PICKLE_GLOBALS:
            raise DatasetError(f"{self.path}: the pickle refers to {module}.{name}, which a file "
                               f"of numpy arrays does not need; not loaded (unpickling runs code)")
        if module.startswith("numpy.core") and hasattr(np, "_core"):
            module = "numpy._core" + module[len("numpy.core"):]  # numpy 2 moved it
        return super().find_class(module, name)


def load_pickle(path):
    """The dict of arrays a dataset pickle holds; `DatasetError` naming the file otherwise."""
    path = str(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise DatasetError(f"{path}: cannot read it: {e.strerror}") from None
    with f:
        try:
            data = _ArrayUnpickler(f, path).load()
        except DatasetError:
            raise
        except Exception as e:  # a truncated or foreign file fails in many ways
            raise DatasetError(f"{path}: not a readable pickle ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: holds a {type(data).__name__}, not a dict of arrays")
    return data


def _array(data, key, path, tail):
    """data[key] as float64, checked to be (N, *tail)."""
    expected = "(N, " + ", ".join(str(d) for d in tail) + ")"
    if key not in data:
        keys = ", ".join(sorted(repr(k) for k in data)) or "none"
        raise DatasetError(f"{path}: no key '{key}' (an array {expected}); its keys: {keys}")
    value = data[key]
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiu":
        what = (f"an array of {value.dtype}" if isinstance(value, np.ndarray)
                else type(value).__name__)
        raise DatasetError(f"{path}: '{key}' is {what}, expected numbers {expected}")
    if value.shape[1:] != tuple(tail) or value.ndim != len(tail) + 1:
        raise DatasetError(f"{path}: '{key}' has shape {value.shape}, expected {expected}")
    if len(value) == 0:
        raise DatasetError(f"{path}: '{key}' holds no frames")
    return value.astype(np.float64)


def _pose(data, key, path):
    """SMPL axis-angle poses (N, 72) or (N, 24, 3) → (N, 24, 3)."""
    value = data.get(key)
    if isinstance(value, np.ndarray) and value.ndim == 3:
        return _array(data, key, path, (24, 3))
    return _array(data, key, path, (72,)).reshape(-1, 24, 3)


def _common_length(path, series):
    """The frames every series has; a note when they differ (the references keep the first ones,
    as do we: the files of one sequence start together)."""
    lengths = {name: len(v) for name, v in series.items()}
    n = min(lengths.values())
    if len(set(lengths.values())) == 1:
        return n, []
    counts = ", ".join(f"{name} {count}" for name, count in lengths.items())
    return n, [f"lengths differ ({counts}): kept the first {n} frames"]


def find_translation(path, pkl_path):
    """`path` itself if it is a file, else the official `S1/acting1/gt_skel_gbl_pos.txt` under the
    folder `path` that belongs to the DIP pickle `s1_acting1.pkl` (names matched ignoring case)."""
    path = str(path)
    if os.path.isfile(path):
        return path
    if not os.path.isdir(path):
        raise DatasetError(f"{path}: no such file or folder (the TotalCapture translation)")
    stem = os.path.splitext(os.path.basename(pkl_path))[0]
    subject, _, action = stem.partition("_")
    found = path
    for part in (subject, action):
        entries = {e.lower(): e for e in os.listdir(found)} if os.path.isdir(found) else {}
        if part.lower() not in entries:
            raise DatasetError(f"{pkl_path}: no {subject.upper()}/{action}/{TRANSLATION_FILE} "
                               f"under {path} (the translation of '{stem}')")
        found = os.path.join(found, entries[part.lower()])
    txt = os.path.join(found, TRANSLATION_FILE)
    if not os.path.isfile(txt):
        raise DatasetError(f"{pkl_path}: no {txt} (the translation of '{stem}')")
    return txt


def read_translation(path, joint=DEFAULT_TRANSLATION_JOINT):
    """Root translation in M (N, 3), m, relative to frame 0, from TotalCapture's official
    `gt_skel_gbl_pos.txt`: a header line of tab-separated joint names, then per frame one
    tab-separated "x y z" per joint in inches in the capture's frame, whose x and z point the
    other way than M's (reference §3)."""
    path = str(path)
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise DatasetError(f"{path}: cannot read it: {e.strerror}") from None
    names = [n.strip() for n in lines[0].split("\t")] if lines else []
    if joint not in names:
        known = ", ".join(n for n in names if n) or "none"
        raise DatasetError(f"{path}: line 1 names no joint '{joint}' (it names: {known})")
    column = names.index(joint)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split("\t")
        if column >= len(fields):
            raise DatasetError(f"{path}: line {number}: {len(fields)} fields, no '{joint}' "
                               f"(field {column + 1})")
        try:
            xyz = [float(v) for v in fields[column].split()]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            raise DatasetError(f"{path}: line {number}: '{joint}' is {fields[column]!r}, "
                               f"expected three numbers 'x y z'")
        rows.append(xyz)
    if not rows:
        raise DatasetError(f"{path}: no frames after the header line")
    p = np.array(rows) * INCH_M * np.array([-1.0, 1.0, -1.0])
    return p - p[0]
