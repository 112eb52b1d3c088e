//! Assembly and solution of PIP's per-frame QP (see the module docs of [`super`]).
//!
//! The QP is assembled once per solve as
//! - the cost on `v̇`: `½v̇ᵀP_aa·v̇ + q_aᵀv̇` (rotation and position PD), the weights of the force
//!   penalty per λ component and of the torque regulariser per DoF;
//! - `M`, `h` and the contact Jacobians `J_k` of the equation of motion `τ = M·v̇ + h − Σ_k J_kᵀλ_k`;
//! - the inequality rows `C·z ≤ d` over `z = [v̇ (75), λ (3 per point)]` (friction pyramid on λ,
//!   velocity bounds on v̇).
//!
//! and solved in one of two exactly equivalent ways ([`Formulation`]):
//! - **Reduced** (default): τ substituted, `z = [v̇, λ]` with the dense Hessian
//!   `H = blockdiag(P_aa, diag(w_λ²)) + BᵀB`, `B = [W·M, −W·J_cᵀ]` (`W` the torque weights), and
//!   gradient `g = [q_a, 0] + Bᵀ·W·h`. `H = LLᵀ` (Cholesky). The unconstrained optimum is
//!   `z_u = −H⁻¹g`; with inequalities, a dense interior-point method solves the dual
//!   `min_{μ≥0} ½μᵀ(X̃ᵀX̃)μ + (d̃ − C̃·z_u)ᵀμ`, `X̃ = L⁻¹C̃ᵀ` (rows of `C` scaled to unit `‖L⁻¹cᵢ‖`: a
//!   unit-diagonal dual Hessian), and `z = z_u − L⁻ᵀ·X̃·μ`. One variable per inequality row
//!   (~44 with both feet in contact), bound constraints only (the `bound_qp` module; clarabel
//!   when it does not converge).
//! - **Full**: the original form, clarabel on `x = [v̇, λ, τ]` with the equation of motion as 75
//!   equality rows (`min ½xᵀPx + qᵀx` s.t. `A·x + s = b`, `s ∈ {0}^75 × R₊^m`). Used when `H` is not
//!   numerically positive definite (a zero torque or force weight) and as the tests' reference.
//!
//! Both end the same way: `τ = M·v̇ + h − Σ_k J_kᵀλ_k` from the solved `v̇`, `λ` (so the equation of
//! motion holds to rounding), and the fallback checks on `x = [v̇, λ, τ]`.

use imuflow_body::rotation::axis_angle_from_rotation;
use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
    ZeroConeT,
};
use imuflow_body::dynamics::{
    DofVector, DynamicsData, MassMatrix, NUM_DOFS, PointJacobian, joint_dof,
};
use imuflow_body::kinematics::local_to_global_rotations;
use imuflow_body::skeleton::SIP_JOINTS;
use imuflow_body::{Imu, JointId, NUM_JOINTS, Pose};
use imuflow_contact::ContactSet;
use imuflow_contact::pip::FEET;
use imuflow_graph::frames::MAX_CONTACT_POINTS;
use nalgebra::{DMatrix, DVector, Rotation3, Vector3};

use super::{POSITION_PD_JOINTS, PipConfig, bound_qp};
use crate::cholesky::{ColumnCholesky, add_four_columns};
use crate::wide::with_avx2;
use crate::{PhysicsBody, Reference};

/// What the solver reported for one step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveStats {
    /// The interior-point iterations of the last solve (0 when it had no inequality rows, which
    /// the reduced formulation solves in closed form).
    pub iterations: u32,
    /// Wall time of the last solve (s) after assembly: reduction, factorisations, interior point, recovery.
    pub solve_time_s: f64,
    /// Variables and constraint rows of the last solve: `[v̇, λ]` and the inequality rows for the
    /// reduced formulation, `[v̇, λ, τ]` and equality + inequality rows for the full one.
    pub variables: usize,
    pub constraints: usize,
}

/// A solved step.
pub struct Solution {
    /// Generalized acceleration v̇.
    pub acceleration: DofVector,
    /// Per contact point, the force on the body (N, M).
    pub forces: [Vector3<f64>; MAX_CONTACT_POINTS],
    /// Generalized force from the equation of motion (root virtual force/torque, joint torques).
    pub tau: DofVector,
}

