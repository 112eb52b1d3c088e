//! The tracking least squares of GlobalPose's pre- and re-tracking (SIGGRAPH 2025 Eq. 11/14 in the
//! unconstrained form of App. B, Eq. 26/27):
//!
//! ```text
//! min_q̈  ‖[0 | I₇₂]·q̈ − θ̈_des‖² + Σ_i k_i·‖J_i·q̈ + J̇_i·q̇ − r̈_des,i‖² + β·‖M·q̈ − t‖²
//! ```
//!
//! with `t = −h` (pre-tracking) or `t = −h + J_cᵀ·λ` (re-tracking), so that the last term is the
//! generalized force `τ = M·q̈ + h (− J_cᵀλ)` the motion needs.
//!
//! The original stacks the rows into a sparse matrix and runs scipy's LSQR with default tolerances (an
//! iterative, approximate solve). With 75 unknowns we form the normal equations
//! `(AᵀA + Σ k_i·J_iᵀJ_i + β·M²)·q̈ = Aᵀθ̈_des + Σ k_i·J_iᵀ(r̈_des,i − J̇_i·q̇) + β·M·t` (M is symmetric,
//! so `MᵀM = M²`, computed once per frame and shared by both passes) and solve them exactly with a
//! dense in-place Cholesky factorisation. The matrix is positive definite: `AᵀA` covers the 72
//! rotational DoFs and every point Jacobian has the identity on the root translation. Squaring the
//! condition number is harmless here (the test compares against an SVD solve of the stacked system
//! to 1e-8).

use imuflow_body::dynamics::{DofVector, MassMatrix, NUM_DOFS, PointJacobian};
use nalgebra::Vector3;

use imuflow_contact::force::NUM_CONTACT_JOINTS;

use crate::wide::with_avx2;

/// The terms of one tracking pass.
pub struct TrackingTerms<'a> {
    /// Desired angular accelerations `θ̈_des` in the rotational DoFs (entries `3..75`; `0..3` ignored).
    pub theta_ddot_des: &'a DofVector,
    /// Jacobians `J_i` of the tracked points (the contact joints).
    pub jacobians: &'a [PointJacobian; NUM_CONTACT_JOINTS],
    /// `J̇_i·q̇` of the tracked points.
    pub jdot_v: &'a [Vector3<f64>; NUM_CONTACT_JOINTS],
    /// Desired linear accelerations `r̈_des,i`.
    pub r_ddot_des: &'a [Vector3<f64>; NUM_CONTACT_JOINTS],
    /// Tracking weights `k_i` (on the squared norms).
    pub weights: &'a [f64; NUM_CONTACT_JOINTS],
    /// Mass matrix `M`.
    pub mass: &'a MassMatrix,
    /// `M²`.
    pub mass_squared: &'a MassMatrix,
    /// Torque target `t`: `M·q̈ ≈ t`.
    pub torque_target: &'a DofVector,
    /// Torque weight β (on the squared norm).
    pub torque_weight: f64,
}

/// Solve one pass into `qddot`, using `normal` as scratch. False (and `qddot` unspecified) when the
/// normal matrix is not positive definite or a value is not finite.
pub fn solve_tracking(
    terms: &TrackingTerms<'_>,
    normal: &mut MassMatrix,
    qddot: &mut DofVector,
) -> bool {
    let beta = terms.torque_weight;
    // β·M² in one pass over the slices (a copy and then nalgebra's `*=` were two).
    for (n, &m2) in normal
        .as_mut_slice()
        .iter_mut()
        .zip(terms.mass_squared.as_slice())
    {
        *n = m2 * beta;
    }
    terms.mass.mul_to(terms.torque_target, qddot);
    *qddot *= beta;
    for d in 3..NUM_DOFS {
        normal[(d, d)] += 1.0;
        qddot[d] += terms.theta_ddot_des[d];
    }
    for i in 0..NUM_CONTACT_JOINTS {
        let k = terms.weights[i];
        if k == 0.0 {
            continue;
        }
        let j = &terms.jacobians[i];
        if !add_weighted_gram(normal, k, j) {
            return false;
        }
        let rhs = terms.r_ddot_des[i] - terms.jdot_v[i];
        qddot.gemv_tr(k, j, &rhs, 1.0);
    }
    cholesky_solve_in_place(normal, qddot)
}

