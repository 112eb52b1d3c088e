//! GlobalPose's physics optimizer (SIGGRAPH 2025 §3.3, Eq. 7–16 and App. B Eq. 26/27; reference §5.4):
//! pre-tracking, force-based contact estimation, re-tracking.
//!
//! # The method, per frame
//!
//! The state is our floating-base character (`imuflow_body::dynamics`, GlobalPose's singularity-free
//! coordinates: `q̇ ∈ R⁷⁵` = root linear velocity in the world, then per joint the angular velocity
//! relative to its parent in its own frame).
//!
//! - **First frame**: the reference pose with its lowest contact joint (pelvis, feet, hands) on the floor
//!   ([`place_on_floor`]), zero velocity.
//! - Then, every frame (reference §5.4 steps 1–11; our order of computation):
//!   - Root velocity refinement (Eq. 25, [`refined_root_velocity`]), shared with the `integrate` method.
//!   - State terms (step 1): `M`, `h`, and for the five contact joints position, velocity, `J`, `J̇q̇`.
//!   - Pose PD (step 2, Eq. 9): `θ̈_des,j = kp·log(R_cur,jᵀ·R_ref,j) − kd·ω_j` for all 24 joints (root
//!     rotation included), in the joint's tangent space (right perturbation, as the state update).
//!   - Contact-joint targets (step 3, Eq. 7–8): `target_i = p + ṽ·dt + r_ref,i` (reference pose relative
//!     to the root), pulled to the current position by the stationary weight `w_i`; position PD
//!     (Eq. 10) `r̈_des,i = kp·(target_i − r_i) − kd·ṙ_i`. (Step 4, the pelvis drop, is the pelvis's
//!     clearance here; see the deviations.)
//!   - Tracking weights (step 5): `k_i = β_cjoint`, ×10 for joints in contact in the previous frame.
//!   - **Pre-tracking** (step 6, Eq. 11/26): least squares, torque weight `β_τ`, target
//!     `M·q̈ + h = 0` ([`tracking`]). Residual root wrench `r = (M·q̈ + h)[0..6]`.
//!   - **Contacts** (steps 7–9, Eq. 12–13): `imuflow_contact::force` explains `r` with friction-cone
//!     forces at stationary joints touching the floor and adds potential contacts (5-frame counters).
//!   - Target update (step 10): contact targets less than 0.15 m above the floor are pulled 10 % down;
//!     every target stays above it. With [`Terrain::Flat`] (the default) the feet's targets are
//!     pulled from any height (see the deviations).
//!   - **Re-tracking** (step 11, Eq. 14/27): the PD recomputed with the new targets, torque weight
//!     `3·β_τ`, target `M·q̈ + h − J_cᵀλ = 0`; then GlobalPose's update `δ = q̇·dt + ½·q̈·dt²`,
//!     `q ← q ⊕ δ`, `q̇ += q̈·dt` (`imuflow_body::dynamics::integrate`).
//!
//! Outputs ([`MotionEstimate`]): the integrated state; `tau = M·q̈ + h − J_cᵀλ` of re-tracking (its first
//! six entries are the residual root wrench left over; `residual_root_force_n` = its force part);
//! per contact joint the contact force (world); the contact mask; surface heights 0 (the floor).
//! [`GlobalPose::contacts`] holds the contacts with one point per contact joint at its ground point.
//!
//! # Deviations from the original
//!
//! - **Solver**: the original runs scipy's LSQR on the sparse stacked rows (default tolerances, so
//!   approximate). We solve the 75×75 normal equations exactly by Cholesky ([`tracking`]).
//! - **Floor and heights**: the original compares joint heights with `floor_y = −0.97` (tuned to SMPL)
//!   and lowers the pelvis point by 0.15 m after computing its PD. We keep the floor at y = 0 and give
//!   each joint a clearance (`ContactGeometry`; the pelvis's is [`GlobalPoseConfig::pelvis_drop_m`]).
//!   Heights, the target pull/clamp and the contact forces use the joint's *ground point* (joint −
//!   clearance·ŷ); the tracked point (PD and `J_i` in the least squares) is the joint itself, as in
//!   the original (lowering current and target by the same amount does not change `r̈_des`).
//! - **Contact force point**: the forces act at the ground points (their Jacobians' root columns form
//!   `G`; their full Jacobians give `J_cᵀλ`). The original's Jacobians are those of the joints.
//! - **Flat terrain** by default ([`Terrain`]): the paper keeps a contact that lands more than
//!   0.15 m above the floor at that height (a proxy surface: a step, a seat). On flat ground with
//!   a biased vertical velocity every jump then landed higher (2.8 m in 14 s of jumps); our
//!   default pulls stationary feet down from any height. `terrain = "proxy"` restores the paper.
//! - **Grasp** allowed for both hands (the original's off-by-one lets only the right hand grasp); see
//!   `imuflow_contact::force`.
//! - **Weights** `k_i` and `β` weigh the squared norms, as written in the paper (Eq. 11, 26).
//! - **Gravity** 9.81 (the original 9.8); masses from our body model, not SMPL voxels.
//!
//! # Fallback
//!
//! Never panics. When a solve fails (the normal matrix not positive definite) or produces non-finite
//! values or a body faster than a human's ([`crate::within_human_speeds`]: root 15 m/s, a joint
//! 150 rad/s: a diverged step), the frame is the degraded estimate ([`crate::degraded`]: the
//! reference pose, the root moved from its last position at the refined root velocity, kept above
//! the floor), with no contacts and zero forces, and the step reports `fallback = true`; the next
//! frame continues the physics from that state. A non-finite reference keeps the previous state
//! unchanged (also `fallback = true`) and does not enter the velocity refinement.

