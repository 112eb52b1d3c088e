//! Raw sensor samples of a synthesized motion: what six consumer IMUs would deliver before any
//! on-board fusion — accelerometer, gyroscope and magnetometer samples at the sensors' own rate, on
//! their own clocks, delivered late and sometimes not at all — with the truth of every sample kept
//! for tests.
//!
//! **World frame W** (what the magnetometer's field is given in, and what a 9D fusion's
//! orientation refers to): z up, East-North-Up, the calibration stage's `z-up` convention with the
//! subject (facing +z in M) facing `heading_deg` right-handed about up from +x_W, as
//! [`crate::SensorSetup`] places its z-up frames: `R_WM = R_MI(heading)ᵀ` of
//! [`InertialFrame::ZUp`]. Its origin is M's, so the floor is z_W = 0. Magnetic north is +y_W: the
//! horizontal reference of VQF's 9D estimate (Laidig & Seel 2023; vqf-rs `update_mag` takes the
//! heading as atan2(m_x, m_y), which is 0 for a field along +y), so a 9D fusion's `R_ES` is `R_WS`
//! up to its errors.
//!
//! **Signals** of sensor k at a true time t (the source clock): the pose is the motion's clip
//! interpolated at t (slerp / lerp, as [`imuflow_motion::retarget::resample`]), and the IMU
//! synthesis ([`imuflow_motion::imu_synthesis::synthesize_imus`], ideal, the options' stencil)
//! runs on each sensor's own grid of sample times, so a noise-free raw stream equals the
//! `ImuFrame` synthesis at the sensor rate. With the sensor mounted as
//! [`crate::SensorFrames::ideal_from_sensor`] (`R_S'S`):
//! - accelerometer = specific force in S, `R_S'Sᵀ·f_S'` (m/s², +9.81 up at rest);
//! - gyroscope = angular rate in S, `R_S'Sᵀ·ω_S'` (rad/s);
//! - magnetometer = `R_WSᵀ·B_W(p)` (µT) with `R_WS = R_WM·R_MS'·R_S'S`, the earth field
//!   ([`EarthField`]) plus, when disturbed, the field of magnetized objects in the floor at the
//!   sensor's position p ([`MagneticDisturbance`]) and a hard-iron offset per sensor.
//!
//! **Sensor errors** ([`SensorNoise`], scaled by [`RawOptions::noise_scale`]): white noise, a
//! constant bias and a bias random walk on accelerometer and gyroscope, white noise on the
//! magnetometer.
//!
//! **Clocks and delivery.** Sensor k's clock reads `c_k(t) = E + o_k + (1 + d_k)·t` at source time
//! t, with its offset o_k uniform in ±[`RawOptions::clock_offset_ms`], its drift d_k uniform in
//! ±[`RawOptions::clock_drift_ppm`] and a common epoch E = `clock_offset_ms` that keeps every
//! reading ≥ 0 (with no offset configured the clocks start with the source's). The sensor samples when its
//! clock reads a whole multiple of the sample period 1/[`RawOptions::rate_hz`], so drift changes
//! the true sample times; `sample_time_ns` is that clock reading. A sample is lost with probability
//! [`RawOptions::loss`], and otherwise delivered at its true time plus a delay uniform in
//! 0..[`RawOptions::jitter_ms`].
//!
//! **Frames.** [`RawImuFrame`]s are built in delivery order, at most one sample per sensor each: a
//! sample starts a new frame when its sensor already has one in the current frame or when it came
//! more than half a sample period after the frame's first. `capture_ns` is the latest delivery time
//! in the frame (source clock, 0 at the start of the motion), `seq` the frame's index, PRELUDE set
//! when a sample in it was taken before the clip's first frame. `orientation_mask` is 0 (no
//! on-board fusion); `magnetometer_mask` has the bits of the samples with a magnetometer reading.

