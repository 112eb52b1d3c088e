//! The no-physics baseline: the networks' pose, with the root translation integrated from the root
//! velocity after GlobalPose's stationary-joint refinement.
//!
//! GlobalPose (SIGGRAPH 2025) Eq. 4/25, as implemented (reference §5.4 "Root velocity refinement"):
//! with `r_i` the position of contact joint i ∈ {pelvis, feet, hands} relative to the root (world axes),
//! `s_i` its stationary probability and `w_i = clip(5·s_i − 3, 0, 1)` (0 at s ≤ 0.6, 1 at s ≥ 0.8),
//!
//! ```text
//! v = (Σ_i w_i·(r_i(t−1) − r_i(t))/dt + β_v·v_net) / (β_v + Σ_i w_i),   β_v = 1
//! ```
//!
//! a weighted average of "a stationary joint stays where it is" and the network's root velocity. The
//! first frame puts the lowest contact joint on the floor. On flat terrain ([`Terrain::Flat`], the
//! default) the root is then moved so that the lowest stationary foot approaches the floor by
//! [`crate::FLAT_FLOOR_PULL_RATE`] of its height each frame (vertical errors of the network velocity would
//! otherwise accumulate, most over jumps). PIP's kinematics carries foot-contact
//! probabilities only (pelvis and hands 0), so with PIP weights only the feet anchor the root.

use imuflow_body::kinematics::FkData;
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::CONTACT_JOINTS;
use imuflow_body::{NUM_JOINTS, Pose, forward_kinematics};
use imuflow_contact::ContactSet;
use nalgebra::Vector3;

use crate::estimate::{FEET, place_on_floor};
use crate::{
    DT_S, FLAT_FLOOR_PULL_RATE, Method, MotionEstimate, PhysicsBody, Reference, StepReport, Terrain,
};

/// Weight of the network velocity against the stationary joints (GlobalPose reference §5.4: β_velocity = 1).
pub const NETWORK_VELOCITY_WEIGHT: f64 = 1.0;

/// A joint counts as in contact (for the output's contact mask) from this stationary weight on.
const CONTACT_WEIGHT: f64 = 0.5;

/// Stationary weight `w = clip(5·s − 3, 0, 1)` (GlobalPose reference §5.4).
pub fn stationary_weight(probability: f64) -> f64 {
    (5.0 * probability - 3.0).clamp(0.0, 1.0)
}

/// Eq. 25: the refined root velocity from the contact joints relative to the root (world axes) in the
/// previous and this frame, their stationary probabilities, and the network's root velocity.
pub fn refined_root_velocity(
    previous_rel: &[Vector3<f64>; CONTACT_JOINTS.len()],
    rel: &[Vector3<f64>; CONTACT_JOINTS.len()],
    stationary_prob: &[f64; CONTACT_JOINTS.len()],
    network_velocity: &Vector3<f64>,
) -> Vector3<f64> {
    let mut sum = NETWORK_VELOCITY_WEIGHT * network_velocity;
    let mut total = NETWORK_VELOCITY_WEIGHT;
    for i in 0..CONTACT_JOINTS.len() {
        let w = stationary_weight(stationary_prob[i]);
        sum += w * (previous_rel[i] - rel[i]) / DT_S;
        total += w;
    }
    sum / total
}

/// On flat ground, the root's vertical velocity while a foot is planted: the weighted mean of the
/// stationary joints' vertical motion relative to the root (Eq. 25 without the network's term;
/// the legs' pose fixes the root's height over a planted foot, and the network's vertical
/// velocity would only add its bias). `None` without a stationary foot.
pub fn planted_vertical_velocity(
    previous_rel: &[Vector3<f64>; CONTACT_JOINTS.len()],
    rel: &[Vector3<f64>; CONTACT_JOINTS.len()],
    weights: &[f64; CONTACT_JOINTS.len()],
) -> Option<f64> {
    let planted = CONTACT_JOINTS
        .iter()
        .zip(weights)
        .any(|(j, w)| FEET.contains(j) && *w > 0.0);
    let total: f64 = weights.iter().sum();
    let sum: f64 = (0..CONTACT_JOINTS.len())
        .map(|i| weights[i] * (previous_rel[i].y - rel[i].y) / DT_S)
        .sum();
    planted.then(|| sum / total)
}

/// Contact joints ([`CONTACT_JOINTS`]) of `reference`'s pose relative to the root, in world axes.
pub fn contact_joints_rel(
    physics: &PhysicsBody,
    reference: &Reference,
    fk: &mut FkData,
) -> [Vector3<f64>; CONTACT_JOINTS.len()] {
    let mut pose = reference.pose.clone();
    pose.root_in_world_m = Vector3::zeros();
    forward_kinematics(&physics.body.skeleton, &pose, fk);
    CONTACT_JOINTS.map(|j| fk.joint_in_world_m[j.index()])
}