pub mod tracking;

use imuflow_body::dynamics::{
    DofVector, DynamicsData, MassMatrix, NUM_DOFS, PointJacobian, integrate, joint_dof,
};
use imuflow_body::kinematics::FkData;
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::CONTACT_JOINTS;
use imuflow_body::{JointId, Pose};
use imuflow_contact::force::{
    ForceContactConfig, ForceContactEstimator, ForceEstimate, ForceInput, NUM_CONTACT_JOINTS,
};
use imuflow_contact::{ContactPoint, ContactSet};
use nalgebra::{Vector3, Vector6};

use crate::degraded::Degraded;
use crate::estimate::{FEET, place_on_floor};
use crate::integrate::{contact_joints_rel, refined_root_velocity, stationary_weight};
use crate::{
    DT_S, Method, MotionEstimate, PhysicsBody, Reference, StepReport, Terrain, pull_to_floor,
    within_human_speeds,
};
use tracking::{TrackingTerms, solve_tracking, square_skipping_zeros};

/// GlobalPose's gains and weights. `Default` is the paper's/code's values (reference §5.4).
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalPoseConfig {
    /// Pose PD stiffness (kp_pose = 3600).
    pub kp_rotation: f64,
    /// Pose PD damping (kd_pose = 60).
    pub kd_rotation: f64,
    /// Contact-joint position PD stiffness (kp_tran = 3600).
    pub kp_position: f64,
    /// Contact-joint position PD damping (kd_tran = 60).
    pub kd_position: f64,
    /// Friction coefficient (μ = 0.7). Overrides `contact.friction`.
    pub friction: f64,
    /// Weight of the contact-joint tracking terms (reference §5.4: β_cjoint = 1).
    pub joint_tracking_weight: f64,
    /// Factor on the tracking weight of joints in contact in the previous frame (reference §5.4 step 5: 10).
    pub previous_contact_factor: f64,
    /// Torque regularization of pre-tracking β_τ (reference §5.4 / paper "Hyperparameters":
    /// 1e-3/80, 80 kg being the character's approximate mass).
    pub torque_weight: f64,
    /// Factor on β_τ for re-tracking (paper: β*_τ = 3·β_τ; reference §5.4 step 11).
    pub retracking_torque_factor: f64,
    /// Frame period (s) (reference §5.4: dt = 1/60).
    pub dt_s: f64,
    /// Drop of the pelvis contact point below the pelvis joint (sitting; reference §5.4 step 4: 0.15 m).
    /// Replaces the pelvis clearance of the body's `ContactGeometry`.
    pub pelvis_drop_m: f64,
    /// Contact estimation constants (reference §5.4 steps 7–10); `friction` is taken from above.
    pub contact: ForceContactConfig,
    /// The ground: flat (feet pulled to the floor from any height) or the paper's proxy surfaces.
    pub terrain: Terrain,
}

