//! Rotation representations and helpers (f64; cast with `.cast::<f32>()` for the wire).
//!
//! Conventions (reference §0): matrices act on column vectors; the 6D representation is the first two
//! COLUMNS of R, `[R00, R10, R20, R01, R11, R21]`; Euler 'XYZ' is intrinsic as in scipy
//! (R = Rx(a)·Ry(b)·Rz(c)); the angle between rotations is ‖log(R1ᵀR2)‖.

use nalgebra::{Matrix3, Quaternion, RealField, Rotation3, Unit, UnitQuaternion, Vector3};

/// Encode R as its first two columns: `[R00, R10, R20, R01, R11, R21]` (f32 or f64).
pub fn r6d_from_rotation<T: RealField + Copy>(r: &Rotation3<T>) -> [T; 6] {
    let m = r.matrix();
    [
        m[(0, 0)],
        m[(1, 0)],
        m[(2, 0)],
        m[(0, 1)],
        m[(1, 1)],
        m[(2, 1)],
    ]
}

/// Decode a 6D rotation (f32 or f64) by Gram–Schmidt: c0 = normalize(a), c1 = normalize(b − (c0·b)c0),
/// c2 = c0 × c1. As in the reference implementation, NaN produced by degenerate input (zero or parallel
/// columns) becomes 0 (here any non-finite entry does, which also covers infinite input), so degenerate
/// input gives a matrix with zero columns rather than NaN; callers that need a proper rotation should
/// reject non-finite or degenerate network output before decoding.
pub fn rotation_from_r6d<T: RealField + Copy>(r6d: &[T; 6]) -> Rotation3<T> {
    let a = Vector3::new(r6d[0], r6d[1], r6d[2]);
    let b = Vector3::new(r6d[3], r6d[4], r6d[5]);
    let c0 = a / a.norm();
    let c1 = b - c0 * c0.dot(&b);
    let c1 = c1 / c1.norm();
    let c2 = c0.cross(&c1);
    let mut m = Matrix3::from_columns(&[c0, c1, c2]);
    m.iter_mut().for_each(|v| {
        if !v.is_finite() {
            *v = T::zero();
        }
    });
    Rotation3::from_matrix_unchecked(m)
}

/// Intrinsic rotation about x, then the new y, then the newer z (scipy `'XYZ'`): R = Rx(a)·Ry(b)·Rz(c).
/// Angles in radians.
pub fn rotation_from_euler_xyz(angles_rad: [f64; 3]) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), angles_rad[0])
        * Rotation3::from_axis_angle(&Vector3::y_axis(), angles_rad[1])
        * Rotation3::from_axis_angle(&Vector3::z_axis(), angles_rad[2])
}

/// Inverse of [`rotation_from_euler_xyz`]: angles (a, b, c) in radians with b ∈ [−π/2, π/2].
/// At gimbal lock (|b| = π/2) only a ± c is defined; like scipy, the third angle is set to 0.
pub fn euler_xyz_from_rotation(r: &Rotation3<f64>) -> [f64; 3] {
    let m = r.matrix();
    let sb = m[(0, 2)].clamp(-1.0, 1.0);
    let b = sb.asin();
    // cos(b) below ~1e-7 rad from the pole: treat as gimbal lock.
    if (1.0 - sb.abs()) > 1e-12 {
        let a = (-m[(1, 2)]).atan2(m[(2, 2)]);
        let c = (-m[(0, 1)]).atan2(m[(0, 0)]);
        [a, b, c]
    } else if sb > 0.0 {
        // Rx(a)Ry(π/2): row 1 = [sin(a+c), cos(a+c), 0].
        [m[(1, 0)].atan2(m[(1, 1)]), std::f64::consts::FRAC_PI_2, 0.0]
    } else {
        // Rx(a)Ry(−π/2): row 1 = [sin(c−a), cos(c−a), 0].
        [
            (-m[(1, 0)]).atan2(m[(1, 1)]),
            -std::f64::consts::FRAC_PI_2,
            0.0,
        ]
    }
}

