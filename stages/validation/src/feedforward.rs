//! Feed-forward joint torques: the torques that would make the body perform the estimate's motion,
//! by inverse dynamics on the estimate itself, with the floor taking the root's share.
//!
//! A PD motor only pushes once the joint lags its target: it must be wrong to act. Walking loads
//! the stance leg with the whole body weight and every landing with more, so a PD body tracks each
//! step late, lands hard and loses the rhythm within two or three steps. Adding the torques the
//! motion needs (computed-torque control) leaves the PD only the errors to correct.
//!
//! Per frame, from the last three estimates (finite differences, so the acceleration lags half a
//! frame):
//! 1. `τ = M(q)·v̇ + h(q, v)` by recursive Newton–Euler on the body model the optimizer uses
//!    (`imuflow_body::dynamics`; the rapier body is built from the same segments). Its first six
//!    rows are the wrench the root needs, which only the floor can give.
//! 2. The floor's share: contact forces `λ` at the sole corners of the estimate's feet that touch
//!    the floor, inside a friction pyramid, such that `Σ J_kᵀλ_k` matches the root wrench as
//!    closely as possible (non-negative least squares over the pyramid's edges, projected
//!    Gauss–Seidel; a few dozen unknowns).
//! 3. The joints' feed-forward torques `τ − Σ J_kᵀλ_k` (rows past the root). Whatever root wrench
//!    the floor cannot give (a flight phase, an implausible estimate) is dropped: nothing acts on
//!    the root in torques mode.
//!
//! The simulation adds these torques to its PD motors ([`crate::Simulation::set_feedforward`]).

use std::collections::VecDeque;

use imuflow_body::BodyModel;
use imuflow_body::dynamics::{DofVector, DynamicsData, PointJacobian, RigidBodyModel, joint_dof};
use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::{JointId, NUM_JOINTS};
use nalgebra::{DMatrix, DVector, Vector3};

/// A sole corner touches the floor when the estimate has it this low, m. [inferred: the data's
/// stance feet stand a few degrees toe-down, which lifts the heel corners 2-3 cm]
const CONTACT_HEIGHT_M: f64 = 0.04;
/// Friction coefficient of the pyramid, below the simulation's floor friction (0.8) so the
/// planned forces do not rely on the edge of the cone. [inferred]
const PLANNING_FRICTION: f64 = 0.6;
/// Half the width of the sole at 1.75 m stature, m (the foot box is 4.5 cm). [inferred]
const SOLE_HALF_WIDTH_M: f64 = 0.04;
/// Regularisation of the contact forces (per unit of pyramid-edge force², relative to the
/// wrench residual): picks the smallest forces among equally good ones.
const FORCE_REGULARISATION: f64 = 1e-6;
/// Projected Gauss–Seidel sweeps of the force distribution.
const SWEEPS: usize = 60;
/// The torque rows of the root wrench count this much more than its force rows (N·m against N:
/// a 10 cm lever).
const TORQUE_ROW_WEIGHT: f64 = 10.0;

/// Inverse dynamics of the estimate, one frame at a time.
pub struct Feedforward {
    model: RigidBodyModel,
    data: DynamicsData,
    /// The last three estimates, oldest first.
    history: VecDeque<Pose>,
    /// Sole corners in each ankle's frame, [left, right] × [heel out, heel in, ball out, ball in].
    corners: [[Vector3<f64>; 4]; 2],
    /// The joints' feed-forward torques in their own frames (root: zero), N·m.
    torque: [Vector3<f64>; NUM_JOINTS],
    /// The share of the root's needed force the floor could give in the last frame (0-1).
    pub floor_share: f64,
}

const ANKLES: [JointId; 2] = [JointId::LEFT_ANKLE, JointId::RIGHT_ANKLE];
const BALLS: [JointId; 2] = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT];

impl Feedforward {
    pub fn new(body: &BodyModel) -> Feedforward {
        let rest = body.rest_positions_on_floor_m();
        let half_width = SOLE_HALF_WIDTH_M * body.stature_m / 1.75;
        let corners = [0, 1].map(|side| {
            let ankle = rest[ANKLES[side].index()];
            let ball = rest[BALLS[side].index()];
            // The heel is 0.25 foot lengths behind the ankle, the ball 0.45 ahead (body_model.rs,
            // models/body.toml); the rest pose stands on y = 0 with every frame world-aligned.
            let foot_length = (ball.z - ankle.z) / 0.45;
            let heel = Vector3::new(ankle.x, 0.0, ankle.z - 0.25 * foot_length);
            let ball = Vector3::new(ball.x, 0.0, ball.z);
            let dx = Vector3::new(half_width, 0.0, 0.0);
            [heel + dx, heel - dx, ball + dx, ball - dx].map(|p| p - ankle)
        });
        Feedforward {
            model: RigidBodyModel::new(body),
            data: DynamicsData::new(),
            history: VecDeque::with_capacity(3),
            corners,
            torque: [Vector3::zeros(); NUM_JOINTS],
            floor_share: 0.0,
        }
    }