/// `normal += k·JᵀJ` over the columns of `J` that are not all zero. A point Jacobian is zero outside
/// the root translation and the point's chain of ancestors (`point_jacobian`), ten joints at most of
/// twenty-four, so this visits a sixth of the entries or less. Each visited entry gets nalgebra's
/// `gemm_tr` arithmetic, `k·((a₀b₀ + a₁b₁) + a₂b₂) + n`, and a skipped one would have had `k·0` added:
/// the same bits as `normal.gemm_tr(k, j, j, 1.0)` (test). False when `J` holds a value that is not
/// finite (the dense product would have spread it; here it could hide in a skipped product).
fn add_weighted_gram(normal: &mut MassMatrix, k: f64, j: &PointJacobian) -> bool {
    if !j.iter().all(|v| v.is_finite()) {
        return false;
    }
    let mut used = [0usize; NUM_DOFS];
    let mut n = 0;
    for c in 0..NUM_DOFS {
        if j.column(c).iter().any(|&v| v != 0.0) {
            used[n] = c;
            n += 1;
        }
    }
    let used = &used[..n];
    for &c in used {
        let b = j.fixed_view::<3, 1>(0, c);
        for &r in used {
            let a = j.fixed_view::<3, 1>(0, r);
            let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            normal[(r, c)] += k * dot;
        }
    }
    true
}

with_avx2! {
    /// `out = m·m` for a matrix with many exact zeros, such as a mass matrix (an entry is zero
    /// unless one of its two DoFs' joints is an ancestor of the other's: 42 % of the SMPL tree's
    /// entries are not). Column `c` of the product is the sum of `m[k][c]·(column k)` in the order
    /// of `k`, as nalgebra's product of fixed-size matrices computes it (a column `axpy` per `k`);
    /// the columns with `m[k][c] = 0` are left out, and adding their products could change nothing
    /// but the sign of a zero: the same bits as `m * m` for a finite `m` (test), in 42 % of the
    /// multiply-adds. Measured: the dense product was most of `GlobalPose::step`'s own time. Runs
    /// four lanes wide where the CPU has AVX2 ([`crate::wide`]).
    pub fn square_skipping_zeros(m: &MassMatrix, out: &mut MassMatrix) -> () =
        square_skipping_zeros_body;
}

#[inline(always)]
fn square_skipping_zeros_body(m: &MassMatrix, out: &mut MassMatrix) {
    const N: usize = NUM_DOFS;
    let src = m.as_slice(); // column-major: (r, c) at c·N + r
    let dst = out.as_mut_slice();
    for (c, column) in dst.chunks_exact_mut(N).enumerate() {
        column.fill(0.0);
        for (k, &m_kc) in src[c * N..(c + 1) * N].iter().enumerate() {
            if m_kc == 0.0 {
                continue;
            }
            for (y, &x) in column.iter_mut().zip(&src[k * N..(k + 1) * N]) {
                *y += x * m_kc;
            }
        }
    }
}

