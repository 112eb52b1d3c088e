//! imuflow-graph: the dataflow layer every imuflow stage stands on.
//!
//! - [`frames`]: the wire contract (frame types shared over iceoryx2 without copying).
//! - [`schema`], [`validate`], [`graph`]: graph files, their validation and the checked graph.
//! - [`transport`]: typed ports over iceoryx2 publish-subscribe plus wake-up events.
//! - [`stage`]: the Stage API that built-in and external stage processes use.
//! - [`params`]: a stage's parameters as a typed struct, its specs derived ([`stage_params!`]).
//! - [`launch`]: the launcher/supervisor behind `imuflow run`.
//! - [`wire`]: the wire contract as data, for stages in other languages (Python).

pub mod frames;
pub mod graph;
pub mod launch;
pub mod naming;
pub mod overrides;
pub mod params;
pub mod schema;
pub mod spec;
pub mod stage;
pub mod stats;
pub mod transform;
pub mod transport;
pub mod validate;
pub mod wait;
pub mod wire;

pub use frames::{Frame, FrameHeader, FrameType};
pub use graph::{Graph, GraphLoadError, Mode};
pub use spec::{Registry, StageSpec};
pub use stage::{StageContext, StageError, Step};
