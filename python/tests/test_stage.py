"""Python stages in real graphs, between Rust stages, through the launcher.

Run: `IMUFLOW_BIN=target/debug/imuflow python python/tests/test_stage.py` (or pytest) with this
package, numpy, mcap and iceoryx2 installed; .ci/run runs it in its verify venv. Without
IMUFLOW_BIN the graph tests are skipped (they say so).

Expectations are independent of the stage code: the filter's output is recomputed here by a plain
loop over the recorded input (not the example's vectorized code), frame counts come from the
sample's README, and "no leaks" is checked on the files the run's shared-memory prefix owns.
"""
import glob
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(HERE, ".."))
import imuflow  # noqa: E402
from imuflow import stage as stage_module  # noqa: E402

FRAMES = 1511  # models/sample/README.md
SMOOTH = os.path.join(ROOT, "python", "examples", "smooth.py")

HEAD = """
name = "{name}"
[stages.source]
kind = "imu-source"
params = {{ mode = "replay", path = "models/sample/walk.mcap" }}
[stages.calib]
kind = "calibration"
inputs = {{ imu = "source.imu" }}
params = {{ method = "tpose", frame = "z-up", heading_deg = 30.0 }}
[stages.kin]
kind = "kinematics"
inputs = {{ imu = "calib.body_imu" }}
params = {{ net = "pip", weights = "models/pip.safetensors" }}
"""


def binary():
    path = os.environ.get("IMUFLOW_BIN")
    return os.path.abspath(path) if path else None


