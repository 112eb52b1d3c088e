"""imuflow.datasets and `python -m imuflow.convert`: DIP-IMU and TotalCapture as recordings.

Run: `python python/tests/test_datasets.py` (or pytest) with numpy and mcap installed. With
IMUFLOW_BIN (or a built target/debug/imuflow) the Rust side reads the converted files too: the
packaged layouts against `imuflow stage --layouts`, `imuflow export`, the imu-source stage's replay
through a graph, and `imuflow compare --input` with python/examples/real-imu.toml. Without a binary
those parts are skipped and say so.

The datasets themselves are licensed and not here: the fixtures below imitate their files (the
keys, shapes and float64 arrays the papers' code reads, pickled the way Python 2 pickled them, so
they load only with latin1, NaN where a sensor dropped out). Expected values are derived by hand
in the comments: a rotation about z by 90° as a quaternion, the specific force of a known
orientation and acceleration, which of the 17 (or 6) sensors lands in which slot, a sensor turning
at 1 rad/s, inches turned into metres.
"""
import contextlib
import io
import json
import os
import pickle
import struct
import subprocess
import sys
import tempfile
from types import FunctionType

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(HERE, ".."))
import imuflow  # noqa: E402
from imuflow import convert, datasets  # noqa: E402
from imuflow.datasets import DatasetError  # noqa: E402

G = 9.81
H = np.sqrt(0.5)
INVALID = 2


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# ---------------------------------------------------------------------------------------------
# Fixtures


class Py2Pickler(pickle._Pickler):
    """Pickles as Python 2 did (protocol 2): byte strings and str both as Python 2 `str`
    (BINSTRING), numpy's functions under their numpy-1 module names. Such a file loads in Python 3
    only with encoding='latin1' (numpy's raw bytes are not ASCII), like the datasets' files."""

    dispatch = dict(pickle._Pickler.dispatch)

    def save_py2_str(self, obj):
        data = obj if isinstance(obj, bytes) else obj.encode("latin1")
        if len(data) < 256:
            self.write(pickle.SHORT_BINSTRING + bytes([len(data)]) + data)
        else:
            self.write(pickle.BINSTRING + struct.pack("<i", len(data)) + data)
        self.memoize(obj)

    def save_global(self, obj, name=None):
        name = name or obj.__qualname__
        module = pickle.whichmodule(obj, name).replace("numpy._core", "numpy.core")
        self.write(pickle.GLOBAL + f"{module}\n{name}\n".encode())
        self.memoize(obj)

    dispatch[bytes] = save_py2_str
    dispatch[str] = save_py2_str
    dispatch[FunctionType] = save_global


def write_py2_pickle(path, obj):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "wb") as f:
        Py2Pickler(f, protocol=2).dump(obj)


def dip_fixture(n=12):
    """A DIP-IMU sequence: 17 sensors, all identity with acceleration (index, 0, 0) except:
    sensor 7 (left elbow → imuflow's 0) turned 90° about z; sensor 12 (right knee → imuflow's 3)
    R_x(90°)·R_y(t/60), turning about its own y at 1 rad/s; NaN in sensor 12's orientation at
    frame 5, in sensor 11's (left knee → 2) acceleration at frame 7 and in sensor 1 (unused) at
    frame 2. Pose: root turned 90° about z, left elbow (18) 180° about x, NaN at frame 9."""
    ori = np.tile(np.eye(3), (n, 17, 1, 1))
    acc = np.zeros((n, 17, 3))
    acc[..., 0] = np.arange(17)
    ori[:, 7] = rot_z(np.pi / 2)
    for t in range(n):
        ori[t, 12] = rot_x(np.pi / 2) @ rot_y(t / 60)
    ori[5, 12] = np.nan
    acc[7, 11] = np.nan
    ori[2, 1] = np.nan
    gt = np.zeros((n, 72))
    gt[:, 0:3] = [0, 0, np.pi / 2]
    gt[:, 54:57] = [np.pi, 0, 0]
    gt[9, 30] = np.nan
    return {"imu_ori": ori, "imu_acc": acc, "gt": gt}


