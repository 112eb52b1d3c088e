//! Synthetic IMU signals from a motion: the one code path for training-data synthesis and the
//! imu-source stage.
//!
//! Sensors sit on the bones of [`Imu::joint`] (forearms, lower legs, head, pelvis) at
//! [`BodyModel::imu_offsets_in_joint_m`] (from `models/body.toml`). The ideal sensor frame S is the bone
//! frame B, i.e. the sensor is already T-pose calibrated (reference §4: in the T-pose every R_MB is the
//! identity), so the ideal `R_MS` is the joint's global rotation (reference §1).
//!
//! Signals per frame and sensor (frame M: x left, y up, z forward; SI units):
//! - orientation `R_MS` (sensor to model);
//! - position in M;
//! - free acceleration in M (gravity removed; what TransPose/PIP/GlobalPose networks take, reference §3):
//!   the second finite difference of the sensor position, with [`AccelStencil`];
//! - specific force in S, what an accelerometer measures: `R_MSᵀ (a − g)` (GlobalPose `a_S`, §3);
//! - angular velocity in S and in M from consecutive orientations (see [`synthesize_imus`]).
//!
//! Augmentation ([`AugmentationConfig`], seeded) follows the GlobalPose synthesis facts of reference §3
//! (mounting rotation/position errors as constants plus random walks, accelerometer/gyro white noise plus
//! bias random walks) and adds a heading (yaw about M's y axis) drift random walk on the reported
//! orientation, which the reference does not simulate (the GlobalPose paper motivates it: magnetic
//! interference causes relative heading drift). The networks' inputs are then recomputed from the noisy
//! measurements as GlobalPose's simulated T-pose calibration does (§3): `a_M = R̃·ã_S + g`,
//! `ω_M = R̃·ω̃_S`, with R̃ the reported orientation.
//!
//! Gravity is [`GRAVITY_IN_MODEL_MPS2`] (9.81 m/s², imuflow's constant, as PIP's RBDL); the GlobalPose
//! synthesis uses 9.8 (§0). Only the specific force depends on it.

use nalgebra::{Rotation3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::retarget::MotionClip;
use imuflow_body::SiteMask;
use imuflow_body::body_model::{BodyModel, GRAVITY_IN_MODEL_MPS2};
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::rotation::{Axis, axis_angle_from_rotation};
use imuflow_body::skeleton::{Imu, MAX_SITES};

/// Half-width n (frames) of the TransPose/PIP smoothing stencil (reference §3, paper eq. 11: n = 4,
/// chosen there as closest to real TotalCapture accelerometer statistics). Defined at 60 Hz.
pub const TRANSPOSE_SMOOTHING_FRAMES: usize = 4;

/// Fewest frames [`synthesize_imus`] accepts: a second difference needs three positions. (The reference
/// preprocessing discards sequences of ≤ 12 frames altogether, §3.)
pub const MIN_FRAMES: usize = 3;

/// k = √(π/8): a 3-D isotropic Gaussian with per-axis σ = k·s has expected norm s (reference §3). The
/// "mean norm" parameters of [`AugmentationConfig`] are converted with it, as GlobalPose does.
pub const MEAN_NORM_TO_SIGMA: f64 = 0.626_657_068_657_750_1;

/// Finite-difference stencil for the acceleration from positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AccelStencil {
    /// `(p[t−1] − 2p[t] + p[t+1]) / dt²`. At the two ends (clips of ≥ 4 frames) the one-sided 4-point
    /// stencil `(2p0 − 5p1 + 4p2 − p3) / dt²`, as GlobalPose's `imu_synthesis.py` (reference §3); with
    /// exactly 3 frames the ends repeat the middle value (the one-sided 3-point stencil).
    Central,
    /// TransPose/PIP `_syn_acc` (reference §3): `(p[t−n] + p[t+n] − 2p[t]) / (n·dt)²` with
    /// n = [`TRANSPOSE_SMOOTHING_FRAMES`] for t in [n, N−1−n]; frames 1..n−1 and N−n..N−2 use n = 1;
    /// frames 0 and N−1 are 0. (The reference writes `·3600/n²`, i.e. dt = 1/60 s.)
    #[default]
    SmoothedTransPose,
}

/// Magnitudes of the augmentation model, SI units. [`Default`] gives the reference (GlobalPose §3)
/// values; [`AugmentationConfig::NONE`] gives ideal signals. "Mean norm" parameters describe an isotropic
/// 3-D Gaussian through the expected norm of a draw (per-axis σ = [`MEAN_NORM_TO_SIGMA`] × value).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AugmentationConfig {
    /// Constant mounting (residual calibration) rotation error per sensor: rotation vector with mean norm
    /// this value (rad); isotropic axis, angle Maxwell-distributed. 0.1 rad: GlobalPose's constant
    /// `dw ~ N(0, (0.1k)²)` (§3). (GlobalPose also draws a uniform random mounting and removes it with a
    /// simulated exact T-pose calibration; the net effect is this residual error alone, so it is not
    /// simulated.) The brief asked for angle ~ N(0, σ) about a random axis; the reference's isotropic
    /// Gaussian is followed instead.
    pub mounting_rotation_error_rad: f64,
    /// Random walk of the mounting rotation (soft tissue, strap slip): per-step rotation-vector mean
    /// norm = value·√dt (rad/√s). 1e-2: GlobalPose's per-frame σ = 1e-2·k·√(1/60) (§3).
    pub mounting_rotation_walk_rad_per_sqrt_s: f64,
    /// Constant mounting position error per sensor, in the bone frame, mean norm (m). 1e-2 m:
    /// GlobalPose's constant `dp ~ N(0, (1e-2·k)²)` (§3).
    pub mounting_position_error_m: f64,
    /// Random walk of the mounting position in the bone frame: per-step mean norm = value·√dt (m/√s).
    /// 1e-3: GlobalPose's per-frame σ = 1e-3·k·√(1/60) (§3). It enters the positions, hence the
    /// finite-difference acceleration (≈ 0.4 m/s² of extra jitter at 60 Hz with the central stencil).
    pub mounting_position_walk_m_per_sqrt_s: f64,
    /// Accelerometer white noise, per axis and per sample at the clip's rate (m/s²). 0.05: GlobalPose
    /// `N(0, 0.05²)` per 60 Hz frame (§3).
    pub accel_noise_mps2: f64,
    /// Accelerometer bias random walk, per axis: per-step σ = value·√dt (m/s²/√s). 1e-4: GlobalPose
    /// "random walk σ 1e-4·√(1/60)" (§3). Starts at 0 (bias removed at calibration).
    pub accel_bias_walk_mps2_per_sqrt_s: f64,
    /// Gyroscope white noise, per axis and per sample (rad/s). 0.005: GlobalPose `N(0, 0.005²)` (§3).
    pub gyro_noise_radps: f64,
    /// Gyroscope bias random walk, per axis: per-step σ = value·√dt (rad/s/√s). 1e-5: GlobalPose (§3).
    /// Starts at 0.
    pub gyro_bias_walk_radps_per_sqrt_s: f64,
    /// Heading drift of the reported orientation: yaw about M's y axis, one random walk per sensor with
    /// per-step σ = value·√dt (rad/√s), starting at 0. Not in the reference code; 4.5e-3 rad/√s
    /// [inferred] gives a 1σ drift of ≈ 2° after one minute, the order of relative heading drift of
    /// magnetometer-aided consumer IMUs indoors that the GlobalPose paper's walking calibration corrects.
    pub heading_drift_rad_per_sqrt_s: f64,
}

