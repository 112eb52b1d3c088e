//! The knees and elbows as the joints they are: a knee turns about one axis, an elbow flexes about
//! one axis and lets the forearm twist about its own; and the projection of a pose onto them.
//!
//! Why it matters: the networks predict each bone's global orientation on its own, so an upper
//! leg and a lower leg that each look right can meet at a knee bent sideways or twisted. Where the
//! lower leg (or forearm) carries a sensor, its orientation is known to the calibration error, and
//! the anatomical joint then pins all but the flexion (knee) or the flexion and twist (elbow) of the
//! bone above it. [`project_limb_joints`] keeps the lower bones' global orientations and moves what
//! the joint cannot do onto the upper leg and upper arm.
//!
//! The axes, in the local frames of the SMPL topology (x = left, y = up, z = forward in the
//! T-pose): a knee flexes about x; an elbow is `Ry(flexion)·Rx(twist)`, the forearm lying along
//! ±x. In the retargeted Bandai Namco truth the knees are exact x hinges (off-axis p99 0.9°) and the
//! elbows exact `Ry·Rx` (the `Rz` left between them p99 0.5°), measured over 40 walks, 10 runs and 40
//! of the held-out clips (2026-11-26). The papers' networks (PIP, GlobalPose) output free 3-DoF
//! rotations for both joints and impose nothing of the kind.

use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use crate::NUM_JOINTS;
use crate::kinematics::local_to_global_rotations;
use crate::skeleton::{JointId, Skeleton};

/// Elbow flexion of people standing at ease, arms hanging, deg: the middle of the 15–35° measured
/// on people not told to straighten their arms. The calibration's relaxed pose assumes it; the
/// synthetic natural start stands with it.
pub const RELAXED_ELBOW_DEG: f64 = 25.0;

/// The knees, each with its hip (the joint whose local rotation takes the correction).
const KNEES: [JointId; 2] = [JointId::LEFT_KNEE, JointId::RIGHT_KNEE];
/// The elbows, each with its shoulder.
const ELBOWS: [JointId; 2] = [JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW];

/// The rotation about `axis` (unit) nearest to `r`: the twist of its swing–twist decomposition
/// (the quaternion's vector part projected on the axis, renormalised). Identity when `r` is a half
/// turn about an axis perpendicular to `axis`, where every rotation about `axis` is as near.
pub fn nearest_rotation_about(r: &Rotation3<f64>, axis: &Vector3<f64>) -> Rotation3<f64> {
    let q = UnitQuaternion::from_rotation_matrix(r);
    let along = axis * q.vector().dot(axis);
    let twist = nalgebra::Quaternion::new(q.w, along.x, along.y, along.z);
    if twist.norm() < 1e-12 {
        return Rotation3::identity();
    }
    UnitQuaternion::new_normalize(twist).to_rotation_matrix()
}

/// A knee's local rotation made a pure flexion (about x), the nearest such rotation.
pub fn hinge_knee(local: &Rotation3<f64>) -> Rotation3<f64> {
    nearest_rotation_about(local, &Vector3::x())
}

/// An elbow's local rotation made `Ry(flexion)·Rx(twist)`: written as `Ry(a)·Rz(b)·Rx(c)`, the
/// abduction `b` is dropped. (The exact nearest two-axis rotation has no closed form; for the few
/// degrees of `b` the networks leave this is the same to second order in `b`.)
pub fn hinge_elbow(local: &Rotation3<f64>) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::y_axis(), elbow_flexion(local)) * elbow_twist(local)
}

/// The flexion `a` of an elbow's local rotation written as `Ry(a)·Rz(b)·Rx(c)` (its first
/// column is `(cos a cos b, sin b, −sin a cos b)`).
fn elbow_flexion(local: &Rotation3<f64>) -> f64 {
    let m = local.matrix();
    (-m[(2, 0)]).atan2(m[(0, 0)])
}

