use std::path::{Path, PathBuf};

use imuflow_body::NUM_IMUS;
use imuflow_body::rotation::{angle_between, rotation_from_axis_angle, rotation_from_quat_wxyz};
use imuflow_graph::frames::flags;

use super::*;
use crate::prelude::{PreludeKind, PreludeOptions};
use crate::{Options, SensorSetup};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

/// Randomly mounted sensors in a z-up frame at heading 30°, with a `kind` prelude of 1 s stands.
fn options(kind: PreludeKind) -> Options {
    Options {
        prelude: PreludeOptions {
            kind,
            stand_s: 1.0,
            ..PreludeOptions::default()
        },
        sensors: SensorSetup {
            random_mounting: true,
            frame: InertialFrame::ZUp,
            frame_heading_deg: 30.0,
            heading_offset_deg: 0.0,
        },
        seed: 5,
        ..Options::default()
    }
}

fn body() -> BodyModel {
    crate::body_model(&Options::default()).expect("body")
}

fn motion(kind: PreludeKind, rate_hz: f64) -> Motion {
    Motion::load(&fixture(), &options(kind), rate_hz).expect("fixture loads")
}

fn raw(motion: &Motion, options: RawOptions) -> RawSession {
    RawSession::synthesize(motion, &body(), &options).expect("raw synthesis")
}

fn ideal() -> RawOptions {
    RawOptions {
        heading_deg: 30.0,
        ..RawOptions::default()
    }
}

fn v64(v: [f32; 3]) -> Vector3<f64> {
    Vector3::from(v.map(f64::from))
}

fn by_sensor(session: &RawSession, k: usize) -> Vec<RawSample> {
    let mut s: Vec<RawSample> = session
        .samples
        .iter()
        .filter(|s| s.sensor == k)
        .copied()
        .collect();
    s.sort_by(|a, b| a.true_time_s.total_cmp(&b.true_time_s));
    s
}

#[test]
fn noise_free_samples_equal_the_imu_synthesis_at_the_sensor_rate() {
    // The raw stream of the 60 Hz motion at 200 Hz against the ImuFrames of the same clip
    // resampled to 200 Hz by the motion crate and synthesized there: same mounting, same z-up
    // frame at the same heading. (Not the BVH loaded at 200 Hz: its rounded frame time,
    // 0.0333333 s, puts its frames a few µs off the 60 Hz clip's, which moves the 200 Hz
    // accelerations' spikes by up to 0.05 m/s².)
    let at_60 = motion(PreludeKind::None, 60.0);
    let clip = imuflow_motion::retarget::resample(&at_60.clip, 200.0).expect("resample");
    let at_200 = Motion::from_clip(clip, &body(), &options(PreludeKind::None)).expect("synthesis");
    let session = raw(&at_60, ideal());
    assert_eq!(session.samples.len(), NUM_IMUS * at_200.len());
    let (mut da, mut dw, mut dr) = (0.0f64, 0.0f64, 0.0f64);
    for s in &session.samples {
        let seq = s.tick as usize;
        assert!((s.true_time_s - seq as f64 / 200.0).abs() < 1e-12);
        assert_eq!(s.sample_time_ns, seq as u64 * 5_000_000);
        assert_eq!(s.delivery_ns, s.sample_time_ns);
        let f = at_200.imu_frame(seq).expect("frame");
        let k = s.sensor;
        da = da.max((s.accelerometer_mps2 - v64(f.specific_force_mps2[k])).norm());
        dw = dw.max((s.gyroscope_radps - v64(f.angular_rate_radps[k])).norm());
        let r = rotation_from_quat_wxyz(&f.orientation_wxyz[k].map(f64::from)).expect("unit");
        dr = dr.max(angle_between(&r, &s.world_from_sensor));
    }
    // f32 on the wire: ≈ 1e-6 relative.
    assert!(da < 1e-5, "specific force differs by {da} m/s²");
    assert!(dw < 1e-6, "angular rate differs by {dw} rad/s");
    assert!(dr < 1e-6, "orientation differs by {dr} rad");
}

