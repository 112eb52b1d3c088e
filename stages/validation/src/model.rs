//! The simulated body, derived from imuflow's body model (`models/body.toml`, the same model the
//! optimizer uses): which joints become links, their mass properties, collision shapes and the
//! inertia each joint drives (for the gains). Plain data, no rapier types.

use imuflow_body::body_model::BodyModel;
use imuflow_body::kinematics::FkData;
use imuflow_body::skeleton::{JointId, NUM_JOINTS};
use imuflow_graph::params::Param;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// Joints that are not simulated, parents before children: the neck and the collars (massless in
/// the body model), the wrists (never estimated: the kinematics nets leave them at identity, PIP's
/// ignored joints) and the massless leaves (toes and fingers). Each is rigidly part of its nearest
/// simulated ancestor's link, in its rest pose; the rotation of an inner one is folded into its
/// children's targets (`Target::folded`), so every simulated joint keeps the estimate's
/// orientation in the world and only the rigid joint's own bend is lost (the shoulders sit where
/// the rest pose has them on the chest). rapier's multibody costs links × degrees of freedom²
/// (its mass matrix, recomputed every step): 15 links and 51 degrees of freedom instead of 20 and
/// 66 take the time per frame down by about 40 %.
pub const RIGID_JOINTS: [JointId; 9] = [
    JointId::NECK,
    JointId::LEFT_COLLAR,
    JointId::RIGHT_COLLAR,
    JointId::LEFT_FOOT,
    JointId::RIGHT_FOOT,
    JointId::LEFT_WRIST,
    JointId::RIGHT_WRIST,
    JointId::LEFT_HAND,
    JointId::RIGHT_HAND,
];

/// Mass (kg) the massless inner joints that are simulated (spine2) take from their parent's segment so
/// that every link of the multibody has a mass the solver can drive: with a few grams the stiff
/// motors of these joints were ill-conditioned (20-90° errors while standing). The total mass is
/// unchanged. [inferred]
const MASSLESS_LINK_MASS_KG: f64 = 0.5;
/// The validation stage's `foot_pitch_deg`: how far the feet are pitched toe-down, relative to the
/// skeleton's rest pose, when they stand flat on the floor, degrees: the soles are level at this
/// ankle pitch. Default 0, the rest pose: the kinematics nets output the ankles at identity (PIP's
/// ignored joints) and the calibration prelude stands in the rest pose. Motion retargeted from the
/// Bandai Namco skeleton stands pitched 9.3° (the median over the stance frames of the test
/// split's walk and run clips, p10 9.0°: its actors' feet have other proportions than ours, and
/// retargeting maps the ankle-to-toe bone); tracking those walks with level soles at 9.3° fell as
/// often as at 0° (18.9 against 16.6 falls a minute on 20 test-split walks), so one default serves
/// both.
pub const FOOT_PITCH_PARAM: Param<f64> = imuflow_graph::param! {
    /// ankle pitch (toe down, degrees) at which the soles are level: 0 for the nets' estimates,
    /// 9.3 for Bandai-retargeted truth
    foot_pitch_deg: f64 = 0, float(-45.0, 45.0)
};
/// The default foot pitch, degrees (see [`FOOT_PITCH_PARAM`] for why).
pub const DEFAULT_FOOT_PITCH_DEG: f64 = FOOT_PITCH_PARAM.default;
/// Principal inertia (kg·m²) of those links: a 0.5 kg body of about 10 cm radius. [inferred]
const MASSLESS_LINK_INERTIA_KGM2: f64 = 5e-3;
/// Smallest inertia (kg·m²) a joint's gains are scaled by, so the wrists stay stiff enough. [inferred]
const MIN_DRIVEN_INERTIA_KGM2: f64 = 0.02;

