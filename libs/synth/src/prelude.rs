//! A constructed calibration prelude, prepended to a clip so that a simulated session starts the
//! way a real one does: a held T-pose and/or stand (N-pose), one step forward, stand. The clip is
//! then turned about the vertical so its first frame faces +z (the direction the subject faced
//! while calibrating, which defines the model frame M) and moved to where the prelude ends, and the
//! last prelude pose blends into its first pose.
//!
//! The poses are built on the 24-joint body: T-pose = every local rotation the identity; N-pose =
//! the T-pose with the shoulders turned so the arms hang down (`R_z(∓90°)`, GlobalPose's N-pose,
//! whose forearm bone orientations the calibration stage assumes). The step: the root moves forward
//! along a minimum-jerk profile with a small dip; the right leg swings (hip flexion up to 25°, knee
//! flexion up to 45°) in the first half, the left leg in the second; the arms swing ±8°.

use std::f64::consts::{FRAC_PI_2, PI};

use imuflow_body::limb_joints::RELAXED_ELBOW_DEG;
use imuflow_body::rotation::{Axis, slerp};
use imuflow_body::{BodyModel, JointId, Pose};
use imuflow_graph::params::Param;
use imuflow_motion::retarget::MotionClip;
use nalgebra::{Rotation3, Vector3};

/// Which prelude to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PreludeKind {
    /// The clip as it is.
    #[default]
    None,
    /// T-pose hold, then the clip.
    Tpose,
    /// Stand (N-pose), one step forward, stand, then the clip.
    Walk,
    /// T-pose hold, N-pose stand, one step forward, stand, then the clip.
    TposeWalk,
    /// N-pose stand, then the clip: a natural recording's start, with no scripted step.
    Stand,
}

impl PreludeKind {
    /// Names as in the stage's `prelude` parameter.
    pub const NAMES: [&'static str; 5] = ["none", "tpose", "walk", "tpose+walk", "stand"];

    pub fn parse(name: &str) -> Option<PreludeKind> {
        match name {
            "none" => Some(PreludeKind::None),
            "tpose" => Some(PreludeKind::Tpose),
            "walk" => Some(PreludeKind::Walk),
            "tpose+walk" => Some(PreludeKind::TposeWalk),
            "stand" => Some(PreludeKind::Stand),
            _ => None,
        }
    }

    fn has_tpose(self) -> bool {
        matches!(self, PreludeKind::Tpose | PreludeKind::TposeWalk)
    }

    fn has_walk(self) -> bool {
        matches!(self, PreludeKind::Walk | PreludeKind::TposeWalk)
    }
}

/// Shape of the prelude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreludeOptions {
    pub kind: PreludeKind,
    /// Length of each hold / stand (s).
    pub stand_s: f64,
    /// Step length (m) and duration (s).
    pub step_m: f64,
    pub step_s: f64,
    /// Duration of each blend between poses (s).
    pub blend_s: f64,
    /// Heading change during the step (deg). Not 0 means the subject does not stand as before the
    /// step: a walking calibration must then ask for a redo (used by tests).
    pub turn_deg: f64,
    /// Elbow flexion while standing in the N-pose (deg; 0: straight arms, as GlobalPose's N-pose).
    /// Relaxed arms hang with the elbows bent 15–35°.
    pub elbow_deg: f64,
}

/// The imu-source stage's `prelude_stand_s`, the default of [`PreludeOptions::stand_s`].
pub const STAND_PARAM: Param<f64> = imuflow_graph::param! {
    /// synthesize: length of each prelude hold / stand, s
    prelude_stand_s: f64 = 3, float(0.5, 60.0)
};

/// The imu-source stage's `step_m`, the default of [`PreludeOptions::step_m`].
pub const STEP_PARAM: Param<f64> = imuflow_graph::param! {
    /// synthesize: length of the prelude's step forward, m
    step_m: f64 = 0.6, float(0.1, 1.5)
};

impl Default for PreludeOptions {
    fn default() -> PreludeOptions {
        PreludeOptions {
            kind: PreludeKind::None,
            stand_s: STAND_PARAM.default,
            step_m: STEP_PARAM.default,
            step_s: 1.2,
            blend_s: 1.0,
            turn_deg: 0.0,
            elbow_deg: 0.0,
        }
    }
}

impl PreludeOptions {
    /// How a synthetic subject bends the elbows standing in a prelude of `kind` (deg): told to
    /// take the T- or N-pose (`tpose`, `walk`), straight; at a natural start (`stand`), nobody said
    /// anything and people stand at ease ([`RELAXED_ELBOW_DEG`], the calibration's relaxed pose).
    pub fn default_elbow_deg(kind: PreludeKind) -> f64 {
        match kind {
            PreludeKind::Stand => RELAXED_ELBOW_DEG,
            _ => 0.0,
        }
    }
}