/// The `integrate` method.
pub struct Integrate {
    physics: PhysicsBody,
    terrain: Terrain,
    fk: FkData,
    /// Contact joints relative to the root (world axes) in the previous frame; `None` before the first.
    previous_rel: Option<[Vector3<f64>; CONTACT_JOINTS.len()]>,
    previous: MotionEstimate,
    contacts: ContactSet,
}

impl Integrate {
    pub fn new(physics: PhysicsBody) -> Integrate {
        Integrate::with_terrain(physics, Terrain::default())
    }

    pub fn with_terrain(physics: PhysicsBody, terrain: Terrain) -> Integrate {
        Integrate {
            physics,
            terrain,
            fk: FkData::new(),
            previous_rel: None,
            previous: MotionEstimate::default(),
            contacts: ContactSet::new(),
        }
    }

    /// Height above the floor of the lowest stationary foot's ground point (negative: below it),
    /// 0 without a stationary foot.
    fn stationary_foot_height(
        &mut self,
        pose: &Pose,
        weights: &[f64; CONTACT_JOINTS.len()],
    ) -> f64 {
        forward_kinematics(&self.physics.body.skeleton, pose, &mut self.fk);
        CONTACT_JOINTS
            .iter()
            .zip(weights)
            .filter(|(j, w)| FEET.contains(j) && **w >= CONTACT_WEIGHT)
            .map(|(j, _)| {
                let geometry = &self.physics.geometry;
                geometry.height_above(*j, &self.fk.joint_in_world_m[j.index()], 0.0)
            })
            .reduce(f64::min)
            .unwrap_or(0.0)
    }

    /// Continue from another method's frame: the next step integrates from `root` (m, M), with
    /// `reference` as the previous frame's networks' estimate (its contact joints for the velocity
    /// refinement, its rotations for the joint velocities). The physics methods' degraded
    /// estimate ([`crate::degraded`]) steps from where they stood this way.
    pub fn continue_from(&mut self, reference: &Reference, root: &Vector3<f64>) {
        self.previous_rel = Some(self.contact_joints_rel(reference));
        self.previous.pose.clone_from(&reference.pose);
        self.previous.pose.root_in_world_m = *root;
    }

    /// Contact joints relative to the root, in world axes, of the reference pose.
    fn contact_joints_rel(
        &mut self,
        reference: &Reference,
    ) -> [Vector3<f64>; CONTACT_JOINTS.len()] {
        contact_joints_rel(&self.physics, reference, &mut self.fk)
    }
}

impl Method for Integrate {
    /// The contacts of the last step: joints whose stationary weight reached 0.5 (no forces).
    fn contacts(&self) -> &ContactSet {
        &self.contacts
    }

    fn reset(&mut self) {
        self.previous_rel = None;
    }

