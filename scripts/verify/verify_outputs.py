#!/usr/bin/env python3
"""Independent check of what an imuflow run wrote: an .rrd from the rerun-logger and an .mcap
from the recorder, both fed by an ImuFrame edge named `imu` at the logger.

Reads the .rrd with the official rerun SDK (rerun-sdk[datafusion]==0.36.3, RrdReader) and the
.mcap with the official Python `mcap` reader, and checks channels, message counts, frame sequence
numbers (decoded through the layout schema the recorder writes), timelines and entities against
what the graph should produce. Exits non-zero with a message on any mismatch.

usage: verify_outputs.py RRD MCAP TOPIC=COUNT [TOPIC=COUNT ...] [+COLUMN ...]
  e.g. verify_outputs.py out/smoke.rrd out/smoke.mcap source.imu=600 source.imu/json=600
  +COLUMN: an .rrd column that must exist, e.g. +/motion/skeleton/joints:Points3D:positions.
  Without any, the IMU columns of a logger input named `imu` are required.
"""
import json
import struct
import sys

from mcap.reader import make_reader
import rerun.experimental as rx

SENSORS = ["left_forearm", "right_forearm", "left_lower_leg", "right_lower_leg", "head", "pelvis"]


def fail(msg):
    print(f"verify_outputs: FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def check_mcap(path, want):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            fail(f"{path}: no summary/statistics (file not finalized)")
        topics = {ch.id: ch.topic for ch in summary.channels.values()}
        counts = {topics[cid]: n for cid, n in summary.statistics.channel_message_counts.items()}
        if counts != want:
            fail(f"{path}: channel message counts {counts}, expected {want}")
        schemas = {s.id: s for s in summary.schemas.values()}
        layouts = {}
        for ch in summary.channels.values():
            schema = schemas[ch.schema_id]
            if ch.message_encoding == "imuflow-raw":
                if schema.encoding != "imuflow-layout":
                    fail(f"{path}: raw channel {ch.topic} has schema encoding {schema.encoding}")
                layout = json.loads(schema.data)
                if layout["type_name"] != schema.name:
                    fail(f"{path}: {ch.topic}: layout {layout['type_name']} under schema {schema.name}")
                layouts[ch.topic] = layout
        seqs = {topic: [] for topic in counts}
        for _schema, channel, message in reader.iter_messages():
            layout = layouts.get(channel.topic)
            if layout is None:
                seqs[channel.topic].append(json.loads(message.data)["header"]["seq"])
                continue
            if len(message.data) != layout["size"]:
                fail(f"{path}: {channel.topic}: message of {len(message.data)} bytes, layout says {layout['size']}")
            offset = next(fl["offset"] for fl in layout["fields"] if fl["name"] == "header.seq")
            seqs[channel.topic].append(struct.unpack_from("<Q", message.data, offset)[0])
        for topic, got in seqs.items():
            if sorted(got) != list(range(want[topic])):
                fail(f"{path}: {topic}: frame sequence numbers are not 0..{want[topic] - 1}")
    print(f"verify_outputs: {path}: OK ({', '.join(f'{t}: {n}' for t, n in sorted(want.items()))}; layouts decoded)")


def imu_columns():
    columns = []
    for sensor in SENSORS:
        columns += [f"/imu/{sensor}/orientation:Transform3D:quaternion",
                    f"/plots/imu/{sensor}/specific_force_mps2:Scalars:scalars"]
    return columns


def check_rrd(path, columns):
    reader = rx.RrdReader(path)
    recordings = reader.recordings()
    if not recordings or recordings[0].application_id != "imuflow":
        fail(f"{path}: no imuflow recording ({recordings})")
    schema = str(reader.store().schema())
    for timeline in ["seq", "capture_time"]:
        if f"Index(timeline:{timeline})" not in schema:
            fail(f"{path}: timeline '{timeline}' missing")
    for column in columns:
        if column not in schema:
            fail(f"{path}: column {column} missing")
    print(f"verify_outputs: {path}: OK (rerun SDK {rx.__name__} read {len(recordings)} recording)")


if __name__ == "__main__":
    topics = [a for a in sys.argv[3:] if not a.startswith("+")]
    columns = [a[1:] for a in sys.argv[3:] if a.startswith("+")]
    if len(sys.argv) < 4 or not topics or any("=" not in a for a in topics):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    expected = {t: int(n) for t, n in (a.rsplit("=", 1) for a in topics)}
    check_rrd(sys.argv[1], columns or imu_columns())
    check_mcap(sys.argv[2], expected)