/// The T-pose facing +z with the root at `root_m`.
pub fn t_pose(root_m: Vector3<f64>) -> Pose {
    Pose::t_pose(root_m)
}

/// The N-pose (arms down) facing +z with the root at `root_m`.
pub fn n_pose(root_m: Vector3<f64>) -> Pose {
    let mut p = Pose::t_pose(root_m);
    p.parent_from_joint[JointId::LEFT_SHOULDER.index()] = Axis::Z.rotation(-FRAC_PI_2);
    p.parent_from_joint[JointId::RIGHT_SHOULDER.index()] = Axis::Z.rotation(FRAC_PI_2);
    p
}

/// The N-pose with both elbows bent by `elbow_rad` (the hands forward): relaxed arms.
pub fn relaxed_n_pose(root_m: Vector3<f64>, elbow_rad: f64) -> Pose {
    let mut p = n_pose(root_m);
    // With the upper arm hanging (shoulder R_z(∓90°)), a turn about the elbow's local y axis is
    // a turn about M's left axis: R_z(−90°)·R_y(−θ)·R_z(90°) = R_x(−θ), hand forward.
    p.parent_from_joint[JointId::LEFT_ELBOW.index()] = Axis::Y.rotation(-elbow_rad);
    p.parent_from_joint[JointId::RIGHT_ELBOW.index()] = Axis::Y.rotation(elbow_rad);
    p
}

/// Root height of the body standing straight with its foot joints at y = 0 (the floor the
/// retargeting puts under a clip).
pub fn standing_root_height_m(body: &BodyModel) -> f64 {
    let rest = body.rest_positions_on_floor_m();
    let feet = rest[JointId::LEFT_FOOT.index()]
        .y
        .min(rest[JointId::RIGHT_FOOT.index()].y);
    rest[JointId::ROOT.index()].y - feet
}

/// A growing sequence of poses at a fixed frame time.
#[derive(Clone, Debug)]
pub struct PoseTrack {
    frame_time_s: f64,
    poses: Vec<Pose>,
}

impl PoseTrack {
    /// A track holding `first` only.
    pub fn new(frame_time_s: f64, first: Pose) -> PoseTrack {
        PoseTrack {
            frame_time_s,
            poses: vec![first],
        }
    }

    /// The last pose.
    pub fn last(&self) -> &Pose {
        // `new` puts one pose in and nothing removes any.
        &self.poses[self.poses.len() - 1]
    }

    fn frames(&self, secs: f64) -> usize {
        (secs / self.frame_time_s).round().max(1.0) as usize
    }

    /// Holds the last pose for `secs`.
    pub fn hold(&mut self, secs: f64) {
        let last = self.last().clone();
        let n = self.frames(secs);
        self.poses.extend(std::iter::repeat_n(last, n));
    }

    /// Moves from the last pose to `target` in `secs` (minimum-jerk in time: slerp of every local
    /// rotation, lerp of the root).
    pub fn blend_to(&mut self, target: &Pose, secs: f64) {
        let from = self.last().clone();
        let n = self.frames(secs);
        for i in 1..=n {
            let s = min_jerk(i as f64 / n as f64);
            let mut p = Pose::default();
            for (j, r) in p.parent_from_joint.iter_mut().enumerate() {
                *r = slerp(&from.parent_from_joint[j], &target.parent_from_joint[j], s);
            }
            p.root_in_world_m = from.root_in_world_m.lerp(&target.root_in_world_m, s);
            self.poses.push(p);
        }
    }

    /// One step forward (along the last pose's facing) of `length_m` in `secs`, turning by
    /// `turn_rad` about the vertical on the way. The last pose should be a standing pose.
    pub fn step_forward(&mut self, length_m: f64, secs: f64, turn_rad: f64) {
        let start = self.last().clone();
        let facing = start.parent_from_joint[JointId::ROOT.index()];
        let direction = heading_rotation(&facing) * Vector3::z();
        let n = self.frames(secs);
        for i in 1..=n {
            let u = i as f64 / n as f64;
            let s = min_jerk(u);
            let mut p = start.clone();
            p.root_in_world_m = start.root_in_world_m + direction * (length_m * s)
                - Vector3::y() * (0.02 * (PI * u).sin());
            p.parent_from_joint[JointId::ROOT.index()] = Axis::Y.rotation(turn_rad * s) * facing;
            // Right leg first, then the left.
            swing_leg(
                &mut p,
                JointId::RIGHT_HIP,
                JointId::RIGHT_KNEE,
                (2.0 * u).min(1.0),
            );
            swing_leg(
                &mut p,
                JointId::LEFT_HIP,
                JointId::LEFT_KNEE,
                (2.0 * u - 1.0).max(0.0),
            );
            let arm = (8.0_f64).to_radians() * (2.0 * PI * u).sin();
            for (joint, sign) in [
                (JointId::LEFT_SHOULDER, 1.0),
                (JointId::RIGHT_SHOULDER, -1.0),
            ] {
                let r = &mut p.parent_from_joint[joint.index()];
                *r = Axis::X.rotation(sign * arm) * *r;
            }
            self.poses.push(p);
        }
    }