    fn step(
        &mut self,
        reference: &Reference,
        _contacts: Option<&ContactSet>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport> {
        let rel = self.contact_joints_rel(reference);
        let weights = reference.stationary_prob.map(stationary_weight);
        *out = MotionEstimate {
            pose: reference.pose.clone(),
            ..MotionEstimate::default()
        };
        match &self.previous_rel {
            None => {
                out.pose.root_in_world_m = Vector3::zeros();
                place_on_floor(&self.physics, &mut out.pose, &CONTACT_JOINTS, &mut self.fk);
            }
            Some(previous_rel) => {
                let mut v = refined_root_velocity(
                    previous_rel,
                    &rel,
                    &reference.stationary_prob,
                    &reference.root_velocity_mps,
                );
                if self.terrain == Terrain::Flat
                    && let Some(v_y) = planted_vertical_velocity(previous_rel, &rel, &weights)
                {
                    v.y = v_y;
                }
                out.pose.root_in_world_m = self.previous.pose.root_in_world_m + v * DT_S;
                if self.terrain == Terrain::Flat {
                    out.pose.root_in_world_m.y -=
                        FLAT_FLOOR_PULL_RATE * self.stationary_foot_height(&out.pose, &weights);
                }
                out.v.fixed_rows_mut::<3>(0).copy_from(&v);
                // Joint velocities in the body crate's coordinates: log(R_prevᵀ·R)/dt in the joint frame.
                for j in 0..NUM_JOINTS {
                    let d = self.previous.pose.parent_from_joint[j].transpose()
                        * out.pose.parent_from_joint[j];
                    let w = axis_angle_from_rotation(&d) / DT_S;
                    out.v.fixed_rows_mut::<3>(3 + 3 * j).copy_from(&w);
                }
            }
        }
        self.contacts.clear();
        for (i, j) in CONTACT_JOINTS.iter().enumerate() {
            if weights[i] >= CONTACT_WEIGHT {
                out.contact_mask |= 1 << j.index();
            }
        }
        self.contacts.mask = out.contact_mask;
        self.previous_rel = Some(rel);
        self.previous = out.clone();
        Ok(StepReport::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::JointId;
    use nalgebra::Rotation3;

    fn reference() -> Reference {
        Reference {
            stationary_prob: [0.0; 5],
            ..Reference::default()
        }
    }

    #[test]
    fn the_weight_ramps_from_point_six_to_point_eight() {
        assert_eq!(stationary_weight(0.6), 0.0);
        assert!((stationary_weight(0.7) - 0.5).abs() < 1e-12);
        assert_eq!(stationary_weight(0.8), 1.0);
        assert_eq!(stationary_weight(0.95), 1.0);
    }

    #[test]
    fn without_stationary_joints_the_root_follows_the_network_velocity() {
        let mut m = Integrate::new(PhysicsBody::new(1.75, 70.0).unwrap());
        let mut r = reference();
        r.root_velocity_mps = Vector3::new(0.0, 0.0, 1.2);
        let mut out = MotionEstimate::default();
        m.step(&r, None, &mut out).unwrap();
        let start = out.pose.root_in_world_m;
        // The first frame stands the T-pose on its feet (clearance: feet rest on the floor).
        assert!(
            (start.y - m.physics.body.rest_root_height_m).abs() < 1e-9,
            "{start}"
        );
        for _ in 0..60 {
            m.step(&r, None, &mut out).unwrap();
        }
        let moved = out.pose.root_in_world_m - start;
        assert!(
            (moved - Vector3::new(0.0, 0.0, 1.2)).norm() < 1e-9,
            "{moved}"
        );
        assert!((out.v[2] - 1.2).abs() < 1e-12);
    }

    #[test]
    fn a_stationary_foot_holds_the_root_against_a_wrong_network_velocity() {
        // Hand-derived: one foot fully stationary (w = 1), the pose still, the network says 1 m/s:
        // v = (1·0 + 1·1 m/s) / (1 + 1) = 0.5 m/s. (The paper's Eq. 25 alone: proxy terrain.)
        let mut m = Integrate::with_terrain(PhysicsBody::new(1.75, 70.0).unwrap(), Terrain::Proxy);
        let mut r = reference();
        r.stationary_prob[1] = 0.9;
        r.root_velocity_mps = Vector3::new(1.0, 0.0, 0.0);
        let mut out = MotionEstimate::default();
        m.step(&r, None, &mut out).unwrap();
        m.step(&r, None, &mut out).unwrap();
        assert!((out.v[0] - 0.5).abs() < 1e-12, "{}", out.v[0]);
        assert_eq!(out.contact_mask, 1 << JointId::LEFT_FOOT.index());
        // A swinging pose that moves the foot backwards relative to the root while the foot is
        // stationary moves the root forward by the same amount (walking): rotate the left hip.
        let before = m.contact_joints_rel(&r)[1];
        r.pose.parent_from_joint[JointId::LEFT_HIP.index()] =
            Rotation3::new(Vector3::new(-0.2, 0.0, 0.0));
        let after = m.contact_joints_rel(&r)[1];
        r.root_velocity_mps = Vector3::zeros();
        let root_before = out.pose.root_in_world_m;
        m.step(&r, None, &mut out).unwrap();
        // (before − after)/dt weighted 1 against the network's 0 with weight 1: half of it.
        let want = (before - after) / 2.0;
        assert!((out.pose.root_in_world_m - root_before - want).norm() < 1e-9);
        // The joint velocity of the hip is the rotation over one frame.
        let w = Vector3::new(out.v[3 + 3], out.v[4 + 3], out.v[5 + 3]);
        assert!(
            (w - Vector3::new(-0.2, 0.0, 0.0) / DT_S).norm() < 1e-9,
            "{w}"
        );
    }

    #[test]
    fn on_flat_ground_a_planted_foot_alone_sets_the_vertical_velocity_and_the_foot_stays_down() {
        // The network says 1 m/s up and 1 m/s sideways; one foot is planted, the pose still.
        // Horizontal: Eq. 25, (0 + 1)/2 = 0.5 m/s. Vertical: the foot's (0), not the network's.
        let mut m = Integrate::new(PhysicsBody::new(1.75, 70.0).unwrap());
        let mut r = reference();
        r.stationary_prob[1] = 0.9;
        r.root_velocity_mps = Vector3::new(1.0, 1.0, 0.0);
        let mut out = MotionEstimate::default();
        m.step(&r, None, &mut out).unwrap();
        let start = out.pose.root_in_world_m;
        for _ in 0..30 {
            m.step(&r, None, &mut out).unwrap();
        }
        assert!((out.v[0] - 0.5).abs() < 1e-12, "{}", out.v[0]);
        assert!(out.v[1].abs() < 1e-12, "{}", out.v[1]);
        assert!((out.pose.root_in_world_m.y - start.y).abs() < 1e-9);
        // Lifted 10 cm (as after a biased flight), the planted foot comes back down by
        // FLAT_FLOOR_PULL_RATE of its height per frame: 10 cm·0.8^n.
        m.previous.pose.root_in_world_m.y += 0.1;
        for n in 1..=5 {
            m.step(&r, None, &mut out).unwrap();
            let above = out.pose.root_in_world_m.y - start.y;
            let want = 0.1 * (1.0 - FLAT_FLOOR_PULL_RATE).powi(n);
            assert!(
                (above - want).abs() < 1e-9,
                "frame {n}: {above} m, want {want}"
            );
        }
    }
}
