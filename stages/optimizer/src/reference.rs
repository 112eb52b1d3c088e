//! [`Reference`]: the kinematics networks' estimate for one frame, decoded from the wire in f64.

use imuflow_body::{NUM_JOINTS, Pose};
use imuflow_graph::frames::{KinematicsFrame, NUM_STATIONARY_JOINTS};
use nalgebra::{Rotation3, Vector3};

/// What the networks say about one frame (see `KinematicsFrame` for the conventions).
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// Reference pose: local rotations, the root's in the world; `root_in_world_m` is zero (the networks
    /// give no translation).
    pub pose: Pose,
    /// Joint positions relative to the root joint, M axes (m).
    pub joint_position_rel_m: [Vector3<f64>; NUM_JOINTS],
    /// Joint velocities in M (m/s). PIP predicts all 24; GlobalPose only the root's (index 0).
    pub joint_velocity_mps: [Vector3<f64>; NUM_JOINTS],
    /// Probability that the [left, right] foot touches the ground.
    pub foot_contact_prob: [f64; 2],
    /// Probability that [pelvis, left foot, right foot, left hand, right hand] is stationary.
    pub stationary_prob: [f64; NUM_STATIONARY_JOINTS],
    /// Root velocity in M (m/s).
    pub root_velocity_mps: Vector3<f64>,
}

impl Default for Reference {
    fn default() -> Reference {
        Reference {
            pose: Pose::default(),
            joint_position_rel_m: [Vector3::zeros(); NUM_JOINTS],
            joint_velocity_mps: [Vector3::zeros(); NUM_JOINTS],
            foot_contact_prob: [0.0; 2],
            stationary_prob: [0.0; NUM_STATIONARY_JOINTS],
            root_velocity_mps: Vector3::zeros(),
        }
    }
}

impl Reference {
    /// Decode a frame. Errors name the field that is not finite or not a rotation.
    pub fn read(frame: &KinematicsFrame) -> Result<Reference, String> {
        let mut r = Reference {
            pose: Pose::from_wire(&frame.local_pose_wxyz, &[0.0; 3]).map_err(|e| e.to_string())?,
            ..Reference::default()
        };
        for j in 0..NUM_JOINTS {
            r.joint_position_rel_m[j] = finite3(&frame.joint_position_m[j], "joint_position_m", j)?;
            r.joint_velocity_mps[j] =
                finite3(&frame.joint_velocity_mps[j], "joint_velocity_mps", j)?;
        }
        r.foot_contact_prob = probabilities(&frame.foot_contact_prob, "foot_contact_prob")?;
        r.stationary_prob = probabilities(&frame.stationary_prob, "stationary_prob")?;
        r.root_velocity_mps = finite3(&frame.root_velocity_mps, "root_velocity_mps", 0)?;
        Ok(r)
    }

    /// Local rotation of joint `j` (the root's: world from pelvis).
    pub fn rotation(&self, j: usize) -> &Rotation3<f64> {
        &self.pose.parent_from_joint[j]
    }
}

fn finite3(v: &[f32; 3], field: &str, index: usize) -> Result<Vector3<f64>, String> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(Vector3::from(*v).cast())
    } else {
        Err(format!("{field}[{index}] is not finite: {v:?}"))
    }
}

fn probabilities<const N: usize>(p: &[f32; N], field: &str) -> Result<[f64; N], String> {
    match p.iter().position(|v| !(0.0..=1.0).contains(v)) {
        Some(i) => Err(format!("{field}[{i}] = {} is not a probability", p[i])),
        None => Ok(p.map(f64::from)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;

    #[test]
    fn decodes_rotations_and_rejects_garbage_by_field() {
        let mut frame = KinematicsFrame::zeroed();
        for q in frame.local_pose_wxyz.iter_mut() {
            *q = [1.0, 0.0, 0.0, 0.0];
        }
        // 90° about y for the root: [cos 45°, 0, sin 45°, 0].
        let h = std::f32::consts::FRAC_1_SQRT_2;
        frame.local_pose_wxyz[0] = [h, 0.0, h, 0.0];
        frame.foot_contact_prob = [0.9, 0.1];
        let r = Reference::read(&frame).unwrap();
        let z = r.rotation(0) * Vector3::z();
        assert!((z - Vector3::x()).norm() < 1e-6, "{z}");
        frame.joint_velocity_mps[3][1] = f32::NAN;
        assert!(
            Reference::read(&frame)
                .unwrap_err()
                .contains("joint_velocity_mps[3]")
        );
        frame.joint_velocity_mps[3][1] = 0.0;
        frame.stationary_prob[4] = 1.5;
        assert!(
            Reference::read(&frame)
                .unwrap_err()
                .contains("stationary_prob[4]")
        );
        frame.stationary_prob[4] = 0.5;
        frame.local_pose_wxyz[5] = [0.0; 4];
        assert!(
            Reference::read(&frame)
                .unwrap_err()
                .contains("local_pose_wxyz[5]")
        );
    }
}