    /// The poses so far.
    pub fn into_poses(self) -> Vec<Pose> {
        self.poses
    }
}

/// Minimum-jerk profile 10u³ − 15u⁴ + 6u⁵ (0 → 1 with zero velocity and acceleration at both ends).
fn min_jerk(u: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
}

/// Hip flexion (thigh forward: −x rotation) and knee flexion (shank back) along a swing phase
/// `v` ∈ [0, 1]; both 0 at the ends.
fn swing_leg(p: &mut Pose, hip: JointId, knee: JointId, v: f64) {
    let bump = (PI * v).sin();
    p.parent_from_joint[hip.index()] = Axis::X.rotation(-(25.0_f64).to_radians() * bump);
    p.parent_from_joint[knee.index()] = Axis::X.rotation((45.0_f64).to_radians() * bump);
}

/// The rotation about the vertical that turns +z to the horizontal part of `r`'s forward axis.
fn heading_rotation(r: &Rotation3<f64>) -> Rotation3<f64> {
    let f = r * Vector3::z();
    Axis::Y.rotation(f.x.atan2(f.z))
}

/// A clip with a prelude in front.
#[derive(Clone, Debug, PartialEq)]
pub struct WithPrelude {
    /// The prelude's frames, then the clip's (turned and moved; its first pose ends the prelude's
    /// last blend). The clip's frame time.
    pub clip: MotionClip,
    /// How many frames come before the clip's first: frame `prelude_frames` is the clip's frame 0.
    pub prelude_frames: usize,
}

