//! Small rotation helpers the calibration needs beyond `imuflow_body::rotation`.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

/// Rotation average by projecting the arithmetic mean of the matrices onto SO(3) (the reference's
/// `mean_rot`, §4: U·Vᵀ of the SVD of the mean, with the last column of U flipped if the determinant
/// would be negative). This is the chordal L2 mean: exact for identical inputs and within a tiny
/// fraction of the spread of the geodesic mean for the few-degree spreads of a still window.
/// `None` for no rotations (or a degenerate SVD, which a set of rotations never produces).
pub fn mean_rotation<'a>(
    rotations: impl IntoIterator<Item = &'a Rotation3<f64>>,
) -> Option<Rotation3<f64>> {
    let mut sum = Matrix3::zeros();
    let mut n = 0usize;
    for r in rotations {
        sum += r.matrix();
        n += 1;
    }
    if n == 0 {
        return None;
    }
    project_to_rotation(&(sum / n as f64))
}

/// The rotation nearest to `m` in the Frobenius norm; `None` if `m` is not finite.
pub fn project_to_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = m.svd(true, true);
    let (mut u, v_t) = (svd.u?, svd.v_t?);
    if (u * v_t).determinant() < 0.0 {
        u.column_mut(2).neg_mut();
    }
    Some(Rotation3::from_matrix_unchecked(u * v_t))
}

/// Signed angle (rad, in (−π, π]) of the rotation about `axis` that turns `from` towards `to`, both
/// taken in the plane perpendicular to `axis` (right-handed about `axis`).
pub fn signed_angle_about(
    axis: &Unit<Vector3<f64>>,
    from: &Vector3<f64>,
    to: &Vector3<f64>,
) -> f64 {
    let sin = from.cross(to).dot(axis);
    let cos = from.dot(to) - from.dot(axis) * to.dot(axis);
    sin.atan2(cos)
}

/// `v` without its component along `axis`.
pub fn horizontal(v: &Vector3<f64>, axis: &Unit<Vector3<f64>>) -> Vector3<f64> {
    v - axis.into_inner() * v.dot(axis)
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::rotation::{Axis, angle_between};

    #[test]
    fn mean_of_symmetric_rotations_is_the_middle() {
        let base = Axis::X.rotation(0.4) * Axis::Z.rotation(-1.1);
        let a = base * Axis::Y.rotation(0.1);
        let b = base * Axis::Y.rotation(-0.1);
        let m = mean_rotation([&a, &b]).expect("two rotations");
        assert!(angle_between(&m, &base) < 1e-9);
        assert!(mean_rotation(std::iter::empty()).is_none());
    }

    #[test]
    fn projection_repairs_a_scaled_rotation_and_rejects_nan() {
        let r = Axis::Z.rotation(0.7) * Axis::X.rotation(2.0);
        let p = project_to_rotation(&(r.matrix() * 0.8)).expect("finite");
        assert!(angle_between(&p, &r) < 1e-9);
        assert!((p.matrix().determinant() - 1.0).abs() < 1e-12);
        let mut m = *r.matrix();
        m[(1, 1)] = f64::NAN;
        assert!(project_to_rotation(&m).is_none());
    }

    #[test]
    fn signed_angle_is_right_handed() {
        let up = Vector3::y_axis();
        let a = signed_angle_about(&up, &Vector3::z(), &Vector3::x());
        assert!(
            (a - std::f64::consts::FRAC_PI_2).abs() < 1e-12,
            "z to x about +y is +90°"
        );
        // Vertical components do not matter.
        let b = signed_angle_about(
            &up,
            &Vector3::new(0.0, 5.0, 1.0),
            &Vector3::new(-1.0, -3.0, 0.0),
        );
        assert!((b + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }
}
