//! Where a joint touches the ground.
//!
//! PIP and GlobalPose test joint *positions* against a floor height tuned to their own body models (PIP's
//! foot bodies sit 2.4 cm below its floor_y; GlobalPose lowers the pelvis point by 0.15 m, reference
//! §5.2/§5.4). Our body model puts the floor at y = 0 with every joint at its anatomical height, so we
//! keep the floor where it is and give each joint a *clearance*: how high the joint sits above the
//! surface it rests on. A joint touches the surface when `y_joint − clearance ≤ surface_height`, and its
//! contact points lie `clearance` below the joint.

use imuflow_body::{BodyModel, JointId, NUM_JOINTS};
use nalgebra::Vector3;

/// Clearance of the pelvis when sitting (GlobalPose's 0.15 m pelvis drop, reference §5.4 step 4).
pub const PELVIS_SITTING_CLEARANCE_M: f64 = 0.15;
/// Clearance of joints that are not feet or the pelvis: about the radius of the limb around the joint
/// (knees, elbows, hands, head, spine). [inferred: imuflow's choice, not from the papers]
pub const LIMB_CLEARANCE_M: f64 = 0.05;
/// Half the side of PIP's contact square (20 cm side; CVPR 2022 §3.2.3, reference §5.2).
pub const PIP_SQUARE_HALF_SIDE_M: f64 = 0.1;

/// Per-joint ground clearance of one subject.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactGeometry {
    /// Height of each joint above the surface it rests on (m).
    pub clearance_m: [f64; NUM_JOINTS],
}

impl ContactGeometry {
    /// Clearances from the body model: ankles and feet at their T-pose height above the floor (the model
    /// stands on y = 0), the pelvis at GlobalPose's sitting drop, every other joint [`LIMB_CLEARANCE_M`].
    pub fn new(body: &BodyModel) -> ContactGeometry {
        let rest = body.rest_positions_on_floor_m();
        let mut clearance_m = [LIMB_CLEARANCE_M; NUM_JOINTS];
        for j in [
            JointId::LEFT_ANKLE,
            JointId::RIGHT_ANKLE,
            JointId::LEFT_FOOT,
            JointId::RIGHT_FOOT,
        ] {
            clearance_m[j.index()] = rest[j.index()].y.max(0.0);
        }
        clearance_m[JointId::PELVIS.index()] = PELVIS_SITTING_CLEARANCE_M;
        ContactGeometry { clearance_m }
    }

    /// Clearance of one joint (m).
    pub fn clearance(&self, joint: JointId) -> f64 {
        self.clearance_m[joint.index()]
    }

    /// The point under `joint` that touches the ground, given the joint's world position.
    pub fn ground_point(&self, joint: JointId, joint_position: &Vector3<f64>) -> Vector3<f64> {
        joint_position - Vector3::new(0.0, self.clearance(joint), 0.0)
    }

    /// Height of `joint`'s ground point above a surface at `surface_height` (negative: penetrating).
    pub fn height_above(
        &self,
        joint: JointId,
        joint_position: &Vector3<f64>,
        surface_height: f64,
    ) -> f64 {
        joint_position.y - self.clearance(joint) - surface_height
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::BodyParams;

    #[test]
    fn feet_of_the_rest_pose_touch_the_floor_and_the_pelvis_does_not() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let geometry = ContactGeometry::new(&body);
        let rest = body.rest_positions_on_floor_m();
        for j in [JointId::LEFT_FOOT, JointId::RIGHT_FOOT, JointId::LEFT_ANKLE] {
            let h = geometry.height_above(j, &rest[j.index()], 0.0);
            assert!(h.abs() < 1e-12, "{j:?} rests on the floor: {h}");
        }
        // The ankle sits at Winter's ankle height (0.039 × stature, body.toml) above its sole.
        let ankle = geometry.clearance(JointId::LEFT_ANKLE);
        assert!((ankle - 0.039 * 1.75).abs() < 0.01, "{ankle}");
        // Standing: the pelvis is a leg length above the floor, far from sitting on it.
        let pelvis = geometry.height_above(JointId::PELVIS, &rest[0], 0.0);
        assert!(pelvis > 0.6, "{pelvis}");
    }
}
