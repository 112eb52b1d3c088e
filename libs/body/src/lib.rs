//! imuflow-body: the shared body-model library (no process). See `README.md` in this crate.
//!
//! Frame M everywhere: x = left, y = up, z = forward (the subject faces +z in the T-pose), gravity
//! (0, −9.81, 0); SI units; rotations act on column vectors.
//!
//! - [`skeleton`]: the 24-joint SMPL topology, joint handles and joint sets, the sensor sites.
//! - [`sensor_set`]: which sites a capture setup wears (`models/sensor-sets.toml`).
//! - [`body_model`]: dimensions, segment masses/inertias and IMU placement from `models/body.toml`.
//! - [`rotation`]: 6D, Euler, axis-angle, from-to, slerp, geodesic angle.
//! - [`kinematics`]: forward and inverse kinematics with preallocated buffers.
//! - [`limb_joints`]: knees as hinges, elbows as flexion-and-twist joints; projection of a pose onto them.
//! - [`dynamics`]: floating-base rigid-body dynamics (mass matrix, bias forces, inverse/forward dynamics,
//!   point Jacobians) in GlobalPose's singularity-free coordinates; [`urdf`]: the same model as URDF.

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod body_model;
pub mod dynamics;
pub mod inertial;
pub mod kinematics;
pub mod limb_joints;
pub mod rotation;
pub mod sensor_set;
pub mod skeleton;
pub mod urdf;

pub use body_model::{BodyModel, BodyParams, GRAVITY_IN_MODEL_MPS2};
pub use kinematics::{
    FkData, Pose, WirePoseError, forward_kinematics, mirror_rotation, mirror_vector,
};
pub use sensor_set::{SensorSet, SiteMask};
pub use skeleton::{Imu, JointId, MAX_SITES, NUM_IMUS, NUM_JOINTS, Skeleton};

#[cfg(test)]
mod test_util;
