//! imuflow-calibration: the `calibration` stage. Turns raw `ImuFrame`s (sensor orientation `R_IS`,
//! specific force and angular rate in the sensor frame) into `BodyImuFrame`s (bone orientation
//! `R_MB`, free acceleration and angular velocity in the model frame M). See `README.md`.
//!
//! The algorithms are plain modules without IO; [`stage`] is the process wrapper.
//! - [`convention`]: inertial-frame conventions and the reference (T/N) poses.
//! - [`sample`], [`stillness`], [`segments`]: checked readings, stillness, holds and steps.
//! - [`tpose`]: held-pose calibration (reference §4). [`walking`]: walking calibration (GlobalPose
//!   §3.4, Eq. 17–24).
//! - [`calibration`]: the result and how it is applied. [`file`]: save / load as JSON.
//! - [`calibrator`]: the streaming session: phases, attempts, redo reasons, drift updates.

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod calibration;
pub mod calibrator;
pub mod convention;
pub mod error;
pub mod file;
pub mod math;
pub mod sample;
pub mod segments;
pub mod stage;
pub mod stillness;
pub mod tpose;
pub mod walking;

pub use calibration::{Calibration, Method, SensorCalibration};
pub use calibrator::{Calibrator, CalibratorConfig, Event};
pub use convention::{InertialFrame, ReferencePose};
pub use error::{FileError, NotCalibrated, Rejection};
pub use stage::{SPEC, run};

/// Number of IMUs (IMU order: left forearm, right forearm, left lower leg, right lower leg, head,
/// pelvis).
pub const NUM_IMUS: usize = imuflow_body::NUM_IMUS;

/// Index of the pelvis sensor, the heading reference of walking calibration (GlobalPose's sixth).
pub const PELVIS: usize = imuflow_body::Imu::Pelvis.index();

/// The name of the site in wire slot `k` (`left_forearm`, ...), as in models/body.toml and
/// calibration files.
pub use imuflow_body::skeleton::site_name as sensor_name;
