"""imuflow.recording against the bundled sample (models/sample/walk.mcap) and files made from it.

Run: `python python/tests/test_recording.py` (or pytest) with numpy and mcap installed; .ci/run
runs it in the verify venv. Expectations are independent of the decoder: frame counts from
models/sample/README.md, properties that hold only if every field is read at the right offset
(unit quaternions, gravity's magnitude in the accelerometers of a person standing still, seq
counting up), and a file cut short reading as a prefix of the whole. The export through the
`imuflow` binary is read back here by a reader of its own (the glb's chunks and accessors, the
npz's arrays) and compared with the recording's poses; it is skipped, saying so, when no binary is
found (IMUFLOW_BIN, PATH, target/release or target/debug).
"""
import json
import os
import struct
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
import imuflow  # noqa: E402

SAMPLE = os.path.join(HERE, "..", "..", "models", "sample", "walk.mcap")
FRAMES = 1511  # models/sample/README.md


def motion_topic(rec):
    return next(t for t, ty in rec.topics.items() if ty.startswith("imuflow.MotionFrame"))


def test_the_sample_decodes_through_its_stored_layouts():
    rec = imuflow.open_recording(SAMPLE)
    imu_topic = next(t for t, ty in rec.topics.items() if ty.startswith("imuflow.ImuFrame"))
    imu = rec.frames(imu_topic)
    assert len(imu) == FRAMES, len(imu)
    seq = imu["header.seq"]
    assert np.all(np.diff(seq.astype(np.int64)) == 1), "seq counts up by one"
    q = imu["orientation_wxyz"]
    assert q.shape == (FRAMES, 6, 4)
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-4), "unit quaternions"
    # The sample starts with a held T-pose: on average over its first second the accelerometers
    # measure gravity alone (each sample carries the reference sensor noise, ~0.1-0.2 m/s²).
    force = np.linalg.norm(imu["specific_force_mps2"][:60], axis=-1).mean(axis=0)
    assert np.all(np.abs(force - 9.81) < 0.05), force
    seq_t, rotations, root = rec.poses(motion_topic(rec))
    assert rotations.shape == (len(seq_t), 24, 4) and root.shape == (len(seq_t), 3)
    assert np.allclose(np.linalg.norm(rotations, axis=-1), 1.0, atol=1e-4)
    assert np.all((root[:, 1] > 0.7) & (root[:, 1] < 1.2)), "the pelvis stands about 0.9 m up"


def test_a_recording_cut_short_reads_up_to_the_cut():
    whole = open(SAMPLE, "rb").read()
    rec = imuflow.open_recording(SAMPLE)
    topic = motion_topic(rec)
    full = rec.frames(topic)
    with tempfile.TemporaryDirectory() as d:
        cut = os.path.join(d, "cut.mcap")
        with open(cut, "wb") as f:
            f.write(whole[: len(whole) * 2 // 3])
        part = imuflow.open_recording(cut).frames(topic)
    assert 0 < len(part) < len(full), (len(part), len(full))
    assert part.tobytes() == full[: len(part)].tobytes()


def test_bad_input_is_a_named_error():
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "notes.mcap")
        with open(path, "w") as f:
            f.write("not a recording\n")
        try:
            imuflow.open_recording(path)
        except imuflow.RecordingError as e:
            assert "notes.mcap" in str(e), e
        else:
            raise AssertionError("a text file opened as a recording")
    rec = imuflow.open_recording(SAMPLE)
    try:
        rec.frames("no.such.topic")
    except imuflow.RecordingError as e:
        assert "no.such.topic" in str(e) and "it has" in str(e), e
    else:
        raise AssertionError("an unknown topic decoded")


def test_layouts_cover_each_frame():
    """Every layout the binary prints (`imuflow stage --layouts`, when IMUFLOW_BIN names it) becomes
    a dtype of the frame's size whose fields do not overlap."""
    binary = os.environ.get("IMUFLOW_BIN")
    if not binary:
        return
    import json
    import subprocess
    layouts = json.loads(subprocess.run([binary, "stage", "--layouts"], check=True,
                                        capture_output=True, text=True).stdout)
    assert len(layouts) >= 6
    for layout in layouts:
        dtype = imuflow.dtype_from_layout(layout)
        assert dtype.itemsize == layout["size"]
        spans = sorted((dtype.fields[n][1], dtype.fields[n][1] + dtype.fields[n][0].itemsize)
                       for n in dtype.names)
        covered = sum(b - a for a, b in spans)
        assert covered == layout["size"], (layout["type_name"], covered)
        assert all(b1 <= a2 for (_, b1), (a2, _) in zip(spans, spans[1:])), layout["type_name"]


class Skipped(Exception):
    """A test that cannot run here, run as a script."""


def skip(reason):
    """pytest's skip under pytest; as a script, the runner below says it skipped and why."""
    if "pytest" in sys.modules:
        import pytest
        pytest.skip(reason)
    raise Skipped(reason)


def exported_truth(rec, topic):
    """The truth frames an export keeps: those not flagged PRELUDE, CALIBRATING or INVALID."""
    frames = rec.frames(topic)
    left_out = imuflow.PRELUDE | imuflow.CALIBRATING | imuflow.INVALID
    keep = (frames["header.flags"] & left_out) == 0
    return frames["local_pose_wxyz"][keep], frames["root_position_m"][keep]


def read_glb(path):
    """(the JSON document, the BIN chunk) of a .glb, read by glTF 2.0's "Binary glTF Layout"."""
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data)), (magic, version, length)
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON"
    doc = json.loads(data[20:20 + json_len])
    bin_len, bin_type = struct.unpack_from("<I4s", data, 20 + json_len)
    assert bin_type == b"BIN\0"
    return doc, data[28 + json_len:28 + json_len + bin_len]


