//! Forward and inverse kinematics on the 24-joint skeleton.
//!
//! Model/Data split (pinocchio style): the [`Skeleton`] is immutable, [`FkData`] is a workspace allocated
//! once and overwritten every frame, and the algorithms are free functions that allocate nothing.
//! Following the reference `ParametricModel` (§0): joint i's local transform is `(R_local[i], bone[i])` and
//! `root_in_world_m` is the world position of the root joint itself.

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::body_model::BodyModel;
use crate::skeleton::{Imu, JointId, NUM_IMUS, NUM_JOINTS, Skeleton};

/// `S·R·S` with S the reflection x → −x: the rotation `r` seen in a mirror across the x = 0
/// plane (a rotation again: S is its own inverse and det S² = 1). Global rotations of a pose
/// mirror joint by joint this way, and so do local ones, since `S·(A·B)·S = (S·A·S)·(S·B·S)`.
pub fn mirror_rotation(r: &Rotation3<f64>) -> Rotation3<f64> {
    let m = r.matrix();
    // Conjugating by diag(−1, 1, 1) negates the entries that mix x with y or z.
    Rotation3::from_matrix_unchecked(Matrix3::new(
        m[(0, 0)],
        -m[(0, 1)],
        -m[(0, 2)],
        -m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        -m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
    ))
}

/// `S·v` with S the reflection x → −x: a position, velocity or acceleration seen in the mirror
/// (an angular velocity, a pseudovector, mirrors as `−S·ω`).
pub fn mirror_vector(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(-v.x, v.y, v.z)
}

/// One frame of body pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    /// Local joint rotations `parent_from_joint`, indexed by [`JointId::index`]; the root's entry is its
    /// global rotation `world_from_pelvis`. Identity everywhere is the T-pose facing +z.
    pub parent_from_joint: [Rotation3<f64>; NUM_JOINTS],
    /// World position of the root joint (m, frame M).
    pub root_in_world_m: Vector3<f64>,
}

impl Pose {
    /// The T-pose (all identity) with the root at `root_in_world_m`.
    pub fn t_pose(root_in_world_m: Vector3<f64>) -> Pose {
        Pose {
            parent_from_joint: [Rotation3::identity(); NUM_JOINTS],
            root_in_world_m,
        }
    }

    /// The pose reflected across the body's sagittal plane (x → −x in the model frame, x the
    /// body's left): each joint takes its mirror joint's rotation conjugated by the reflection,
    /// [`mirror_rotation`], and the root moves to (−x, y, z). On a left–right symmetric body
    /// model the joint positions are the reflected positions of the mirror joints.
    pub fn mirrored(&self) -> Pose {
        let mut mirrored = Pose::t_pose(mirror_vector(&self.root_in_world_m));
        for j in JointId::all() {
            mirrored.parent_from_joint[j.index()] =
                mirror_rotation(&self.parent_from_joint[j.mirror().index()]);
        }
        mirrored
    }

    /// A pose from its wire form (`KinematicsFrame`/`MotionFrame`: per joint the local rotation as an
    /// f32 quaternion `[w, x, y, z]`, and the root position in m). Errors name the field that is not a
    /// rotation or not finite.
    pub fn from_wire(
        local_pose_wxyz: &[[f32; 4]; NUM_JOINTS],
        root_in_world_m: &[f32; 3],
    ) -> Result<Pose, WirePoseError> {
        let mut pose = Pose::t_pose(Vector3::from(*root_in_world_m).cast());
        if !pose.root_in_world_m.iter().all(|v| v.is_finite()) {
            return Err(WirePoseError::Root(*root_in_world_m));
        }
        for (j, q) in local_pose_wxyz.iter().enumerate() {
            let q = q.map(f64::from);
            pose.parent_from_joint[j] = crate::rotation::rotation_from_quat_wxyz(&q)
                .ok_or(WirePoseError::Rotation { joint: j, wxyz: q })?;
        }
        Ok(pose)
    }

    /// Whether every number in the pose is finite.
    pub fn is_finite(&self) -> bool {
        self.root_in_world_m.iter().all(|v| v.is_finite())
            && self
                .parent_from_joint
                .iter()
                .all(|r| r.matrix().iter().all(|v| v.is_finite()))
    }
}

impl Default for Pose {
    fn default() -> Pose {
        Pose::t_pose(Vector3::zeros())
    }
}

/// A wire pose that is not a pose ([`Pose::from_wire`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum WirePoseError {
    #[error("local_pose_wxyz[{joint}] is not a rotation: {wxyz:?}")]
    Rotation { joint: usize, wxyz: [f64; 4] },
    #[error("root_position_m is not finite: {0:?}")]
    Root([f32; 3]),
}