/// The twist `Rx(c)` of an elbow's local rotation written as `Ry(a)·Rz(b)·Rx(c)` (its second
/// row is `(sin b, cos b cos c, −cos b sin c)`).
fn elbow_twist(local: &Rotation3<f64>) -> Rotation3<f64> {
    let m = local.matrix();
    Rotation3::from_axis_angle(&Vector3::x_axis(), (-m[(1, 2)]).atan2(m[(1, 1)]))
}

/// Makes the knees hinges and the elbows flexion-and-twist joints, keeping every lower leg's and
/// forearm's global orientation: what a knee or elbow cannot do moves to the hip or shoulder above
/// it (`parent' = parent · joint · joint'ᵀ`). Every other joint is left as it was.
pub fn project_limb_joints(pose: &mut [Rotation3<f64>; NUM_JOINTS]) {
    for (joints, project) in [
        (KNEES, hinge_knee as fn(&Rotation3<f64>) -> Rotation3<f64>),
        (ELBOWS, hinge_elbow),
    ] {
        for joint in joints {
            let Some(parent) = joint.parent() else {
                continue;
            };
            let (j, p) = (joint.index(), parent.index());
            let projected = project(&pose[j]);
            pose[p] = pose[p] * pose[j] * projected.transpose();
            pose[j] = projected;
        }
    }
}

/// Sets each knee's and elbow's flexion from where the networks put the joints, keeping everything
/// [`project_limb_joints`] fixed: the lower legs' and forearms' global orientations (their sensors)
/// and each elbow's twist. The upper leg (upper arm) then turns about the knee's (elbow's) flexion
/// axis until it points as nearly as it can at the predicted knee (elbow) as seen from the hip
/// (shoulder). `pose` must already be anatomical (after [`project_limb_joints`]).
///
/// Why: with the lower bone on its sensor, the flexion is all that is left to estimate of the
/// upper bone, and the networks' rotations give it only as the angle between their upper bone and
/// the measurement, which carries the rotation network's own error of that upper bone. Both papers'
/// networks also predict every joint's position (PIP's rnn2, GlobalPose's iknet.net1, trained on
/// positions), and the direction from hip to knee pins the same angle independently of it. On the
/// validation split it took PIP's SIP error from 6.85° to 6.79° and GlobalPose's from 5.47° to
/// 5.43° end to end, scored on the clips' own frames (6.97 to 6.40° and 5.72 to 5.68° while the
/// calibration prelude's standing was scored too; stages/kinematics/README.md, "Limb joints").
///
/// `positions` are the predicted joint positions relative to the root, in the frame the pose's
/// root orientation (`pose[0]`) maps to; `skeleton` gives the rest offsets. A prediction along the
/// flexion axis (no direction in the plane the joint allows) leaves that joint as it was.
pub fn flex_toward_positions(
    pose: &mut [Rotation3<f64>; NUM_JOINTS],
    positions: &[Vector3<f64>; NUM_JOINTS],
    skeleton: &Skeleton,
) {
    // Once for all four limbs: each change below keeps every global orientation but its own
    // upper bone's, and no limb reads another's upper bone.
    let mut global = [Rotation3::identity(); NUM_JOINTS];
    local_to_global_rotations(pose, &mut global);
    for knee in KNEES {
        let Some(hip) = knee.parent() else { continue };
        let lower = global[knee.index()];
        // The upper leg is `lower · Rx(θ)ᵀ`: its rest offset to the knee, b, turned by Rx(−θ) in
        // the lower leg's frame, should point at the predicted knee, u in that frame.
        let b = skeleton.offset_in_parent_m(knee);
        let u = lower.transpose() * (positions[knee.index()] - positions[hip.index()]);
        let Some(angle) = angle_in_plane((b.y, b.z), (u.y, u.z)) else {
            continue;
        };
        let flexed = Rotation3::from_axis_angle(&Vector3::x_axis(), -angle);
        set_joint_keeping_child(pose, &global, knee, flexed);
    }
    for elbow in ELBOWS {
        let Some(shoulder) = elbow.parent() else {
            continue;
        };
        let forearm = global[elbow.index()];
        // The elbow is Ry(a)·Rx(c) (hinge_elbow); the twist c stays. The upper arm is then
        // `forearm · Rx(c)ᵀ · Ry(a)ᵀ` and its offset b, turned by Ry(−a), should point at u.
        let twist = elbow_twist(&pose[elbow.index()]);
        let b = skeleton.offset_in_parent_m(elbow);
        let u =
            twist * forearm.transpose() * (positions[elbow.index()] - positions[shoulder.index()]);
        // Ry(ψ) turns (z, x) by ψ, as Rx(ψ) turns (y, z).
        let Some(angle) = angle_in_plane((b.z, b.x), (u.z, u.x)) else {
            continue;
        };
        let flexed = Rotation3::from_axis_angle(&Vector3::y_axis(), -angle) * twist;
        set_joint_keeping_child(pose, &global, elbow, flexed);
    }
}