/// How [`Qp::solve_with`] solves the (same) QP; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Formulation {
    /// τ eliminated, the dual of the QP in `[v̇, λ]` (the default).
    Reduced,
    /// The original QP in `[v̇, λ, τ]` with the equation of motion as equalities (chosen by the tests;
    /// the reduced path falls back to it internally).
    #[cfg_attr(not(test), allow(dead_code))]
    Full,
}

enum Reduced {
    Solved(Vec<f64>, u32),
    Failed,
    NotPositiveDefinite,
}

/// Reusable buffers of the QP.
pub struct Qp {
    /// Upper triangle of the cost Hessian on v̇.
    paa: Box<MassMatrix>,
    mass: Box<MassMatrix>,
    h: DofVector,
    /// Linear cost on v̇.
    q: DofVector,
    /// Per λ component, the force-penalty weight (not squared).
    lam_w: Vec<f64>,
    /// Per DoF, the torque-regulariser weight (not squared).
    tau_w: DofVector,
    nc: usize,
    /// A point's or a bone's angular Jacobian (both 3 × 75), one task at a time.
    jac: Box<PointJacobian>,
    contact_jac: Box<[PointJacobian; MAX_CONTACT_POINTS]>,
    cols: Vec<usize>,
    /// Inequality rows `C·z ≤ d` over `z = [v̇, λ]`, as triplets.
    c_rows: Vec<usize>,
    c_cols: Vec<usize>,
    c_vals: Vec<f64>,
    d: Vec<f64>,
}

impl Qp {
    pub fn new() -> Qp {
        Qp {
            paa: Box::new(MassMatrix::zeros()),
            mass: Box::new(MassMatrix::zeros()),
            h: DofVector::zeros(),
            q: DofVector::zeros(),
            lam_w: Vec::new(),
            tau_w: DofVector::zeros(),
            nc: 0,
            jac: Box::new(PointJacobian::zeros()),
            contact_jac: Box::new([PointJacobian::zeros(); MAX_CONTACT_POINTS]),
            cols: Vec::with_capacity(NUM_DOFS),
            c_rows: Vec::new(),
            c_cols: Vec::new(),
            c_vals: Vec::new(),
            d: Vec::new(),
        }
    }