/// One collision shape, in its link's frame (the joint's frame: at rest its axes are M's).
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A capsule between two points, m.
    Capsule {
        a: Vector3<f64>,
        b: Vector3<f64>,
        radius: f64,
    },
    /// A sphere, m.
    Ball { centre: Vector3<f64>, radius: f64 },
    /// A box, m: half extents along its own axes, which are the link's turned by `rotation`.
    Cuboid {
        centre: Vector3<f64>,
        half_extents: Vector3<f64>,
        rotation: Rotation3<f64>,
    },
}

impl Shape {
    /// The same shape moved by `by` (from a carried joint's frame into its link's).
    fn translated(self, by: &Vector3<f64>) -> Shape {
        match self {
            Shape::Capsule { a, b, radius } => Shape::Capsule {
                a: a + by,
                b: b + by,
                radius,
            },
            Shape::Ball { centre, radius } => Shape::Ball {
                centre: centre + by,
                radius,
            },
            Shape::Cuboid {
                centre,
                half_extents,
                rotation,
            } => Shape::Cuboid {
                centre: centre + by,
                half_extents,
                rotation,
            },
        }
    }
}

/// One rigid link of the simulated multibody.
#[derive(Debug, Clone)]
pub struct Link {
    /// The skeleton joint this link rotates about (its origin is the joint centre).
    pub joint: JointId,
    /// Link mass, kg.
    pub mass_kg: f64,
    /// Centre of mass in the link frame, m.
    pub com_m: Vector3<f64>,
    /// Principal inertia about the centre of mass, link axes, kg·m².
    pub inertia_kgm2: Vector3<f64>,
    /// Collision shapes, each with the skeleton joint whose segment it covers (the link's own, or
    /// a rigid joint it carries); none for links that cannot touch the floor in practice: neck,
    /// collars.
    pub shapes: Vec<(JointId, Shape)>,
    /// Scalar inertia the joint drives at rest (mean of the diagonal, kg·m²): the larger of its
    /// subtree's and the rest of the body's inertia about the joint centre, floored at
    /// [`MIN_DRIVEN_INERTIA_KGM2`]. A knee swings the shank and foot in the air but lifts the whole
    /// body above it in stance; gains sized for the smaller load could not hold a standing body up.
    /// The PD gains are per unit of it.
    pub driven_inertia_kgm2: f64,
}

/// The simulated body: one link per simulated joint, in topological (SMPL) order, root first.
#[derive(Debug, Clone)]
pub struct SimModel {
    pub body: BodyModel,
    pub links: Vec<Link>,
    /// Total simulated mass (the body's), kg.
    pub total_mass_kg: f64,
    /// Whole-body inertia about the pelvis at rest (mean of the diagonal), kg·m²; scales the
    /// root-orientation gains.
    pub root_inertia_kgm2: f64,
    /// Hip to ball of the foot at rest, m (the foot placement's lever).
    pub leg_length_m: f64,
}

/// Whether `joint` is a link of the simulation.
pub fn is_simulated(joint: JointId) -> bool {
    !RIGID_JOINTS.contains(&joint)
}

/// The simulated joint whose link carries `joint`: itself, or its nearest simulated ancestor.
pub fn carrier(joint: JointId) -> JointId {
    let mut j = joint;
    while !is_simulated(j) {
        j = j.parent().expect("the root is simulated");
    }
    j
}

/// Where `joint` sits at rest in the frame of the link that carries its parent, m: its offset in
/// its parent plus those of the rigid joints between (they hold their rest pose). For a link's
/// joint this is its anchor in its parent link; for a rigid joint, its place in its own carrier.
pub fn offset_in_carrier(body: &BodyModel, joint: JointId) -> Vector3<f64> {
    let mut offset = *body.skeleton.offset_in_parent_m(joint);
    let mut j = joint.parent().expect("the root has no carrier above it");
    while !is_simulated(j) {
        offset += body.skeleton.offset_in_parent_m(j);
        j = j.parent().expect("the root is simulated");
    }
    offset
}

