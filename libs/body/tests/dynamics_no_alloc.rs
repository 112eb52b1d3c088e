//! Per-frame dynamics (state update, M, h, Jacobians, J̇v, inverse and forward dynamics, integration) must
//! not allocate once the workspace exists (counted with a wrapping global allocator; this file holds a
//! single test so no other test thread allocates while counting).

mod common;

use common::{Counting, allocations};

use imuflow_body::dynamics::{
    AngularJacobian, DofVector, DynamicsData, PointJacobian, RigidBodyModel, integrate,
};
use imuflow_body::rotation::Axis;
use imuflow_body::{BodyModel, BodyParams, JointId, Pose};
use nalgebra::Vector3;

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_frame_dynamics_allocates_nothing() {
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.8, 80.0).unwrap();
    let model = RigidBodyModel::new(&body);
    let mut data = DynamicsData::new();
    let mut jac = PointJacobian::zeros();
    let mut ang = AngularJacobian::zeros();
    let mut tau = DofVector::zeros();
    let mut a = DofVector::zeros();
    let mut pose = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
    let mut v = DofVector::from_fn(|r, _| (r as f64 * 0.3).sin());
    let before = allocations();
    let mut checksum = 0.0;
    for frame in 0..50 {
        pose.parent_from_joint[JointId::LEFT_KNEE.index()] = Axis::X.rotation(frame as f64 * 0.01);
        data.set_state(&model, &pose, &v);
        checksum += data.mass_matrix(&model)[(3, 3)];
        checksum += data.bias_forces(&model)[1];
        for j in [JointId::LEFT_FOOT, JointId::RIGHT_HAND, JointId::HEAD] {
            data.point_jacobian(j, &Vector3::new(0.0, 0.01, 0.0), &mut jac);
            data.angular_jacobian(j, &mut ang);
            checksum += jac[(1, 20)] + ang[(0, 9)] + data.point_jdot_v(j, &Vector3::zeros()).y;
        }
        checksum += data.kinetic_energy(&model) + data.potential_energy(&model);
        checksum += data.center_of_mass(&model).y;
        data.inverse_dynamics(&model, &a, &mut tau);
        data.forward_dynamics(&model, &DofVector::zeros(), &mut a)
            .unwrap();
        integrate(&mut pose, &mut v, &a, 1.0 / 60.0);
    }
    let after = allocations();
    assert!(checksum.is_finite());
    assert_eq!(
        after - before,
        0,
        "per-frame dynamics allocated {} times",
        after - before
    );
}