use anyhow::{Context, bail};
use imuflow_body::BodyModel;
use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::slerp;
use imuflow_body::{Imu, MAX_SITES};
use imuflow_graph::frames::{FrameHeader, RawImuFrame, flags};
use imuflow_motion::imu_synthesis::{AccelStencil, SynthesisOptions, synthesize_imus};
use imuflow_motion::retarget::MotionClip;
use nalgebra::{Rotation3, Vector2, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::{InertialFrame, Motion};

/// Which magnetometer the sensors have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Magnetometer {
    /// No magnetometer: `magnetometer_mask` stays 0.
    None,
    /// The earth field alone (and the magnetometer noise).
    #[default]
    Clean,
    /// The earth field plus the field of magnetized objects in the floor and a hard-iron offset
    /// per sensor.
    Disturbed,
}

impl Magnetometer {
    /// Names as in the imu-source's `raw_magnetometer` parameter.
    pub const NAMES: [&'static str; 3] = ["none", "clean", "disturbed"];

    /// Parses a name of [`Magnetometer::NAMES`].
    pub fn parse(name: &str) -> Option<Magnetometer> {
        match name {
            "none" => Some(Magnetometer::None),
            "clean" => Some(Magnetometer::Clean),
            "disturbed" => Some(Magnetometer::Disturbed),
            _ => None,
        }
    }
}

/// The undisturbed geomagnetic field, pointing north (+y_W) and down.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EarthField {
    /// Total intensity, µT. 50 µT: mid-latitude Europe (the geomagnetic field ranges from about 25
    /// to 65 µT over the earth).
    pub strength_ut: f64,
    /// Inclination (dip below the horizontal), degrees. 60°: mid-latitude northern hemisphere.
    pub inclination_deg: f64,
}

impl Default for EarthField {
    fn default() -> EarthField {
        EarthField {
            strength_ut: 50.0,
            inclination_deg: 60.0,
        }
    }
}

impl EarthField {
    /// The field in W (µT): `F·(0, cos I, −sin I)`.
    pub fn in_world_ut(&self) -> Vector3<f64> {
        let i = self.inclination_deg.to_radians();
        self.strength_ut * Vector3::new(0.0, i.cos(), -i.sin())
    }
}

/// Error magnitudes of one accelerometer/gyroscope/magnetometer, per axis, SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorNoise {
    /// Accelerometer white-noise density, m/s²/√Hz; per sample σ = density·√rate (the discrete form
    /// of continuous white noise, as in Kalibr's IMU noise model).
    pub accel_noise_density: f64,
    /// Accelerometer constant bias, per axis uniform in ±this, m/s².
    pub accel_bias_mps2: f64,
    /// Accelerometer bias random walk, m/s²/√s: per-sample step σ = this·√dt.
    pub accel_bias_walk: f64,
    /// Gyroscope white-noise density, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// Gyroscope constant bias, per axis uniform in ±this, rad/s.
    pub gyro_bias_radps: f64,
    /// Gyroscope bias random walk, rad/s/√s.
    pub gyro_bias_walk: f64,
    /// Magnetometer white noise per sample, µT.
    pub mag_noise_ut: f64,
}

/// Standard gravity, m/s² (what "g" means in a data sheet's mg).
const STANDARD_GRAVITY: f64 = 9.806_65;

impl SensorNoise {
    /// A consumer-grade MEMS IMU: the Bosch BMI160 (data sheet BST-BMI160-DS000, section 1
    /// "Specification", typical values): accelerometer output noise density 180 µg/√Hz and zero-g
    /// offset ±40 mg; gyroscope output noise density 0.007 °/s/√Hz and zero-rate offset ±3 °/s. The
    /// data sheet gives no bias random walk; its offset temperature coefficients (±1 mg/K,
    /// ±0.05 °/s/K) set it \[inferred\]: a 1σ walk after 60 s equal to the drift of a 1 K change.
    /// Magnetometer: 0.5 µT [chosen: the order of the RMS noise consumer magnetometers such as the
    /// BMM150 specify].
    pub const CONSUMER_MEMS: SensorNoise = SensorNoise {
        accel_noise_density: 180e-6 * STANDARD_GRAVITY,
        accel_bias_mps2: 40e-3 * STANDARD_GRAVITY,
        accel_bias_walk: 1e-3 * STANDARD_GRAVITY / 7.745_966_692_414_834, // / √60
        gyro_noise_density: 0.007 * std::f64::consts::PI / 180.0,
        gyro_bias_radps: 3.0 * std::f64::consts::PI / 180.0,
        gyro_bias_walk: 0.05 * std::f64::consts::PI / 180.0 / 7.745_966_692_414_834,
        mag_noise_ut: 0.5,
    };

