//! Augmentations of the motion itself (not of the sensors): more kinds of movement from the same
//! clips. Applied to training clips only, so validation, test and holdout stay the recorded motion.
//!
//! - [`mirror`]: the clip reflected left–right (the sagittal plane): a left-handed wave becomes a
//!   right-handed one, a turn to the left a turn to the right.
//! - [`time_warp`]: the clip played `speed` times faster (slower below 1), then resampled to the
//!   shard rate; the body moves through the same poses at other velocities and accelerations.
//! - [`recombine`]: the legs and pelvis of one clip under the spine, head and arms of another: a
//!   punch while walking, a wave while turning. Every joint keeps a rotation some person made, so
//!   the new poses stay within joint limits; only their combination is new.

use imuflow_body::JointId;
use imuflow_body::retarget::{MotionClip, ResampleError, resample};
use nalgebra::{Matrix3, Rotation3};

/// The joint on the other side of the body (itself on the midline), SMPL order.
pub fn mirror_joint(j: JointId) -> JointId {
    let i = j.index();
    // SMPL pairs: hips 1/2, knees 4/5, ankles 7/8, feet 10/11, collars 13/14, shoulders 16/17,
    // elbows 18/19, wrists 20/21, hands 22/23.
    let other = match i {
        1 | 4 | 7 | 10 | 13 | 16 | 18 | 20 | 22 => i + 1,
        2 | 5 | 8 | 11 | 14 | 17 | 19 | 21 | 23 => i - 1,
        _ => i,
    };
    JointId::from_index(other).unwrap_or(j)
}

/// The reflection x → −x of the model frame (x is the body's left).
fn reflection() -> Matrix3<f64> {
    Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, 1.0, 1.0))
}

/// `clip` reflected across the body's sagittal plane (x → −x in the model frame): each joint takes
/// its mirror joint's rotation conjugated by the reflection, `S·R·S` (a rotation again: S is its
/// own inverse and det S² = 1), and the root moves to (−x, y, z). On a left–right symmetric body
/// model the joint positions are the reflected positions of the mirror joints.
pub fn mirror(clip: &MotionClip) -> MotionClip {
    let s = reflection();
    let poses = clip
        .poses
        .iter()
        .map(|pose| {
            let mut m = pose.clone();
            for j in JointId::all() {
                let r = pose.parent_from_joint[mirror_joint(j).index()];
                m.parent_from_joint[j.index()] =
                    Rotation3::from_matrix_unchecked(s * r.matrix() * s);
            }
            m.root_in_world_m.x = -pose.root_in_world_m.x;
            m
        })
        .collect();
    MotionClip {
        frame_time_s: clip.frame_time_s,
        poses,
    }
}

/// The joints [`recombine`] takes from the upper-body clip, SMPL order: spine1 3, spine2 6, spine3 9,
/// neck 12, collars 13/14, head 15, shoulders 16/17, elbows 18/19, wrists 20/21, hands 22/23. The
/// rest (pelvis 0 with the root's path and heading, hips 1/2, knees 4/5, ankles 7/8, feet 10/11)
/// come from the lower-body clip.
pub const UPPER_BODY: [usize; 15] = [3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23];

/// The lower body (root path, pelvis, legs) of `lower` with the upper body ([`UPPER_BODY`]: local
/// rotations from the first spine joint up) of `upper`, frame by frame; as long as the shorter of
/// the two. Both clips must have the same frame time (resample them to the shard rate first).
pub fn recombine(lower: &MotionClip, upper: &MotionClip) -> MotionClip {
    debug_assert!((lower.frame_time_s - upper.frame_time_s).abs() < 1e-9);
    let poses = lower
        .poses
        .iter()
        .zip(&upper.poses)
        .map(|(l, u)| {
            let mut pose = l.clone();
            for &j in &UPPER_BODY {
                pose.parent_from_joint[j] = u.parent_from_joint[j];
            }
            pose
        })
        .collect();
    MotionClip {
        frame_time_s: lower.frame_time_s,
        poses,
    }
}

