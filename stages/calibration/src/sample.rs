//! One input frame in the calibration's own (f64, checked) form.

use imuflow_body::rotation::rotation_from_quat_wxyz;
use imuflow_body::{Imu, MAX_SITES, SiteMask};
use imuflow_graph::frames::ImuFrame;

use crate::error::Rejection;
use nalgebra::{Rotation3, Vector3};

/// One sensor's reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorSample {
    /// `R_IS`: sensor frame to the sensor's inertial frame.
    pub inertial_from_sensor: Rotation3<f64>,
    /// Specific force in S (m/s²; +9.81 up at rest).
    pub specific_force_mps2: Vector3<f64>,
    /// Angular rate in S (rad/s).
    pub angular_rate_radps: Vector3<f64>,
}

impl SensorSample {
    const ZERO: SensorSample = SensorSample {
        inertial_from_sensor: Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0,
        )),
        specific_force_mps2: Vector3::new(0.0, 0.0, 0.0),
        angular_rate_radps: Vector3::new(0.0, 0.0, 0.0),
    };

    /// Free acceleration in I: `a_I = R_IS·a_S + g_I` (GlobalPose Eq. 17).
    pub fn free_acceleration_in_inertial(
        &self,
        gravity_in_inertial: &Vector3<f64>,
    ) -> Vector3<f64> {
        self.inertial_from_sensor * self.specific_force_mps2 + gravity_in_inertial
    }
}

/// The sensors of a set at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The frame's `seq`.
    pub seq: u64,
    /// Capture time (s) on the calibrator's clock (see `Calibrator`).
    pub time_s: f64,
    /// The sites calibrated (the graph's sensor set).
    pub sites: SiteMask,
    /// Bit i set when sensor i's reading is usable: its bit was set in the frame and every number
    /// is finite with a quaternion of positive finite norm. Unusable sensors hold zeros.
    pub valid_mask: u32,
    /// By wire slot; the sites outside `sites` hold zeros.
    pub sensors: [SensorSample; MAX_SITES],
}

impl Sample {
    /// Converts and checks the sensors of `sites` in a wire frame.
    pub fn from_frame(frame: &ImuFrame, time_s: f64, sites: SiteMask) -> Sample {
        let mut s = Sample {
            seq: frame.header.seq,
            time_s,
            sites,
            valid_mask: 0,
            sensors: [SensorSample::ZERO; MAX_SITES],
        };
        for i in sites.sites().map(Imu::index) {
            if frame.valid_mask & (1 << i) == 0 {
                continue;
            }
            if let Some(reading) = sensor_reading(frame, i) {
                s.sensors[i] = reading;
                s.valid_mask |= 1 << i;
            }
        }
        s
    }

    /// Every sensor of the set usable in every sample of `window` (not empty), or the first
    /// sensor (in slot order) that was not, with how often and from when.
    pub fn check_usable(window: &[Sample], phase: &'static str) -> Result<(), Rejection> {
        let Some(first) = window.first() else {
            return Err(Rejection::NoSamples { phase });
        };
        for k in first.slots() {
            let mut unusable = window.iter().filter(|s| s.valid_mask & (1 << k) == 0);
            if let Some(at) = unusable.next() {
                return Err(Rejection::Unusable {
                    phase,
                    sensor: crate::sensor_name(k),
                    frames: 1 + unusable.count(),
                    of: window.len(),
                    from_s: at.time_s - first.time_s,
                });
            }
        }
        Ok(())
    }

    /// Whether every sensor of the set is usable.
    pub fn all_valid(&self) -> bool {
        self.valid_mask & self.sites.0 == self.sites.0
    }

    /// The slots of the set's sites, in order.
    pub fn slots(&self) -> impl Iterator<Item = usize> + use<> {
        self.sites.sites().map(Imu::index)
    }
}

fn sensor_reading(frame: &ImuFrame, i: usize) -> Option<SensorSample> {
    let q = frame.orientation_wxyz[i].map(f64::from);
    let f = frame.specific_force_mps2[i].map(f64::from);
    let w = frame.angular_rate_radps[i].map(f64::from);
    if !f.iter().chain(w.iter()).all(|v| v.is_finite()) {
        return None;
    }
    Some(SensorSample {
        inertial_from_sensor: rotation_from_quat_wxyz(&q)?,
        specific_force_mps2: Vector3::from(f),
        angular_rate_radps: Vector3::from(w),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every sensor of the six-site set valid.
    const ALL_VALID: u32 = 0b11_1111;

    fn six(f: &ImuFrame) -> Sample {
        Sample::from_frame(f, 0.0, SiteMask::of(Imu::SIX))
    }

    fn frame() -> ImuFrame {
        let mut f = ImuFrame {
            valid_mask: ALL_VALID,
            ..Default::default()
        };
        for q in &mut f.orientation_wxyz {
            *q = [1.0, 0.0, 0.0, 0.0];
        }
        f
    }

    #[test]
    fn bad_numbers_and_cleared_bits_make_a_sensor_unusable() {
        let mut f = frame();
        assert!(six(&f).all_valid());
        f.specific_force_mps2[1][2] = f32::NAN;
        f.orientation_wxyz[2] = [0.0; 4];
        f.angular_rate_radps[3][0] = f32::INFINITY;
        f.valid_mask &= !(1 << 4);
        let s = six(&f);
        assert_eq!(s.valid_mask, 0b100001);
        assert!(!s.all_valid());
        assert_eq!(s.sensors[1].specific_force_mps2, Vector3::zeros());
    }
}
