use super::*;
use crate::MAX_ROOT_SPEED_MPS;
use imuflow_body::NUM_JOINTS;
use nalgebra::Rotation3;

fn method() -> GlobalPose {
    GlobalPose::new(
        PhysicsBody::new(1.75, 70.0).unwrap(),
        GlobalPoseConfig::default(),
    )
    .unwrap()
}

/// The T-pose, feet stationary, no network velocity.
fn standing() -> Reference {
    Reference {
        stationary_prob: [0.0, 0.9, 0.9, 0.0, 0.0],
        ..Reference::default()
    }
}

const FEET_MASK: u32 = (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index());

#[test]
fn globalpose_standing_still_holds_the_root_and_carries_the_weight_on_both_feet() {
    let mut m = method();
    let reference = standing();
    let mut out = MotionEstimate::default();
    assert!(!m.step(&reference, None, &mut out).unwrap().fallback);
    let start = out.pose.root_in_world_m;
    // First frame: the T-pose stands on its feet (foot clearance = rest height).
    assert!(
        (start.y - m.physics.body.rest_root_height_m).abs() < 1e-9,
        "{start}"
    );
    for frame in 0..60 {
        let report = m.step(&reference, None, &mut out).unwrap();
        assert!(!report.fallback, "frame {frame}");
    }
    let drift = (out.pose.root_in_world_m - start).norm();
    assert!(drift < 0.01, "root drift {drift} m");
    assert_eq!(out.contact_mask, FEET_MASK);
    assert_eq!(m.contacts().mask, FEET_MASK);
    // The proxy surface under the standing feet is the floor (within a centimetre); joints not in
    // contact have none.
    for (j, h) in out.surface_height_m.iter().enumerate() {
        if FEET_MASK & (1 << j) != 0 {
            assert!(h.abs() < 0.01, "joint {j}: surface at {h} m");
        } else {
            assert_eq!(*h, 0.0, "joint {j}");
        }
    }
    // Independent expectation: standing still, the floor carries the body's weight.
    let mg = m.physics.model.total_mass_kg() * 9.81;
    let grf: f64 = out.ground_reaction_force_n.iter().map(|f| f.y).sum();
    assert!(
        (grf - mg).abs() < 0.1 * mg,
        "vertical GRF {grf} N vs m·g {mg} N"
    );
    // Both feet share it (the pose is symmetric).
    let (l, r) = (
        out.ground_reaction_force_n[JointId::LEFT_FOOT.index()].y,
        out.ground_reaction_force_n[JointId::RIGHT_FOOT.index()].y,
    );
    assert!((l - r).abs() < 0.1 * mg, "{l} {r}");
    // The pose stays the reference.
    for j in 0..NUM_JOINTS {
        let a = out.pose.parent_from_joint[j].angle_to(reference.rotation(j));
        assert!(a < 1e-3, "joint {j}: {a} rad");
    }
}

#[test]
fn globalpose_re_tracking_leaves_less_residual_force_than_pre_tracking() {
    let mut m = method();
    let reference = standing();
    let mut out = MotionEstimate::default();
    for _ in 0..10 {
        m.step(&reference, None, &mut out).unwrap();
    }
    assert_eq!(out.contact_mask, FEET_MASK);
    let r = m.pass_residuals();
    let pre = r.pre_tracking.fixed_rows::<3>(0).norm();
    let post = r.re_tracking.fixed_rows::<3>(0).norm();
    // Pre-tracking has no contacts: the root carries (about) the weight. Re-tracking: the feet do.
    let mg = m.physics.model.total_mass_kg() * 9.81;
    assert!((pre - mg).abs() < 0.05 * mg, "pre {pre} vs {mg}");
    assert!(post < 0.5 * pre, "pre {pre} N, post {post} N");
    assert!((out.residual_root_force_n.norm() - post).abs() < 1e-9);
}

