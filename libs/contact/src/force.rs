//! GlobalPose's force-based contact estimation (SIGGRAPH 2025 §3.3.2 "Contact estimation" and
//! "Re-tracking", Eq. 12–13; reference §5.4 steps 7–10), used by the optimizer between its pre-tracking
//! and re-tracking passes.
//!
//! The pre-tracking pass lets a virtual "rocket" on the root supply whatever wrench the motion needs:
//! the residual root wrench `r = (M·q̈ + h)[0..6]` (world force, then root torque in the root frame: the
//! first six generalized forces of `imuflow_body::dynamics`). This module explains `r` with contact forces
//! at the five contact joints ([`CONTACT_JOINTS`]: pelvis, left foot, right foot, left hand, right hand;
//! every per-joint array here is in that order):
//!
//! 1. **Contact determination** (step 7): a joint is *stationary* when its stationary probability
//!    exceeds 0.7; it is in contact when it is stationary and was in contact in the previous frame or
//!    touches the floor (its ground point less than 0.05 m above it). If any joint is in contact,
//!    stationary joints whose height is within 0.05 m of a contacting joint's join it. The other
//!    stationary joints are *potential* contacts. Pelvis veto: when either leg (knee − hip) is within
//!    45° of straight down the person is not sitting, and the pelvis is neither.
//! 2. **Explaining the residual** (step 8, Eq. 12): `min ½fᵀ(GᵀG + β·I)f − (Gᵀr)ᵀf` subject to the
//!    linearised friction cone, with `G = J_c[:, 0:6]ᵀ·B` (the root columns of the contact points'
//!    Jacobians) and per contact `B` the 3×4 friction-pyramid basis, columns `(μ, 1, 0)`, `(−μ, 1, 0)`,
//!    `(0, 1, μ)`, `(0, 1, −μ)` over `√(1 + μ²)`, `f ≥ 0`. A hand more than 0.15 m above the floor is a
//!    *grasp*: `B = I₃`, `f` unbounded (it may hold on to anything). `err = ‖G·f − r‖` (Eq. 13).
//! 3. **Adding potential contacts** (step 9), lowest first, while `err` > 400: try the joint; its
//!    counter counts consecutive frames in which adding it cut the error below 0.6 of the previous one
//!    (otherwise the counter restarts at 0); it is accepted from the 5th such frame on, and reverted
//!    before. Joints not tried in a frame restart their counter.
//! 4. **Target update** (step 10, [`ForceContactConfig::pull_target`]): a contacting joint's target
//!    less than 0.15 m above the floor is pulled 10 % of the way down to it each frame, and every target
//!    is kept above the floor.
//!
//! # Heights
//!
//! GlobalPose compares joint positions to `floor_y = −0.97`, tuned to SMPL, and lowers the pelvis point
//! by 0.15 m (step 4). Here every height is that of the joint's *ground point* above the floor (y = 0):
//! `ContactGeometry::height_above`, whose per-joint clearance already includes the 0.15 m pelvis drop.
//! The force acts at the ground point, so the optimizer passes the Jacobian of that point.
//!
//! # The QP solver
//!
//! At most 5 contacts × 4 pyramid coordinates = 20 variables, with only sign bounds and a strictly
//! positive definite Hessian (`β > 0`). We solve it exactly with a primal active-set method
//! ([`solve_bounded_qp`]): each iteration is a Cholesky solve on the free variables, on fixed-size
//! stack arrays (no allocation), and it converges in a handful of iterations. The original used OSQP;
//! clarabel (an interior-point solver) would work too, but it allocates per problem, stops at a
//! tolerance rather than at the exact optimum, and costs far more per call than this tiny problem
//! warrants (it is solved up to 4 times per frame).
//!
//! # Deviations from the original
//!
//! - **Grasp for both hands.** The original tests `contact index > 3`, which only the right hand
//!   (index 4) passes: an off-by-one, so its left hand never grasps (reference §5.4 step 8). Here both
//!   hands can grasp (`index ≥ 3`).
//! - The paper text accepts a potential contact when it "halves" the error; the code uses a ratio of 0.6
//!   ([`ForceContactConfig::accept_ratio`]). We follow the code.
//! - Heights against a per-joint clearance instead of a tuned floor height (see "Heights").

// Small dense kernels over parallel per-joint/per-variable arrays: index loops read like the maths.
#![allow(clippy::needless_range_loop)]

