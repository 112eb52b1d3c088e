//! A Cholesky factorisation of dense matrices that gives nalgebra's bits, four lanes wide where
//! the CPU has AVX2.
//!
//! PIP's QP factorises its reduced Hessian (about 90 × 90) once a solve and its dual's
//! normal matrix (about 30 × 30) once per interior-point iteration and for the starting point;
//! GlobalPose's tracking factorises its 75 × 75 normal matrix twice a frame. nalgebra's
//! `Cholesky::new_internal` was the largest single item of `imuflow bench physics` (16-18 % of its
//! samples), compiled, as the whole binary, for plain x86-64. This is the same left-looking
//! algorithm with the same arithmetic in the same order: column `j` gets `−L[j][k]·(column k)`
//! added for each earlier `k`, then its diagonal's square root and the division below it. Built a
//! second time for AVX2 ([`crate::wide`]), and the substitutions stay nalgebra's, so a solve gives
//! the same bits as `Cholesky::new(m)?.solve(b)` (tests).

use nalgebra::{DMatrix, DVector};

use crate::wide::with_avx2;

/// The factor `L` of `A = L·Lᵀ`, in the lower triangle (the strict upper triangle still holds `A`'s,
/// as nalgebra's `l_dirty`).
pub struct ColumnCholesky {
    factor: DMatrix<f64>,
}

impl ColumnCholesky {
    /// Factorises `matrix` (square; only its lower triangle is read). `None` when a pivot is zero,
    /// negative or not a number, as `nalgebra::Cholesky::new`.
    pub fn new(mut matrix: DMatrix<f64>) -> Option<ColumnCholesky> {
        assert!(matrix.is_square(), "a square matrix");
        let n = matrix.nrows();
        factorise(matrix.as_mut_slice(), n).then_some(ColumnCholesky { factor: matrix })
    }

    /// `L` in the lower triangle, the input's strict upper triangle above it.
    pub fn l_dirty(&self) -> &DMatrix<f64> {
        &self.factor
    }

    /// `x` with `A·x = b`: nalgebra's forward and backward substitutions on `L`.
    pub fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let mut x = b.clone();
        self.factor.solve_lower_triangular_unchecked_mut(&mut x);
        self.factor.tr_solve_lower_triangular_unchecked_mut(&mut x);
        x
    }
}

with_avx2! {
    /// `L` of column-major `a` (`n × n`) in place, nalgebra's arithmetic (module docs); false at a
    /// pivot that is zero, negative or not a number.
    pub(crate) fn factorise(a: &mut [f64], n: usize) -> bool = factorise_body;
}

#[inline(always)]
fn factorise_body(a: &mut [f64], n: usize) -> bool {
    assert_eq!(a.len(), n * n, "an n × n matrix");
    for j in 0..n {
        let (done, rest) = a.split_at_mut(j * n);
        let column = &mut rest[j..n];
        // Column k from row j down, with the factor nalgebra's `col_j.axpy(−L[j][k], col_k, 1)`
        // multiplies it by.
        let earlier = |k: usize| {
            let c = &done[k * n + j..(k + 1) * n];
            (-c[0], c)
        };
        // Four earlier columns per pass over column j: each entry still gets `y = f·x + y` for
        // k = 0, 1, 2, … in order.
        let mut k = 0;
        while k + 4 <= j {
            let [(f0, c0), (f1, c1), (f2, c2), (f3, c3)] = std::array::from_fn(|i| earlier(k + i));
            add_four_columns(column, [f0, f1, f2, f3], [c0, c1, c2, c3]);
            k += 4;
        }
        for k in k..j {
            let (f, c) = earlier(k);
            for (y, x) in column.iter_mut().zip(c) {
                *y += f * x;
            }
        }
        let diag = column[0];
        // nalgebra's `try_sqrt` refuses a negative number and NaN; a zero is refused before it.
        if diag == 0.0 || diag.is_nan() || diag < 0.0 {
            return false;
        }
        let denom = diag.sqrt();
        column[0] = denom;
        for y in &mut column[1..] {
            *y /= denom;
        }
    }
    true
}

/// `y += f₀·x₀`, then `+= f₁·x₁`, `+= f₂·x₂`, `+= f₃·x₃`, entry by entry in that order: four
/// column `axpy`s with the bits of four passes, each entry loaded and stored once (the passes were
/// bound by those loads and stores). Inlined into its callers' AVX2 builds.
#[inline(always)]
pub(crate) fn add_four_columns(y: &mut [f64], f: [f64; 4], x: [&[f64]; 4]) {
    let [f0, f1, f2, f3] = f;
    let [x0, x1, x2, x3] = x;
    for ((((y, x0), x1), x2), x3) in y.iter_mut().zip(x0).zip(x1).zip(x2).zip(x3) {
        let mut v = *y;
        v += f0 * x0;
        v += f1 * x1;
        v += f2 * x2;
        v += f3 * x3;
        *y = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_random::uniform;
    use nalgebra::Cholesky;

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn the_factor_and_the_solve_have_nalgebras_bits() {
        let mut rnd = uniform(17);
        for n in [1, 2, 7, 30, 87, 99] {
            let a = DMatrix::from_fn(n, n, |_, _| rnd());
            let spd = a.transpose() * &a + DMatrix::identity(n, n) * 0.1;
            let b = DVector::from_fn(n, |_, _| rnd());
            let ours = ColumnCholesky::new(spd.clone()).expect("positive definite");
            let theirs = Cholesky::new(spd.clone()).expect("positive definite");
            assert_eq!(
                bits(ours.l_dirty().as_slice()),
                bits(theirs.l_dirty().as_slice()),
                "n = {n}"
            );
            assert_eq!(
                bits(ours.solve(&b).as_slice()),
                bits(theirs.solve(&b).as_slice()),
                "n = {n}"
            );
            // Both builds agree where this CPU has AVX2 (the public path takes it).
            let mut portable = spd.clone();
            assert!(factorise_body(portable.as_mut_slice(), n));
            assert_eq!(
                bits(portable.as_slice()),
                bits(ours.l_dirty().as_slice()),
                "n = {n}"
            );
            // And it solves the system.
            let residual = (&spd * ours.solve(&b) - &b).amax();
            assert!(residual < 1e-8, "n = {n}: residual {residual}");
        }
    }

    #[test]
    fn a_matrix_nalgebra_refuses_is_refused() {
        let mut indefinite = DMatrix::<f64>::identity(5, 5);
        indefinite[(3, 3)] = -1.0;
        let mut singular = DMatrix::<f64>::identity(5, 5);
        singular[(2, 2)] = 0.0;
        let mut nan = DMatrix::<f64>::identity(5, 5);
        nan[(4, 1)] = f64::NAN;
        for m in [indefinite, singular, nan] {
            assert!(Cholesky::new(m.clone()).is_none());
            assert!(ColumnCholesky::new(m).is_none());
        }
    }
}