impl AugmentationConfig {
    /// No augmentation: the output equals the ideal synthesis exactly.
    pub const NONE: AugmentationConfig = AugmentationConfig {
        mounting_rotation_error_rad: 0.0,
        mounting_rotation_walk_rad_per_sqrt_s: 0.0,
        mounting_position_error_m: 0.0,
        mounting_position_walk_m_per_sqrt_s: 0.0,
        accel_noise_mps2: 0.0,
        accel_bias_walk_mps2_per_sqrt_s: 0.0,
        gyro_noise_radps: 0.0,
        gyro_bias_walk_radps_per_sqrt_s: 0.0,
        heading_drift_rad_per_sqrt_s: 0.0,
    };

    /// The reference values (see each field).
    pub const REFERENCE: AugmentationConfig = AugmentationConfig {
        mounting_rotation_error_rad: 0.1,
        mounting_rotation_walk_rad_per_sqrt_s: 1e-2,
        mounting_position_error_m: 1e-2,
        mounting_position_walk_m_per_sqrt_s: 1e-3,
        accel_noise_mps2: 0.05,
        accel_bias_walk_mps2_per_sqrt_s: 1e-4,
        gyro_noise_radps: 0.005,
        gyro_bias_walk_radps_per_sqrt_s: 1e-5,
        heading_drift_rad_per_sqrt_s: 4.5e-3,
    };

    fn fields(&self) -> [(&'static str, f64); 9] {
        [
            (
                "mounting_rotation_error_rad",
                self.mounting_rotation_error_rad,
            ),
            (
                "mounting_rotation_walk_rad_per_sqrt_s",
                self.mounting_rotation_walk_rad_per_sqrt_s,
            ),
            ("mounting_position_error_m", self.mounting_position_error_m),
            (
                "mounting_position_walk_m_per_sqrt_s",
                self.mounting_position_walk_m_per_sqrt_s,
            ),
            ("accel_noise_mps2", self.accel_noise_mps2),
            (
                "accel_bias_walk_mps2_per_sqrt_s",
                self.accel_bias_walk_mps2_per_sqrt_s,
            ),
            ("gyro_noise_radps", self.gyro_noise_radps),
            (
                "gyro_bias_walk_radps_per_sqrt_s",
                self.gyro_bias_walk_radps_per_sqrt_s,
            ),
            (
                "heading_drift_rad_per_sqrt_s",
                self.heading_drift_rad_per_sqrt_s,
            ),
        ]
    }

    /// Every magnitude must be finite and ≥ 0.
    pub fn validate(&self) -> Result<(), SynthesisError> {
        for (field, value) in self.fields() {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SynthesisError::InvalidConfig { field, value });
            }
        }
        Ok(())
    }
}

impl Default for AugmentationConfig {
    fn default() -> AugmentationConfig {
        AugmentationConfig::REFERENCE
    }
}

/// An augmentation model with the seed of its random draws (same seed, same output).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Augmentation {
    /// Magnitudes.
    pub config: AugmentationConfig,
    /// Seed of [`StdRng::seed_from_u64`].
    pub seed: u64,
}

/// Options of [`synthesize_imus`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SynthesisOptions {
    /// Acceleration stencil.
    pub stencil: AccelStencil,
    /// `None`: ideal signals.
    pub augmentation: Option<Augmentation>,
    /// The sites to synthesize (a sensor set's, [`imuflow_body::SensorSet::mask`]); the others'
    /// slots stay empty. The augmentation draws per site in slot order, so a set's draws do not
    /// depend on what other sets hold.
    pub sites: SiteMask,
}

impl Default for SynthesisOptions {
    /// The TransPose/PIP stencil, ideal signals, the six-site set.
    fn default() -> Self {
        SynthesisOptions {
            stencil: AccelStencil::default(),
            augmentation: None,
            sites: SiteMask::of(Imu::SIX),
        }
    }
}

/// One sensor's signals in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    /// Reported orientation `R_MS` (sensor to model). Ideal: the bone's global rotation; augmented: with
    /// the mounting error and the heading drift.
    pub model_from_sensor: Rotation3<f64>,
    /// True sensor position in M (m), including the mounting position error.
    pub position_in_model_m: Vector3<f64>,
    /// Free acceleration in M (m/s², gravity removed), as the networks take it: ideal = the finite
    /// difference of the position; augmented = `R̃·ã_S + g` from the noisy measurement.
    pub free_accel_in_model_mps2: Vector3<f64>,
    /// Specific force in S, `R_MSᵀ(a − g)` (m/s²), plus noise and bias when augmented: what a real
    /// accelerometer measures (+9.81 up at rest).
    pub specific_force_in_sensor_mps2: Vector3<f64>,
    /// Angular velocity in S (rad/s), plus noise and bias when augmented: what a gyroscope measures.
    pub angular_velocity_in_sensor_radps: Vector3<f64>,
    /// Angular velocity in M (rad/s): the reported orientation times the sensor-frame value.
    pub angular_velocity_in_model_radps: Vector3<f64>,
}

impl ImuSample {
    fn zero() -> ImuSample {
        ImuSample {
            model_from_sensor: Rotation3::identity(),
            position_in_model_m: Vector3::zeros(),
            free_accel_in_model_mps2: Vector3::zeros(),
            specific_force_in_sensor_mps2: Vector3::zeros(),
            angular_velocity_in_sensor_radps: Vector3::zeros(),
            angular_velocity_in_model_radps: Vector3::zeros(),
        }
    }
}

