"""numpy dtypes from imuflow frame layouts.

A layout is the JSON object `imuflow stage --layouts` prints for each frame type and a recorder
stores as the schema of each raw channel (schema encoding `imuflow-layout`):

    {"type_name": "imuflow.MotionFrame.v1", "size": 1728,
     "fields": [{"name": "header.seq", "offset": 0, "type": "u64", "shape": [], "doc": ...}, ...]}

Fields are little-endian scalars at byte offsets, arrays in C order. The dtype built here has one
entry per field, named as in the layout (`header.seq`, `local_pose_wxyz`, ...), at the layout's
offsets and with its itemsize, so `numpy.frombuffer(raw_bytes, dtype)` views frames in place.
"""

import numpy as np

SCALARS = {"u8": "<u1", "u16": "<u2", "u32": "<u4", "u64": "<u8", "i32": "<i4", "i64": "<i8",
           "f32": "<f4", "f64": "<f8"}


class LayoutError(ValueError):
    """A layout that does not describe a frame (unknown scalar type, field outside the frame)."""


def dtype_from_layout(layout):
    """The numpy structured dtype of one frame layout (a dict as in the module doc)."""
    try:
        size = int(layout["size"])
        fields = layout["fields"]
        name = layout.get("type_name", "?")
    except (KeyError, TypeError, ValueError) as e:
        raise LayoutError(f"not a frame layout: {e}") from None
    names, formats, offsets = [], [], []
    for field in fields:
        scalar = SCALARS.get(field.get("type"))
        if scalar is None:
            raise LayoutError(f"{name}: field {field.get('name')!r} has unknown type {field.get('type')!r}")
        shape = tuple(int(n) for n in field.get("shape", []))
        fmt = np.dtype((scalar, shape)) if shape else np.dtype(scalar)
        offset = int(field["offset"])
        if offset < 0 or offset + fmt.itemsize > size:
            raise LayoutError(f"{name}: field {field['name']!r} ({fmt.itemsize} bytes at {offset}) "
                              f"is outside the {size}-byte frame")
        names.append(field["name"])
        formats.append(fmt)
        offsets.append(offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})


def flatten_fields(array):
    """A dict of plain arrays, one per field (`header.seq` → (N,), `local_pose_wxyz` → (N, 24, 4)),
    for code that prefers columns to records."""
    return {name: array[name] for name in array.dtype.names}
