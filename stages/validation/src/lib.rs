//! imuflow's validation stage: an independent rapier3d simulation replays every estimated frame
//! with joint motors and ground contact, and scores how physically plausible the estimate is.

pub mod model;
pub mod sim;
pub mod stage;
pub mod support;
pub mod validator;

pub use model::SimModel;
pub use sim::{Mode, SimConfig, Simulation, Target};
pub use stage::{SPEC, run};
pub use support::{Support, SupportJudge, SupportState};
pub use validator::{FallRule, Outcome, Stats, Validator};