    /// Build and solve the QP at the state stored in `data` (`set_state` done with `pose`). `inequalities`: false
    /// drops the friction and velocity rows (the tests compare the formulations without them too).
    /// `None` when the solve failed.
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        physics: &PhysicsBody,
        config: &PipConfig,
        data: &mut DynamicsData,
        pose: &Pose,
        reference: &Reference,
        contacts: &ContactSet,
        inequalities: bool,
        stats: &mut SolveStats,
    ) -> Option<Solution> {
        self.solve_with(
            Formulation::Reduced,
            physics,
            config,
            data,
            pose,
            reference,
            contacts,
            inequalities,
            stats,
        )
    }

    /// [`Qp::solve`] with a chosen formulation (the reduced one falls back to the full one when its
    /// Hessian is not positive definite).
    #[allow(clippy::too_many_arguments)]
    pub fn solve_with(
        &mut self,
        formulation: Formulation,
        physics: &PhysicsBody,
        config: &PipConfig,
        data: &mut DynamicsData,
        pose: &Pose,
        reference: &Reference,
        contacts: &ContactSet,
        inequalities: bool,
        stats: &mut SolveStats,
    ) -> Option<Solution> {
        if !self.assemble(
            physics,
            config,
            data,
            pose,
            reference,
            contacts,
            inequalities,
        ) {
            return None;
        }
        let start = Instant::now();
        let z = match formulation {
            Formulation::Reduced => match self.solve_reduced(config) {
                Reduced::Solved(z, iterations) => {
                    stats.iterations = iterations;
                    stats.variables = NUM_DOFS + 3 * self.nc;
                    stats.constraints = self.d.len();
                    Some(z)
                }
                Reduced::Failed => None,
                Reduced::NotPositiveDefinite => self.solve_full(config, stats),
            },
            Formulation::Full => self.solve_full(config, stats),
        };
        let solution = z.and_then(|z| self.finish(config, &z));
        stats.solve_time_s = start.elapsed().as_secs_f64();
        solution
    }

    /// Fill the cost, dynamics and inequality buffers; false when some data is not finite.
    #[allow(clippy::too_many_arguments)]
    fn assemble(
        &mut self,
        physics: &PhysicsBody,
        config: &PipConfig,
        data: &mut DynamicsData,
        pose: &Pose,
        reference: &Reference,
        contacts: &ContactSet,
        inequalities: bool,
    ) -> bool {
        let model = &physics.model;
        let nc = contacts.points().len();
        self.nc = nc;
        let lam0 = NUM_DOFS;
        let v = *data.velocity();
        let dt = config.dt;

        // ---- cost ----
        // As slices: nalgebra's `fill` walks its element iterator, which does not become a memset.
        self.paa.as_mut_slice().fill(0.0);
        self.q.fill(0.0);
        // Joint-rotation PD (Eq. 3/5), tangent space, root rotation included.
        for j in JointId::all() {
            let i = j.index();
            let d = joint_dof(j);
            let rel = pose.parent_from_joint[i].transpose() * reference.rotation(i);
            let e = axis_angle_from_rotation(&rel);
            for r in 0..3 {
                let want = config.kp_rotation * e[r] - config.kd_rotation * v[d + r];
                self.paa[(d + r, d + r)] += 1.0;
                self.q[d + r] -= want;
            }
        }
        // Joint-position PD from the predicted velocities (Eq. 4/6).
        let w2 = config.coeff_joint_velocity * config.coeff_joint_velocity;
        for &j in &POSITION_PD_JOINTS {
            data.point_jacobian(j, &Vector3::zeros(), &mut self.jac);
            let vel = data.point_velocity(j, &Vector3::zeros());
            let jdv = data.point_jdot_v(j, &Vector3::zeros());
            let want = reference.joint_velocity_mps[j.index()] * (config.kp_position * dt)
                - vel * config.kd_position
                - jdv;
            chain_columns(j, &mut self.cols);
            add_task(&mut self.paa, &mut self.q, &self.cols, &self.jac, &want, w2);
        }
        // World orientation of the instrumented bones (imuflow; `PipConfig::coeff_sensor_bone`):
        // `J_ω,j·v̇ ≈` [`orientation_target`]. The upper legs and upper arms get the same rows
        // (`PipConfig::coeff_limb_bone`): the kinematics stage sets them from their lower bones'
        // sensors through the knee and elbow.
        let mut reference_world = [Rotation3::identity(); NUM_JOINTS];
        local_to_global_rotations(&reference.pose.parent_from_joint, &mut reference_world);
        for (j, weight) in orientation_rows(config) {
            let w2 = weight * weight;
            if w2 > 0.0 {
                let want = orientation_target(data, j, &reference_world[j.index()], config);
                data.angular_jacobian(j, &mut self.jac);
                chain_columns(j, &mut self.cols);
                add_task(&mut self.paa, &mut self.q, &self.cols, &self.jac, &want, w2);
            }
        }
        // Height-scaled force penalty ("Signorini", reference §5.2 cost 3).
        self.lam_w.clear();
        for p in contacts.points() {
            let height = p.position.y - contacts.surface_height_m[p.joint.index()];
            let w = config.coeff_lambda * height.max(config.lambda_min_height_m);
            self.lam_w.extend([w; 3]);
        }
        // Torque regulariser (Eq. 12): root 6 DoFs virtual, the rest joint torques.
        for d in 0..NUM_DOFS {
            self.tau_w[d] = if d < 6 {
                config.coeff_root_virtual
            } else {
                config.coeff_joint_torque
            };
        }

        // ---- dynamics: M·v̇ + h = τ + Σ_k J_kᵀ·λ_k (Eq. 9) ----
        self.h = *data.bias_forces(model);
        *self.mass = *data.mass_matrix(model);
        for (k, p) in contacts.points().iter().enumerate() {
            let i = p.joint.index();
            let fk = data.fk();
            let local = fk.world_from_joint[i].inverse() * (p.position - fk.joint_in_world_m[i]);
            data.point_jacobian(p.joint, &local, &mut self.contact_jac[k]);
        }

        // ---- inequalities C·z ≤ d ----
        self.c_rows.clear();
        self.c_cols.clear();
        self.c_vals.clear();
        self.d.clear();
        if inequalities {
            // Friction pyramid (Eq. 10): (±√2, −μ, 0)·λ ≤ 0, (0, −μ, ±√2)·λ ≤ 0.
            let s2 = std::f64::consts::SQRT_2;
            let mu = config.friction;
            for k in 0..nc {
                for coef in [
                    [s2, -mu, 0.0],
                    [-s2, -mu, 0.0],
                    [0.0, -mu, s2],
                    [0.0, -mu, -s2],
                ] {
                    let row = self.d.len();
                    for (r, &x) in coef.iter().enumerate() {
                        if x != 0.0 {
                            self.push_c(row, lam0 + 3 * k + r, x);
                        }
                    }
                    self.d.push(0.0);
                }
            }
            // Feet, always (reference §5.2(b)).
            let surface = config.contact.surface_height_m;
            let lock = config.foot_lock_probability;
            for (k, &foot) in FEET.iter().enumerate() {
                let c = reference.foot_contact_prob[k];
                let th = -(c.min(lock - 1e-5) / lock).ln();
                let th = if th.is_nan() { f64::INFINITY } else { th };
                let height = physics.geometry.height_above(
                    foot,
                    &data.fk().joint_in_world_m[foot.index()],
                    surface,
                );
                let th_y = -height / dt;
                let bounds = [(-th, th), (th_y, th.max(th_y) + 1e-6), (-th, th)];
                self.velocity_rows(data, foot, bounds, dt);
            }
            // Other contact bodies (reference §5.2(a)).
            let (slide, rise) = (config.contact_body_slide_mps, config.contact_body_rise_mps);
            for j in JointId::all() {
                if contacts.contains(j) && !FEET.contains(&j) {
                    let bounds = [(-slide, slide), (0.0, rise), (-slide, slide)];
                    self.velocity_rows(data, j, bounds, dt);
                }
            }
        }
        [
            self.q.as_slice(),
            self.paa.as_slice(),
            self.mass.as_slice(),
            self.h.as_slice(),
            &self.lam_w,
            &self.d,
            &self.c_vals,
        ]
        .into_iter()
        .chain(self.contact_jac[..nc].iter().map(|j| j.as_slice()))
        .all(all_finite)
    }

    /// The reduced formulation (module docs): `z = [v̇, λ]`.
    fn solve_reduced(&self, config: &PipConfig) -> Reduced {
        let nc = self.nc;
        let nz = NUM_DOFS + 3 * nc;
        let m = self.d.len();
        // B = [W·M, −W·J_cᵀ]: W·τ = B·z + W·h.
        let mut b = DMatrix::<f64>::zeros(NUM_DOFS, nz);
        for c in 0..NUM_DOFS {
            for r in 0..NUM_DOFS {
                b[(r, c)] = self.tau_w[r] * self.mass[(r, c)];
            }
        }
        for k in 0..nc {
            let jk = &self.contact_jac[k];
            for r in 0..3 {
                let col = NUM_DOFS + 3 * k + r;
                for c in 0..NUM_DOFS {
                    b[(c, col)] = -self.tau_w[c] * jk[(r, c)];
                }
            }
        }
        // Bᵀ·B and (below) Xᵀ·X as a product with an explicit transpose: nalgebra's `tr_mul` is
        // a column-by-column dot product, the `*` of dynamic matrices a blocked matrixmultiply
        // kernel (the QP's largest single cost before; same product, other summation order).
        let bt = b.transpose();
        let mut hess = &bt * &b;
        for c in 0..NUM_DOFS {
            for r in 0..=c {
                let x = self.paa[(r, c)];
                hess[(r, c)] += x;
                if r != c {
                    hess[(c, r)] += x;
                }
            }
        }
        for (i, w) in self.lam_w.iter().enumerate() {
            hess[(NUM_DOFS + i, NUM_DOFS + i)] += w * w;
        }
        let wh = DVector::from_iterator(NUM_DOFS, (0..NUM_DOFS).map(|i| self.tau_w[i] * self.h[i]));
        let mut g = &bt * &wh;
        for i in 0..NUM_DOFS {
            g[i] += self.q[i];
        }
        let Some(chol) = ColumnCholesky::new(hess) else {
            return Reduced::NotPositiveDefinite;
        };
        let mut z = chol.solve(&g);
        z.neg_mut();
        if !z.iter().all(|x| x.is_finite()) {
            return Reduced::NotPositiveDefinite;
        }
        if m == 0 {
            return Reduced::Solved(z.as_slice().to_vec(), 0);
        }
        // Cᵀ (nz × m), then X = L⁻¹Cᵀ.
        let mut x = DMatrix::<f64>::zeros(nz, m);
        for ((&r, &c), &v) in self.c_rows.iter().zip(&self.c_cols).zip(&self.c_vals) {
            x[(c, r)] += v;
        }
        // Dual linear term d − C·z_u (before scaling).
        let mut p = DVector::from_fn(m, |i, _| self.d[i] - x.column(i).dot(&z));
        // Both substitutions read only the lower triangle: the factor as the Cholesky left it.
        let l = chol.l_dirty();
        if !solve_lower_triangular_from_first_nonzero(l, &mut x) {
            return Reduced::NotPositiveDefinite;
        }
        // Scale each row to ‖L⁻¹cᵢ‖ = 1 (μ = D·ν).
        for (i, pi) in p.iter_mut().enumerate() {
            let s = x.column(i).norm();
            if s > 0.0 && s.is_finite() {
                x.column_mut(i).unscale_mut(s);
                *pi /= s;
            }
        }
        let qd = x.transpose() * &x;
        let dense = bound_qp::solve(
            &qd,
            &p,
            config.solver_tolerance,
            config.solver_max_iterations,
        );
        let (nu, iterations) = match dense {
            Some(solution) => (solution.nu, solution.iterations),
            None => match clarabel_dual(&qd, p.as_slice(), config) {
                Some(solved) => solved,
                None => return Reduced::Failed,
            },
        };
        let nu = nu.map(|v| v.max(0.0));
        let mut corr = &x * nu;
        if !l.tr_solve_lower_triangular_mut(&mut corr) {
            return Reduced::Failed;
        }
        z -= corr;
        Reduced::Solved(z.as_slice().to_vec(), iterations)
    }

    /// The full formulation (module docs): returns `[v̇, λ]` of `x = [v̇, λ, τ]`.
    fn solve_full(&self, config: &PipConfig, stats: &mut SolveStats) -> Option<Vec<f64>> {
        let nc = self.nc;
        let lam0 = NUM_DOFS;
        let tau0 = NUM_DOFS + 3 * nc;
        let n = tau0 + NUM_DOFS;
        // P: upper triangle, column by column.
        let mut colptr = Vec::with_capacity(n + 1);
        let mut rowval = Vec::with_capacity(3000);
        let mut nzval = Vec::with_capacity(3000);
        colptr.push(0);
        for c in 0..NUM_DOFS {
            for r in 0..=c {
                let x = self.paa[(r, c)];
                if x != 0.0 {
                    rowval.push(r);
                    nzval.push(x);
                }
            }
            colptr.push(rowval.len());
        }
        for (i, w) in self.lam_w.iter().enumerate() {
            rowval.push(lam0 + i);
            nzval.push(w * w);
            colptr.push(rowval.len());
        }
        for d in 0..NUM_DOFS {
            rowval.push(tau0 + d);
            nzval.push(self.tau_w[d] * self.tau_w[d]);
            colptr.push(rowval.len());
        }
        let mut q = vec![0.0; n];
        q[..NUM_DOFS].copy_from_slice(self.q.as_slice());
        // A: the equation of motion M·v̇ − τ − Σ J_kᵀλ_k = −h, then the inequalities.
        let (mut ar, mut ac, mut av) = (Vec::new(), Vec::new(), Vec::new());
        let mut push = |r: usize, c: usize, x: f64| {
            ar.push(r);
            ac.push(c);
            av.push(x);
        };
        for c in 0..NUM_DOFS {
            for r in 0..NUM_DOFS {
                let x = self.mass[(r, c)];
                if x != 0.0 {
                    push(r, c, x);
                }
            }
        }
        for d in 0..NUM_DOFS {
            push(d, tau0 + d, -1.0);
        }
        for k in 0..nc {
            for c in 0..NUM_DOFS {
                for r in 0..3 {
                    let x = self.contact_jac[k][(r, c)];
                    if x != 0.0 {
                        push(c, lam0 + 3 * k + r, -x);
                    }
                }
            }
        }
        for ((&r, &c), &x) in self.c_rows.iter().zip(&self.c_cols).zip(&self.c_vals) {
            push(NUM_DOFS + r, c, x);
        }
        let m_rows = NUM_DOFS + self.d.len();
        let b: Vec<f64> = self
            .h
            .iter()
            .map(|x| -x)
            .chain(self.d.iter().copied())
            .collect();
        let p_mat = CscMatrix::new(n, n, colptr, rowval, nzval);
        let a_mat = CscMatrix::new_from_triplets(m_rows, n, ar, ac, av);
        let mut cones: Vec<SupportedConeT<f64>> = vec![ZeroConeT(NUM_DOFS)];
        if m_rows > NUM_DOFS {
            cones.push(NonnegativeConeT(m_rows - NUM_DOFS));
        }
        let mut solver =
            DefaultSolver::new(&p_mat, &q, &a_mat, &b, &cones, settings(config)).ok()?;
        solver.solve();
        let sol = &solver.solution;
        stats.iterations = sol.iterations;
        stats.variables = n;
        stats.constraints = m_rows;
        if !matches!(
            sol.status,
            SolverStatus::Solved | SolverStatus::AlmostSolved
        ) {
            return None;
        }
        Some(sol.x[..tau0].to_vec())
    }

    /// τ from the equation of motion (exact projection, see the module docs), the fallback checks.
    fn finish(&self, config: &PipConfig, z: &[f64]) -> Option<Solution> {
        let acceleration = DofVector::from_column_slice(&z[..NUM_DOFS]);
        let mut forces = [Vector3::zeros(); MAX_CONTACT_POINTS];
        let mut tau = *self.mass * acceleration + self.h;
        for (k, f) in forces.iter_mut().enumerate().take(self.nc) {
            let i = NUM_DOFS + 3 * k;
            *f = Vector3::new(z[i], z[i + 1], z[i + 2]);
            tau -= self.contact_jac[k].transpose() * *f;
        }
        let norm = z
            .iter()
            .chain(tau.iter())
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt();
        if !norm.is_finite() || norm > config.fallback_norm {
            return None;
        }
        Some(Solution {
            acceleration,
            forces,
            tau,
        })
    }

    fn push_c(&mut self, r: usize, c: usize, x: f64) {
        self.c_rows.push(r);
        self.c_cols.push(c);
        self.c_vals.push(x);
    }

    /// Rows `lo_i ≤ v_i + dt·J_i·v̇ ≤ hi_i` for joint `j`'s origin; infinite bounds give no row.
    fn velocity_rows(&mut self, data: &DynamicsData, j: JointId, bounds: [(f64, f64); 3], dt: f64) {
        data.point_jacobian(j, &Vector3::zeros(), &mut self.jac);
        let vel = data.point_velocity(j, &Vector3::zeros());
        chain_columns(j, &mut self.cols);
        for (i, (lo, hi)) in bounds.into_iter().enumerate() {
            for (sign, bound) in [(1.0, hi), (-1.0, -lo)] {
                if !bound.is_finite() && bound > 0.0 {
                    continue;
                }
                let row = self.d.len();
                for ci in 0..self.cols.len() {
                    let c = self.cols[ci];
                    let x = self.jac[(i, c)];
                    if x != 0.0 {
                        self.push_c(row, c, sign * dt * x);
                    }
                }
                self.d.push(bound - sign * vel[i]);
            }
        }
    }
}

