//! Hand-derived checks of the recorded-stream scores.

use approx::assert_relative_eq;
use imuflow_body::rotation::{Axis, quat_wxyz_from_rotation};
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS, Pose};
use imuflow_graph::frames::{MotionFrame, ValidationFrame, flags};
use nalgebra::Vector3;

use super::*;

const RATE_HZ: f64 = 60.0;
/// Walking speed of the synthetic truth, m/s.
const SPEED_MPS: f64 = 1.2;

fn body() -> BodyModel {
    BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
}

fn frame(seq: u64, pose: &Pose) -> MotionFrame {
    let mut f = MotionFrame::default();
    f.header.seq = seq;
    for (o, r) in f.local_pose_wxyz.iter_mut().zip(&pose.parent_from_joint) {
        *o = quat_wxyz_from_rotation(r).map(|v| v as f32);
    }
    f.root_position_m = pose.root_in_world_m.cast::<f32>().into();
    f
}

/// A T-pose gliding forward at 1.2 m/s with its feet at their rest height on the floor: 10 s,
/// 12 m of travel.
fn gliding_truth(body: &BodyModel, frames: usize) -> Vec<MotionFrame> {
    (0..frames)
        .map(|k| {
            let z = SPEED_MPS * k as f64 / RATE_HZ;
            frame(
                k as u64,
                &Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m, z)),
            )
        })
        .collect()
}

/// A stream with each frame's pose changed by `change`.
fn edited(stream: &[MotionFrame], change: impl Fn(&mut Pose)) -> Vec<MotionFrame> {
    stream
        .iter()
        .map(|f| {
            let mut pose = Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m).unwrap();
            change(&mut pose);
            let mut g = frame(f.header.seq, &pose);
            g.header = f.header;
            g
        })
        .collect()
}

#[test]
fn a_root_shift_is_no_pose_error_but_a_root_distance() {
    let body = body();
    let truth = gliding_truth(&body, 600);
    let shifted = edited(&truth, |p| p.root_in_world_m.x += 0.1);
    let s = score_against_truth(&shifted, &truth, &body, RATE_HZ);
    assert_eq!((s.frames, s.skipped, s.runs), (600, 0, 1));
    assert_relative_eq!(s.joint_position_error_cm.unwrap(), 0.0, epsilon = 1e-9);
    assert_relative_eq!(s.angle_error_deg.unwrap(), 0.0, epsilon = 1e-9);
    assert_relative_eq!(s.sip_error_deg.unwrap(), 0.0, epsilon = 1e-9);
    assert_relative_eq!(s.knee_flexion_error_deg.unwrap(), 0.0, epsilon = 1e-9);
    // A constant offset travels exactly like the truth: no translation error at any window.
    assert_relative_eq!(s.translation_error_2m_m.unwrap(), 0.0, epsilon = 1e-5);
    assert_relative_eq!(s.translation_error_7m_m.unwrap(), 0.0, epsilon = 1e-5);
    assert_relative_eq!(s.translation_drift_percent.unwrap(), 0.0, epsilon = 1e-4);
    assert_eq!(s.per_frame.seq.len(), 600);
    let d = disagreement(&shifted, &truth, &body);
    assert_eq!(d.frames, 600);
    assert_relative_eq!(d.root_distance_m.unwrap(), 0.1, epsilon = 1e-6);
    assert_relative_eq!(d.angle_deg.unwrap(), 0.0, epsilon = 1e-9);
}