impl Default for GlobalPoseConfig {
    fn default() -> GlobalPoseConfig {
        GlobalPoseConfig {
            kp_rotation: 3600.0,
            kd_rotation: 60.0,
            kp_position: 3600.0,
            kd_position: 60.0,
            friction: 0.7,
            joint_tracking_weight: 1.0,
            previous_contact_factor: 10.0,
            torque_weight: 1e-3 / 80.0,
            retracking_torque_factor: 3.0,
            dt_s: DT_S,
            pelvis_drop_m: imuflow_contact::geometry::PELVIS_SITTING_CLEARANCE_M,
            contact: ForceContactConfig::default(),
            terrain: Terrain::default(),
        }
    }
}

/// What the last step's two passes left on the root (for diagnostics and tests).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PassResiduals {
    /// Residual root wrench of pre-tracking `(M·q̈ + h)[0..6]` (world force, root-frame torque).
    pub pre_tracking: Vector6<f64>,
    /// Residual root wrench of re-tracking `(M·q̈* + h − J_cᵀλ)[0..6]`.
    pub re_tracking: Vector6<f64>,
}

/// Per-frame scratch (boxed: the 75×75 matrices are 45 kB each).
struct Scratch {
    mass: MassMatrix,
    mass_squared: MassMatrix,
    normal: MassMatrix,
    jacobians: [PointJacobian; NUM_CONTACT_JOINTS],
    ground_jacobians: [PointJacobian; NUM_CONTACT_JOINTS],
}

/// The `globalpose` method.
pub struct GlobalPose {
    physics: PhysicsBody,
    config: GlobalPoseConfig,
    estimator: ForceContactEstimator,
    data: DynamicsData,
    fk: FkData,
    scratch: Box<Scratch>,
    /// The character's state.
    pose: Pose,
    v: DofVector,
    /// Contact joints of the previous reference relative to the root; `None` before the first frame.
    previous_rel: Option<[Vector3<f64>; NUM_CONTACT_JOINTS]>,
    contacts: ContactSet,
    residuals: PassResiduals,
    /// The estimate of frames the physics cannot solve.
    degraded: Degraded,
}

impl GlobalPose {
    /// The method for one subject. Errors on a configuration that cannot work (non-positive dt,
    /// negative gains or weights, non-finite values).
    pub fn new(mut physics: PhysicsBody, config: GlobalPoseConfig) -> anyhow::Result<GlobalPose> {
        let c = &config;
        let values = [
            c.kp_rotation,
            c.kd_rotation,
            c.kp_position,
            c.kd_position,
            c.friction,
            c.joint_tracking_weight,
            c.previous_contact_factor,
            c.torque_weight,
            c.retracking_torque_factor,
            c.pelvis_drop_m,
        ];
        anyhow::ensure!(
            values.iter().all(|v| v.is_finite() && *v >= 0.0),
            "globalpose: gains, weights, friction and pelvis drop must be finite and ≥ 0: {config:?}"
        );
        anyhow::ensure!(
            c.dt_s.is_finite() && c.dt_s > 0.0,
            "globalpose: dt must be > 0"
        );
        anyhow::ensure!(
            c.joint_tracking_weight > 0.0 && c.torque_weight > 0.0,
            "globalpose: the tracking and torque weights must be > 0 (the least squares is singular otherwise)"
        );
        anyhow::ensure!(
            c.contact.force_regularization > 0.0,
            "globalpose: the contact force regularization must be > 0"
        );
        let degraded = Degraded::new(physics.clone(), c.terrain);
        physics.geometry.clearance_m[JointId::PELVIS.index()] = c.pelvis_drop_m;
        let mut contact = config.contact.clone();
        contact.friction = config.friction;
        Ok(GlobalPose {
            physics,
            estimator: ForceContactEstimator::new(contact),
            config,
            data: DynamicsData::new(),
            fk: FkData::new(),
            scratch: Box::new(Scratch {
                mass: MassMatrix::zeros(),
                mass_squared: MassMatrix::zeros(),
                normal: MassMatrix::zeros(),
                jacobians: [PointJacobian::zeros(); NUM_CONTACT_JOINTS],
                ground_jacobians: [PointJacobian::zeros(); NUM_CONTACT_JOINTS],
            }),
            pose: Pose::t_pose(Vector3::zeros()),
            v: DofVector::zeros(),
            previous_rel: None,
            contacts: ContactSet::new(),
            residuals: PassResiduals::default(),
            degraded,
        })
    }

    /// The residual root wrenches of the last step's two passes.
    pub fn pass_residuals(&self) -> &PassResiduals {
        &self.residuals
    }

