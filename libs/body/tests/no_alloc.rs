//! Per-frame kinematics must not allocate (Model/Data split): counted with a wrapping global allocator.
//! This file holds a single test so no other test thread allocates while counting.

mod common;

use common::{Counting, allocations};

use imuflow_body::kinematics::{
    FkData, Pose, forward_kinematics, global_to_local_rotations, imu_positions_in_world,
};
use imuflow_body::rotation::{Axis, rotation_from_r6d};
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_IMUS, NUM_JOINTS};
use nalgebra::{Rotation3, Vector3};

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_frame_kinematics_allocates_nothing() {
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.8, 80.0).unwrap();
    let mut fk = FkData::new();
    let mut local = [Rotation3::identity(); NUM_JOINTS];
    let mut imus = [Vector3::zeros(); NUM_IMUS];
    let mut pose = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
    let before = allocations();
    let mut checksum = 0.0;
    for frame in 0..100 {
        let a = frame as f64 * 0.01;
        pose.parent_from_joint[JointId::LEFT_KNEE.index()] = Axis::X.rotation(a);
        pose.parent_from_joint[JointId::LEFT_ELBOW.index()] =
            rotation_from_r6d(&[a.cos(), a.sin(), 0.0, -a.sin(), a.cos(), 0.0]);
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        global_to_local_rotations(&fk.world_from_joint, &mut local);
        imu_positions_in_world(&body, &fk, &mut imus);
        checksum += imus[0].x + fk.position(JointId::LEFT_ANKLE).z;
    }
    let after = allocations();
    assert!(checksum.is_finite());
    assert_eq!(
        after - before,
        0,
        "per-frame kinematics allocated {} times",
        after - before
    );
}