/// Synthetic signals of a set of sites ([`SynthesisOptions::sites`]) for every frame of a clip.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct SyntheticImus {
    /// Seconds between frames (the clip's).
    pub frame_time_s: f64,
    /// The sites synthesized; the other slots hold a zero sample (identity orientation).
    pub sites: SiteMask,
    /// One entry per clip frame, indexed by [`Imu::index`] (wire slot).
    pub frames: Vec<[ImuSample; MAX_SITES]>,
}

/// Failure of [`synthesize_imus`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SynthesisError {
    /// The clip is shorter than [`MIN_FRAMES`].
    #[error("IMU synthesis needs at least {needed} frames, the clip has {frames}")]
    TooFewFrames { frames: usize, needed: usize },
    /// The clip's frame time is not a positive finite number.
    #[error("IMU synthesis needs a positive finite frame time, got {frame_time_s} s")]
    InvalidFrameTime { frame_time_s: f64 },
    /// A pose holds a NaN or an infinity.
    #[error("frame {frame} of the clip holds a non-finite number")]
    NonFinitePose { frame: usize },
    /// An augmentation magnitude is negative or not finite.
    #[error("augmentation parameter {field} = {value} must be finite and >= 0")]
    InvalidConfig { field: &'static str, value: f64 },
}

/// Synthesize the IMUs of `options.sites` for `clip` on `body` (clips should be at 60 Hz, the rate the reference
/// stencils and noise magnitudes are defined at; see [`crate::retarget::resample`]).
///
/// Angular velocity: interior frames use `ω_S(t) = log(R_{t−1}ᵀ R_{t+1}) / (2dt)` (second-order accurate,
/// exact for rotation at a constant rate about an axis fixed in the sensor or in M); the two end frames
/// extrapolate the one-sided rates, `1.5·log(R_0ᵀR_1)/dt − 0.5·log(R_1ᵀR_2)/dt` (second order, also
/// exact at a constant rate). This replaces GlobalPose's `vee(Rᵀ·Ṙ)` with a central matrix difference
/// (§3), which is only approximately skew; DIP preprocessing's forward `log(R_tᵀR_{t+1})·60` (§3) is
/// first order. `ω_M = R_MS·ω_S`. Rates above π/(2dt) (94 rad/s at 60 Hz) alias.
pub fn synthesize_imus(
    clip: &MotionClip,
    body: &BodyModel,
    options: &SynthesisOptions,
) -> Result<SyntheticImus, SynthesisError> {
    let mut out = SyntheticImus::default();
    synthesize_imus_into(clip, body, options, &mut out)?;
    Ok(out)
}

/// [`synthesize_imus`] into a reused output (no allocation once `out.frames` has the capacity). On error
/// `out` is left empty.
pub fn synthesize_imus_into(
    clip: &MotionClip,
    body: &BodyModel,
    options: &SynthesisOptions,
    out: &mut SyntheticImus,
) -> Result<(), SynthesisError> {
    out.frames.clear();
    let dt = clip.frame_time_s;
    out.frame_time_s = dt;
    out.sites = options.sites;
    let sites = options.sites;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(SynthesisError::InvalidFrameTime { frame_time_s: dt });
    }
    let n = clip.poses.len();
    if n < MIN_FRAMES {
        return Err(SynthesisError::TooFewFrames {
            frames: n,
            needed: MIN_FRAMES,
        });
    }
    if let Some(frame) = clip.poses.iter().position(|p| !p.is_finite()) {
        return Err(SynthesisError::NonFinitePose { frame });
    }
    if let Some(a) = &options.augmentation {
        a.config.validate()?;
    }
    out.frames.resize(n, [ImuSample::zero(); MAX_SITES]);

    let mut noise = options
        .augmentation
        .map(|a| NoiseState::new(&a.config, a.seed, dt, sites));

    // Pass 1: true sensor orientations and positions (with the mounting errors).
    let mut fk = FkData::new();
    for (t, (pose, frame)) in clip.poses.iter().zip(out.frames.iter_mut()).enumerate() {
        forward_kinematics(&body.skeleton, pose, &mut fk);
        if let Some(ns) = noise.as_mut() {
            ns.step_mounting(t);
        }
        for imu in sites.sites() {
            let s = imu.index();
            let joint = imu.joint();
            let model_from_bone = fk.world_from(joint);
            let offset = body.imu_offsets_in_joint_m[s];
            let sample = &mut frame[s];
            match noise.as_ref() {
                None => {
                    sample.model_from_sensor = *model_from_bone;
                    sample.position_in_model_m = fk.position(joint) + model_from_bone * offset;
                }
                Some(ns) => {
                    let dw = ns.mount_rot_const[s] + ns.mount_rot_walk[s];
                    sample.model_from_sensor = if dw == Vector3::zeros() {
                        *model_from_bone
                    } else {
                        model_from_bone * Rotation3::new(dw)
                    };
                    let dp = ns.mount_pos_const[s] + ns.mount_pos_walk[s];
                    sample.position_in_model_m =
                        fk.position(joint) + model_from_bone * (offset + dp);
                }
            }
        }
    }

    // Pass 2: free acceleration (true) and pass 3: sensor-frame angular velocity (true).
    for s in sites.sites().map(Imu::index) {
        for t in 0..n {
            let a = accel_at(&out.frames, s, t, dt, options.stencil);
            let w = angular_velocity_at(&out.frames, s, t, dt);
            out.frames[t][s].free_accel_in_model_mps2 = a;
            out.frames[t][s].angular_velocity_in_sensor_radps = w;
        }
    }

    // Pass 4: measurements, noise and the network-frame quantities.
    let g = GRAVITY_IN_MODEL_MPS2;
    for (t, frame) in out.frames.iter_mut().enumerate() {
        if let Some(ns) = noise.as_mut() {
            ns.step_sensors(t);
        }
        for s in sites.sites().map(Imu::index) {
            let sample = &mut frame[s];
            let true_model_from_sensor = sample.model_from_sensor;
            let a = sample.free_accel_in_model_mps2;
            let specific_force = true_model_from_sensor.transpose() * (a - g);
            let gyro = sample.angular_velocity_in_sensor_radps;
            match noise.as_mut() {
                None => {
                    sample.specific_force_in_sensor_mps2 = specific_force;
                    sample.angular_velocity_in_model_radps = true_model_from_sensor * gyro;
                }
                Some(ns) => {
                    let accel_error = ns.accel_bias[s] + ns.gaussian3(ns.accel_noise_sigma);
                    let gyro_error = ns.gyro_bias[s] + ns.gaussian3(ns.gyro_noise_sigma);
                    let heading = ns.heading[s];
                    let reported = if heading == 0.0 {
                        true_model_from_sensor
                    } else {
                        Axis::Y.rotation(heading) * true_model_from_sensor
                    };
                    let measured_gyro = gyro + gyro_error;
                    sample.model_from_sensor = reported;
                    sample.specific_force_in_sensor_mps2 = specific_force + accel_error;
                    sample.angular_velocity_in_sensor_radps = measured_gyro;
                    sample.angular_velocity_in_model_radps = reported * measured_gyro;
                    // a_M = R̃·ã_S + g = R_y(ψ)(a − g) + g + R̃·e = a + (R_y(ψ) − I)(a − g) + R̃·e,
                    // written so that zero augmentation gives `a` bit for bit.
                    let heading_term = if heading == 0.0 {
                        Vector3::zeros()
                    } else {
                        (Axis::Y.rotation(heading).matrix() - nalgebra::Matrix3::identity())
                            * (a - g)
                    };
                    sample.free_accel_in_model_mps2 = a + heading_term + reported * accel_error;
                }
            }
        }
    }
    Ok(())
}

