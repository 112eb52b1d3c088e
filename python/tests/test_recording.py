"""imuflow.recording against the bundled sample (models/sample/walk.mcap) and files made from it.

Run: `python python/tests/test_recording.py` (or pytest) with numpy and mcap installed; .ci/run
runs it in the verify venv. Expectations are independent of the decoder: frame counts from
models/sample/README.md, properties that hold only if every field is read at the right offset
(unit quaternions, gravity's magnitude in the accelerometers of a person standing still, seq
counting up), and a file cut short reading as a prefix of the whole.
"""
import os
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


if __name__ == "__main__":
    tests = [v for k, v in sorted(globals().items()) if k.startswith("test_")]
    for test in tests:
        test()
        print(f"ok {test.__name__}")
