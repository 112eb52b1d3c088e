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
//! - [`perturb`]: smooth random offsets on the spine, neck, head, collar, shoulder and elbow
//!   rotations (a deeper bow, a twist, arms further in front or raised, elbows bent further),
//!   within ranges that keep the joints inside their anatomical limits: postures no recorded clip
//!   holds, on the recorded legs and root path.

use imuflow_body::JointId;
use imuflow_body::retarget::{MotionClip, ResampleError, resample};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

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

/// The range of [`perturb`]'s offset on one joint, degrees about the joint's own x (the body's
/// left in the T-pose: forward bend of the spine, twist of a T-posed arm), y (up: twist of the
/// spine, an arm swung forward or back) and z (forward: lateral bend, an arm raised or lowered)
/// axes, `[low, high]` each.
struct OffsetRange {
    joint: JointId,
    degrees: [[f64; 2]; 3],
}

/// Why these ranges: the spine's three joints together bend forward up to 45° and back 24°, bend
/// sideways and twist up to 24° and 30° (about the ranges of motion of the thoracolumbar spine);
/// neck and head ±10° each; collars ±8°; shoulders swing mostly forward (the hands in front of the
/// body, crossed arms: the postures issue 12 measured the networks getting wrong), rise or drop
/// 25° and twist 25°, which stays inside the shoulder's range from any recorded posture but its
/// extremes. Elbows get a flexion offset of their own ([`ELBOW_FLEXION_DEG`]).
const OFFSET_RANGES: [OffsetRange; 9] = [
    OffsetRange {
        joint: JointId::SPINE1,
        degrees: [[-8.0, 15.0], [-10.0, 10.0], [-8.0, 8.0]],
    },
    OffsetRange {
        joint: JointId::SPINE2,
        degrees: [[-8.0, 15.0], [-10.0, 10.0], [-8.0, 8.0]],
    },
    OffsetRange {
        joint: JointId::SPINE3,
        degrees: [[-8.0, 15.0], [-10.0, 10.0], [-8.0, 8.0]],
    },
    OffsetRange {
        joint: JointId::NECK,
        degrees: [[-10.0, 10.0], [-10.0, 10.0], [-10.0, 10.0]],
    },
    OffsetRange {
        joint: JointId::HEAD,
        degrees: [[-10.0, 10.0], [-10.0, 10.0], [-10.0, 10.0]],
    },
    OffsetRange {
        joint: JointId::LEFT_COLLAR,
        degrees: [[-8.0, 8.0], [-8.0, 8.0], [-8.0, 8.0]],
    },
    OffsetRange {
        joint: JointId::RIGHT_COLLAR,
        degrees: [[-8.0, 8.0], [-8.0, 8.0], [-8.0, 8.0]],
    },
    // The left arm lies along +x: about y, negative swings it forward; about z, positive raises it.
    OffsetRange {
        joint: JointId::LEFT_SHOULDER,
        degrees: [[-25.0, 25.0], [-45.0, 15.0], [-25.0, 25.0]],
    },
    // The right arm lies along −x: the mirror image (positive about y forward, negative about z up).
    OffsetRange {
        joint: JointId::RIGHT_SHOULDER,
        degrees: [[-25.0, 25.0], [-15.0, 45.0], [-25.0, 25.0]],
    },
];

/// The elbows' extra flexion, degrees, `[low, high]`: negative straightens the arm. The offset is
/// clamped frame by frame so the elbow stays between straight and [`ELBOW_MAX_FLEXION_DEG`].
const ELBOW_FLEXION_DEG: [f64; 2] = [-30.0, 50.0];
const ELBOW_MAX_FLEXION_DEG: f64 = 145.0;

/// A smooth random signal in [−1, 1]: three sinusoids of 0.05–0.5 Hz (a posture held for
/// seconds, changing over one to ten) with random phases and weights summing to 1.
struct SmoothNoise {
    parts: [(f64, f64, f64); 3],
}