def accessor_array(doc, blob, index):
    """A float accessor as an (count, width) array."""
    accessor = doc["accessors"][index]
    assert accessor["componentType"] == 5126, "FLOAT"
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[accessor["type"]]
    view = doc["bufferViews"][accessor["bufferView"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    values = np.frombuffer(blob, dtype="<f4", count=accessor["count"] * width, offset=start)
    return values.reshape(accessor["count"], width)


def test_export_runs_the_binary_and_reads_back_as_the_recording():
    try:
        imuflow.recording.find_binary()
    except imuflow.recording.ExportError as e:
        skip(f"no export through the binary: {e}")
    rec = imuflow.open_recording(SAMPLE)
    topic = motion_topic(rec)
    rotations, root = exported_truth(rec, topic)
    with tempfile.TemporaryDirectory() as d:
        glb = rec.export(topic, os.path.join(d, "walk.glb"))
        doc, blob = read_glb(glb)
        names = [n.get("name") for n in doc["nodes"][:24]]
        assert names[0] == "pelvis" and names[4] == "left_knee", names
        (animation,) = doc["animations"]
        assert len(animation["samplers"]) == 25 and len(animation["channels"]) == 25
        times = accessor_array(doc, blob, animation["samplers"][0]["input"])[:, 0]
        assert len(times) == len(rotations), (len(times), len(rotations))
        assert np.allclose(times, np.arange(len(times)) / 60.0, atol=1e-5)
        for channel in animation["channels"]:
            node, path = channel["target"]["node"], channel["target"]["path"]
            sampler = animation["samplers"][channel["sampler"]]
            assert sampler["interpolation"] == "LINEAR"
            values = accessor_array(doc, blob, sampler["output"])
            if path == "translation":
                assert node == 0 and np.allclose(values, root, atol=1e-6)
                continue
            assert path == "rotation"
            xyzw = rotations[:, node][:, [1, 2, 3, 0]]
            sign = np.sign(np.sum(values * xyzw, axis=1, keepdims=True))
            assert np.allclose(values, sign * xyzw, atol=1e-6), names[node]

        # The format from the extension or named; the module function as the method.
        npz = imuflow.recording.export(SAMPLE, topic, os.path.join(d, "walk.data"), format="npz")
        amass = np.load(npz)
        assert amass["poses"].shape == (len(rotations), 72) and float(amass["mocap_framerate"]) == 60.0
        # AMASS's trans is Z-up, (x, y, z) of the model frame as (x, -z, y), less a constant (SMPL's
        # root joint): the root's displacements carry over turned so.
        moved = amass["trans"] - amass["trans"][0]
        want = (root - root[0])[:, [0, 2, 1]] * [1, -1, 1]
        assert np.allclose(moved, want, atol=1e-6), np.abs(moved - want).max()
        bvh = rec.export(topic, os.path.join(d, "walk.bvh"), unit="cm", stature_m=1.6)
        assert open(bvh).read().startswith("HIERARCHY")

        # The binary's refusal, named; nothing written.
        bad = os.path.join(d, "bad.glb")
        try:
            rec.export("no.such.channel", bad)
        except imuflow.recording.ExportError as e:
            assert "walk.mcap" in str(e) and "no.such.channel" in str(e), e
        else:
            raise AssertionError("an unknown channel exported")
        assert not os.path.exists(bad)


def test_a_sensor_sets_estimate_exports_the_joints_it_observes_or_all_when_asked():
    try:
        binary = imuflow.recording.find_binary()
    except imuflow.recording.ExportError as e:
        skip(f"no export through the binary: {e}")
    import subprocess
    root = os.path.join(HERE, "..", "..")
    with tempfile.TemporaryDirectory() as d:
        mcap = os.path.join(d, "legs.mcap")
        run = subprocess.run(
            [binary, "run", "configs/examples/lower-body.toml", "--no-progress", "--quiet",
             "--set", f"stages.record.params.path={mcap}", "--without", "viz"],
            cwd=root, capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        rec = imuflow.open_recording(mcap)

        def joints(**options):
            bvh = rec.export("opt.motion", os.path.join(d, "legs.bvh"), **options)
            with open(bvh) as f:
                return [line.split()[1] for line in f if line.split()[:1] in (["ROOT"], ["JOINT"])]

        assert joints() == ["pelvis", "left_hip", "left_knee", "right_hip", "right_knee"], joints()
        assert len(joints(all_joints=True)) == 24


def test_export_says_what_it_lacks():
    try:
        imuflow.recording.export(SAMPLE, "source.truth", "walk.fbx")
    except imuflow.recording.ExportError as e:
        assert "walk.fbx" in str(e) and "bvh, glb, npz" in str(e), e
    else:
        raise AssertionError("an unknown extension exported")
    saved = os.environ.get("IMUFLOW_BIN")
    os.environ["IMUFLOW_BIN"] = os.path.join(HERE, "no-such-imuflow")
    try:
        imuflow.recording.export(SAMPLE, "source.truth", "walk.glb")
    except imuflow.recording.ExportError as e:
        assert "IMUFLOW_BIN" in str(e) and "no-such-imuflow" in str(e), e
    else:
        raise AssertionError("exported without a binary")
    finally:
        if saved is None:
            del os.environ["IMUFLOW_BIN"]
        else:
            os.environ["IMUFLOW_BIN"] = saved


if __name__ == "__main__":
    tests = [v for k, v in sorted(globals().items()) if k.startswith("test_")]
    for test in tests:
        try:
            test()
        except Skipped as e:
            print(f"skip {test.__name__}: {e}")
            continue
        print(f"ok {test.__name__}")