/// The reduced formulation's dual through clarabel (the fallback when the dense solver does not
/// converge): `min ½νᵀQν + pᵀν` s.t. `ν ≥ 0`. Returns ν and the iterations.
pub(super) fn clarabel_dual(
    qd: &DMatrix<f64>,
    p: &[f64],
    config: &PipConfig,
) -> Option<(DVector<f64>, u32)> {
    let m = p.len();
    // clarabel: min ½νᵀQν + pᵀν s.t. −ν + s = 0, s ≥ 0.
    let mut colptr = Vec::with_capacity(m + 1);
    let mut rowval = Vec::with_capacity(m * (m + 1) / 2);
    let mut nzval = Vec::with_capacity(m * (m + 1) / 2);
    colptr.push(0);
    for c in 0..m {
        for r in 0..=c {
            rowval.push(r);
            nzval.push(qd[(r, c)]);
        }
        colptr.push(rowval.len());
    }
    let p_mat = CscMatrix::new(m, m, colptr, rowval, nzval);
    let a_mat = CscMatrix::new(m, m, (0..=m).collect(), (0..m).collect(), vec![-1.0; m]);
    let zeros = vec![0.0; m];
    let cones = [NonnegativeConeT(m)];
    let Ok(mut solver) = DefaultSolver::new(
        &p_mat,
        p,
        &a_mat,
        &zeros,
        &cones,
        // Rows already scaled to a unit-diagonal dual Hessian: clarabel's equilibration only
        // costs time (and an iteration); no infinite bounds to presolve away.
        DefaultSettings {
            equilibrate_enable: false,
            presolve_enable: false,
            ..settings(config)
        },
    ) else {
        return None;
    };
    solver.solve();
    let sol = &solver.solution;
    if !matches!(
        sol.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    ) {
        return None;
    }
    Some((DVector::from_column_slice(&sol.x), sol.iterations))
}