/// Rotation from a rotation vector (axis × angle, radians; Rodrigues).
pub fn rotation_from_axis_angle(rotvec_rad: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::new(*rotvec_rad)
}

/// Rotation vector (axis × angle, angle in [0, π], radians) of R. Goes through a quaternion (Shepperd's
/// method in nalgebra) so it stays accurate near 0 and near π, where the skew-part formula fails.
pub fn axis_angle_from_rotation(r: &Rotation3<f64>) -> Vector3<f64> {
    let q = UnitQuaternion::from_rotation_matrix(r);
    rotvec_from_quaternion(&q)
}

fn rotvec_from_quaternion(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let s = v.norm();
    if s < 1e-12 {
        // angle ≈ 2s/w; first-order limit of angle/s.
        return v * (2.0 / w);
    }
    let angle = 2.0 * s.atan2(w);
    v * (angle / s)
}

/// Shortest rotation taking direction `from` to direction `to`. For antiparallel inputs the rotation is
/// by π about an axis perpendicular to `from` (the choice of axis is then arbitrary but deterministic).
pub fn from_to(from: &Unit<Vector3<f64>>, to: &Unit<Vector3<f64>>) -> Rotation3<f64> {
    let c = from.dot(to);
    if c < -1.0 + 1e-12 {
        // Pick the basis axis least aligned with `from` to build a perpendicular axis.
        let f = from.into_inner();
        let helper = if f.x.abs() <= f.y.abs() && f.x.abs() <= f.z.abs() {
            Vector3::x()
        } else if f.y.abs() <= f.z.abs() {
            Vector3::y()
        } else {
            Vector3::z()
        };
        let axis = Unit::new_normalize(f.cross(&helper));
        return Rotation3::from_axis_angle(&axis, std::f64::consts::PI);
    }
    let v = from.cross(to);
    let q = UnitQuaternion::new_normalize(Quaternion::new(1.0 + c, v.x, v.y, v.z));
    q.to_rotation_matrix()
}

/// Spherical linear interpolation from `r0` (t = 0) to `r1` (t = 1) along the shorter arc.
/// Never panics (unlike `UnitQuaternion::slerp` on antipodal input).
pub fn slerp(r0: &Rotation3<f64>, r1: &Rotation3<f64>, t: f64) -> Rotation3<f64> {
    let q0 = UnitQuaternion::from_rotation_matrix(r0);
    let q1 = UnitQuaternion::from_rotation_matrix(r1);
    slerp_quaternion(&q0, &q1, t).to_rotation_matrix()
}

/// Quaternion form of [`slerp`].
pub fn slerp_quaternion(
    q0: &UnitQuaternion<f64>,
    q1: &UnitQuaternion<f64>,
    t: f64,
) -> UnitQuaternion<f64> {
    let a = q0.quaternion();
    let mut b = *q1.quaternion();
    let mut d = a.dot(&b);
    if d < 0.0 {
        b = -b;
        d = -d;
    }
    if d > 1.0 - 1e-10 {
        return UnitQuaternion::new_normalize(a * (1.0 - t) + b * t);
    }
    let theta = d.min(1.0).acos();
    let s = theta.sin();
    let wa = ((1.0 - t) * theta).sin() / s;
    let wb = (t * theta).sin() / s;
    UnitQuaternion::new_normalize(a * wa + b * wb)
}

/// Geodesic angle between two rotations, ‖log(R1ᵀR2)‖, in radians ∈ [0, π].
pub fn angle_between(r1: &Rotation3<f64>, r2: &Rotation3<f64>) -> f64 {
    let q = UnitQuaternion::from_rotation_matrix(&(r1.transpose() * r2));
    2.0 * q.imag().norm().atan2(q.w.abs())
}

/// Unit quaternion in wire order `[w, x, y, z]` (w ≥ 0) of R.
pub fn quat_wxyz_from_rotation(r: &Rotation3<f64>) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(r);
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    [s * q.w, s * q.i, s * q.j, s * q.k]
}