    /// Every magnitude times `scale`.
    pub fn scaled(&self, scale: f64) -> SensorNoise {
        SensorNoise {
            accel_noise_density: self.accel_noise_density * scale,
            accel_bias_mps2: self.accel_bias_mps2 * scale,
            accel_bias_walk: self.accel_bias_walk * scale,
            gyro_noise_density: self.gyro_noise_density * scale,
            gyro_bias_radps: self.gyro_bias_radps * scale,
            gyro_bias_walk: self.gyro_bias_walk * scale,
            mag_noise_ut: self.mag_noise_ut * scale,
        }
    }
}

/// What to synthesize (the imu-source's `raw_*` parameters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawOptions {
    /// Sample rate of every sensor on its own clock, Hz.
    pub rate_hz: f64,
    /// Scale of [`SensorNoise::CONSUMER_MEMS`] (0: ideal sensors).
    pub noise_scale: f64,
    pub magnetometer: Magnetometer,
    pub field: EarthField,
    /// Each sensor's clock offset uniform in ±this, ms.
    pub clock_offset_ms: f64,
    /// Each sensor's clock drift uniform in ±this, parts per million.
    pub clock_drift_ppm: f64,
    /// Delivery delay of each sample uniform in 0..this, ms.
    pub jitter_ms: f64,
    /// Probability that a sample is lost.
    pub loss: f64,
    /// Seed of every draw (independent streams per effect, so turning one effect on or off leaves
    /// the others' draws as they were).
    pub seed: u64,
    /// The direction the subject faces in W, degrees (as
    /// [`crate::SensorSetup::frame_heading_deg`]).
    pub heading_deg: f64,
    /// Acceleration stencil of the synthesis.
    pub stencil: AccelStencil,
}

impl Default for RawOptions {
    fn default() -> RawOptions {
        RawOptions {
            rate_hz: 200.0,
            noise_scale: 0.0,
            magnetometer: Magnetometer::Clean,
            field: EarthField::default(),
            clock_offset_ms: 0.0,
            clock_drift_ppm: 0.0,
            jitter_ms: 0.0,
            loss: 0.0,
            seed: 0,
            heading_deg: 0.0,
            stencil: AccelStencil::default(),
        }
    }
}

impl RawOptions {
    /// Every value in its range; the error names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        let checks = [
            ("rate_hz", self.rate_hz, f64::MIN_POSITIVE, 1e6),
            ("noise_scale", self.noise_scale, 0.0, 1e3),
            ("clock_offset_ms", self.clock_offset_ms, 0.0, 1e9),
            ("clock_drift_ppm", self.clock_drift_ppm, 0.0, 1e5),
            ("jitter_ms", self.jitter_ms, 0.0, 1e6),
            ("loss", self.loss, 0.0, 0.999),
            ("field.strength_ut", self.field.strength_ut, 0.0, 1e4),
            (
                "field.inclination_deg",
                self.field.inclination_deg,
                -90.0,
                90.0,
            ),
            ("heading_deg", self.heading_deg, -1e4, 1e4),
        ];
        for (name, value, lo, hi) in checks {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                bail!("raw synthesis: {name} = {value} is outside {lo}..={hi}");
            }
        }
        Ok(())
    }

    /// The sample period on the sensors' clocks, ns.
    pub fn period_ns(&self) -> f64 {
        1e9 / self.rate_hz
    }
}

/// One sensor's clock: it reads `epoch_ns + offset_ns + (1 + drift)·t` at source time t (ns).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorClock {
    /// The common epoch E that keeps readings ≥ 0, ns.
    pub epoch_ns: f64,
    /// This sensor's offset o_k, ns.
    pub offset_ns: f64,
    /// This sensor's drift d_k (rate error, 1e-6 = 1 ppm).
    pub drift: f64,
}