/// Whether every value is finite. A fold without an early exit: the compiler vectorises it, where a
/// short-circuiting `all` over chained iterators checked one value at a time (measured: 3 % of
/// `imuflow bench physics` for the 12,000 values of an assembled QP).
fn all_finite(values: &[f64]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_finite())
}

/// `x ← L⁻¹·x` for lower-triangular `l`, column by column, each from its first nonzero entry. The
/// columns of `Cᵀ` are sparse: a friction-pyramid row touches only its point's three λ, which come
/// after the 75 DoFs, so its solution is zero above them and its substitution is a short one at the
/// end. Below the first nonzero this is nalgebra's `solve_lower_triangular_mut` step for step
/// (`xᵢ = xᵢ/lᵢᵢ`, then `x_r += (−xᵢ)·l_ri` for the rows below); above it that loop would divide
/// zeros and add zero multiples: the same bits (test). False when the diagonal holds a zero.
fn solve_lower_triangular_from_first_nonzero(l: &DMatrix<f64>, x: &mut DMatrix<f64>) -> bool {
    let n = l.nrows();
    if (0..n).any(|i| l[(i, i)] == 0.0) {
        return false;
    }
    for b in x.as_mut_slice().chunks_exact_mut(n) {
        if let Some(first) = b.iter().position(|&v| v != 0.0) {
            forward_substitute(l.as_slice(), n, b, first);
        }
    }
    true
}

