//! Assembly and solution of PIP's per-frame QP (see the module docs of [`super`]).
//!
//! clarabel form: `min ½xᵀPx + qᵀx` s.t. `A·x + s = b`, `s ∈ {0}^75 × R₊^m` (rows 0..75: the equation of
//! motion; then friction rows and velocity-bound rows `a·x ≤ b`). `P` is built column by column in its
//! upper triangle directly in CSC form; `A` from triplets.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
    ZeroConeT,
};
use imuflow_body::dynamics::{
    DofVector, DynamicsData, MassMatrix, NUM_DOFS, PointJacobian, joint_dof,
};
use imuflow_body::{JointId, Pose};
use imuflow_contact::ContactSet;
use imuflow_contact::pip::FEET;
use imuflow_graph::frames::MAX_CONTACT_POINTS;
use nalgebra::Vector3;

use super::{POSITION_PD_JOINTS, PipConfig};
use crate::{PhysicsBody, Reference};

/// What clarabel reported for one step (the last solve when there was a re-solve).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveStats {
    /// Solves this step (2 when the unconstrained re-solve ran).
    pub solves: u32,
    /// Interior-point iterations of the last solve.
    pub iterations: u32,
    /// clarabel's solve time of the last solve (s), setup and factorisations included.
    pub solve_time_s: f64,
    /// Variables and constraint rows of the last solve.
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

/// Reusable buffers of the QP.
pub struct Qp {
    paa: Box<MassMatrix>,
    q: Vec<f64>,
    jac: Box<PointJacobian>,
    contact_jac: Box<[PointJacobian; MAX_CONTACT_POINTS]>,
    cols: Vec<usize>,
    a_rows: Vec<usize>,
    a_cols: Vec<usize>,
    a_vals: Vec<f64>,
    b: Vec<f64>,
}

impl Qp {
    pub fn new() -> Qp {
        Qp {
            paa: Box::new(MassMatrix::zeros()),
            q: Vec::new(),
            jac: Box::new(PointJacobian::zeros()),
            contact_jac: Box::new([PointJacobian::zeros(); MAX_CONTACT_POINTS]),
            cols: Vec::with_capacity(NUM_DOFS),
            a_rows: Vec::new(),
            a_cols: Vec::new(),
            a_vals: Vec::new(),
            b: Vec::new(),
        }
    }

    /// Build and solve the QP at the state stored in `data` (`set_state` done with `pose`). `inequalities`: false
    /// drops the friction and velocity rows (the fallback re-solve). `None` when the solve failed.
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
        let model = &physics.model;
        let nc = contacts.points().len();
        let lam0 = NUM_DOFS;
        let tau0 = NUM_DOFS + 3 * nc;
        let n = tau0 + NUM_DOFS;
        let v = *data.velocity();
        let dt = config.dt;

        // ---- cost ----
        self.paa.fill(0.0);
        self.q.clear();
        self.q.resize(n, 0.0);
        // Joint-rotation PD (Eq. 3/5), tangent space, root rotation included.
        for j in JointId::all() {
            let i = j.index();
            let d = joint_dof(j);
            let rel = pose.parent_from_joint[i].transpose() * reference.rotation(i);
            let e = rel.scaled_axis();
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
            for (ia, &ca) in self.cols.iter().enumerate() {
                let ja = self.jac.column(ca);
                self.q[ca] -= w2 * ja.dot(&want);
                for &cb in &self.cols[ia..] {
                    let s = w2 * ja.dot(&self.jac.column(cb));
                    let (r, c) = if ca <= cb { (ca, cb) } else { (cb, ca) };
                    self.paa[(r, c)] += s;
                }
            }
        }
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
        // Height-scaled force penalty ("Signorini", reference §5.2 cost 3).
        for (k, p) in contacts.points().iter().enumerate() {
            let height = p.position.y - contacts.surface_height_m[p.joint.index()];
            let w = config.coeff_lambda * height.max(config.lambda_min_height_m);
            for r in 0..3 {
                rowval.push(lam0 + 3 * k + r);
                nzval.push(w * w);
                colptr.push(rowval.len());
            }
        }
        // Torque regulariser (Eq. 12): root 6 DoFs virtual, the rest joint torques.
        for d in 0..NUM_DOFS {
            let w = if d < 6 {
                config.coeff_root_virtual
            } else {
                config.coeff_joint_torque
            };
            rowval.push(tau0 + d);
            nzval.push(w * w);
            colptr.push(rowval.len());
        }

