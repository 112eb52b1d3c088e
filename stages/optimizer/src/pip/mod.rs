//! PIP's dual PD controller and QP (CVPR 2022 §3.2, Eq. 3–13; reference §5.2), solved on its
//! reduced (τ-free, dual) form by a dense interior-point method, clarabel as fallback and reference.
//!
//! # Per frame
//!
//! State `(q, v)` in `imuflow_body::dynamics` coordinates (root position + local rotations; root linear
//! velocity in M, then per joint the angular velocity relative to its parent in its own frame).
//!
//! 1. **Contacts** (Eq. 7–8): the contact stage's set (PIP's rule on this state, [`imuflow_contact::pip`]),
//!    or, when the step gets none, the same rule evaluated here.
//! 2. **QP** over `x = [v̇ (75), λ (3 per contact point, world forces on the body), τ (75)]` (solved
//!    with τ eliminated, see "Solver" below), minimising
//!    `Σ ½‖A_i·x − b_i‖²`:
//!    - joint-rotation PD (Eq. 3/5), every joint including the root's rotation, weight 1:
//!      `v̇_j ≈ kp_rotation·log(R_cur,jᵀ·R_ref,j) − kd_rotation·ω_j`;
//!    - joint-position PD from the predicted joint velocities (Eq. 4/6), SMPL joints 0..21 except the
//!      feet 10/11, weight [`PipConfig::coeff_joint_velocity`]:
//!      `J_j·v̇ ≈ kp_position·v_ref,j·dt − kd_position·v_j − J̇_j·v` (= 60·(v_ref − v) with the defaults;
//!      `v_ref` is the networks' world-frame joint velocity, reference §2.2);
//!    - instrumented bones' world orientation (imuflow, not PIP), the six bones that carry an IMU,
//!      weight [`PipConfig::coeff_sensor_bone`]: `J_ω,j·v̇ ≈ kp_rotation·e_j − kd_rotation·ω_j −
//!      J̇_ω,j·v`, `e_j` the world-axes rotation from the current to the reference orientation.
//!      The reference carries those bones at their calibrated measurement (the kinematics stage
//!      imposes it); with local-rotation PD alone the errors of every joint above a bone added up,
//!      and PIP's output left its sensors by 7.0° on the holdout split (4.9° with these rows);
//!    - the same rows on the upper legs and upper arms (imuflow, not PIP), weight
//!      [`PipConfig::coeff_limb_bone`]: the kinematics stage sets them from the lower bones'
//!      sensors through the anatomical knee and elbow, and with local-rotation PD the physics root's
//!      and spine's departures turned them (SIP on 60 validation clips 6.79 -> 6.59°);
//!    - "Signorini" force penalty (reference §5.2 cost 3): `coeff_lambda·max(height, 0.005)·λ_k ≈ 0`
//!      per point, height = the point's height above its surface;
//!    - torque regulariser (Eq. 12, reference §5.2 cost 4): `0.1·τ_root (6) ≈ 0`, `0.01·τ_joints ≈ 0`;
//!      the root's "virtual" force and torque are allowed but penalised.
//!
//!    subject to the equation of motion `M·v̇ + h = τ + Σ_k J_kᵀ·λ_k` (Eq. 9), the linearised friction
//!    pyramid per point (Eq. 10; rows `(±√2, −μ, 0)`, `(0, −μ, ±√2)` applied to λ ≤ 0), and bounds on the
//!    next point velocity `v⁺ = J·v + dt·J·v̇` (Eq. 11, reference §5.2(a)/(b)):
//!    - both feet, always: `th = −ln(min(c, 0.84999)/0.85)` from the foot-contact probability c,
//!      `th_y = −height/dt`; `|v⁺_x|, |v⁺_z| ≤ th`, `th_y ≤ v⁺_y ≤ max(th, th_y) + 1e-6`;
//!    - other contact bodies: `|v⁺_x|, |v⁺_z| ≤ 0.1`, `0 ≤ v⁺_y ≤ 100`.
//! 3. **Integration** (Eq. 13): semi-implicit Euler, `v += v̇·dt`, `q ← q ⊕ v·dt`.
//!
//! # Differences from PIP, and why
//!
//! - **Coordinates.** PIP's RBDL body uses Euler angles (reference §5.1) and its rotation PD takes the
//!   wrapped Euler-angle difference. We use the singularity-free spherical joints of
//!   `imuflow_body::dynamics`, so the rotation PD is GlobalPose's tangent-space form
//!   `kp·log(R_curᵀ·R_ref) − kd·ω` (reference §5.4 step 2). Same gains.
//! - **Body and floor.** Our body model (anatomical joint heights, masses from the body model) replaces
//!   PIP's URDF; `floor_y = −0.87` becomes "ground point at or below y = 0" with per-joint clearances
//!   (`imuflow_contact::geometry`). The Signorini and foot heights are those ground-point heights.
//! - **Velocity bounds** act on the joint origins (PIP: the body origins), with the joint's ground-point
//!   height in `th_y`.
//! - **Solver.** An interior-point method instead of quadprog, on an exactly equivalent smaller
//!   problem (the `qp` submodule's docs). `τ` only enters the cost (the torque regulariser) and is fixed by
//!   the equation of motion, so substituting `τ = M·v̇ + h − Σ_k J_kᵀλ_k` leaves a strictly convex QP in
//!   `z = [v̇, λ]` with the same minimiser (`v̇`, `λ`) and the same feasible set: the friction rows act
//!   on λ, the velocity rows on v̇, neither on τ. Its Hessian `H` (dense, 75 + 3·n_points) is factored
//!   once (Cholesky); the unconstrained optimum is one solve, and the inequalities are handled through
//!   the dual `min_{μ≥0} ½μᵀC·H⁻¹·Cᵀμ + (d − C·z_u)ᵀμ` (one variable per inequality row, ~28–44,
//!   bounds only; `z = z_u − H⁻¹Cᵀμ`). This also covers frames without contact points, where the foot
//!   velocity bounds (always present) constrain `v̇` alone. Strong duality holds for a feasible convex
//!   QP, so the recovered `z` is the primal optimum (to the solver's tolerance). The dual is small and
//!   dense, so a hand-written dense Mehrotra predictor-corrector (`bound_qp`) solves it: 0.18 ms
//!   against clarabel's 0.53 ms on the same dual (QP p50, `imuflow bench physics`, a training run
//!   on the other core), clarabel's sparse set-up and kernels being most of its time at this size.
//!   clarabel stays the fallback when the dense solver does not converge, and solves the original
//!   form (3.8 ms). The original form (`[v̇, λ, τ]`
//!   with the equation of motion as 75 equality rows) is kept: it is used when `H` is not numerically
//!   positive definite (zero torque or force weights, where λ or v̇ need not be unique) and by the
//!   tests as the reference (same optimum to ~1e-7 relative). Either way `τ` is finally computed from
//!   the equation of motion with the solved `v̇` and `λ`, so the output satisfies it to rounding.
//! - **Fallback** (PIP live demo, reference §5.2 "Solver"): when the QP fails (not solved, non-finite
//!   data or solution, `‖x‖ > 1e4`), re-solve without the inequalities; when that fails too, follow the
//!   reference pose kinematically (keep the root position, zero velocity). Both set
//!   `StepReport::fallback`.
//! - **First frame**: the reference pose placed on the floor (PIP: the network pose with zero
//!   translation, on its own floor), zero velocity.
//! - PIP's disabled cost terms (acceleration matching `coeff_acc`, plain λ size, position PD variant)
//!   are not implemented.