impl SensorClock {
    /// The reading at source time `t_ns`.
    pub fn reading_ns(&self, t_ns: f64) -> f64 {
        self.epoch_ns + self.offset_ns + (1.0 + self.drift) * t_ns
    }

    /// The source time at which the clock reads `reading_ns`.
    pub fn source_time_ns(&self, reading_ns: f64) -> f64 {
        (reading_ns - self.epoch_ns - self.offset_ns) / (1.0 + self.drift)
    }
}

/// Magnetized objects under the floor (reinforcement, pipes, furniture fittings): point dipoles on
/// a jittered grid below the area the subject covers. A dipole's field falls off as 1/r³, so it
/// turns the field's direction by up to 20–30° near the floor (where the lower-leg sensors are) and
/// by a few degrees at most at head height, and it is curl- and divergence-free as a real field is.
#[derive(Clone, Debug, PartialEq)]
pub struct MagneticDisturbance {
    /// Dipole positions in W (m) and moments (A·m²).
    pub dipoles: Vec<(Vector3<f64>, Vector3<f64>)>,
}

impl MagneticDisturbance {
    /// Grid spacing of the dipoles, m.
    pub const SPACING_M: f64 = 1.2;
    /// Depth of the dipoles below the floor, m.
    pub const DEPTH_M: f64 = 0.25;
    /// Moment of each dipole, A·m² [chosen: the strongest disturbance 0.3 m above the floor turns
    /// the 25 µT horizontal field by about 20–30°, see the tests].
    pub const MOMENT_AM2: f64 = 14.0;
    /// μ0/4π in µT·m/A: `B = μ0/4π·(3(m·r̂)r̂ − m)/r³` in µT with m in A·m² and r in m.
    const MU0_OVER_4PI_UT: f64 = 0.1;

    /// Dipoles under the horizontal rectangle `min..max` of W (plus one spacing around it), each
    /// displaced by up to a third of the spacing and pointing in a uniformly random direction.
    pub fn draw(rng: &mut StdRng, min: Vector2<f64>, max: Vector2<f64>) -> MagneticDisturbance {
        let s = Self::SPACING_M;
        let count = |lo: f64, hi: f64| ((hi - lo) / s).ceil().max(0.0) as usize + 3;
        let (nx, ny) = (count(min.x, max.x), count(min.y, max.y));
        let mut dipoles = Vec::with_capacity(nx * ny);
        for i in 0..nx {
            for j in 0..ny {
                let jitter = Vector2::new(rng.random::<f64>(), rng.random::<f64>())
                    .map(|u| (u * 2.0 - 1.0) * s / 3.0);
                let at = Vector3::new(
                    min.x + (i as f64 - 1.0) * s + jitter.x,
                    min.y + (j as f64 - 1.0) * s + jitter.y,
                    -Self::DEPTH_M,
                );
                let dir: Vector3<f64> = Vector3::from_fn(|_, _| rng.sample(StandardNormal));
                dipoles.push((at, dir.normalize() * Self::MOMENT_AM2));
            }
        }
        MagneticDisturbance { dipoles }
    }

    /// The disturbance's field at `p` (W, m), µT.
    pub fn field_ut(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.dipoles
            .iter()
            .map(|(at, m)| {
                let r = p - at;
                let d = r.norm();
                let u = r / d;
                (3.0 * m.dot(&u) * u - m) * (Self::MU0_OVER_4PI_UT / (d * d * d))
            })
            .sum()
    }
}

/// One sample a sensor took, with its truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawSample {
    /// IMU index (IMU order).
    pub sensor: usize,
    /// Tick on the sensor's clock: it read `tick·period` when it took the sample.
    pub tick: u64,
    /// When the sample was taken, source clock, s.
    pub true_time_s: f64,
    /// The sensor's clock reading then, ns (what `sample_time_ns` carries).
    pub sample_time_ns: u64,
    /// When it was delivered, source clock, ns.
    pub delivery_ns: u64,
    /// True orientation `R_WS`.
    pub world_from_sensor: Rotation3<f64>,
    /// True position in W, m.
    pub position_in_world_m: Vector3<f64>,
    /// Accelerometer (specific force in S), m/s², errors included.
    pub accelerometer_mps2: Vector3<f64>,
    /// Gyroscope (angular rate in S), rad/s, errors included.
    pub gyroscope_radps: Vector3<f64>,
    /// Magnetometer (field in S), µT, errors included; `None` without a magnetometer.
    pub magnetometer_ut: Option<Vector3<f64>>,
    /// Taken before the clip's first frame.
    pub prelude: bool,
}

