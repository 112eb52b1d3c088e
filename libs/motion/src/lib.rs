//! imuflow-motion: motion data in and out of imuflow's body model (no process). See `README.md`
//! in this crate. The skeleton, body model, rotations, kinematics and dynamics stay in
//! `imuflow-body`; everything that reads, converts, resamples, synthesizes or augments motion lives
//! here.
//!
//! - [`bvh`]: BVH parsing and writing; [`retarget`]: BVH onto the 24-joint body, resampling, export.
//! - [`npz`]: AMASS-style `.npz` motion import and export (Z-up SMPL `trans` ↔ Y-up root position).
//! - [`imu_synthesis`]: synthetic IMU signals (orientation, acceleration, angular velocity) with a
//!   seeded augmentation model, for training and the imu-source stage.
//! - [`augment`]: motion augmentations for training data (mirroring, time warping, recombined
//!   upper and lower bodies, perturbed postures, standing idle, other statures).

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod augment;
pub mod bvh;
pub mod imu_synthesis;
pub mod npz;
pub mod retarget;

// The body crate's deterministic test rotations, shared by path (test-only code).
#[cfg(test)]
#[path = "../../body/src/test_util.rs"]
mod test_util;