    /// Forgets the history (a gap in the estimate: its differences would be meaningless).
    pub fn clear(&mut self) {
        self.history.clear();
    }

    /// Takes the next estimate (`dt` after the previous one) and returns the joints' feed-forward
    /// torques, each in its joint's own frame; `None` until three estimates are known.
    pub fn update(&mut self, pose: &Pose, dt: f64) -> Option<&[Vector3<f64>; NUM_JOINTS]> {
        if self.history.len() == 3 {
            self.history.pop_front();
        }
        self.history.push_back(pose.clone());
        if self.history.len() < 3 || dt <= 0.0 {
            return None;
        }
        let v_before = velocity(&self.history[0], &self.history[1], dt);
        let v = velocity(&self.history[1], &self.history[2], dt);
        let vdot = (v - v_before) / dt;
        if !vdot.iter().all(|x| x.is_finite()) {
            return None;
        }
        let pose = self.history[2].clone();
        Some(self.plan(&pose, &v, &vdot))
    }

    /// Inverse dynamics at `(pose, v)` for `vdot`, the floor taking the root rows.
    fn plan(
        &mut self,
        pose: &Pose,
        v: &DofVector,
        vdot: &DofVector,
    ) -> &[Vector3<f64>; NUM_JOINTS] {
        self.data.set_state(&self.model, pose, v);
        let mut tau = DofVector::zeros();
        self.data.inverse_dynamics(&self.model, vdot, &mut tau);
        self.take_floor_share(&mut tau);
        for j in JointId::all() {
            let k = joint_dof(j);
            self.torque[j.index()] = Vector3::new(tau[k], tau[k + 1], tau[k + 2]);
        }
        self.torque[0] = Vector3::zeros();
        &self.torque
    }

