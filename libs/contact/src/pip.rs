//! PIP's contact rule (CVPR 2022 §3.2.3 "contact"; reference §5.2 "Contact set"), evaluated on the
//! *current physics state* (the optimizer's previous output), not on the networks' pose.
//!
//! - Candidate bodies: PIP's 16 ([`CANDIDATES`]): hips, spine1–3, knees, shoulders, head, elbows, hands
//!   and feet, mapped to our SMPL [`JointId`]s.
//! - A body is in contact when its ground point is at or below its surface
//!   (`ContactGeometry::height_above ≤ 0`, replacing PIP's `y ≤ floor_y = −0.87`, which was tuned to
//!   PIP's own body). A foot is also in contact when the networks' foot-contact probability exceeds
//!   [`PipContactConfig::foot_probability_threshold`] (0.5) and the foot is at most
//!   [`PipContactConfig::foot_margin_m`] (0.03 m) above the surface.
//! - Each contact body adds 4 points: its ground point ± (h, 0, ±h) in world x/z with
//!   h = [`PipContactConfig::square_half_side_m`] (0.1 m: a 20 cm square, independent of the body's
//!   orientation, as in PIP). Point order per body: (+h, +h), (+h, −h), (−h, +h), (−h, −h) in (x, z).
//!
//! **Feet.** We use `LEFT_FOOT`/`RIGHT_FOOT` (SMPL 10/11) as PIP does; their height decides the contact.
//! Our foot joint is the ball of the foot (12 cm in front of the ankle, like PIP's foot body, which
//! sits at ankle height 12 cm forward). **Deviation:** the foot's square is centred halfway between the
//! ankle and the ball of the foot in world x/z ([`foot_square_centre`]), at the foot's ground-point
//! height, instead of under the ball. Centred under the ball it spans ankle + 2 cm .. ankle + 22 cm and
//! misses the heel; in our body the centre of mass stands above the ankles, i.e. 2 cm behind that
//! square, and a standing body tips backwards (measured with the optimizer: 1.3 cm root drift in 1 s
//! and a 40 N·m virtual root torque). Halfway it spans ankle − 4 cm .. ankle + 16 cm, inside the real
//! sole (heel ≈ ankle − 6 cm, toes ≈ ankle + 20 cm). Other bodies use their ground point. The ankles are
//! not candidates (not in PIP either).
//!
//! **Capacity.** A [`ContactSet`] holds 32 points, i.e. 8 bodies. PIP has no limit (16 bodies, 64 points,
//! only reachable when lying on the floor). When more than 8 bodies touch, we keep the feet first and
//! then the lowest bodies (smallest height above the surface); the rest are dropped and counted in the
//! return value of [`pip_contacts`].

use imuflow_body::{JointId, NUM_JOINTS};
use imuflow_graph::frames::MAX_CONTACT_POINTS;
use imuflow_graph::params::Param;
use nalgebra::Vector3;

use crate::geometry::{ContactGeometry, PIP_SQUARE_HALF_SIDE_M};
use crate::set::{ContactPoint, ContactSet};

/// PIP's 16 candidate contact bodies (reference §5.2), as SMPL joints. The feet are the last two.
pub const CANDIDATES: [JointId; 16] = [
    JointId::LEFT_HIP,
    JointId::RIGHT_HIP,
    JointId::SPINE1,
    JointId::LEFT_KNEE,
    JointId::RIGHT_KNEE,
    JointId::SPINE2,
    JointId::SPINE3,
    JointId::LEFT_SHOULDER,
    JointId::RIGHT_SHOULDER,
    JointId::HEAD,
    JointId::LEFT_ELBOW,
    JointId::RIGHT_ELBOW,
    JointId::LEFT_HAND,
    JointId::RIGHT_HAND,
    JointId::LEFT_FOOT,
    JointId::RIGHT_FOOT,
];