use imuflow_body::skeleton::CONTACT_JOINTS;
use nalgebra::{Matrix3, SMatrix, Vector3, Vector6};

/// Number of contact joints (pelvis, feet, hands).
pub const NUM_CONTACT_JOINTS: usize = CONTACT_JOINTS.len();

/// Largest number of force coordinates: 4 pyramid coordinates per contact joint.
pub const MAX_FORCE_VARIABLES: usize = 4 * NUM_CONTACT_JOINTS;

/// Index of the pelvis in [`CONTACT_JOINTS`].
const PELVIS: usize = 0;
/// Indices of the hands in [`CONTACT_JOINTS`] (the grasp candidates).
const FIRST_HAND: usize = 3;

/// Root columns of a contact point's Jacobian: `J_c[:, 0:6]` (world velocity of the point with respect
/// to the root's linear velocity (world) and angular velocity (root frame)).
pub type RootJacobian = SMatrix<f64, 3, 6>;

/// GlobalPose's contact-estimation constants. `Default` = the original's values (reference §5.4,
/// SIGGRAPH 2025 "Hyperparameters in physics optimizer").
#[derive(Clone, Debug, PartialEq)]
pub struct ForceContactConfig {
    /// Friction coefficient μ of the pyramid (reference §5.4: μ = 0.7).
    pub friction: f64,
    /// Regularization β_λ on the contact forces in Eq. 12 (reference §5.4: β_extforce = 0.4).
    pub force_regularization: f64,
    /// A joint is stationary above this probability (reference §5.4 step 1: s > 0.7).
    pub stationary_threshold: f64,
    /// A ground point lower than this above the floor touches it (reference §5.4 step 7: 0.05 m).
    pub touch_height_m: f64,
    /// Stationary joints within this height of a contacting joint join the contacts (step 7: 0.05 m).
    pub same_height_m: f64,
    /// Pelvis veto: a leg (knee − hip) within this angle of straight down means standing (step 7: π/4).
    pub pelvis_veto_angle_rad: f64,
    /// A hand higher than this above the floor grasps: unbounded force (step 8: 0.15 m).
    pub grasp_height_m: f64,
    /// Potential contacts are tried while the error exceeds this (N; step 9, e_th = 400).
    pub error_threshold: f64,
    /// Adding a potential contact counts when `err_new / err` is below this (step 9: 0.6).
    pub accept_ratio: f64,
    /// Consecutive counted frames before a potential contact is accepted (step 9: 5).
    pub accept_frames: u32,
    /// Targets of contacts lower than this above the floor are pulled down (step 10: d_th = 0.15 m).
    pub pull_height_m: f64,
    /// Fraction of the height removed per frame by the pull (step 10: 0.1).
    pub pull_rate: f64,
}

impl Default for ForceContactConfig {
    fn default() -> ForceContactConfig {
        ForceContactConfig {
            friction: 0.7,
            force_regularization: 0.4,
            stationary_threshold: 0.7,
            touch_height_m: 0.05,
            same_height_m: 0.05,
            pelvis_veto_angle_rad: std::f64::consts::FRAC_PI_4,
            grasp_height_m: 0.15,
            error_threshold: 400.0,
            accept_ratio: 0.6,
            accept_frames: 5,
            pull_height_m: 0.15,
            pull_rate: 0.1,
        }
    }
}

impl ForceContactConfig {
    /// Step 10: the new height above the floor of a target at `height_m` (ground point, m): pulled 10 %
    /// of the way down when the joint is in contact and lower than `pull_height_m`, then clamped ≥ 0.
    pub fn pull_target(&self, height_m: f64, in_contact: bool) -> f64 {
        let h = if in_contact && height_m < self.pull_height_m {
            height_m - self.pull_rate * height_m
        } else {
            height_m
        };
        h.max(0.0)
    }

    /// Friction-pyramid basis `B` (3×4): columns `(μ, 1, 0)`, `(−μ, 1, 0)`, `(0, 1, μ)`, `(0, 1, −μ)`
    /// over `√(1 + μ²)` (unit vectors on the cone's edges).
    pub fn pyramid(&self) -> SMatrix<f64, 3, 4> {
        let mu = self.friction;
        let c = 1.0 / (1.0 + mu * mu).sqrt();
        SMatrix::<f64, 3, 4>::from_columns(&[
            Vector3::new(mu, 1.0, 0.0) * c,
            Vector3::new(-mu, 1.0, 0.0) * c,
            Vector3::new(0.0, 1.0, mu) * c,
            Vector3::new(0.0, 1.0, -mu) * c,
        ])
    }
}

