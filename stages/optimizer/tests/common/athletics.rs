//! Athletic motions built on the body model in code: a back flip (1 s of flight, upside down,
//! tucked) and a forward roll (over the back on the floor, the feet off it for over a second).
//! Each is a list of true poses at 60 Hz; [`references`] turns them into what perfect networks
//! would say about them, [`with_network_errors`] adds the kinds of error networks make on motion
//! they never saw, and [`kinematics_frame`] puts a reference on the wire.

use bytemuck::Zeroable;
use imuflow_body::kinematics::FkData;
use imuflow_body::rotation::quat_wxyz_from_rotation;
use imuflow_body::{JointId, NUM_JOINTS, Pose, forward_kinematics};
use imuflow_graph::frames::KinematicsFrame;
use imuflow_optimizer::estimate::place_on_floor;
use imuflow_optimizer::{DT_S, PhysicsBody, Reference};
use nalgebra::{Rotation3, Vector3};

pub const G: f64 = 9.81;

/// Flight time of the back flip (s): 1 s with no foot on the floor.
pub const FLIGHT_S: f64 = 1.0;

/// Duration of the forward roll's full turn (s).
pub const ROLL_S: f64 = 1.8;

/// A sagittal pose by its world angles (rad, positive: the limb's lower end turned backwards, a
/// rotation about +x, the body's left): pelvis pitch (positive: leaning forward), thigh, shank,
/// foot; the arms hang at `arm` from the vertical, forward. The ankle keeps the foot at `foot`.
#[derive(Clone, Copy, Debug)]
pub struct Sagittal {
    pub pelvis: f64,
    pub thigh: f64,
    pub shank: f64,
    pub foot: f64,
    pub spine: f64,
    pub arm: f64,
}

impl Sagittal {
    pub const STAND: Sagittal = Sagittal {
        pelvis: 0.0,
        thigh: 0.0,
        shank: 0.0,
        foot: 0.0,
        spine: 0.0,
        arm: 0.0,
    };
    /// A squat: thighs near horizontal, knees ahead of the ankles, trunk leaning forward.
    pub const CROUCH: Sagittal = Sagittal {
        pelvis: 0.5,
        thigh: -1.2,
        shank: 0.5,
        foot: 0.0,
        spine: 0.2,
        arm: -0.8,
    };
    /// The deep squat a roll starts from, hands reaching forward.
    pub const DEEP: Sagittal = Sagittal {
        pelvis: 0.9,
        thigh: -1.5,
        shank: 0.8,
        foot: 0.0,
        spine: 0.4,
        arm: -1.4,
    };
    /// A tight tuck (relative to the pelvis: thighs to the chest, heels to the seat, head in).
    pub const TUCK: Sagittal = Sagittal {
        pelvis: 0.0,
        thigh: -2.2,
        shank: 0.1,
        foot: 0.3,
        spine: 0.6,
        arm: -1.0,
    };

    pub fn lerp(&self, other: &Sagittal, s: f64) -> Sagittal {
        let l = |a: f64, b: f64| a + (b - a) * s;
        Sagittal {
            pelvis: l(self.pelvis, other.pelvis),
            thigh: l(self.thigh, other.thigh),
            shank: l(self.shank, other.shank),
            foot: l(self.foot, other.foot),
            spine: l(self.spine, other.spine),
            arm: l(self.arm, other.arm),
        }
    }