/// The joints a link carries (its own and the rigid joints riding on it), each with its position
/// in the link's frame at rest, m.
fn carried(body: &BodyModel, link: JointId) -> Vec<(JointId, Vector3<f64>)> {
    std::iter::once((link, Vector3::zeros()))
        .chain(
            RIGID_JOINTS
                .into_iter()
                .filter(|j| carrier(*j) == link)
                .map(|j| (j, offset_in_carrier(body, j))),
        )
        .collect()
}

impl SimModel {
    /// The simulated body of `body`, its soles level in the rest pose ([`DEFAULT_FOOT_PITCH_DEG`]).
    pub fn new(body: &BodyModel) -> SimModel {
        SimModel::with_foot_pitch(body, DEFAULT_FOOT_PITCH_DEG)
    }

    /// The simulated body of `body` with soles that are level when the ankle frame is pitched
    /// `foot_pitch_deg` toe-down (0: level in the skeleton's rest pose).
    pub fn with_foot_pitch(body: &BodyModel, foot_pitch_deg: f64) -> SimModel {
        let rest = body.skeleton.rest_positions_from_root_m();
        let mut links: Vec<Link> = JointId::all()
            .filter(|j| is_simulated(*j))
            .map(|joint| {
                let (mass_kg, com_m, inertia) = link_mass(body, joint);
                Link {
                    joint,
                    mass_kg,
                    com_m,
                    inertia_kgm2: inertia,
                    shapes: carried(body, joint)
                        .into_iter()
                        .flat_map(|(j, at)| {
                            shapes(body, j, foot_pitch_deg.to_radians())
                                .into_iter()
                                .map(move |shape| (j, shape.translated(&at)))
                        })
                        .collect(),
                    driven_inertia_kgm2: 0.0,
                }
            })
            .collect();
        // The stand-in masses of the massless joints come out of their parents' segments.
        for i in 0..links.len() {
            if body.segments.iter().any(|s| s.joint == links[i].joint) {
                continue;
            }
            let parent = links[i].joint.parent().expect("the root has a segment");
            if let Some(p) = links.iter_mut().find(|l| l.joint == parent) {
                p.mass_kg -= MASSLESS_LINK_MASS_KG;
            }
        }
        // Inertia about each joint centre at rest (parallel-axis theorem per link), of the subtree
        // and of the rest of the body.
        for i in 0..links.len() {
            let joint = links[i].joint;
            let centre = rest[joint.index()];
            let mut subtree = Matrix3::zeros();
            let mut others = Matrix3::zeros();
            for l in &links {
                let r = rest[l.joint.index()] + l.com_m - centre;
                let about_centre = Matrix3::from_diagonal(&l.inertia_kgm2)
                    + l.mass_kg * (Matrix3::identity() * r.norm_squared() - r * r.transpose());
                if l.joint == joint || l.joint.is_descendant_of(joint) {
                    subtree += about_centre;
                } else {
                    others += about_centre;
                }
            }
            links[i].driven_inertia_kgm2 =
                (subtree.trace().max(others.trace()) / 3.0).max(MIN_DRIVEN_INERTIA_KGM2);
        }
        let total_mass_kg = links.iter().map(|l| l.mass_kg).sum();
        let root_inertia_kgm2 = links[0].driven_inertia_kgm2;
        let leg_length_m =
            (rest[JointId::LEFT_HIP.index()] - rest[JointId::LEFT_FOOT.index()]).norm();
        SimModel {
            body: body.clone(),
            links,
            total_mass_kg,
            root_inertia_kgm2,
            leg_length_m,
        }
    }

    /// Index into [`SimModel::links`] of each simulated joint's link (`None` for the rigid leaves).
    pub fn link_of_joint(&self) -> [Option<usize>; NUM_JOINTS] {
        let mut map = [None; NUM_JOINTS];
        for (i, l) in self.links.iter().enumerate() {
            map[l.joint.index()] = Some(i);
        }
        map
    }

    /// Index into [`SimModel::links`] of the link a joint moves with (see [`carrier`]).
    pub fn carrying_link(&self, joint: JointId) -> usize {
        self.link_of_joint()[carrier(joint).index()].expect("carriers are links")
    }
}