#[test]
fn the_gyroscope_integrates_to_the_true_orientation() {
    let session = raw(&motion(PreludeKind::Stand, 60.0), ideal());
    for k in 0..NUM_IMUS {
        let samples = by_sensor(&session, k);
        let mut r = samples[0].world_from_sensor;
        let mut worst: f64 = 0.0;
        for w in samples.windows(2) {
            // The rate at the middle of the step (the synthesis's rates are central differences).
            let omega = (w[0].gyroscope_radps + w[1].gyroscope_radps) / 2.0;
            r *= rotation_from_axis_angle(&(omega * (w[1].true_time_s - w[0].true_time_s)));
            worst = worst.max(angle_between(&r, &w[1].world_from_sensor));
        }
        // 3.6 s (stand, blend, 1.6 s of walking): the midpoint rule errs at the clip's kinks (the
        // BVH is 30 Hz); measured at most 0.3° (lower legs).
        assert!(
            worst.to_degrees() < 0.5,
            "sensor {k}: {:.3}°",
            worst.to_degrees()
        );
    }
}

#[test]
fn at_rest_the_accelerometer_reads_minus_g_and_the_magnetometer_the_earth_field() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    let session = raw(&at_60, ideal());
    let earth = EarthField::default();
    let mut standing = 0;
    for s in &session.samples {
        let m = s.magnetometer_ut.expect("clean magnetometer");
        let m_w = s.world_from_sensor * m;
        assert!((m.norm() - 50.0).abs() < 1e-9, "{m:?}");
        // Inclination 60° below the horizontal, horizontal part along +y_W (north).
        let dip = (-m_w.z).atan2(m_w.xy().norm()).to_degrees();
        assert!((dip - 60.0).abs() < 1e-9, "{dip}");
        assert!(m_w.x.abs() < 1e-9 && m_w.y > 0.0, "{m_w:?}");
        assert!((m_w - earth.in_world_ut()).norm() < 1e-9);
        // The first 0.8 s: the N-pose hold (1 s) before the blend into the clip.
        if s.true_time_s < 0.8 {
            standing += 1;
            let a = s.accelerometer_mps2;
            assert!((a.norm() - 9.81).abs() < 1e-9, "{a:?}");
            assert!((s.world_from_sensor * a - Vector3::new(0.0, 0.0, 9.81)).norm() < 1e-9);
            assert!(s.gyroscope_radps.norm() < 1e-9);
        }
    }
    assert_eq!(standing, NUM_IMUS * 160);
    // Independently of the raw path: the 60 Hz ImuFrames' orientations (z-up at 30°) turn the
    // magnetometer of a sample taken at the same instant into the earth field.
    for s in session.samples.iter().filter(|s| s.tick % 10 == 0) {
        let f = at_60.imu_frame((s.tick / 10 * 3) as usize).expect("frame");
        let r = rotation_from_quat_wxyz(&f.orientation_wxyz[s.sensor].map(f64::from)).expect("q");
        let m_w = r * s.magnetometer_ut.expect("clean");
        assert!((m_w - earth.in_world_ut()).norm() < 1e-3, "{m_w:?}");
    }
}

#[test]
fn without_a_magnetometer_nothing_is_flagged() {
    let session = raw(
        &motion(PreludeKind::None, 60.0),
        RawOptions {
            magnetometer: Magnetometer::None,
            ..ideal()
        },
    );
    assert!(session.samples.iter().all(|s| s.magnetometer_ut.is_none()));
    assert!(session.frames.iter().all(|f| f.magnetometer_mask == 0));
    let clean = raw(&motion(PreludeKind::None, 60.0), ideal());
    assert!(
        clean
            .frames
            .iter()
            .all(|f| f.magnetometer_mask == f.valid_mask)
    );
}

/// The angle (deg) by which `b` turns the earth field's horizontal direction (+y).
fn horizontal_turn_deg(b: &Vector3<f64>) -> f64 {
    b.x.atan2(b.y).abs().to_degrees()
}