/// How far past straight a knee or elbow may be turned (hyperextension), rad. Clinical
/// range-of-motion norms allow a few degrees of hyperextension at both joints and count more than
/// about 10° as a hypermobile joint; this limit is that common value, not fitted to the data.
pub const MAX_HYPEREXTENSION_RAD: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// Turns back every knee and elbow that is bent backwards more than [`MAX_HYPEREXTENSION_RAD`]
/// to that limit, keeping the lower legs' and forearms' global orientations (their sensors) and
/// each elbow's twist: only the upper leg or upper arm moves. `pose` must be anatomical (after
/// [`project_limb_joints`]).
///
/// Why: the networks, on motion they never saw, sometimes bend a knee or elbow the wrong way, and
/// the flexion step ([`flex_toward_positions`]) follows their predicted joints there too. A knee
/// flexes about its x axis (positive: the lower leg swings back); a left elbow flexes by a
/// negative `Ry` angle (its forearm, along +x, swings forward to +z), a right elbow (along −x) by
/// a positive one. On the validation split it is better by a hair (SIP pip −0.005°, globalpose
/// −0.002°: those motions rarely bend a limb backwards); on the held-out motions pip's SIP fell
/// from 19.4 to 18.4° (stages/kinematics/README.md, "Limb joints").
pub fn limit_hyperextension(pose: &mut [Rotation3<f64>; NUM_JOINTS]) {
    let mut global = [Rotation3::identity(); NUM_JOINTS];
    local_to_global_rotations(pose, &mut global);
    for knee in KNEES {
        if knee_flexion(&pose[knee.index()]) < -MAX_HYPEREXTENSION_RAD {
            let limited = Rotation3::from_axis_angle(&Vector3::x_axis(), -MAX_HYPEREXTENSION_RAD);
            set_joint_keeping_child(pose, &global, knee, limited);
        }
    }
    for elbow in ELBOWS {
        let local = pose[elbow.index()];
        if elbow_side(elbow) * elbow_flexion(&local) < -MAX_HYPEREXTENSION_RAD {
            let limited = Rotation3::from_axis_angle(
                &Vector3::y_axis(),
                -elbow_side(elbow) * MAX_HYPEREXTENSION_RAD,
            ) * elbow_twist(&local);
            set_joint_keeping_child(pose, &global, elbow, limited);
        }
    }
}

/// A knee's or elbow's flexion (rad) in its local rotation `local`: positive the way the joint
/// bends (the lower leg back, the forearm forward), negative bent backwards; of the nearest
/// anatomical rotation (a knee's hinge angle, an elbow's `Ry` angle signed by its side), so a free
/// 3-DoF rotation has one too. `None` for any other joint.
pub fn flexion(joint: JointId, local: &Rotation3<f64>) -> Option<f64> {
    if KNEES.contains(&joint) {
        Some(knee_flexion(local))
    } else if ELBOWS.contains(&joint) {
        Some(elbow_side(joint) * elbow_flexion(local))
    } else {
        None
    }
}

/// A knee's hinge angle about x (positive: the lower leg swings back).
fn knee_flexion(local: &Rotation3<f64>) -> f64 {
    hinge_knee(local).scaled_axis().x
}

/// The sign that makes an elbow's `Ry` angle its flexion: a left elbow (forearm along +x) flexes
/// by a negative `Ry` angle, a right one (along −x) by a positive one.
fn elbow_side(elbow: JointId) -> f64 {
    if elbow == JointId::LEFT_ELBOW {
        -1.0
    } else {
        1.0
    }
}