impl SimModel {
    /// Height (M's y, m) of the lowest point of any collision shape with the body posed as `fk`.
    pub fn lowest_point_m(&self, fk: &FkData) -> f64 {
        let mut lowest = f64::INFINITY;
        for link in &self.links {
            let j = link.joint.index();
            let (rotation, origin) = (&fk.world_from_joint[j], &fk.joint_in_world_m[j]);
            let height = |p: &Vector3<f64>| (origin + rotation * p).y;
            for (_, shape) in &link.shapes {
                let low = match shape {
                    Shape::Capsule { a, b, radius } => height(a).min(height(b)) - radius,
                    Shape::Ball { centre, radius } => height(centre) - radius,
                    Shape::Cuboid {
                        centre,
                        half_extents: h,
                        rotation: box_rotation,
                    } => (0..8)
                        .map(|k| {
                            let sign = |bit: usize| if k & (1 << bit) == 0 { -1.0 } else { 1.0 };
                            let corner = Vector3::new(sign(0) * h.x, sign(1) * h.y, sign(2) * h.z);
                            height(&(centre + box_rotation * corner))
                        })
                        .fold(f64::INFINITY, f64::min),
                };
                lowest = lowest.min(low);
            }
        }
        lowest
    }
}

/// Mass, centre of mass and principal inertia of the link at `joint`: its body-model segment and
/// those of the rigid joints it carries (their inertias moved to the common centre of mass; the
/// hand continues the forearm along its axis, so the sum stays diagonal), or the small stand-in
/// mass for a massless inner joint.
fn link_mass(body: &BodyModel, joint: JointId) -> (f64, Vector3<f64>, Vector3<f64>) {
    let parts: Vec<(f64, Vector3<f64>, Matrix3<f64>)> = carried(body, joint)
        .into_iter()
        .filter_map(|(j, at)| {
            let s = body.segments.iter().find(|s| s.joint == j)?;
            Some((s.mass_kg, at + s.com_in_joint_m, s.inertia_about_com_kgm2))
        })
        .collect();
    let mass: f64 = parts.iter().map(|p| p.0).sum();
    if mass <= 0.0 {
        return (
            MASSLESS_LINK_MASS_KG,
            Vector3::zeros(),
            Vector3::repeat(MASSLESS_LINK_INERTIA_KGM2),
        );
    }
    let com = parts.iter().map(|p| p.0 * p.1).sum::<Vector3<f64>>() / mass;
    let inertia: Matrix3<f64> = parts
        .iter()
        .map(|(m, c, i)| {
            let r = c - com;
            i + *m * (Matrix3::identity() * r.norm_squared() - r * r.transpose())
        })
        .sum();
    (mass, com, inertia.diagonal())
}