    /// The pose with an extra pitch `turn` of the whole body (rad, about +x) and the root at
    /// `root`.
    pub fn pose(&self, turn: f64, root: Vector3<f64>) -> Pose {
        let mut pose = Pose::t_pose(root);
        let x = |a: f64| Rotation3::new(Vector3::new(a, 0.0, 0.0));
        let p = &mut pose.parent_from_joint;
        p[JointId::PELVIS.index()] = x(self.pelvis + turn);
        for (hip, knee, ankle) in [
            (JointId::LEFT_HIP, JointId::LEFT_KNEE, JointId::LEFT_ANKLE),
            (
                JointId::RIGHT_HIP,
                JointId::RIGHT_KNEE,
                JointId::RIGHT_ANKLE,
            ),
        ] {
            p[hip.index()] = x(self.thigh - self.pelvis);
            p[knee.index()] = x(self.shank - self.thigh);
            p[ankle.index()] = x(self.foot - self.shank);
        }
        // The trunk bends forward over the three spine joints and the neck.
        for j in [
            JointId::SPINE1,
            JointId::SPINE2,
            JointId::SPINE3,
            JointId::NECK,
        ] {
            p[j.index()] = x(self.spine / 4.0);
        }
        // Arms from the T-pose down to the sides (1.3 rad about z), then forward by `arm`.
        for (shoulder, down) in [
            (JointId::LEFT_SHOULDER, -1.3),
            (JointId::RIGHT_SHOULDER, 1.3),
        ] {
            p[shoulder.index()] = x(self.arm) * Rotation3::new(Vector3::new(0.0, 0.0, down));
        }
        pose
    }
}

