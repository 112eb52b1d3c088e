//! A dense interior-point solver for the reduced formulation's dual: `min ½νᵀQν + pᵀν` subject
//! to `ν ≥ 0`, with `Q` positive semidefinite (about 20–50 variables, dense).
//!
//! Why not clarabel here: clarabel is a general sparse conic solver; for this small dense problem
//! its setup (CSC assembly, ordering, symbolic factorisation of an `2m × 2m` KKT system) and its
//! sparse kernels dominate: on `imuflow bench physics`'s duals (28 variables on average) clarabel
//! took 428 µs a solve against 62 µs here, timed one after the other on the same problems. The same primal-dual method on the dense
//! `m × m` normal equations `(Q + S·N⁻¹)·Δν = r` costs one dense Cholesky per iteration.
//! clarabel stays the fallback (a failed solve here is retried there) and the solver of the full
//! formulation, which the tests use as the reference.
//!
//! Method: Mehrotra's predictor-corrector (Nocedal & Wright, *Numerical Optimization*, 2006,
//! Algorithm 16.4, specialised to bounds): KKT conditions `Qν + p − s = 0`, `ν∘s = 0`,
//! `ν, s ≥ 0`; each iteration factorises `Q + diag(s/ν)` once and solves it for an affine step
//! and a centred, corrected one.

use nalgebra::{DMatrix, DVector};

use crate::cholesky::ColumnCholesky;

/// Fraction of the step to the boundary taken (keeps ν and s strictly positive).
const STEP_TO_BOUNDARY: f64 = 0.99;

/// The solution of one bound-constrained QP.
#[derive(Debug, Clone)]
pub struct BoundQpSolution {
    pub nu: DVector<f64>,
    pub iterations: u32,
}

/// Solves `min ½νᵀQν + pᵀν, ν ≥ 0` to `tol` (relative to the problem's scale) within
/// `max_iterations`; `None` if it did not converge or a factorisation failed.
pub fn solve(
    q: &DMatrix<f64>,
    p: &DVector<f64>,
    tol: f64,
    max_iterations: u32,
) -> Option<BoundQpSolution> {
    let m = p.len();
    if m == 0 {
        return Some(BoundQpSolution {
            nu: DVector::zeros(0),
            iterations: 0,
        });
    }
    let scale = 1.0 + p.amax().max(q.amax());
    let (mut nu, mut s) = starting_point(q, p)?;
    for iteration in 0..=max_iterations {
        // Dual residual r = Qν + p − s and the complementarity gap.
        let mut r = q * &nu + p - &s;
        let mu = nu.dot(&s) / m as f64;
        if r.amax() <= tol * scale && mu <= tol * scale {
            return Some(BoundQpSolution {
                nu,
                iterations: iteration,
            });
        }
        if iteration == max_iterations {
            return None;
        }
        // Newton on Qν + p − s = 0, ν∘s = target: with rc = target − ν∘s,
        // (Q + diag(s/ν))·Δν = −r + rc/ν and Δs = (rc − s∘Δν)/ν.
        let mut kkt = q.clone();
        for i in 0..m {
            kkt[(i, i)] += s[i] / nu[i];
        }
        let chol = ColumnCholesky::new(kkt)?;
        r.neg_mut();
        let step = |rc: &DVector<f64>| {
            let rhs = &r + rc.component_div(&nu);
            let dnu = chol.solve(&rhs);
            let ds = (rc - s.component_mul(&dnu)).component_div(&nu);
            (dnu, ds)
        };
        // Predictor: the affine step towards ν∘s = 0.
        let rc_affine = -nu.component_mul(&s);
        let (dnu_a, ds_a) = step(&rc_affine);
        let alpha_a = max_step(&nu, &dnu_a).min(max_step(&s, &ds_a));
        let mu_a = (&nu + alpha_a * &dnu_a).dot(&(&s + alpha_a * &ds_a)) / m as f64;
        let sigma = (mu_a / mu).powi(3);
        // Corrector: centre by σμ and correct the affine step's second-order term.
        let rc = rc_affine - dnu_a.component_mul(&ds_a) + DVector::from_element(m, sigma * mu);
        let (dnu, ds) = step(&rc);
        let alpha = (STEP_TO_BOUNDARY * max_step(&nu, &dnu).min(max_step(&s, &ds))).min(1.0);
        nu.axpy(alpha, &dnu, 1.0);
        s.axpy(alpha, &ds, 1.0);
        if !nu.iter().chain(s.iter()).all(|x| x.is_finite()) {
            return None;
        }
    }
    None
}

