//! The `contact` stage kind: PIP's contact rule (CVPR 2022 §3.2.3; reference §5.2) between the
//! kinematics networks and the optimizer. The rule itself, the contact geometry and the wire form of
//! a contact set live in the `imuflow-contact` library (libs/contact), which the optimizer links too.
//!
//! - `stage`: the [`SPEC`] (ports, parameters) and [`run`], the process's main loop.

pub mod stage;

pub use stage::{SPEC, run};