/// `0..1` eased in and out.
fn smooth(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

fn frames(secs: f64) -> usize {
    (secs / DT_S).round() as usize
}

/// Standing still for `secs` at horizontal position `at`.
fn stand(out: &mut Vec<Pose>, physics: &PhysicsBody, secs: f64, at: Vector3<f64>) {
    on_feet(
        out,
        physics,
        Sagittal::STAND,
        Sagittal::STAND,
        secs,
        smooth,
        at,
    );
}

/// Blends from `a` to `b` over `secs` with the lowest body part (the feet; the hands when they
/// reach down in a squat) on the floor at horizontal position `at`.
fn on_feet(
    out: &mut Vec<Pose>,
    physics: &PhysicsBody,
    a: Sagittal,
    b: Sagittal,
    secs: f64,
    ease: fn(f64) -> f64,
    at: Vector3<f64>,
) {
    let mut fk = FkData::new();
    let body: Vec<JointId> = JointId::all().collect();
    let n = frames(secs);
    for k in 1..=n {
        let mut pose = a.lerp(&b, ease(k as f64 / n as f64)).pose(0.0, at);
        place_on_floor(physics, &mut pose, &body, &mut fk);
        out.push(pose);
    }
}

/// A standing back flip: stand, crouch, push off, 1 s of flight turning a full backward
/// somersault in a tuck (upside down at its top, about 1.2 m up), land, absorb, stand.
pub fn back_flip(physics: &PhysicsBody) -> Vec<Pose> {
    let mut out = Vec::new();
    let origin = Vector3::zeros();
    stand(&mut out, physics, 0.5, origin);
    on_feet(
        &mut out,
        physics,
        Sagittal::STAND,
        Sagittal::CROUCH,
        0.3,
        smooth,
        origin,
    );
    // Push-off: extending with a growing speed (s², so the legs are fastest at take-off).
    on_feet(
        &mut out,
        physics,
        Sagittal::CROUCH,
        Sagittal::STAND,
        0.15,
        |s| s * s,
        origin,
    );
    let take_off = out.last().unwrap().root_in_world_m;
    // Ballistic root: up at g·T/2, back 0.6 m/s; lands at take-off height (same pose).
    let v0 = Vector3::new(0.0, G * FLIGHT_S / 2.0, -0.6);
    let n = frames(FLIGHT_S);
    for k in 1..=n {
        let t = k as f64 * DT_S;
        let s = t / FLIGHT_S;
        let root = take_off + v0 * t + Vector3::new(0.0, -0.5 * G * t * t, 0.0);
        let tuck = (std::f64::consts::PI * s).sin().powi(2);
        let turn = -std::f64::consts::TAU * smooth(s);
        out.push(Sagittal::STAND.lerp(&Sagittal::TUCK, tuck).pose(turn, root));
    }
    let landed = out.last().unwrap().root_in_world_m;
    let at = Vector3::new(landed.x, 0.0, landed.z);
    let half = Sagittal::STAND.lerp(&Sagittal::CROUCH, 0.6);
    on_feet(&mut out, physics, Sagittal::STAND, half, 0.2, smooth, at);
    on_feet(&mut out, physics, half, Sagittal::STAND, 0.4, smooth, at);
    stand(&mut out, physics, 0.5, at);
    out
}

/// A forward roll: stand, squat, roll forward over the back in a tuck (a full turn in
/// [`ROLL_S`], the lowest body part on the floor, rolling without slipping), squat, stand.
pub fn forward_roll(physics: &PhysicsBody) -> Vec<Pose> {
    let mut out = Vec::new();
    let origin = Vector3::zeros();
    stand(&mut out, physics, 0.5, origin);
    on_feet(
        &mut out,
        physics,
        Sagittal::STAND,
        Sagittal::DEEP,
        0.5,
        smooth,
        origin,
    );
    let mut fk = FkData::new();
    let body: Vec<JointId> = JointId::all().collect();
    let n = frames(ROLL_S);
    // Into the tuck over the first fifth of the roll, out of it over the last fifth; the pelvis
    // turns a full circle forward from the squat's lean.
    let mut z = out.last().unwrap().root_in_world_m.z;
    let mut previous_pitch = Sagittal::DEEP.pelvis;
    for k in 1..=n {
        let s = k as f64 / n as f64;
        let into = smooth(5.0 * s).min(smooth(5.0 * (1.0 - s)));
        let shape = Sagittal::DEEP.lerp(&Sagittal::TUCK, into);
        let shape = Sagittal {
            pelvis: Sagittal::DEEP.pelvis * (1.0 - into),
            ..shape
        };
        let pitch = Sagittal::DEEP.pelvis + std::f64::consts::TAU * smooth(s);
        let mut pose = shape.pose(pitch - shape.pelvis, Vector3::new(0.0, 0.0, z));
        place_on_floor(physics, &mut pose, &body, &mut fk);
        // Rolling without slipping: the root advances by its height times the turn.
        z += pose.root_in_world_m.y * (pitch - previous_pitch);
        pose.root_in_world_m.z = z;
        previous_pitch = pitch;
        out.push(pose);
    }
    let at = Vector3::new(0.0, 0.0, z);
    on_feet(
        &mut out,
        physics,
        Sagittal::DEEP,
        Sagittal::STAND,
        0.6,
        smooth,
        at,
    );
    stand(&mut out, physics, 0.5, at);
    out
}

/// World joint positions of a pose.
pub fn joints(physics: &PhysicsBody, pose: &Pose, fk: &mut FkData) -> [Vector3<f64>; NUM_JOINTS] {
    forward_kinematics(&physics.body.skeleton, pose, fk);
    fk.joint_in_world_m
}

/// What perfect networks would say about each frame: the true local pose, joint positions
/// relative to the root, world joint velocities (backward differences, as the training data's),
/// a foot in contact (0.9) when its ground point is within 2 cm of the floor and it moves slower
/// than 0.3 m/s (else 0.1), a contact joint stationary (0.9) when it moves slower than 0.2 m/s.
pub fn references(physics: &PhysicsBody, poses: &[Pose]) -> Vec<Reference> {
    let mut fk = FkData::new();
    let positions: Vec<_> = poses.iter().map(|p| joints(physics, p, &mut fk)).collect();
    let stationary = [
        JointId::PELVIS,
        JointId::LEFT_FOOT,
        JointId::RIGHT_FOOT,
        JointId::LEFT_HAND,
        JointId::RIGHT_HAND,
    ];
    (0..poses.len())
        .map(|k| {
            let now = &positions[k];
            let velocity: [Vector3<f64>; NUM_JOINTS] = std::array::from_fn(|j| match k {
                0 => Vector3::zeros(),
                _ => (now[j] - positions[k - 1][j]) / DT_S,
            });
            let mut pose = poses[k].clone();
            pose.root_in_world_m = Vector3::zeros();
            let prob = |yes: bool| if yes { 0.9 } else { 0.1 };
            let foot = |j: JointId| {
                let h = physics.geometry.height_above(j, &now[j.index()], 0.0);
                prob(h < 0.02 && velocity[j.index()].norm() < 0.3)
            };
            Reference {
                pose,
                joint_position_rel_m: std::array::from_fn(|j| now[j] - now[0]),
                joint_velocity_mps: velocity,
                foot_contact_prob: [foot(JointId::LEFT_FOOT), foot(JointId::RIGHT_FOOT)],
                stationary_prob: stationary.map(|j| prob(velocity[j.index()].norm() < 0.2)),
                root_velocity_mps: velocity[0],
            }
        })
        .collect()
}

/// Errors of the kinds networks make on motion they never saw, each in a stretch of its own
/// (hand-made, not measured; deterministic for `seed`):
/// - every joint's rotation off by up to 0.15 rad about each axis, every joint velocity by up to
///   0.5 m/s per axis, frame to frame at random (jitter);
/// - the root's vertical velocity 1 m/s too high throughout (a bias);
/// - the feet said in contact (0.9) in a random half of the frames (flicker), and in contact and
///   stationary for the 0.5 s from frame 70 (the middle of the flight or the roll);
/// - the root orientation off by 2.6 rad about the left axis in frames 80..86 (the estimate
///   flipping over while the body is upside down).
pub fn with_network_errors(references: &mut [Reference], seed: u64) {
    let mut state = seed.max(1);
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state as f64 / u64::MAX as f64) * 2.0 - 1.0
    };
    for (k, r) in references.iter_mut().enumerate() {
        for rotation in r.pose.parent_from_joint.iter_mut() {
            let e = Vector3::new(uniform(), uniform(), uniform()) * 0.15;
            *rotation *= Rotation3::new(e);
        }
        for v in r.joint_velocity_mps.iter_mut() {
            *v += Vector3::new(uniform(), uniform(), uniform()) * 0.5 + Vector3::new(0.0, 1.0, 0.0);
        }
        r.root_velocity_mps = r.joint_velocity_mps[0];
        if uniform() > 0.0 || (70..100).contains(&k) {
            r.foot_contact_prob = [0.9, 0.9];
        }
        if (70..100).contains(&k) {
            r.stationary_prob[1] = 0.9;
            r.stationary_prob[2] = 0.9;
        }
        if (80..86).contains(&k) {
            r.pose.parent_from_joint[0] *= Rotation3::new(Vector3::new(2.6, 0.0, 0.0));
        }
    }
}

/// A reference as the kinematics stage would publish it.
pub fn kinematics_frame(r: &Reference) -> KinematicsFrame {
    let mut frame = KinematicsFrame::zeroed();
    for j in 0..NUM_JOINTS {
        frame.local_pose_wxyz[j] =
            quat_wxyz_from_rotation(&r.pose.parent_from_joint[j]).map(|v| v as f32);
        frame.joint_position_m[j] = r.joint_position_rel_m[j].cast::<f32>().into();
        frame.joint_velocity_mps[j] = r.joint_velocity_mps[j].cast::<f32>().into();
    }
    frame.foot_contact_prob = r.foot_contact_prob.map(|p| p as f32);
    frame.stationary_prob = r.stationary_prob.map(|p| p as f32);
    frame.root_velocity_mps = r.root_velocity_mps.cast::<f32>().into();
    let gravity = r.pose.parent_from_joint[0].transpose() * Vector3::new(0.0, -G, 0.0);
    frame.gravity_in_root_mps2 = gravity.cast::<f32>().into();
    frame
}