#[test]
fn the_disturbance_turns_the_field_near_the_floor_and_little_higher_up() {
    let earth = EarthField::default().in_world_ut();
    for seed in 0..4 {
        let mut rng = StdRng::seed_from_u64(seed);
        let d = MagneticDisturbance::draw(&mut rng, Vector2::zeros(), Vector2::new(3.0, 3.0));
        let max_turn = |height: f64| {
            let mut worst: f64 = 0.0;
            for i in 0..=60 {
                for j in 0..=60 {
                    let p = Vector3::new(i as f64 * 0.05, j as f64 * 0.05, height);
                    worst = worst.max(horizontal_turn_deg(&(earth + d.field_ut(&p))));
                }
            }
            worst
        };
        // Lower legs (≈ 0.3 m), forearms and pelvis (≈ 0.85–1 m), head (≈ 1.65 m).
        let (legs, arms, head) = (max_turn(0.3), max_turn(0.85), max_turn(1.65));
        assert!((15.0..40.0).contains(&legs), "seed {seed}: {legs}°");
        assert!(arms < 8.0, "seed {seed}: {arms}°");
        assert!(head < 3.0, "seed {seed}: {head}°");
        // A real field: divergence- and curl-free (central differences, h = 1 mm).
        let p = Vector3::new(1.3, 0.7, 0.4);
        let h = 1e-3;
        let jac = nalgebra::Matrix3::from_fn(|i, j| {
            let e = Vector3::ith(j, h);
            (d.field_ut(&(p + e))[i] - d.field_ut(&(p - e))[i]) / (2.0 * h)
        });
        let scale = jac.norm();
        assert!(scale > 1.0, "the field varies: {scale} µT/m");
        assert!(jac.trace().abs() < 1e-4 * scale, "div {}", jac.trace());
        assert!((jac - jac.transpose()).norm() < 1e-4 * scale, "curl");
    }
}

#[test]
fn a_disturbed_magnetometer_is_disturbed_near_the_floor_plus_its_hard_iron() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    let disturbed = raw(
        &at_60,
        RawOptions {
            magnetometer: Magnetometer::Disturbed,
            ..ideal()
        },
    );
    let field = disturbed.disturbance.as_ref().expect("disturbed");
    let earth = EarthField::default().in_world_ut();
    let mut worst = [0.0f64; NUM_IMUS];
    for s in &disturbed.samples {
        let k = s.sensor;
        let hard_iron = disturbed.hard_iron_ut[k];
        assert!(hard_iron.iter().all(|v| v.abs() <= HARD_IRON_UT));
        let m_w = s.world_from_sensor * (s.magnetometer_ut.expect("mag") - hard_iron);
        let expected = earth + field.field_ut(&s.position_in_world_m);
        assert!((m_w - expected).norm() < 1e-9);
        worst[k] = worst[k].max(horizontal_turn_deg(&m_w));
    }
    assert!(disturbed.hard_iron_ut.iter().all(|v| v.norm() > 0.0));
    // IMU order: forearms, lower legs, head, pelvis.
    for leg in [2, 3] {
        assert!(worst[leg] > 2.0 * worst[4], "{worst:?}");
    }
    assert!(worst[4] < 3.0, "head: {worst:?}");
    // Clean: no hard iron, no disturbance.
    let clean = raw(&at_60, ideal());
    assert!(clean.disturbance.is_none());
    assert!(clean.hard_iron_ut.iter().all(|v| *v == Vector3::zeros()));
}

/// Least-squares line y = a + b·x.
fn fit_line(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    let b = sxy / sxx;
    (my - b * mx, b)
}

#[test]
fn clock_offset_and_drift_show_up_in_the_sample_times_as_drawn() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    let options = RawOptions {
        clock_offset_ms: 500.0,
        clock_drift_ppm: 100.0,
        seed: 11,
        ..ideal()
    };
    let session = raw(&at_60, options);
    let end_s = (at_60.len() - 1) as f64 / 60.0;
    for k in 0..NUM_IMUS {
        let clock = session.clocks[k];
        assert_eq!(clock.epoch_ns, 500e6);
        assert!(clock.offset_ns.abs() <= 500e6 && clock.drift.abs() <= 100e-6);
        let samples = by_sensor(&session, k);
        assert_eq!(samples.len(), session.ticks[k]);
        // Regular ticks of the sensor's own clock: 5 ms apart on it.
        for w in samples.windows(2) {
            assert_eq!(w[1].sample_time_ns - w[0].sample_time_ns, 5_000_000);
        }
        let t: Vec<f64> = samples.iter().map(|s| s.true_time_s * 1e9).collect();
        let c: Vec<f64> = samples.iter().map(|s| s.sample_time_ns as f64).collect();
        let (intercept, slope) = fit_line(&t, &c);
        assert!(
            (slope - (1.0 + clock.drift)).abs() < 1e-9,
            "sensor {k}: slope {slope}"
        );
        assert!(
            (intercept - (500e6 + clock.offset_ns)).abs() < 2.0,
            "sensor {k}: intercept {intercept}"
        );
        // The true sample period is the nominal one over (1 + drift), over the whole motion.
        let expected = end_s * 200.0 * (1.0 + clock.drift);
        assert!((samples.len() as f64 - expected).abs() <= 1.0);
    }
    // Drawn per sensor: no two clocks alike.
    for a in 0..NUM_IMUS {
        for b in a + 1..NUM_IMUS {
            assert_ne!(session.clocks[a], session.clocks[b]);
        }
    }
    // Seeded: the same options give the same clocks and frames.
    let again = raw(&at_60, options);
    assert_eq!(again.clocks, session.clocks);
    assert_eq!(again.frames, session.frames);
}

