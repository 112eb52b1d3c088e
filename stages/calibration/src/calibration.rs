//! A finished calibration and how it turns raw readings into bone-frame data.
//!
//! Per sensor k, with ψ_k its heading correction and R_MI the model-from-inertial rotation of the
//! reference (pelvis) sensor:
//!
//! ```text
//! R_MI,k = R_y(ψ_k) · R_MI                          (the sensor's own model-from-inertial)
//! R_MB   = R_MI,k · R_IS · R_SB                     (bone orientation in M)
//! a_M    = R_MI,k · R_IS · a_S + g_M − offset_k     (free acceleration in M)
//! ω_M    = R_MI,k · R_IS · ω_S                      (angular velocity in M)
//! ```
//!
//! ψ_k is the yaw (right-handed about M's up axis y, radians) that re-aligns sensor k's inertial
//! frame with the pelvis sensor's: GlobalPose's relative heading error R_k (Eq. 22) written in M,
//! `R_MI·R_k·R_MIᵀ = R_y(ψ_k)`. The pelvis's is 0 by definition; a T-pose calibration has none
//! (all 0), since it assumes every sensor shares one inertial frame.

use imuflow_body::GRAVITY_IN_MODEL_MPS2;
use imuflow_body::rotation::{Axis, quat_wxyz_from_rotation};
use imuflow_graph::frames::{BodyImuFrame, flags};
use nalgebra::{Rotation3, Vector3};

use imuflow_body::{Imu, MAX_SITES, SiteMask};

use crate::sample::Sample;

/// Which procedure produced a calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// No calibration: I is M and every sensor frame is its bone frame.
    None,
    /// Held T-pose (or N-pose) with a configured inertial-frame convention and heading.
    Tpose,
    /// Stand, one step forward, stand (GlobalPose §3.4).
    Walking,
}

impl Method {
    pub const NAMES: [&'static str; 3] = ["tpose", "walking", "none"];

    pub fn parse(name: &str) -> Option<Method> {
        match name {
            "tpose" => Some(Method::Tpose),
            "walking" => Some(Method::Walking),
            "none" => Some(Method::None),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Method::None => "none",
            Method::Tpose => "tpose",
            Method::Walking => "walking",
        }
    }
}

/// One sensor's part of a calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorCalibration {
    /// ψ_k (rad), see the module doc.
    pub heading_correction_rad: f64,
    /// `R_SB`: bone frame to sensor frame.
    pub sensor_from_bone: Rotation3<f64>,
    /// Mean free acceleration in M while standing still (m/s²), subtracted from every output.
    pub accel_offset_in_model_mps2: Vector3<f64>,
}

impl SensorCalibration {
    pub const IDENTITY: SensorCalibration = SensorCalibration {
        heading_correction_rad: 0.0,
        sensor_from_bone: Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0,
        )),
        accel_offset_in_model_mps2: Vector3::new(0.0, 0.0, 0.0),
    };
}

/// A complete calibration of a sensor set's sensors.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    pub method: Method,
    /// `R_MI` of the reference (pelvis) sensor.
    pub model_from_inertial: Rotation3<f64>,
    /// The sites calibrated (the sensor set's).
    pub sites: SiteMask,
    /// By wire slot; identities outside `sites`.
    pub sensors: [SensorCalibration; MAX_SITES],
}

impl Calibration {
    /// `method = "none"`: the readings are already bone orientations in M (every site of `sites`).
    pub fn identity(sites: SiteMask) -> Calibration {
        Calibration {
            method: Method::None,
            model_from_inertial: Rotation3::identity(),
            sites,
            sensors: [SensorCalibration::IDENTITY; MAX_SITES],
        }
    }

    /// `R_MI,k = R_y(ψ_k)·R_MI` of sensor `k`.
    pub fn sensor_model_from_inertial(&self, k: usize) -> Rotation3<f64> {
        Axis::Y.rotation(self.sensors[k].heading_correction_rad) * self.model_from_inertial
    }

    /// The per-sensor heading corrections ψ (rad), by wire slot.
    pub fn heading_corrections_rad(&self) -> [f64; MAX_SITES] {
        self.sensors.map(|s| s.heading_correction_rad)
    }

    /// Writes the calibrated payload of `sample` into `out` (header flags: INVALID when a sensor
    /// is unusable; its entry is then the identity and zeros, with its `valid_mask` bit clear).
    /// Slots outside the calibrated sites are left as they are.
    pub fn apply(&self, sample: &Sample, out: &mut BodyImuFrame) {
        for k in self.sites.sites().map(Imu::index) {
            let cal = &self.sensors[k];
            out.heading_correction_rad[k] = cal.heading_correction_rad as f32;
            if sample.valid_mask & (1 << k) == 0 {
                out.bone_orientation_wxyz[k] = [1.0, 0.0, 0.0, 0.0];
                out.free_acceleration_mps2[k] = [0.0; 3];
                out.angular_velocity_radps[k] = [0.0; 3];
                continue;
            }
            let s = &sample.sensors[k];
            let model_from_sensor = self.sensor_model_from_inertial(k) * s.inertial_from_sensor;
            let bone = model_from_sensor * cal.sensor_from_bone;
            let accel = model_from_sensor * s.specific_force_mps2 + GRAVITY_IN_MODEL_MPS2
                - cal.accel_offset_in_model_mps2;
            let omega = model_from_sensor * s.angular_rate_radps;
            out.bone_orientation_wxyz[k] = quat_wxyz_from_rotation(&bone).map(|v| v as f32);
            out.free_acceleration_mps2[k] = to_f32(&accel);
            out.angular_velocity_radps[k] = to_f32(&omega);
        }
        out.valid_mask = sample.valid_mask & self.sites.0;
        if out.valid_mask != self.sites.0 {
            out.header.flags |= flags::INVALID;
        }
    }
}

fn to_f32(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}
