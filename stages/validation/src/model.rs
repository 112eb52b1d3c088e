//! The simulated body, derived from imuflow's body model (`models/body.toml`, the same model the
//! optimizer uses): which joints become links, their mass properties, collision shapes and the
//! inertia each joint drives (for the gains). Plain data, no rapier types.

use imuflow_body::body_model::BodyModel;
use imuflow_body::kinematics::FkData;
use imuflow_body::skeleton::{JointId, NUM_JOINTS};
use nalgebra::{Matrix3, Vector3};

/// Joints that are not simulated: the massless leaves (toes and fingers). Each is rigidly part of
/// its parent's link (ankle, wrist); their rotations in the estimate are not tracked.
pub const RIGID_LEAVES: [JointId; 4] = [
    JointId::LEFT_FOOT,
    JointId::RIGHT_FOOT,
    JointId::LEFT_HAND,
    JointId::RIGHT_HAND,
];

/// Mass (kg) the massless inner joints (spine2, neck, collars) take from their parent's segment so
/// that every link of the multibody has a mass the solver can drive: with a few grams the stiff
/// motors of these joints were ill-conditioned (20-90° errors while standing). The total mass is
/// unchanged. [inferred]
const MASSLESS_LINK_MASS_KG: f64 = 0.5;
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
    /// A box, m (half extents along the link's axes).
    Cuboid {
        centre: Vector3<f64>,
        half_extents: Vector3<f64>,
    },
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
    /// Collision shapes (none for links that cannot touch the floor in practice: neck, collars).
    pub shapes: Vec<Shape>,
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
}

/// Whether `joint` is a link of the simulation.
pub fn is_simulated(joint: JointId) -> bool {
    !RIGID_LEAVES.contains(&joint)
}

impl SimModel {
    /// The simulated body of `body`.
    pub fn new(body: &BodyModel) -> SimModel {
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
                    shapes: shapes(body, joint),
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
        SimModel {
            body: body.clone(),
            links,
            total_mass_kg,
            root_inertia_kgm2,
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

    /// The link a joint moves with: itself, or for a rigid leaf its parent's link.
    pub fn carrying_link(&self, joint: JointId) -> usize {
        let map = self.link_of_joint();
        let carrier = if is_simulated(joint) {
            joint
        } else {
            joint.parent().unwrap_or(JointId::ROOT)
        };
        map[carrier.index()].unwrap_or(0)
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
            for shape in &link.shapes {
                let low = match shape {
                    Shape::Capsule { a, b, radius } => height(a).min(height(b)) - radius,
                    Shape::Ball { centre, radius } => height(centre) - radius,
                    Shape::Cuboid {
                        centre,
                        half_extents: h,
                    } => (0..8)
                        .map(|k| {
                            let sign = |bit: usize| if k & (1 << bit) == 0 { -1.0 } else { 1.0 };
                            height(
                                &(centre
                                    + Vector3::new(sign(0) * h.x, sign(1) * h.y, sign(2) * h.z)),
                            )
                        })
                        .fold(f64::INFINITY, f64::min),
                };
                lowest = lowest.min(low);
            }
        }
        lowest
    }
}

/// Mass, centre of mass and principal inertia of the link at `joint`: its body-model segment, or
/// the small stand-in mass for a massless inner joint.
fn link_mass(body: &BodyModel, joint: JointId) -> (f64, Vector3<f64>, Vector3<f64>) {
    match body.segments.iter().find(|s| s.joint == joint) {
        Some(s) => (
            s.mass_kg,
            s.com_in_joint_m,
            s.inertia_about_com_kgm2.diagonal(),
        ),
        None => (
            MASSLESS_LINK_MASS_KG,
            Vector3::zeros(),
            Vector3::repeat(MASSLESS_LINK_INERTIA_KGM2),
        ),
    }
}

/// Collision shapes of the link at `joint`: capsules along the bones, a ball for the head and a box
/// for each foot (heel to toe tip, floor to ankle). Radii are fractions of stature from adult
/// anthropometric breadths (thigh 0.07 m, shank 0.05 m, trunk 0.11 m, ... at 1.75 m). [inferred]
fn shapes(body: &BodyModel, joint: JointId) -> Vec<Shape> {
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
            // foot lengths behind it (body_model.rs), the toe tip 0.75 ahead.
            let toe_joint = offset(side(JointId::LEFT_FOOT, JointId::RIGHT_FOOT));
            let ankle_height = -toe_joint.y;
            let foot_length = toe_joint.z / 0.45;
            vec![Shape::Cuboid {
                centre: Vector3::new(0.0, -0.5 * ankle_height, 0.25 * foot_length),
                half_extents: Vector3::new(0.045 * s, 0.5 * ankle_height, 0.5 * foot_length),
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
    fn links_cover_every_joint_but_the_rigid_leaves_with_the_body_mass() {
        let m = model();
        assert_eq!(m.links.len(), NUM_JOINTS - RIGID_LEAVES.len());
        assert_eq!(m.links[0].joint, JointId::ROOT);
        // Parents come before children (the multibody is built in this order).
        for (i, l) in m.links.iter().enumerate().skip(1) {
            let parent = l.joint.parent().unwrap();
            assert!(m.links[..i].iter().any(|p| p.joint == parent));
        }
        // The body's 70 kg, four stand-in masses for spine2, neck and the collars included.
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
    fn foot_box_touches_the_floor_at_rest() {
        let m = model();
        let rest = m.body.rest_positions_on_floor_m();
        let ankle = rest[JointId::LEFT_ANKLE.index()];
        let link = &m.links[m.link_of_joint()[JointId::LEFT_ANKLE.index()].unwrap()];
        let Shape::Cuboid {
            centre,
            half_extents,
        } = &link.shapes[0]
        else {
            panic!("the foot is a box")
        };
        let sole = ankle.y + centre.y - half_extents.y;
        assert!(sole.abs() < 1e-9, "sole at {sole} m");
        // The toe joint lies inside the box.
        let toe = rest[JointId::LEFT_FOOT.index()] - ankle - centre;
        assert!(
            toe.iter()
                .zip(half_extents.iter())
                .all(|(d, h)| d.abs() <= *h + 1e-9)
        );
        // Standing at rest, the soles are the lowest points, on the floor.
        let mut fk = FkData::new();
        let pose = imuflow_body::kinematics::Pose::t_pose(Vector3::new(
            0.0,
            m.body.rest_root_height_m,
            0.0,
        ));
        imuflow_body::kinematics::forward_kinematics(&m.body.skeleton, &pose, &mut fk);
        assert!(m.lowest_point_m(&fk).abs() < 1e-9);
    }
}
