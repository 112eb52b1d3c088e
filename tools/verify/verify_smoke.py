#!/usr/bin/env python3
"""Independent check of what `imuflow run configs/examples/smoke.toml` writes.

Reads the .rrd with the official rerun SDK (rerun-sdk[datafusion]==0.36.3, RrdReader) and the
.mcap with the official Python `mcap` reader, and checks channels, message counts, timelines and
entities against what the graph should produce. Exits non-zero with a message on any mismatch.

usage: verify_smoke.py RRD MCAP FRAMES
"""
import json
import struct
import sys

from mcap.reader import make_reader
import rerun.experimental as rx

SENSORS = ["left_forearm", "right_forearm", "left_lower_leg", "right_lower_leg", "head", "pelvis"]


def fail(msg):
    print(f"verify_smoke: FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def check_mcap(path, frames):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            fail(f"{path}: no summary/statistics (file not finalized)")
        topics = {ch.id: ch.topic for ch in summary.channels.values()}
        counts = {topics[cid]: n for cid, n in summary.statistics.channel_message_counts.items()}
        want = {"source.imu": frames, "source.imu/json": frames}
        if counts != want:
            fail(f"{path}: channel message counts {counts}, expected {want}")
        schemas = {s.id: s for s in summary.schemas.values()}
        raw = next(ch for ch in summary.channels.values() if ch.topic == "source.imu")
        layout = json.loads(schemas[raw.schema_id].data)
        if schemas[raw.schema_id].encoding != "imuflow-layout" or layout["type_name"] != "imuflow.ImuFrame.v1":
            fail(f"{path}: raw channel schema is not the ImuFrame layout")
        seq_field = next(fl for fl in layout["fields"] if fl["name"] == "header.seq")
        seqs, json_seqs = [], []
        for _schema, channel, message in reader.iter_messages():
            if channel.topic == "source.imu":
                if len(message.data) != layout["size"]:
                    fail(f"{path}: raw message of {len(message.data)} bytes, layout says {layout['size']}")
                seqs.append(struct.unpack_from("<Q", message.data, seq_field["offset"])[0])
            else:
                json_seqs.append(json.loads(message.data)["header"]["seq"])
        if seqs != list(range(frames)) or sorted(json_seqs) != list(range(frames)):
            fail(f"{path}: frame sequence numbers are not 0..{frames - 1}")
    print(f"verify_smoke: {path}: OK ({frames} raw + {frames} JSON messages, layout decoded)")


def check_rrd(path):
    reader = rx.RrdReader(path)
    recordings = reader.recordings()
    if not recordings or recordings[0].application_id != "imuflow":
        fail(f"{path}: no imuflow recording ({recordings})")
    schema = str(reader.store().schema())
    for timeline in ["seq", "capture_time"]:
        if f"Index(timeline:{timeline})" not in schema:
            fail(f"{path}: timeline '{timeline}' missing")
    for sensor in SENSORS:
        for column in [f"/imu/{sensor}/orientation:Transform3D:quaternion",
                       f"/plots/imu/{sensor}/specific_force_mps2:Scalars:scalars"]:
            if column not in schema:
                fail(f"{path}: column {column} missing")
    print(f"verify_smoke: {path}: OK (rerun SDK {rx.__name__} read {len(recordings)} recording)")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    check_rrd(sys.argv[1])
    check_mcap(sys.argv[2], int(sys.argv[3]))
