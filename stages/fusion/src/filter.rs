//! Orientation by VQF (D. Laidig and T. Seel, "VQF: Highly Accurate IMU Orientation Estimation with
//! Bias Estimation and Magnetic Disturbance Rejection", Information Fusion 91, 2023), through
//! `vqf-rs`, a port of the authors' C++ implementation. This crate's tests compare it with the
//! authors' PyPI package (`scripts/verify/vqf_reference.py`).
//!
//! The quaternion VQF returns maps sensor-frame vectors into its earth frame (it rotates the
//! magnetometer reading into that frame itself), i.e. it is `R_ES`:
//! - 9D (with magnetometer): E is East-North-Up: x east, y magnetic north, z up (VQF aligns the
//!   horizontal magnetic field with +y; checked against the reference in the tests).
//! - 6D (without): E_i has z up and an arbitrary heading: that of the sensor's first sample
//!   (the gyroscope integration starts at the identity and the inclination correction turns about
//!   horizontal axes only).

use vqf_rs::{Params, VQF};

use crate::quat::{Quat, Vec3};

/// The VQF parameters this stage exposes; everything else keeps the authors' defaults (motion bias
/// estimation on).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VqfParams {
    /// Time constant of the accelerometer (inclination) correction, s (VQF default 3 s).
    pub tau_acc_s: f64,
    /// Time constant of the magnetometer (heading) correction, s (VQF default 9 s).
    pub tau_mag_s: f64,
    /// Rest detection and gyroscope bias estimation at rest.
    pub rest_bias: bool,
    /// How long a sensor must be still before VQF detects rest and estimates its gyroscope bias,
    /// s (VQF default 1.5 s).
    pub rest_min_s: f64,
    /// Largest gyroscope bias VQF estimates, per axis, deg/s (VQF default 2°/s); a sensor whose
    /// bias exceeds it is never detected at rest.
    pub bias_clip_dps: f64,
    /// Magnetic disturbance detection and rejection.
    pub mag_rejection: bool,
}

impl Default for VqfParams {
    /// The authors' defaults (Laidig & Seel 2023, Table 1; `vqf::VQFParams`).
    fn default() -> Self {
        VqfParams {
            tau_acc_s: 3.0,
            tau_mag_s: 9.0,
            rest_bias: true,
            rest_min_s: 1.5,
            bias_clip_dps: 2.0,
            mag_rejection: true,
        }
    }
}

/// One sensor's VQF, fed one sample per sensor period.
pub struct OrientationFilter {
    vqf: VQF,
    /// A magnetometer reading has been fed: the output is the 9D (ENU) orientation from now on,
    /// so the output's earth frame does not switch back and forth with the readings.
    magnetic: bool,
}

impl OrientationFilter {
    /// A filter for samples `period_s` apart (> 0).
    pub fn new(period_s: f64, params: &VqfParams) -> OrientationFilter {
        let vqf_params = Params {
            tau_acc: params.tau_acc_s,
            tau_mag: params.tau_mag_s,
            rest_bias_est_enabled: params.rest_bias,
            rest_min_t: params.rest_min_s,
            bias_clip: params.bias_clip_dps,
            mag_dist_rejection_enabled: params.mag_rejection,
            ..Params::default()
        };
        OrientationFilter {
            vqf: VQF::new(period_s, None, None, Some(vqf_params)),
            magnetic: false,
        }
    }

    /// One sample: angular rate (rad/s), specific force (m/s²) and, for 9D, the magnetic field
    /// (any unit; VQF uses its direction and compares norms only relatively). All finite.
    pub fn update(&mut self, gyr: Vec3, acc: Vec3, mag: Option<Vec3>) {
        self.vqf.update(gyr, acc, mag);
        self.magnetic |= mag.is_some();
    }

    /// Starts the filter again after a long gap, from where it was: the orientation (the 6D part
    /// as the new strapdown start, the heading offset δ), the gyroscope bias estimate and the
    /// magnetic reference are kept; the low-pass states start over. VQF then averages its first
    /// accelerometer samples into its inclination reference and corrects the inclination in full
    /// at once, and weighs its first magnetometer readings 1/N (its start-up behaviour), so what
    /// the sensor turned while nothing came is corrected within a few samples instead of over
    /// `tau_acc` and `tau_mag`, except the 6D heading, which nothing observes.
    pub fn restart(&mut self) {
        let q6 = self.vqf.quat_6d();
        let delta = self.vqf.delta();
        let (bias, sigma) = self.vqf.bias_estimate();
        let (norm, dip) = (self.vqf.mag_ref_norm(), self.vqf.mag_ref_dip());
        self.vqf.reset_state();
        self.vqf.state_mut().gyr_quat = q6;
        self.vqf.state_mut().delta = delta;
        self.vqf.set_bias_estimate(bias, Some(sigma));
        self.vqf.set_mag_ref(norm, dip);
    }

    /// `R_ES` as `[w, x, y, z]`: 9D once a magnetometer reading was fed, else 6D.
    pub fn orientation(&self) -> Quat {
        let q = if self.magnetic {
            self.vqf.quat_9d()
        } else {
            self.vqf.quat_6d()
        };
        [q.0, q.1, q.2, q.3]
    }

    /// The 6D orientation (without the magnetometer's heading correction).
    pub fn orientation_6d(&self) -> Quat {
        let q = self.vqf.quat_6d();
        [q.0, q.1, q.2, q.3]
    }

    /// Whether the output is the 9D orientation.
    pub fn magnetic(&self) -> bool {
        self.magnetic
    }

    /// The current gyroscope bias estimate in the sensor frame, rad/s.
    pub fn gyro_bias(&self) -> Vec3 {
        self.vqf.bias_estimate().0
    }

    /// Whether VQF currently detects rest.
    pub fn at_rest(&self) -> bool {
        self.vqf.rest_detected()
    }
}
