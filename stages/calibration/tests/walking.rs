//! Walking calibration (GlobalPose §3.4) against known truth: random mountings, random inertial
//! frames with per-sensor heading offsets, the reference noise model.

mod common;

use common::*;
use imuflow_body::rotation::Axis;
use imuflow_calibration::{Event, InertialFrame, NUM_IMUS, PELVIS, Rejection};
use imuflow_graph::frames::flags;
use imuflow_synth::prelude::{PoseTrack, PreludeKind, n_pose, standing_root_height_m};
use nalgebra::Vector3;

const FRAMES: [InertialFrame; 3] = [
    InertialFrame::Model,
    InertialFrame::ZUp,
    InertialFrame::ZDown,
];

/// Calibrates a stand–step–stand of seed `seed` (convention by seed, heading 70°, offsets ±45°);
/// returns the per-sensor R_SB and heading errors (deg).
fn errors(seed: u64, augment: bool) -> ([f64; NUM_IMUS], [f64; NUM_IMUS]) {
    let p = prelude(PreludeKind::Walk);
    let frame = FRAMES[seed as usize % 3];
    let motion = synthesize(short_clip(), p, setup(frame, 70.0, 45.0), augment, seed);
    let session = run(walking(frame), &motion);
    assert!(
        session.calibrated_at().is_some(),
        "seed {seed}: {:?}",
        session.rejections()
    );
    (
        sensor_from_bone_errors_deg(&session, &motion, first_stand_mid(&p)),
        heading_errors_deg(&session, &motion),
    )
}

#[test]
fn without_noise_mountings_and_heading_offsets_are_recovered_exactly() {
    for seed in 0..3 {
        let (sb, heading) = errors(seed, false);
        // Only the finite-difference synthesis and f32 wire rounding separate these from the truth.
        assert!(max(sb) < 0.01, "seed {seed}: R_SB errors {sb:?}");
        assert!(
            max(heading) < 0.01,
            "seed {seed}: heading errors {heading:?}"
        );
    }
}