def run_graph(text, d, name):
    """Runs the graph `text` from the repository root with a shared-memory prefix of its own;
    returns (completed process, the prefix's leftover files)."""
    graph = os.path.join(d, f"{name}.toml")
    with open(graph, "w") as f:
        f.write(text)
    prefix = f"imuflow_pytest{os.getpid()}_{name.replace('-', '')}_"
    env = dict(os.environ, IMUFLOW_SHM_PREFIX=prefix)
    done = subprocess.run([binary(), "run", graph, "--no-progress"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    leftovers = glob.glob(f"/dev/shm/{prefix}*") + glob.glob(f"/tmp/iceoryx2/**/{prefix}*",
                                                               recursive=True)
    return done, leftovers


def reference_smoothing(raw, alpha):
    """The filter of examples/smooth.py written out frame by frame in float64."""
    q_prev = p_prev = v_prev = r_prev = None
    out_q, out_p, out_v, out_r = [], [], [], []
    for k in range(len(raw)):
        q = raw["local_pose_wxyz"][k].astype(np.float64)
        p = raw["joint_position_m"][k].astype(np.float64)
        v = raw["joint_velocity_mps"][k].astype(np.float64)
        r = raw["root_velocity_mps"][k].astype(np.float64)
        if q_prev is not None:
            blended = []
            for j in range(24):
                new = q[j] if np.dot(q_prev[j], q[j]) >= 0 else -q[j]
                mix = (1 - alpha) * q_prev[j] + alpha * new
                blended.append(mix / np.sqrt(np.dot(mix, mix)))
            q = np.array(blended)
            p = (1 - alpha) * p_prev + alpha * p
            v = (1 - alpha) * v_prev + alpha * v
            r = (1 - alpha) * r_prev + alpha * r
        q_prev, p_prev, v_prev, r_prev = q, p, v, r
        out_q.append(q), out_p.append(p), out_v.append(v), out_r.append(r)
    return np.array(out_q), np.array(out_p), np.array(out_v), np.array(out_r)


def test_a_python_filter_between_rust_stages():
    if not binary():
        print("skipped: IMUFLOW_BIN is not set (the binary to run graphs with)")
        return
    alpha = 0.3
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "filtered.mcap")
        text = HEAD.format(name="python-filter") + f"""
[stages.smooth]
exec = "{sys.executable}"
args = ["{SMOOTH}"]
inputs = {{ kin = "kin.kinematics" }}
outputs = {{ kinematics = "KinematicsFrame" }}
params = {{ alpha = {alpha} }}
[stages.contact]
kind = "contact"
inputs = {{ kin = "smooth.kinematics", state = "opt.motion", feedback = ["state"] }}
params = {{ method = "pip" }}
[stages.opt]
kind = "optimizer"
inputs = {{ kin = "smooth.kinematics", contacts = "contact.contacts" }}
params = {{ method = "pip" }}
[stages.record]
kind = "recorder"
inputs = {{ raw = "kin.kinematics", smooth = "smooth.kinematics", motion = "opt.motion" }}
params = {{ path = "{out}" }}
"""
        done, leftovers = run_graph(text, d, "python-filter")
        assert done.returncode == 0, done.stderr[-3000:]
        assert not leftovers, leftovers
        rec = imuflow.open_recording(out)
        raw = rec.frames("kin.kinematics")
        smooth = rec.frames("smooth.kinematics")
        motion = rec.frames("opt.motion")
    assert len(raw) == len(smooth) == len(motion) == FRAMES, (len(raw), len(smooth), len(motion))
    assert np.array_equal(smooth["header.seq"], raw["header.seq"])
    assert np.array_equal(smooth["header.capture_ns"], raw["header.capture_ns"])
    # The calibration's CALIBRATING and any INVALID travel through the Python stage.
    assert np.array_equal(smooth["header.flags"], raw["header.flags"])
    assert np.all(smooth["header.publish_ns"] >= raw["header.publish_ns"])
    q, p, v, r = reference_smoothing(raw, alpha)
    assert np.allclose(smooth["local_pose_wxyz"], q, atol=2e-6)
    assert np.allclose(smooth["joint_position_m"], p, atol=2e-6)
    assert np.allclose(smooth["joint_velocity_mps"], v, atol=2e-5)
    assert np.allclose(smooth["root_velocity_mps"], r, atol=2e-6)
    for name in ("foot_contact_prob", "stationary_prob", "gravity_in_root_mps2"):
        assert np.array_equal(smooth[name], raw[name]), name
    # The filter did something (the motion is not constant) and the optimizer after it ran.
    assert np.abs(smooth["joint_position_m"] - raw["joint_position_m"]).max() > 1e-3
    assert np.allclose(np.linalg.norm(motion["local_pose_wxyz"], axis=-1), 1.0, atol=1e-4)
    # The launcher counted the Python stage like any other (its summary line).
    assert "smooth" in done.stdout + done.stderr


def angle_between_deg(q1, q2):
    """Angle of the rotation between unit quaternions (either sign), degrees: from the chord
    |q1 - q2| = 2 sin(angle / 4), which unlike arccos(q1 · q2) keeps its precision near 0."""
    q1, q2 = q1.astype(np.float64), q2.astype(np.float64)
    chord = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return np.degrees(4 * np.arcsin(np.clip(chord / 2, 0, 1)))


def test_pip_in_numpy_matches_the_rust_networks():
    """examples/pip_numpy.py (a kinematics stage: the weight file through numpy LSTMs) beside the
    Rust kinematics stage on identical calibrated input: the same estimate up to float32
    rounding."""
    if not binary():
        print("skipped: IMUFLOW_BIN is not set")
        return
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "ab.mcap")
        text = HEAD.format(name="python-pip").replace(
            'weights = "models/pip.safetensors" }',
            'weights = "models/pip.safetensors", sensor_bones = "network", '
            'limb_joints = "free" }') + f"""
[stages.pynet]
exec = "{sys.executable}"
args = ["{os.path.join(ROOT, 'python', 'examples', 'pip_numpy.py')}"]
inputs = {{ imu = "calib.body_imu" }}
outputs = {{ kinematics = "KinematicsFrame" }}
params = {{ weights = "models/pip.safetensors" }}
[stages.record]
kind = "recorder"
inputs = {{ rust = "kin.kinematics", numpy = "pynet.kinematics" }}
params = {{ path = "{out}" }}
"""
        done, leftovers = run_graph(text, d, "python-pip")
        assert done.returncode == 0, done.stderr[-3000:]
        assert not leftovers, leftovers
        rec = imuflow.open_recording(out)
        rust = rec.frames("kin.kinematics")
        py = rec.frames("pynet.kinematics")
    assert len(rust) == len(py) == FRAMES
    assert np.array_equal(rust["header.flags"], py["header.flags"])
    estimated = (rust["header.flags"] & imuflow.INVALID) == 0
    assert estimated.sum() > 1000, estimated.sum()  # the walk after the T-pose calibration
    angle = angle_between_deg(rust["local_pose_wxyz"], py["local_pose_wxyz"])
    assert angle.max() < 0.005, angle.max()
    for name, tolerance in [("joint_position_m", 1e-4), ("joint_velocity_mps", 1e-3),
                            ("foot_contact_prob", 1e-4), ("root_velocity_mps", 1e-3),
                            ("gravity_in_root_mps2", 1e-4)]:
        error = np.abs(rust[name].astype(np.float64) - py[name]).max()
        assert error < tolerance, (name, error)
    # Not trivially equal: the estimate moves.
    assert np.ptp(rust["joint_position_m"][estimated], axis=0).max() > 0.1


