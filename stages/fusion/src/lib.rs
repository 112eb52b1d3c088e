//! imuflow-fusion: the `fusion` stage. Turns raw sensor samples (`RawImuFrame`: accelerometer,
//! gyroscope, magnetometer and perhaps an on-board orientation, each sensor stamped by its own
//! clock at its own rate) into `ImuFrame`s (orientation `R_IS`, specific force and angular rate in
//! the sensor frame) on the graph's output grid. See `README.md`.
//!
//! The algorithms are plain modules without IO; [`stage`] is the process wrapper.
//! - [`filter`]: VQF (Laidig & Seel 2023) per sensor, at the sensor's rate.
//! - [`clock`]: each sensor's clock mapped onto the source clock (lower envelope of the delivery
//!   delay, offset and drift).
//! - [`lowpass`]: the band limit of accelerometer and gyroscope before resampling.
//! - [`sensor`]: one sensor's stream: checks, counters, gap filling, fusion, resampling.
//! - [`assembler`]: the output grid: which frame is due, INVALID sensors, PRELUDE.

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod assembler;
pub mod clock;
pub mod filter;
pub mod lowpass;
pub mod quat;
pub mod sensor;
pub mod stage;

pub use assembler::{Assembler, Origin, Settings};
pub use filter::{OrientationFilter, VqfParams};
pub use sensor::{MagnetometerUse, OrientationSource, SensorSettings};
pub use stage::{SPEC, run};

/// The name of the site in wire slot `i` (as in models/body.toml and calibration files).
pub use imuflow_body::skeleton::site_name as sensor_name;

/// Input the stage cannot go on with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FusionError {
    /// `orientation = "onboard"`, and a sample came without an on-board orientation.
    NoOnboardOrientation { sensor: usize, sample_ns: u64 },
}

impl std::fmt::Display for FusionError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FusionError::NoOnboardOrientation { sensor, sample_ns } => write!(
                f,
                "orientation = \"onboard\", but sensor {} ({}) delivered a sample without an \
                 on-board orientation (orientation_mask bit {sensor} clear, sample time \
                 {sample_ns} ns); use orientation = \"auto\" or \"fuse\" to fuse it instead",
                sensor,
                sensor_name(*sensor),
            ),
        }
    }
}

impl std::error::Error for FusionError {}
