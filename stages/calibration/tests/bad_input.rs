//! Bad input gives a clear outcome: no panic, no hang, a reason that names the problem.

mod common;

use common::*;
use imuflow_calibration::{
    Calibrator, CalibratorConfig, Event, InertialFrame, Method, NUM_IMUS, Rejection,
};
use imuflow_graph::frames::{BodyImuFrame, ImuFrame, flags};
use imuflow_synth::Motion;
use imuflow_synth::prelude::PreludeKind;

fn walk_motion(seed: u64) -> Motion {
    synthesize(
        short_clip(),
        prelude(PreludeKind::Walk),
        setup(InertialFrame::Model, 0.0, 20.0),
        true,
        seed,
    )
}

fn frames(motion: &Motion) -> impl Iterator<Item = ImuFrame> + '_ {
    (0..motion.len()).map(|i| motion.imu_frame(i).expect("frame"))
}

fn failure(session: &Session) -> String {
    session
        .calibrator
        .finish()
        .expect_err("must not calibrate")
        .to_string()
}

#[test]
fn an_empty_stream_is_not_calibrated() {
    let session = run_frames(walking(InertialFrame::Model), std::iter::empty());
    assert!(
        failure(&session).contains("no frames arrived"),
        "{}",
        failure(&session)
    );
}

#[test]
fn a_stream_too_short_to_hold_still_names_the_hold_length() {
    let motion = walk_motion(1);
    for config in [
        walking(InertialFrame::Model),
        tpose(InertialFrame::Model, 0.0),
    ] {
        let method = config.method;
        let session = run_frames(config, frames(&motion).take(60));
        let msg = failure(&session);
        assert!(msg.contains("after 60 frames"), "{msg}");
        if method == Method::Tpose {
            assert!(
                msg.contains("no still period of hold_s = 1.5 s in 1.0 s of data"),
                "{msg}"
            );
        } else {
            // Both rules of the walking method, each with what the data held: nearly the whole
            // second was still (a stand long enough for the natural start), and no walk followed.
            assert!(
                msg.contains("natural start (a still period of walk_stand_s")
                    && msg.contains("the longest still period was 0.9")
                    && msg.contains("walk_s = 3 s of walking never followed a stand")
                    && msg.contains("stand–step–stand (two stands of hold_s = 1.5 s")
                    && msg.contains("0 stand(s) seen"),
                "{msg}"
            );
        }
        assert!(
            session
                .outputs
                .iter()
                .all(|o| o.header.has(flags::CALIBRATING | flags::INVALID))
        );
    }
}

#[test]
fn standing_without_a_step_says_no_step_followed() {
    let motion = walk_motion(2);
    // The first stand only (3 s): still, but no step.
    let session = run_frames(walking(InertialFrame::Model), frames(&motion).take(180));
    let msg = failure(&session);
    assert!(
        msg.contains("1 stand(s) seen, no step and second stand after it"),
        "{msg}"
    );
}

#[test]
fn a_step_that_takes_too_long_or_is_too_short_is_rejected_with_its_reason() {
    let mut slow = prelude(PreludeKind::Walk);
    slow.step_s = 4.0;
    let motion = synthesize(
        short_clip(),
        slow,
        setup(InertialFrame::Model, 0.0, 0.0),
        true,
        3,
    );
    let session = run(walking(InertialFrame::Model), &motion);
    assert!(
        matches!(
            session.events.last(),
            Some((
                _,
                Event::Rejected {
                    reason: Rejection::MotionTooLong { .. },
                    ..
                }
            ))
        ),
        "{:?}",
        session.events
    );
    assert!(
        failure(&session).contains("take a single step"),
        "{}",
        failure(&session)
    );

    let mut short = prelude(PreludeKind::Walk);
    short.step_m = 0.1;
    let motion = synthesize(
        short_clip(),
        short,
        setup(InertialFrame::Model, 0.0, 0.0),
        true,
        3,
    );
    let session = run(walking(InertialFrame::Model), &motion);
    let msg = failure(&session);
    assert!(
        msg.contains("the pelvis moved 0.1") && msg.contains("take one step forward"),
        "{msg}"
    );
}

