//! Quaternion and vector helpers on plain arrays (`[w, x, y, z]`, as on the wire).

/// A quaternion `[w, x, y, z]`.
pub type Quat = [f64; 4];
/// A 3-vector.
pub type Vec3 = [f64; 3];

pub const IDENTITY: Quat = [1.0, 0.0, 0.0, 0.0];

pub fn dot(a: &Quat, b: &Quat) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// `q / |q|`; `None` for a zero or non-finite quaternion.
pub fn normalized(q: Quat) -> Option<Quat> {
    let n = dot(&q, &q).sqrt();
    (n.is_finite() && n > 1e-9).then(|| q.map(|v| v / n))
}

/// Spherical linear interpolation from `a` (u = 0) to `b` (u = 1) along the shorter arc (`b` is
/// negated when the two lie in opposite hemispheres: q and −q are the same rotation). Nearly equal
/// rotations are interpolated linearly and normalized, where slerp's sin(θ) would divide by ~0.
pub fn slerp(a: &Quat, b: &Quat, u: f64) -> Quat {
    let mut cos = dot(a, b);
    let b = if cos < 0.0 {
        cos = -cos;
        b.map(|v| -v)
    } else {
        *b
    };
    let (wa, wb) = if cos > 0.9995 {
        (1.0 - u, u)
    } else {
        let theta = cos.min(1.0).acos();
        let s = theta.sin();
        (((1.0 - u) * theta).sin() / s, (u * theta).sin() / s)
    };
    let q = [0, 1, 2, 3].map(|i| wa * a[i] + wb * b[i]);
    normalized(q).unwrap_or(*a)
}

/// Linear interpolation from `a` (u = 0) to `b` (u = 1).
pub fn lerp(a: &Vec3, b: &Vec3, u: f64) -> Vec3 {
    [0, 1, 2].map(|i| a[i] + u * (b[i] - a[i]))
}

/// The product `a ⊗ b` (first b, then a, as rotations).
pub fn mul(a: &Quat, b: &Quat) -> Quat {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// The conjugate (the inverse of a unit quaternion).
pub fn conj(q: &Quat) -> Quat {
    [q[0], -q[1], -q[2], -q[3]]
}

/// The rotation vector (axis · angle, rad) of a unit quaternion, the shorter way round.
pub fn rotation_vector(q: &Quat) -> Vec3 {
    let q = if q[0] < 0.0 { q.map(|c| -c) } else { *q };
    let v = (q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if v < 1e-12 {
        // sin(θ/2) ≈ θ/2: the vector part times 2.
        return [2.0 * q[1], 2.0 * q[2], 2.0 * q[3]];
    }
    let angle = 2.0 * v.atan2(q[0]);
    [q[1] / v * angle, q[2] / v * angle, q[3] / v * angle]
}

/// The unit quaternion of a rotation vector (axis · angle, rad): the inverse of
/// [`rotation_vector`].
pub fn from_rotation_vector(v: &Vec3) -> Quat {
    let angle = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let (s, c) = (0.5 * angle).sin_cos();
    // sin(θ/2)/θ → 1/2 for small θ.
    let k = if angle < 1e-12 { 0.5 } else { s / angle };
    [c, k * v[0], k * v[1], k * v[2]]
}

/// The rotation angle between two unit quaternions, rad (accurate for small angles too, unlike
/// `acos` of their dot product).
pub fn angle_between(a: &Quat, b: &Quat) -> f64 {
    let r = mul(&conj(a), b);
    let v = (r[1] * r[1] + r[2] * r[2] + r[3] * r[3]).sqrt();
    2.0 * v.atan2(r[0].abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn about_z(angle: f64) -> Quat {
        [(angle / 2.0).cos(), 0.0, 0.0, (angle / 2.0).sin()]
    }

    #[test]
    fn slerp_moves_at_a_constant_rate_along_the_shorter_arc() {
        let a = about_z(0.2);
        let b = about_z(1.4);
        for u in [0.0, 0.25, 0.5, 1.0] {
            let q = slerp(&a, &b, u);
            assert!(angle_between(&q, &about_z(0.2 + 1.2 * u)) < 1e-12, "{u}");
        }
        // The same rotation written with the other sign: still the short way.
        let q = slerp(&a, &b.map(|v| -v), 0.5);
        assert!(angle_between(&q, &about_z(0.8)) < 1e-12);
        // Nearly equal: no division by ~0.
        let q = slerp(&a, &about_z(0.2 + 1e-9), 0.5);
        assert!(angle_between(&q, &a) < 1e-8);
    }

    #[test]
    fn normalized_refuses_zero_and_non_finite() {
        assert_eq!(normalized([0.0; 4]), None);
        assert_eq!(normalized([f64::NAN, 0.0, 0.0, 1.0]), None);
        assert_eq!(normalized([2.0, 0.0, 0.0, 0.0]), Some(IDENTITY));
    }
}
