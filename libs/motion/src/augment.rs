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
//! - [`standing_idle`]: a person standing still in one of the clip's standing postures, shifting
//!   their weight from foot to foot (the pelvis sways over the planted feet, the legs follow by
//!   inverse kinematics); with [`perturb`] on top, the arms and spine move too. The data has no
//!   standing-idle sessions, which issue 12 measured at 30-34° SIP.

use crate::retarget::{MotionClip, ResampleError, resample};
use imuflow_body::{BodyModel, FkData, JointId, Pose, forward_kinematics};
use nalgebra::{Rotation3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// `clip` reflected across the body's sagittal plane, pose by pose ([`Pose::mirrored`]): a
/// left-handed wave becomes a right-handed one.
pub fn mirror(clip: &MotionClip) -> MotionClip {
    MotionClip {
        frame_time_s: clip.frame_time_s,
        poses: clip.poses.iter().map(Pose::mirrored).collect(),
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
///
/// `arm_scale` multiplies the shoulders' ranges and the elbows' flexion range (1: as listed; 2:
/// arms swung up to 90° forward, raised or lowered 50°: punches, pointing, arms overhead). The
/// upper arms are the bones the networks get most wrong on unfamiliar motion (issue 12), and at
/// 1 the shoulders stay near their recorded postures.
pub fn perturb(clip: &MotionClip, seed: u64, arm_scale: f64) -> MotionClip {
    let mut rng = StdRng::seed_from_u64(seed);
    let joints: Vec<(JointId, [[f64; 2]; 3], [SmoothNoise; 3])> = OFFSET_RANGES
        .iter()
        .map(|r| {
            let noise = [(); 3].map(|_| SmoothNoise::new(&mut rng));
            let is_shoulder = [JointId::LEFT_SHOULDER, JointId::RIGHT_SHOULDER].contains(&r.joint);
            let scale = if is_shoulder { arm_scale } else { 1.0 };
            (r.joint, r.degrees.map(|d| d.map(|v| v * scale)), noise)
        })
        .collect();
    let elbow_flexion_deg = ELBOW_FLEXION_DEG.map(|v| v * arm_scale);
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
                *r = flex_elbow(*r, *joint, noise.in_range(t_s, elbow_flexion_deg));
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

/// Length of one [`standing_idle`] sequence, s.
pub const STANDING_IDLE_S: f64 = 15.0;
/// A frame counts as standing when the root moves slower than this (m/s) and both balls of the
/// feet are this low (m).
const STANDING_SPEED_MPS: f64 = 0.1;
const STANDING_FOOT_HEIGHT_M: f64 = 0.04;
/// Weight shifts: the pelvis moves up to this far sideways (m; a person shifting their weight
/// onto one foot brings the pelvis 4-8 cm towards it), forwards or back, and down (the knees
/// bend), and tilts and turns this much (degrees).
const SWAY_SIDEWAYS_M: f64 = 0.06;
const SWAY_FORWARD_M: f64 = 0.025;
const SWAY_DOWN_M: f64 = 0.02;
const SWAY_ROLL_DEG: f64 = 4.0;
const SWAY_YAW_DEG: f64 = 6.0;

/// [`STANDING_IDLE_S`] of standing still in the first standing posture of `clip` (root slower than
/// 0.1 m/s, both feet down), shifting weight: the pelvis sways sideways, forwards and down, tilts
/// towards the loaded side and turns, in slow smooth random motion (seeded by `seed`), while both
/// feet stay where they stand (the ankles' positions and the feet's orientations are held; hips
/// and knees follow by two-bone inverse kinematics about the knees' own hinges). The upper body
/// keeps the standing posture's local rotations; compose with [`perturb`] to move it. `None` when
/// the clip never stands.
pub fn standing_idle(clip: &MotionClip, body: &BodyModel, seed: u64) -> Option<MotionClip> {
    let mut fk = FkData::new();
    let standing = standing_frame(clip, body, &mut fk)?;
    let start = clip.poses[standing].clone();
    forward_kinematics(&body.skeleton, &start, &mut fk);
    let legs = [Leg::LEFT, Leg::RIGHT].map(|leg| PlantedLeg::new(leg, &fk));
    // Sideways is the pelvis's left axis on the floor, forwards its facing.
    let left = horizontal_unit(fk.world_from(JointId::PELVIS) * Vector3::x())?;
    let forward = Vector3::y().cross(&left);
    let mut rng = StdRng::seed_from_u64(seed);
    let [side, fore, down, yaw] = [(); 4].map(|_| SmoothNoise::new(&mut rng));
    let frames = (STANDING_IDLE_S / clip.frame_time_s).round() as usize;
    let poses = (0..frames)
        .map(|k| {
            let t_s = k as f64 * clip.frame_time_s;
            let shift = side.at(t_s);
            let mut pose = start.clone();
            pose.root_in_world_m += SWAY_SIDEWAYS_M * shift * left
                + SWAY_FORWARD_M * fore.at(t_s) * forward
                - SWAY_DOWN_M * 0.5 * (down.at(t_s) + 1.0) * Vector3::y();
            // The pelvis drops on the unloaded side: moving left loads the left foot, so the
            // pelvis rolls down on the right (about the forward axis).
            let roll = Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(forward),
                SWAY_ROLL_DEG.to_radians() * shift,
            );
            let turn = Rotation3::from_axis_angle(
                &Vector3::y_axis(),
                SWAY_YAW_DEG.to_radians() * yaw.at(t_s),
            );
            let pelvis = JointId::PELVIS.index();
            pose.parent_from_joint[pelvis] = turn * roll * start.parent_from_joint[pelvis];
            // A pelvis that moved beyond the legs' reach comes down until they reach (nearly
            // straight standing knees have only millimetres to spare).
            for _ in 0..3 {
                forward_kinematics(&body.skeleton, &pose, &mut fk);
                let lower = legs
                    .iter()
                    .map(|leg| leg.drop_to_reach(&fk))
                    .fold(0.0, f64::max);
                pose.root_in_world_m.y -= lower;
            }
            for leg in &legs {
                leg.plant(&mut pose, body, &mut fk);
            }
            pose
        })
        .collect();
    Some(MotionClip {
        frame_time_s: clip.frame_time_s,
        poses,
    })
}

fn horizontal_unit(v: Vector3<f64>) -> Option<Vector3<f64>> {
    Vector3::new(v.x, 0.0, v.z).try_normalize(1e-6)
}

/// The first frame where the root moves slower than [`STANDING_SPEED_MPS`] and both balls of the
/// feet are below [`STANDING_FOOT_HEIGHT_M`].
fn standing_frame(clip: &MotionClip, body: &BodyModel, fk: &mut FkData) -> Option<usize> {
    (1..clip.poses.len()).find(|&k| {
        let step = clip.poses[k].root_in_world_m - clip.poses[k - 1].root_in_world_m;
        let speed = Vector3::new(step.x, 0.0, step.z).norm() / clip.frame_time_s;
        if speed > STANDING_SPEED_MPS {
            return false;
        }
        forward_kinematics(&body.skeleton, &clip.poses[k], fk);
        [JointId::LEFT_FOOT, JointId::RIGHT_FOOT]
            .iter()
            .all(|f| fk.position(*f).y < STANDING_FOOT_HEIGHT_M)
    })
}

/// One leg's joints.
struct Leg {
    hip: JointId,
    knee: JointId,
    ankle: JointId,
}

impl Leg {
    const LEFT: Leg = Leg {
        hip: JointId::LEFT_HIP,
        knee: JointId::LEFT_KNEE,
        ankle: JointId::LEFT_ANKLE,
    };
    const RIGHT: Leg = Leg {
        hip: JointId::RIGHT_HIP,
        knee: JointId::RIGHT_KNEE,
        ankle: JointId::RIGHT_ANKLE,
    };
}

/// A leg whose foot stays where it stood.
struct PlantedLeg {
    leg: Leg,
    ankle_m: Vector3<f64>,
    foot: Rotation3<f64>,
    thigh_m: f64,
    shank_m: f64,
    /// The knee's bend axis in the thigh's frame.
    hinge: nalgebra::Unit<Vector3<f64>>,
}

impl PlantedLeg {
    fn new(leg: Leg, fk: &FkData) -> PlantedLeg {
        let (h, k, a) = (
            *fk.position(leg.hip),
            *fk.position(leg.knee),
            *fk.position(leg.ankle),
        );
        let thigh = fk.world_from(leg.hip);
        // A straight knee shows no bend: its rest hinge, the thigh's x axis (the body's left in
        // the T-pose: the shank swings back).
        let bend = (k - h).cross(&(a - k));
        let hinge_world = bend
            .try_normalize(1e-6)
            .unwrap_or_else(|| thigh * Vector3::x());
        PlantedLeg {
            ankle_m: a,
            foot: *fk.world_from(leg.ankle),
            thigh_m: (k - h).norm(),
            shank_m: (a - k).norm(),
            hinge: nalgebra::Unit::new_normalize(thigh.inverse() * hinge_world),
            leg,
        }
    }

    /// How far the pelvis must come down for this leg to reach its ankle with the knee bent at
    /// least a little (99.5 % of the leg's length), m; 0 when it reaches.
    fn drop_to_reach(&self, fk: &FkData) -> f64 {
        let to_ankle = self.ankle_m - *fk.position(self.leg.hip);
        let excess = to_ankle.norm() - 0.995 * (self.thigh_m + self.shank_m);
        if excess <= 0.0 {
            return 0.0;
        }
        // Lowering the hip by δ shortens the hip-ankle distance by about δ·cos(leg from vertical).
        excess * to_ankle.norm() / to_ankle.y.abs().max(0.5 * to_ankle.norm())
    }

    /// Turns `pose`'s hip, knee and ankle so the ankle stands at the planted position with the
    /// foot turned as planted, given the pose's pelvis. `fk` is scratch.
    fn plant(&self, pose: &mut Pose, body: &BodyModel, fk: &mut FkData) {
        let l = &self.leg;
        forward_kinematics(&body.skeleton, pose, fk);
        let hip = *fk.position(l.hip);
        // The knee's interior angle that puts the ankle at the planted distance (law of cosines),
        // the distance kept reachable.
        let (a, b) = (self.thigh_m, self.shank_m);
        let reach = (self.ankle_m - hip)
            .norm()
            .clamp((a - b).abs() + 1e-6, a + b - 1e-6);
        let interior = |d: f64| {
            ((a * a + b * b - d * d) / (2.0 * a * b))
                .clamp(-1.0, 1.0)
                .acos()
        };
        let now = (*fk.position(l.ankle) - hip).norm();
        let more_bend = interior(now) - interior(reach);
        let knee = l.knee.index();
        pose.parent_from_joint[knee] =
            Rotation3::from_axis_angle(&self.hinge, more_bend) * pose.parent_from_joint[knee];
        // Swing the thigh about the hip so the ankle lands on its planted position.
        forward_kinematics(&body.skeleton, pose, fk);
        let swing =
            Rotation3::rotation_between(&(*fk.position(l.ankle) - hip), &(self.ankle_m - hip))
                .unwrap_or_else(Rotation3::identity);
        let pelvis = *fk.world_from(JointId::PELVIS);
        let h = l.hip.index();
        pose.parent_from_joint[h] = pelvis.inverse() * swing * pelvis * pose.parent_from_joint[h];
        // The foot keeps its planted orientation.
        forward_kinematics(&body.skeleton, pose, fk);
        pose.parent_from_joint[l.ankle.index()] = fk.world_from(l.knee).inverse() * self.foot;
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
            let p = fk.position(j.mirror());
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
        for arm_scale in [1.0, 2.0] {
            let a = perturb(&clip, 7, arm_scale);
            assert_eq!(a.poses.len(), clip.poses.len());
            // Deterministic per seed, different across seeds.
            let again = perturb(&clip, 7, arm_scale);
            let other = perturb(&clip, 8, arm_scale);
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
            let mut arm_offset_max = 0.0f64;
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
                    let is_shoulder =
                        [JointId::LEFT_SHOULDER, JointId::RIGHT_SHOULDER].contains(&r.joint);
                    let scale = if is_shoulder { arm_scale } else { 1.0 };
                    let max = Vector3::from_fn(|a, _| {
                        scale * r.degrees[a][0].abs().max(r.degrees[a][1].abs())
                    });
                    let offset = orig.parent_from_joint[r.joint.index()].inverse()
                        * p.parent_from_joint[r.joint.index()];
                    if is_shoulder {
                        arm_offset_max = arm_offset_max.max(offset.angle().to_degrees());
                    }
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
                    assert!((flexion - recorded) >= arm_scale * ELBOW_FLEXION_DEG[0] - 1e-6);
                    assert!(forearm.z > -1e-9 && forearm.y.abs() < 0.1, "{forearm}");
                }
                // Smooth: no wrist moves more than 2 cm between frames at scale 1 (0.5 Hz at most,
                // 1.2 m/s; the arms' ranges, and so their speeds, grow with the scale), but where
                // the recorded bend itself jumps (frame 600).
                forward_kinematics(&body.skeleton, p, &mut fk);
                if k > 0 && k != 600 {
                    for j in [JointId::LEFT_WRIST, JointId::RIGHT_WRIST, JointId::HEAD] {
                        let step = (fk.position(j) - fk_prev.position(j)).norm();
                        assert!(
                            step < 0.02 * arm_scale,
                            "{} moved {step} m at frame {k}",
                            j.name()
                        );
                        moved += step;
                    }
                }
                std::mem::swap(&mut fk, &mut fk_prev);
            }
            assert!(
                moved > 1.0,
                "the offsets must move the upper body: {moved} m in all"
            );
            // The scale widens the arms' postures: 2 takes a shoulder past what 1 can reach
            // (57°, the norm of its largest offsets).
            assert!(
                arm_offset_max > 30.0 * arm_scale,
                "scale {arm_scale}: shoulders turned at most {arm_offset_max}°"
            );
        }
    }

    #[test]
    fn standing_idle_sways_the_pelvis_over_feet_that_stay_put() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        // Two seconds of walking in place (root moving), then standing: straight knees (the
        // reach limit) and, in a second clip, knees bent 20°, arms down.
        for knee_deg in [0.0f64, 20.0] {
            let mut stand = Pose::t_pose(Vector3::zeros());
            let bend = knee_deg.to_radians();
            for (hip, knee) in [(1, 4), (2, 5)] {
                stand.parent_from_joint[hip] =
                    Rotation3::from_axis_angle(&Vector3::x_axis(), -0.5 * bend);
                stand.parent_from_joint[knee] =
                    Rotation3::from_axis_angle(&Vector3::x_axis(), bend);
            }
            let mut fk = FkData::new();
            forward_kinematics(&body.skeleton, &stand, &mut fk);
            stand.root_in_world_m.y = -fk.position(JointId::LEFT_FOOT).y;
            let mut poses: Vec<Pose> = (0..120)
                .map(|k| {
                    let mut p = stand.clone();
                    p.root_in_world_m.z += 0.02 * k as f64;
                    p
                })
                .collect();
            let standing_at = poses.last().unwrap().root_in_world_m;
            poses.extend((0..60).map(|_| {
                let mut p = stand.clone();
                p.root_in_world_m = standing_at;
                p
            }));
            let clip = MotionClip {
                frame_time_s: 1.0 / 60.0,
                poses,
            };
            let idle = standing_idle(&clip, &body, 3).unwrap();
            assert_eq!(idle.poses.len(), (STANDING_IDLE_S * 60.0) as usize);
            forward_kinematics(&body.skeleton, &clip.poses[125], &mut fk);
            let planted = [
                JointId::LEFT_ANKLE,
                JointId::RIGHT_ANKLE,
                JointId::LEFT_FOOT,
                JointId::RIGHT_FOOT,
            ]
            .map(|j| (*fk.position(j), *fk.world_from(j)));
            let start = fk.position(JointId::PELVIS).xz();
            let (mut widest, mut previous) = (0.0f64, None::<Vector3<f64>>);
            for pose in &idle.poses {
                forward_kinematics(&body.skeleton, pose, &mut fk);
                for (j, (at, turned)) in [
                    JointId::LEFT_ANKLE,
                    JointId::RIGHT_ANKLE,
                    JointId::LEFT_FOOT,
                    JointId::RIGHT_FOOT,
                ]
                .iter()
                .zip(&planted)
                {
                    assert!(
                        (fk.position(*j) - at).norm() < 1e-6,
                        "{} moved {} m (knees {knee_deg}°)",
                        j.name(),
                        (fk.position(*j) - at).norm()
                    );
                    assert!(
                        // (angle_to is NaN for equal rotations: acos of a cosine rounded past 1)
                        (fk.world_from(*j).matrix() - turned.matrix()).norm() < 1e-6,
                        "{} turned (knees {knee_deg}°)",
                        j.name(),
                    );
                }
                // The knees bend forwards only (the shank behind the thigh's line seen from the
                // side would be a knee bent backwards) and never past 60°.
                for (hip, knee, ankle) in [(1, 4, 7), (2, 5, 8)] {
                    let thigh = fk.joint_in_world_m[knee] - fk.joint_in_world_m[hip];
                    let shank = fk.joint_in_world_m[ankle] - fk.joint_in_world_m[knee];
                    assert!(thigh.angle(&shank).to_degrees() < 60.0);
                }
                let pelvis = *fk.position(JointId::PELVIS);
                widest = widest.max((pelvis.xz() - start).norm());
                if let Some(p) = previous {
                    assert!((pelvis - p).norm() < 0.005, "the pelvis jumps");
                }
                previous = Some(pelvis);
            }
            assert!(
                widest > 0.02,
                "the weight must shift: the pelvis moved {widest} m at most"
            );
            assert!(widest < SWAY_SIDEWAYS_M + SWAY_FORWARD_M + 1e-9);
        }
        // A clip that never stands gives nothing.
        let walking = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: (0..60)
                .map(|k| Pose::t_pose(Vector3::new(0.0, 0.9, 0.03 * k as f64)))
                .collect(),
        };
        assert!(standing_idle(&walking, &body, 1).is_none());
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