impl SmoothNoise {
    fn new(rng: &mut StdRng) -> SmoothNoise {
        let mut parts = [(0.0, 0.0, 0.0); 3];
        for p in &mut parts {
            *p = (
                rng.random_range(0.1..1.0),
                std::f64::consts::TAU * rng.random_range(0.05..0.5),
                rng.random_range(0.0..std::f64::consts::TAU),
            );
        }
        let total: f64 = parts.iter().map(|p| p.0).sum();
        for p in &mut parts {
            p.0 /= total;
        }
        SmoothNoise { parts }
    }

    fn at(&self, t_s: f64) -> f64 {
        self.parts
            .iter()
            .map(|&(w, omega, phase)| w * (omega * t_s + phase).sin())
            .sum()
    }

    /// The signal mapped onto `[low, high]`.
    fn in_range(&self, t_s: f64, [low, high]: [f64; 2]) -> f64 {
        low + 0.5 * (self.at(t_s) + 1.0) * (high - low)
    }
}

/// `clip` with smooth random offsets (seeded by `seed`) on the upper body's joints: each joint's
/// recorded local rotation R becomes R·exp(ω(t)), ω's components drawn from [`OFFSET_RANGES`];
/// each elbow's flexion changes by [`ELBOW_FLEXION_DEG`] about the axis of its recorded bend,
/// clamped to keep the elbow between straight and 145°. Legs, pelvis and root path stay recorded.
pub fn perturb(clip: &MotionClip, seed: u64) -> MotionClip {
    let mut rng = StdRng::seed_from_u64(seed);
    let joints: Vec<(JointId, [[f64; 2]; 3], [SmoothNoise; 3])> = OFFSET_RANGES
        .iter()
        .map(|r| {
            let noise = [(); 3].map(|_| SmoothNoise::new(&mut rng));
            (r.joint, r.degrees, noise)
        })
        .collect();
    let elbows =
        [JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW].map(|j| (j, SmoothNoise::new(&mut rng)));
    let poses = clip
        .poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let t_s = k as f64 * clip.frame_time_s;
            let mut p = pose.clone();
            for (joint, degrees, noise) in &joints {
                let omega =
                    Vector3::from_fn(|a, _| noise[a].in_range(t_s, degrees[a]).to_radians());
                let r = &mut p.parent_from_joint[joint.index()];
                *r *= Rotation3::new(omega);
            }
            for (joint, noise) in &elbows {
                let r = &mut p.parent_from_joint[joint.index()];
                *r = flex_elbow(*r, *joint, noise.in_range(t_s, ELBOW_FLEXION_DEG));
            }
            p
        })
        .collect();
    MotionClip {
        frame_time_s: clip.frame_time_s,
        poses,
    }
}