def tc_fixture(n=10):
    """A TotalCapture sequence as DIP stored it: six sensors, identity, acceleration (stored index,
    0, 0); the pose two frames longer than the IMU data (as in some of DIP's files)."""
    acc = np.zeros((n, 6, 3))
    acc[..., 0] = np.arange(6)
    gt = np.zeros((n + 2, 72))
    gt[:, 3:6] = [0.2, 0, 0]  # left hip
    return {"ori": np.tile(np.eye(3), (n, 6, 1, 1)), "acc": acc, "gt": gt}


def write_translation(path, frames):
    """An official gt_skel_gbl_pos.txt: a header of tab-separated joint names, per frame one
    "x y z" per joint (inches) each followed by a tab. Hips(k) = (10 + k, 40, 20 − 2k),
    Spine(k) = (10, 50 + k, 20), the feet fixed."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write("Hips\tSpine\tLeftFoot\tRightFoot\n")
        for k in range(frames):
            joints = [(10 + k, 40, 20 - 2 * k), (10, 50 + k, 20), (5, 3, 1), (15, 3, 1)]
            f.write("".join(f"{x} {y} {z}\t" for x, y, z in joints) + "\n")


# ---------------------------------------------------------------------------------------------
# DIP-IMU


def test_the_fixture_is_a_python2_pickle():
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "s_01", "01.pkl")
        write_py2_pickle(path, dip_fixture())
        with open(path, "rb") as f:
            try:
                pickle.load(f)
            except UnicodeDecodeError:
                pass
            else:
                raise AssertionError("the fixture loads without latin1: not what Python 2 wrote")
        with open(path, "rb") as f:
            data = pickle.load(f, encoding="latin1")
        assert data["imu_ori"].shape == (12, 17, 3, 3) and data["imu_ori"].dtype == np.float64


def test_dip_converts_with_hand_derived_values():
    with tempfile.TemporaryDirectory() as d:
        src = os.path.join(d, "s_01", "01.pkl")
        out = os.path.join(d, "out", "s_01", "01.mcap")
        write_py2_pickle(src, dip_fixture())
        done = datasets.convert_dip(src, out)
        rec = imuflow.open_recording(out)
        assert rec.topics == {"source.imu": "imuflow.ImuFrame.v2",
                              "source.truth": "imuflow.MotionFrame.v1"}, rec.topics
        imu = rec.frames("source.imu")
        seq, rotations, root = rec.poses("source.truth")
        truth = rec.frames("source.truth")

    assert len(imu) == 12 and list(imu["header.seq"]) == list(range(12))
    # 10⁹/60 ns per frame, truncated as the synthesizing source does.
    assert list(imu["header.capture_ns"][:4]) == [0, 16666666, 33333333, 50000000]
    # Frame 5 lost sensor 3 (bit 8), frame 7 sensor 2 (bit 4); sensor 1 of the 17 is not used.
    expected_mask = [63] * 12
    expected_mask[5], expected_mask[7] = 63 - 8, 63 - 4
    assert list(imu["valid_mask"]) == expected_mask, imu["valid_mask"]
    assert [k for k in range(12) if imu["header.flags"][k] & INVALID] == [5, 7]
    assert done.missing_per_sensor == [0, 0, 1, 1, 0, 0] and done.invalid_frames == 2

    q = imu["orientation_wxyz"].astype(np.float64)
    f = imu["specific_force_mps2"].astype(np.float64)
    w = imu["angular_rate_radps"].astype(np.float64)
    # Sensor 0 = DIP's 7, R_z(90°): q = (cos 45°, 0, 0, sin 45°); its acceleration (7, 0, 0) in M
    # is f = R_zᵀ·((7, 0, 0) − (0, −9.81, 0)) = R_zᵀ·(7, 9.81, 0) = (9.81, −7, 0).
    assert np.allclose(q[:, 0], [H, 0, 0, H], atol=1e-6)
    assert np.allclose(f[:, 0], [G, -7, 0], atol=1e-5)
    # Identity sensors 1, 2, 4, 5 = DIP's 8, 11, 0, 2: f = (index, 9.81, 0).
    for k, index in [(1, 8), (2, 11), (4, 0), (5, 2)]:
        rows = [t for t in range(12) if expected_mask[t] & (1 << k)]
        assert np.allclose(f[rows, k], [index, G, 0], atol=1e-5), (k, f[rows, k])
    # Sensor 3 = DIP's 12 at frame 0, R_x(90°): f = R_xᵀ·(12, 9.81, 0) = (12, 0, −9.81); it turns
    # at 1 rad/s about its own y in every frame it has a sample, also frame 4 (no frame 5: the
    # backward difference) and the last.
    assert np.allclose(f[0, 3], [12, 0, -G], atol=1e-5)
    for t in range(12):
        expected = [0, 0, 0] if t == 5 else [0, 1, 0]
        assert np.allclose(w[t, 3], expected, atol=1e-4), (t, w[t, 3])
    assert np.allclose(w[:, [0, 1, 2, 4, 5]], 0, atol=1e-6)
    # A sensor without a sample: identity and zeros.
    assert np.array_equal(q[5, 3], [1, 0, 0, 0]) and not f[5, 3].any() and not w[5, 3].any()
    assert np.array_equal(q[7, 2], [1, 0, 0, 0]) and not f[7, 2].any()

    # Truth: root (0, 0, π/2) → (cos 45°, 0, 0, sin 45°); left elbow (π, 0, 0) → (0, 1, 0, 0);
    # every other joint the identity; frame 9 (NaN) INVALID and all identity; root at zero.
    assert list(seq) == list(range(12))
    good = [t for t in range(12) if t != 9]
    assert np.allclose(rotations[good, 0], [H, 0, 0, H], atol=1e-6)
    assert np.allclose(rotations[good, 18], [0, 1, 0, 0], atol=1e-6)
    others = [j for j in range(24) if j not in (0, 18)]
    assert np.allclose(rotations[:, others], [1, 0, 0, 0])
    assert np.allclose(rotations[9], [1, 0, 0, 0])
    assert [t for t in range(12) if truth["header.flags"][t] & INVALID] == [9]
    assert not root.any() and not truth["q"].any() and not truth["tau"].any()
    assert done.truth_frames == 12 and done.truth_invalid_frames == 1


def test_the_specific_force_gives_back_the_free_acceleration():
    """R·f + g = a for every usable sample (a second derivation: through the fixture's matrices,
    not the converter's quaternions), which is what the calibration stage with method `none`
    computes; and the sensors arrive in the order [7, 8, 11, 12, 0, 2]."""
    data = dip_fixture()
    with tempfile.TemporaryDirectory() as d:
        src, out = os.path.join(d, "a", "01.pkl"), os.path.join(d, "01.mcap")
        write_py2_pickle(src, data)
        datasets.convert_dip(src, out)
        imu = imuflow.open_recording(out).frames("source.imu")
    for k, index in enumerate([7, 8, 11, 12, 0, 2]):
        for t in range(12):
            if imu["valid_mask"][t] & (1 << k):
                back = data["imu_ori"][t, index] @ imu["specific_force_mps2"][t, k] + [0, -G, 0]
                assert np.allclose(back, data["imu_acc"][t, index], atol=1e-5), (t, k, back)


def test_rotation_conversions_agree_with_rodrigues():
    """quat_from_matrix against a second algorithm: random axis-angle vectors (angles up to π, so
    every branch of Shepperd's method is taken) through Rodrigues' formula
    R = I + sin θ·K + (1 − cos θ)·K², against quat_from_axis_angle (up to the sign)."""
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, 396), [0.0, 1e-9, np.pi - 1e-7, np.pi]])
    matrices = []
    for (x, y, z), a in zip(axes, angles):
        k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        matrices.append(np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k)
    from_matrix = datasets.quat_from_matrix(np.array(matrices))
    from_vector = datasets.quat_from_axis_angle(axes * angles[:, None])
    assert np.allclose(np.abs(np.sum(from_matrix * from_vector, axis=1)), 1, atol=1e-9)
    assert np.allclose(datasets.matrix_from_quat(from_matrix), matrices, atol=1e-9)
    assert np.all(from_matrix[:, 0] >= 0)
    # And back: the rotation vectors (angles below π, where the vector is unique).
    below = angles < np.pi - 1e-6
    vectors = axes * angles[:, None]
    assert np.allclose(datasets.rotvec_from_quat(from_vector[below]), vectors[below], atol=1e-7)


# ---------------------------------------------------------------------------------------------
# TotalCapture


def test_totalcapture_reorders_and_reads_the_translation():
    with tempfile.TemporaryDirectory() as d:
        src = os.path.join(d, "dip_tc", "s1_acting1.pkl")
        official = os.path.join(d, "official")
        txt = os.path.join(official, "S1", "acting1", "gt_skel_gbl_pos.txt")
        write_py2_pickle(src, tc_fixture(10))
        write_translation(txt, 15)
        out = os.path.join(d, "tc.mcap")
        done = datasets.convert_totalcapture(src, out, translation_txt=official)  # found by name
        imu = imuflow.open_recording(out).frames("source.imu")
        _, rotations, root = imuflow.open_recording(out).poses("source.truth")
        spine = os.path.join(d, "spine.mcap")
        datasets.convert_totalcapture(src, spine, translation_txt=txt, translation_joint="Spine")
        _, _, spine_root = imuflow.open_recording(spine).poses("source.truth")
        bare = os.path.join(d, "bare.mcap")
        datasets.convert_totalcapture(src, bare)
        _, _, bare_root = imuflow.open_recording(bare).poses("source.truth")
    # imuflow's sensor k is DIP's stored sensor [2, 3, 0, 1, 4, 5][k]: f = (index, 9.81, 0).
    assert np.allclose(imu["specific_force_mps2"][:, :6, 0], [2, 3, 0, 1, 4, 5], atol=1e-6)
    assert np.allclose(imu["specific_force_mps2"][:, :6, 1], G, atol=1e-6)
    # 10 IMU frames, 12 poses, 15 translations: the first 10 of each, and the summary says so.
    assert len(imu) == 10 and len(rotations) == 10 and done.frames == 10
    assert any("kept the first 10" in n for n in done.notes), done.notes
    # Left hip 0.2 rad about x: (cos 0.1, sin 0.1, 0, 0).
    assert np.allclose(rotations[:, 1], [np.cos(0.1), np.sin(0.1), 0, 0], atol=1e-6)
    # Hips: x 10 + k in, z 20 − 2k in; negated and relative to frame 0: (−0.0254k, 0, 0.0508k) m.
    k = np.arange(10)
    assert np.allclose(root, np.stack([-0.0254 * k, 0 * k, 0.0508 * k], axis=1), atol=1e-6)
    # Spine: y 50 + k in → (0, 0.0254k, 0) m.
    assert np.allclose(spine_root, np.stack([0 * k, 0.0254 * k, 0 * k], axis=1), atol=1e-6)
    assert not bare_root.any()


def test_totalcapture_without_poses_has_no_truth():
    data = tc_fixture(6)
    del data["gt"]
    with tempfile.TemporaryDirectory() as d:
        src, out = os.path.join(d, "x", "s2_walking1.pkl"), os.path.join(d, "o.mcap")
        write_py2_pickle(src, data)
        done = datasets.convert_totalcapture(src, out)
        rec = imuflow.open_recording(out)
    assert list(rec.topics) == ["source.imu"] and done.truth_frames == 0
    assert "no 'gt' pose" in done.summary()


# ---------------------------------------------------------------------------------------------
# Bad input


def expect_error(call, *needles):
    try:
        call()
    except DatasetError as e:
        for needle in needles:
            assert needle in str(e), (needle, str(e))
        return str(e)
    raise AssertionError(f"no error naming {needles}")


def test_malformed_input_is_a_named_error():
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "o.mcap")
        missing = dip_fixture()
        del missing["imu_acc"]
        path = os.path.join(d, "s", "missing.pkl")
        write_py2_pickle(path, missing)
        expect_error(lambda: datasets.convert_dip(path, out), path, "'imu_acc'", "'gt'")

        wrong = dip_fixture()
        wrong["imu_acc"] = np.zeros((12, 17, 4))
        path = os.path.join(d, "s", "shape.pkl")
        write_py2_pickle(path, wrong)
        expect_error(lambda: datasets.convert_dip(path, out), path, "'imu_acc'", "(12, 17, 4)",
                     "(N, 17, 3)")

        wrong = dip_fixture()
        wrong["gt"] = [[0.0] * 72]
        path = os.path.join(d, "s", "list.pkl")
        write_py2_pickle(path, wrong)
        expect_error(lambda: datasets.convert_dip(path, out), path, "'gt' is list")

        path = os.path.join(d, "notes.pkl")
        with open(path, "w") as f:
            f.write("DIP-IMU s_01\n")
        expect_error(lambda: datasets.convert_dip(path, out), path, "not a readable pickle")

        path = os.path.join(d, "cut.pkl")
        whole = io.BytesIO()
        Py2Pickler(whole, protocol=2).dump(dip_fixture())
        with open(path, "wb") as f:
            f.write(whole.getvalue()[: len(whole.getvalue()) // 2])
        expect_error(lambda: datasets.convert_totalcapture(path, out), path,
                     "not a readable pickle")

        path = os.path.join(d, "list.pkl")
        write_py2_pickle(path, [1, 2])
        expect_error(lambda: datasets.convert_dip(path, out), path, "not a dict")

        # A pickle that would call os.getcwd: refused before anything is called.
        path = os.path.join(d, "code.pkl")
        with open(path, "wb") as f:
            f.write(b"\x80\x02cos\ngetcwd\n)R.")
        expect_error(lambda: datasets.convert_dip(path, out), path, "os.getcwd", "not loaded")

        expect_error(lambda: datasets.convert_dip(os.path.join(d, "none.pkl"), out), "none.pkl")
        assert not os.path.exists(out) and not os.path.exists(out + ".partial")

        src = os.path.join(d, "tc", "s1_acting1.pkl")
        write_py2_pickle(src, tc_fixture(4))
        txt = os.path.join(d, "gt", "S1", "acting1", "gt_skel_gbl_pos.txt")
        write_translation(txt, 4)
        expect_error(lambda: datasets.convert_totalcapture(src, out, txt, "Pelvis"),
                     txt, "'Pelvis'", "Hips, Spine")
        with open(txt, "a") as f:
            f.write("1 2\t3 4 5\t1 1 1\t2 2 2\t\n")
        expect_error(lambda: datasets.convert_totalcapture(src, out, txt), txt, "line 6", "'Hips'")
        expect_error(lambda: datasets.convert_totalcapture(src, out, os.path.join(d, "nowhere")),
                     "nowhere")
        other = os.path.join(d, "tc", "s4_freestyle3.pkl")
        write_py2_pickle(other, tc_fixture(4))
        expect_error(lambda: datasets.convert_totalcapture(other, out, os.path.join(d, "gt")),
                     other, "S4/freestyle3/gt_skel_gbl_pos.txt")
        assert not os.path.exists(out)


# ---------------------------------------------------------------------------------------------
# The command line


def run_cli(*args):
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python"))
    return subprocess.run([sys.executable, "-m", "imuflow.convert", *args], capture_output=True,
                          text=True, env=env, timeout=120)


def test_the_cli_converts_a_folder_and_names_the_file_that_fails():
    with tempfile.TemporaryDirectory() as d:
        src, out = os.path.join(d, "DIP_IMU"), os.path.join(d, "out")
        write_py2_pickle(os.path.join(src, "s_01", "01.pkl"), dip_fixture())
        write_py2_pickle(os.path.join(src, "s_01", "02.pkl"), dip_fixture(20))
        broken = dip_fixture()
        del broken["imu_acc"]
        write_py2_pickle(os.path.join(src, "s_02", "01.pkl"), broken)
        with open(os.path.join(src, "readme.txt"), "w") as f:
            f.write("not a sequence\n")
        done = run_cli("dip", src, out)
        assert done.returncode == 1, (done.stdout, done.stderr)
        assert "[1/3] s_01/01.pkl -> " in done.stdout and "12 frames" in done.stdout, done.stdout
        assert "[2/3] s_01/02.pkl -> " in done.stdout and "20 frames" in done.stdout, done.stdout
        assert "[3/3] s_02/01.pkl: error: " in done.stderr, done.stderr
        assert "'imu_acc'" in done.stderr, done.stderr
        assert "converted 2 of 3" in done.stderr, done.stderr
        written = sorted(os.path.relpath(os.path.join(a, n), out) for a, _, ns in os.walk(out)
                         for n in ns)
        assert written == ["s_01/01.mcap", "s_01/02.mcap"], written
        assert len(imuflow.open_recording(os.path.join(out, "s_01", "02.mcap"))
                   .frames("source.imu")) == 20

        assert run_cli("dip", os.path.join(src, "s_01", "01.pkl"), os.path.join(d, "one.mcap"),
                       "--gt-translation", "x.txt").returncode == 2
        assert run_cli("dip", os.path.join(d, "nothing"), out).returncode == 2


def test_the_cli_finds_each_totalcapture_translation():
    with tempfile.TemporaryDirectory() as d:
        src, out, official = (os.path.join(d, n) for n in ("TC_DIP", "out", "official"))
        write_py2_pickle(os.path.join(src, "s1_acting1.pkl"), tc_fixture(8))
        write_py2_pickle(os.path.join(src, "s2_walking2.pkl"), tc_fixture(6))
        write_translation(os.path.join(official, "S1", "acting1", "gt_skel_gbl_pos.txt"), 8)
        write_translation(os.path.join(official, "S2", "walking2", "gt_skel_gbl_pos.txt"), 6)
        stdout = io.StringIO()
        with contextlib.redirect_stdout(stdout):
            code = convert.main(["totalcapture", src, out, "--gt-translation", official])
        assert code == 0, stdout.getvalue()
        assert "from gt_skel_gbl_pos.txt ('Hips'" in stdout.getvalue(), stdout.getvalue()
        _, _, root = imuflow.open_recording(os.path.join(out, "s2_walking2.mcap")).poses(
            "source.truth")
        assert np.allclose(root[5], [-0.0254 * 5, 0, 0.0508 * 5], atol=1e-6)
        # One translation file for a whole folder cannot be right.
        stderr = io.StringIO()
        with contextlib.redirect_stderr(stderr):
            code = convert.main(["totalcapture", src, out, "--gt-translation",
                                 os.path.join(official, "S1", "acting1", "gt_skel_gbl_pos.txt")])
        assert code == 2 and "folder" in stderr.getvalue(), stderr.getvalue()


# ---------------------------------------------------------------------------------------------
# The packaged layouts and the Rust side


def binary():
    """IMUFLOW_BIN when set (a wrong path then fails the tests), else a built debug binary."""
    if os.environ.get("IMUFLOW_BIN"):
        return os.path.abspath(os.environ["IMUFLOW_BIN"])
    built = os.path.join(ROOT, "target", "debug", "imuflow")
    return built if os.path.isfile(built) else None


def test_the_packaged_layouts_describe_the_frames():
    """Sizes from graph/src/frames.rs's field lists, by hand: ImuFrame = 32 (header) + 17·4·4 +
    17·3·4 + 17·3·4 + 4 + 4 = 720 (one slot per site of the catalogue); MotionFrame = 32 + 24·4·4
    + 3·4 + 3·75·4 + 24·3·4 + 4 + 24·4 + 3·4 = 1728; every byte in exactly one field."""
    for name, size in [("ImuFrame", 720), ("MotionFrame", 1728)]:
        layout = imuflow.writer.packaged_layout(name)
        dtype = imuflow.dtype_from_layout(layout)
        assert layout["size"] == size == dtype.itemsize, (name, layout["size"])
        spans = sorted((dtype.fields[n][1], dtype.fields[n][1] + dtype.fields[n][0].itemsize)
                       for n in dtype.names)
        assert spans[0][0] == 0 and spans[-1][1] == size
        assert all(b == a for (_, b), (a, _) in zip(spans, spans[1:])), name


def test_the_packaged_layouts_are_the_binarys():
    if not binary():
        print("skipped: no imuflow binary (IMUFLOW_BIN or target/debug/imuflow) to compare "
              "python/imuflow/layouts.json with")
        return
    printed = json.loads(subprocess.run([binary(), "stage", "--layouts"], check=True,
                                        capture_output=True, text=True).stdout)
    wanted = [layout for layout in printed if layout["struct_name"] in ("ImuFrame", "MotionFrame")]
    with open(imuflow.writer.LAYOUTS_FILE, encoding="utf-8") as f:
        packaged = json.load(f)
    assert packaged == wanted, (
        "python/imuflow/layouts.json differs from `imuflow stage --layouts`; regenerate it with\n"
        "  target/debug/imuflow stage --layouts | python3 -c \"import json, sys; json.dump([l for l "
        "in json.load(sys.stdin) if l['struct_name'] in ('ImuFrame', 'MotionFrame')], "
        "open('python/imuflow/layouts.json', 'w', encoding='utf-8'), indent=2, "
        "ensure_ascii=False)\"")


def run_graph(text, d, name):
    graph = os.path.join(d, f"{name}.toml")
    with open(graph, "w") as f:
        f.write(text)
    env = dict(os.environ, IMUFLOW_SHM_PREFIX=f"imuflow_dstest{os.getpid()}_{name}_")
    return subprocess.run([binary(), "run", graph, "--no-progress"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def test_the_rust_side_reads_the_recordings():
    """`imuflow export` (the truth, at the recorded rate) and the imu-source stage's replay (what
    `imuflow compare --input` runs), recorded again by the recorder stage: the same frames."""
    if not binary():
        print("skipped: no imuflow binary (IMUFLOW_BIN or target/debug/imuflow): the Rust readers "
              "were not tried on the converted files")
        return
    with tempfile.TemporaryDirectory() as d:
        src, rec = os.path.join(d, "s_01", "01.pkl"), os.path.join(d, "dip.mcap")
        write_py2_pickle(src, dip_fixture())
        datasets.convert_dip(src, rec)

        npz = os.path.join(d, "truth.npz")
        done = subprocess.run([binary(), "export", rec, "--channel", "source.truth", "--format",
                               "npz", "-o", npz, "--keep-all"], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        exported = np.load(npz)
        assert float(exported["mocap_framerate"]) == 60.0  # our `rate_hz` metadata
        poses = exported["poses"].reshape(-1, 24, 3)
        assert poses.shape[0] == 12
        good = [t for t in range(12) if t != 9]
        # Local rotations carry over as they are: the left elbow 180° about x (either sign).
        assert np.allclose(np.abs(poses[good, 18, 0]), np.pi, atol=1e-5)
        assert np.allclose(poses[good][:, 18, 1:], 0, atol=1e-5)

        again = os.path.join(d, "again.mcap")
        graph = f"""
name = "replay-converted"
rate_hz = 60
[stages.source]
kind = "imu-source"
params = {{ mode = "replay", path = "{rec}" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "source.imu", truth = "source.truth" }}
params = {{ path = "{again}" }}
"""
        done = run_graph(graph, d, "replay")
        assert done.returncode == 0, done.stderr[-3000:]
        ours, theirs = imuflow.open_recording(rec), imuflow.open_recording(again)
        for topic in ("source.imu", "source.truth"):
            a, b = ours.frames(topic), theirs.frames(topic)
            assert len(a) == len(b) == 12, (topic, len(a), len(b))
            for name in a.dtype.names:
                if name != "header.publish_ns":  # stamped anew by the replay
                    assert np.array_equal(a[name], b[name]), (topic, name)


def test_compare_runs_a_converted_recording():
    """python/examples/real-imu.toml on a converted sequence: three variants scored against the
    truth, and the shared calibration (`none`) hands the networks the dataset's own orientations
    and accelerations: R_MB = R and a_M = R·f + g = a."""
    if not binary():
        print("skipped: no imuflow binary (IMUFLOW_BIN or target/debug/imuflow): "
              "`imuflow compare --input` was not run")
        return
    n = 60
    data = dip_fixture(n)
    with tempfile.TemporaryDirectory() as d:
        src, rec, out = os.path.join(d, "s_09", "01.pkl"), os.path.join(d, "dip.mcap"), \
            os.path.join(d, "compare")
        write_py2_pickle(src, data)
        datasets.convert_dip(src, rec)
        env = dict(os.environ, IMUFLOW_SHM_PREFIX=f"imuflow_dstest{os.getpid()}_compare_")
        done = subprocess.run([binary(), "compare", "python/examples/real-imu.toml", "--input",
                               rec, "--out", out, "--no-progress", "--quiet"], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        with open(os.path.join(out, "results.json")) as f:
            results = json.load(f)
        body = imuflow.open_recording(os.path.join(out, "real-imu.mcap")).frames("calib.body_imu")
    assert results["truth"] == "source.truth" and results["failed_branches"] == []
    assert results["shared"] == ["source", "calib"], results["shared"]
    metrics = {m["metric"]: m["values"] for m in results["metrics"]}
    for variant in ("pip", "globalpose", "no-physics"):
        assert np.isfinite(metrics["angle error"][variant]), metrics["angle error"]
        # DIP-IMU has no translation: the truth travels nowhere, so no translation windows.
        assert metrics["translation error at 2 m"][variant] is None
        # The frames a sensor or the truth lost (5, 7, 9) are not scored.
        assert metrics["frames scored"][variant] <= n - 3, metrics["frames scored"]
    assert len(body) == n
    for row in body:
        t = int(row["header.seq"])
        for k, index in enumerate([7, 8, 11, 12, 0, 2]):
            if not row["valid_mask"] & (1 << k):
                continue
            r = datasets.matrix_from_quat(row["bone_orientation_wxyz"][k].astype(np.float64))
            assert np.allclose(r, data["imu_ori"][t, index], atol=1e-5), (t, k)
            assert np.allclose(row["free_acceleration_mps2"][k], data["imu_acc"][t, index],
                               atol=1e-4), (t, k, row["free_acceleration_mps2"][k])


if __name__ == "__main__":
    tests = [v for k, v in sorted(globals().items()) if k.startswith("test_")]
    for test in tests:
        test()
        print(f"ok {test.__name__}")