#[test]
fn a_sensor_that_is_always_nan_or_missing_is_named() {
    let motion = walk_motion(4);
    let nan = frames(&motion).map(|mut f| {
        f.specific_force_mps2[3][1] = f32::NAN;
        f
    });
    let session = run_frames(walking(InertialFrame::Model), nan);
    let msg = failure(&session);
    assert!(
        msg.contains(&format!(
            "right_lower_leg never had a usable sample (missing, NaN, infinite or a zero \
             quaternion) in {} frames",
            motion.len()
        )),
        "{msg}"
    );
    assert!(
        session.events.is_empty(),
        "never still: {:?}",
        session.events
    );

    let missing = frames(&motion).map(|mut f| {
        f.valid_mask &= !(1 << 4);
        f
    });
    let msg = failure(&run_frames(tpose(InertialFrame::Model, 0.0), missing));
    assert!(
        msg.contains("head never had a usable sample") && !msg.contains("pelvis"),
        "{msg}"
    );
}

#[test]
fn a_nan_sample_ends_a_stand_early_and_afterwards_marks_only_that_sensor() {
    let motion = walk_motion(5);
    let n = motion.len();
    let glitchy = frames(&motion).enumerate().map(|(i, mut f)| {
        // Frame 60 restarts the first stand's still run (0..181): 106 frames remain, more than the
        // 1.5 s hold.
        if i == 60 || i == n - 5 {
            f.orientation_wxyz[0] = [f32::NAN; 4];
        }
        f
    });
    let session = run_frames(walking(InertialFrame::Model), glitchy);
    assert!(session.calibrated_at().is_some(), "{:?}", session.events);
    let out = &session.outputs[n - 5];
    assert!(out.header.has(flags::INVALID) && !out.header.has(flags::CALIBRATING));
    assert_eq!(out.valid_mask, 0b111110);
    assert_eq!(out.bone_orientation_wxyz[0], [1.0, 0.0, 0.0, 0.0]);
    assert!(
        out.bone_orientation_wxyz
            .iter()
            .flatten()
            .all(|v| v.is_finite())
    );
    assert_eq!(session.outputs[n - 4].valid_mask, 0b111111);
}

#[test]
fn a_sensor_dropping_out_during_the_step_asks_for_a_redo() {
    let motion = walk_motion(6);
    let dropout = frames(&motion).enumerate().map(|(i, mut f)| {
        if i == 200 {
            f.valid_mask &= !(1 << 1);
        }
        f
    });
    let session = run_frames(walking(InertialFrame::Model), dropout);
    assert_eq!(session.rejections().len(), 1, "{:?}", session.events);
    let msg = failure(&session);
    assert!(
        msg.contains("sensor right_forearm had no usable sample in 1 of the step's")
            && msg.contains("`max_gap_ms`")
            && msg.contains("so do it again"),
        "{msg}"
    );
}

#[test]
fn garbage_never_panics() {
    // Deterministic garbage: huge, tiny, zero, negative and NaN values, timestamps that jump back.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let values = [
        0.0f32,
        1.0,
        -1.0,
        1e30,
        -1e-30,
        f32::NAN,
        f32::INFINITY,
        9.81,
        0.5,
    ];
    for method in [Method::Tpose, Method::Walking, Method::None] {
        let config = CalibratorConfig {
            method,
            ..CalibratorConfig::default()
        };
        let mut calibrator = Calibrator::new(config);
        for i in 0..2000u64 {
            let mut f = ImuFrame::default();
            f.header.seq = i;
            f.header.capture_ns = next() % 100_000_000_000;
            f.valid_mask = (next() % 64) as u32;
            for k in 0..NUM_IMUS {
                let mut pick = || values[(next() % values.len() as u64) as usize];
                f.orientation_wxyz[k] = [pick(), pick(), pick(), pick()];
                f.specific_force_mps2[k] = [pick(), pick(), pick()];
                f.angular_rate_radps[k] = [pick(), pick(), pick()];
            }
            let mut out = BodyImuFrame::default();
            let _ = calibrator.push(&f, &mut out);
            assert!(
                out.free_acceleration_mps2
                    .iter()
                    .flatten()
                    .all(|v| !v.is_nan())
                    || method == Method::None
            );
        }
        let _ = calibrator.finish();
    }
}

