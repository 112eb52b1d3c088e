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
use crate::skeleton::JointId;

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
    let m = local.matrix();
    // Ry(a)·Rz(b)·Rx(c): first column (cos a cos b, sin b, −sin a cos b), second row
    // (sin b, cos b cos c, −cos b sin c).
    let flexion = (-m[(2, 0)]).atan2(m[(0, 0)]);
    let twist = (-m[(1, 2)]).atan2(m[(1, 1)]);
    Rotation3::from_axis_angle(&Vector3::y_axis(), flexion)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), twist)
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
}