/// A synthesized raw session: the samples, the frames they are delivered in, and the truth of
/// every drawn quantity.
#[derive(Clone, Debug)]
pub struct RawSession {
    pub options: RawOptions,
    /// `R_WM`: model frame to the world frame.
    pub world_from_model: Rotation3<f64>,
    /// Each slot's clock (drawn for every slot, so a site's clock does not depend on the set).
    pub clocks: [SensorClock; MAX_SITES],
    /// Samples each sensor took (lost ones included); 0 for slots the motion's set leaves empty.
    pub ticks: [usize; MAX_SITES],
    /// Each sensor's constant accelerometer (m/s²) and gyroscope (rad/s) bias, in S.
    pub accel_bias_mps2: [Vector3<f64>; MAX_SITES],
    pub gyro_bias_radps: [Vector3<f64>; MAX_SITES],
    /// Each sensor's hard-iron offset, µT in S (zero unless disturbed).
    pub hard_iron_ut: [Vector3<f64>; MAX_SITES],
    /// The floor's field (disturbed magnetometer only).
    pub disturbance: Option<MagneticDisturbance>,
    /// The delivered samples, in delivery order.
    pub samples: Vec<RawSample>,
    /// The frames, in delivery order (`seq` = index).
    pub frames: Vec<RawImuFrame>,
}

// Distinct random streams (ASCII tags), so each effect's draws do not depend on the others'.
const CLOCK_STREAM: u64 = 0x636c_6f63_6b73_0000; // "clocks"
const NOISE_STREAM: u64 = 0x6e6f_6973_6500_0000; // "noise"
const DELIVERY_STREAM: u64 = 0x6465_6c69_7665_7279; // "delivery"
const MAGNET_STREAM: u64 = 0x6d61_676e_6574_0000; // "magnet"

impl RawSession {
    /// Synthesizes the raw samples of `motion` (its clip with prelude, at the graph's rate; worn as
    /// its sensors were drawn; the sites it synthesized) on `body`.
    pub fn synthesize(
        motion: &Motion,
        body: &BodyModel,
        options: &RawOptions,
    ) -> anyhow::Result<RawSession> {
        options.validate()?;
        let n = motion.len();
        if n < 2 {
            bail!("raw synthesis: the motion has {n} frames, it needs at least 2");
        }
        let frame_time_s = motion.clip.frame_time_s;
        let end_s = (n - 1) as f64 * frame_time_s;
        let world_from_model = InertialFrame::ZUp
            .model_from_inertial(options.heading_deg.to_radians())
            .transpose();
        let clocks = draw_clocks(options);
        let noise = SensorNoise::CONSUMER_MEMS.scaled(options.noise_scale);
        let mut magnet_rng = StdRng::seed_from_u64(options.seed ^ MAGNET_STREAM);
        let disturbance = (options.magnetometer == Magnetometer::Disturbed).then(|| {
            let (min, max) = floor_area(&motion.clip, &world_from_model);
            MagneticDisturbance::draw(&mut magnet_rng, min, max)
        });
        let hard_iron_ut: [Vector3<f64>; MAX_SITES] = std::array::from_fn(|_| {
            let v = uniform3(&mut magnet_rng, HARD_IRON_UT);
            if disturbance.is_some() {
                v
            } else {
                Vector3::zeros()
            }
        });
        let context = SensorContext {
            motion,
            body,
            options,
            world_from_model,
            noise,
            disturbance: disturbance.as_ref(),
            prelude_end_s: motion.prelude_frames as f64 * frame_time_s,
            end_s,
        };
        let mut session = RawSession {
            options: *options,
            world_from_model,
            clocks,
            ticks: [0; MAX_SITES],
            accel_bias_mps2: [Vector3::zeros(); MAX_SITES],
            gyro_bias_radps: [Vector3::zeros(); MAX_SITES],
            hard_iron_ut,
            disturbance: None,
            samples: Vec::new(),
            frames: Vec::new(),
        };
        for k in motion.sites.sites().map(Imu::index) {
            let sensor = context
                .sensor(k, &clocks[k], &hard_iron_ut[k])
                .with_context(|| format!("raw synthesis of sensor {k}"))?;
            session.ticks[k] = sensor.ticks;
            session.accel_bias_mps2[k] = sensor.accel_bias;
            session.gyro_bias_radps[k] = sensor.gyro_bias;
            session.samples.extend(sensor.samples);
        }
        session
            .samples
            .sort_by_key(|s| (s.delivery_ns, s.sample_time_ns, s.sensor));
        session.frames = build_frames(&session.samples, options.period_ns() / 2.0);
        session.disturbance = disturbance;
        Ok(session)
    }
}