#[test]
fn the_loss_rate_is_within_binomial_bounds() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    for loss in [0.0, 0.05, 0.3] {
        let session = raw(
            &at_60,
            RawOptions {
                loss,
                seed: 3,
                ..ideal()
            },
        );
        let ticks: usize = session.ticks.iter().sum();
        let lost = (ticks - session.samples.len()) as f64;
        let n = ticks as f64;
        // 4 standard deviations of a binomial count.
        let bound = 4.0 * (n * loss * (1.0 - loss)).sqrt();
        assert!(
            (lost - n * loss).abs() <= bound,
            "loss {loss}: {lost} of {n}"
        );
        let in_frames: u32 = session
            .frames
            .iter()
            .map(|f| f.valid_mask.count_ones())
            .sum();
        assert_eq!(in_frames as usize, session.samples.len());
    }
}

#[test]
fn frames_hold_each_sample_once_one_per_sensor_in_delivery_order() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    let session = raw(
        &at_60,
        RawOptions {
            clock_offset_ms: 500.0,
            clock_drift_ppm: 100.0,
            jitter_ms: 12.0,
            loss: 0.1,
            seed: 7,
            ..ideal()
        },
    );
    let half_period_ns = 2_500_000;
    let mut unmatched: std::collections::HashMap<(usize, u64), RawSample> = session
        .samples
        .iter()
        .map(|s| ((s.sensor, s.sample_time_ns), *s))
        .collect();
    let mut previous_capture = 0;
    let mut reordered = false;
    for (i, f) in session.frames.iter().enumerate() {
        assert_eq!(f.header.seq, i as u64);
        assert!(f.header.capture_ns >= previous_capture, "frame {i}");
        previous_capture = f.header.capture_ns;
        assert_ne!(f.valid_mask, 0);
        assert_eq!(f.orientation_mask, 0);
        let mut prelude = false;
        let mut latest = 0;
        for k in (0..NUM_IMUS).filter(|k| f.valid_mask & (1 << k) != 0) {
            let s = unmatched
                .remove(&(k, f.sample_time_ns[k]))
                .expect("a sample of this sensor at this time, not in an earlier frame");
            assert!(s.delivery_ns <= f.header.capture_ns);
            assert!(
                f.header.capture_ns - s.delivery_ns <= half_period_ns,
                "frame {i}"
            );
            assert_eq!(f.accelerometer_mps2[k], f32x3(&s.accelerometer_mps2));
            prelude |= s.prelude;
            latest = latest.max(s.delivery_ns);
        }
        assert_eq!(f.header.capture_ns, latest, "the latest delivery");
        assert_eq!(f.header.has(flags::PRELUDE), prelude, "frame {i}");
        if i > 0 {
            let prev = &session.frames[i - 1];
            reordered |= (0..NUM_IMUS).any(|k| {
                prev.valid_mask & f.valid_mask & (1 << k) != 0
                    && prev.sample_time_ns[k] > f.sample_time_ns[k]
            });
        }
    }
    assert!(
        unmatched.is_empty(),
        "{} samples in no frame",
        unmatched.len()
    );
    // 12 ms of jitter at 5 ms periods reorders some of a sensor's own samples.
    assert!(reordered);
    // The prelude's frames come first (up to the jitter) and only they are flagged.
    let flagged = session
        .frames
        .iter()
        .filter(|f| f.header.has(flags::PRELUDE))
        .count();
    assert!(flagged > 0 && flagged < session.frames.len());
}