#[test]
fn with_reference_noise_mountings_and_heading_offsets_are_within_tolerance() {
    // Measured over 40 seeds (240 sensors): R_SB median 0.8°, 95th percentile 1.8°, max 3.7°;
    // heading median 0.6°, 95th percentile 2.1°, max 3.6°. The heading error is the integration
    // error across a 0.6 m step (about 1 cm at 1σ from 0.05 m/s² accelerometer noise over the
    // ~2.5 s integrated); R_SB inherits it plus the mounting random walk between the two stands.
    let mut all_sb = Vec::new();
    let mut all_heading = Vec::new();
    for seed in 10..22 {
        let (sb, heading) = errors(seed, true);
        assert!(max(sb) < 4.5, "seed {seed}: R_SB errors {sb:?}");
        assert!(
            max(heading) < 4.5,
            "seed {seed}: heading errors {heading:?}"
        );
        all_sb.extend(sb);
        all_heading.extend(heading);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(mean(&all_sb) < 1.5, "mean R_SB error {}", mean(&all_sb));
    assert!(
        mean(&all_heading) < 1.5,
        "mean heading error {}",
        mean(&all_heading)
    );
}

#[test]
fn frames_are_flagged_calibrating_until_the_calibration_is_accepted() {
    let p = prelude(PreludeKind::Walk);
    let motion = synthesize(
        short_clip(),
        p,
        setup(InertialFrame::ZUp, -30.0, 20.0),
        false,
        5,
    );
    let session = run(walking(InertialFrame::ZUp), &motion);
    let at = session.calibrated_at().expect("calibrated");
    // The second stand is detected `hold_s` (1.5 s) after it starts, so the prelude's 3 s stand
    // after the step is still going on.
    let stand_after_step = 1 + 180 + 72;
    assert!(
        (stand_after_step + 90..stand_after_step + 180).contains(&at),
        "at {at}"
    );
    for (i, out) in session.outputs.iter().enumerate() {
        let calibrating = out.header.has(flags::CALIBRATING);
        assert_eq!(calibrating, i < at, "frame {i}");
        assert_eq!(out.header.has(flags::INVALID), i < at, "frame {i}");
        assert_eq!(out.valid_mask == 0, i < at, "frame {i}");
        assert_eq!(out.header.seq, i as u64);
    }
    // Calibrated frames carry the heading corrections.
    let truth = true_heading_corrections(&motion);
    let last = session.outputs.last().expect("frames");
    for (out, truth) in last.heading_correction_rad.iter().zip(truth) {
        assert!((f64::from(*out) - truth).abs() < 1e-3, "{out} vs {truth}");
    }
    assert_eq!(last.heading_correction_rad[PELVIS], 0.0);
}

#[test]
fn not_returning_to_the_start_pose_asks_for_a_redo() {
    let mut p = prelude(PreludeKind::Walk);
    p.turn_deg = 35.0;
    let motion = synthesize(
        short_clip(),
        p,
        setup(InertialFrame::Model, 0.0, 10.0),
        true,
        8,
    );
    let session = run(walking(InertialFrame::Model), &motion);
    assert!(session.calibrated_at().is_none());
    let rejected: Vec<&Rejection> = session
        .events
        .iter()
        .filter_map(|(_, e)| match e {
            Event::Rejected { reason, .. } => Some(reason),
            _ => None,
        })
        .collect();
    assert_eq!(rejected.len(), 1, "{:?}", session.events);
    let Rejection::PoseChanged { angle_deg, .. } = rejected[0] else {
        panic!("expected PoseChanged, got {:?}", rejected[0]);
    };
    assert!((30.0..40.0).contains(angle_deg), "{angle_deg}");
    let err = session.calibrator.finish().expect_err("never calibrated");
    let msg = err.to_string();
    assert!(
        msg.contains("walking") && msg.contains("turned") && msg.contains("same pose"),
        "{msg}"
    );
    assert!(
        session
            .outputs
            .iter()
            .all(|o| o.header.has(flags::CALIBRATING))
    );
}

#[test]
fn a_rejected_attempt_is_followed_by_a_good_one() {
    // Stand, a step with a 35° turn (rejected), stand, a straight step (accepted), stand, motion.
    let body = body();
    let origin = Vector3::new(0.0, standing_root_height_m(&body), 0.0);
    let mut track = PoseTrack::new(1.0 / RATE_HZ, n_pose(origin));
    track.hold(3.0);
    track.step_forward(0.6, 1.2, 35f64.to_radians());
    track.hold(3.0);
    track.step_forward(0.6, 1.2, 0.0);
    track.hold(3.0);
    let clip = imuflow_motion::retarget::MotionClip {
        frame_time_s: 1.0 / RATE_HZ,
        poses: track.into_poses(),
    };
    let motion = synthesize(
        clip,
        prelude(PreludeKind::None),
        setup(InertialFrame::ZDown, 120.0, 45.0),
        true,
        9,
    );
    let session = run(walking(InertialFrame::ZDown), &motion);
    assert_eq!(session.rejections().len(), 1, "{:?}", session.events);
    assert!(
        session.rejections()[0].contains("turned"),
        "{:?}",
        session.rejections()
    );
    let at = session.calibrated_at().expect("second attempt accepted");
    assert!(at > 1 + 180 + 72 + 180 + 72, "at {at}");
    // The relative headings and the mountings do not depend on which way the subject faced.
    let heading = heading_errors_deg(&session, &motion);
    assert!(max(heading) < 4.5, "{heading:?}");
    let sb = sensor_from_bone_errors_deg(&session, &motion, 1 + 180 + 72 + 90);
    assert!(max(sb) < 4.5, "{sb:?}");
}

#[test]
fn a_later_step_re_estimates_a_heading_that_drifted() {
    // Stand, step (calibration), stand 4 s, step, stand: sensor 2's inertial frame turns by 15°
    // about up 2 s into the middle stand (a magnetic disturbance).
    let body = body();
    let origin = Vector3::new(0.0, standing_root_height_m(&body), 0.0);
    let mut track = PoseTrack::new(1.0 / RATE_HZ, n_pose(origin));
    track.hold(3.0);
    track.step_forward(0.6, 1.2, 0.0);
    track.hold(4.0);
    track.step_forward(0.6, 1.2, 0.0);
    track.hold(3.0);
    let clip = imuflow_motion::retarget::MotionClip {
        frame_time_s: 1.0 / RATE_HZ,
        poses: track.into_poses(),
    };
    let frame = InertialFrame::ZUp;
    let motion = synthesize(
        clip,
        prelude(PreludeKind::None),
        setup(frame, 10.0, 30.0),
        true,
        11,
    );
    let drift_from = 1 + 180 + 72 + 120;
    let drift = 15f64.to_radians();
    let up_in_i = frame.up_in_inertial();
    let frames = |drift_update: bool| {
        let mut config = walking(frame);
        config.drift_update = drift_update;
        let frames = (0..motion.len()).map(|i| {
            let mut f = motion.imu_frame(i).expect("frame");
            if i >= drift_from {
                let q = f.orientation_wxyz[2].map(f64::from);
                let r = imuflow_body::rotation::rotation_from_quat_wxyz(&q).expect("unit");
                let turned = nalgebra::Rotation3::from_axis_angle(&up_in_i, drift) * r;
                f.orientation_wxyz[2] =
                    imuflow_body::rotation::quat_wxyz_from_rotation(&turned).map(|v| v as f32);
            }
            f
        });
        run_frames(config, frames)
    };
    let session = frames(true);
    let truth = true_heading_corrections(&motion);
    let updated = session
        .events
        .iter()
        .find_map(|(_, e)| match e {
            Event::HeadingUpdated {
                corrections_rad, ..
            } => Some(*corrections_rad),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no heading update: {:?}", session.events));
    // R_MB = R_y(ψ')·R_MI·R_turn·R_IS·R_SB needs ψ' = ψ − 15°.
    let err = (wrap(updated[2] - (truth[2] - drift))).to_degrees().abs();
    assert!(err < 4.5, "sensor 2: updated ψ off by {err}°");
    for k in [0, 1, 3, 4] {
        let err = wrap(updated[k] - truth[k]).to_degrees().abs();
        assert!(err < 4.5, "sensor {k}: ψ off by {err}° after the update");
    }
    // The last frame's bone orientation of sensor 2 is right again; without the update it is off
    // by the drift.
    let last = motion.len() - 1;
    let bones = true_bones(&body, &motion.clip.poses[last]);
    let with_update = bone_error_deg(&session.outputs[last], &bones, 2);
    let without = bone_error_deg(&frames(false).outputs[last], &bones, 2);
    assert!(with_update < 5.0, "{with_update}");
    assert!(without > 10.0, "{without}");
    // Sanity: the yaw about M's y used for ψ matches the drift's axis.
    assert!(
        (frame.model_from_inertial(0.0) * up_in_i.into_inner() - Axis::Y.unit().into_inner())
            .norm()
            < 1e-12
    );
}
