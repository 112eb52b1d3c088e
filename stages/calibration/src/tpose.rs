//! T-pose (or N-pose) calibration (reference §4: TransPose App. A, PIP live demo, GlobalPose
//! `_fixpose_calibration`).
//!
//! `R_MI` comes from the configured inertial-frame convention and the subject's heading (instead of
//! placing one sensor in a known orientation: the same information, given as parameters). While the
//! subject holds the pose, every bone's `R_MB` is known, so `R_SB = (R_MI·R̄_IS)ᵀ·R_MB,ref` with R̄_IS
//! the rotation average over the still window. The mean free acceleration over the window is the
//! accelerometer offset (TransPose live: in M, subtracted every frame).
//!
//! All sensors must share one inertial frame: a T-pose cannot see a per-sensor heading offset (it
//! would end up, wrongly, in R_SB). That is what walking calibration is for.

use imuflow_body::GRAVITY_IN_MODEL_MPS2;
use nalgebra::Vector3;

use crate::calibration::{Calibration, Method, SensorCalibration};
use crate::convention::{InertialFrame, ReferencePose};
use crate::error::Rejection;
use crate::math::mean_rotation;
use crate::sample::Sample;
use crate::sensor_name;
use imuflow_body::MAX_SITES;

/// What a held-pose calibration needs to know.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TposeConfig {
    pub frame: InertialFrame,
    /// The direction the subject faces, right-handed about up from the convention's forward (rad).
    pub heading_rad: f64,
    pub pose: ReferencePose,
    /// Estimate and subtract the accelerometer offset.
    pub accel_offset: bool,
    /// Largest angle between measured gravity and the convention's down axis (deg).
    pub max_gravity_deg: f64,
}

/// Calibrates from `window`, the still samples of the held pose.
pub fn calibrate_tpose(window: &[Sample], config: &TposeConfig) -> Result<Calibration, Rejection> {
    Sample::check_usable(window, "hold")?;
    check_gravity(window, config.frame, config.max_gravity_deg)?;
    let model_from_inertial = config.frame.model_from_inertial(config.heading_rad);
    let reference = config.pose.bone_orientations();
    let sites = window[0].sites;
    let mut sensors = [SensorCalibration::IDENTITY; MAX_SITES];
    for k in window[0].slots() {
        let cal = &mut sensors[k];
        let inertial_from_sensor =
            mean_rotation(window.iter().map(|s| &s.sensors[k].inertial_from_sensor))
                .ok_or(Rejection::NoSamples { phase: "hold" })?;
        cal.sensor_from_bone =
            (model_from_inertial * inertial_from_sensor).transpose() * reference[k];
        if config.accel_offset {
            cal.accel_offset_in_model_mps2 = window
                .iter()
                .map(|s| {
                    let r = &s.sensors[k];
                    model_from_inertial * (r.inertial_from_sensor * r.specific_force_mps2)
                        + GRAVITY_IN_MODEL_MPS2
                })
                .sum::<Vector3<f64>>()
                / window.len() as f64;
        }
    }
    Ok(Calibration {
        method: Method::Tpose,
        model_from_inertial,
        sites,
        sensors,
    })
}

/// GlobalPose's sanity check (reference §4: < 8°), per sensor: the specific force averaged over a
/// still window points up; it must agree with the convention's up axis.
pub fn check_gravity(
    window: &[Sample],
    frame: InertialFrame,
    max_deg: f64,
) -> Result<(), Rejection> {
    let up = frame.up_in_inertial();
    let Some(first) = window.first() else {
        return Err(Rejection::NoSamples { phase: "hold" });
    };
    for k in first.slots() {
        let measured_up: Vector3<f64> = window
            .iter()
            .map(|s| s.sensors[k].inertial_from_sensor * s.sensors[k].specific_force_mps2)
            .sum();
        // A dead accelerometer (no gravity at all) fails the check as "opposite".
        let angle_deg = if measured_up.norm() < 1e-3 {
            180.0
        } else {
            measured_up.angle(&up.into_inner()).to_degrees()
        };
        // NaN (from a non-finite reading) fails too.
        if angle_deg.is_nan() || angle_deg > max_deg {
            return Err(Rejection::GravityMismatch {
                sensor: sensor_name(k),
                angle_deg,
                max_deg,
                frame: frame.name(),
            });
        }
    }
    Ok(())
}