with_avx2! {
    /// One column `b` of the substitution, from row `first` on, over column-major `l` (`n × n`).
    fn forward_substitute(l: &[f64], n: usize, b: &mut [f64], first: usize) -> () =
        forward_substitute_body;
}

#[inline(always)]
fn forward_substitute_body(l: &[f64], n: usize, b: &mut [f64], first: usize) {
    let column = |i: usize| &l[i * n..(i + 1) * n];
    let mut i = first;
    // Four unknowns per pass over the rows below them: each row still gets `x_r += (−xᵢ)·l_ri`
    // for i in order.
    while i + 4 <= n {
        let [l0, l1, l2, l3] = std::array::from_fn(|k| column(i + k));
        // The four unknowns, each after the updates from the ones before it.
        let c0 = b[i] / l0[i];
        b[i] = c0;
        b[i + 1] += -c0 * l0[i + 1];
        b[i + 2] += -c0 * l0[i + 2];
        b[i + 3] += -c0 * l0[i + 3];
        let c1 = b[i + 1] / l1[i + 1];
        b[i + 1] = c1;
        b[i + 2] += -c1 * l1[i + 2];
        b[i + 3] += -c1 * l1[i + 3];
        let c2 = b[i + 2] / l2[i + 2];
        b[i + 2] = c2;
        b[i + 3] += -c2 * l2[i + 3];
        let c3 = b[i + 3] / l3[i + 3];
        b[i + 3] = c3;
        let below = i + 4..n;
        add_four_columns(
            &mut b[below.clone()],
            [-c0, -c1, -c2, -c3],
            [l0, l1, l2, l3].map(|l| &l[below.clone()]),
        );
        i += 4;
    }
    for i in i..n {
        let li = column(i);
        let coeff = b[i] / li[i];
        b[i] = coeff;
        for (y, &l_ri) in b[i + 1..].iter_mut().zip(&li[i + 1..]) {
            *y += -coeff * l_ri;
        }
    }
}

