use super::*;
use imuflow_body::GRAVITY_IN_MODEL_MPS2;
use imuflow_body::dynamics::{DynamicsData, NUM_DOFS, PointJacobian};
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

/// A trunk bent 20° forward while the reference's joint velocities say "stand still": the
/// local-rotation PD and the joint-position PD disagree, and the compromise leaves the bones below
/// the trunk short of their reference world orientation. The mean world-orientation error (deg) of
/// `bones` after 30 steps of `config`.
fn world_error_under_a_bent_trunk(config: PipConfig, bones: &[JointId]) -> f64 {
    let mut m = pip(config);
    m.set_state(standing_pose(&m, 0.0), DofVector::zeros());
    let mut r = standing_reference([0.9, 0.9]);
    r.pose.parent_from_joint[JointId::SPINE1.index()] =
        Rotation3::new(Vector3::new(20f64.to_radians(), 0.0, 0.0));
    let mut out = MotionEstimate::default();
    for _ in 0..30 {
        assert!(!m.step(&r, None, &mut out).unwrap().fallback);
    }
    let world = |pose: &Pose, j: JointId| {
        let mut fk = FkData::new();
        imuflow_body::forward_kinematics(&m.physics.body.skeleton, pose, &mut fk);
        fk.world_from_joint[j.index()]
    };
    bones
        .iter()
        .map(|&j| {
            world(&out.pose, j)
                .angle_to(&world(&r.pose, j))
                .to_degrees()
        })
        .sum::<f64>()
        / bones.len() as f64
}

#[test]
fn the_sensor_bone_rows_bring_the_instrumented_bones_to_their_world_orientation() {
    // The forearms and the head carry sensors below the bent trunk. The limb-bone rows are off,
    // so only the sensor-bone rows act.
    let sensor_bones = imuflow_body::Imu::SIX.map(|imu| imu.joint());
    let error = |coeff: f64| {
        let config = PipConfig {
            coeff_sensor_bone: coeff,
            coeff_limb_bone: 0.0,
            ..PipConfig::default()
        };
        world_error_under_a_bent_trunk(config, &sensor_bones)
    };
    let (without, with) = (error(0.0), error(1.0));
    eprintln!("sensor-bone world error: {without:.2}° without the rows, {with:.2}° with");
    assert!(without > 1.0, "the test needs a conflict: {without}°");
    assert!(
        with < 0.5 * without,
        "{with}° with the rows, {without}° without"
    );
}

#[test]
fn the_limb_bone_rows_bring_the_upper_limbs_to_their_world_orientation() {
    // The upper arms hang off the bent spine, the upper legs off the root. The sensor-bone rows
    // are off, so only the limb-bone rows act.
    let upper_limbs = imuflow_body::skeleton::SIP_JOINTS;
    let error = |coeff: f64| {
        let config = PipConfig {
            coeff_limb_bone: coeff,
            coeff_sensor_bone: 0.0,
            ..PipConfig::default()
        };
        world_error_under_a_bent_trunk(config, &upper_limbs)
    };
    let (without, with) = (error(0.0), error(1.0));
    eprintln!("upper-limb world error: {without:.2}° without the rows, {with:.2}° with");
    assert!(without > 0.5, "the test needs a conflict: {without}°");
    assert!(
        with < 0.7 * without,
        "{with}° with the rows, {without}° without"
    );
}