/// Second difference of sensor `s`'s positions at frame `t` (needs ≥ [`MIN_FRAMES`] frames).
fn accel_at(
    frames: &[[ImuSample; MAX_SITES]],
    s: usize,
    t: usize,
    dt: f64,
    stencil: AccelStencil,
) -> Vector3<f64> {
    let n = frames.len();
    let p = |i: usize| frames[i][s].position_in_model_m;
    // Written as sums of differences so that a still sensor gives exactly 0.
    let centred = |h: usize| ((p(t - h) - p(t)) + (p(t + h) - p(t))) / ((h as f64 * dt).powi(2));
    match stencil {
        AccelStencil::SmoothedTransPose => {
            let h = TRANSPOSE_SMOOTHING_FRAMES;
            if t == 0 || t + 1 == n {
                Vector3::zeros()
            } else if t >= h && t + h < n {
                centred(h)
            } else {
                centred(1)
            }
        }
        AccelStencil::Central => {
            if t > 0 && t + 1 < n {
                centred(1)
            } else if n >= 4 {
                let (a, b, c, d) = if t == 0 {
                    (p(0), p(1), p(2), p(3))
                } else {
                    (p(n - 1), p(n - 2), p(n - 3), p(n - 4))
                };
                (2.0 * (a - b) - 3.0 * (b - c) + (c - d)) / (dt * dt)
            } else {
                // Exactly 3 frames: both ends take the only second difference.
                ((p(0) - p(1)) + (p(2) - p(1))) / (dt * dt)
            }
        }
    }
}

/// Sensor-frame angular velocity of sensor `s` at frame `t` from the orientations (see
/// [`synthesize_imus`]; needs ≥ [`MIN_FRAMES`] frames).
fn angular_velocity_at(
    frames: &[[ImuSample; MAX_SITES]],
    s: usize,
    t: usize,
    dt: f64,
) -> Vector3<f64> {
    let n = frames.len();
    let r = |i: usize| &frames[i][s].model_from_sensor;
    // Rotation vector of R_iᵀR_j.
    let log = |i: usize, j: usize| axis_angle_from_rotation(&(r(i).transpose() * r(j)));
    if t > 0 && t + 1 < n {
        log(t - 1, t + 1) / (2.0 * dt)
    } else if t == 0 {
        (1.5 * log(0, 1) - 0.5 * log(1, 2)) / dt
    } else {
        (1.5 * log(n - 2, n - 1) - 0.5 * log(n - 3, n - 2)) / dt
    }
}

/// Random state of the augmentation model. Draw order (fixed, so a seed fixes the output), sensors
/// in slot order: per sensor the constant mounting rotation then position error; per frame the
/// mounting walks of all sensors (pass 1); per frame the bias/heading walks of all sensors, then per
/// sensor the accelerometer and gyro white noise (pass 4).
struct NoiseState {
    rng: StdRng,
    sites: SiteMask,
    mount_rot_const: [Vector3<f64>; MAX_SITES],
    mount_pos_const: [Vector3<f64>; MAX_SITES],
    mount_rot_walk: [Vector3<f64>; MAX_SITES],
    mount_pos_walk: [Vector3<f64>; MAX_SITES],
    accel_bias: [Vector3<f64>; MAX_SITES],
    gyro_bias: [Vector3<f64>; MAX_SITES],
    heading: [f64; MAX_SITES],
    // Per-step / per-sample standard deviations (per axis).
    mount_rot_step_sigma: f64,
    mount_pos_step_sigma: f64,
    accel_noise_sigma: f64,
    accel_bias_step_sigma: f64,
    gyro_noise_sigma: f64,
    gyro_bias_step_sigma: f64,
    heading_step_sigma: f64,
}

impl NoiseState {
    fn new(c: &AugmentationConfig, seed: u64, dt: f64, sites: SiteMask) -> NoiseState {
        let k = MEAN_NORM_TO_SIGMA;
        let sqrt_dt = dt.sqrt();
        let mut ns = NoiseState {
            rng: StdRng::seed_from_u64(seed),
            sites,
            mount_rot_const: [Vector3::zeros(); MAX_SITES],
            mount_pos_const: [Vector3::zeros(); MAX_SITES],
            mount_rot_walk: [Vector3::zeros(); MAX_SITES],
            mount_pos_walk: [Vector3::zeros(); MAX_SITES],
            accel_bias: [Vector3::zeros(); MAX_SITES],
            gyro_bias: [Vector3::zeros(); MAX_SITES],
            heading: [0.0; MAX_SITES],
            mount_rot_step_sigma: k * c.mounting_rotation_walk_rad_per_sqrt_s * sqrt_dt,
            mount_pos_step_sigma: k * c.mounting_position_walk_m_per_sqrt_s * sqrt_dt,
            accel_noise_sigma: c.accel_noise_mps2,
            accel_bias_step_sigma: c.accel_bias_walk_mps2_per_sqrt_s * sqrt_dt,
            gyro_noise_sigma: c.gyro_noise_radps,
            gyro_bias_step_sigma: c.gyro_bias_walk_radps_per_sqrt_s * sqrt_dt,
            heading_step_sigma: c.heading_drift_rad_per_sqrt_s * sqrt_dt,
        };
        for s in sites.sites().map(Imu::index) {
            ns.mount_rot_const[s] = ns.gaussian3(k * c.mounting_rotation_error_rad);
            ns.mount_pos_const[s] = ns.gaussian3(k * c.mounting_position_error_m);
        }
        ns
    }

