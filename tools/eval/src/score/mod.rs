//! Scores of recorded motion streams: what `imuflow compare` reports for each variant of a run.
//!
//! Inputs are the wire frames as a recording holds them ([`MotionFrame`], [`ValidationFrame`],
//! decoded with `imuflow_graph::frames::frame_from_bytes`). Rules shared by every function here:
//! - streams are paired by `header.seq`;
//! - a frame flagged INVALID, CALIBRATING or END_OF_STREAM ([`SKIPPED_FLAGS`]) in either stream, or
//!   whose pose does not decode, is skipped, and so is its partner;
//! - sequence metrics (jitter, skating, translation, standing forces) never difference across a gap
//!   in the scored seqs: they are computed per run of consecutive seqs.
//!
//! - [`score_against_truth`] / [`score_without_truth`]: [`MotionScores`] of one estimate;
//! - [`sensor_bone_error_deg`]: how far an estimate's instrumented bones are from its sensors;
//! - [`disagreement`]: two estimates against each other, when there is no truth;
//! - [`summarize_validation`]: the validation stage's stream as [`ValidationScores`];
//! - [`paired_bootstrap`]: whether a difference between two variants' per-frame scores is more
//!   than noise.
//!
//! [`MotionFrame`]: imuflow_graph::frames::MotionFrame
//! [`ValidationFrame`]: imuflow_graph::frames::ValidationFrame

mod bootstrap;
mod disagreement;
mod motion;
mod pairing;
mod sensors;
mod validation;

pub use bootstrap::{BootstrapError, PairedDifference, paired_bootstrap};
pub use disagreement::{Disagreement, disagreement};
pub use motion::{MotionScores, PerFrame, PerJoint, score_against_truth, score_without_truth};
pub use pairing::{SKIPPED_FLAGS, is_scored};
pub use sensors::sensor_bone_error_deg;
pub use validation::{ValidationScores, summarize_validation, validation_stats};

#[cfg(test)]
mod tests;
