use super::*;
use imuflow_body::GRAVITY_IN_MODEL_MPS2;
use imuflow_body::dynamics::{DynamicsData, PointJacobian};
use nalgebra::Rotation3;

fn pip(config: PipConfig) -> Pip {
    Pip::new(PhysicsBody::new(1.75, 70.0).unwrap(), config).unwrap()
}

fn standing_reference(foot: [f64; 2]) -> Reference {
    Reference {
        foot_contact_prob: foot,
        ..Reference::default()
    }
}

fn standing_pose(p: &Pip, dy: f64) -> Pose {
    Pose::t_pose(Vector3::new(
        0.0,
        p.physics.body.rest_root_height_m + dy,
        0.0,
    ))
}

#[test]
fn position_pd_joints_are_smpl_0_to_21_without_the_feet() {
    let ids: Vec<usize> = POSITION_PD_JOINTS.iter().map(|j| j.index()).collect();
    let want: Vec<usize> = (0..22).filter(|&i| i != 10 && i != 11).collect();
    assert_eq!(ids, want);
}

#[test]
fn standing_still_the_body_stays_and_the_feet_carry_its_weight_inside_the_pyramid() {
    let mut m = pip(PipConfig::default());
    let r = standing_reference([0.9, 0.9]);
    let mut out = MotionEstimate::default();
    let first = m.step(&r, None, &mut out).unwrap();
    assert!(!first.fallback);
    let start = out.pose.root_in_world_m;
    assert!((start.y - m.physics.body.rest_root_height_m).abs() < 1e-9);
    for frame in 0..60 {
        let report = m.step(&r, None, &mut out).unwrap();
        assert!(!report.fallback, "frame {frame}");
    }
    let drift = (out.pose.root_in_world_m - start).norm();
    assert!(drift < 0.01, "root drift {drift} m");
    // Both feet, 4 points each.
    assert_eq!(
        out.contact_mask,
        (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index())
    );
    assert_eq!(m.contacts().points().len(), 8);
    // Static equilibrium: the ground carries m·g (the root's penalised virtual force takes the rest).
    let weight = m.physics.model.total_mass_kg() * 9.81;
    let grf: Vector3<f64> = out.ground_reaction_force_n.iter().sum();
    assert!(
        (grf.y - weight).abs() < 0.05 * weight,
        "vertical GRF {} vs weight {weight}",
        grf.y
    );
    // The residual root force is the rest of the weight.
    assert!((grf.y + out.residual_root_force_n.y - weight).abs() < 0.02 * weight);
    let mu = m.config.friction;
    for p in m.contacts().points() {
        let f = p.force;
        let slack = 1e-6 * (1.0 + f.norm());
        assert!(f.y >= -slack, "{f}");
        assert!(
            std::f64::consts::SQRT_2 * f.x.abs() <= mu * f.y + slack,
            "{f}"
        );
        assert!(
            std::f64::consts::SQRT_2 * f.z.abs() <= mu * f.y + slack,
            "{f}"
        );
    }
}

#[test]
fn a_dropped_body_without_contacts_falls_with_gravity() {
    let mut m = pip(PipConfig::default());
    let start = standing_pose(&m, 0.10);
    m.set_state(start.clone(), DofVector::zeros());
    let g = -GRAVITY_IN_MODEL_MPS2.y;
    let dt = m.config.dt;
    let mut out = MotionEstimate::default();
    let n = 5;
    for k in 0..n {
        // The networks see a free fall: every joint should be at −g·(k+1)·dt after this step.
        let mut r = standing_reference([0.0, 0.0]);
        r.joint_velocity_mps = [Vector3::new(0.0, -g * (k + 1) as f64 * dt, 0.0); 24];
        let report = m.step(&r, None, &mut out).unwrap();
        assert!(!report.fallback);
        assert_eq!(out.contact_mask, 0, "10 cm above the floor, no contact");
    }
    // Semi-implicit Euler under g: drop = g·dt²·n(n+1)/2, velocity = −g·n·dt.
    let drop = start.root_in_world_m.y - out.pose.root_in_world_m.y;
    let want = g * dt * dt * (n * (n + 1)) as f64 / 2.0;
    assert!((drop - want).abs() < 0.05 * want, "drop {drop} vs {want}");
    assert!((out.v[1] + g * n as f64 * dt).abs() < 0.05 * g * n as f64 * dt);
    assert!(out.ground_reaction_force_n.iter().all(|f| f.norm() == 0.0));
}