/// Output workspace of [`forward_kinematics`]; allocate once and reuse.
#[derive(Clone, Debug, PartialEq)]
pub struct FkData {
    /// Global joint rotations `world_from_joint` (frame M).
    pub world_from_joint: [Rotation3<f64>; NUM_JOINTS],
    /// Joint positions in the world (m, frame M).
    pub joint_in_world_m: [Vector3<f64>; NUM_JOINTS],
}

impl FkData {
    /// A workspace holding the T-pose at the origin.
    pub fn new() -> FkData {
        FkData {
            world_from_joint: [Rotation3::identity(); NUM_JOINTS],
            joint_in_world_m: [Vector3::zeros(); NUM_JOINTS],
        }
    }

    /// Global rotation of `joint`.
    pub fn world_from(&self, joint: JointId) -> &Rotation3<f64> {
        &self.world_from_joint[joint.index()]
    }

    /// World position of `joint` (m).
    pub fn position(&self, joint: JointId) -> &Vector3<f64> {
        &self.joint_in_world_m[joint.index()]
    }
}

impl Default for FkData {
    fn default() -> FkData {
        FkData::new()
    }
}

/// Forward kinematics: local rotations + root position -> global rotations and joint positions.
/// Allocation-free; overwrites all of `out`.
pub fn forward_kinematics(skeleton: &Skeleton, pose: &Pose, out: &mut FkData) {
    for j in JointId::all() {
        let i = j.index();
        match j.parent() {
            None => {
                out.world_from_joint[i] = pose.parent_from_joint[i];
                out.joint_in_world_m[i] = pose.root_in_world_m;
            }
            Some(p) => {
                let world_from_parent = out.world_from_joint[p.index()];
                out.world_from_joint[i] = world_from_parent * pose.parent_from_joint[i];
                out.joint_in_world_m[i] = out.joint_in_world_m[p.index()]
                    + world_from_parent * skeleton.offset_in_parent_m(j);
            }
        }
    }
}

/// Local to global rotations only (no positions): `world_from_joint[i] = world_from_joint[parent] · parent_from_joint[i]`.
pub fn local_to_global_rotations(
    parent_from_joint: &[Rotation3<f64>; NUM_JOINTS],
    world_from_joint: &mut [Rotation3<f64>; NUM_JOINTS],
) {
    for j in JointId::all() {
        let i = j.index();
        world_from_joint[i] = match j.parent() {
            None => parent_from_joint[i],
            Some(p) => world_from_joint[p.index()] * parent_from_joint[i],
        };
    }
}

/// Inverse kinematics of rotations (reference `inverse_kinematics_R`):
/// `parent_from_joint[i] = world_from_joint[parent]ᵀ · world_from_joint[i]`; the root keeps its global rotation.
pub fn global_to_local_rotations(
    world_from_joint: &[Rotation3<f64>; NUM_JOINTS],
    parent_from_joint: &mut [Rotation3<f64>; NUM_JOINTS],
) {
    for j in JointId::all() {
        let i = j.index();
        parent_from_joint[i] = match j.parent() {
            None => world_from_joint[i],
            Some(p) => world_from_joint[p.index()].transpose() * world_from_joint[i],
        };
    }
}