mod bound_qp;
mod qp;
#[cfg(test)]
mod tests;

use anyhow::ensure;
use imuflow_body::dynamics::{DofVector, DynamicsData, integrate_semi_implicit_euler};
use imuflow_body::kinematics::FkData;
use imuflow_body::{JointId, Pose};
use imuflow_contact::ContactSet;
use imuflow_contact::pip::{PipContactConfig, pip_contacts};
use imuflow_graph::params::Param;
use nalgebra::Vector3;

use crate::estimate::{FEET, place_on_floor};
use crate::{DT_S, Method, MotionEstimate, PhysicsBody, Reference, StepReport};

pub use qp::SolveStats;

/// PIP's gains and weights. `Default` is the paper's/code's values (reference §5.2,
/// `physics_parameters.json`).
#[derive(Clone, Debug, PartialEq)]
pub struct PipConfig {
    /// Joint-rotation PD stiffness (1/s²; PIP kp_ang = 2400, Eq. 3).
    pub kp_rotation: f64,
    /// Joint-rotation PD damping (1/s; kd_ang = 60, Eq. 3).
    pub kd_rotation: f64,
    /// Joint-position PD stiffness (1/s²; kp_lin = 3600, Eq. 4; multiplies `v_ref·dt`).
    pub kp_position: f64,
    /// Joint-position PD damping (1/s; kd_lin = 60, Eq. 4).
    pub kd_position: f64,
    /// Friction coefficient of the pyramid (μ = 0.6, Eq. 10).
    pub friction: f64,
    /// Time step (s; PIP dt = 0.0166667, Eq. 13).
    pub dt: f64,
    /// Weight of the joint-position PD rows (coeff_jvel = 1, Eq. 6).
    pub coeff_joint_velocity: f64,
    /// Weight of the world-orientation PD rows of the six instrumented bones (imuflow, not PIP:
    /// the reference carries their calibrated measurement, and the local-rotation PD alone let
    /// its errors add up along each chain; same gains as the rotation PD; 0 turns it off).
    pub coeff_sensor_bone: f64,
    /// Weight of the same rows on the upper legs and upper arms (imuflow, not PIP: the kinematics
    /// stage sets them from the lower legs' and forearms' sensors through the anatomical knee and
    /// elbow, and the local-rotation PD let the root's and spine's errors turn them; 0 turns it
    /// off).
    pub coeff_limb_bone: f64,
    /// Weight of the height-scaled force penalty (coeff_lambda = 10, reference §5.2 cost 3).
    pub coeff_lambda: f64,
    /// Smallest height used in that penalty (m; 0.005, reference §5.2 cost 3).
    pub lambda_min_height_m: f64,
    /// Weight of the root's virtual force/torque (coeff_virtual = 0.1, Eq. 12).
    pub coeff_root_virtual: f64,
    /// Weight of the joint torques (coeff_tau = 0.01, Eq. 12).
    pub coeff_joint_torque: f64,
    /// Foot-contact probability at which a foot is locked: `th = −ln(min(c, lock − ε)/lock)`
    /// (0.85, reference §5.2(b)).
    pub foot_lock_probability: f64,
    /// Horizontal velocity bound of non-foot contact bodies (m/s; 0.1, reference §5.2(a)).
    pub contact_body_slide_mps: f64,
    /// Upward velocity bound of non-foot contact bodies (m/s; 100, reference §5.2(a)).
    pub contact_body_rise_mps: f64,
    /// A solution with `‖x‖` above this counts as failed (PIP 1e4; PNP 1e5, reference §5.2/§5.3).
    pub fallback_norm: f64,
    /// PIP's contact rule, used when a step gets no contact set (reference §5.2 "Contact set").
    pub contact: PipContactConfig,
    /// The interior-point solvers' gap and feasibility tolerances (default 1e-7: ample for 60 Hz;
    /// clarabel's own 1e-8).
    pub solver_tolerance: f64,
    /// The interior-point solvers' iteration limit (50; typical solves take 9–25).
    pub solver_max_iterations: u32,
}