    fn gaussian(&mut self, sigma: f64) -> f64 {
        let z: f64 = self.rng.sample(StandardNormal);
        sigma * z
    }

    fn gaussian3(&mut self, sigma: f64) -> Vector3<f64> {
        let x = self.gaussian(sigma);
        let y = self.gaussian(sigma);
        let z = self.gaussian(sigma);
        Vector3::new(x, y, z)
    }

    /// Mounting random walks; frame 0 keeps the constant errors only.
    fn step_mounting(&mut self, t: usize) {
        if t == 0 {
            return;
        }
        for s in self.sites.sites().map(Imu::index) {
            let step = self.gaussian3(self.mount_rot_step_sigma);
            self.mount_rot_walk[s] += step;
            let step = self.gaussian3(self.mount_pos_step_sigma);
            self.mount_pos_walk[s] += step;
        }
    }

    /// Bias and heading random walks (zero at frame 0: calibrated at the start).
    fn step_sensors(&mut self, t: usize) {
        if t == 0 {
            return;
        }
        for s in self.sites.sites().map(Imu::index) {
            let step = self.gaussian3(self.accel_bias_step_sigma);
            self.accel_bias[s] += step;
            let step = self.gaussian3(self.gyro_bias_step_sigma);
            self.gyro_bias[s] += step;
            let step = self.gaussian(self.heading_step_sigma);
            self.heading[s] += step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::random_rotations;
    use approx::assert_relative_eq;
    use imuflow_body::body_model::BodyParams;
    use imuflow_body::kinematics::Pose;
    use imuflow_body::rotation::{angle_between, slerp};
    use imuflow_body::skeleton::{JointId, NUM_IMUS, NUM_JOINTS};
    use std::f64::consts::PI;

    const DT: f64 = 1.0 / 60.0;
    const G: f64 = 9.81;

    /// The reference subject: IMU offsets are body.toml's numbers unscaled.
    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.741, 73.0).unwrap()
    }

    fn clip(poses: Vec<Pose>) -> MotionClip {
        MotionClip {
            frame_time_s: DT,
            poses,
        }
    }

    fn ideal(stencil: AccelStencil) -> SynthesisOptions {
        SynthesisOptions {
            stencil,
            augmentation: None,
            ..SynthesisOptions::default()
        }
    }

    fn augmented(config: AugmentationConfig, seed: u64) -> SynthesisOptions {
        SynthesisOptions {
            stencil: AccelStencil::SmoothedTransPose,
            augmentation: Some(Augmentation { config, seed }),
            ..SynthesisOptions::default()
        }
    }

    const STENCILS: [AccelStencil; 2] = [AccelStencil::Central, AccelStencil::SmoothedTransPose];

    /// A clip where every joint moves: slerp between two random poses, root on a curve.
    fn busy_clip(n: usize) -> MotionClip {
        let a = random_rotations(NUM_JOINTS, 5);
        let b = random_rotations(NUM_JOINTS, 6);
        let poses = (0..n)
            .map(|t| {
                let s = t as f64 / (n - 1) as f64;
                let mut p = Pose::t_pose(Vector3::new(s.sin(), 0.9 + 0.1 * s * s, 2.0 * s));
                for j in 0..NUM_JOINTS {
                    p.parent_from_joint[j] = slerp(&a[j], &b[j], s);
                }
                p
            })
            .collect();
        clip(poses)
    }

    #[test]
    fn a_set_synthesizes_its_sites_on_their_bones_and_leaves_the_rest_empty() {
        let body = body();
        let clip = busy_clip(30);
        let six = synthesize_imus(&clip, &body, &SynthesisOptions::default()).unwrap();
        let suit_options = SynthesisOptions {
            sites: SiteMask::of(Imu::CATALOGUE),
            ..SynthesisOptions::default()
        };
        let suit = synthesize_imus(&clip, &body, &suit_options).unwrap();
        let mut fk = FkData::new();
        for (t, (a, b)) in six.frames.iter().zip(&suit.frames).enumerate() {
            // Ideal signals of a site do not depend on which other sites are synthesized.
            assert_eq!(a[..NUM_IMUS], b[..NUM_IMUS]);
            forward_kinematics(&body.skeleton, &clip.poses[t], &mut fk);
            for imu in Imu::CATALOGUE {
                let s = &b[imu.index()];
                // Each sensor rides its bone: the ideal sensor frame is the bone frame, at the
                // body model's placement.
                assert!(angle_between(&s.model_from_sensor, fk.world_from(imu.joint())) < 1e-12);
                let expected = fk.position(imu.joint())
                    + fk.world_from(imu.joint()) * body.imu_offsets_in_joint_m[imu.index()];
                assert_relative_eq!(s.position_in_model_m, expected, epsilon = 1e-12);
            }
            for empty in &a[NUM_IMUS..] {
                assert_eq!(*empty, ImuSample::zero());
            }
        }
        assert_eq!(six.sites, SiteMask::of(Imu::SIX));
        assert_eq!(suit.sites.len(), MAX_SITES);
        // Augmented, a seed fixes a set's draws.
        let config = AugmentationConfig::default();
        let legs = SiteMask::of([Imu::Pelvis, Imu::LeftUpperLeg, Imu::RightUpperLeg]);
        let run = || {
            synthesize_imus(
                &clip,
                &body,
                &SynthesisOptions {
                    sites: legs,
                    ..augmented(config, 3)
                },
            )
            .unwrap()
        };
        let (x, y) = (run(), run());
        assert_eq!(x, y);
        assert_ne!(
            x.frames[5][Imu::LeftUpperLeg.index()],
            x.frames[5][Imu::RightUpperLeg.index()]
        );
        assert_eq!(x.frames[5][Imu::Head.index()], ImuSample::zero());
    }