FAILING_STAGE = """
import imuflow
stage = imuflow.Stage.from_env()
out = stage.output("kinematics", "KinematicsFrame")
stage.ready()
for step in stage:
    if step.seq == 100:
        raise RuntimeError("the filter diverged at frame 100")
    out.publish(step, joint_position_m=step["kin"]["joint_position_m"])
stage.finish()
"""


def python_stage_after_kin(name, stage, script, d, output="KinematicsFrame"):
    """The sample through calibration and PIP's networks into the Python stage `stage` running
    `script` (input `kin`, output `kinematics` of type `output`), recorded."""
    return HEAD.format(name=name) + f"""
[stages.{stage}]
exec = "{sys.executable}"
args = ["{script}"]
inputs = {{ kin = "kin.kinematics" }}
outputs = {{ kinematics = "{output}" }}
[stages.record]
kind = "recorder"
inputs = {{ out = "{stage}.kinematics" }}
params = {{ path = "{os.path.join(d, 'out.mcap')}" }}
"""


def test_a_python_stage_that_raises_is_reported_by_name():
    if not binary():
        print("skipped: IMUFLOW_BIN is not set")
        return
    with tempfile.TemporaryDirectory() as d:
        script = os.path.join(d, "diverging.py")
        with open(script, "w") as f:
            f.write(FAILING_STAGE)
        text = python_stage_after_kin("python-raises", "diverging", script, d)
        done, leftovers = run_graph(text, d, "python-raises")
    assert done.returncode != 0
    assert "stage 'diverging' failed" in done.stderr, done.stderr[-2000:]
    # The traceback's last line, as the launcher shows any stage's stderr.
    assert "RuntimeError: the filter diverged at frame 100" in done.stderr, done.stderr[-2000:]
    assert not leftovers, leftovers


def test_a_frame_type_the_graph_does_not_give_is_named():
    if not binary():
        print("skipped: IMUFLOW_BIN is not set")
        return
    with tempfile.TemporaryDirectory() as d:
        # smooth.py writes KinematicsFrame; this graph declares its output a MotionFrame.
        text = python_stage_after_kin("python-wrong-type", "smooth", SMOOTH, d, "MotionFrame")
        done, leftovers = run_graph(text, d, "python-wrong-type")
    assert done.returncode != 0
    assert ("output 'kinematics' carries MotionFrame in the graph but the stage uses "
            "KinematicsFrame") in done.stderr, done.stderr[-2000:]
    assert not leftovers, leftovers


SOURCE_STAGE = """
import imuflow
stage = imuflow.Stage.from_env()
out = stage.output("imu", "ImuFrame")
frames = int(stage.params["frames"])
if stage.ready():
    for seq in range(frames):
        if stage.should_stop:
            break
        frame = out.loan(seq=seq, capture_ns=seq * 16_666_667)
        frame["orientation_wxyz"][:, 0] = 1.0
        frame["specific_force_mps2"][:, 1] = seq
        frame["valid_mask"] = 0b111111
        out.send(frame)
        stage.progress(seq + 1, frames)
stage.finish()
"""

