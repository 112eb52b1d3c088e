//! The imu-source stage: six IMUs' frames from a motion file (synthesized), an mcap recording
//! (replayed) or live sensors over UDP, as `ImuFrame`s on output `imu`, plus the ground-truth pose
//! (`MotionFrame`) on output `truth` where one is known.
//!
//! Modes (param `mode`):
//! - `synthesize`: BVH -> 24-joint clip (joint mapping, default the built-in Bandai Namco one) ->
//!   resampled to the graph's rate -> synthetic IMUs ([`imuflow_motion::imu_synthesis`]). By default
//!   the orientation is `R_MS` (the sensor's inertial frame is the model frame M, the sensor frame
//!   the bone frame); specific force and angular rate are in the sensor frame. For calibration
//!   tests: a calibration prelude ([`prelude`]), random mountings and inertial-frame conventions
//!   with per-sensor heading offsets ([`imuflow_synth::SensorSetup`]). `truth` carries the pose of the
//!   same `seq`, prelude included.
//!   With `raw`: the raw accelerometer, gyroscope and magnetometer samples six consumer IMUs would
//!   deliver, each on its own clock ([`imuflow_synth::raw`]), as `RawImuFrame`s on `raw` instead,
//!   interleaved in time with the truth.
//! - `replay`: re-publishes the `ImuFrame`s (and `MotionFrame`s, if any) of a recorder's mcap file
//!   in file order, keeping their `seq`, `capture_ns` and flags.
//! - `udp`: receives the packets described in [`udp`] from live sensors.
//! - `file`: a recorded session (CSV/TSV with a layout TOML, or Xsens MVNX) read by
//!   imuflow-sensor-files, published as raw samples on `raw` (and MVNX's truth on `truth`).
//! - `slimevr`: live SlimeVR trackers over UDP ([`slimevr`]): the stage answers them as the
//!   SlimeVR server does and publishes their on-board orientations and accelerations as
//!   `RawImuFrame`s on output `raw`.
//!
//! A sample that is not finite clears its sensor's bit of `valid_mask` and flags the frame
//! INVALID; it never stops the stage.

mod file;
mod publisher;
mod replay;
pub mod slimevr;
pub mod stage;
mod synth;
pub mod udp;

pub use imuflow_synth::{ALL_VALID, mark_invalid_sensors};
pub use stage::{SPEC, run};
