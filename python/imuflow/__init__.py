"""imuflow from Python.

`imuflow.Stage`: a stage written in Python (`exec = "python3"` in a graph), speaking the same
protocol over the same iceoryx2 services as the Rust stages; frames are numpy views of shared
memory (see `imuflow.stage`). Needs the `iceoryx2` bindings of the launcher's iceoryx2 version.

`imuflow.recording`: a recorder's mcap file as numpy structured arrays, decoded through the frame
layouts the file itself stores (no offsets are hard-coded here), plus the pose streams as plain
(N, 24, 4) / (N, 3) arrays for analysis.

`imuflow.layout`: numpy dtypes from imuflow's frame layouts (the JSON that `imuflow stage
--layouts` prints, every recording stores as its channels' schemas, and each run writes for its
stages).
"""

from .layout import dtype_from_layout, flatten_fields
from .recording import Recording, RecordingError, open_recording
from .stage import (
    CALIBRATING,
    DEGRADED,
    END_OF_STREAM,
    FEEDBACK_INITIAL,
    INVALID,
    PRELUDE,
    RESTARTED,
    Output,
    Stage,
    StageError,
    Step,
)

__all__ = [
    "CALIBRATING",
    "DEGRADED",
    "END_OF_STREAM",
    "FEEDBACK_INITIAL",
    "INVALID",
    "PRELUDE",
    "RESTARTED",
    "Output",
    "Recording",
    "RecordingError",
    "Stage",
    "StageError",
    "Step",
    "dtype_from_layout",
    "flatten_fields",
    "open_recording",
]