/// The elbow rotation `r` bent `extra_deg` further (straightened below 0) about the hinge its
/// recorded bend turns about, the result kept between straight and [`ELBOW_MAX_FLEXION_DEG`]. A
/// nearly straight elbow has no measurable hinge: a small share of the T-pose's forward-flexion
/// axis (the forearm swings towards +z, the body's front) keeps the hinge continuous there; above
/// about 15° of recorded bend the bend's own axis dominates.
fn flex_elbow(r: Rotation3<f64>, joint: JointId, extra_deg: f64) -> Rotation3<f64> {
    // The forearm's rest direction in the elbow's frame: along the arm, +x on the left.
    let rest = if joint == JointId::LEFT_ELBOW {
        Vector3::x()
    } else {
        -Vector3::x()
    };
    let bent = r * rest;
    let flexion = rest.angle(&bent);
    let front_hinge = rest.cross(&Vector3::z());
    let hinge = (rest.cross(&bent) + 0.05 * front_hinge).normalize();
    let target = (flexion + extra_deg.to_radians()).clamp(0.0, ELBOW_MAX_FLEXION_DEG.to_radians());
    Rotation3::from_axis_angle(&nalgebra::Unit::new_unchecked(hinge), target - flexion) * r
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
    fn perturbed_postures_stay_in_range_and_change_smoothly() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        // 20 s of the T-pose with the elbows bent 90° forward and then 140° (near the limit).
        let mut poses = Vec::new();
        for k in 0..1200 {
            let mut pose = Pose::t_pose(Vector3::new(0.0, 0.9, 0.0));
            let bend = if k < 600 { 90f64 } else { 140.0 }.to_radians();
            pose.parent_from_joint[JointId::LEFT_ELBOW.index()] =
                Rotation3::from_axis_angle(&Vector3::y_axis(), -bend);
            pose.parent_from_joint[JointId::RIGHT_ELBOW.index()] =
                Rotation3::from_axis_angle(&Vector3::y_axis(), bend);
            poses.push(pose);
        }
        let clip = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses,
        };
        let a = perturb(&clip, 7);
        assert_eq!(a.poses.len(), clip.poses.len());
        // Deterministic per seed, different across seeds.
        let again = perturb(&clip, 7);
        let other = perturb(&clip, 8);
        let spine = JointId::SPINE2.index();
        assert_eq!(
            a.poses[300].parent_from_joint[spine],
            again.poses[300].parent_from_joint[spine]
        );
        assert!(
            a.poses[300].parent_from_joint[spine]
                .angle_to(&other.poses[300].parent_from_joint[spine])
                > 1e-3
        );
        let (mut fk, mut fk_prev) = (FkData::new(), FkData::new());
        let mut moved = 0.0f64;
        for (k, (p, orig)) in a.poses.iter().zip(&clip.poses).enumerate() {
            // Legs, pelvis and the root path are the recorded ones.
            assert_eq!(p.root_in_world_m, orig.root_in_world_m);
            for j in [0, 1, 2, 4, 5, 7, 8, 10, 11, 20, 21, 22, 23] {
                assert_eq!(
                    p.parent_from_joint[j], orig.parent_from_joint[j],
                    "joint {j}"
                );
            }
            // Every offset within its range: at most the norm of the range's extremes.
            for r in &OFFSET_RANGES {
                let max = Vector3::from_fn(|a, _| r.degrees[a][0].abs().max(r.degrees[a][1].abs()));
                let offset = orig.parent_from_joint[r.joint.index()].inverse()
                    * p.parent_from_joint[r.joint.index()];
                assert!(
                    offset.angle().to_degrees() <= max.norm() + 1e-9,
                    "{}",
                    r.joint.name()
                );
            }
            // The elbows stay between straight and 145°, their forearms in front of the arm's
            // line (the hinge of the recorded bend).
            for (elbow, rest) in [
                (JointId::LEFT_ELBOW, Vector3::x()),
                (JointId::RIGHT_ELBOW, -Vector3::x()),
            ] {
                let forearm = p.parent_from_joint[elbow.index()] * rest;
                let flexion = rest.angle(&forearm).to_degrees();
                assert!(flexion <= ELBOW_MAX_FLEXION_DEG + 1e-6, "{flexion}");
                let recorded = if k < 600 { 90.0 } else { 140.0 };
                assert!((flexion - recorded) >= ELBOW_FLEXION_DEG[0] - 1e-6);
                assert!(forearm.z > -1e-9 && forearm.y.abs() < 0.1, "{forearm}");
            }
            // Smooth: no wrist moves more than 2 cm between frames (0.5 Hz at most, 1.2 m/s),
            // but where the recorded bend itself jumps (frame 600).
            forward_kinematics(&body.skeleton, p, &mut fk);
            if k > 0 && k != 600 {
                for j in [JointId::LEFT_WRIST, JointId::RIGHT_WRIST, JointId::HEAD] {
                    let step = (fk.position(j) - fk_prev.position(j)).norm();
                    assert!(step < 0.02, "{} moved {step} m at frame {k}", j.name());
                    moved += step;
                }
            }
            std::mem::swap(&mut fk, &mut fk_prev);
        }
        assert!(
            moved > 1.0,
            "the offsets must move the upper body: {moved} m in all"
        );
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