        // ---- constraints ----
        self.a_rows.clear();
        self.a_cols.clear();
        self.a_vals.clear();
        self.b.clear();
        // Equation of motion (Eq. 9): M·v̇ − τ − Σ J_kᵀλ_k = −h.
        let h = *data.bias_forces(model);
        let m = data.mass_matrix(model);
        for c in 0..NUM_DOFS {
            for r in 0..NUM_DOFS {
                let x = m[(r, c)];
                if x != 0.0 {
                    self.push_a(r, c, x);
                }
            }
        }
        for d in 0..NUM_DOFS {
            self.push_a(d, tau0 + d, -1.0);
            self.b.push(-h[d]);
        }
        for (k, p) in contacts.points().iter().enumerate() {
            let i = p.joint.index();
            let fk = data.fk();
            let local = fk.world_from_joint[i].inverse() * (p.position - fk.joint_in_world_m[i]);
            data.point_jacobian(p.joint, &local, &mut self.contact_jac[k]);
            chain_columns(p.joint, &mut self.cols);
            for ci in 0..self.cols.len() {
                let c = self.cols[ci];
                for r in 0..3 {
                    let x = self.contact_jac[k][(r, c)];
                    if x != 0.0 {
                        self.push_a(c, lam0 + 3 * k + r, -x);
                    }
                }
            }
        }
        let mut rows = NUM_DOFS;
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
                    for (r, &x) in coef.iter().enumerate() {
                        if x != 0.0 {
                            self.push_a(rows, lam0 + 3 * k + r, x);
                        }
                    }
                    self.b.push(0.0);
                    rows += 1;
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
                rows = self.velocity_rows(data, foot, bounds, dt, rows);
            }
            // Other contact bodies (reference §5.2(a)).
            let (slide, rise) = (config.contact_body_slide_mps, config.contact_body_rise_mps);
            for j in JointId::all() {
                if contacts.contains(j) && !FEET.contains(&j) {
                    let bounds = [(-slide, slide), (0.0, rise), (-slide, slide)];
                    rows = self.velocity_rows(data, j, bounds, dt, rows);
                }
            }
        }
        let m_rows = rows;
        let finite = self
            .q
            .iter()
            .chain(&nzval)
            .chain(&self.b)
            .chain(&self.a_vals)
            .all(|x| x.is_finite());
        if !finite {
            return None;
        }
        let p_mat = CscMatrix::new(n, n, colptr, rowval, nzval);
        let a_mat = CscMatrix::new_from_triplets(
            m_rows,
            n,
            self.a_rows.clone(),
            self.a_cols.clone(),
            self.a_vals.clone(),
        );
        let mut cones: Vec<SupportedConeT<f64>> = vec![ZeroConeT(NUM_DOFS)];
        if m_rows > NUM_DOFS {
            cones.push(NonnegativeConeT(m_rows - NUM_DOFS));
        }
        let tol = config.solver_tolerance;
        let settings = DefaultSettings {
            verbose: false,
            max_iter: config.solver_max_iterations,
            tol_gap_abs: tol,
            tol_gap_rel: tol,
            tol_feas: tol,
            ..DefaultSettings::default()
        };
        let mut solver =
            DefaultSolver::new(&p_mat, &self.q, &a_mat, &self.b, &cones, settings).ok()?;
        solver.solve();
        let sol = &solver.solution;
        stats.solves += 1;
        stats.iterations = sol.iterations;
        stats.solve_time_s = sol.solve_time;
        stats.variables = n;
        stats.constraints = m_rows;
        if !matches!(
            sol.status,
            SolverStatus::Solved | SolverStatus::AlmostSolved
        ) {
            return None;
        }
        let x = &sol.x;
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !norm.is_finite() || norm > config.fallback_norm {
            return None;
        }
        let acceleration = DofVector::from_column_slice(&x[..NUM_DOFS]);
        let mut forces = [Vector3::zeros(); MAX_CONTACT_POINTS];
        // τ from the equation of motion (exact projection, see the module docs).
        let m = data.mass_matrix(model);
        let mut tau = m * acceleration + h;
        for (k, f) in forces.iter_mut().enumerate().take(nc) {
            *f = Vector3::new(x[lam0 + 3 * k], x[lam0 + 3 * k + 1], x[lam0 + 3 * k + 2]);
            tau -= self.contact_jac[k].transpose() * *f;
        }
        Some(Solution {
            acceleration,
            forces,
            tau,
        })
    }

    fn push_a(&mut self, r: usize, c: usize, x: f64) {
        self.a_rows.push(r);
        self.a_cols.push(c);
        self.a_vals.push(x);
    }

    /// Rows `lo_i ≤ v_i + dt·J_i·v̇ ≤ hi_i` for joint `j`'s origin; infinite bounds give no row.
    fn velocity_rows(
        &mut self,
        data: &DynamicsData,
        j: JointId,
        bounds: [(f64, f64); 3],
        dt: f64,
        mut rows: usize,
    ) -> usize {
        data.point_jacobian(j, &Vector3::zeros(), &mut self.jac);
        let vel = data.point_velocity(j, &Vector3::zeros());
        chain_columns(j, &mut self.cols);
        for (i, (lo, hi)) in bounds.into_iter().enumerate() {
            for (sign, bound) in [(1.0, hi), (-1.0, -lo)] {
                if !bound.is_finite() && bound > 0.0 {
                    continue;
                }
                for ci in 0..self.cols.len() {
                    let c = self.cols[ci];
                    let x = self.jac[(i, c)];
                    if x != 0.0 {
                        self.push_a(rows, c, sign * dt * x);
                    }
                }
                self.b.push(bound - sign * vel[i]);
                rows += 1;
            }
        }
        rows
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