    /// The configuration.
    pub fn config(&self) -> &GlobalPoseConfig {
        &self.config
    }

    /// Write the current state (and the given contact results) into `out`.
    fn write_state(&self, out: &mut MotionEstimate) {
        out.pose = self.pose.clone();
        out.v = self.v;
    }

    /// The degraded estimate (the documented fallback), and the physics continues from it.
    fn fall_back(
        &mut self,
        reference: &Reference,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport> {
        let root = self.pose.root_in_world_m;
        self.degraded.estimate(reference, &root, out)?;
        self.pose.clone_from(&out.pose);
        self.v = out.v;
        self.estimator.reset();
        self.contacts.clear();
        self.contacts.mask = out.contact_mask;
        self.residuals = PassResiduals::default();
        Ok(StepReport { fallback: true })
    }

    /// Steps 1–11 for a frame after the first. `None` when a solve failed or went non-finite (the
    /// state is then untouched).
    fn physics_step(
        &mut self,
        reference: &Reference,
        rel: &[Vector3<f64>; NUM_CONTACT_JOINTS],
        root_velocity: &Vector3<f64>,
        out: &mut MotionEstimate,
    ) -> Option<()> {
        let cfg = &self.config;
        let model = &self.physics.model;
        let geometry = &self.physics.geometry;
        let dt = cfg.dt_s;
        let s = &mut *self.scratch;

        // 1. State terms.
        self.data.set_state(model, &self.pose, &self.v);
        s.mass.copy_from(self.data.mass_matrix(model));
        let h = *self.data.bias_forces(model);
        square_skipping_zeros(&s.mass, &mut s.mass_squared);
        let mut current = [Vector3::zeros(); NUM_CONTACT_JOINTS];
        let mut velocity = [Vector3::zeros(); NUM_CONTACT_JOINTS];
        let mut jdot_v = [Vector3::zeros(); NUM_CONTACT_JOINTS];
        let mut ground_local = [Vector3::zeros(); NUM_CONTACT_JOINTS];
        for (i, &j) in CONTACT_JOINTS.iter().enumerate() {
            let origin = Vector3::zeros();
            current[i] = self.data.fk().joint_in_world_m[j.index()];
            velocity[i] = self.data.point_velocity(j, &origin);
            jdot_v[i] = self.data.point_jdot_v(j, &origin);
            self.data.point_jacobian(j, &origin, &mut s.jacobians[i]);
            // Ground point: `clearance` below the joint, in the joint's frame.
            ground_local[i] = self.data.fk().world_from_joint[j.index()].inverse()
                * Vector3::new(0.0, -geometry.clearance(j), 0.0);
            self.data
                .point_jacobian(j, &ground_local[i], &mut s.ground_jacobians[i]);
        }

        // 2. Pose PD (Eq. 9) in each joint's tangent space.
        let mut theta_ddot = DofVector::zeros();
        for j in JointId::all() {
            let i = j.index();
            let d = joint_dof(j);
            let err = axis_angle_from_rotation(
                &(self.pose.parent_from_joint[i].transpose() * reference.rotation(i)),
            );
            let w = self.v.fixed_rows::<3>(d).into_owned();
            theta_ddot
                .fixed_rows_mut::<3>(d)
                .copy_from(&(cfg.kp_rotation * err - cfg.kd_rotation * w));
        }

        // 3. Contact-joint targets (Eq. 7–8) and the position PD (Eq. 10).
        let mut target = [Vector3::zeros(); NUM_CONTACT_JOINTS];
        for i in 0..NUM_CONTACT_JOINTS {
            let w = stationary_weight(reference.stationary_prob[i]);
            let t = self.pose.root_in_world_m + root_velocity * dt + rel[i];
            target[i] = t + w * (current[i] - t);
        }
        let pd = |target: &[Vector3<f64>; NUM_CONTACT_JOINTS]| {
            std::array::from_fn::<_, NUM_CONTACT_JOINTS, _>(|i| {
                cfg.kp_position * (target[i] - current[i]) - cfg.kd_position * velocity[i]
            })
        };
        let r_ddot = pd(&target);

        // 5. Tracking weights.
        let previous = self.estimator.previous_contacts();
        let weights: [f64; NUM_CONTACT_JOINTS] = std::array::from_fn(|i| {
            cfg.joint_tracking_weight
                * if previous[i] {
                    cfg.previous_contact_factor
                } else {
                    1.0
                }
        });

        // 6. Pre-tracking.
        let torque_target = -h;
        let mut qddot = DofVector::zeros();
        let ok = solve_tracking(
            &TrackingTerms {
                theta_ddot_des: &theta_ddot,
                jacobians: &s.jacobians,
                jdot_v: &jdot_v,
                r_ddot_des: &r_ddot,
                weights: &weights,
                mass: &s.mass,
                mass_squared: &s.mass_squared,
                torque_target: &torque_target,
                torque_weight: cfg.torque_weight,
            },
            &mut s.normal,
            &mut qddot,
        );
        if !ok {
            return None;
        }
        let tau_pre = s.mass * qddot + h;
        let residual = Vector6::from_fn(|k, _| tau_pre[k]);
        if !residual.iter().all(|v| v.is_finite()) {
            return None;
        }

        // 7–9. Contacts.
        let fk = self.data.fk();
        let leg = |hip: JointId, knee: JointId| {
            fk.joint_in_world_m[knee.index()] - fk.joint_in_world_m[hip.index()]
        };
        let mut height_m: [f64; NUM_CONTACT_JOINTS] =
            std::array::from_fn(|i| geometry.height_above(CONTACT_JOINTS[i], &current[i], 0.0));
        if cfg.terrain == Terrain::Flat {
            // The lowest stationary foot stands on the floor, wherever an accumulated vertical
            // error put it: it touches now (not after step 9's five frames of a potential
            // contact), and step 10 pulls it down to y = 0.
            let threshold = self.estimator.config.stationary_threshold;
            let stands = |i: usize| {
                FEET.contains(&CONTACT_JOINTS[i]) && reference.stationary_prob[i] > threshold
            };
            let lowest = (0..NUM_CONTACT_JOINTS)
                .filter(|&i| stands(i))
                .map(|i| height_m[i])
                .reduce(f64::min);
            if let Some(lowest) = lowest.filter(|h| *h > 0.0) {
                for (i, h) in height_m.iter_mut().enumerate() {
                    if FEET.contains(&CONTACT_JOINTS[i]) {
                        *h -= lowest;
                    }
                }
            }
        }
        let input = ForceInput {
            stationary_prob: reference.stationary_prob,
            height_m,
            root_jacobian: std::array::from_fn(|i| {
                s.ground_jacobians[i].fixed_view::<3, 6>(0, 0).into_owned()
            }),
            leg: [
                leg(JointId::LEFT_HIP, JointId::LEFT_KNEE),
                leg(JointId::RIGHT_HIP, JointId::RIGHT_KNEE),
            ],
            residual,
        };
        let est: ForceEstimate = self.estimator.estimate(&input);

        // 10. Contact target update on the ground points, then the PD again.
        for (i, &j) in CONTACT_JOINTS.iter().enumerate() {
            let c = geometry.clearance(j);
            // On flat ground a foot is on the floor whatever height it landed at; pelvis and
            // hands keep the paper's limit (a seat, a table).
            let height = target[i].y - c;
            let g = match cfg.terrain {
                Terrain::Flat if FEET.contains(&j) => pull_to_floor(height, est.contact[i]),
                _ => self.estimator.config.pull_target(height, est.contact[i]),
            };
            target[i].y = g + c;
        }
        let r_ddot = pd(&target);

        // 11. Re-tracking with the contact forces.
        let mut contact_tau = DofVector::zeros();
        for i in 0..NUM_CONTACT_JOINTS {
            if est.contact[i] {
                contact_tau.gemv_tr(1.0, &s.ground_jacobians[i], &est.force[i], 1.0);
            }
        }
        let torque_target = contact_tau - h;
        let ok = solve_tracking(
            &TrackingTerms {
                theta_ddot_des: &theta_ddot,
                jacobians: &s.jacobians,
                jdot_v: &jdot_v,
                r_ddot_des: &r_ddot,
                weights: &weights,
                mass: &s.mass,
                mass_squared: &s.mass_squared,
                torque_target: &torque_target,
                torque_weight: cfg.torque_weight * cfg.retracking_torque_factor,
            },
            &mut s.normal,
            &mut qddot,
        );
        if !ok {
            return None;
        }
        let tau = s.mass * qddot + h - contact_tau;
        if !tau.iter().all(|v| v.is_finite()) {
            return None;
        }
        let mut pose = self.pose.clone();
        let mut v = self.v;
        integrate(&mut pose, &mut v, &qddot, dt);
        if !pose.is_finite() || !within_human_speeds(&v) {
            return None;
        }

        // Commit.
        let root_rotation = *self.pose.parent_from_joint[0].matrix();
        self.pose = pose;
        self.v = v;
        self.residuals = PassResiduals {
            pre_tracking: residual,
            re_tracking: Vector6::from_fn(|k, _| tau[k]),
        };
        self.contacts.clear();
        *out = MotionEstimate::default();
        for (i, &j) in CONTACT_JOINTS.iter().enumerate() {
            if est.contact[i] {
                let point = ContactPoint {
                    joint: j,
                    position: geometry.ground_point(j, &current[i]),
                    force: est.force[i],
                };
                // Five points never exceed the set's capacity.
                let _ = self.contacts.push(point);
                out.ground_reaction_force_n[j.index()] = est.force[i];
                // The proxy surface (GlobalPose §3.3, assumed horizontal): the height at which the
                // contact is held, i.e. the contact target's ground point after the step-10 pull;
                // the floor (0) for contacts near it, a step or a seat for contacts above it.
                let height = (target[i].y - geometry.clearance(j)).max(0.0);
                out.surface_height_m[j.index()] = height;
                self.contacts.surface_height_m[j.index()] = height;
            }
        }
        let torque_world = root_rotation * Vector3::new(tau[3], tau[4], tau[5]);
        self.contacts.residual_root_wrench = [
            tau[0],
            tau[1],
            tau[2],
            torque_world.x,
            torque_world.y,
            torque_world.z,
        ];
        out.tau = tau;
        out.contact_mask = self.contacts.mask;
        out.residual_root_force_n = Vector3::new(tau[0], tau[1], tau[2]);
        self.write_state(out);
        Some(())
    }
}

/// Whether every value the method reads from `reference` is finite.
fn reference_is_finite(reference: &Reference) -> bool {
    reference
        .pose
        .parent_from_joint
        .iter()
        .all(|r| r.matrix().iter().all(|v| v.is_finite()))
        && reference.root_velocity_mps.iter().all(|v| v.is_finite())
        && reference.stationary_prob.iter().all(|v| v.is_finite())
}

impl Method for GlobalPose {
    /// The contacts of the last step, one point per contact joint (at its ground point) with its
    /// estimated force (N, world); `residual_root_wrench` = re-tracking's residual (torque in M).
    fn contacts(&self) -> &ContactSet {
        &self.contacts
    }

