//! imuflow-eval: evaluation in one place (a library, no process). See `README.md` in this crate.
//!
//! - [`metrics`]: the pose and motion metrics and their protocols (reference §6): SIP, angle and
//!   joint position errors, jitter, translation error and drift, foot skating, ground penetration.
//! - [`test_split`]: the dataset's test split, sequence by sequence.
//! - [`nets`]: `imuflow eval`, the kinematics nets on the test split.
//! - [`limbs`]: `imuflow eval --limbs`, the knees' and elbows' share of a pose error.
//! - [`physics`]: `imuflow eval-physics`, the physics methods on the test split.
//! - [`score`]: scores of recorded streams (motion against truth, without truth, two estimates
//!   against each other, validation), and a paired bootstrap for A/B differences.

pub mod limbs;
pub mod metrics;
pub mod nets;
pub mod physics;
pub mod score;
pub mod test_split;