/// What the estimator needs about one frame (the optimizer's current state after pre-tracking).
#[derive(Clone, Debug, PartialEq)]
pub struct ForceInput {
    /// Stationary probability of each contact joint (the networks').
    pub stationary_prob: [f64; NUM_CONTACT_JOINTS],
    /// Height of each contact joint's ground point above the floor (m), current state.
    pub height_m: [f64; NUM_CONTACT_JOINTS],
    /// Root columns of each ground point's Jacobian.
    pub root_jacobian: [RootJacobian; NUM_CONTACT_JOINTS],
    /// [left, right] leg direction: knee − hip, world (for the pelvis veto).
    pub leg: [Vector3<f64>; 2],
    /// Residual root wrench of pre-tracking, `(M·q̈ + h)[0..6]`: world force (N), root torque in the
    /// root frame (N·m).
    pub residual: Vector6<f64>,
}

/// The result of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceEstimate {
    /// Joint in contact.
    pub contact: [bool; NUM_CONTACT_JOINTS],
    /// Contact joint grasping (a hand above `grasp_height_m`: unbounded force).
    pub grasp: [bool; NUM_CONTACT_JOINTS],
    /// Stationary joints that were not contacts after the rules (before step 9 tried them).
    pub potential: [bool; NUM_CONTACT_JOINTS],
    /// Force on the body at each contact joint's ground point (N, world); zero when not in contact.
    pub force: [Vector3<f64>; NUM_CONTACT_JOINTS],
    /// The part of the residual the forces explain, `G·f` (same coordinates as the residual).
    pub explained: Vector6<f64>,
    /// `err = ‖G·f − r‖` (Eq. 13).
    pub error: f64,
}

/// GlobalPose's force-based contact estimator: per-joint counters and the previous frame's contacts.
#[derive(Clone, Debug)]
pub struct ForceContactEstimator {
    pub config: ForceContactConfig,
    counters: [u32; NUM_CONTACT_JOINTS],
    previous: [bool; NUM_CONTACT_JOINTS],
}

impl ForceContactEstimator {
    pub fn new(config: ForceContactConfig) -> ForceContactEstimator {
        ForceContactEstimator {
            config,
            counters: [0; NUM_CONTACT_JOINTS],
            previous: [false; NUM_CONTACT_JOINTS],
        }
    }

    /// Forget the counters and the previous contacts (a new sequence).
    pub fn reset(&mut self) {
        self.counters = [0; NUM_CONTACT_JOINTS];
        self.previous = [false; NUM_CONTACT_JOINTS];
    }

    /// The contacts of the previous [`estimate`](Self::estimate) (the optimizer's tracking weights, step 5).
    pub fn previous_contacts(&self) -> [bool; NUM_CONTACT_JOINTS] {
        self.previous
    }

    /// The step-9 counters (consecutive frames in which adding each potential contact helped).
    pub fn counters(&self) -> [u32; NUM_CONTACT_JOINTS] {
        self.counters
    }

    /// Step 7: contacts and potential contacts from the stationary flags, the previous contacts and
    /// the heights, with the pelvis veto.
    pub fn determine(
        &self,
        input: &ForceInput,
    ) -> ([bool; NUM_CONTACT_JOINTS], [bool; NUM_CONTACT_JOINTS]) {
        let c = &self.config;
        let stationary = input.stationary_prob.map(|s| s > c.stationary_threshold);
        let mut contact = [false; NUM_CONTACT_JOINTS];
        for i in 0..NUM_CONTACT_JOINTS {
            contact[i] =
                stationary[i] && (self.previous[i] || input.height_m[i] < c.touch_height_m);
        }
        let touching = contact;
        if touching.iter().any(|&t| t) {
            for i in 0..NUM_CONTACT_JOINTS {
                if stationary[i] && !contact[i] {
                    contact[i] = (0..NUM_CONTACT_JOINTS).any(|k| {
                        touching[k]
                            && (input.height_m[i] - input.height_m[k]).abs() < c.same_height_m
                    });
                }
            }
        }
        let mut potential = [false; NUM_CONTACT_JOINTS];
        for i in 0..NUM_CONTACT_JOINTS {
            potential[i] = stationary[i] && !contact[i];
        }
        if (contact[PELVIS] || potential[PELVIS]) && input.leg.iter().any(|l| self.leg_down(l)) {
            contact[PELVIS] = false;
            potential[PELVIS] = false;
        }
        (contact, potential)
    }

