"""imuflow from Python.

`imuflow.recording`: a recorder's mcap file as numpy structured arrays, decoded through the frame
layouts the file itself stores (no offsets are hard-coded here), plus the pose streams as plain
(N, 24, 4) / (N, 3) arrays for analysis.

`imuflow.layout`: numpy dtypes from imuflow's frame layouts (the JSON that `imuflow stage
--layouts` prints and every recording stores as its channels' schemas).
"""

from .layout import dtype_from_layout, flatten_fields
from .recording import Recording, RecordingError, open_recording

__all__ = [
    "Recording",
    "RecordingError",
    "dtype_from_layout",
    "flatten_fields",
    "open_recording",
]
