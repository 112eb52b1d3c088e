"""A recorder's mcap file as numpy arrays.

    import imuflow
    rec = imuflow.open_recording("out/sample.mcap")
    rec.topics                       # {'source.imu': 'imuflow.ImuFrame.v2', 'opt.motion': ..., ...}
    imu = rec.frames("source.imu")   # structured array, one record per frame, fields by name
    imu["header.seq"], imu["specific_force_mps2"]            # (N,), (N, 6, 3)
    seq, rotations, root = rec.poses("opt.motion")         # (N,), (N, 24, 4) wxyz, (N, 3) m
    df = rec.dataframe("opt.contacts")                       # with pandas installed
    rec.export("opt.motion", "out/walk.glb")                 # via the `imuflow export` binary

Each raw channel's frames are decoded through the layout stored with it (its schema, encoding
`imuflow-layout`), so a recording made by another imuflow version reads correctly as long as its
layouts say what it holds. A file whose recorder was killed reads up to its last complete message.
"""

import json
import os
import shutil
import subprocess

import numpy as np
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.exceptions import McapError

from .layout import LayoutError, dtype_from_layout

RAW_ENCODING = "imuflow-raw"
LAYOUT_ENCODING = "imuflow-layout"


class RecordingError(Exception):
    """A file that is not a readable imuflow recording, or a topic it does not have."""


class ExportError(RecordingError):
    """`imuflow export` refused (its message names the file and channel) or could not be run."""


EXPORT_FORMATS = ("bvh", "glb", "npz")


class Recording:
    """The raw channels of one recorder mcap file, read once into memory."""

    def __init__(self, path):
        self.path = str(path)
        self._layouts = {}  # topic -> layout dict
        self._raw = {}  # topic -> list of bytes
        try:
            with open(self.path, "rb") as f:
                for schema, channel, message in _messages(f):
                    if channel.message_encoding != RAW_ENCODING:
                        continue
                    if channel.topic not in self._layouts:
                        self._layouts[channel.topic] = _layout_of(schema, channel.topic, self.path)
                    self._raw.setdefault(channel.topic, []).append(message.data)
        except OSError as e:
            raise RecordingError(f"{self.path}: {e}") from None
        except McapError as e:
            raise RecordingError(f"{self.path}: not a readable mcap file: {e}") from None
        if not self._layouts:
            raise RecordingError(f"{self.path}: no imuflow raw channels (is it a recorder's output?)")

    @property
    def topics(self):
        """Topic → frame type name, for every raw channel with messages."""
        return {t: layout["type_name"] for t, layout in self._layouts.items()}

    def layout(self, topic):
        """The stored layout of `topic` (a dict: type_name, size, fields)."""
        return self._layouts[self._topic(topic)]

    def frames(self, topic):
        """Every frame of `topic` as a structured array (fields named as in the layout)."""
        topic = self._topic(topic)
        layout = self._layouts[topic]
        try:
            dtype = dtype_from_layout(layout)
        except LayoutError as e:
            raise RecordingError(f"{self.path}: topic {topic!r}: {e}") from None
        messages = self._raw[topic]
        for i, data in enumerate(messages):
            if len(data) != dtype.itemsize:
                raise RecordingError(f"{self.path}: topic {topic!r}: message {i} has {len(data)} bytes, "
                                     f"its layout {layout['type_name']} says {dtype.itemsize}")
        return np.frombuffer(b"".join(messages), dtype=dtype)

    def poses(self, topic):
        """A MotionFrame topic (a truth, an estimate, a simulated body) as (seq (N,), local
        rotations (N, 24, 4) unit quaternions w, x, y, z relative to each joint's parent, root
        position (N, 3) in m, y up)."""
        frames = self.frames(topic)
        names = frames.dtype.names
        if "local_pose_wxyz" not in names or "root_position_m" not in names:
            raise RecordingError(f"{self.path}: topic {topic!r} holds {self.topics[topic]}, not MotionFrames")
        return (frames["header.seq"].copy(), frames["local_pose_wxyz"].copy(),
                frames["root_position_m"].copy())

    def dataframe(self, topic):
        """`topic` as a pandas DataFrame: one column per scalar (arrays spread as `name[i][j]`)."""
        try:
            import pandas as pd
        except ImportError:
            raise RecordingError("dataframe() needs pandas (pip install 'imuflow[pandas]')") from None
        frames = self.frames(topic)
        columns = {}
        for name in frames.dtype.names:
            values = frames[name]
            if values.ndim == 1:
                columns[name] = values
                continue
            for index in np.ndindex(values.shape[1:]):
                columns[name + "".join(f"[{i}]" for i in index)] = values[(slice(None),) + index]
        return pd.DataFrame(columns)

    def export(self, channel, out, format=None, **options):
        """Writes MotionFrame channel `channel` to `out` with `imuflow export` (see `export`)."""
        return export(self.path, channel, out, format=format, **options)

    def _topic(self, topic):
        if topic not in self._layouts:
            raise RecordingError(f"{self.path}: no topic {topic!r} (it has {sorted(self._layouts)})")
        return topic