/// Hard-iron offset per axis uniform in ±this, µT [chosen: a few µT left after a user's hard-iron
/// calibration; uncalibrated offsets of consumer magnetometers reach tens of µT].
pub const HARD_IRON_UT: f64 = 5.0;

/// Draws every sensor's clock (offset and drift, both drawn even when zero so the seed means the
/// same whatever is configured).
fn draw_clocks(options: &RawOptions) -> [SensorClock; MAX_SITES] {
    let mut rng = StdRng::seed_from_u64(options.seed ^ CLOCK_STREAM);
    let epoch_ns = options.clock_offset_ms * 1e6;
    std::array::from_fn(|_| {
        let offset = rng.random::<f64>() * 2.0 - 1.0;
        let drift = rng.random::<f64>() * 2.0 - 1.0;
        SensorClock {
            epoch_ns,
            offset_ns: offset * options.clock_offset_ms * 1e6,
            drift: drift * options.clock_drift_ppm * 1e-6,
        }
    })
}

/// The horizontal rectangle of W (m) the root covers over the clip.
fn floor_area(
    clip: &MotionClip,
    world_from_model: &Rotation3<f64>,
) -> (Vector2<f64>, Vector2<f64>) {
    let mut min = Vector2::repeat(f64::INFINITY);
    let mut max = Vector2::repeat(f64::NEG_INFINITY);
    for pose in &clip.poses {
        let p = world_from_model * pose.root_in_world_m;
        min = min.inf(&p.xy());
        max = max.sup(&p.xy());
    }
    (min, max)
}

/// Each component uniform in ±`half_width`.
fn uniform3(rng: &mut StdRng, half_width: f64) -> Vector3<f64> {
    Vector3::from_fn(|_, _| (rng.random::<f64>() * 2.0 - 1.0) * half_width)
}

/// Each component Gaussian with standard deviation `sigma`.
fn gaussian3(rng: &mut StdRng, sigma: f64) -> Vector3<f64> {
    Vector3::from_fn(|_, _| sigma * rng.sample::<f64, _>(StandardNormal))
}

/// What every sensor's synthesis shares.
struct SensorContext<'a> {
    motion: &'a Motion,
    body: &'a BodyModel,
    options: &'a RawOptions,
    world_from_model: Rotation3<f64>,
    noise: SensorNoise,
    disturbance: Option<&'a MagneticDisturbance>,
    prelude_end_s: f64,
    end_s: f64,
}

/// One sensor's delivered samples and its drawn biases.
struct SensorSamples {
    ticks: usize,
    accel_bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    samples: Vec<RawSample>,
}