/// clarabel's settings from the configuration.
fn settings(config: &PipConfig) -> DefaultSettings<f64> {
    let tol = config.solver_tolerance;
    DefaultSettings {
        verbose: false,
        max_iter: config.solver_max_iterations,
        tol_gap_abs: tol,
        tol_gap_rel: tol,
        tol_feas: tol,
        ..DefaultSettings::default()
    }
}

/// Adds the task `w2·½‖J·v̇ − want‖²` to the cost (`J` a 3 × 75 Jacobian whose nonzero columns
/// are `cols`, ascending): `P_aa += w2·JᵀJ` (upper triangle), `q −= w2·Jᵀ·want`.
fn add_task(
    paa: &mut MassMatrix,
    q: &mut DofVector,
    cols: &[usize],
    jac: &PointJacobian,
    want: &Vector3<f64>,
    w2: f64,
) {
    for (ia, &ca) in cols.iter().enumerate() {
        let ja = jac.column(ca);
        q[ca] -= w2 * ja.dot(want);
        for &cb in &cols[ia..] {
            paa[(ca, cb)] += w2 * ja.dot(&jac.column(cb));
        }
    }
}

/// The columns of `v` a point of joint `j` depends on: the root translation and every ancestor's block.
fn chain_columns(j: JointId, out: &mut Vec<usize>) {
    out.clear();
    out.extend(0..3);
    let mut k = Some(j);
    let start = out.len();
    while let Some(a) = k {
        let d = joint_dof(a);
        out.extend(d..d + 3);
        k = a.parent();
    }
    out[start..].sort_unstable();
}