#[test]
fn the_solution_satisfies_the_equation_of_motion() {
    let mut m = pip(PipConfig::default());
    m.set_state(standing_pose(&m, 0.0), DofVector::zeros());
    let mut r = standing_reference([0.0, 0.9]);
    r.pose.parent_from_joint[JointId::LEFT_KNEE.index()] =
        Rotation3::new(Vector3::new(0.5, 0.0, 0.0));
    r.joint_velocity_mps[JointId::LEFT_HAND.index()] = Vector3::new(0.3, 0.0, 0.0);
    let mut out = MotionEstimate::default();
    let mut data = DynamicsData::new();
    for _ in 0..4 {
        let (pose0, v0) = (m.state().0.clone(), *m.state().1);
        let report = m.step(&r, None, &mut out).unwrap();
        assert!(!report.fallback);
        assert!(!m.contacts().points().is_empty());
        let a = (out.v - v0) / m.config.dt;
        data.set_state(&m.physics.model, &pose0, &v0);
        let h = *data.bias_forces(&m.physics.model);
        let mut residual = data.mass_matrix(&m.physics.model) * a + h - out.tau;
        let mut jac = PointJacobian::zeros();
        for p in m.contacts().points() {
            let i = p.joint.index();
            let local = data.fk().world_from_joint[i].inverse()
                * (p.position - data.fk().joint_in_world_m[i]);
            data.point_jacobian(p.joint, &local, &mut jac);
            residual -= jac.transpose() * p.force;
        }
        assert!(
            residual.norm() < 1e-6,
            "‖M·a + h − τ − Jᵀλ‖ = {}",
            residual.norm()
        );
        // Non-trivial: forces and torques are actually there.
        assert!(out.tau.norm() > 1.0);
    }
}

#[test]
fn a_bent_knee_reference_is_tracked() {
    let mut m = pip(PipConfig::default());
    m.set_state(standing_pose(&m, 0.0), DofVector::zeros());
    // Left knee flexed 30° (about +x the shank swings backwards), left foot free, right foot planted.
    let mut r = standing_reference([0.0, 0.9]);
    let knee = JointId::LEFT_KNEE.index();
    r.pose.parent_from_joint[knee] = Rotation3::new(Vector3::new(30f64.to_radians(), 0.0, 0.0));
    let mut out = MotionEstimate::default();
    for _ in 0..30 {
        assert!(!m.step(&r, None, &mut out).unwrap().fallback);
    }
    let err = out.pose.parent_from_joint[knee]
        .angle_to(&r.pose.parent_from_joint[knee])
        .to_degrees();
    assert!(err < 2.0, "knee error {err}°");
    // The planted foot stayed put (locked by the c ≥ 0.85 bounds).
    let root = (out.pose.root_in_world_m - standing_pose(&m, 0.0).root_in_world_m).norm();
    assert!(root < 0.05, "{root}");
}

#[test]
fn solver_failures_fall_back_instead_of_panicking() {
    // Every solution is "too large": both the QP and the unconstrained re-solve fail, so the step
    // follows the reference kinematically at the current root position, at rest.
    let mut m = pip(PipConfig {
        fallback_norm: 1.0,
        ..PipConfig::default()
    });
    let start = standing_pose(&m, 0.0);
    m.set_state(start.clone(), DofVector::from_element(0.1));
    let mut r = standing_reference([0.9, 0.9]);
    r.pose.parent_from_joint[JointId::RIGHT_ELBOW.index()] =
        Rotation3::new(Vector3::new(0.0, 0.7, 0.0));
    let mut out = MotionEstimate::default();
    let report = m.step(&r, None, &mut out).unwrap();
    assert!(report.fallback);
    assert_eq!(m.last_solve().unwrap().solves, 2);
    assert_eq!(out.pose.root_in_world_m, start.root_in_world_m);
    assert_eq!(out.pose.parent_from_joint, r.pose.parent_from_joint);
    assert_eq!(out.v, DofVector::zeros());

    // Non-finite network output: no panic, a flagged frame, a finite state.
    let mut m = pip(PipConfig::default());
    m.set_state(start, DofVector::zeros());
    let mut r = standing_reference([0.9, 0.9]);
    r.joint_velocity_mps[3].x = f64::NAN;
    let report = m.step(&r, None, &mut out).unwrap();
    assert!(report.fallback);
    assert!(out.pose.is_finite() && out.v.iter().all(|x| x.is_finite()));
    // And it recovers on the next good frame.
    let report = m
        .step(&standing_reference([0.9, 0.9]), None, &mut out)
        .unwrap();
    assert!(!report.fallback);
}

#[test]
fn a_given_contact_set_is_used_and_reset_restarts_from_the_reference() {
    let mut m = pip(PipConfig::default());
    let r = standing_reference([0.9, 0.9]);
    let mut out = MotionEstimate::default();
    m.step(&r, None, &mut out).unwrap();
    // An empty set from the contact stage: no contact forces, the root's virtual force holds the body.
    let empty = ContactSet::new();
    m.step(&r, Some(&empty), &mut out).unwrap();
    assert_eq!(out.contact_mask, 0);
    assert!(out.ground_reaction_force_n.iter().all(|f| f.norm() == 0.0));
    assert!(out.residual_root_force_n.y > 0.5 * m.physics.model.total_mass_kg() * 9.81);
    m.reset();
    let mut lifted = standing_reference([0.9, 0.9]);
    lifted.pose.root_in_world_m = Vector3::new(0.0, 3.0, 0.0);
    m.step(&lifted, None, &mut out).unwrap();
    assert!((out.pose.root_in_world_m.y - m.physics.body.rest_root_height_m).abs() < 1e-9);
    assert_eq!(out.v, DofVector::zeros());
}