#[test]
fn an_elbow_turned_ninety_degrees_gives_the_counted_errors() {
    let body = body();
    let truth = gliding_truth(&body, 120);
    let turn = Axis::Y.rotation(std::f64::consts::FRAC_PI_2);
    let bent = edited(&truth, |p| {
        p.parent_from_joint[JointId::LEFT_ELBOW.index()] = turn;
    });
    let s = score_against_truth(&bent, &truth, &body, RATE_HZ);
    // Elbow, wrist and hand turn 90° globally (protocol G sets the wrist and hand local rotations to
    // identity in both, so they follow the elbow); 3 × 90° over 24 joints.
    assert_relative_eq!(s.angle_error_deg.unwrap(), 270.0 / 24.0, epsilon = 1e-4);
    // The elbow is not a SIP joint.
    assert_relative_eq!(s.sip_error_deg.unwrap(), 0.0, epsilon = 1e-9);
    // A left elbow turned +90° about y is bent 90° backwards (its forearm, along +x, swings to
    // −z): against the T-pose's straight arms, 90° on one elbow of two; the knees agree.
    assert_relative_eq!(s.elbow_flexion_error_deg.unwrap(), 45.0, epsilon = 1e-4);
    assert_relative_eq!(s.knee_flexion_error_deg.unwrap(), 0.0, epsilon = 1e-9);
    let per_joint = s.per_joint.as_ref().unwrap();
    for j in JointId::all() {
        let expected =
            if [JointId::LEFT_ELBOW, JointId::LEFT_WRIST, JointId::LEFT_HAND].contains(&j) {
                90.0
            } else {
                0.0
            };
        assert_relative_eq!(
            per_joint.angle_error_deg[j.index()],
            expected,
            epsilon = 1e-4
        );
    }
    // Positions: a 90° turn about y moves a point at v from the elbow by √2·|v without its y part|.
    let chord = |v: Vector3<f64>| std::f64::consts::SQRT_2 * Vector3::new(v.x, 0.0, v.z).norm();
    let wrist = *body.skeleton.offset_in_parent_m(JointId::LEFT_WRIST);
    let hand = wrist + body.skeleton.offset_in_parent_m(JointId::LEFT_HAND);
    let expected_cm = 100.0 * (chord(wrist) + chord(hand)) / NUM_JOINTS as f64;
    assert_relative_eq!(
        s.joint_position_error_cm.unwrap(),
        expected_cm,
        epsilon = 1e-4
    );
    assert_relative_eq!(
        per_joint.joint_position_error_cm[JointId::LEFT_WRIST.index()],
        100.0 * chord(wrist),
        epsilon = 1e-4
    );
    assert_relative_eq!(
        per_joint.joint_position_error_cm[JointId::LEFT_ELBOW.index()],
        0.0,
        epsilon = 1e-9
    );
    assert!(
        s.per_frame
            .angle_error_deg
            .iter()
            .all(|e| (e - 270.0 / 24.0).abs() < 1e-4)
    );
}

#[test]
fn without_truth_only_the_estimates_own_motion_is_scored() {
    let body = body();
    let truth = gliding_truth(&body, 600);
    let s = score_without_truth(&truth, &body, RATE_HZ);
    assert_eq!(s.frames, 600);
    assert!(s.sip_error_deg.is_none() && s.joint_position_error_cm.is_none());
    assert!(s.knee_flexion_error_deg.is_none() && s.elbow_flexion_error_deg.is_none());
    assert!(s.translation_error_2m_m.is_none() && s.standing_grf_fraction.is_none());
    assert!(s.per_frame.seq.is_empty() && s.per_joint.is_none());
    // Constant velocity: no jerk (up to the wire's f32 rounding of 12 m of travel).
    assert!(s.jitter_km_s3.unwrap() < 0.01, "{s:?}");
    assert!(s.root_jitter_km_s3.unwrap() < 0.01, "{s:?}");
    // Both feet rest at their clearance (in contact, not below it) and glide at 1.2 m/s.
    assert_relative_eq!(s.ground_penetration_m.unwrap(), 0.0, epsilon = 1e-6);
    assert_relative_eq!(s.foot_skating_mps.unwrap(), SPEED_MPS, epsilon = 1e-3);
    // Sink everything 3 cm: both feet 3 cm under the floor.
    let sunk = edited(&truth, |p| p.root_in_world_m.y -= 0.03);
    let s = score_without_truth(&sunk, &body, RATE_HZ);
    assert_relative_eq!(s.ground_penetration_m.unwrap(), 0.03, epsilon = 1e-6);
}