/// IMU positions in the world (m, frame M) from an FK result, in IMU order.
pub fn imu_positions_in_world(body: &BodyModel, fk: &FkData, out: &mut [Vector3<f64>; NUM_IMUS]) {
    for imu in Imu::SIX {
        let j = imu.joint();
        out[imu.index()] =
            fk.position(j) + fk.world_from(j) * body.imu_offsets_in_joint_m[imu.index()];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body_model::BodyParams;
    use crate::rotation::{Axis, angle_between};
    use crate::test_util::random_rotations;
    use approx::assert_relative_eq;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn wire_poses_decode_and_bad_fields_are_named() {
        let mut wxyz = [[1.0f32, 0.0, 0.0, 0.0]; NUM_JOINTS];
        let h = std::f32::consts::FRAC_1_SQRT_2;
        wxyz[4] = [h, h, 0.0, 0.0]; // 90° about x
        let pose = Pose::from_wire(&wxyz, &[0.1, 0.9, -0.2]).unwrap();
        let y = pose.parent_from_joint[4] * Vector3::y();
        assert!((y - Vector3::z()).norm() < 1e-6, "{y}");
        assert!((pose.root_in_world_m - Vector3::new(0.1, 0.9, -0.2)).norm() < 1e-6);
        wxyz[7] = [0.0; 4];
        let err = Pose::from_wire(&wxyz, &[0.0; 3]).unwrap_err().to_string();
        assert!(
            err.starts_with("local_pose_wxyz[7] is not a rotation"),
            "{err}"
        );
        let err = Pose::from_wire(&wxyz, &[f32::NAN, 0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("root_position_m is not finite"), "{err}");
    }

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.741, 73.0).unwrap()
    }

    #[test]
    fn fk_of_a_hand_built_pose_matches_hand_computed_positions() {
        let body = body();
        let sk = &body.skeleton;
        let hip_x = sk.offset_in_parent_m(JointId::LEFT_HIP).x;
        let thigh = -sk.offset_in_parent_m(JointId::LEFT_KNEE).y;
        let shank = -sk.offset_in_parent_m(JointId::LEFT_ANKLE).y;
        let mut pose = Pose::t_pose(Vector3::new(1.0, 2.0, 3.0));
        // Root turned 90° about y: the body faces +x, its left (+x) points to −z.
        pose.parent_from_joint[JointId::ROOT.index()] = Axis::Y.rotation(FRAC_PI_2);
        // Knee flexed 90° about x: the shank's −y becomes −z in the thigh frame.
        pose.parent_from_joint[JointId::LEFT_KNEE.index()] = Axis::X.rotation(FRAC_PI_2);
        let mut fk = FkData::new();
        forward_kinematics(sk, &pose, &mut fk);

        let hip = Vector3::new(1.0, 2.0, 3.0 - hip_x);
        assert_relative_eq!(*fk.position(JointId::LEFT_HIP), hip, epsilon = 1e-12);
        let knee = hip + Vector3::new(0.0, -thigh, 0.0);
        assert_relative_eq!(*fk.position(JointId::LEFT_KNEE), knee, epsilon = 1e-12);
        // Shank direction: Ry(90°)·Rx(90°)·(0,−1,0) = Ry(90°)·(0,0,−1) = (−1,0,0).
        let ankle = knee + Vector3::new(-shank, 0.0, 0.0);
        assert_relative_eq!(*fk.position(JointId::LEFT_ANKLE), ankle, epsilon = 1e-12);
        // The right leg is untouched: straight down below the right hip.
        let r_hip = *fk.position(JointId::RIGHT_HIP);
        assert_relative_eq!(r_hip, Vector3::new(1.0, 2.0, 3.0 + hip_x), epsilon = 1e-12);
        assert_relative_eq!(
            fk.position(JointId::RIGHT_ANKLE).y,
            r_hip.y - thigh - shank,
            epsilon = 1e-12
        );
    }

    #[test]
    fn bone_lengths_are_preserved_for_random_poses() {
        let body = body();
        let rots = random_rotations(NUM_JOINTS * 5, 21);
        let mut fk = FkData::new();
        for chunk in rots.chunks(NUM_JOINTS) {
            let mut pose = Pose::t_pose(Vector3::new(0.3, 0.9, -2.0));
            pose.parent_from_joint.copy_from_slice(chunk);
            forward_kinematics(&body.skeleton, &pose, &mut fk);
            for j in JointId::all() {
                if let Some(p) = j.parent() {
                    let d = (fk.position(j) - fk.position(p)).norm();
                    assert_relative_eq!(
                        d,
                        body.skeleton.offset_in_parent_m(j).norm(),
                        epsilon = 1e-12
                    );
                }
            }
        }
    }

    #[test]
    fn ik_inverts_fk_rotations() {
        let body = body();
        let rots = random_rotations(NUM_JOINTS, 33);
        let mut pose = Pose::default();
        pose.parent_from_joint.copy_from_slice(&rots);
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        let mut local = [Rotation3::identity(); NUM_JOINTS];
        global_to_local_rotations(&fk.world_from_joint, &mut local);
        for j in JointId::all() {
            assert!(
                angle_between(&local[j.index()], &rots[j.index()]) < 1e-9,
                "{j}"
            );
        }
        let mut global = [Rotation3::identity(); NUM_JOINTS];
        local_to_global_rotations(&local, &mut global);
        for j in JointId::all() {
            assert!(angle_between(&global[j.index()], &fk.world_from_joint[j.index()]) < 1e-9);
        }
    }

    #[test]
    fn imu_positions_follow_their_bones() {
        let body = body();
        let mut pose = Pose::t_pose(Vector3::zeros());
        // Left elbow bent 90° forward: forearm (+x) rotates about −y towards +z.
        pose.parent_from_joint[JointId::LEFT_ELBOW.index()] = Axis::Y.rotation(-FRAC_PI_2);
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        let mut imus = [Vector3::zeros(); NUM_IMUS];
        imu_positions_in_world(&body, &fk, &mut imus);
        let elbow = fk.position(JointId::LEFT_ELBOW);
        let o = body.imu_offsets_in_joint_m[Imu::LeftForearm.index()];
        // (ox, oy, 0) rotated by −90° about y -> (0, oy, ox).
        assert_relative_eq!(
            imus[0],
            elbow + Vector3::new(0.0, o.y, o.x),
            epsilon = 1e-12
        );
        assert!(fk.position(JointId::LEFT_WRIST).z > elbow.z + 0.2);
    }
}
