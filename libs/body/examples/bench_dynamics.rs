//! Per-call timings of the dynamics (release build):
//!
//! ```sh
//! cargo run --release -p imuflow-body --example bench_dynamics
//! ```
//!
//! Prints the median over repeated passes of 200 random states of: `set_state`, `M` (CRBA), `h` (RNEA),
//! 10 point Jacobians, 10 `J̇·v`, inverse dynamics, forward dynamics, and the optimizer's per-frame bundle
//! `set_state + M + h + 10 J + 10 J̇·v`.

use std::hint::black_box;
use std::time::Instant;

use imuflow_body::dynamics::{DofVector, DynamicsData, PointJacobian, RigidBodyModel};
use imuflow_body::{BodyModel, BodyParams, JointId, Pose};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

const STATES: usize = 200;

/// Pose, velocity and generalized force of one benchmark state.
type State = (Pose, DofVector, DofVector);
const PASSES: usize = 25;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let body = BodyModel::new(&BodyParams::builtin()?, 1.741, 73.0)?;
    let model = RigidBodyModel::new(&body);
    let mut data = DynamicsData::new();
    let mut rng = StdRng::seed_from_u64(7);
    let mut normal = move || rng.sample::<f64, _>(StandardNormal);
    let states: Vec<State> = (0..STATES)
        .map(|_| {
            let mut pose = Pose::t_pose(Vector3::new(normal(), normal(), normal()));
            for r in pose.parent_from_joint.iter_mut() {
                let q = Quaternion::new(normal(), normal(), normal(), normal());
                *r = UnitQuaternion::new_normalize(q).to_rotation_matrix();
            }
            let v = DofVector::from_fn(|_, _| normal());
            let tau = DofVector::from_fn(|_, _| 10.0 * normal());
            (pose, v, tau)
        })
        .collect();
    // The ten points an optimizer typically needs: GlobalPose's five contact joints and the six IMU
    // joints minus the pelvis (already listed).
    let points: [(JointId, Vector3<f64>); 10] = [
        (JointId::PELVIS, Vector3::zeros()),
        (JointId::LEFT_FOOT, Vector3::zeros()),
        (JointId::RIGHT_FOOT, Vector3::zeros()),
        (JointId::LEFT_HAND, Vector3::zeros()),
        (JointId::RIGHT_HAND, Vector3::zeros()),
        (JointId::LEFT_ELBOW, Vector3::new(0.1, 0.0, 0.0)),
        (JointId::RIGHT_ELBOW, Vector3::new(-0.1, 0.0, 0.0)),
        (JointId::LEFT_KNEE, Vector3::new(0.0, -0.2, 0.05)),
        (JointId::RIGHT_KNEE, Vector3::new(0.0, -0.2, 0.05)),
        (JointId::HEAD, Vector3::new(0.0, 0.1, 0.0)),
    ];
    let mut jac = PointJacobian::zeros();
    let mut out = DofVector::zeros();

    let mut bench = |name: &str, f: &mut dyn FnMut(&mut DynamicsData, &State)| {
        let mut per_call = Vec::with_capacity(PASSES);
        for _ in 0..PASSES {
            let t0 = Instant::now();
            for s in &states {
                f(&mut data, s);
            }
            per_call.push(t0.elapsed().as_secs_f64() * 1e6 / STATES as f64);
        }
        per_call.sort_by(f64::total_cmp);
        println!(
            "{name:44} median {:8.2} µs   min {:8.2} µs",
            per_call[PASSES / 2],
            per_call[0]
        );
    };
    println!("imuflow-body dynamics, {STATES} random states × {PASSES} passes, per call:");
    bench("set_state (FK, velocities)", &mut |d, (p, v, _)| {
        d.set_state(&model, p, v)
    });
    bench("set_state + mass_matrix (CRBA)", &mut |d, (p, v, _)| {
        d.set_state(&model, p, v);
        black_box(d.mass_matrix(&model));
    });
    bench("set_state + bias_forces (RNEA)", &mut |d, (p, v, _)| {
        d.set_state(&model, p, v);
        black_box(d.bias_forces(&model));
    });
    bench("set_state + 10 point Jacobians", &mut |d, (p, v, _)| {
        d.set_state(&model, p, v);
        for (j, pt) in &points {
            d.point_jacobian(*j, pt, &mut jac);
            black_box(&jac);
        }
    });
    bench("set_state + 10 J̇·v", &mut |d, (p, v, _)| {
        d.set_state(&model, p, v);
        for (j, pt) in &points {
            black_box(d.point_jdot_v(*j, pt));
        }
    });
    bench(
        "set_state + inverse_dynamics (RNEA)",
        &mut |d, (p, v, tau)| {
            d.set_state(&model, p, v);
            d.inverse_dynamics(&model, tau, &mut out);
            black_box(&out);
        },
    );
    bench("set_state + forward_dynamics (M, h, LᵀDL)", &mut |d,
                                                               (
        p,
        v,
        tau,
    )| {
        d.set_state(&model, p, v);
        if d.forward_dynamics(&model, tau, &mut out).is_ok() {
            black_box(&out);
        }
    });
    bench(
        "per frame: set_state + M + h + 10 J + 10 J̇·v",
        &mut |d, (p, v, _)| {
            d.set_state(&model, p, v);
            black_box(d.mass_matrix(&model));
            black_box(d.bias_forces(&model));
            for (j, pt) in &points {
                d.point_jacobian(*j, pt, &mut jac);
                black_box(&jac);
                black_box(d.point_jdot_v(*j, pt));
            }
        },
    );
    Ok(())
}