/// Mehrotra's starting point (Nocedal & Wright, section 16.6, adapted to bounds): the solution of
/// the regularised equations `(Q + I)·ν = −p`, `s = Qν + p`, both shifted into the interior and
/// then balanced so that neither complementarity factor dominates. Started from ν = s = 1 instead,
/// the iterates of these problems (|p| in the hundreds) first climbed to gaps of 1e10 and took
/// 30–50 iterations; from here they take 9–10, as clarabel does.
fn starting_point(q: &DMatrix<f64>, p: &DVector<f64>) -> Option<(DVector<f64>, DVector<f64>)> {
    let m = p.len();
    let mut regularised = q.clone();
    for i in 0..m {
        regularised[(i, i)] += 1.0;
    }
    let mut nu = ColumnCholesky::new(regularised)?.solve(p);
    nu.neg_mut();
    let mut s = q * &nu + p;
    let shift_nu = (-1.5 * nu.min()).max(0.0) + 1e-8;
    let shift_s = (-1.5 * s.min()).max(0.0) + 1e-8;
    nu.add_scalar_mut(shift_nu);
    s.add_scalar_mut(shift_s);
    let gap = nu.dot(&s);
    let (balance_nu, balance_s) = (0.5 * gap / s.sum(), 0.5 * gap / nu.sum());
    nu.add_scalar_mut(balance_nu);
    s.add_scalar_mut(balance_s);
    Some((nu, s))
}

/// The largest `α ≤ 1` with `x + α·dx ≥ 0` (x > 0).
fn max_step(x: &DVector<f64>, dx: &DVector<f64>) -> f64 {
    x.iter()
        .zip(dx.iter())
        .filter(|(_, d)| **d < 0.0)
        .map(|(x, d)| -x / d)
        .fold(1.0, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pip::PipConfig;
    use crate::pip::qp::clarabel_dual;

    /// `Q = XᵀX` with `rank` rows in X (Q singular when rank < m, as the dual's can be), and
    /// `p = Xᵀw + t` with `t ≥ 0`: bounded below on `ν ≥ 0` (along Q's null space the cost is
    /// `tᵀν ≥ 0`), as the dual of a feasible QP is.
    fn problem(m: usize, rank: usize, seed: u64) -> (DMatrix<f64>, DVector<f64>) {
        let mut rnd = crate::test_random::uniform(seed);
        let x = DMatrix::from_fn(rank, m, |_, _| rnd());
        let w = DVector::from_fn(rank, |_, _| rnd() * 3.0);
        let t = DVector::from_fn(m, |_, _| rnd().abs() * 0.5);
        (x.transpose() * &x, x.transpose() * w + t)
    }

    /// The same dual through clarabel (the solver's fallback) at a tight tolerance.
    fn clarabel_solution(q: &DMatrix<f64>, p: &DVector<f64>) -> DVector<f64> {
        let config = PipConfig {
            solver_tolerance: 1e-10,
            solver_max_iterations: 200,
            ..PipConfig::default()
        };
        clarabel_dual(q, p.as_slice(), &config)
            .expect("clarabel solves it")
            .0
    }

    fn objective(q: &DMatrix<f64>, p: &DVector<f64>, nu: &DVector<f64>) -> f64 {
        0.5 * nu.dot(&(q * nu)) + p.dot(nu)
    }

    #[test]
    fn meets_the_kkt_conditions_and_clarabels_optimum() {
        for (seed, (m, rank)) in [(8, 20), (20, 20), (44, 44), (44, 30), (60, 75), (5, 2)]
            .into_iter()
            .enumerate()
        {
            let (q, p) = problem(m, rank, seed as u64 + 1);
            let ours = solve(&q, &p, 1e-10, 60).expect("converges");
            // KKT: ν ≥ 0, gradient g = Qν + p ≥ 0, and ν∘g = 0.
            let g = &q * &ours.nu + &p;
            let scale = 1.0 + p.amax();
            for i in 0..m {
                assert!(ours.nu[i] >= -1e-12, "ν[{i}] = {}", ours.nu[i]);
                assert!(g[i] >= -1e-7 * scale, "gradient[{i}] = {}", g[i]);
                assert!(
                    (ours.nu[i] * g[i]).abs() < 1e-7 * scale,
                    "complementarity {i}: {}",
                    ours.nu[i] * g[i]
                );
            }
            // A second solver: the same optimal value (ν itself is not unique when Q is singular).
            let theirs = clarabel_solution(&q, &p);
            let (a, b) = (objective(&q, &p, &ours.nu), objective(&q, &p, &theirs));
            assert!(
                (a - b).abs() < 1e-7 * (1.0 + b.abs()),
                "m {m}, rank {rank}: objective {a} vs clarabel {b}"
            );
            assert!(ours.iterations > 0 && ours.iterations < 40);
        }
    }

    #[test]
    fn an_unconstrained_optimum_inside_the_bounds_is_found_exactly() {
        // Q = I, p = −1: optimum ν = 1, the bound inactive.
        let q = DMatrix::identity(6, 6);
        let p = DVector::from_element(6, -1.0);
        let nu = solve(&q, &p, 1e-10, 60).unwrap().nu;
        assert!((nu - DVector::from_element(6, 1.0)).amax() < 1e-8);
        // p = +1: optimum ν = 0, every bound active.
        let nu = solve(&q, &DVector::from_element(6, 1.0), 1e-10, 60)
            .unwrap()
            .nu;
        assert!(nu.amax() < 1e-8);
    }
}
