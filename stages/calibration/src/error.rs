//! Why a calibration attempt was rejected, and the stage's hard failures.

use std::path::PathBuf;

/// Why an attempt must be redone. The message says what was measured and what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Rejection {
    #[error(
        "a sensor's sample was unusable (NaN, infinite, zero quaternion or valid bit cleared) \
         during the {phase}: do it again"
    )]
    NoSamples { phase: &'static str },
    #[error(
        "sensor {sensor} had no usable sample in {frames} of the {phase}'s {of} frames (the first \
         {from_s:.2} s into it): lost for longer than the fusion fills (its `max_gap_ms`), NaN, \
         infinite or a zero quaternion; every sample of the {phase} is needed, so do it again"
    )]
    Unusable {
        phase: &'static str,
        sensor: &'static str,
        frames: usize,
        of: usize,
        from_s: f64,
    },
    #[error(
        "sensor {sensor}: gravity is {angle_deg:.0}° away from the up axis of `frame = \"{frame}\"` \
         (max_gravity_deg = {max_deg}°): is the inertial-frame convention right?"
    )]
    GravityMismatch {
        sensor: &'static str,
        angle_deg: f64,
        max_deg: f64,
        frame: &'static str,
    },
    #[error(
        "sensor {sensor} turned {angle_deg:.1}° between the stand before and the stand after the \
         motion (max_pose_change_deg = {max_deg}°): stand in the same pose before and after the step"
    )]
    PoseChanged {
        sensor: &'static str,
        angle_deg: f64,
        max_deg: f64,
    },
    #[error(
        "sensor {sensor} moved {vertical_m:.2} m vertically during the step or walk ({param} = \
         {max_m} m): calibrate on flat ground"
    )]
    NotLevel {
        sensor: &'static str,
        vertical_m: f64,
        max_m: f64,
        /// The parameter that bounds it (`max_vertical_m` or `max_walk_vertical_m`).
        param: &'static str,
    },
    #[error(
        "the pelvis moved {length_m:.2} m between the stands (min_step_m..max_step_m = \
         {min_m}..{max_m} m): take one step forward"
    )]
    StepLength {
        length_m: f64,
        min_m: f64,
        max_m: f64,
    },
    #[error(
        "sensor {sensor} moved {length_m:.2} m but the pelvis {pelvis_m:.2} m (they may differ by \
         max_step_mismatch_m = {max_m} m): stand in the same pose before and after the step"
    )]
    StepMismatch {
        sensor: &'static str,
        length_m: f64,
        pelvis_m: f64,
        max_m: f64,
    },
    #[error(
        "the motion between the two stands lasted {secs:.1} s (max_step_s = {max_s} s): take a \
         single step"
    )]
    MotionTooLong { secs: f64, max_s: f64 },
    #[error(
        "the pelvis moved {length_m:.2} m in the walk_s = {walk_s} s after the stand (min_walk_m \
         = {min_m} m): walk on after standing still"
    )]
    WalkTooShort {
        length_m: f64,
        min_m: f64,
        walk_s: f64,
    },
    #[error(
        "the walk after the stand turned {turn_deg:.0}° (max_walk_turn_deg = {max_deg}°): walk \
         straight for the first few seconds"
    )]
    WalkTurned { turn_deg: f64, max_deg: f64 },
    #[error(
        "sensor {sensor}'s path differs from the pelvis's by {rms_m:.2} m RMS once turned onto \
         it (max_walk_mismatch_m = {max_m} m): is it worn on the body, and did the walk start from \
         standing?"
    )]
    WalkMismatch {
        sensor: &'static str,
        rms_m: f64,
        max_m: f64,
    },
}

/// Reading or writing a calibration file.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("calibration file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("calibration file {path}: not a calibration ({message})")]
    Parse { path: PathBuf, message: String },
    #[error("calibration file {path}: field `{field}` {problem}")]
    Field {
        path: PathBuf,
        field: String,
        problem: String,
    },
}

/// The stream ended before any calibration was accepted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "the stream ended after {frames} frames without a completed {method} calibration:\n{reason}"
)]
pub struct NotCalibrated {
    pub method: &'static str,
    pub frames: u64,
    pub reason: String,
}