#[test]
fn flagged_frames_in_either_stream_are_skipped() {
    let body = body();
    let mut truth = gliding_truth(&body, 600);
    let mut estimate = truth.clone();
    // A wild estimate on frame 100 that the producer flagged: it must not count anywhere.
    estimate[100].root_position_m = [1000.0, -50.0, 3.0];
    estimate[100].header.flags = flags::INVALID;
    truth[300].header.flags = flags::CALIBRATING;
    // An undecodable estimate (all-zero quaternion) is skipped as well.
    estimate[450].local_pose_wxyz[3] = [0.0; 4];
    let s = score_against_truth(&estimate, &truth, &body, RATE_HZ);
    assert_eq!((s.frames, s.skipped, s.runs), (597, 3, 4));
    assert!(!s.per_frame.seq.contains(&100) && !s.per_frame.seq.contains(&300));
    assert_relative_eq!(s.joint_position_error_cm.unwrap(), 0.0, epsilon = 1e-9);
    assert!(s.jitter_km_s3.unwrap() < 0.01, "{s:?}");
    assert!(s.ground_penetration_m.unwrap() < 1e-6, "{s:?}");
    let d = disagreement(&estimate, &truth, &body);
    assert_eq!(d.frames, 597);
    assert_relative_eq!(d.root_distance_m.unwrap(), 0.0, epsilon = 1e-9);
}

#[test]
fn standing_forces_are_a_fraction_of_body_weight() {
    let body = body();
    let stand = Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m, 0.0));
    let truth: Vec<MotionFrame> = (0..180).map(|k| frame(k, &stand)).collect();
    // 90 % of body weight, split over the feet.
    let weight = body.mass_kg * 9.81;
    let mut estimate = truth.clone();
    for f in &mut estimate {
        f.ground_reaction_force_n[JointId::LEFT_FOOT.index()] = [0.0, (0.45 * weight) as f32, 0.0];
        f.ground_reaction_force_n[JointId::RIGHT_FOOT.index()] = [0.0, (0.45 * weight) as f32, 0.0];
    }
    let s = score_against_truth(&estimate, &truth, &body, RATE_HZ);
    // 3 s standing, the first second left out.
    assert_eq!(s.standing_frames, 120);
    assert_relative_eq!(s.standing_grf_fraction.unwrap(), 0.9, epsilon = 1e-6);
    assert_relative_eq!(s.standing_grf_deviation.unwrap(), 0.1, epsilon = 1e-6);
    // No forces at all: a stream without physics, not a body in free fall.
    let s = score_against_truth(&truth, &truth, &body, RATE_HZ);
    assert!(s.standing_grf_fraction.is_none());
    // A truth that never stands still gives no standing frames.
    let walking = gliding_truth(&body, 180);
    let s = score_against_truth(&estimate, &walking, &body, RATE_HZ);
    assert_eq!(s.standing_frames, 0);
    assert!(s.standing_grf_fraction.is_none());
}