    #[test]
    fn uniform_circular_motion_gives_centripetal_acceleration() {
        let body = body();
        let (r, w) = (1.5, PI); // radius (m), angular speed (rad/s)
        let n = 121;
        let centre = Vector3::new(0.0, 1.0, 0.0);
        let yaw = Axis::Y.rotation(0.5); // fixed, not the identity
        let poses: Vec<Pose> = (0..n)
            .map(|t| {
                let phi = w * t as f64 * DT;
                let mut p = Pose::t_pose(centre + Vector3::new(r * phi.cos(), 0.0, r * phi.sin()));
                p.parent_from_joint[0] = yaw;
                p
            })
            .collect();
        let clip = clip(poses);
        let pelvis = Imu::Pelvis.index();
        // Fixed orientation: the sensor circles a centre shifted by its constant offset.
        let sensor_centre = centre + yaw * body.imu_offsets_in_joint_m[pelvis];
        for stencil in STENCILS {
            let out = synthesize_imus(&clip, &body, &ideal(stencil)).unwrap();
            for (t, frame) in out.frames.iter().enumerate() {
                let s = &frame[pelvis];
                let a = s.free_accel_in_model_mps2;
                let is_end = t == 0 || t == n - 1;
                if stencil == AccelStencil::SmoothedTransPose && is_end {
                    assert_eq!(a, Vector3::zeros(), "frame {t}: reference zeroes the ends");
                    continue;
                }
                // Second differences of a sinusoid shrink it by 4·sin²(ωh/2)/(ωh)² ≈ 1 − (ωh)²/12:
                // 0.37 % for the n = 4 window (h = 4dt), 0.02 % for n = 1; the central stencil's
                // one-sided ends err by (11/12)(ω·dt)² = 0.25 %. Tolerance 0.5 %.
                assert_relative_eq!(a.norm(), w * w * r, max_relative = 5e-3);
                let to_centre = sensor_centre - s.position_in_model_m;
                assert_relative_eq!(to_centre.norm(), r, epsilon = 1e-12);
                assert!(
                    a.normalize().dot(&to_centre.normalize()) > 1.0 - 1e-6,
                    "frame {t}"
                );
                // Specific force: +g up (sensor y = M y under a yaw), horizontal part = a in S axes.
                let f = s.specific_force_in_sensor_mps2;
                assert_relative_eq!(f.y, G, epsilon = 1e-9);
                assert_relative_eq!(
                    f,
                    s.model_from_sensor.transpose() * a + Vector3::new(0.0, G, 0.0),
                    epsilon = 1e-12
                );
                // Orientation fixed: no rotation.
                assert!(s.angular_velocity_in_model_radps.norm() < 1e-9);
            }
        }
    }