/// `clip` played `speed` times as fast, resampled to `rate_hz`.
pub fn time_warp(clip: &MotionClip, speed: f64, rate_hz: f64) -> Result<MotionClip, ResampleError> {
    let faster = MotionClip {
        frame_time_s: clip.frame_time_s / speed,
        poses: clip.poses.clone(),
    };
    resample(&faster, rate_hz)
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::{BodyModel, BodyParams, FkData, Pose, forward_kinematics};
    use nalgebra::{Unit, Vector3};

    fn some_pose() -> Pose {
        let mut pose = Pose::t_pose(Vector3::new(0.3, 0.9, -1.2));
        for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
            let axis = Unit::new_normalize(Vector3::new(1.0, j as f64 - 4.0, 0.5 * j as f64));
            *r = Rotation3::from_axis_angle(&axis, 0.1 + 0.05 * j as f64);
        }
        pose
    }

    #[test]
    fn mirrored_joints_are_the_reflected_positions_of_their_mirror_joints() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let clip = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![some_pose()],
        };
        let mirrored = mirror(&clip);
        let (mut fk, mut fk_m) = (FkData::new(), FkData::new());
        forward_kinematics(&body.skeleton, &clip.poses[0], &mut fk);
        forward_kinematics(&body.skeleton, &mirrored.poses[0], &mut fk_m);
        for j in JointId::all() {
            let p = fk.position(mirror_joint(j));
            let want = Vector3::new(-p.x, p.y, p.z);
            let got = fk_m.position(j);
            assert!((got - want).norm() < 1e-9, "{}: {got} vs {want}", j.name());
            // Every mirrored rotation is a proper rotation.
            let d = mirrored.poses[0].parent_from_joint[j.index()]
                .matrix()
                .determinant();
            assert!((d - 1.0).abs() < 1e-12);
        }
        // Twice is the original.
        let back = mirror(&mirrored);
        for (a, b) in back.poses[0]
            .parent_from_joint
            .iter()
            .zip(&clip.poses[0].parent_from_joint)
        {
            assert!((a.matrix() - b.matrix()).norm() < 1e-12);
        }
    }

    #[test]
    fn recombined_legs_follow_the_lower_clip_and_arms_the_upper_clip() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let lower = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![some_pose(), some_pose(), some_pose()],
        };
        let mut other = Pose::t_pose(Vector3::new(-4.0, 1.1, 7.0));
        for (j, r) in other.parent_from_joint.iter_mut().enumerate() {
            *r = Rotation3::from_axis_angle(&Vector3::y_axis(), -0.3 + 0.02 * j as f64);
        }
        let upper = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![other.clone(), other.clone()],
        };
        let mixed = recombine(&lower, &upper);
        assert_eq!(mixed.poses.len(), 2, "as long as the shorter clip");
        let (mut fk_l, mut fk_u, mut fk_m) = (FkData::new(), FkData::new(), FkData::new());
        forward_kinematics(&body.skeleton, &lower.poses[0], &mut fk_l);
        forward_kinematics(&body.skeleton, &other, &mut fk_u);
        forward_kinematics(&body.skeleton, &mixed.poses[0], &mut fk_m);
        // The legs stand where the lower clip's stand (same root, pelvis and leg rotations).
        for j in [0, 1, 2, 4, 5, 7, 8, 10, 11] {
            let j = JointId::from_index(j).unwrap();
            assert!(
                (fk_m.position(j) - fk_l.position(j)).norm() < 1e-12,
                "{}",
                j.name()
            );
        }
        // The arms hold the upper clip's posture relative to the chest (spine3's frame).
        let chest = JointId::from_index(9).unwrap();
        for j in [16, 18, 20, 15] {
            let j = JointId::from_index(j).unwrap();
            let in_chest = |fk: &FkData| {
                fk.world_from(chest).inverse() * (fk.position(j) - fk.position(chest))
            };
            assert!(
                (in_chest(&fk_m) - in_chest(&fk_u)).norm() < 1e-9,
                "{}",
                j.name()
            );
        }
    }

    #[test]
    fn the_mirror_map_pairs_left_and_right() {
        assert_eq!(mirror_joint(JointId::LEFT_ELBOW), JointId::RIGHT_ELBOW);
        assert_eq!(mirror_joint(JointId::RIGHT_HAND), JointId::LEFT_HAND);
        assert_eq!(mirror_joint(JointId::HEAD), JointId::HEAD);
        for j in JointId::all() {
            assert_eq!(mirror_joint(mirror_joint(j)), j);
            assert!(
                j.name().contains("left") == mirror_joint(j).name().contains("right")
                    || mirror_joint(j) == j
            );
        }
    }

    #[test]
    fn time_warp_changes_the_duration_and_keeps_the_path() {
        // The root moves 1 m along z in 1 s at 30 Hz; twice as fast it takes 0.5 s at 60 Hz.
        let poses = (0..=30)
            .map(|k| Pose::t_pose(Vector3::new(0.0, 0.9, k as f64 / 30.0)))
            .collect();
        let clip = MotionClip {
            frame_time_s: 1.0 / 30.0,
            poses,
        };
        let fast = time_warp(&clip, 2.0, 60.0).unwrap();
        assert_eq!(fast.poses.len(), 31);
        assert!((fast.poses[30].root_in_world_m.z - 1.0).abs() < 1e-9);
        assert!((fast.poses[15].root_in_world_m.z - 0.5).abs() < 1e-9);
        let slow = time_warp(&clip, 0.5, 60.0).unwrap();
        assert_eq!(slow.poses.len(), 121);
        assert!((slow.poses[120].root_in_world_m.z - 1.0).abs() < 1e-9);
    }
}