/// The optimizer stage's `sensor_bone_weight`: the default of [`PipConfig::coeff_sensor_bone`].
pub const SENSOR_BONE_WEIGHT_PARAM: Param<f64> = imuflow_graph::param! {
    /// pip: weight of the world-orientation PD on the six instrumented bones (0: PIP's own cost)
    sensor_bone_weight: f64 = 1, float(0.0, 1e3)
};

/// The optimizer stage's `limb_bone_weight`: the default of [`PipConfig::coeff_limb_bone`].
pub const LIMB_BONE_WEIGHT_PARAM: Param<f64> = imuflow_graph::param! {
    /// pip: weight of the same PD on the upper legs and upper arms, which the kinematics stage
    /// sets from the sensors below them (0: PIP's own cost)
    limb_bone_weight: f64 = 1, float(0.0, 1e3)
};

impl Default for PipConfig {
    fn default() -> PipConfig {
        PipConfig {
            kp_rotation: 2400.0,
            kd_rotation: 60.0,
            kp_position: 3600.0,
            kd_position: 60.0,
            friction: 0.6,
            dt: DT_S,
            coeff_joint_velocity: 1.0,
            coeff_sensor_bone: SENSOR_BONE_WEIGHT_PARAM.default,
            coeff_limb_bone: LIMB_BONE_WEIGHT_PARAM.default,
            coeff_lambda: 10.0,
            lambda_min_height_m: 0.005,
            coeff_root_virtual: 0.1,
            coeff_joint_torque: 0.01,
            foot_lock_probability: 0.85,
            contact_body_slide_mps: 0.1,
            contact_body_rise_mps: 100.0,
            fallback_norm: 1e4,
            contact: PipContactConfig::default(),
            solver_tolerance: 1e-7,
            solver_max_iterations: 50,
        }
    }
}