/// `clip` with the prelude of `options` in front (the clip itself unchanged, and no prelude
/// frames, when the kind is `None`).
pub fn with_prelude(clip: &MotionClip, body: &BodyModel, options: &PreludeOptions) -> WithPrelude {
    let unchanged = || WithPrelude {
        clip: clip.clone(),
        prelude_frames: 0,
    };
    let Some(first) = clip.poses.first() else {
        return unchanged();
    };
    if options.kind == PreludeKind::None {
        return unchanged();
    }
    let origin = Vector3::new(0.0, standing_root_height_m(body), 0.0);
    let start = if options.kind.has_tpose() {
        t_pose(origin)
    } else {
        relaxed_n_pose(origin, options.elbow_deg.to_radians())
    };
    let mut track = PoseTrack::new(clip.frame_time_s, start);
    track.hold(options.stand_s);
    if options.kind.has_walk() {
        if options.kind.has_tpose() {
            track.blend_to(
                &relaxed_n_pose(origin, options.elbow_deg.to_radians()),
                options.blend_s,
            );
            track.hold(options.stand_s);
        }
        track.step_forward(
            options.step_m,
            options.step_s,
            options.turn_deg.to_radians(),
        );
        track.hold(options.stand_s);
    }
    // Turn the clip to face +z at its start and move it to where the prelude ends.
    let turn = heading_rotation(&first.parent_from_joint[JointId::ROOT.index()]).inverse();
    let end = track.last().root_in_world_m;
    let place = |p: &Pose| {
        let mut q = p.clone();
        let r = &mut q.parent_from_joint[JointId::ROOT.index()];
        *r = turn * *r;
        let offset = turn * (p.root_in_world_m - first.root_in_world_m);
        q.root_in_world_m = Vector3::new(end.x + offset.x, p.root_in_world_m.y, end.z + offset.z);
        q
    };
    track.blend_to(&place(first), options.blend_s);
    let mut poses = track.into_poses();
    // The blend's last pose is the clip's first.
    let prelude_frames = poses.len() - 1;
    poses.extend(clip.poses.iter().skip(1).map(place));
    WithPrelude {
        clip: MotionClip {
            frame_time_s: clip.frame_time_s,
            poses,
        },
        prelude_frames,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::BodyParams;
    use imuflow_body::kinematics::{FkData, forward_kinematics};
    use imuflow_body::rotation::angle_between;

    fn body() -> BodyModel {
        let params = BodyParams::builtin().expect("builtin");
        BodyModel::new(
            &params,
            params.reference_stature_m(),
            params.reference_mass_kg(),
        )
        .expect("body")
    }

    #[test]
    fn n_pose_forearms_point_down_and_the_step_ends_where_it_should() {
        let body = body();
        let mut fk = FkData::new();
        let origin = Vector3::new(0.0, standing_root_height_m(&body), 0.0);
        forward_kinematics(&body.skeleton, &n_pose(origin), &mut fk);
        let down = -Vector3::y();
        for (elbow, wrist) in [
            (JointId::LEFT_ELBOW, JointId::LEFT_WRIST),
            (JointId::RIGHT_ELBOW, JointId::RIGHT_WRIST),
        ] {
            let forearm = (fk.position(wrist) - fk.position(elbow)).normalize();
            assert!(forearm.dot(&down) > 0.99, "{forearm:?}");
        }
        let mut track = PoseTrack::new(1.0 / 60.0, n_pose(origin));
        track.step_forward(0.6, 1.2, 0.0);
        let last = track.last();
        assert!((last.root_in_world_m - origin - Vector3::new(0.0, 0.0, 0.6)).norm() < 1e-9);
        for j in 0..24 {
            assert!(
                angle_between(
                    &last.parent_from_joint[j],
                    &n_pose(origin).parent_from_joint[j]
                ) < 1e-9
            );
        }
    }

    #[test]
    fn stand_prelude_holds_the_n_pose_then_blends_into_the_clip() {
        let body = body();
        let mut a = Pose::t_pose(Vector3::new(1.0, 0.9, 2.0));
        a.parent_from_joint[0] = Axis::Y.rotation(-0.5);
        let clip = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![a.clone(), a],
        };
        let options = PreludeOptions {
            kind: PreludeKind::Stand,
            stand_s: 1.0,
            blend_s: 0.5,
            ..PreludeOptions::default()
        };
        let out = with_prelude(&clip, &body, &options);
        // The N-pose, held 1 s, a 0.5 s blend whose last pose is the clip's first, then the clip's
        // second frame: no step.
        assert_eq!(out.prelude_frames, 60 + 30);
        assert_eq!(out.clip.poses.len(), 1 + 60 + 30 + 1);
        let origin = Vector3::new(0.0, standing_root_height_m(&body), 0.0);
        for pose in &out.clip.poses[..=60] {
            assert_eq!(pose, &n_pose(origin));
        }
        // The clip starts where the subject stood, facing +z.
        let start = &out.clip.poses[out.prelude_frames];
        assert!(angle_between(&start.parent_from_joint[0], &Rotation3::identity()) < 1e-9);
        assert!((start.root_in_world_m - Vector3::new(0.0, 0.9, 0.0)).norm() < 1e-9);
    }

    #[test]
    fn prelude_turns_the_clip_to_face_forward_and_keeps_its_frames() {
        let body = body();
        let mut a = Pose::t_pose(Vector3::new(3.0, 0.9, -2.0));
        a.parent_from_joint[0] = Axis::Y.rotation(1.0);
        let mut b = a.clone();
        b.root_in_world_m += Axis::Y.rotation(1.0) * Vector3::new(0.0, 0.0, 0.1);
        let clip = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![a, b],
        };
        let options = PreludeOptions {
            kind: PreludeKind::TposeWalk,
            ..PreludeOptions::default()
        };
        let WithPrelude {
            clip: out,
            prelude_frames,
        } = with_prelude(&clip, &body, &options);
        // T hold + blend + stand + step + stand + blend, then the clip's second frame.
        assert_eq!(out.poses.len(), 1 + 180 + 60 + 180 + 72 + 180 + 60 + 1);
        assert_eq!(prelude_frames, 1 + 180 + 60 + 180 + 72 + 180 + 60 - 1);
        // The clip's first frame, placed: facing +z (its heading was 1 rad).
        let clip_start = &out.poses[prelude_frames];
        assert!(angle_between(&clip_start.parent_from_joint[0], &Rotation3::identity()) < 1e-9);
        let last = &out.poses[out.poses.len() - 1];
        let prev = &out.poses[out.poses.len() - 2];
        let step = last.root_in_world_m - prev.root_in_world_m;
        assert!(
            (step - Vector3::new(0.0, 0.0, 0.1)).norm() < 1e-9,
            "the clip walks along +z: {step:?}"
        );
        assert!(angle_between(&prev.parent_from_joint[0], &Rotation3::identity()) < 1e-9);
        let none = with_prelude(&clip, &body, &PreludeOptions::default());
        assert_eq!((none.clip, none.prelude_frames), (clip, 0));
    }
}