/// The feet, in the order of the networks' foot-contact probabilities [left, right].
pub const FEET: [JointId; 2] = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT];

/// Points per contact body (the corners of PIP's square).
pub const POINTS_PER_BODY: usize = 4;

/// At most this many bodies fit a [`ContactSet`].
pub const MAX_BODIES: usize = MAX_CONTACT_POINTS / POINTS_PER_BODY;

/// Parameters of PIP's rule. `Default` = the paper's/code's values.
#[derive(Clone, Debug, PartialEq)]
pub struct PipContactConfig {
    /// A foot with contact probability above this counts as in contact near the floor (PIP: 0.5,
    /// reference §5.2).
    pub foot_probability_threshold: f64,
    /// How far above the surface such a foot may be (m; PIP: floor_y + 0.03, reference §5.2).
    pub foot_margin_m: f64,
    /// Half the side of the support square (m; PIP: 0.2 m side, reference §5.2).
    pub square_half_side_m: f64,
    /// Height of the surface (M's y, m). The floor is 0 (our convention; PIP's floor_y = −0.87 belongs
    /// to its body model, see the module docs).
    pub surface_height_m: f64,
}

/// The contact stage's `foot_threshold`: the default of
/// [`PipContactConfig::foot_probability_threshold`] (PIP: 0.5, reference §5.2).
pub const FOOT_THRESHOLD_PARAM: Param<f64> = imuflow_graph::param! {
    /// foot-contact probability above which a foot near the floor is in contact (PIP 0.5)
    foot_threshold: f64 = 0.5, float(0.0, 1.0)
};

/// The contact stage's `foot_margin_m`: the default of [`PipContactConfig::foot_margin_m`] (PIP:
/// floor_y + 0.03, reference §5.2).
pub const FOOT_MARGIN_PARAM: Param<f64> = imuflow_graph::param! {
    /// how far above the floor such a foot may be (m, PIP 0.03)
    foot_margin_m: f64 = 0.03, float(0.0, 0.5)
};

impl Default for PipContactConfig {
    fn default() -> PipContactConfig {
        PipContactConfig {
            foot_probability_threshold: FOOT_THRESHOLD_PARAM.default,
            foot_margin_m: FOOT_MARGIN_PARAM.default,
            square_half_side_m: PIP_SQUARE_HALF_SIDE_M,
            surface_height_m: 0.0,
        }
    }
}

/// Whether `joint` is in contact by PIP's rule. `foot_probability` is the foot's contact probability
/// (ignored for other joints).
pub fn in_contact(
    joint: JointId,
    joint_position: &Vector3<f64>,
    foot_probability: f64,
    geometry: &ContactGeometry,
    config: &PipContactConfig,
) -> bool {
    let h = geometry.height_above(joint, joint_position, config.surface_height_m);
    let is_foot = FEET.contains(&joint);
    h <= 0.0
        || (is_foot
            && foot_probability > config.foot_probability_threshold
            && h <= config.foot_margin_m)
}

/// The ankle of a foot joint.
fn foot_ankle(j: JointId) -> Option<JointId> {
    match j {
        JointId::LEFT_FOOT => Some(JointId::LEFT_ANKLE),
        JointId::RIGHT_FOOT => Some(JointId::RIGHT_ANKLE),
        _ => None,
    }
}

/// Centre of a foot's support square: world x/z halfway between the ankle and the foot joint (ball of
/// the foot), y of the foot's ground point (see the module docs).
pub fn foot_square_centre(
    foot: JointId,
    ankle: JointId,
    joints: &[Vector3<f64>; NUM_JOINTS],
    geometry: &ContactGeometry,
) -> Vector3<f64> {
    let ground = geometry.ground_point(foot, &joints[foot.index()]);
    let a = &joints[ankle.index()];
    Vector3::new(0.5 * (ground.x + a.x), ground.y, 0.5 * (ground.z + a.z))
}