    fn reset(&mut self) {
        self.previous_rel = None;
        self.estimator.reset();
        self.contacts.clear();
        self.residuals = PassResiduals::default();
        self.v = DofVector::zeros();
        self.degraded.reset();
    }

    fn step(
        &mut self,
        reference: &Reference,
        _contacts: Option<&ContactSet>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport> {
        if !reference_is_finite(reference) {
            // Nothing to follow: keep the previous state.
            *out = MotionEstimate::default();
            self.write_state(out);
            self.contacts.clear();
            return Ok(StepReport { fallback: true });
        }
        let rel = contact_joints_rel(&self.physics, reference, &mut self.fk);
        let Some(previous_rel) = self.previous_rel.replace(rel) else {
            // First frame: the reference pose standing on its lowest contact joint, at rest.
            self.pose = reference.pose.clone();
            self.pose.root_in_world_m = Vector3::zeros();
            place_on_floor(&self.physics, &mut self.pose, &CONTACT_JOINTS, &mut self.fk);
            self.v = DofVector::zeros();
            self.estimator.reset();
            self.contacts.clear();
            self.degraded.reset();
            *out = MotionEstimate::default();
            self.write_state(out);
            self.degraded.follow(reference);
            return Ok(StepReport::default());
        };
        let root_velocity = refined_root_velocity(
            &previous_rel,
            &rel,
            &reference.stationary_prob,
            &reference.root_velocity_mps,
        );
        let report = if self
            .physics_step(reference, &rel, &root_velocity, out)
            .is_some()
        {
            StepReport::default()
        } else {
            self.fall_back(reference, out)?
        };
        self.degraded.follow(reference);
        Ok(report)
    }
}

/// Number of generalized coordinates (for the docs' arithmetic).
const _: () = assert!(NUM_DOFS == 75);

#[cfg(test)]
mod tests;