/// Rotation from a wire quaternion `[w, x, y, z]`, normalized; `None` when its norm is not a positive
/// finite number (e.g. all zeros or NaN from a failed sensor).
pub fn rotation_from_quat_wxyz(q: &[f64; 4]) -> Option<Rotation3<f64>> {
    let q = Quaternion::new(q[0], q[1], q[2], q[3]);
    let n = q.norm();
    if !(n.is_finite() && n > 1e-12) {
        return None;
    }
    Some(UnitQuaternion::new_unchecked(q / n).to_rotation_matrix())
}

/// Row-major flattening `[R00, R01, R02, R10, …]`, the wire and network-input layout (f32 or f64).
pub fn row_major_from_rotation<T: RealField + Copy>(r: &Rotation3<T>) -> [T; 9] {
    let m = r.matrix();
    std::array::from_fn(|k| m[(k / 3, k % 3)])
}

/// Inverse of [`row_major_from_rotation`]. The matrix is taken as is (not re-orthonormalized).
pub fn rotation_from_row_major<T: RealField + Copy>(v: &[T; 9]) -> Rotation3<T> {
    Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(v))
}

/// Rotation about a principal axis, used by the BVH channel conventions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// Unit vector along this axis.
    pub fn unit(self) -> Unit<Vector3<f64>> {
        match self {
            Axis::X => Vector3::x_axis(),
            Axis::Y => Vector3::y_axis(),
            Axis::Z => Vector3::z_axis(),
        }
    }

    /// Rotation by `angle_rad` about this axis.
    pub fn rotation(self, angle_rad: f64) -> Rotation3<f64> {
        Rotation3::from_axis_angle(&self.unit(), angle_rad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::random_rotations;
    use approx::assert_relative_eq;
    use std::f64::consts::{FRAC_PI_2, PI};

    #[test]
    fn ninety_degrees_about_y_maps_z_to_x() {
        let r = rotation_from_axis_angle(&Vector3::new(0.0, FRAC_PI_2, 0.0));
        assert_relative_eq!(r * Vector3::z(), Vector3::x(), epsilon = 1e-12);
        assert_relative_eq!(r * Vector3::x(), -Vector3::z(), epsilon = 1e-12);
        assert_relative_eq!(r * Vector3::y(), Vector3::y(), epsilon = 1e-12);
    }

    #[test]
    fn r6d_is_the_first_two_columns() {
        // 90° about z: columns are R·x = y and R·y = −x.
        let r = Axis::Z.rotation(FRAC_PI_2);
        let e = r6d_from_rotation(&r);
        let expected = [0.0, 1.0, 0.0, -1.0, 0.0, 0.0];
        for (a, b) in e.iter().zip(expected) {
            assert_relative_eq!(*a, b, epsilon = 1e-12);
        }
        for r in random_rotations(200, 7) {
            let back = rotation_from_r6d(&r6d_from_rotation(&r));
            assert!(angle_between(&r, &back) < 1e-9);
        }
    }

    #[test]
    fn r6d_decode_orthonormalizes_and_zeroes_nan() {
        // Unnormalized, non-orthogonal columns: a along x (scaled), b tilted towards x.
        let r = rotation_from_r6d(&[2.0, 0.0, 0.0, 1.0, 3.0, 0.0]);
        assert_relative_eq!(*r.matrix(), Matrix3::identity(), epsilon = 1e-12);
        let zero = rotation_from_r6d(&[0.0; 6]);
        assert!(zero.matrix().iter().all(|v| *v == 0.0));
        // Parallel columns: c0 is defined, c1 and c2 become 0.
        let par = rotation_from_r6d(&[0.0, 1.0, 0.0, 0.0, 2.0, 0.0]);
        assert_relative_eq!(
            par.matrix().column(0).into_owned(),
            Vector3::y(),
            epsilon = 1e-12
        );
        assert!(
            par.matrix()
                .column(1)
                .iter()
                .chain(par.matrix().column(2).iter())
                .all(|v| *v == 0.0)
        );
        // The f32 path (network outputs) agrees with f64.
        for r in random_rotations(20, 13) {
            let e = r6d_from_rotation(&r).map(|v| v as f32);
            let r32 = rotation_from_r6d(&e);
            assert!(angle_between(&r, &r32.cast::<f64>()) < 1e-5);
        }
    }

    #[test]
    fn euler_xyz_matches_hand_values_and_round_trips() {
        // Intrinsic XYZ with (90°, 0, 0) is Rx(90°): y → z.
        let r = rotation_from_euler_xyz([FRAC_PI_2, 0.0, 0.0]);
        assert_relative_eq!(r * Vector3::y(), Vector3::z(), epsilon = 1e-12);
        // Intrinsic order: Rx(90°)·Ry(90°) maps x → Rx(−z) = y (extrinsic order would give −z).
        let r = rotation_from_euler_xyz([FRAC_PI_2, FRAC_PI_2, 0.0]);
        assert_relative_eq!(r * Vector3::x(), Vector3::y(), epsilon = 1e-12);
        for r in random_rotations(500, 11) {
            let e = euler_xyz_from_rotation(&r);
            assert!(e[1].abs() <= FRAC_PI_2 + 1e-12);
            assert!(angle_between(&r, &rotation_from_euler_xyz(e)) < 1e-9);
        }
    }

    #[test]
    fn euler_xyz_gimbal_lock_keeps_the_rotation() {
        for b in [FRAC_PI_2, -FRAC_PI_2] {
            let r = rotation_from_euler_xyz([0.3, b, 0.5]);
            let e = euler_xyz_from_rotation(&r);
            assert_eq!(e[2], 0.0);
            assert_relative_eq!(e[1], b, epsilon = 1e-6);
            assert!(
                angle_between(&r, &rotation_from_euler_xyz(e)) < 1e-9,
                "{e:?}"
            );
        }
        // Only a+c (b = +90°) or a−c... is defined; the recovered first angle carries it.
        let e = euler_xyz_from_rotation(&rotation_from_euler_xyz([0.3, FRAC_PI_2, 0.5]));
        assert_relative_eq!(e[0], 0.8, epsilon = 1e-9);
        let e = euler_xyz_from_rotation(&rotation_from_euler_xyz([0.3, -FRAC_PI_2, 0.5]));
        assert_relative_eq!(e[0], -0.2, epsilon = 1e-9);
    }

    #[test]
    fn axis_angle_round_trips_near_zero_and_near_pi() {
        let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
        for angle in [0.0, 1e-9, 1e-5, 0.7, 2.0, PI - 1e-6, PI - 1e-9, PI] {
            let v = axis * angle;
            let back = axis_angle_from_rotation(&rotation_from_axis_angle(&v));
            if angle > PI - 1e-6 {
                // At π the axis sign is ambiguous: compare the rotations and the angle.
                assert_relative_eq!(back.norm(), angle, epsilon = 1e-7);
                assert!(back.normalize().dot(&axis).abs() > 1.0 - 1e-9);
            } else {
                assert_relative_eq!(back, v, epsilon = 1e-12);
            }
        }
        for r in random_rotations(200, 3) {
            let back = rotation_from_axis_angle(&axis_angle_from_rotation(&r));
            assert!(angle_between(&r, &back) < 1e-9);
        }
    }

    #[test]
    fn from_to_maps_a_to_b_including_antiparallel() {
        let cases = [
            (Vector3::x(), Vector3::y()),
            (Vector3::new(1.0, 2.0, 3.0), Vector3::new(-1.0, 0.5, 0.1)),
            (Vector3::z(), Vector3::z()),
            (Vector3::z(), -Vector3::z()),
            (Vector3::new(0.3, -0.2, 0.9), Vector3::new(-0.3, 0.2, -0.9)),
        ];
        for (a, b) in cases {
            let (a, b) = (Unit::new_normalize(a), Unit::new_normalize(b));
            let r = from_to(&a, &b);
            assert_relative_eq!(r * a.into_inner(), b.into_inner(), epsilon = 1e-12);
            assert_relative_eq!(r.matrix().determinant(), 1.0, epsilon = 1e-12);
            // Shortest: the angle equals the angle between the vectors.
            assert_relative_eq!(
                angle_between(&Rotation3::identity(), &r),
                a.dot(&b).clamp(-1.0, 1.0).acos(),
                epsilon = 1e-7
            );
        }
    }

    #[test]
    fn slerp_halfway_about_a_fixed_axis_and_endpoints() {
        let r0 = Axis::Y.rotation(0.2);
        let r1 = Axis::Y.rotation(1.4);
        assert_relative_eq!(
            angle_between(&slerp(&r0, &r1, 0.5), &Axis::Y.rotation(0.8)),
            0.0,
            epsilon = 1e-9
        );
        assert!(angle_between(&slerp(&r0, &r1, 0.0), &r0) < 1e-9);
        assert!(angle_between(&slerp(&r0, &r1, 1.0), &r1) < 1e-9);
        // Rotations exactly π apart: no panic, and the midpoint is π/2 from both.
        let r1 = Axis::X.rotation(PI);
        let mid = slerp(&Rotation3::identity(), &r1, 0.5);
        assert_relative_eq!(angle_between(&mid, &r1), FRAC_PI_2, epsilon = 1e-9);
    }

    #[test]
    fn euler_xyz_round_trips_just_off_gimbal_lock() {
        for b in [FRAC_PI_2 - 1e-5, FRAC_PI_2 - 1e-7, -FRAC_PI_2 + 1e-6] {
            let r = rotation_from_euler_xyz([0.4, b, -1.1]);
            let e = euler_xyz_from_rotation(&r);
            assert!(
                angle_between(&r, &rotation_from_euler_xyz(e)) < 1e-6,
                "{b}: {e:?}"
            );
        }
    }

    #[test]
    fn wire_quaternions_and_row_major_layout() {
        // 90° about z: q = [cos 45°, 0, 0, sin 45°].
        let q = quat_wxyz_from_rotation(&Axis::Z.rotation(FRAC_PI_2));
        let h = std::f64::consts::FRAC_1_SQRT_2;
        for (a, b) in q.iter().zip([h, 0.0, 0.0, h]) {
            assert_relative_eq!(*a, b, epsilon = 1e-12);
        }
        // w ≥ 0 even for rotations whose quaternion nalgebra returns with w < 0.
        for r in random_rotations(50, 17) {
            let q = quat_wxyz_from_rotation(&r);
            assert!(q[0] >= 0.0);
            let back = rotation_from_quat_wxyz(&q.map(|v| 3.0 * v)).unwrap();
            assert!(angle_between(&r, &back) < 1e-12);
        }
        assert!(rotation_from_quat_wxyz(&[0.0; 4]).is_none());
        assert!(rotation_from_quat_wxyz(&[f64::NAN, 0.0, 0.0, 1.0]).is_none());
        // Row-major: R·x = y puts R10 = 1 at index 3.
        let v = row_major_from_rotation(&Axis::Z.rotation(FRAC_PI_2));
        assert_relative_eq!(v[3], 1.0, epsilon = 1e-12);
        assert_relative_eq!(v[1], -1.0, epsilon = 1e-12);
        let r = Axis::X.rotation(0.3);
        assert_eq!(rotation_from_row_major(&row_major_from_rotation(&r)), r);
    }

    #[test]
    fn angle_between_is_the_log_norm() {
        let r1 = Axis::Z.rotation(0.4);
        let r2 = Axis::Z.rotation(-0.3);
        assert_relative_eq!(angle_between(&r1, &r2), 0.7, epsilon = 1e-12);
        for (a, b) in random_rotations(50, 5).iter().zip(random_rotations(50, 9)) {
            let expected = axis_angle_from_rotation(&(a.transpose() * b)).norm();
            assert_relative_eq!(angle_between(a, &b), expected, epsilon = 1e-9);
        }
    }
}