    /// Whether a leg vector (knee − hip) is within the veto angle of straight down.
    fn leg_down(&self, leg: &Vector3<f64>) -> bool {
        let n = leg.norm();
        n > 0.0 && (-leg.y / n) > self.config.pelvis_veto_angle_rad.cos()
    }

    /// Steps 7–9 for one frame: determine the contacts, explain the residual, add potential contacts.
    /// Updates the counters and the previous contacts. Never panics; non-finite inputs give no contacts.
    pub fn estimate(&mut self, input: &ForceInput) -> ForceEstimate {
        let (mut contact, potential) = self.determine(input);
        let grasp: [bool; NUM_CONTACT_JOINTS] = std::array::from_fn(|i| {
            i >= FIRST_HAND && input.height_m[i] > self.config.grasp_height_m
        });
        let mut best = self.explain(input, &contact, &grasp);

        // Step 9: potential contacts, lowest first.
        let mut order: [usize; NUM_CONTACT_JOINTS] = std::array::from_fn(|i| i);
        order.sort_by(|&a, &b| input.height_m[a].total_cmp(&input.height_m[b]));
        let mut tried = [false; NUM_CONTACT_JOINTS];
        for &i in &order {
            if !potential[i] || best.error <= self.config.error_threshold {
                continue;
            }
            tried[i] = true;
            contact[i] = true;
            let candidate = self.explain(input, &contact, &grasp);
            if candidate.error / best.error < self.config.accept_ratio {
                self.counters[i] += 1;
            } else {
                self.counters[i] = 0;
            }
            if self.counters[i] >= self.config.accept_frames {
                best = candidate;
            } else {
                contact[i] = false;
            }
        }
        for i in 0..NUM_CONTACT_JOINTS {
            if !tried[i] {
                self.counters[i] = 0;
            }
        }
        if !best.error.is_finite() {
            contact = [false; NUM_CONTACT_JOINTS];
            best = Explained {
                force: [Vector3::zeros(); NUM_CONTACT_JOINTS],
                explained: Vector6::zeros(),
                error: input.residual.norm(),
            };
        }
        self.previous = contact;
        ForceEstimate {
            contact,
            grasp: std::array::from_fn(|i| grasp[i] && contact[i]),
            potential,
            force: best.force,
            explained: best.explained,
            error: best.error,
        }
    }

    /// Step 8 for a given contact set: the QP of Eq. 12 and its error (Eq. 13).
    fn explain(
        &self,
        input: &ForceInput,
        contact: &[bool; NUM_CONTACT_JOINTS],
        grasp: &[bool; NUM_CONTACT_JOINTS],
    ) -> Explained {
        let pyramid = self.config.pyramid();
        // Columns of G and the matching force directions (world).
        let mut g = [Vector6::<f64>::zeros(); MAX_FORCE_VARIABLES];
        let mut dir = [Vector3::<f64>::zeros(); MAX_FORCE_VARIABLES];
        let mut owner = [0usize; MAX_FORCE_VARIABLES];
        let mut bounded = [true; MAX_FORCE_VARIABLES];
        let mut n = 0;
        for i in 0..NUM_CONTACT_JOINTS {
            if !contact[i] {
                continue;
            }
            let jt = input.root_jacobian[i].transpose();
            if grasp[i] {
                for (k, d) in Matrix3::<f64>::identity().column_iter().enumerate() {
                    dir[n + k] = d.into_owned();
                    g[n + k] = jt * d;
                    owner[n + k] = i;
                    bounded[n + k] = false;
                }
                n += 3;
            } else {
                for (k, d) in pyramid.column_iter().enumerate() {
                    dir[n + k] = d.into_owned();
                    g[n + k] = jt * d;
                    owner[n + k] = i;
                }
                n += 4;
            }
        }
        let mut h = [[0.0; MAX_FORCE_VARIABLES]; MAX_FORCE_VARIABLES];
        let mut lin = [0.0; MAX_FORCE_VARIABLES];
        for a in 0..n {
            for b in 0..n {
                h[a][b] = g[a].dot(&g[b]);
            }
            h[a][a] += self.config.force_regularization;
            lin[a] = g[a].dot(&input.residual);
        }
        let mut f = [0.0; MAX_FORCE_VARIABLES];
        solve_bounded_qp(&h, &lin, &bounded[..n], &mut f[..n]);
        let mut out = Explained {
            force: [Vector3::zeros(); NUM_CONTACT_JOINTS],
            explained: Vector6::zeros(),
            error: 0.0,
        };
        for k in 0..n {
            out.force[owner[k]] += dir[k] * f[k];
            out.explained += g[k] * f[k];
        }
        out.error = (out.explained - input.residual).norm();
        out
    }
}

