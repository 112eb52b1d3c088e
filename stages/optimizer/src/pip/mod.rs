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
//! - **Failure and fallback.** A step fails when the QP is not solved, its data or solution is not
//!   finite, `‖x‖ > 1e5` ([`PipConfig::fallback_norm`]; PNP's threshold, reference §5.3, where
//!   PIP's code has 1e4), or the integrated state is faster than a human
//!   ([`crate::within_human_speeds`], the divergence guard GlobalPose has). The frame is then the
//!   degraded estimate ([`crate::degraded`]) and the physics continues from it
//!   (`StepReport::fallback`). PIP's live demo re-solves without the inequalities (reference §5.2
//!   "Solver"), and where that failed too imuflow followed the reference at the last root
//!   position at rest; see "Why not PIP's fallback" below.
//!
//! # Why not PIP's fallback
//!
//! A synthesized standing back flip (1 s of flight, tucked, upside down; `tests/athletics.rs`) with
//! perfect network outputs failed in 83 of 183 frames, from the top of the flight to the end,
//! and never recovered. Three things made it:
//!
//! 1. **`‖x‖ > 1e4` rejects landings.** `x` holds forces (N) and torques (N·m) of a 70 kg body
//!    (PIP's URDF weighs 40 kg, reference §5.1), and the velocity bounds stop a contact within one
//!    frame: stopping 70 kg at 3 m/s in 1/60 s takes 12.6 kN. The first rejected solve was the
//!    body landing on its head and shoulders: contact forces 5.6 kN, root force 11 kN,
//!    ‖x‖ = 1.3e4. With 1e5 (PNP's value) the same clip solves every frame.
//! 2. **The re-solve without inequalities drops the floor.** Nothing stops a body from falling
//!    through it; the flip's body sank to 1.4 m below the floor within 15 frames.
//! 3. **A state in the floor does not get out.** PIP's contact rows keep penetrating bodies from
//!    going deeper (`v⁺_y ≥ 0`), not out; the feet's rows ask for the whole depth within one frame
//!    (`th_y = −height/dt`: 85 m/s at 1.4 m), which needs a solution of ‖x‖ ≈ 6e4, rejected
//!    again; the re-solve sank further. Following the reference "at the last root position"
//!    put an upside-down pose at a standing root height into the floor as well.
//!
//! The degraded estimate is kept above the floor and moves with the networks' root velocity, so
//! the physics restarts from a state it can solve.
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

use crate::degraded::Degraded;
use crate::estimate::{FEET, place_on_floor};
use crate::{
    DT_S, Method, MotionEstimate, PhysicsBody, Reference, StepReport, Terrain, within_human_speeds,
};

pub use qp::{SolveStats, orientation_rows, orientation_target};

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
    /// A solution with `‖x‖` above this counts as failed (1e5: PNP's, reference §5.3; PIP's code
    /// has 1e4, reference §5.2, which the forces of a 70 kg body landing exceed: module docs).
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
            fallback_norm: 1e5,
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
    /// The estimate of frames the QP cannot solve (flat floor, as PIP's QP has).
    degraded: Degraded,
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
            degraded: Degraded::new(physics.clone(), Terrain::Flat),
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

    /// The solver's statistics of the last step's solve (None before the first QP).
    pub fn last_solve(&self) -> Option<SolveStats> {
        self.last
    }

    /// The current state with `tau` and the contacts' forces into `out`.
    fn write(&self, tau: DofVector, out: &mut MotionEstimate) {
        *out = MotionEstimate {
            pose: self.pose.clone(),
            v: self.v,
            tau,
            ground_reaction_force_n: self.contacts.joint_forces(),
            contact_mask: self.contacts.mask,
            surface_height_m: self.contacts.surface_height_m,
            residual_root_force_n: Vector3::new(tau[0], tau[1], tau[2]),
        };
    }

    /// The frame could not be solved: publish the degraded estimate and continue from it.
    fn degrade(&mut self, reference: &Reference, out: &mut MotionEstimate) -> anyhow::Result<()> {
        let root = self.pose.root_in_world_m;
        self.degraded.estimate(reference, &root, out)?;
        if !out.pose.is_finite() || !out.v.iter().all(|x| x.is_finite()) {
            // Only a non-finite reference gets here: keep the state.
            for p in self.contacts.points_mut() {
                p.force = Vector3::zeros();
            }
            self.write(DofVector::zeros(), out);
            return Ok(());
        }
        self.pose.clone_from(&out.pose);
        self.v = out.v;
        self.contacts.clear();
        self.contacts.mask = out.contact_mask;
        Ok(())
    }

    /// One QP step from the current state; `None` (the state untouched) when it failed.
    fn physics_step(
        &mut self,
        reference: &Reference,
        contacts: Option<&ContactSet>,
    ) -> Option<DofVector> {
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
        let solved = self.qp.solve(
            &self.physics,
            &self.config,
            &mut self.data,
            &self.pose,
            reference,
            &self.contacts,
            true,
            &mut stats,
        );
        self.last = Some(stats);
        let sol = solved?;
        let (mut pose, mut v) = (self.pose.clone(), self.v);
        integrate_semi_implicit_euler(&mut pose, &mut v, &sol.acceleration, self.config.dt);
        if !pose.is_finite() || !within_human_speeds(&v) {
            return None;
        }
        let tau = sol.tau;
        for (p, f) in self.contacts.points_mut().iter_mut().zip(&sol.forces) {
            p.force = *f;
        }
        // Residual root wrench in M: force as is, the root torque from the pelvis frame.
        let torque = self.pose.parent_from_joint[0] * Vector3::new(tau[3], tau[4], tau[5]);
        self.contacts.residual_root_wrench = [tau[0], tau[1], tau[2], torque.x, torque.y, torque.z];
        self.pose = pose;
        self.v = v;
        Some(tau)
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
        self.degraded.reset();
    }

    fn step(
        &mut self,
        reference: &Reference,
        contacts: Option<&ContactSet>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport> {
        let mut report = StepReport::default();
        if !self.started {
            self.pose = reference.pose.clone();
            self.pose.root_in_world_m = Vector3::zeros();
            place_on_floor(&self.physics, &mut self.pose, &FEET, &mut self.fk);
            self.v = DofVector::zeros();
            self.contacts.clear();
            self.degraded.reset();
            self.started = self.pose.is_finite();
            if !self.started {
                report.fallback = true;
                self.pose =
                    Pose::t_pose(Vector3::new(0.0, self.physics.body.rest_root_height_m, 0.0));
            }
            self.write(DofVector::zeros(), out);
        } else {
            match self.physics_step(reference, contacts) {
                Some(tau) => self.write(tau, out),
                None => {
                    report.fallback = true;
                    self.degrade(reference, out)?;
                }
            }
        }
        self.degraded.follow(reference);
        Ok(report)
    }
}