#[test]
fn a_validation_stream_summarizes_like_the_stage() {
    let mass_kg = 70.0;
    let feet = (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index());
    let mut frames: Vec<ValidationFrame> = (0..600)
        .map(|k| {
            let mut f = ValidationFrame::default();
            f.header.seq = k;
            f.tracking_error_m = k as f32 / 1000.0;
            // Half the frames a foot is down, sliding at 0.2 m/s; the others report 0 skate.
            if k % 2 == 0 {
                f.sim_contact_mask = feet;
                f.foot_skate_mps = 0.2;
            }
            f.residual_root_force_n = [0.0, (0.5 * mass_kg * 9.81) as f32, 0.0];
            // Support: the first 4 frames not judged; then every 10th frame unsupported, every
            // 10th (shifted) with the centre of pressure 5 cm outside the feet, one 2 cm outside
            // (within the 3 cm tolerance), the rest inside or in flight.
            f.support = match k {
                0..4 => 0,
                _ if k % 10 == 0 => 3,
                _ if k % 3 == 0 => 2,
                _ => 1,
            };
            if k >= 4 && k % 10 == 5 {
                f.support = 1;
                f.support_gap_m = 0.05;
            }
            if k == 7 {
                f.support_gap_m = 0.02;
            }
            f
        })
        .collect();
    // Two falls in 10 s; one resync.
    frames[200].balance_lost = 1;
    frames[400].balance_lost = 1;
    for f in &mut frames[300..] {
        f.resyncs = 1;
    }
    // A flagged frame with absurd values is left out.
    let mut flagged = ValidationFrame::default();
    flagged.header.seq = 600;
    flagged.header.flags = flags::INVALID;
    flagged.tracking_error_m = 100.0;
    flagged.balance_lost = 1;
    frames.push(flagged);
    let v = summarize_validation(&frames, RATE_HZ, mass_kg);
    assert_eq!((v.frames, v.skipped, v.falls, v.resyncs), (600, 1, 2, 1));
    assert_relative_eq!(v.simulated_s, 10.0, epsilon = 1e-12);
    assert_relative_eq!(v.falls_per_minute, 12.0, epsilon = 1e-9);
    assert_relative_eq!(v.tracking_error_mean_m, 0.2995, epsilon = 1e-6);
    // The stage's percentile: the value at rank round(0.95 · 599) = 569.
    assert_relative_eq!(v.tracking_error_p95_m, 0.569, epsilon = 1e-6);
    assert_relative_eq!(v.foot_skate_mean_mps, 0.2, epsilon = 1e-6);
    assert_relative_eq!(v.residual_force_mean_fraction, 0.5, epsilon = 1e-6);
    // 596 judged frames: 60 unsupported (10, 20, ..., 590, and 0 is not judged: 59) and 60
    // outside (5, 15, ..., 595).
    assert_relative_eq!(
        v.support_violated_fraction,
        (59.0 + 60.0) / 596.0,
        epsilon = 1e-12
    );
}

#[test]
fn sensor_bone_error_pairs_by_seq_and_leaves_out_incomplete_measurements() {
    use imuflow_graph::frames::BodyImuFrame;
    let body = body();
    let estimate = gliding_truth(&body, 4);
    // Every bone of the gliding T-pose is at identity; the measurements agree except the head
    // sensor, 60° off about x, so the mean over six sensors is 10°.
    let head = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 60f64.to_radians());
    let measured = |seq: u64, valid_mask: u32| {
        let mut f = BodyImuFrame::default();
        f.header.seq = seq;
        f.valid_mask = valid_mask;
        f.bone_orientation_wxyz = [[1.0, 0.0, 0.0, 0.0]; imuflow_graph::frames::MAX_SITES];
        f.bone_orientation_wxyz[4] = quat_wxyz_from_rotation(&head).map(|v| v as f32);
        (seq, f)
    };
    // Seq 1's head sensor is not valid, seq 3 has no measurement: both left out.
    let frames: std::collections::BTreeMap<u64, BodyImuFrame> =
        [measured(0, 0x3f), measured(1, 0x2f), measured(2, 0x3f)].into();
    let six = imuflow_body::SensorSet::six().mask();
    let error = sensor_bone_error_deg(&estimate, &frames, &body, six).unwrap();
    assert_relative_eq!(error, 10.0, epsilon = 1e-4);
    // A lower-body set (pelvis, lower legs, upper legs: slots 2, 3, 5, 6, 7) has no head sensor:
    // every sensor agrees, and seq 1 (its head invalid) counts too. A frame without the thighs'
    // samples is left out for it.
    let legs = imuflow_body::SensorSet::builtin("lower-body")
        .unwrap()
        .mask();
    let frames_legs: std::collections::BTreeMap<u64, BodyImuFrame> =
        [measured(0, 0xff), measured(1, 0xef), measured(2, 0x3f)].into();
    let error = sensor_bone_error_deg(&estimate, &frames_legs, &body, legs).unwrap();
    assert_relative_eq!(error, 0.0, epsilon = 1e-4);
    assert_eq!(
        sensor_bone_error_deg(&estimate, &[measured(2, 0x3f)].into(), &body, legs),
        None
    );
    // An estimate whose frames are all flagged INVALID has nothing to score.
    let invalid: Vec<MotionFrame> = estimate
        .iter()
        .map(|f| {
            let mut g = *f;
            g.header.flags |= flags::INVALID;
            g
        })
        .collect();
    assert_eq!(sensor_bone_error_deg(&invalid, &frames, &body, six), None);
}