/// Forces and error of one contact set.
struct Explained {
    force: [Vector3<f64>; NUM_CONTACT_JOINTS],
    explained: Vector6<f64>,
    error: f64,
}

/// Minimise `½xᵀHx − linᵀx` subject to `x_k ≥ 0` where `bounded[k]` (the other variables are free), for
/// `H` symmetric positive definite. `n = bounded.len()` ≤ [`MAX_FORCE_VARIABLES`]; only the leading
/// `n × n` block of `h` and the first `n` of `lin` are read; the solution goes to `x` (length `n`).
///
/// Primal active-set method (Nocedal & Wright, *Numerical Optimization*, Alg. 16.3) from `x = 0`: solve
/// the equality-constrained problem on the free set by Cholesky; step to it, stopping at the first bound
/// it crosses (which joins the active set); at a subproblem optimum release the active bound with the
/// most negative multiplier, or stop when none is negative. Exact up to rounding, allocation-free. On
/// a non-finite input or after 100 iterations `x` holds the last feasible iterate.
pub fn solve_bounded_qp(
    h: &[[f64; MAX_FORCE_VARIABLES]; MAX_FORCE_VARIABLES],
    lin: &[f64; MAX_FORCE_VARIABLES],
    bounded: &[bool],
    x: &mut [f64],
) {
    let n = bounded.len();
    assert!(n <= MAX_FORCE_VARIABLES && x.len() == n, "QP size");
    x.fill(0.0);
    // Active set: bounded variables held at 0. Start with all bounded variables active.
    let mut active = [false; MAX_FORCE_VARIABLES];
    active[..n].copy_from_slice(bounded);
    for _ in 0..100 {
        // Subproblem: H_FF·p_F = lin_F (p_A = 0).
        let mut p = [0.0; MAX_FORCE_VARIABLES];
        if !solve_free(h, lin, &active[..n], &mut p[..n]) {
            return;
        }
        let reached = (0..n).all(|k| active[k] || !bounded[k] || p[k] >= 0.0);
        if reached {
            x.copy_from_slice(&p[..n]);
            // Multipliers of the active bounds: ∇ = H·x − lin ≥ 0 at the optimum.
            let mut release = None;
            let mut most = -1e-12 * (1.0 + lin[..n].iter().map(|v| v.abs()).fold(0.0, f64::max));
            for k in 0..n {
                if active[k] {
                    let grad: f64 = (0..n).map(|m| h[k][m] * x[m]).sum::<f64>() - lin[k];
                    if grad < most {
                        most = grad;
                        release = Some(k);
                    }
                }
            }
            match release {
                Some(k) => active[k] = false,
                None => return,
            }
        } else {
            // Step from x toward p, stopping at the first bound.
            let mut alpha = 1.0;
            let mut blocking = None;
            for k in 0..n {
                if !active[k] && bounded[k] && p[k] < 0.0 {
                    let a = x[k] / (x[k] - p[k]);
                    if a < alpha {
                        alpha = a;
                        blocking = Some(k);
                    }
                }
            }
            for k in 0..n {
                x[k] += alpha * (p[k] - x[k]);
            }
            if let Some(k) = blocking {
                active[k] = true;
                x[k] = 0.0;
            }
        }
    }
}