#[test]
fn standing_still_forever_with_garbage_free_stillness_only_calibrates_tpose() {
    // A constant frame is perfectly still: a T-pose calibrates on it, walking waits for a step.
    let mut f = ImuFrame {
        valid_mask: 0b111111,
        ..Default::default()
    };
    for k in 0..NUM_IMUS {
        f.orientation_wxyz[k] = [1.0, 0.0, 0.0, 0.0];
        f.specific_force_mps2[k] = [0.0, 9.81, 0.0];
    }
    let stream = |n: u64| {
        (0..n).map(move |i| {
            let mut g = f;
            g.header.seq = i;
            g.header.capture_ns = i * 16_666_667;
            g
        })
    };
    assert!(
        run_frames(tpose(InertialFrame::Model, 0.0), stream(600))
            .calibrated_at()
            .is_some()
    );
    let walking = run_frames(walking(InertialFrame::Model), stream(600));
    assert!(walking.calibrated_at().is_none());
    assert_eq!(walking.events.len(), 1, "one stand: {:?}", walking.events);
}

#[test]
fn method_none_passes_bone_orientations_through() {
    let motion = synthesize(
        short_clip(),
        prelude(PreludeKind::None),
        imuflow_synth::SensorSetup::default(),
        false,
        0,
    );
    let config = CalibratorConfig {
        method: Method::None,
        ..CalibratorConfig::default()
    };
    let session = run(config, &motion);
    let body = body();
    for (t, out) in session.outputs.iter().enumerate() {
        assert_eq!(out.header.flags, 0);
        let truth = true_bones(&body, &motion.clip.poses[t]);
        for k in 0..NUM_IMUS {
            assert!(bone_error_deg(out, &truth, k) < 0.01);
        }
    }
    assert!(session.calibrator.finish().is_ok());
}

#[test]
fn a_fusing_sources_start_up_is_not_reported_as_bad_samples() {
    // The fusion stage's first frames have no sample of a sensor yet (bits cleared): that is its
    // start-up, not bad data. A sensor lost later is counted from its first usable frame on.
    let motion = walk_motion(7);
    let stream = frames(&motion).take(150).enumerate().map(|(i, mut f)| {
        if i < 3 {
            f.valid_mask = 0;
        }
        if i == 100 {
            f.valid_mask &= !(1 << 2);
        }
        f
    });
    let msg = failure(&run_frames(walking(InertialFrame::Model), stream));
    assert!(
        msg.contains("left_lower_leg in 1 of 147 frames")
            && !msg.contains("left_forearm")
            && !msg.contains("never had"),
        "{msg}"
    );
    // One line per cause.
    assert!(
        msg.lines().filter(|l| l.starts_with("- ")).count() >= 3,
        "{msg}"
    );
}

#[test]
fn a_flat_sensor_is_refused_naming_its_site() {
    // A sensor that reports the same reading throughout (dead, or lying on a table) looks still
    // for ever: the natural start's walk then finds its path is not the body's, and says which.
    let motion = synthesize(
        sample_walk_clip(),
        imuflow_synth::prelude::PreludeOptions {
            stand_s: 1.0,
            ..prelude(PreludeKind::Stand)
        },
        setup(InertialFrame::ZUp, 0.0, 15.0),
        false,
        8,
    );
    let first = motion.imu_frame(0).expect("frame");
    let flat = frames(&motion).map(|mut f| {
        f.orientation_wxyz[3] = first.orientation_wxyz[3];
        f.specific_force_mps2[3] = first.specific_force_mps2[3];
        f.angular_rate_radps[3] = first.angular_rate_radps[3];
        f
    });
    let session = run_frames(walking(InertialFrame::ZUp), flat);
    let msg = failure(&session);
    assert!(
        msg.contains("right_lower_leg") && msg.contains("is it worn on the body"),
        "{msg}"
    );
}