    /// Subtracts from `tau` the generalized forces of the floor contact forces that best supply
    /// its root rows (see the module docs).
    fn take_floor_share(&mut self, tau: &mut DofVector) {
        // Each touching corner contributes four pyramid edges `d = n + μ·t` (n up, t horizontal).
        let edges = [
            Vector3::new(PLANNING_FRICTION, 1.0, 0.0),
            Vector3::new(-PLANNING_FRICTION, 1.0, 0.0),
            Vector3::new(0.0, 1.0, PLANNING_FRICTION),
            Vector3::new(0.0, 1.0, -PLANNING_FRICTION),
        ];
        let mut columns: Vec<DofVector> = Vec::with_capacity(32);
        let mut jacobian = PointJacobian::zeros();
        for (side, ankle) in ANKLES.into_iter().enumerate() {
            for corner in &self.corners[side] {
                if self.data.point_position(ankle, corner).y > CONTACT_HEIGHT_M {
                    continue;
                }
                self.data.point_jacobian(ankle, corner, &mut jacobian);
                for d in &edges {
                    columns.push(jacobian.transpose() * d);
                }
            }
        }
        self.floor_share = 0.0;
        if columns.is_empty() {
            return;
        }
        let weight = |row: usize| if row < 3 { 1.0 } else { TORQUE_ROW_WEIGHT };
        let n = columns.len();
        let g = DMatrix::from_fn(6, n, |r, c| weight(r) * columns[c][r]);
        let w = DVector::from_fn(6, |r, _| weight(r) * tau[r]);
        let mut q = g.transpose() * &g;
        let scale = q.diagonal().max().max(1e-12);
        for i in 0..n {
            q[(i, i)] += FORCE_REGULARISATION * scale;
        }
        let c = g.transpose() * &w;
        let beta = non_negative_least_squares(&q, &c, SWEEPS);
        let mut floor = DofVector::zeros();
        for (b, column) in beta.iter().zip(&columns) {
            floor += *b * column;
        }
        let needed = Vector3::new(tau[0], tau[1], tau[2]);
        let given = Vector3::new(floor[0], floor[1], floor[2]);
        self.floor_share = if needed.norm() > 1e-9 {
            (given.dot(&needed) / needed.norm_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        *tau -= floor;
    }
}

/// `min ½βᵀQβ − cᵀβ` over `β ≥ 0` by projected Gauss–Seidel (Q symmetric positive definite).
/// Hand-written: a few dozen unknowns, bounds only, solved every frame; a general QP solver's
/// set-up would cost more than the solve.
fn non_negative_least_squares(q: &DMatrix<f64>, c: &DVector<f64>, sweeps: usize) -> DVector<f64> {
    let n = c.len();
    let mut beta = DVector::zeros(n);
    for _ in 0..sweeps {
        for i in 0..n {
            let residual = c[i] - q.row(i).transpose().dot(&beta) + q[(i, i)] * beta[i];
            beta[i] = (residual / q[(i, i)]).max(0.0);
        }
    }
    beta
}

/// The generalized velocity (`imuflow_body::dynamics` coordinates) that takes `from` to `to` in
/// `dt`: the root's world velocity, then each joint's angular velocity relative to its parent in
/// its own frame (`R(t) = R(t−dt)·exp([ω]·dt)`).
fn velocity(from: &Pose, to: &Pose, dt: f64) -> DofVector {
    let mut v = DofVector::zeros();
    let root = (to.root_in_world_m - from.root_in_world_m) / dt;
    v.fixed_rows_mut::<3>(0).copy_from(&root);
    for j in JointId::all() {
        let i = j.index();
        let w = axis_angle_from_rotation(
            &(from.parent_from_joint[i].inverse() * to.parent_from_joint[i]),
        ) / dt;
        v.fixed_rows_mut::<3>(joint_dof(j)).copy_from(&w);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::body_model::BodyParams;
    use nalgebra::Rotation3;

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
    }

    #[test]
    fn projected_gauss_seidel_finds_the_bounded_optimum() {
        // min ½(β0² + β1²) − (2β0 − 3β1) over β ≥ 0: β = (2, 0), checked by hand.
        let q = DMatrix::identity(2, 2);
        let c = DVector::from_vec(vec![2.0, -3.0]);
        let beta = non_negative_least_squares(&q, &c, 10);
        assert!((beta[0] - 2.0).abs() < 1e-12 && beta[1] == 0.0, "{beta}");
    }

    #[test]
    fn standing_still_the_feet_carry_the_weight_and_the_joints_hold_the_pose() {
        let body = body();
        let mut ff = Feedforward::new(&body);
        let pose = Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m, 0.0));
        for _ in 0..2 {
            assert!(ff.update(&pose, 1.0 / 60.0).is_none());
        }
        let torque = *ff.update(&pose, 1.0 / 60.0).expect("three frames");
        // The floor gives the whole weight (the root needs nothing else at rest).
        assert!(ff.floor_share > 0.99, "floor share {}", ff.floor_share);
        // A T-pose's arms are held out: each shoulder carries its arm's weight times its lever,
        // by hand from the model's segments (forward kinematics of the rest pose).
        let model = RigidBodyModel::new(&body);
        let mut data = DynamicsData::new();
        data.set_state(&model, &pose, &DofVector::zeros());
        for shoulder in [JointId::LEFT_SHOULDER, JointId::RIGHT_SHOULDER] {
            let at = data.fk().joint_in_world_m[shoulder.index()];
            let mut moment = Vector3::zeros();
            let mut subtree = vec![shoulder];
            while let Some(j) = subtree.pop() {
                let link = model.link(j);
                let com = data.point_position(j, &link.com_in_joint_m);
                moment += (com - at).cross(&Vector3::new(0.0, -link.mass_kg * 9.81, 0.0));
                subtree.extend(j.children());
            }
            // The joint must supply the opposite of gravity's moment (frames are world-aligned).
            let held = torque[shoulder.index()];
            assert!(
                (held + moment).norm() < 0.02 * moment.norm(),
                "{shoulder:?}: {held} against gravity's {moment}"
            );
        }
    }

    #[test]
    fn in_the_air_the_floor_gives_nothing() {
        let body = body();
        let mut ff = Feedforward::new(&body);
        let mut pose = Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m + 0.3, 0.0));
        pose.parent_from_joint[JointId::LEFT_KNEE.index()] =
            Rotation3::from_euler_angles(0.3, 0.0, 0.0);
        for _ in 0..3 {
            ff.update(&pose, 1.0 / 60.0);
        }
        assert_eq!(ff.floor_share, 0.0);
    }
}
