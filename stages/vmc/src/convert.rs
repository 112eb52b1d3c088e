//! imuflow's model frame M to Unity's frame, the one VMC receivers read.
//!
//! M (docs/architecture.md, "Conventions") is right-handed: x = the subject's left, y = up,
//! z = forward (the subject faces +z in the T-pose). Unity is left-handed: x = right, y = up,
//! z = forward, and a humanoid avatar faces +z. Both name the same physical directions up and
//! forward; only "left" and "right" swap axes, so the change of coordinates is the mirror
//! `S = diag(−1, 1, 1)`:
//!
//! - a point or offset: `p_U = S·p_M`, i.e. `(x, y, z) → (−x, y, z)`;
//! - a rotation: `R_U = S·R_M·S⁻¹ = S·R_M·S`, so that `R_U·p_U = S·(R_M·p_M)`. A mirror turns
//!   the sense of a rotation around (a rotation axis is a pseudovector): `S·R(a, θ)·S =
//!   R(det(S)·S·a, θ) = R((a_x, −a_y, −a_z), θ)`. With the quaternion `q = (cos θ/2, sin θ/2·a)`
//!   that is `(w, x, y, z) → (w, x, −y, −z)`. Unity's quaternion arithmetic is Hamilton's on the
//!   coordinates (its handedness only says how the numbers look on screen), so the converted
//!   quaternion rotates the converted points exactly as the original rotates the original points
//!   (a property test below checks it).
//!
//! The subject's left stays the avatar's left: M's +x (left) is Unity's −x, which is the left of
//! an avatar facing +z. Neither conversion depends on the other bones, so a local rotation
//! converts the same way as a global one, and products convert factor by factor.

/// A point or offset in M as Unity coordinates: `(x, y, z) → (−x, y, z)`.
pub fn unity_point(p_m: [f32; 3]) -> [f32; 3] {
    [-p_m[0], p_m[1], p_m[2]]
}

/// A rotation quaternion `[w, x, y, z]` in M as the same rotation in Unity coordinates,
/// `[w, x, −y, −z]` (see the module docs for the derivation).
pub fn unity_rotation_wxyz(q_m: [f32; 4]) -> [f32; 4] {
    [q_m[0], q_m[1], -q_m[2], -q_m[3]]
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Point3, Quaternion, Rotation3, UnitQuaternion, Vector3};
    use proptest::prelude::*;

    use super::*;

    fn unit(q: [f32; 4]) -> UnitQuaternion<f64> {
        let q = q.map(f64::from);
        UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
    }

    fn wxyz(q: &UnitQuaternion<f64>) -> [f32; 4] {
        [q.w, q.i, q.j, q.k].map(|v| v as f32)
    }

    fn rotate(q: [f32; 4], p: [f32; 3]) -> [f32; 3] {
        let p = Point3::from(Vector3::from(p.map(f64::from)));
        let r = unit(q) * p;
        [r.x, r.y, r.z].map(|v| v as f32)
    }

    fn close(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-4)
    }

    /// Quaternions q and −q are the same rotation.
    fn same_rotation(a: [f32; 4], b: [f32; 4]) -> bool {
        let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
        (dot.abs() - 1.0).abs() < 1e-5
    }

    fn any_rotation() -> impl Strategy<Value = [f32; 4]> {
        // A random axis-angle: every rotation, including the half turns.
        (
            -1.0f64..1.0,
            -1.0f64..1.0,
            -1.0f64..1.0,
            0.0f64..std::f64::consts::TAU,
        )
            .prop_filter("an axis", |(x, y, z, _)| x * x + y * y + z * z > 1e-3)
            .prop_map(|(x, y, z, angle)| {
                let axis = nalgebra::Unit::new_normalize(Vector3::new(x, y, z));
                wxyz(&UnitQuaternion::from_axis_angle(&axis, angle))
            })
    }

    fn any_point() -> impl Strategy<Value = [f32; 3]> {
        [-2.0f32..2.0, -2.0f32..2.0, -2.0f32..2.0]
    }

    proptest! {
        /// The converted rotation applied to the converted point is the converted rotated point.
        #[test]
        fn the_converted_rotation_moves_the_converted_point(q in any_rotation(), p in any_point()) {
            let direct = unity_point(rotate(q, p));
            let converted = rotate(unity_rotation_wxyz(q), unity_point(p));
            prop_assert!(close(direct, converted), "{direct:?} vs {converted:?}");
        }

        /// S·R·S with matrices (the definition) gives the converted quaternion's matrix.
        #[test]
        fn the_conversion_is_the_mirror_conjugation(q in any_rotation()) {
            let s = Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0));
            let r = unit(q).to_rotation_matrix();
            let conjugated = UnitQuaternion::from_rotation_matrix(
                &Rotation3::from_matrix_unchecked(s * r.matrix() * s),
            );
            prop_assert!(same_rotation(wxyz(&conjugated), unity_rotation_wxyz(q)));
        }

        /// Chains of local rotations convert factor by factor (parent·local stays parent·local).
        #[test]
        fn products_convert_factor_by_factor(a in any_rotation(), b in any_rotation()) {
            let product = wxyz(&(unit(a) * unit(b)));
            let converted = wxyz(&(unit(unity_rotation_wxyz(a)) * unit(unity_rotation_wxyz(b))));
            prop_assert!(same_rotation(unity_rotation_wxyz(product), converted));
        }
    }

    #[test]
    fn a_left_turn_stays_a_left_turn() {
        // Hand-derived: a quarter turn about up that takes the subject's forward (M's +z) to its
        // left (M's +x). In Unity the same turn takes forward (+z) to the left, −x, which is a
        // quarter turn about y the other way: (cos 45°, 0, −sin 45°, 0).
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let turn_m = [h, 0.0, h, 0.0];
        assert!(close(rotate(turn_m, [0.0, 0.0, 1.0]), [1.0, 0.0, 0.0]));
        let turn_u = unity_rotation_wxyz(turn_m);
        assert_eq!(turn_u, [h, 0.0, -h, 0.0]);
        assert!(close(rotate(turn_u, [0.0, 0.0, 1.0]), [-1.0, 0.0, 0.0]));
        // Raising the left arm (along +x in M) by rolling about forward: it ends up pointing up
        // in both frames.
        let roll_m = [h, 0.0, 0.0, h];
        assert!(close(rotate(roll_m, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]));
        let roll_u = unity_rotation_wxyz(roll_m);
        assert!(close(
            rotate(roll_u, unity_point([1.0, 0.0, 0.0])),
            [0.0, 1.0, 0.0]
        ));
    }

    #[test]
    fn the_subjects_left_is_the_avatars_left() {
        // The subject's left hand in the T-pose is at +x in M; the avatar faces +z in Unity, so
        // its left is −x.
        assert_eq!(unity_point([0.8, 1.4, 0.05]), [-0.8, 1.4, 0.05]);
    }
}