/// `H_FF·p_F = lin_F` on the free variables (not `active`), `p_A = 0`. False when `H_FF` is not
/// positive definite or something is not finite.
fn solve_free(
    h: &[[f64; MAX_FORCE_VARIABLES]; MAX_FORCE_VARIABLES],
    lin: &[f64; MAX_FORCE_VARIABLES],
    active: &[bool],
    p: &mut [f64],
) -> bool {
    let n = active.len();
    let mut idx = [0usize; MAX_FORCE_VARIABLES];
    let mut m = 0;
    for k in 0..n {
        if !active[k] {
            idx[m] = k;
            m += 1;
        }
    }
    // Cholesky L·Lᵀ of the free block, in place (lower triangle).
    let mut l = [[0.0; MAX_FORCE_VARIABLES]; MAX_FORCE_VARIABLES];
    for a in 0..m {
        for b in 0..=a {
            let mut s = h[idx[a]][idx[b]];
            for c in 0..b {
                s -= l[a][c] * l[b][c];
            }
            if a == b {
                if s.is_nan() || s <= 0.0 {
                    return false;
                }
                l[a][a] = s.sqrt();
            } else {
                l[a][b] = s / l[b][b];
            }
        }
    }
    let mut y = [0.0; MAX_FORCE_VARIABLES];
    for a in 0..m {
        let mut s = lin[idx[a]];
        for c in 0..a {
            s -= l[a][c] * y[c];
        }
        y[a] = s / l[a][a];
    }
    for a in (0..m).rev() {
        let mut s = y[a];
        for c in a + 1..m {
            s -= l[c][a] * y[c];
        }
        y[a] = s / l[a][a];
    }
    p.fill(0.0);
    for a in 0..m {
        p[idx[a]] = y[a];
    }
    p.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Root columns of the Jacobian of a point at `d` from the root (root rotation = identity):
    /// `[I | −[d]×]`.
    fn root_jacobian(d: Vector3<f64>) -> RootJacobian {
        let mut j = RootJacobian::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&-d.cross_matrix());
        j
    }

    /// Standing: pelvis 0.95 m above the floor, feet 0.1 m to each side under it, hands at the sides.
    fn standing(residual: Vector6<f64>) -> ForceInput {
        let down = Vector3::new(0.0, -1.0, 0.0);
        ForceInput {
            stationary_prob: [0.0, 0.9, 0.9, 0.0, 0.0],
            height_m: [0.8, 0.0, 0.0, 0.8, 0.8],
            root_jacobian: [
                root_jacobian(Vector3::new(0.0, -0.15, 0.0)),
                root_jacobian(Vector3::new(0.1, -0.95, 0.0)),
                root_jacobian(Vector3::new(-0.1, -0.95, 0.0)),
                root_jacobian(Vector3::new(0.3, -0.1, 0.0)),
                root_jacobian(Vector3::new(-0.3, -0.1, 0.0)),
            ],
            leg: [down, down],
            residual,
        }
    }

    fn weight() -> Vector6<f64> {
        Vector6::new(0.0, 70.0 * 9.81, 0.0, 0.0, 0.0, 0.0)
    }

    #[test]
    fn force_weight_on_two_feet_splits_evenly() {
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        let out = est.estimate(&standing(weight()));
        assert_eq!(out.contact, [false, true, true, false, false]);
        let (l, r) = (out.force[1], out.force[2]);
        // Mirror symmetry (x → −x): equal vertical forces, opposite lateral ones.
        assert!((l.y - r.y).abs() < 1e-6 * l.y, "{l} {r}");
        assert!((l.x + r.x).abs() < 1e-6 * l.y && l.z.abs() < 1e-6 * l.y);
        // Hand-derived: the 8 edge columns g_k of G sum to (0, 8/c, 0, 0, 0, 0) (c = √(1+μ²); lateral
        // parts cancel within a foot, the feet's torques cancel each other), so the vertical e_y is an
        // eigenvector of G·Gᵀ with λ = 8/c², and G·f = G·Gᵀ(G·Gᵀ + β)⁻¹·r = λ/(λ + β)·r: the
        // regularization leaves about 7 % of the weight unexplained.
        let mg = 70.0 * 9.81;
        let lambda = 8.0 / (1.0 + 0.7 * 0.7);
        let sum = (l.y + r.y) / mg;
        assert!(sum > 0.9 && sum < 1.0, "{sum}");
        assert!(
            (sum - lambda / (lambda + 0.4)).abs() < 1e-9,
            "{sum} vs {}",
            lambda / (lambda + 0.4)
        );
        // The error is what is left and below the threshold that would look for more contacts.
        assert!((out.error - (out.explained - weight()).norm()).abs() < 1e-9);
        assert!(out.error < 0.1 * mg, "{}", out.error);
    }

    #[test]
    fn force_grasp_at_the_root_shrinks_by_the_regularization() {
        // One grasping hand at the root: G = [I; 0], so f = r_f/(1 + β), err = β/(1 + β)·|r_f|.
        let mut input = standing(Vector6::new(30.0, -40.0, 50.0, 0.0, 0.0, 0.0));
        input.stationary_prob = [0.0, 0.0, 0.0, 0.0, 0.9];
        input.root_jacobian[4] = root_jacobian(Vector3::zeros());
        input.height_m[4] = 0.0; // touching: a contact; not grasping below 0.15 m
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        assert!(!est.estimate(&input).grasp[4]);
        input.height_m[4] = 1.0; // above: grasping, but only a contact if it was one before
        let out = est.estimate(&input);
        assert!(out.contact[4] && out.grasp[4]);
        let want = Vector3::new(30.0, -40.0, 50.0) / 1.4;
        assert!((out.force[4] - want).norm() < 1e-9, "{}", out.force[4]);
        assert!((out.error - 0.4 / 1.4 * 50.0_f64.sqrt() * 10.0).abs() < 1e-9);
        // The left hand grasps too (the original's off-by-one let only the right hand).
        input.stationary_prob = [0.0, 0.0, 0.0, 0.9, 0.0];
        input.root_jacobian[3] = root_jacobian(Vector3::zeros());
        input.height_m[3] = 0.0;
        est.reset();
        est.estimate(&input);
        input.height_m[3] = 1.0;
        let out = est.estimate(&input);
        assert!(out.grasp[3] && (out.force[3] - want).norm() < 1e-9);
    }

    #[test]
    fn force_horizontal_push_beyond_the_cone_leaves_the_hand_derived_error() {
        // One foot at the root (no torque), a pure sideways residual F: only the edge (μ, 1, 0)/c
        // helps; f₁ = (μ/c)·F/(1 + β) since |(μ, 1)/c| = 1, and e = B·f − r.
        let (mu, beta, big_f) = (0.7_f64, 0.4, 500.0);
        let c = (1.0 + mu * mu).sqrt();
        let mut input = standing(Vector6::new(big_f, 0.0, 0.0, 0.0, 0.0, 0.0));
        input.stationary_prob = [0.0, 0.9, 0.0, 0.0, 0.0];
        input.root_jacobian[1] = root_jacobian(Vector3::zeros());
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        let out = est.estimate(&input);
        let f1 = mu / c * big_f / (1.0 + beta);
        let want_force = Vector3::new(mu, 1.0, 0.0) / c * f1;
        assert!(
            (out.force[1] - want_force).norm() < 1e-9,
            "{}",
            out.force[1]
        );
        let want_err = (Vector3::new(mu * f1 / c - big_f, f1 / c, 0.0)).norm();
        assert!(
            (out.error - want_err).abs() < 1e-9,
            "{} {want_err}",
            out.error
        );
        // The force stays in the cone: |f_x| ≤ μ·f_y.
        assert!(out.force[1].x <= mu * out.force[1].y + 1e-9);
    }

    #[test]
    fn force_a_moving_foot_is_never_a_contact() {
        let mut input = standing(weight());
        input.stationary_prob = [0.0, 0.65, 0.9, 0.0, 0.0];
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        for _ in 0..10 {
            let out = est.estimate(&input);
            assert!(!out.contact[1] && !out.potential[1] && out.force[1] == Vector3::zeros());
            assert!(out.contact[2]);
        }
    }

    #[test]
    fn force_same_height_joins_and_previous_contact_persists() {
        let mut input = standing(weight());
        // The left foot 3 cm above the floor (too high to touch), the right on it: same height.
        input.height_m[1] = 0.07;
        input.height_m[2] = 0.04;
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        assert_eq!(
            est.estimate(&input).contact,
            [false, true, true, false, false]
        );
        // Lifted to 0.3 m but still stationary: held because it was in contact.
        input.height_m[1] = 0.3;
        assert!(est.estimate(&input).contact[1]);
        est.reset();
        assert!(!est.estimate(&input).contact[1]);
    }

    #[test]
    fn force_potential_contact_accepted_on_the_fifth_frame_not_the_fourth() {
        // Sitting: the feet are moving, the pelvis is stationary 0.5 m above the floor (a chair) with
        // thighs horizontal; pre-tracking needs the weight on the root.
        let mut input = standing(weight());
        input.stationary_prob = [0.9, 0.0, 0.0, 0.0, 0.0];
        input.height_m[0] = 0.5;
        input.leg = [Vector3::new(0.0, 0.0, 0.4); 2];
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        for frame in 1..=4 {
            let out = est.estimate(&input);
            assert!(out.potential[0] && !out.contact[0], "frame {frame}");
            assert_eq!(est.counters()[0], frame);
            assert!((out.error - weight().norm()).abs() < 1e-9);
        }
        let out = est.estimate(&input);
        assert!(out.contact[0], "accepted on the 5th frame");
        assert!(out.force[0].y > 0.5 * 70.0 * 9.81 && out.error < 400.0);
        // From then on it is a contact by the previous-contact rule.
        assert!(est.estimate(&input).contact[0]);
        // A frame without help resets the counter.
        est.reset();
        for _ in 0..3 {
            est.estimate(&input);
        }
        input.residual = Vector6::zeros(); // nothing to explain: not tried
        est.estimate(&input);
        assert_eq!(est.counters()[0], 0);
    }

    #[test]
    fn force_pelvis_veto_when_a_leg_points_down() {
        let mut input = standing(weight());
        input.stationary_prob = [0.9, 0.0, 0.0, 0.0, 0.0];
        input.height_m[0] = 0.0; // pelvis ground point on the floor
        let mut est = ForceContactEstimator::new(ForceContactConfig::default());
        // One leg 40° from straight down: vetoed.
        let a = 40f64.to_radians();
        input.leg = [
            Vector3::new(0.0, -a.cos(), a.sin()),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let (contact, potential) = est.determine(&input);
        assert!(!contact[0] && !potential[0]);
        // Both legs 50° from down (sitting on the floor with bent knees): the pelvis is a contact.
        let b = 50f64.to_radians();
        input.leg = [Vector3::new(0.0, -b.cos(), b.sin()); 2];
        assert!(est.estimate(&input).contact[0]);
    }

    #[test]
    fn force_target_pull_and_clamp() {
        let c = ForceContactConfig::default();
        assert!((c.pull_target(0.1, true) - 0.09).abs() < 1e-12);
        assert_eq!(c.pull_target(0.1, false), 0.1);
        assert_eq!(c.pull_target(0.2, true), 0.2);
        assert_eq!(c.pull_target(-0.02, false), 0.0);
    }

    #[test]
    fn force_qp_matches_brute_force_enumeration() {
        // Random 6-variable QPs: the active-set optimum equals the best KKT point over all 2⁶ active
        // sets (the unique point that is feasible with nonnegative multipliers).
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        for _ in 0..20 {
            let n = 6;
            let a: [[f64; 6]; 6] = std::array::from_fn(|_| std::array::from_fn(|_| rnd()));
            let mut h = [[0.0; MAX_FORCE_VARIABLES]; MAX_FORCE_VARIABLES];
            let mut lin = [0.0; MAX_FORCE_VARIABLES];
            for i in 0..n {
                for j in 0..n {
                    h[i][j] = (0..n).map(|k| a[k][i] * a[k][j]).sum::<f64>();
                }
                h[i][i] += 0.4;
                lin[i] = rnd() * 10.0;
            }
            let bounded = [true, true, true, true, false, true];
            let mut x = [0.0; 6];
            solve_bounded_qp(&h, &lin, &bounded, &mut x);
            let obj = |x: &[f64]| {
                let mut o = 0.0;
                for i in 0..n {
                    o -= lin[i] * x[i];
                    for j in 0..n {
                        o += 0.5 * x[i] * h[i][j] * x[j];
                    }
                }
                o
            };
            let mut best = f64::INFINITY;
            for mask in 0..(1u32 << n) {
                let active: [bool; 6] = std::array::from_fn(|k| bounded[k] && mask & (1 << k) != 0);
                if (0..n).any(|k| !bounded[k] && mask & (1 << k) != 0) {
                    continue;
                }
                let mut p = [0.0; 6];
                if solve_free(&h, &lin, &active, &mut p)
                    && (0..n).all(|k| !bounded[k] || p[k] >= -1e-12)
                {
                    best = best.min(obj(&p));
                }
            }
            assert!(x.iter().zip(bounded).all(|(v, b)| !b || *v >= 0.0));
            assert!(
                (obj(&x) - best).abs() < 1e-9 * (1.0 + best.abs()),
                "{} {best}",
                obj(&x)
            );
        }
    }
}