impl SensorContext<'_> {
    /// Sensor `k`'s samples over the motion.
    fn sensor(
        &self,
        k: usize,
        clock: &SensorClock,
        hard_iron: &Vector3<f64>,
    ) -> anyhow::Result<SensorSamples> {
        let period_ns = self.options.period_ns();
        let (first_tick, times_s) = tick_times(clock, period_ns, self.end_s);
        let clip = MotionClip {
            frame_time_s: period_ns / (1.0 + clock.drift) * 1e-9,
            poses: times_s
                .iter()
                .map(|t| pose_at(&self.motion.clip, *t))
                .collect(),
        };
        let synthesis = SynthesisOptions {
            stencil: self.options.stencil,
            augmentation: None,
            ..SynthesisOptions::default()
        };
        let imus = synthesize_imus(&clip, self.body, &synthesis).with_context(|| {
            format!(
                "{} samples at {} Hz over {:.3} s",
                times_s.len(),
                self.options.rate_hz,
                self.end_s
            )
        })?;
        let mount = self.motion.sensors.ideal_from_sensor[k];
        let mut errors = SensorErrors::new(&self.noise, self.options, k);
        let mut delivery = StdRng::seed_from_u64(self.options.seed ^ DELIVERY_STREAM ^ k as u64);
        let earth = self.options.field.in_world_ut();
        let mut samples = Vec::with_capacity(times_s.len());
        for (n, (t, frame)) in times_s.iter().zip(&imus.frames).enumerate() {
            let s = &frame[k];
            let world_from_sensor = self.world_from_model * s.model_from_sensor * mount;
            let position = self.world_from_model * s.position_in_model_m;
            let (accel_error, gyro_error, mag_error) = errors.step();
            let magnetometer = (self.options.magnetometer != Magnetometer::None).then(|| {
                let field = earth
                    + self
                        .disturbance
                        .map_or(Vector3::zeros(), |d| d.field_ut(&position));
                world_from_sensor.transpose() * field + hard_iron + mag_error
            });
            // Both drawn for every tick, so loss does not shift the jitter draws and vice versa.
            let lost = delivery.random::<f64>() < self.options.loss;
            let delay_s = delivery.random::<f64>() * self.options.jitter_ms * 1e-3;
            if lost {
                continue;
            }
            let tick = first_tick + n as u64;
            samples.push(RawSample {
                sensor: k,
                tick,
                true_time_s: *t,
                sample_time_ns: (tick as f64 * period_ns).round() as u64,
                delivery_ns: ((t + delay_s) * 1e9).round() as u64,
                world_from_sensor,
                position_in_world_m: position,
                accelerometer_mps2: mount.transpose() * s.specific_force_in_sensor_mps2
                    + accel_error,
                gyroscope_radps: mount.transpose() * s.angular_velocity_in_sensor_radps
                    + gyro_error,
                magnetometer_ut: magnetometer,
                prelude: *t < self.prelude_end_s,
            });
        }
        Ok(SensorSamples {
            ticks: times_s.len(),
            accel_bias: errors.accel_bias,
            gyro_bias: errors.gyro_bias,
            samples,
        })
    }
}

/// The first tick index and the source times (s) of the ticks of `clock` in [0, `end_s`]: the
/// clock reads `tick·period_ns` at each.
fn tick_times(clock: &SensorClock, period_ns: f64, end_s: f64) -> (u64, Vec<f64>) {
    let first = (clock.reading_ns(0.0) / period_ns).ceil().max(0.0) as u64;
    let mut times = Vec::new();
    for tick in first.. {
        let t_s = clock.source_time_ns(tick as f64 * period_ns) * 1e-9;
        // The tick at 0 may come out a rounding error below it.
        if t_s > end_s + 1e-12 {
            break;
        }
        times.push(t_s.clamp(0.0, end_s));
    }
    (first, times)
}

/// The pose of `clip` at `t_s`: slerp of every rotation, lerp of the root between the two frames
/// around it (as `resample`).
fn pose_at(clip: &MotionClip, t_s: f64) -> Pose {
    let last = clip.poses.len() - 1;
    let x = (t_s / clip.frame_time_s).max(0.0);
    let i0 = (x.floor() as usize).min(last);
    let i1 = (i0 + 1).min(last);
    let u = (x - i0 as f64).clamp(0.0, 1.0);
    let (p0, p1) = (&clip.poses[i0], &clip.poses[i1]);
    let mut p = Pose::default();
    for (j, r) in p.parent_from_joint.iter_mut().enumerate() {
        *r = slerp(&p0.parent_from_joint[j], &p1.parent_from_joint[j], u);
    }
    p.root_in_world_m = p0.root_in_world_m.lerp(&p1.root_in_world_m, u);
    p
}