/// The joints of the position PD (Eq. 4): SMPL 0..21 except the feet (reference §5.2 cost 2).
pub const POSITION_PD_JOINTS: [JointId; 20] = {
    let mut out = [JointId::PELVIS; 20];
    let mut i = 0;
    let mut k = 0;
    while i < 22 {
        if i != 10 && i != 11 {
            out[k] = match JointId::from_index(i) {
                Some(j) => j,
                None => JointId::PELVIS,
            };
            k += 1;
        }
        i += 1;
    }
    out
};

/// The `pip` method.
pub struct Pip {
    physics: PhysicsBody,
    config: PipConfig,
    data: DynamicsData,
    fk: FkData,
    pose: Pose,
    v: DofVector,
    started: bool,
    contacts: ContactSet,
    qp: qp::Qp,
    last: Option<SolveStats>,
}

impl Pip {
    /// A PIP optimizer for `physics` (errors on non-finite or out-of-range constants).
    pub fn new(physics: PhysicsBody, config: PipConfig) -> anyhow::Result<Pip> {
        let c = &config;
        let values = [
            c.kp_rotation,
            c.kd_rotation,
            c.kp_position,
            c.kd_position,
            c.friction,
            c.coeff_joint_velocity,
            c.coeff_lambda,
            c.lambda_min_height_m,
            c.coeff_root_virtual,
            c.coeff_joint_torque,
            c.contact_body_slide_mps,
            c.contact_body_rise_mps,
        ];
        ensure!(
            values.iter().all(|v| v.is_finite() && *v >= 0.0),
            "pip: gains, weights and bounds must be finite and ≥ 0: {config:?}"
        );
        ensure!(c.dt > 0.0 && c.dt.is_finite(), "pip: dt must be > 0");
        ensure!(
            c.foot_lock_probability > 0.0 && c.foot_lock_probability <= 1.0,
            "pip: foot_lock_probability must be in (0, 1]"
        );
        ensure!(c.fallback_norm > 0.0, "pip: fallback_norm must be > 0");
        ensure!(
            c.solver_tolerance > 0.0 && c.solver_max_iterations > 0,
            "pip: solver tolerance and iterations must be > 0"
        );
        Ok(Pip {
            physics,
            config,
            data: DynamicsData::new(),
            fk: FkData::new(),
            pose: Pose::default(),
            v: DofVector::zeros(),
            started: false,
            contacts: ContactSet::new(),
            qp: qp::Qp::new(),
            last: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PipConfig {
        &self.config
    }

    /// The current state (pose, generalized velocity).
    pub fn state(&self) -> (&Pose, &DofVector) {
        (&self.pose, &self.v)
    }

    /// Start from a given state instead of the first reference pose (tests, restarts).
    pub fn set_state(&mut self, pose: Pose, v: DofVector) {
        self.pose = pose;
        self.v = v;
        self.started = true;
    }

    /// The solver's statistics of the last step's solves (None before the first QP).
    pub fn last_solve(&self) -> Option<SolveStats> {
        self.last
    }

    /// Kinematic fallback: the reference rotations at the current root position, at rest.
    fn follow_reference(&mut self, reference: &Reference) {
        let root = self.pose.root_in_world_m;
        self.pose = reference.pose.clone();
        self.pose.root_in_world_m = root;
        self.v = DofVector::zeros();
        for p in self.contacts.points_mut() {
            p.force = Vector3::zeros();
        }
    }
}

impl Method for Pip {
    /// The contacts the last step used, with the solved per-point forces (N, M) filled in.
    fn contacts(&self) -> &ContactSet {
        &self.contacts
    }

    fn reset(&mut self) {
        self.started = false;
        self.v = DofVector::zeros();
        self.contacts.clear();
        self.last = None;
    }

    fn step(
        &mut self,
        reference: &Reference,
        contacts: Option<&ContactSet>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport> {
        let mut report = StepReport::default();
        let mut tau = DofVector::zeros();
        if !self.started {
            self.pose = reference.pose.clone();
            self.pose.root_in_world_m = Vector3::zeros();
            place_on_floor(&self.physics, &mut self.pose, &FEET, &mut self.fk);
            self.v = DofVector::zeros();
            self.contacts.clear();
            self.started = self.pose.is_finite();
            if !self.started {
                report.fallback = true;
                self.pose =
                    Pose::t_pose(Vector3::new(0.0, self.physics.body.rest_root_height_m, 0.0));
            }
        } else {
            self.data
                .set_state(&self.physics.model, &self.pose, &self.v);
            match contacts {
                Some(c) => {
                    self.contacts.clone_from(c);
                    for p in self.contacts.points_mut() {
                        p.force = Vector3::zeros();
                    }
                }
                None => {
                    pip_contacts(
                        &self.data.fk().joint_in_world_m,
                        reference.foot_contact_prob,
                        &self.physics.geometry,
                        &self.config.contact,
                        &mut self.contacts,
                    );
                }
            }
            let mut stats = SolveStats::default();
            let mut solved = self.qp.solve(
                &self.physics,
                &self.config,
                &mut self.data,
                &self.pose,
                reference,
                &self.contacts,
                true,
                &mut stats,
            );
            if solved.is_none() {
                report.fallback = true;
                solved = self.qp.solve(
                    &self.physics,
                    &self.config,
                    &mut self.data,
                    &self.pose,
                    reference,
                    &self.contacts,
                    false,
                    &mut stats,
                );
            }
            self.last = Some(stats);
            match solved {
                Some(sol) => {
                    let (pose0, v0) = (self.pose.clone(), self.v);
                    integrate_semi_implicit_euler(
                        &mut self.pose,
                        &mut self.v,
                        &sol.acceleration,
                        self.config.dt,
                    );
                    if self.pose.is_finite() && self.v.iter().all(|x| x.is_finite()) {
                        tau = sol.tau;
                        for (p, f) in self.contacts.points_mut().iter_mut().zip(&sol.forces) {
                            p.force = *f;
                        }
                        // Residual root wrench in M: force as is, the root torque from the pelvis frame.
                        let torque =
                            pose0.parent_from_joint[0] * Vector3::new(tau[3], tau[4], tau[5]);
                        self.contacts.residual_root_wrench =
                            [tau[0], tau[1], tau[2], torque.x, torque.y, torque.z];
                    } else {
                        report.fallback = true;
                        self.pose = pose0;
                        self.v = v0;
                        self.follow_reference(reference);
                    }
                }
                None => {
                    report.fallback = true;
                    self.follow_reference(reference);
                }
            }
            if !self.pose.is_finite() {
                // Only a non-finite reference gets here: keep a usable state.
                self.pose =
                    Pose::t_pose(Vector3::new(0.0, self.physics.body.rest_root_height_m, 0.0));
                self.v = DofVector::zeros();
            }
        }
        *out = MotionEstimate {
            pose: self.pose.clone(),
            v: self.v,
            tau,
            ground_reaction_force_n: self.contacts.joint_forces(),
            contact_mask: self.contacts.mask,
            surface_height_m: self.contacts.surface_height_m,
            residual_root_force_n: Vector3::new(tau[0], tau[1], tau[2]),
        };
        Ok(report)
    }
}