/// The angle that turns the planar vector `from` onto the direction of `to` (counter-clockwise
/// from the first axis to the second); `None` when either is too short to have a direction.
fn angle_in_plane(from: (f64, f64), to: (f64, f64)) -> Option<f64> {
    let cross = from.0 * to.1 - from.1 * to.0;
    let dot = from.0 * to.0 + from.1 * to.1;
    let lengths = (from.0.hypot(from.1), to.0.hypot(to.1));
    (lengths.0 > 1e-9 && lengths.1 > 1e-9).then(|| cross.atan2(dot))
}

/// Gives `joint` the local rotation `local` and its parent whatever keeps `joint`'s global
/// orientation (`global`, of the pose before the change).
fn set_joint_keeping_child(
    pose: &mut [Rotation3<f64>; NUM_JOINTS],
    global: &[Rotation3<f64>; NUM_JOINTS],
    joint: JointId,
    local: Rotation3<f64>,
) {
    let Some(parent) = joint.parent() else { return };
    let Some(grandparent) = parent.parent() else {
        return;
    };
    let parent_global = global[joint.index()] * local.transpose();
    pose[parent.index()] = global[grandparent.index()].transpose() * parent_global;
    pose[joint.index()] = local;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::local_to_global_rotations;
    use crate::rotation::angle_between;
    use crate::test_util::{XorShift, random_rotations};

    fn global(local: &[Rotation3<f64>; NUM_JOINTS]) -> [Rotation3<f64>; NUM_JOINTS] {
        let mut world = [Rotation3::identity(); NUM_JOINTS];
        local_to_global_rotations(local, &mut world);
        world
    }

    #[test]
    fn the_nearest_rotation_about_an_axis_beats_every_other_angle() {
        // A second algorithm: a 0.01° grid over the angle about x.
        for r in random_rotations(20, 1) {
            let best = hinge_knee(&r);
            let d = angle_between(&r, &best);
            for k in 0..36_000 {
                let other =
                    Rotation3::from_axis_angle(&Vector3::x_axis(), (k as f64 / 100.0).to_radians());
                assert!(angle_between(&r, &other) >= d - 1e-9);
            }
        }
    }

    #[test]
    fn pure_joints_are_left_alone() {
        let mut rng = XorShift(2);
        for _ in 0..50 {
            let knee = Rotation3::from_axis_angle(&Vector3::x_axis(), 1.3 + 1.1 * rng.signed());
            let elbow = Rotation3::from_axis_angle(&Vector3::y_axis(), 2.5 * rng.signed())
                * Rotation3::from_axis_angle(&Vector3::x_axis(), 1.5 * rng.signed());
            assert!(angle_between(&hinge_knee(&knee), &knee) < 1e-9);
            assert!(angle_between(&hinge_elbow(&elbow), &elbow) < 1e-9);
        }
    }

    #[test]
    fn projection_keeps_the_lower_bones_and_makes_the_joints_anatomical() {
        let random = random_rotations(NUM_JOINTS, 3);
        let pose: [Rotation3<f64>; NUM_JOINTS] = std::array::from_fn(|j| random[j]);
        let before = global(&pose);
        let mut projected = pose;
        project_limb_joints(&mut projected);
        let after = global(&projected);
        let upper = [
            JointId::LEFT_HIP,
            JointId::RIGHT_HIP,
            JointId::LEFT_SHOULDER,
            JointId::RIGHT_SHOULDER,
        ];
        for j in JointId::all() {
            let moved = angle_between(&before[j.index()], &after[j.index()]);
            if upper.contains(&j) {
                assert!(moved > 1e-3, "{} should take the correction", j.name());
            } else {
                assert!(moved < 1e-9, "{} moved {moved} rad", j.name());
            }
        }
        for knee in KNEES {
            let axis = projected[knee.index()].scaled_axis();
            assert!(axis.y.abs() < 1e-9 && axis.z.abs() < 1e-9, "{axis:?}");
        }
        for elbow in ELBOWS {
            // The abduction Rz between the flexion and the twist is gone: m[(1, 0)] = sin b.
            assert!(projected[elbow.index()].matrix()[(1, 0)].abs() < 1e-9);
        }
    }

    fn skeleton() -> Skeleton {
        let params = crate::BodyParams::builtin().unwrap();
        crate::BodyModel::new(&params, 1.75, 70.0).unwrap().skeleton
    }

    /// A random pose with anatomical knees and elbows.
    fn anatomical_pose(seed: u64) -> [Rotation3<f64>; NUM_JOINTS] {
        let random = random_rotations(NUM_JOINTS, seed);
        let mut pose: [Rotation3<f64>; NUM_JOINTS] = std::array::from_fn(|j| random[j]);
        project_limb_joints(&mut pose);
        pose
    }

    /// Joint positions relative to the root, in the root's parent frame (forward kinematics).
    fn positions(
        pose: &[Rotation3<f64>; NUM_JOINTS],
        skeleton: &Skeleton,
    ) -> [Vector3<f64>; NUM_JOINTS] {
        let mut full = crate::Pose::t_pose(Vector3::zeros());
        full.parent_from_joint = *pose;
        let mut fk = crate::FkData::new();
        crate::forward_kinematics(skeleton, &full, &mut fk);
        std::array::from_fn(|j| *fk.position(JointId::all().nth(j).unwrap()))
    }

    /// Turns a knee or elbow by `angle` about its flexion axis, keeping its child bone's global
    /// orientation (what a wrong flexion estimate looks like after `project_limb_joints`).
    fn misflex(
        pose: &mut [Rotation3<f64>; NUM_JOINTS],
        joint: JointId,
        axis: Vector3<f64>,
        angle: f64,
    ) {
        let (j, p) = (joint.index(), joint.parent().unwrap().index());
        let turned =
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle) * pose[j];
        pose[p] = pose[p] * pose[j] * turned.transpose();
        pose[j] = turned;
    }

    /// Each limb's flexion as a positive angle (knee: about x; elbow: the `Ry` angle of
    /// `Ry·Rx`, sign by side), and the elbow's twist.
    fn flexions(pose: &[Rotation3<f64>; NUM_JOINTS]) -> ([f64; 4], [f64; 2]) {
        let knee = |k: JointId| pose[k.index()].scaled_axis().x;
        let elbow = |e: JointId, side: f64| {
            let m = pose[e.index()].matrix();
            side * (-m[(2, 0)]).atan2(m[(0, 0)])
        };
        let twist = |e: JointId| {
            let m = pose[e.index()].matrix();
            (-m[(1, 2)]).atan2(m[(1, 1)])
        };
        (
            [
                knee(JointId::LEFT_KNEE),
                knee(JointId::RIGHT_KNEE),
                elbow(JointId::LEFT_ELBOW, -1.0),
                elbow(JointId::RIGHT_ELBOW, 1.0),
            ],
            ELBOWS.map(twist),
        )
    }

    #[test]
    fn limbs_bent_backwards_past_the_limit_are_turned_back_to_it_and_nothing_else() {
        // The sign convention, checked on the body itself: a flexed knee puts the ankle behind
        // the hip-knee line (−z), a flexed elbow the wrist in front of the shoulder-elbow line (+z).
        let skeleton = skeleton();
        let mut bent = [Rotation3::identity(); NUM_JOINTS];
        bent[JointId::LEFT_KNEE.index()] = Rotation3::from_axis_angle(&Vector3::x_axis(), 1.0);
        bent[JointId::LEFT_ELBOW.index()] = Rotation3::from_axis_angle(&Vector3::y_axis(), -1.0);
        bent[JointId::RIGHT_ELBOW.index()] = Rotation3::from_axis_angle(&Vector3::y_axis(), 1.0);
        let p = positions(&bent, &skeleton);
        let at = |j: JointId| p[j.index()];
        assert!(at(JointId::LEFT_ANKLE).z < at(JointId::LEFT_KNEE).z - 0.1);
        assert!(at(JointId::LEFT_WRIST).z > at(JointId::LEFT_ELBOW).z + 0.1);
        assert!(at(JointId::RIGHT_WRIST).z > at(JointId::RIGHT_ELBOW).z + 0.1);
        for (found, want) in flexions(&bent).0.iter().zip([1.0, 0.0, 1.0, 1.0]) {
            assert!((found - want).abs() < 1e-12, "{found} against {want}");
        }

        let (mut within, mut beyond) = (0, 0);
        for seed in 1..60 {
            let mut pose = anatomical_pose(300 + seed);
            let (before_flexion, before_twist) = flexions(&pose);
            let before = global(&pose);
            limit_hyperextension(&mut pose);
            let (after_flexion, after_twist) = flexions(&pose);
            let after = global(&pose);
            for (b, a) in before_flexion.iter().zip(after_flexion) {
                if *b >= -MAX_HYPEREXTENSION_RAD {
                    within += 1;
                    assert!((a - b).abs() < 1e-9, "seed {seed}: {b} moved to {a}");
                } else {
                    beyond += 1;
                    assert!(
                        (a + MAX_HYPEREXTENSION_RAD).abs() < 1e-9,
                        "seed {seed}: {b} -> {a}"
                    );
                }
            }
            for (b, a) in before_twist.iter().zip(after_twist) {
                assert!((a - b).abs() < 1e-9, "seed {seed}: twist {b} -> {a}");
            }
            // Only the upper legs and arms turn; the lower bones (the sensors') and all else stay.
            let uppers: Vec<JointId> = KNEES
                .iter()
                .chain(&ELBOWS)
                .map(|j| j.parent().unwrap())
                .collect();
            for j in JointId::all().filter(|j| !uppers.contains(j)) {
                let d = angle_between(&before[j.index()], &after[j.index()]);
                assert!(d < 1e-9, "seed {seed}: {} moved {d} rad", j.name());
            }
            // Limited twice is limited once.
            let once = pose;
            limit_hyperextension(&mut pose);
            for j in JointId::all() {
                assert!(angle_between(&once[j.index()], &pose[j.index()]) < 1e-12);
            }
        }
        assert!(
            within > 20 && beyond > 20,
            "{within} within, {beyond} beyond the limit"
        );
    }

    #[test]
    fn flexion_is_positive_the_way_each_limb_bends_and_none_elsewhere() {
        let about =
            |axis: &nalgebra::Unit<Vector3<f64>>, a: f64| Rotation3::from_axis_angle(axis, a);
        let (x, y, z) = (Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis());
        // The bends of the sign-convention test above (checked there on the body's positions).
        let cases = [
            (JointId::LEFT_KNEE, about(&x, 1.0), 1.0),
            (JointId::RIGHT_KNEE, about(&x, -0.2), -0.2),
            (JointId::LEFT_ELBOW, about(&y, -1.0), 1.0),
            (JointId::RIGHT_ELBOW, about(&y, 1.0), 1.0),
            (JointId::RIGHT_ELBOW, about(&y, -0.3), -0.3),
            // Free rotations: the angle of the nearest anatomical one. A knee also turned about
            // z (a swing perpendicular to its hinge) keeps its hinge angle; an elbow written
            // Ry(a)·Rz(b)·Rx(c) has flexion a, whatever its abduction b and twist c.
            (JointId::LEFT_KNEE, about(&z, 0.2) * about(&x, 0.7), 0.7),
            (
                JointId::LEFT_ELBOW,
                about(&y, -0.8) * about(&z, 0.1) * about(&x, 0.5),
                0.8,
            ),
        ];
        for (joint, local, want) in cases {
            let found = flexion(joint, &local).unwrap();
            assert!(
                (found - want).abs() < 1e-12,
                "{}: {found} against {want}",
                joint.name()
            );
        }
        for seed in 1..20 {
            let pose = anatomical_pose(500 + seed);
            let want = flexions(&pose).0;
            for (limb, want) in KNEES.iter().chain(&ELBOWS).zip(want) {
                let found = flexion(*limb, &pose[limb.index()]).unwrap();
                assert!(
                    (found - want).abs() < 1e-12,
                    "seed {seed}: {found} against {want}"
                );
            }
        }
        for joint in [
            JointId::PELVIS,
            JointId::LEFT_HIP,
            JointId::RIGHT_SHOULDER,
            JointId::LEFT_WRIST,
        ] {
            assert_eq!(flexion(joint, &about(&x, 0.5)), None, "{}", joint.name());
        }
    }

    #[test]
    fn the_flexion_of_an_anatomical_pose_is_recovered_from_its_joint_positions() {
        let skeleton = skeleton();
        let mut rng = XorShift(7);
        for seed in 1..40 {
            let truth = anatomical_pose(seed);
            let predicted = positions(&truth, &skeleton);
            let mut pose = truth;
            for knee in KNEES {
                misflex(&mut pose, knee, Vector3::x(), 1.2 * rng.signed());
            }
            for elbow in ELBOWS {
                misflex(&mut pose, elbow, Vector3::y(), 1.2 * rng.signed());
            }
            flex_toward_positions(&mut pose, &predicted, &skeleton);
            for j in JointId::all() {
                let d = angle_between(&pose[j.index()], &truth[j.index()]);
                assert!(d < 1e-9, "seed {seed}: {} off by {d} rad", j.name());
            }
        }
    }

    #[test]
    fn the_upper_bone_points_nearest_the_prediction_and_the_sensor_bones_stay() {
        let skeleton = skeleton();
        let mut rng = XorShift(11);
        for seed in 1..20 {
            let mut pose = anatomical_pose(100 + seed);
            // Predictions that no anatomical pose matches exactly: each joint moved up to 10 cm.
            let mut predicted = positions(&anatomical_pose(200 + seed), &skeleton);
            for p in predicted.iter_mut() {
                *p += 0.1 * Vector3::new(rng.signed(), rng.signed(), rng.signed());
            }
            let before = global(&pose);
            let twist = |r: &Rotation3<f64>| (-r.matrix()[(1, 2)]).atan2(r.matrix()[(1, 1)]);
            let twists = ELBOWS.map(|e| twist(&pose[e.index()]));
            flex_toward_positions(&mut pose, &predicted, &skeleton);
            let after = global(&pose);
            for (i, elbow) in ELBOWS.iter().enumerate() {
                assert!((twist(&pose[elbow.index()]) - twists[i]).abs() < 1e-9);
                assert!(
                    pose[elbow.index()].matrix()[(1, 0)].abs() < 1e-9,
                    "still Ry·Rx"
                );
            }
            for knee in KNEES {
                let axis = pose[knee.index()].scaled_axis();
                assert!(
                    axis.y.abs() < 1e-9 && axis.z.abs() < 1e-9,
                    "still a hinge: {axis:?}"
                );
            }
            // Only the upper legs and arms turn; the lower bones (the sensors') and all else stay.
            let uppers = KNEES.iter().chain(&ELBOWS).map(|j| j.parent().unwrap());
            let uppers: Vec<JointId> = uppers.collect();
            for j in JointId::all().filter(|j| !uppers.contains(j)) {
                let d = angle_between(&before[j.index()], &after[j.index()]);
                assert!(d < 1e-9, "{} moved {d} rad", j.name());
            }
            for (joint, axis) in KNEES
                .map(|k| (k, Vector3::x()))
                .into_iter()
                .chain(ELBOWS.map(|e| (e, Vector3::y())))
            {
                let parent = joint.parent().unwrap();
                // A second algorithm: no other flexion (0.05° grid) points the upper bone closer.
                let target = (predicted[joint.index()] - predicted[parent.index()]).normalize();
                let offset = skeleton.offset_in_parent_m(joint).normalize();
                let best = (after[parent.index()] * offset).dot(&target);
                let lower = after[joint.index()];
                let local = pose[joint.index()];
                for k in 0..7200 {
                    let extra = Rotation3::from_axis_angle(
                        &nalgebra::Unit::new_normalize(axis),
                        (k as f64 * 0.05).to_radians(),
                    );
                    let other = lower * (extra * local).transpose();
                    assert!((other * offset).dot(&target) <= best + 1e-12);
                }
            }
        }
    }
}