#[test]
fn the_noise_has_the_data_sheet_magnitudes() {
    let at_60 = motion(PreludeKind::Stand, 60.0);
    let clean = raw(&at_60, ideal());
    let noisy = raw(
        &at_60,
        RawOptions {
            noise_scale: 1.0,
            ..ideal()
        },
    );
    let bmi160 = SensorNoise::CONSUMER_MEMS;
    // Per-sample white noise at 200 Hz: density·√200.
    let accel_sigma = 180e-6 * 9.806_65 * 200f64.sqrt();
    let gyro_sigma = 0.007f64.to_radians() * 200f64.sqrt();
    let (mut accel_diffs, mut gyro_diffs) = (Vec::new(), Vec::new());
    for k in 0..NUM_IMUS {
        let (c, n) = (by_sensor(&clean, k), by_sensor(&noisy, k));
        assert_eq!(c.len(), n.len());
        let accel: Vec<Vector3<f64>> = n
            .iter()
            .zip(&c)
            .map(|(n, c)| n.accelerometer_mps2 - c.accelerometer_mps2)
            .collect();
        let gyro: Vec<Vector3<f64>> = n
            .iter()
            .zip(&c)
            .map(|(n, c)| n.gyroscope_radps - c.gyroscope_radps)
            .collect();
        // The constant biases are within the data sheet's offsets and are what the errors
        // average to (the walks move them by ≈ 2 mg and 0.01 °/s in 2.6 s).
        let (ba, bg) = (noisy.accel_bias_mps2[k], noisy.gyro_bias_radps[k]);
        assert!(ba.iter().all(|v| v.abs() <= bmi160.accel_bias_mps2));
        assert!(bg.iter().all(|v| v.abs() <= bmi160.gyro_bias_radps));
        let mean = |v: &[Vector3<f64>]| v.iter().sum::<Vector3<f64>>() / v.len() as f64;
        assert!((mean(&accel) - ba).norm() < 0.01, "sensor {k}");
        assert!((mean(&gyro) - bg).norm() < 0.001, "sensor {k}");
        for w in accel.windows(2) {
            accel_diffs.extend((w[1] - w[0]).iter().copied());
        }
        for w in gyro.windows(2) {
            gyro_diffs.extend((w[1] - w[0]).iter().copied());
        }
    }
    // Consecutive differences of white noise have variance 2σ² (the walks add < 0.1 %); ≈ 9 000
    // values: the estimate's standard error is 0.75 %, the tolerance 4 %.
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let ratio_a = rms(&accel_diffs) / (2f64.sqrt() * accel_sigma);
    let ratio_g = rms(&gyro_diffs) / (2f64.sqrt() * gyro_sigma);
    assert!((ratio_a - 1.0).abs() < 0.04, "accelerometer {ratio_a}");
    assert!((ratio_g - 1.0).abs() < 0.04, "gyroscope {ratio_g}");
    // Noise alone leaves the clocks, the delivery and the truth as they were.
    for (a, b) in clean.samples.iter().zip(&noisy.samples) {
        assert_eq!((a.sensor, a.sample_time_ns), (b.sensor, b.sample_time_ns));
        assert_eq!(a.world_from_sensor, b.world_from_sensor);
    }
}

#[test]
fn bad_options_and_short_motions_are_errors_naming_the_field() {
    let at_60 = motion(PreludeKind::None, 60.0);
    let err = RawSession::synthesize(
        &at_60,
        &body(),
        &RawOptions {
            rate_hz: f64::NAN,
            ..ideal()
        },
    )
    .expect_err("NaN rate");
    assert!(format!("{err:#}").contains("rate_hz"), "{err:#}");
    let err = RawSession::synthesize(
        &at_60,
        &body(),
        &RawOptions {
            loss: 1.0,
            ..ideal()
        },
    )
    .expect_err("loss 1");
    assert!(format!("{err:#}").contains("loss"), "{err:#}");
    // 95 frames at 60 Hz are 1.57 s: at 1 Hz each sensor takes 2 samples, fewer than a second
    // difference needs.
    let err = RawSession::synthesize(
        &at_60,
        &body(),
        &RawOptions {
            rate_hz: 1.0,
            ..ideal()
        },
    )
    .expect_err("too few samples");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("sensor 0") && msg.contains("at least 3"),
        "{msg}"
    );
}