/// The bones whose world orientation the QP tracks (imuflow's rows beside PIP's), with their
/// weights: the sensors' bones (`PipConfig::coeff_sensor_bone`) and the SIP joints' frames, which
/// are exactly the upper legs and upper arms (`PipConfig::coeff_limb_bone`).
pub fn orientation_rows(config: &PipConfig) -> impl Iterator<Item = (JointId, f64)> {
    let sensor_bones = Imu::SIX.map(|imu| (imu.joint(), config.coeff_sensor_bone));
    let limb_bones = SIP_JOINTS.map(|j| (j, config.coeff_limb_bone));
    sensor_bones.into_iter().chain(limb_bones)
}

/// The angular acceleration the QP asks of bone `j` to reach the world orientation `wanted`:
/// `kp·e − kd·ω − J̇_ω·v`, with `e` the rotation from the current to the wanted orientation
/// (world axes) and `J̇_ω·v` = Σ over the chain of `ω_parent(k) × ω_k` (the derivative of
/// `ω_k = ω_parent(k) + R_k·ω_rel,k`).
pub fn orientation_target(
    data: &DynamicsData,
    j: JointId,
    wanted: &Rotation3<f64>,
    config: &PipConfig,
) -> Vector3<f64> {
    let current = data.fk().world_from_joint[j.index()];
    let e = current * axis_angle_from_rotation(&(current.transpose() * wanted));
    let omega = data.angular_velocity(j);
    let mut jdot_v = Vector3::zeros();
    let mut k = Some(j);
    while let Some(link) = k {
        if let Some(parent) = link.parent() {
            jdot_v += data
                .angular_velocity(parent)
                .cross(&data.angular_velocity(link));
        }
        k = link.parent();
    }
    e * config.kp_rotation - omega * config.kd_rotation - jdot_v
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Cholesky;

    #[test]
    fn pip_all_finite_finds_any_infinity_or_nan() {
        let mut values = vec![1.0; 1001];
        assert!(all_finite(&values) && all_finite(&[]));
        for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN] {
            for at in [0, 500, 1000] {
                values[at] = bad;
                assert!(!all_finite(&values), "{bad} at {at}");
                values[at] = -0.0;
            }
        }
        assert!(all_finite(&values));
    }

    #[test]
    fn pip_sparse_forward_substitution_gives_the_same_bits_as_nalgebras() {
        let mut rnd = crate::test_random::uniform(5);
        let n = NUM_DOFS + 12;
        let a = DMatrix::<f64>::from_fn(n, n, |_, _| rnd());
        let spd = a.transpose() * &a + DMatrix::<f64>::identity(n, n);
        let l = Cholesky::new(spd).expect("positive definite").l();
        // Columns like Cᵀ's: one nonzero (a velocity bound), a few at the end (a friction row),
        // none, and a dense one.
        let mut x = DMatrix::<f64>::zeros(n, 4);
        x[(40, 0)] = 1.0;
        for r in [n - 3, n - 2, n - 1] {
            x[(r, 1)] = rnd();
        }
        for r in 0..n {
            x[(r, 3)] = rnd();
        }
        let mut want = x.clone();
        assert!(l.solve_lower_triangular_mut(&mut want));
        // The portable build, column by column (the call below takes the AVX2 one where it can).
        let mut portable = x.clone();
        for b in portable.as_mut_slice().chunks_exact_mut(n) {
            if let Some(first) = b.iter().position(|&v| v != 0.0) {
                forward_substitute_body(l.as_slice(), n, b, first);
            }
        }
        assert!(solve_lower_triangular_from_first_nonzero(&l, &mut x));
        let bits = |m: &DMatrix<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&portable), bits(&x));
        for (i, (a, b)) in x.iter().zip(want.iter()).enumerate() {
            // `==`: a leading zero may differ in sign, nothing else.
            assert!(a == b, "entry {i}: {a:e} against {b:e}");
        }
        assert!(x.column(0).iter().take(40).all(|&v| v == 0.0));
        assert!(x[(40, 0)] != 0.0 && x[(n - 1, 0)] != 0.0);
    }
}
