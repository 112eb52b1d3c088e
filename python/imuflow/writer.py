"""Writing imuflow recordings from Python: mcap files as the recorder stage writes them.

What the Rust readers (`Recording::load`: the imu-source stage's `replay` mode, `imuflow compare
--input`, `imuflow export`) and `imuflow.open_recording` expect, as stages/recorder writes it:

- header profile `imuflow`;
- per stream one channel, topic `stage.port` (`source.imu`), message encoding `imuflow-raw` (the
  frame's little-endian bytes), channel metadata `input`, `frame` (struct name) and `frame_size`;
- its schema named after the versioned frame type (`imuflow.ImuFrame.v2`), schema encoding
  `imuflow-layout`, data the layout as pretty-printed JSON;
- one metadata record `imuflow` whose `rate_hz` the readers take as the recording's rate;
- messages with sequence = `header.seq`, log time = `header.capture_ns`, publish time =
  `header.publish_ns`; zstd chunks.

The layouts come with the package (`layouts.json`: the ImuFrame and MotionFrame entries of
`imuflow stage --layouts`, checked against the binary by tests/test_datasets.py), so writing needs
no imuflow binary.
"""

import json
import os

import numpy as np
from mcap.writer import CompressionType, Writer

from .layout import dtype_from_layout
from .recording import LAYOUT_ENCODING, RAW_ENCODING

LAYOUTS_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "layouts.json")


def packaged_layout(struct_name):
    """The layout of frame type `struct_name` (`ImuFrame`, `MotionFrame`) this package ships."""
    with open(LAYOUTS_FILE, encoding="utf-8") as f:
        layouts = json.load(f)
    for layout in layouts:
        if layout["struct_name"] == struct_name:
            return layout
    raise KeyError(f"{LAYOUTS_FILE} has no layout of {struct_name} "
                   f"(it has {[l['struct_name'] for l in layouts]})")


def empty_frames(layout, n):
    """`n` zeroed frames of `layout` as a structured array (fields named as in the layout)."""
    return np.zeros(n, dtype=dtype_from_layout(layout))


class Stream:
    """One channel to write: its topic (`source.imu`), the input name the recorder would have
    given it (`imu`), its frames' layout and the frames (a structured array of that layout)."""

    def __init__(self, topic, input_name, layout, frames):
        if frames.dtype != dtype_from_layout(layout):
            raise ValueError(f"{topic}: the frames are not {layout['type_name']} frames")
        self.topic, self.input_name, self.layout, self.frames = topic, input_name, layout, frames


def write_recording(path, streams, metadata):
    """Writes `streams` into the mcap file `path`, frame k of every stream before frame k + 1 of
    any (the order a recorder sees a source's outputs in), with `metadata` (str → str, `rate_hz`
    included) as the `imuflow` metadata record.

    The file is written beside `path` and renamed into place when complete, so a failure leaves
    no partial recording behind."""
    path = str(path)
    folder = os.path.dirname(path)
    if folder:
        os.makedirs(folder, exist_ok=True)
    partial = path + ".partial"
    try:
        with open(partial, "wb") as f:
            _write(f, streams, metadata)
        os.replace(partial, path)
    except BaseException:
        if os.path.exists(partial):
            os.remove(partial)
        raise


def _write(f, streams, metadata):
    writer = Writer(f, compression=CompressionType.ZSTD)
    writer.start(profile="imuflow", library=f"imuflow-python {_version()}")
    schemas, channels = {}, []
    for s in streams:
        name = s.layout["type_name"]
        if name not in schemas:
            data = json.dumps(s.layout, indent=2, ensure_ascii=False).encode("utf-8")
            schemas[name] = writer.register_schema(name=name, encoding=LAYOUT_ENCODING, data=data)
        meta = {"input": s.input_name, "frame": s.layout["struct_name"],
                "frame_size": str(s.layout["size"])}
        channels.append(writer.register_channel(topic=s.topic, message_encoding=RAW_ENCODING,
                                                schema_id=schemas[name], metadata=meta))
    writer.add_metadata("imuflow", {str(k): str(v) for k, v in metadata.items()})
    longest = max((len(s.frames) for s in streams), default=0)
    for k in range(longest):
        for s, channel in zip(streams, channels):
            if k < len(s.frames):
                frame = s.frames[k : k + 1]
                writer.add_message(channel_id=channel,
                                   log_time=int(frame["header.capture_ns"][0]),
                                   publish_time=int(frame["header.publish_ns"][0]),
                                   sequence=int(frame["header.seq"][0]) & 0xFFFFFFFF,
                                   data=frame.tobytes())
    writer.finish()


def _version():
    try:
        from importlib.metadata import version
        return version("imuflow")
    except Exception:  # not installed: run from the source tree
        return "source"