/// Solve `A·x = b` for symmetric positive definite `A` by Cholesky, overwriting `A` with its factor
/// (lower triangle) and `b` with `x`. False when `A` is not positive definite or not finite.
///
/// The factorisation ([`crate::cholesky::factorise`]) runs down the columns of the column-major
/// storage, so the innermost loops read and write contiguous memory and vectorise (four lanes wide
/// with AVX2); the textbook form (a dot product along a row per entry) strides by a whole column
/// per step. Every entry still gets the same subtractions in the same order, so the result is the
/// same to the bit (test: `..._same_bits_as_the_textbook_form`). Measured: this solve was about
/// 40 % of the GlobalPose optimizer's time in an offline graph.
pub fn cholesky_solve_in_place(a: &mut MassMatrix, b: &mut DofVector) -> bool {
    const N: usize = NUM_DOFS;
    let s = a.as_mut_slice(); // column-major: (r, c) at c·N + r
    if !crate::cholesky::factorise(s, N) {
        return false;
    }
    // L·y = b, by columns: y[k] is final once the columns before it are subtracted.
    for k in 0..N {
        let y = b[k] / s[k * N + k];
        b[k] = y;
        for r in k + 1..N {
            b[r] -= s[k * N + r] * y;
        }
    }
    // Lᵀ·x = y.
    for r in (0..N).rev() {
        let mut v = b[r];
        for k in r + 1..N {
            v -= s[r * N + k] * b[k];
        }
        b[r] = v / s[r * N + r];
    }
    b.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_random::uniform;
    use nalgebra::DMatrix;

    #[test]
    fn globalpose_normal_equations_equal_an_svd_solve_of_the_stacked_rows() {
        let mut rnd = uniform(7);
        // A symmetric positive definite "mass matrix" with a spread of scales, random Jacobians.
        let b = MassMatrix::from_fn(|_, _| rnd());
        let mut mass = Box::new(b.transpose() * b * 0.2);
        for d in 0..NUM_DOFS {
            mass[(d, d)] += if d < 3 { 70.0 } else { 0.5 };
        }
        let mass_squared = Box::new(*mass * *mass);
        let theta = DofVector::from_fn(|_, _| 100.0 * rnd());
        let jac: [PointJacobian; NUM_CONTACT_JOINTS] =
            std::array::from_fn(|_| PointJacobian::from_fn(|_, _| rnd()));
        let jdv: [Vector3<f64>; NUM_CONTACT_JOINTS] =
            std::array::from_fn(|_| Vector3::new(rnd(), rnd(), rnd()));
        let rdd: [Vector3<f64>; NUM_CONTACT_JOINTS] =
            std::array::from_fn(|_| Vector3::new(rnd(), rnd(), rnd()) * 50.0);
        let weights = [1.0, 10.0, 1.0, 10.0, 1.0];
        let target = DofVector::from_fn(|_, _| 500.0 * rnd());
        let beta = 1e-3 / 80.0 * 3.0;
        let terms = TrackingTerms {
            theta_ddot_des: &theta,
            jacobians: &jac,
            jdot_v: &jdv,
            r_ddot_des: &rdd,
            weights: &weights,
            mass: &mass,
            mass_squared: &mass_squared,
            torque_target: &target,
            torque_weight: beta,
        };
        let mut normal = Box::new(MassMatrix::zeros());
        let mut x = DofVector::zeros();
        assert!(solve_tracking(&terms, &mut normal, &mut x));

        // The stacked system of Eq. 26/27, rows scaled by the square roots of the weights.
        let rows = 72 + 3 * NUM_CONTACT_JOINTS + NUM_DOFS;
        let mut a = DMatrix::<f64>::zeros(rows, NUM_DOFS);
        let mut rhs = nalgebra::DVector::<f64>::zeros(rows);
        for r in 0..72 {
            a[(r, 3 + r)] = 1.0;
            rhs[r] = theta[3 + r];
        }
        for i in 0..NUM_CONTACT_JOINTS {
            let s = weights[i].sqrt();
            for k in 0..3 {
                let r = 72 + 3 * i + k;
                for c in 0..NUM_DOFS {
                    a[(r, c)] = s * jac[i][(k, c)];
                }
                rhs[r] = s * (rdd[i][k] - jdv[i][k]);
            }
        }
        let sb = beta.sqrt();
        for k in 0..NUM_DOFS {
            let r = 72 + 3 * NUM_CONTACT_JOINTS + k;
            for c in 0..NUM_DOFS {
                a[(r, c)] = sb * mass[(k, c)];
            }
            rhs[r] = sb * target[k];
        }
        let want = a.svd(true, true).solve(&rhs, 1e-14).unwrap();
        let err = (0..NUM_DOFS)
            .map(|k| (x[k] - want[k]).abs())
            .fold(0.0, f64::max);
        let scale = want.amax();
        assert!(
            err < 1e-8 * scale.max(1.0),
            "max error {err} (scale {scale})"
        );
    }

    /// The textbook Cholesky (a dot product along a row per entry) and substitutions, as the
    /// solve was written before it ran down the columns.
    fn textbook_cholesky_solve(a: &mut MassMatrix, b: &mut DofVector) {
        const N: usize = NUM_DOFS;
        for c in 0..N {
            let mut d = a[(c, c)];
            for k in 0..c {
                d -= a[(c, k)] * a[(c, k)];
            }
            let d = d.sqrt();
            a[(c, c)] = d;
            for r in c + 1..N {
                let mut v = a[(r, c)];
                for k in 0..c {
                    v -= a[(r, k)] * a[(c, k)];
                }
                a[(r, c)] = v / d;
            }
        }
        for r in 0..N {
            let mut v = b[r];
            for k in 0..r {
                v -= a[(r, k)] * b[k];
            }
            b[r] = v / a[(r, r)];
        }
        for r in (0..N).rev() {
            let mut v = b[r];
            for k in r + 1..N {
                v -= a[(k, r)] * b[k];
            }
            b[r] = v / a[(r, r)];
        }
    }

    #[test]
    fn globalpose_cholesky_by_columns_gives_the_same_bits_as_the_textbook_form() {
        let mut rnd = uniform(11);
        for _ in 0..5 {
            let m = MassMatrix::from_fn(|_, _| rnd());
            let spd = m.transpose() * m + MassMatrix::identity() * 0.1;
            let rhs = DofVector::from_fn(|_, _| rnd());
            let (mut a, mut x) = (Box::new(spd), rhs);
            let (mut a_ref, mut x_ref) = (Box::new(spd), rhs);
            assert!(cholesky_solve_in_place(&mut a, &mut x));
            textbook_cholesky_solve(&mut a_ref, &mut x_ref);
            assert_eq!(x.as_slice(), x_ref.as_slice());
            // The factor too (lower triangle; the solve leaves the upper one as it was).
            for c in 0..NUM_DOFS {
                for r in c..NUM_DOFS {
                    assert_eq!(a[(r, c)].to_bits(), a_ref[(r, c)].to_bits(), "L[{r}][{c}]");
                }
            }
            // And it solves the system.
            let residual = (spd * x - rhs).amax();
            assert!(residual < 1e-9, "residual {residual}");
        }
    }

    /// The body's mass matrix and the contact joints' point Jacobians in a random pose and velocity.
    fn a_body_in_motion(seed: u64) -> (Box<MassMatrix>, Vec<PointJacobian>) {
        use imuflow_body::dynamics::{DynamicsData, pose_from_q};
        use imuflow_body::skeleton::CONTACT_JOINTS;
        let mut rnd = uniform(seed);
        let body = crate::PhysicsBody::new(1.75, 70.0).expect("the built-in body");
        let q = DofVector::from_fn(|_, _| rnd());
        let v = DofVector::from_fn(|_, _| 2.0 * rnd());
        let mut data = DynamicsData::new();
        data.set_state(&body.model, &pose_from_q(&q), &v);
        let mass = Box::new(*data.mass_matrix(&body.model));
        let jacobians = CONTACT_JOINTS
            .iter()
            .map(|&j| {
                let mut jac = PointJacobian::zeros();
                let point = Vector3::new(rnd(), rnd(), rnd()) * 0.1;
                data.point_jacobian(j, &point, &mut jac);
                jac
            })
            .collect();
        (mass, jacobians)
    }

    #[test]
    fn globalpose_mass_squared_skipping_zeros_gives_the_same_bits_as_the_dense_product() {
        for seed in [3, 4, 5] {
            let (mass, _) = a_body_in_motion(seed);
            // A real mass matrix has the tree's zeros, or the test would not test the skipping.
            let zeros = mass.iter().filter(|&&v| v == 0.0).count();
            assert!(zeros > NUM_DOFS * NUM_DOFS / 2, "{zeros} zero entries");
            let mut sparse = Box::new(MassMatrix::repeat(f64::NAN));
            square_skipping_zeros(&mass, &mut sparse);
            let dense = Box::new(*mass * *mass);
            for (i, (a, b)) in sparse.iter().zip(dense.iter()).enumerate() {
                // `==`: the sign of a zero may differ, nothing else.
                assert!(a == b, "entry {i}: {a:e} against {b:e}");
            }
        }
    }

    #[test]
    fn globalpose_gram_over_the_nonzero_columns_gives_the_same_bits_as_gemm_tr() {
        let mut rnd = uniform(9);
        let (_, jacobians) = a_body_in_motion(6);
        for jac in &jacobians {
            let zero_columns = (0..NUM_DOFS)
                .filter(|&c| jac.column(c).iter().all(|&v| v == 0.0))
                .count();
            assert!(zero_columns >= NUM_DOFS / 2, "{zero_columns} zero columns");
            let start = Box::new(MassMatrix::from_fn(|_, _| rnd()));
            let (mut sparse, mut dense) = (start.clone(), start);
            assert!(add_weighted_gram(&mut sparse, 7.5, jac));
            dense.gemm_tr(7.5, jac, jac, 1.0);
            for (i, (a, b)) in sparse.iter().zip(dense.iter()).enumerate() {
                assert!(a.to_bits() == b.to_bits(), "entry {i}: {a:e} against {b:e}");
            }
        }
        // A value that is not finite is refused, not hidden in a skipped product.
        let mut jac = jacobians[0];
        jac[(1, 40)] = f64::INFINITY;
        assert!(!add_weighted_gram(&mut MassMatrix::zeros(), 1.0, &jac));
    }

    #[test]
    fn globalpose_mass_squared_avx2_build_gives_the_same_bits_as_the_portable_one() {
        if !crate::wide::avx2() {
            eprintln!("no AVX2 on this CPU: only the portable build runs here");
            return;
        }
        for seed in [21, 22] {
            let (mass, _) = a_body_in_motion(seed);
            let (mut wide, mut portable) =
                (Box::new(MassMatrix::zeros()), Box::new(MassMatrix::zeros()));
            square_skipping_zeros(&mass, &mut wide);
            square_skipping_zeros_body(&mass, &mut portable);
            assert_eq!(wide.as_slice(), portable.as_slice());
        }
    }

    #[test]
    fn globalpose_cholesky_rejects_an_indefinite_matrix() {
        let mut a = Box::new(MassMatrix::identity());
        a[(40, 40)] = -1.0;
        let mut b = DofVector::repeat(1.0);
        assert!(!cholesky_solve_in_place(&mut a, &mut b));
        let mut a = Box::new(MassMatrix::identity() * 4.0);
        let mut b = DofVector::repeat(2.0);
        assert!(cholesky_solve_in_place(&mut a, &mut b));
        assert!(b.iter().all(|v| (v - 0.5).abs() < 1e-15));
    }
}