def open_recording(path):
    """Reads a recorder's mcap file (see `Recording`)."""
    return Recording(path)


def export(path, channel, out, format=None, keep_all=False, unit=None, stature_m=None,
           all_joints=False):
    """Exports MotionFrame channel `channel` of recording `path` to the file `out` by running
    `imuflow export` (the formats are the binary's: bvh, glb, npz; `format=None` takes it from
    `out`'s extension). `keep_all`, `unit` ("m" or "cm", BVH), `stature_m` (BVH, glb) and
    `all_joints` (every joint also for a sensor set's estimate that leaves some at rest) are the
    command's options. Returns `out`. Raises `ExportError` with the binary's message (which names
    the file and channel) when it refuses; nothing is written then."""
    out = str(out)
    if format is None:
        format = os.path.splitext(out)[1].lstrip(".").lower()
        if format not in EXPORT_FORMATS:
            raise ExportError(f"{out}: no format given and the extension is not one of {', '.join(EXPORT_FORMATS)}")
    elif format not in EXPORT_FORMATS:
        raise ExportError(f"format {format!r} is not one of {', '.join(EXPORT_FORMATS)}")
    command = [find_binary(), "export", str(path), "--channel", channel, "--format", format, "-o", out]
    if keep_all:
        command.append("--keep-all")
    if unit is not None:
        command += ["--unit", unit]
    if stature_m is not None:
        command += ["--stature-m", str(stature_m)]
    if all_joints:
        command.append("--all-joints")
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        message = done.stderr.strip().removeprefix("error: ") or f"exit status {done.returncode}"
        raise ExportError(message)
    return out


def find_binary():
    """The `imuflow` binary that `export` runs: $IMUFLOW_BIN, else `imuflow` on PATH, else the
    repository's own build (target/release, then target/debug) when this package runs from it."""
    named = os.environ.get("IMUFLOW_BIN")
    if named:
        if not (os.path.isfile(named) and os.access(named, os.X_OK)):
            raise ExportError(f"IMUFLOW_BIN={named!r} is not an executable file")
        return named
    on_path = shutil.which("imuflow")
    if on_path:
        return on_path
    repo = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
    for profile in ("release", "debug"):
        built = os.path.normpath(os.path.join(repo, "target", profile, "imuflow"))
        if os.path.isfile(built) and os.access(built, os.X_OK):
            return built
    raise ExportError("no imuflow binary: set IMUFLOW_BIN to its path, put `imuflow` on PATH, "
                      "or build it in the repository (cargo build --release)")


def _messages(stream):
    """(schema, channel, message) in file order, chunks decompressed; a file cut short (a killed
    recorder) yields every message before the cut, a file that is no mcap at all raises."""
    schemas, channels = {}, {}
    records = StreamReader(stream, skip_magic=False, validate_crcs=True).records
    seen = 0
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except McapError:
            if seen:
                return  # the cut: everything before it is read
            raise
        seen += 1
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            yield schemas.get(channel.schema_id), channel, record


def _layout_of(schema, topic, path):
    if schema is None or schema.encoding != LAYOUT_ENCODING:
        raise RecordingError(f"{path}: topic {topic!r} has no {LAYOUT_ENCODING} schema")
    try:
        return json.loads(schema.data)
    except ValueError as e:
        raise RecordingError(f"{path}: topic {topic!r}: its layout is not JSON: {e}") from None