COUNTER_STAGE = """
import imuflow
stage = imuflow.Stage.from_env()
out = stage.output("count", "MotionFrame")
if stage.ready():
    for step in stage:
        previous = step["prev"]
        first = previous["header.flags"] & imuflow.FEEDBACK_INITIAL
        count = 0.0 if first else previous["q"][0] + 1
        out.publish(step, q=[count, step["imu"]["specific_force_mps2"][0, 1]] + [0.0] * 73)
stage.finish()
"""


def test_a_python_source_and_a_python_stage_with_feedback():
    """Sources and feedback inputs in Python: a counter that adds one to its own previous output
    (offline, the feedback input holds exactly the previous frame) counts every frame."""
    if not binary():
        print("skipped: IMUFLOW_BIN is not set")
        return
    frames = 300
    with tempfile.TemporaryDirectory() as d:
        for name, code in [("source.py", SOURCE_STAGE), ("counter.py", COUNTER_STAGE)]:
            with open(os.path.join(d, name), "w") as f:
                f.write(code)
        out = os.path.join(d, "count.mcap")
        text = f"""
name = "python-feedback"
[stages.source]
exec = "{sys.executable}"
args = ["{os.path.join(d, 'source.py')}"]
outputs = {{ imu = "ImuFrame" }}
params = {{ frames = {frames} }}
[stages.counter]
exec = "{sys.executable}"
args = ["{os.path.join(d, 'counter.py')}"]
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "source.imu", count = "counter.count" }}
params = {{ path = "{out}" }}
"""
        done, leftovers = run_graph(text, d, "python-feedback")
        assert done.returncode == 0, done.stderr[-3000:]
        assert not leftovers, leftovers
        rec = imuflow.open_recording(out)
        imu, count = rec.frames("source.imu"), rec.frames("counter.count")
    assert len(imu) == len(count) == frames
    assert np.array_equal(imu["header.seq"], np.arange(frames))
    assert np.array_equal(imu["header.capture_ns"], np.arange(frames) * 16_666_667)
    assert np.array_equal(count["q"][:, 0], np.arange(frames)), count["q"][:5, 0]
    assert np.array_equal(count["q"][:, 1], np.arange(frames))  # the imu it was aligned with
    # The summary counts the Python source's frames like a Rust source's.
    source_row = next(l for l in done.stdout.splitlines() if l.startswith("source "))
    assert f" {frames} " in source_row, source_row


def test_the_waiter_learns_a_periodic_rhythm_and_ignores_late_frames():
    w = stage_module._ArrivalWaiter()
    assert w.expected() is None
    for k in range(20):
        w.arrived(100.0 + 0.010 * k)
    assert abs(w.expected() - 100.200) < 10e-6, w.expected()
    # Frame 20 comes 2 ms late; frame 21 is still due on the schedule, not 2 ms later.
    w.arrived(100.202)
    assert abs(w.expected() - 100.210) < 300e-6, w.expected()
    # A pause does not become the rhythm.
    w.arrived(110.0)
    assert abs(w.expected() - 110.010) < 1e-3, w.expected()


def test_bindings_of_another_iceoryx2_version_are_refused():
    try:
        stage_module._import_bindings({"iceoryx2": "0.9.1"})
    except imuflow.StageError as e:
        assert "0.9.1" in str(e) and "pip install 'iceoryx2==0.9.*'" in str(e), e
    else:
        raise AssertionError("bindings of iceoryx2 0.10 accepted for a launcher on 0.9")


def test_started_by_hand_is_a_clear_error():
    saved = {k: os.environ.pop(k) for k in (stage_module.ENV_RUN_DIR,) if k in os.environ}
    try:
        imuflow.Stage.from_env()
    except imuflow.StageError as e:
        assert "IMUFLOW_RUN_DIR is not set" in str(e) and "imuflow run" in str(e), e
    else:
        raise AssertionError("a stage started outside a run")
    finally:
        os.environ.update(saved)


if __name__ == "__main__":
    tests = [v for k, v in sorted(globals().items()) if k.startswith("test_")]
    for test in tests:
        test()
        print(f"ok {test.__name__}")
