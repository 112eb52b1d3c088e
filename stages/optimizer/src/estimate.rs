//! [`MotionEstimate`]: a method's result for one frame, and how it goes on the wire (`MotionFrame`).

use imuflow_body::dynamics::{DofVector, pose_to_q};
use imuflow_body::kinematics::FkData;
use imuflow_body::rotation::quat_wxyz_from_rotation;
use imuflow_body::{JointId, NUM_JOINTS, Pose};
use imuflow_graph::frames::MotionFrame;
use nalgebra::Vector3;

use crate::PhysicsBody;

/// The state after one frame plus what the method learned on the way. Coordinates of `v` and `tau`:
/// `imuflow_body::dynamics` (root linear velocity in M, then per joint the angular velocity relative to
/// its parent in its own frame).
#[derive(Clone, Debug, PartialEq)]
pub struct MotionEstimate {
    /// Pose with global translation (root joint position in M).
    pub pose: Pose,
    /// Generalized velocity.
    pub v: DofVector,
    /// Generalized force (root force, then joint torques); zero for methods without dynamics.
    pub tau: DofVector,
    /// Ground-reaction force acting on each joint (N, M).
    pub ground_reaction_force_n: [Vector3<f64>; NUM_JOINTS],
    /// Bit j set when joint j is in contact.
    pub contact_mask: u32,
    /// Proxy-surface height under each contact joint (m); 0 where no contact.
    pub surface_height_m: [f64; NUM_JOINTS],
    /// Residual force on the root the contacts could not explain (N, M).
    pub residual_root_force_n: Vector3<f64>,
}

impl Default for MotionEstimate {
    fn default() -> MotionEstimate {
        MotionEstimate {
            pose: Pose::default(),
            v: DofVector::zeros(),
            tau: DofVector::zeros(),
            ground_reaction_force_n: [Vector3::zeros(); NUM_JOINTS],
            contact_mask: 0,
            surface_height_m: [0.0; NUM_JOINTS],
            residual_root_force_n: Vector3::zeros(),
        }
    }
}

impl MotionEstimate {
    /// Write into a wire frame (the header is the caller's).
    pub fn write(&self, out: &mut MotionFrame) {
        for j in 0..NUM_JOINTS {
            out.local_pose_wxyz[j] =
                quat_wxyz_from_rotation(&self.pose.parent_from_joint[j]).map(|v| v as f32);
            out.ground_reaction_force_n[j] = self.ground_reaction_force_n[j].cast::<f32>().into();
        }
        out.root_position_m = self.pose.root_in_world_m.cast::<f32>().into();
        let q = pose_to_q(&self.pose);
        for i in 0..q.len() {
            out.q[i] = q[i] as f32;
            out.qdot[i] = self.v[i] as f32;
            out.tau[i] = self.tau[i] as f32;
        }
        out.contact_mask = self.contact_mask;
        out.surface_height_m = self.surface_height_m.map(|v| v as f32);
        out.residual_root_force_n = self.residual_root_force_n.cast::<f32>().into();
    }

    /// Read a wire frame back (the optimizer's own output arriving through a feedback edge, or a
    /// recording). Errors name the field.
    pub fn read(frame: &MotionFrame) -> Result<MotionEstimate, String> {
        let mut e = MotionEstimate {
            pose: Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m)
                .map_err(|e| e.to_string())?,
            ..MotionEstimate::default()
        };
        for j in 0..NUM_JOINTS {
            e.ground_reaction_force_n[j] = Vector3::from(frame.ground_reaction_force_n[j]).cast();
        }
        for i in 0..e.v.len() {
            e.v[i] = frame.qdot[i].into();
            e.tau[i] = frame.tau[i].into();
        }
        e.contact_mask = frame.contact_mask;
        e.surface_height_m = frame.surface_height_m.map(f64::from);
        e.residual_root_force_n = Vector3::from(frame.residual_root_force_n).cast();
        let finite =
            e.v.iter().all(|x| x.is_finite()) && e.surface_height_m.iter().all(|x| x.is_finite());
        if !finite {
            return Err("qdot or surface_height_m is not finite".into());
        }
        Ok(e)
    }
}

/// Place `pose` so that the lowest of `joints` rests on the floor (y = 0), keeping x and z: the first
/// frame of every method (GlobalPose reference §5.4 "First frame"; PIP starts from the network pose).
pub fn place_on_floor(physics: &PhysicsBody, pose: &mut Pose, joints: &[JointId], fk: &mut FkData) {
    let lowest = lowest_height(physics, pose, joints, fk);
    if lowest.is_finite() {
        pose.root_in_world_m.y -= lowest;
    }
}

/// Lift `pose` so that none of `joints` is below the floor (y = 0), keeping x and z; a pose already
/// clear of it stays where it is.
pub fn lift_out_of_floor(
    physics: &PhysicsBody,
    pose: &mut Pose,
    joints: &[JointId],
    fk: &mut FkData,
) {
    let lowest = lowest_height(physics, pose, joints, fk);
    if lowest.is_finite() && lowest < 0.0 {
        pose.root_in_world_m.y -= lowest;
    }
}

/// Height above the floor of the lowest ground point of `joints` in `pose` (negative: below it;
/// infinite without joints).
fn lowest_height(physics: &PhysicsBody, pose: &Pose, joints: &[JointId], fk: &mut FkData) -> f64 {
    imuflow_body::forward_kinematics(&physics.body.skeleton, pose, fk);
    joints
        .iter()
        .map(|&j| {
            physics
                .geometry
                .height_above(j, &fk.joint_in_world_m[j.index()], 0.0)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The joints a standing body can rest on when placed on the floor: ankles and feet.
pub const FEET: [JointId; 4] = [
    JointId::LEFT_ANKLE,
    JointId::RIGHT_ANKLE,
    JointId::LEFT_FOOT,
    JointId::RIGHT_FOOT,
];

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;
    use nalgebra::Rotation3;

    #[test]
    fn placing_the_t_pose_puts_the_root_at_its_rest_height_and_the_wire_round_trips() {
        let physics = PhysicsBody::new(1.75, 70.0).unwrap();
        let mut pose = Pose::t_pose(Vector3::new(0.3, 5.0, -1.0));
        let mut fk = FkData::new();
        place_on_floor(&physics, &mut pose, &FEET, &mut fk);
        let want = physics.body.rest_root_height_m;
        assert!((pose.root_in_world_m - Vector3::new(0.3, want, -1.0)).norm() < 1e-9);

        let mut e = MotionEstimate {
            pose,
            ..MotionEstimate::default()
        };
        e.pose.parent_from_joint[JointId::LEFT_KNEE.index()] =
            Rotation3::new(Vector3::new(0.5, 0.0, 0.0));
        e.v[7] = 1.25;
        e.tau[1] = 686.0;
        e.contact_mask = 1 << 10;
        let mut frame = MotionFrame::zeroed();
        e.write(&mut frame);
        // q carries the knee's rotation vector.
        assert!((frame.q[3 + 3 * 4] - 0.5).abs() < 1e-6);
        let back = MotionEstimate::read(&frame).unwrap();
        assert_eq!(back.contact_mask, e.contact_mask);
        assert!((back.v[7] - 1.25).abs() < 1e-6 && (back.tau[1] - 686.0).abs() < 1e-3);
        let angle = back.pose.parent_from_joint[4].angle_to(&e.pose.parent_from_joint[4]);
        assert!(angle < 1e-6, "{angle}");
    }
}