#[test]
fn globalpose_tracks_a_bent_knee() {
    let mut m = method();
    let mut reference = standing();
    let mut out = MotionEstimate::default();
    m.step(&reference, None, &mut out).unwrap();
    m.step(&reference, None, &mut out).unwrap();
    // Bend the left knee 35° (shank backwards); the left foot moves, the right one stands.
    let knee = JointId::LEFT_KNEE.index();
    reference.pose.parent_from_joint[knee] =
        Rotation3::new(Vector3::new(35f64.to_radians(), 0.0, 0.0));
    reference.stationary_prob = [0.0, 0.0, 0.9, 0.0, 0.0];
    let first_error = out.pose.parent_from_joint[knee].angle_to(reference.rotation(knee));
    for frame in 0..30 {
        assert!(
            !m.step(&reference, None, &mut out).unwrap().fallback,
            "{frame}"
        );
    }
    let error = out.pose.parent_from_joint[knee]
        .angle_to(reference.rotation(knee))
        .to_degrees();
    assert!(first_error.to_degrees() > 30.0);
    assert!(error < 2.0, "knee error after 30 frames: {error}°");
    assert!(out.contact_mask & (1 << JointId::LEFT_FOOT.index()) == 0);
}

#[test]
fn globalpose_nan_reference_falls_back_without_panicking() {
    let mut m = method();
    let good = standing();
    let mut out = MotionEstimate::default();
    for _ in 0..3 {
        m.step(&good, None, &mut out).unwrap();
    }
    let before = out.pose.root_in_world_m;
    let mut bad = good.clone();
    bad.pose.parent_from_joint[5] =
        Rotation3::from_matrix_unchecked(nalgebra::Matrix3::repeat(f64::NAN));
    bad.root_velocity_mps.x = f64::NAN;
    let report = m.step(&bad, None, &mut out).unwrap();
    assert!(report.fallback);
    assert!(out.pose.is_finite() && out.v.iter().all(|v| v.is_finite()));
    assert!((out.pose.root_in_world_m - before).norm() < 0.01);
    // The next good frame continues normally.
    let report = m.step(&good, None, &mut out).unwrap();
    assert!(!report.fallback && out.pose.is_finite());
    // The first frame of a sequence can be bad too.
    m.reset();
    assert!(m.step(&bad, None, &mut out).unwrap().fallback);
    assert!(out.pose.is_finite());
}

#[test]
fn globalpose_falls_back_instead_of_following_a_reference_faster_than_a_human() {
    // A network velocity of 400 m/s, no stationary joints: tracking it would accelerate the root
    // far past any human speed within a frame or two.
    let mut m = method();
    let mut out = MotionEstimate::default();
    m.step(&standing(), None, &mut out).unwrap();
    let start = out.pose.root_in_world_m;
    let runaway = Reference {
        root_velocity_mps: Vector3::new(400.0, 0.0, 0.0),
        stationary_prob: [0.0; 5],
        ..Reference::default()
    };
    let mut fallbacks = 0;
    for frame in 1..=30 {
        fallbacks += usize::from(m.step(&runaway, None, &mut out).unwrap().fallback);
        let root_speed = out.v.fixed_rows::<3>(0).norm();
        assert!(
            root_speed <= MAX_ROOT_SPEED_MPS,
            "frame {frame}: {root_speed} m/s"
        );
        let travelled = (out.pose.root_in_world_m - start).norm();
        let bound = MAX_ROOT_SPEED_MPS * frame as f64 * m.config.dt_s + 1e-9;
        assert!(travelled <= bound, "frame {frame}: {travelled} m");
    }
    assert!(
        fallbacks > 0,
        "the reference was not fast enough to test anything"
    );
}

#[test]
fn globalpose_rejects_bad_configurations() {
    let physics = PhysicsBody::new(1.75, 70.0).unwrap();
    let bad = GlobalPoseConfig {
        dt_s: 0.0,
        ..GlobalPoseConfig::default()
    };
    assert!(GlobalPose::new(physics.clone(), bad).is_err());
    let bad = GlobalPoseConfig {
        kp_rotation: f64::NAN,
        ..GlobalPoseConfig::default()
    };
    assert!(GlobalPose::new(physics, bad).is_err());
}