/// Collision shapes of the link at `joint`: capsules along the bones, a ball for the head and a box
/// for each foot (heel to toe tip, floor to ankle). Radii are fractions of stature from adult
/// anthropometric breadths (thigh 0.07 m, shank 0.05 m, trunk 0.11 m, ... at 1.75 m). [inferred]
fn shapes(body: &BodyModel, joint: JointId, foot_pitch_rad: f64) -> Vec<Shape> {
    let s = body.stature_m / 1.75;
    let offset = |j: JointId| *body.skeleton.offset_in_parent_m(j);
    let capsule = |b: Vector3<f64>, radius: f64| Shape::Capsule {
        a: Vector3::zeros(),
        b,
        radius: radius * s,
    };
    let side = |l: JointId, r: JointId| if joint == l { l } else { r };
    match joint {
        JointId::PELVIS => vec![Shape::Capsule {
            a: offset(JointId::LEFT_HIP) + Vector3::new(0.0, 0.03, 0.0),
            b: offset(JointId::RIGHT_HIP) + Vector3::new(0.0, 0.03, 0.0),
            radius: 0.10 * s,
        }],
        JointId::SPINE1 => vec![capsule(offset(JointId::SPINE2), 0.11)],
        JointId::SPINE2 => vec![capsule(offset(JointId::SPINE3), 0.11)],
        JointId::SPINE3 => vec![capsule(offset(JointId::NECK), 0.12)],
        JointId::HEAD => vec![Shape::Ball {
            centre: Vector3::new(0.0, 0.5 * body.head_top_above_head_joint_m, 0.0),
            radius: 0.10 * s,
        }],
        JointId::LEFT_HIP | JointId::RIGHT_HIP => {
            vec![capsule(
                offset(side(JointId::LEFT_KNEE, JointId::RIGHT_KNEE)),
                0.07,
            )]
        }
        JointId::LEFT_KNEE | JointId::RIGHT_KNEE => vec![capsule(
            offset(side(JointId::LEFT_ANKLE, JointId::RIGHT_ANKLE)),
            0.05,
        )],
        JointId::LEFT_SHOULDER | JointId::RIGHT_SHOULDER => vec![capsule(
            offset(side(JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW)),
            0.045,
        )],
        JointId::LEFT_ELBOW | JointId::RIGHT_ELBOW => vec![capsule(
            offset(side(JointId::LEFT_WRIST, JointId::RIGHT_WRIST)),
            0.04,
        )],
        JointId::LEFT_WRIST | JointId::RIGHT_WRIST => vec![capsule(
            offset(side(JointId::LEFT_HAND, JointId::RIGHT_HAND)),
            0.035,
        )],
        JointId::LEFT_ANKLE | JointId::RIGHT_ANKLE => {
            // The foot joint (ball of the foot) lies `ankle height` below and 0.45 foot lengths
            // ahead of the ankle (models/body.toml: foot_joint_forward_fraction); the heel is 0.25
            // foot lengths behind the ankle (body_model.rs). The box runs from the heel to the
            // ball and no further: the toes bend at push-off, and a rigid forefoot reaching 3 cm
            // past the ball dug into the floor as the foot left it (2.4 kN on a foot the estimate
            // had lifted; without it 3 % fewer falls and resyncs on the test walks). Its sole is
            // the plane through the ball that is level when the ankle frame is pitched
            // `foot_pitch_rad` toe-down (see `DEFAULT_FOOT_PITCH_DEG`).
            let toe_joint = offset(side(JointId::LEFT_FOOT, JointId::RIGHT_FOOT));
            let foot_length = toe_joint.z / 0.45;
            let level = Rotation3::from_axis_angle(&Vector3::x_axis(), foot_pitch_rad);
            let ball = level * toe_joint;
            let (sole_depth, heel, tip) = (-ball.y, -0.25 * foot_length, ball.z);
            let rotation = level.inverse();
            vec![Shape::Cuboid {
                centre: rotation * Vector3::new(0.0, -0.5 * sole_depth, 0.5 * (heel + tip)),
                half_extents: Vector3::new(0.045 * s, 0.5 * sole_depth, 0.5 * (tip - heel)),
                rotation,
            }]
        }
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::body_model::BodyParams;

    fn model() -> SimModel {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        SimModel::new(&body)
    }

    #[test]
    fn links_cover_every_joint_but_the_rigid_ones_with_the_body_mass() {
        let m = model();
        assert_eq!(m.links.len(), NUM_JOINTS - RIGID_JOINTS.len());
        assert_eq!(m.links[0].joint, JointId::ROOT);
        // Parents (the carriers of rigid ones) come before children (the multibody is built in
        // this order), and every rigid joint's parent is a link or listed before it.
        for (i, l) in m.links.iter().enumerate().skip(1) {
            let parent = carrier(l.joint.parent().unwrap());
            assert!(m.links[..i].iter().any(|p| p.joint == parent));
        }
        for (i, rigid) in RIGID_JOINTS.iter().enumerate() {
            let parent = rigid.parent().unwrap();
            assert!(is_simulated(parent) || RIGID_JOINTS[..i].contains(&parent));
        }
        // The body's 70 kg, the stand-in mass of spine2 included.
        assert!((m.total_mass_kg - 70.0).abs() < 1e-9);
        // Every link is massive (the lightest real segment is a hand, 0.61 % of 70 kg = 0.43 kg), and
        // the parents that gave up stand-in mass kept most of their own.
        for l in &m.links {
            assert!(l.mass_kg > 0.4, "{:?}: {} kg", l.joint, l.mass_kg);
        }
    }

    #[test]
    fn driven_inertia_is_the_larger_side_about_the_joint() {
        let m = model();
        let map = m.link_of_joint();
        let inertia = |j: JointId| m.links[map[j.index()].unwrap()].driven_inertia_kgm2;
        // The pelvis drives the whole body: about it, 70 kg spread ±0.9 m vertically gives
        // roughly (2/3)·m·(0.45 m)² ≈ 9-15 kg·m² on the mean of the diagonal.
        assert!(
            (5.0..20.0).contains(&m.root_inertia_kgm2),
            "{}",
            m.root_inertia_kgm2
        );
        // A knee in stance carries everything above it, about 0.5 m further from it than the
        // pelvis is: more than the pelvis's own inertia, and far more than the shank and foot.
        let knee = inertia(JointId::LEFT_KNEE);
        assert!(knee > m.root_inertia_kgm2, "knee {knee}");
        // Left and right mirror each other; a joint nearer the centre drives less (the rest of
        // the body is closer to it).
        assert!((inertia(JointId::RIGHT_KNEE) - knee).abs() < 1e-9);
        assert!(inertia(JointId::LEFT_HIP) < knee);
    }

    #[test]
    fn the_sole_is_level_through_the_ball_of_the_foot_at_the_chosen_pitch() {
        let body = model().body;
        for pitch_deg in [0.0, 9.3] {
            let m = SimModel::with_foot_pitch(&body, pitch_deg);
            let link = &m.links[m.link_of_joint()[JointId::LEFT_ANKLE.index()].unwrap()];
            let Shape::Cuboid {
                centre,
                half_extents: h,
                rotation,
            } = &link.shapes[0].1
            else {
                panic!("the foot is a box")
            };
            // Standing at rest with the ankle pitched toe-down as the data's stance feet are.
            let mut pose = imuflow_body::kinematics::Pose::t_pose(Vector3::new(
                0.0,
                m.body.rest_root_height_m,
                0.0,
            ));
            for side in [JointId::LEFT_ANKLE, JointId::RIGHT_ANKLE] {
                pose.parent_from_joint[side.index()] =
                    Rotation3::from_axis_angle(&Vector3::x_axis(), pitch_deg.to_radians());
            }
            let ankle = JointId::LEFT_ANKLE.index();
            let mut fk = FkData::new();
            imuflow_body::kinematics::forward_kinematics(&m.body.skeleton, &pose, &mut fk);
            let ball = fk.joint_in_world_m[JointId::LEFT_FOOT.index()];
            let (at, turn) = (fk.joint_in_world_m[ankle], fk.world_from_joint[ankle]);
            // All four sole corners are at the ball's height: the sole is level through it.
            for (x, z) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
                let corner = at + turn * (centre + rotation * Vector3::new(x * h.x, -h.y, z * h.z));
                assert!(
                    (corner.y - ball.y).abs() < 1e-9,
                    "pitch {pitch_deg}: corner {corner:?}, ball {ball:?}"
                );
            }
            // The box reaches from behind the ankle to the ball, whose height it is.
            let level = turn * rotation;
            let along = |p: Vector3<f64>| (level.inverse() * (p - (at + turn * centre))).z;
            assert!(along(at) > -h.z && along(ball) > 0.0);
            assert!((along(ball) - h.z).abs() < 1e-9, "the box ends at the ball");
            assert!((m.lowest_point_m(&fk) - ball.y).abs() < 1e-9);
        }
    }
}