/// Fill `out` (cleared first) with PIP's contacts for the joint world positions `joints` (the current
/// physics state) and the networks' foot-contact probabilities [left, right]. Forces are zero; surface
/// heights of contact joints are `config.surface_height_m`. Returns how many contact bodies were
/// dropped for lack of capacity (see the module docs), normally 0.
pub fn pip_contacts(
    joints: &[Vector3<f64>; NUM_JOINTS],
    foot_probability: [f64; 2],
    geometry: &ContactGeometry,
    config: &PipContactConfig,
    out: &mut ContactSet,
) -> usize {
    out.clear();
    // (is not a foot, height, joint): sorting puts the feet first, then the lowest bodies.
    let mut found = [(false, 0.0, JointId::PELVIS); CANDIDATES.len()];
    let mut n = 0;
    for &j in &CANDIDATES {
        let p = &joints[j.index()];
        let prob = match FEET.iter().position(|&f| f == j) {
            Some(k) => foot_probability[k],
            None => 0.0,
        };
        if in_contact(j, p, prob, geometry, config) {
            let h = geometry.height_above(j, p, config.surface_height_m);
            found[n] = (!FEET.contains(&j), h, j);
            n += 1;
        }
    }
    let found = &mut found[..n];
    if n > MAX_BODIES {
        found.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    }
    let hs = config.square_half_side_m;
    for &(_, _, j) in found.iter().take(MAX_BODIES) {
        let ground = match foot_ankle(j) {
            Some(ankle) => foot_square_centre(j, ankle, joints, geometry),
            None => geometry.ground_point(j, &joints[j.index()]),
        };
        for (dx, dz) in [(hs, hs), (hs, -hs), (-hs, hs), (-hs, -hs)] {
            out.push(ContactPoint {
                joint: j,
                position: ground + Vector3::new(dx, 0.0, dz),
                force: Vector3::zeros(),
            })
            .expect("at most MAX_BODIES bodies of 4 points");
        }
        out.surface_height_m[j.index()] = config.surface_height_m;
    }
    n.saturating_sub(MAX_BODIES)
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::{BodyModel, BodyParams};

    fn setup() -> (BodyModel, ContactGeometry, [Vector3<f64>; NUM_JOINTS]) {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let geometry = ContactGeometry::new(&body);
        let rest = body.rest_positions_on_floor_m();
        (body, geometry, rest)
    }

    fn lifted(rest: &[Vector3<f64>; NUM_JOINTS], dy: f64) -> [Vector3<f64>; NUM_JOINTS] {
        rest.map(|p| p + Vector3::new(0.0, dy, 0.0))
    }

    #[test]
    fn t_pose_on_the_floor_gives_both_feet_and_eight_corner_points() {
        let (_, geometry, rest) = setup();
        let mut set = ContactSet::new();
        let config = PipContactConfig::default();
        // Probability 0: the feet count by height alone (ground point exactly at y = 0).
        let dropped = pip_contacts(&rest, [0.0, 0.0], &geometry, &config, &mut set);
        assert_eq!(dropped, 0);
        assert_eq!(set.points().len(), 8);
        assert_eq!(
            set.mask,
            (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index())
        );
        // Hand-derived: the left foot's points are (c_x ± 0.1, 0, c_z ± 0.1) with c halfway between the
        // ankle and the ball of the foot, in the documented order.
        let f = rest[JointId::LEFT_FOOT.index()];
        let a = rest[JointId::LEFT_ANKLE.index()];
        let (cx, cz) = ((f.x + a.x) / 2.0, (f.z + a.z) / 2.0);
        assert!(
            f.z - cz > 0.04,
            "the centre lies behind the ball of the foot"
        );
        let want = [(0.1, 0.1), (0.1, -0.1), (-0.1, 0.1), (-0.1, -0.1)]
            .map(|(dx, dz)| Vector3::new(cx + dx, 0.0, cz + dz));
        let left: Vec<_> = set
            .points()
            .iter()
            .filter(|p| p.joint == JointId::LEFT_FOOT)
            .collect();
        assert_eq!(left.len(), 4);
        for (p, w) in left.iter().zip(want) {
            assert!((p.position - w).norm() < 1e-12, "{} vs {w}", p.position);
            assert_eq!(p.force, Vector3::zeros());
        }
        assert_eq!(set.surface_height_m[JointId::RIGHT_FOOT.index()], 0.0);
    }

    #[test]
    fn lifted_feet_count_only_with_a_confident_network_and_within_the_margin() {
        let (_, geometry, rest) = setup();
        let config = PipContactConfig::default();
        let mut set = ContactSet::new();
        let up2 = lifted(&rest, 0.02);
        pip_contacts(&up2, [0.9, 0.9], &geometry, &config, &mut set);
        assert_eq!(set.points().len(), 8);
        // The points lie under the lifted joints (2 cm above the floor), not on the floor.
        assert!(
            set.points()
                .iter()
                .all(|p| (p.position.y - 0.02).abs() < 1e-12)
        );
        pip_contacts(&up2, [0.2, 0.2], &geometry, &config, &mut set);
        assert_eq!(set.points().len(), 0);
        assert_eq!(set.mask, 0);
        // One foot confident, one not.
        pip_contacts(&up2, [0.9, 0.2], &geometry, &config, &mut set);
        assert_eq!(set.mask, 1 << JointId::LEFT_FOOT.index());
        // 4 cm is beyond the 3 cm margin however confident the network is.
        pip_contacts(
            &lifted(&rest, 0.04),
            [1.0, 1.0],
            &geometry,
            &config,
            &mut set,
        );
        assert_eq!(set.points().len(), 0);
    }

    #[test]
    fn a_knee_on_the_ground_is_a_contact() {
        let (_, geometry, rest) = setup();
        let mut joints = lifted(&rest, 0.2); // feet well above the floor
        let k = JointId::LEFT_KNEE;
        // The knee's ground point (clearance below the joint) exactly on the floor.
        joints[k.index()].y = geometry.clearance(k);
        let mut set = ContactSet::new();
        pip_contacts(
            &joints,
            [1.0, 1.0],
            &geometry,
            &PipContactConfig::default(),
            &mut set,
        );
        assert_eq!(set.mask, 1 << k.index());
        assert_eq!(set.points().len(), 4);
        assert!(set.points().iter().all(|p| p.position.y.abs() < 1e-12));
        // 1 mm higher: not in contact (the margin is for feet only).
        joints[k.index()].y += 1e-3;
        pip_contacts(
            &joints,
            [1.0, 1.0],
            &geometry,
            &PipContactConfig::default(),
            &mut set,
        );
        assert_eq!(set.mask, 0);
    }

    #[test]
    fn more_than_eight_bodies_keep_the_feet_then_the_lowest() {
        let (_, geometry, _) = setup();
        // Every joint's ground point below the floor, deeper for earlier candidates except the feet,
        // which are the shallowest: candidate i at height −0.01·(16 − i).
        let mut joints = [Vector3::zeros(); NUM_JOINTS];
        for (i, j) in CANDIDATES.iter().enumerate() {
            joints[j.index()].y = geometry.clearance(*j) - 0.01 * (16 - i) as f64;
        }
        let mut set = ContactSet::new();
        let dropped = pip_contacts(
            &joints,
            [0.0, 0.0],
            &geometry,
            &PipContactConfig::default(),
            &mut set,
        );
        assert_eq!(dropped, 8);
        assert_eq!(set.points().len(), 32);
        // Kept: both feet and the six deepest, i.e. candidates 0..6.
        let mut want = (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index());
        for j in &CANDIDATES[..6] {
            want |= 1 << j.index();
        }
        assert_eq!(set.mask, want);
    }
}