/// One sensor's error state: constant biases, their random walks, the white noise.
struct SensorErrors {
    rng: StdRng,
    accel_bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    accel_walk: Vector3<f64>,
    gyro_walk: Vector3<f64>,
    accel_sigma: f64,
    gyro_sigma: f64,
    mag_sigma: f64,
    accel_step: f64,
    gyro_step: f64,
    started: bool,
}

impl SensorErrors {
    fn new(noise: &SensorNoise, options: &RawOptions, k: usize) -> SensorErrors {
        let mut rng = StdRng::seed_from_u64(options.seed ^ NOISE_STREAM ^ k as u64);
        let sqrt_rate = options.rate_hz.sqrt();
        let sqrt_dt = 1.0 / sqrt_rate;
        SensorErrors {
            accel_bias: uniform3(&mut rng, noise.accel_bias_mps2),
            gyro_bias: uniform3(&mut rng, noise.gyro_bias_radps),
            rng,
            accel_walk: Vector3::zeros(),
            gyro_walk: Vector3::zeros(),
            accel_sigma: noise.accel_noise_density * sqrt_rate,
            gyro_sigma: noise.gyro_noise_density * sqrt_rate,
            mag_sigma: noise.mag_noise_ut,
            accel_step: noise.accel_bias_walk * sqrt_dt,
            gyro_step: noise.gyro_bias_walk * sqrt_dt,
            started: false,
        }
    }

    /// The accelerometer, gyroscope and magnetometer errors of the next sample (the walks start
    /// at 0 on the first).
    fn step(&mut self) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        if self.started {
            self.accel_walk += gaussian3(&mut self.rng, self.accel_step);
            self.gyro_walk += gaussian3(&mut self.rng, self.gyro_step);
        }
        self.started = true;
        let accel = self.accel_bias + self.accel_walk + gaussian3(&mut self.rng, self.accel_sigma);
        let gyro = self.gyro_bias + self.gyro_walk + gaussian3(&mut self.rng, self.gyro_sigma);
        let mag = gaussian3(&mut self.rng, self.mag_sigma);
        (accel, gyro, mag)
    }
}

/// Frames of `samples` (sorted by delivery): a new frame when the sensor already has a sample in
/// the current one or the sample came more than `max_span_ns` after the frame's first.
fn build_frames(samples: &[RawSample], max_span_ns: f64) -> Vec<RawImuFrame> {
    let mut frames: Vec<RawImuFrame> = Vec::new();
    let mut first_ns = 0;
    for s in samples {
        let bit = 1u32 << s.sensor;
        let start_new = match frames.last() {
            None => true,
            Some(f) => f.valid_mask & bit != 0 || (s.delivery_ns - first_ns) as f64 > max_span_ns,
        };
        if start_new {
            first_ns = s.delivery_ns;
            frames.push(RawImuFrame {
                header: FrameHeader {
                    seq: frames.len() as u64,
                    ..FrameHeader::default()
                },
                ..RawImuFrame::default()
            });
        }
        let Some(frame) = frames.last_mut() else {
            continue;
        };
        add_sample(frame, s, bit);
    }
    frames
}

/// Writes `s` into `frame` and moves its capture time to `s`'s delivery.
fn add_sample(frame: &mut RawImuFrame, s: &RawSample, bit: u32) {
    let k = s.sensor;
    frame.header.capture_ns = frame.header.capture_ns.max(s.delivery_ns);
    if s.prelude {
        frame.header.flags |= flags::PRELUDE;
    }
    frame.valid_mask |= bit;
    frame.sample_time_ns[k] = s.sample_time_ns;
    frame.accelerometer_mps2[k] = f32x3(&s.accelerometer_mps2);
    frame.gyroscope_radps[k] = f32x3(&s.gyroscope_radps);
    if let Some(m) = &s.magnetometer_ut {
        frame.magnetometer_mask |= bit;
        frame.magnetometer_ut[k] = f32x3(m);
    }
}

fn f32x3(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

#[cfg(test)]
mod tests;
