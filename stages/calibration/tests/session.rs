//! Calibrating, then feeding ~30 s of motion: the calibrated bone orientations against the truth.

mod common;

use common::*;
use imuflow_calibration::{InertialFrame, NUM_IMUS};
use imuflow_synth::Motion;
use imuflow_synth::prelude::PreludeKind;

/// Bone orientation errors (deg) of every sensor on every frame after the calibration.
fn errors_after_calibration(session: &Session, motion: &Motion) -> Vec<f64> {
    let body = body();
    let from = session.calibrated_at().expect("calibrated");
    let mut errors = Vec::new();
    for t in from..motion.len() {
        let truth = true_bones(&body, &motion.clip.poses[t]);
        for k in 0..NUM_IMUS {
            errors.push(bone_error_deg(&session.outputs[t], &truth, k));
        }
    }
    errors
}

fn stats(mut e: Vec<f64>) -> (f64, f64, f64) {
    e.sort_by(f64::total_cmp);
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    (mean, e[e.len() * 95 / 100], e[e.len() - 1])
}

fn thirty_seconds(seed: u64, offset_deg: f64, augment: bool) -> Motion {
    let frame = FRAMES[seed as usize % 3];
    let clip = ping_pong(&short_clip(), 30.0);
    synthesize(
        clip,
        prelude(PreludeKind::TposeWalk),
        setup(frame, 25.0, offset_deg),
        augment,
        seed,
    )
}

const FRAMES: [InertialFrame; 3] = [
    InertialFrame::Model,
    InertialFrame::ZUp,
    InertialFrame::ZDown,
];

#[test]
fn without_noise_thirty_seconds_reproduce_the_true_bone_orientations() {
    for seed in 0..2 {
        let motion = thirty_seconds(seed, 0.0, false);
        let frame = FRAMES[seed as usize % 3];
        for session in [
            run(walking(frame), &motion),
            run(tpose(frame, 25.0), &motion),
        ] {
            let errors = errors_after_calibration(&session, &motion);
            assert!(
                errors.len() >= 30 * 60 * NUM_IMUS,
                "{} samples",
                errors.len()
            );
            let (mean, _, max) = stats(errors);
            // f32 quaternions on the wire: ~1e-5 rad.
            assert!(max < 0.01, "seed {seed}: mean {mean}°, max {max}°");
        }
    }
}

#[test]
fn with_reference_noise_thirty_seconds_stay_within_tolerance() {
    // Measured over 6 seeds, ~31 s after calibration, all six bones: walking mean 2.0–2.5°, 95th
    // percentile 3.8–5.2°, max 5.1–7.3°; T-pose mean 2.5–3.0°, 95th percentile 5.1–5.8°, max
    // 6.4–7.7°. Most of it is not calibration error: the reference noise model lets each
    // mounting drift as a random walk of 1e-2 rad/√s (3.1° mean after 30 s) and each heading as
    // 4.5e-3 rad/√s (1.4° after 30 s), which a one-time calibration cannot follow.
    for seed in 0..3 {
        let motion = thirty_seconds(seed, 0.0, true);
        let frame = FRAMES[seed as usize % 3];
        let (mean, p95, max) = stats(errors_after_calibration(
            &run(walking(frame), &motion),
            &motion,
        ));
        assert!(
            mean < 3.0 && p95 < 6.5 && max < 9.0,
            "walking seed {seed}: {mean} {p95} {max}"
        );
        let (mean, p95, max) = stats(errors_after_calibration(
            &run(tpose(frame, 25.0), &motion),
            &motion,
        ));
        assert!(
            mean < 3.5 && p95 < 7.0 && max < 10.0,
            "tpose seed {seed}: {mean} {p95} {max}"
        );
    }
}

#[test]
fn per_sensor_heading_offsets_defeat_a_tpose_but_not_walking() {
    // ±40° offsets between the sensors' inertial frames (no shared heading reset): a T-pose folds
    // them into R_SB, which is right in the T-pose only; walking measures and removes them.
    let mut tpose_means = Vec::new();
    for seed in 3..5 {
        let motion = thirty_seconds(seed, 40.0, true);
        let frame = FRAMES[seed as usize % 3];
        let (walking_mean, _, walking_max) = stats(errors_after_calibration(
            &run(walking(frame), &motion),
            &motion,
        ));
        assert!(
            walking_mean < 3.0 && walking_max < 9.0,
            "seed {seed}: {walking_mean} {walking_max}"
        );
        let (tpose_mean, _, _) = stats(errors_after_calibration(
            &run(tpose(frame, 25.0), &motion),
            &motion,
        ));
        tpose_means.push(tpose_mean);
    }
    assert!(tpose_means.iter().all(|m| *m > 4.0), "{tpose_means:?}");
}