    #[test]
    fn forearm_rotating_at_a_constant_rate_has_that_angular_velocity() {
        let body = body();
        let rate = 2.0; // rad/s about the elbow's local y axis
        let n = 30;
        let tilt = Axis::X.rotation(0.3) * Axis::Z.rotation(-0.7);
        let poses: Vec<Pose> = (0..n)
            .map(|t| {
                let mut p = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
                p.parent_from_joint[JointId::ROOT.index()] = Axis::Y.rotation(1.0);
                p.parent_from_joint[JointId::LEFT_SHOULDER.index()] = tilt;
                p.parent_from_joint[JointId::LEFT_ELBOW.index()] =
                    Axis::Y.rotation(-0.2 + rate * t as f64 * DT);
                p
            })
            .collect();
        let clip = clip(poses);
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &clip.poses[0], &mut fk);
        // The elbow's parent frame is fixed, so ω_M = R_M,shoulder · (0, rate, 0).
        let expected_m = fk.world_from(JointId::LEFT_SHOULDER) * Vector3::new(0.0, rate, 0.0);
        let out = synthesize_imus(&clip, &body, &ideal(AccelStencil::Central)).unwrap();
        for (t, frame) in out.frames.iter().enumerate() {
            let s = &frame[Imu::LeftForearm.index()];
            assert_relative_eq!(
                s.angular_velocity_in_sensor_radps,
                Vector3::new(0.0, rate, 0.0),
                epsilon = 1e-9
            );
            assert_relative_eq!(
                s.angular_velocity_in_model_radps,
                expected_m,
                epsilon = 1e-9
            );
            // Nothing else moves.
            let other = &frame[Imu::RightForearm.index()];
            assert!(
                other.angular_velocity_in_model_radps.norm() < 1e-9,
                "frame {t}"
            );
        }
    }

    #[test]
    fn static_pose_has_zero_motion_and_gravity_only_specific_force() {
        let body = body();
        let rots = random_rotations(NUM_JOINTS, 11);
        let mut pose = Pose::t_pose(Vector3::new(0.2, 0.9, -0.4));
        pose.parent_from_joint.copy_from_slice(&rots);
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        let clip = clip(vec![pose; 12]);
        for stencil in STENCILS {
            let out = synthesize_imus(&clip, &body, &ideal(stencil)).unwrap();
            assert_eq!(out.frames.len(), 12);
            for frame in &out.frames {
                for imu in Imu::SIX {
                    let s = &frame[imu.index()];
                    let r = fk.world_from(imu.joint());
                    assert_eq!(s.model_from_sensor, *r);
                    assert_eq!(s.free_accel_in_model_mps2, Vector3::zeros());
                    assert_relative_eq!(
                        s.specific_force_in_sensor_mps2,
                        r.transpose() * Vector3::new(0.0, G, 0.0),
                        epsilon = 1e-12
                    );
                    assert!(s.angular_velocity_in_sensor_radps.norm() < 1e-12);
                    assert!(s.angular_velocity_in_model_radps.norm() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn t_pose_sensor_positions_are_joint_plus_body_toml_offset() {
        let body = body();
        let root = Vector3::new(0.1, 0.95, 0.2);
        let out = synthesize_imus(
            &clip(vec![Pose::t_pose(root); 3]),
            &body,
            &ideal(AccelStencil::Central),
        )
        .unwrap();
        // Left forearm by hand: the elbow is the sum of the bone offsets from the root (all rotations are
        // the identity), plus body.toml's [imus.left_forearm] offset (0.20, 0.03, 0.0) at the reference
        // stature (scale 1).
        let sk = &body.skeleton;
        let elbow = root
            + [
                JointId::SPINE1,
                JointId::SPINE2,
                JointId::SPINE3,
                JointId::LEFT_COLLAR,
                JointId::LEFT_SHOULDER,
                JointId::LEFT_ELBOW,
            ]
            .iter()
            .map(|j| sk.offset_in_parent_m(*j))
            .sum::<Vector3<f64>>();
        assert_relative_eq!(
            out.frames[1][Imu::LeftForearm.index()].position_in_model_m,
            elbow + Vector3::new(0.20, 0.03, 0.0),
            epsilon = 1e-12
        );
        // Every sensor: rest joint position + offset, sensor frame = M.
        let rest = sk.rest_positions_from_root_m();
        for imu in Imu::SIX {
            let s = &out.frames[0][imu.index()];
            assert_relative_eq!(
                s.position_in_model_m,
                root + rest[imu.joint().index()] + body.imu_offsets_in_joint_m[imu.index()],
                epsilon = 1e-12
            );
            assert_eq!(s.model_from_sensor, Rotation3::identity());
        }
    }

    /// Pelvis sensor accelerations for a root trajectory `p(t)` with the T-pose orientation.
    fn pelvis_accels(
        n: usize,
        p: impl Fn(f64) -> Vector3<f64>,
        stencil: AccelStencil,
    ) -> Vec<Vector3<f64>> {
        let poses = (0..n).map(|t| Pose::t_pose(p(t as f64 * DT))).collect();
        synthesize_imus(&clip(poses), &body(), &ideal(stencil))
            .unwrap()
            .frames
            .iter()
            .map(|f| f[Imu::Pelvis.index()].free_accel_in_model_mps2)
            .collect()
    }

    #[test]
    fn stencils_are_exact_on_a_quadratic_with_the_reference_boundaries() {
        let a = Vector3::new(0.7, -0.3, 1.2);
        let n = 20;
        let quad = |t: f64| Vector3::new(0.0, 1.0, 0.0) + a * t * t;
        let smooth = pelvis_accels(n, quad, AccelStencil::SmoothedTransPose);
        for (t, acc) in smooth.iter().enumerate() {
            if t == 0 || t == n - 1 {
                assert_eq!(*acc, Vector3::zeros(), "frame {t}");
            } else {
                assert_relative_eq!(*acc, 2.0 * a, epsilon = 1e-9);
            }
        }
        // The central stencil's one-sided 4-point ends are exact up to cubics.
        for acc in pelvis_accels(n, quad, AccelStencil::Central) {
            assert_relative_eq!(acc, 2.0 * a, epsilon = 1e-9);
        }
        // Which window each frame uses: on p = t⁴, (p(t−h) + p(t+h) − 2p(t))/h² = 12t² + 2h², so frames
        // [4, N−5] show h = 4dt and frames 1..3 and N−4..N−2 show h = dt (reference §3).
        let quartic = |t: f64| Vector3::new(0.0, t.powi(4), 0.0);
        let smooth = pelvis_accels(n, quartic, AccelStencil::SmoothedTransPose);
        for (t, acc) in smooth.iter().enumerate().take(n - 1).skip(1) {
            let h = if (4..=n - 5).contains(&t) {
                4.0 * DT
            } else {
                DT
            };
            let tt = t as f64 * DT;
            assert_relative_eq!(acc.y, 12.0 * tt * tt + 2.0 * h * h, epsilon = 1e-8);
        }
    }

    #[test]
    fn three_frames_are_enough_and_shorter_clips_are_typed_errors() {
        let body = body();
        let quad = |t: f64| Vector3::new(0.3 * t * t, 1.0, 0.0);
        for acc in pelvis_accels(3, quad, AccelStencil::Central) {
            assert_relative_eq!(acc, Vector3::new(0.6, 0.0, 0.0), epsilon = 1e-9);
        }
        let smooth = pelvis_accels(3, quad, AccelStencil::SmoothedTransPose);
        assert_eq!(smooth[0], Vector3::zeros());
        assert_relative_eq!(smooth[1], Vector3::new(0.6, 0.0, 0.0), epsilon = 1e-9);
        for frames in 0..3 {
            let err = synthesize_imus(
                &clip(vec![Pose::default(); frames]),
                &body,
                &ideal(AccelStencil::Central),
            );
            assert_eq!(err, Err(SynthesisError::TooFewFrames { frames, needed: 3 }));
        }
        let mut poses = vec![Pose::default(); 10];
        poses[5].parent_from_joint[7] =
            Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_element(f64::NAN));
        assert_eq!(
            synthesize_imus(&clip(poses.clone()), &body, &ideal(AccelStencil::Central)),
            Err(SynthesisError::NonFinitePose { frame: 5 })
        );
        poses[5] = Pose::t_pose(Vector3::new(0.0, f64::INFINITY, 0.0));
        assert_eq!(
            synthesize_imus(&clip(poses), &body, &ideal(AccelStencil::Central)),
            Err(SynthesisError::NonFinitePose { frame: 5 })
        );
        let mut bad = clip(vec![Pose::default(); 5]);
        bad.frame_time_s = 0.0;
        assert!(matches!(
            synthesize_imus(&bad, &body, &ideal(AccelStencil::Central)),
            Err(SynthesisError::InvalidFrameTime { .. })
        ));
        let config = AugmentationConfig {
            gyro_noise_radps: -1.0,
            ..AugmentationConfig::NONE
        };
        assert_eq!(
            synthesize_imus(
                &clip(vec![Pose::default(); 5]),
                &body,
                &augmented(config, 1)
            ),
            Err(SynthesisError::InvalidConfig {
                field: "gyro_noise_radps",
                value: -1.0
            })
        );
    }

    #[test]
    fn augmentation_is_deterministic_per_seed_and_zero_config_is_ideal() {
        let body = body();
        let clip = busy_clip(90);
        let reference = augmented(AugmentationConfig::REFERENCE, 42);
        let a = synthesize_imus(&clip, &body, &reference).unwrap();
        let b = synthesize_imus(&clip, &body, &reference).unwrap();
        assert_eq!(a, b);
        let c =
            synthesize_imus(&clip, &body, &augmented(AugmentationConfig::REFERENCE, 43)).unwrap();
        for t in [0, 45, 89] {
            for s in 0..NUM_IMUS {
                assert_ne!(
                    a.frames[t][s].model_from_sensor,
                    c.frames[t][s].model_from_sensor
                );
                assert_ne!(
                    a.frames[t][s].specific_force_in_sensor_mps2,
                    c.frames[t][s].specific_force_in_sensor_mps2
                );
            }
        }
        let ideal_out =
            synthesize_imus(&clip, &body, &ideal(AccelStencil::SmoothedTransPose)).unwrap();
        let zero = synthesize_imus(&clip, &body, &augmented(AugmentationConfig::NONE, 42)).unwrap();
        assert_eq!(zero, ideal_out);
        // The reference augmentation does change the signals, by plausible amounts.
        let mut max_da: f64 = 0.0;
        for (x, y) in a.frames.iter().zip(&ideal_out.frames) {
            for s in 0..NUM_IMUS {
                let d = angle_between(&x[s].model_from_sensor, &y[s].model_from_sensor);
                assert!(d > 0.0 && d < 0.5, "orientation error {d} rad");
                max_da = max_da
                    .max((x[s].free_accel_in_model_mps2 - y[s].free_accel_in_model_mps2).norm());
            }
        }
        assert!(max_da > 0.05 && max_da < 5.0, "max accel change {max_da}");
    }

    /// Static T-pose clip of `n` frames.
    fn still(n: usize) -> MotionClip {
        clip(vec![Pose::t_pose(Vector3::new(0.0, 1.0, 0.0)); n])
    }

    /// Sample mean and standard deviation.
    fn mean_std(x: &[f64]) -> (f64, f64) {
        let m = x.iter().sum::<f64>() / x.len() as f64;
        let v = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64;
        (m, v.sqrt())
    }

    #[test]
    fn white_noise_has_the_configured_standard_deviation() {
        let body = body();
        let clip = still(2001);
        let ideal_out =
            synthesize_imus(&clip, &body, &ideal(AccelStencil::SmoothedTransPose)).unwrap();
        let config = AugmentationConfig {
            accel_noise_mps2: 0.05,
            gyro_noise_radps: 0.005,
            ..AugmentationConfig::NONE
        };
        let out = synthesize_imus(&clip, &body, &augmented(config, 3)).unwrap();
        let (mut ea, mut eg, mut em) = (Vec::new(), Vec::new(), Vec::new());
        for (x, y) in out.frames.iter().zip(&ideal_out.frames) {
            for s in 0..NUM_IMUS {
                ea.extend(
                    (x[s].specific_force_in_sensor_mps2 - y[s].specific_force_in_sensor_mps2)
                        .iter(),
                );
                eg.extend(
                    (x[s].angular_velocity_in_sensor_radps - y[s].angular_velocity_in_sensor_radps)
                        .iter(),
                );
                em.extend((x[s].free_accel_in_model_mps2 - y[s].free_accel_in_model_mps2).iter());
            }
        }
        // n = 36 018 samples: the sample std's standard error is σ/√(2n) = 0.37 % of σ, the mean's σ/√n;
        // tolerances of 2 % and 5 standard errors.
        let n = ea.len() as f64;
        for (e, sigma) in [(&ea, 0.05), (&eg, 0.005), (&em, 0.05)] {
            let (m, sd) = mean_std(e);
            assert_relative_eq!(sd, sigma, max_relative = 0.02);
            assert!(m.abs() < 5.0 * sigma / n.sqrt(), "mean {m}");
        }
    }

    #[test]
    fn mounting_rotation_error_has_the_configured_scale() {
        let body = body();
        let clip = still(3);
        let scale = 0.1;
        let config = AugmentationConfig {
            mounting_rotation_error_rad: scale,
            ..AugmentationConfig::NONE
        };
        let mut angles = Vec::new();
        let mut axis_sum = Vector3::zeros();
        let mut out = SyntheticImus::default();
        for seed in 0..2000 {
            synthesize_imus_into(&clip, &body, &augmented(config, seed), &mut out).unwrap();
            for s in &out.frames[0][..NUM_IMUS] {
                // T-pose: the ideal sensor frame is M, so R_MS is the error itself.
                let v = axis_angle_from_rotation(&s.model_from_sensor);
                angles.push(v.norm());
                axis_sum += v.normalize();
            }
        }
        // Isotropic Gaussian rotation vector with per-axis σ = k·s: the angle is Maxwell distributed with
        // mean s, std ≈ 0.42 s and RMS √(3π/8)·s. 12 000 draws: standard error of the mean 0.39 % of s;
        // tolerance 2 %. The mean axis of isotropic unit vectors has per-axis std 1/√(3n) ≈ 0.005.
        let n = angles.len() as f64;
        let (m, _) = mean_std(&angles);
        assert_relative_eq!(m, scale, max_relative = 0.02);
        let rms = (angles.iter().map(|a| a * a).sum::<f64>() / n).sqrt();
        assert_relative_eq!(rms, (3.0 * PI / 8.0).sqrt() * scale, max_relative = 0.02);
        assert!((axis_sum / n).norm() < 0.03);
    }

    #[test]
    fn constant_mounting_rotation_changes_sensor_frame_rates_not_model_frame_rates() {
        let body = body();
        let clip = busy_clip(40);
        let ideal_out = synthesize_imus(&clip, &body, &ideal(AccelStencil::Central)).unwrap();
        let config = AugmentationConfig {
            mounting_rotation_error_rad: 0.3,
            ..AugmentationConfig::NONE
        };
        let mut opts = augmented(config, 9);
        opts.stencil = AccelStencil::Central;
        let out = synthesize_imus(&clip, &body, &opts).unwrap();
        for (x, y) in out.frames.iter().zip(&ideal_out.frames) {
            for s in 0..NUM_IMUS {
                // R_MS = R_MB·E with E constant: ω_M unchanged, ω_S = Eᵀ·ω_B.
                let e = y[s].model_from_sensor.transpose() * x[s].model_from_sensor;
                assert_relative_eq!(
                    x[s].angular_velocity_in_model_radps,
                    y[s].angular_velocity_in_model_radps,
                    epsilon = 1e-9
                );
                assert_relative_eq!(
                    x[s].angular_velocity_in_sensor_radps,
                    e.transpose() * y[s].angular_velocity_in_sensor_radps,
                    epsilon = 1e-9
                );
                assert_relative_eq!(
                    x[s].free_accel_in_model_mps2,
                    y[s].free_accel_in_model_mps2,
                    epsilon = 1e-9
                );
            }
        }
    }

    #[test]
    fn heading_drift_is_a_yaw_random_walk_of_the_configured_rate() {
        let body = body();
        let n = 601; // 10 s
        let clip = still(n);
        let sigma = 0.01;
        let config = AugmentationConfig {
            heading_drift_rad_per_sqrt_s: sigma,
            ..AugmentationConfig::NONE
        };
        let mut finals = Vec::new();
        let mut out = SyntheticImus::default();
        for seed in 0..200 {
            synthesize_imus_into(&clip, &body, &augmented(config, seed), &mut out).unwrap();
            for s in &out.frames[n - 1][..NUM_IMUS] {
                // T-pose: true R_MS = I, so the reported one is the drift: a rotation about y.
                let v = axis_angle_from_rotation(&s.model_from_sensor);
                assert!(v.x.abs() < 1e-12 && v.z.abs() < 1e-12);
                finals.push(v.y);
                // At rest the drift leaves the free acceleration at 0 (gravity is vertical).
                assert!(s.free_accel_in_model_mps2.norm() < 1e-12);
            }
        }
        // After 600 steps of σ·√dt the std is σ·√10 s. 1200 draws: standard error ≈ 2 %; tolerance 10 %.
        let (_, sd) = mean_std(&finals);
        assert_relative_eq!(sd, sigma * 10f64.sqrt(), max_relative = 0.1);
    }
}