#[test]
fn solver_failures_publish_the_degraded_estimate_and_the_physics_continues_from_it() {
    // Every solution is "too large", so every step is the degraded estimate: the reference's
    // rotations, the root moved from where the physics stood by the network's root velocity.
    let mut m = pip(PipConfig {
        fallback_norm: 1.0,
        ..PipConfig::default()
    });
    let start = standing_pose(&m, 0.0);
    m.set_state(start.clone(), DofVector::from_element(0.1));
    let mut r = standing_reference([0.9, 0.9]);
    r.pose.parent_from_joint[JointId::RIGHT_ELBOW.index()] =
        Rotation3::new(Vector3::new(0.0, 0.7, 0.0));
    r.root_velocity_mps = Vector3::new(0.6, 0.0, 0.0);
    let mut out = MotionEstimate::default();
    let report = m.step(&r, None, &mut out).unwrap();
    assert!(report.fallback);
    // No previous reference after `set_state`: this one stands for it, so Eq. 25 (no stationary
    // joint) is the network's velocity: 0.6 m/s · dt along x. The joints rest.
    let want = start.root_in_world_m + Vector3::new(0.6 * DT_S, 0.0, 0.0);
    assert!((out.pose.root_in_world_m - want).norm() < 1e-12);
    assert_eq!(out.pose.parent_from_joint, r.pose.parent_from_joint);
    assert!((out.v.fixed_rows::<3>(0) - r.root_velocity_mps).norm() < 1e-12);
    assert!(out.v.rows(3, NUM_DOFS - 3).iter().all(|&w| w == 0.0));
    assert_eq!(out.tau, DofVector::zeros());
    // The physics continues from that estimate.
    assert_eq!(m.state().0, &out.pose);
    assert_eq!(m.state().1, &out.v);
    // A second failed frame moves on from the first: the elbow turns 0.3 rad more, the root
    // another 0.6 m/s · dt.
    let elbow = JointId::RIGHT_ELBOW;
    r.pose.parent_from_joint[elbow.index()] = Rotation3::new(Vector3::new(0.0, 1.0, 0.0));
    let first = out.pose.root_in_world_m;
    assert!(m.step(&r, None, &mut out).unwrap().fallback);
    let moved = out.pose.root_in_world_m - first;
    assert!(
        (moved - Vector3::new(0.6 * DT_S, 0.0, 0.0)).norm() < 1e-12,
        "{moved}"
    );
    assert_eq!(out.pose.parent_from_joint, r.pose.parent_from_joint);

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

/// A small deterministic generator (xorshift) for the random states below.
struct Rng(u64);

impl Rng {
    /// Uniform in [−1, 1).
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    fn vector(&mut self, scale: f64) -> Vector3<f64> {
        Vector3::new(self.next(), self.next(), self.next()) * scale
    }
}

/// Solve one QP with both formulations at a tight tolerance; assert equal optima; return the
/// reduced solution and the number of contact points.
fn compare_formulations(
    m: &Pip,
    pose: &Pose,
    v: &DofVector,
    reference: &Reference,
    contacts: &ContactSet,
    inequalities: bool,
) -> qp::Solution {
    use qp::Formulation;
    // No fallback threshold: the equivalence is checked on random states whose optima can be
    // larger than a real frame's (one reaches ‖x‖ = 1.09e4 with the limb-bone rows).
    let config = PipConfig {
        solver_tolerance: 1e-12,
        solver_max_iterations: 400,
        fallback_norm: f64::INFINITY,
        ..m.config.clone()
    };
    let mut data = DynamicsData::new();
    let mut solve = |formulation| {
        data.set_state(&m.physics.model, pose, v);
        let mut stats = SolveStats::default();
        let sol = qp::Qp::new()
            .solve_with(
                formulation,
                &m.physics,
                &config,
                &mut data,
                pose,
                reference,
                contacts,
                inequalities,
                &mut stats,
            )
            .unwrap_or_else(|| panic!("{formulation:?} failed: {stats:?}"));
        (sol, stats)
    };
    let (full, full_stats) = solve(Formulation::Full);
    let (reduced, reduced_stats) = solve(Formulation::Reduced);
    assert_eq!(full_stats.variables, reduced_stats.variables + NUM_DOFS);
    let close = |a: &[f64], b: &[f64], what: &str| {
        let scale = 1.0 + b.iter().map(|x| x * x).sum::<f64>().sqrt();
        let err = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt();
        assert!(
            err < 1e-6 * scale,
            "{what}: ‖reduced − full‖ = {err:e} (‖full‖ + 1 = {scale})"
        );
    };
    close(
        reduced.acceleration.as_slice(),
        full.acceleration.as_slice(),
        "v̇",
    );
    close(reduced.tau.as_slice(), full.tau.as_slice(), "τ");
    let nc = contacts.points().len();
    let flat = |s: &qp::Solution| -> Vec<f64> {
        s.forces[..nc]
            .iter()
            .flat_map(|f| [f.x, f.y, f.z])
            .collect()
    };
    close(&flat(&reduced), &flat(&full), "λ");
    reduced
}

#[test]
fn the_reduced_qp_has_the_full_formulations_optimum_on_random_states_with_contacts() {
    let m = pip(PipConfig::default());
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut fk = FkData::new();
    let mut data = DynamicsData::new();
    let mut seen_active_friction = false;
    for case in 0..8 {
        // A perturbed standing pose on the floor, a random velocity and a random reference.
        let mut pose = standing_pose(&m, 0.0);
        for i in 1..pose.parent_from_joint.len() {
            pose.parent_from_joint[i] = Rotation3::new(rng.vector(0.15));
        }
        place_on_floor(&m.physics, &mut pose, &FEET, &mut fk);
        let mut v = DofVector::zeros();
        for x in v.iter_mut() {
            *x = 0.5 * rng.next();
        }
        let mut r = standing_reference([0.5 + 0.5 * rng.next().abs(), 0.9]);
        for i in 0..r.pose.parent_from_joint.len() {
            r.pose.parent_from_joint[i] = Rotation3::new(rng.vector(0.3));
        }
        for j in r.joint_velocity_mps.iter_mut() {
            *j = rng.vector(1.0);
        }
        data.set_state(&m.physics.model, &pose, &v);
        let mut contacts = ContactSet::new();
        pip_contacts(
            &data.fk().joint_in_world_m,
            r.foot_contact_prob,
            &m.physics.geometry,
            &m.config.contact,
            &mut contacts,
        );
        if case % 2 == 1 {
            // A kneeling-like extra contact body: 4 points around the left knee (velocity rows (a)).
            let knee = data.fk().joint_in_world_m[JointId::LEFT_KNEE.index()];
            for (dx, dz) in [(0.1, 0.1), (0.1, -0.1), (-0.1, 0.1), (-0.1, -0.1)] {
                contacts
                    .push(imuflow_contact::ContactPoint {
                        joint: JointId::LEFT_KNEE,
                        position: knee + Vector3::new(dx, 0.0, dz),
                        force: Vector3::zeros(),
                    })
                    .unwrap();
            }
        }
        assert!(!contacts.points().is_empty(), "case {case}: no contact");
        let sol = compare_formulations(&m, &pose, &v, &r, &contacts, true);
        // Non-trivial: some friction-pyramid row is (nearly) active somewhere.
        let mu = m.config.friction;
        seen_active_friction |= sol.forces[..contacts.points().len()].iter().any(|f| {
            f.norm() > 1.0
                && (std::f64::consts::SQRT_2 * f.x.abs().max(f.z.abs()) - mu * f.y).abs()
                    < 1e-3 * f.norm()
        });
        // The unconstrained re-solve too.
        compare_formulations(&m, &pose, &v, &r, &contacts, false);
    }
    assert!(seen_active_friction, "no case had an active friction row");
}

#[test]
fn without_contact_points_the_foot_bounds_still_hold_and_match_the_full_formulation() {
    // 5 cm above the floor, falling and drifting, both feet "locked" (c = 0.9) but no contact point:
    // the QP has no λ, and the foot velocity bounds are constraints on v̇ alone.
    let m = pip(PipConfig::default());
    let pose = standing_pose(&m, 0.05);
    let mut v = DofVector::zeros();
    v[0] = 0.4;
    v[1] = -0.5;
    let mut r = standing_reference([0.9, 0.9]);
    r.pose.parent_from_joint[JointId::LEFT_KNEE.index()] =
        Rotation3::new(Vector3::new(0.8, 0.0, 0.0));
    let contacts = ContactSet::new();
    let sol = compare_formulations(&m, &pose, &v, &r, &contacts, true);
    let free = compare_formulations(&m, &pose, &v, &r, &contacts, false);
    let mut data = DynamicsData::new();
    data.set_state(&m.physics.model, &pose, &v);
    let mut jac = PointJacobian::zeros();
    let mut violated = 0.0f64;
    // The bounded joints are the contact rule's feet (SMPL 10/11).
    for foot in imuflow_contact::pip::FEET {
        data.point_jacobian(foot, &Vector3::zeros(), &mut jac);
        let vel = data.point_velocity(foot, &Vector3::zeros());
        let next = vel + jac * sol.acceleration * m.config.dt;
        // Locked: |v⁺_x|, |v⁺_z| ≤ th ≈ 1.2e-5 (and v⁺_y ≤ th + 1e-6).
        assert!(
            next.x.abs() < 2e-5 && next.z.abs() < 2e-5,
            "{foot:?}: {next}"
        );
        assert!(next.y < 2e-5, "{foot:?}: {next}");
        let next_free = vel + jac * free.acceleration * m.config.dt;
        violated = violated.max(next_free.x.abs()).max(next_free.y);
    }
    // Without the bounds the feet would move: they bind.
    assert!(violated > 0.01, "{violated}");
}
