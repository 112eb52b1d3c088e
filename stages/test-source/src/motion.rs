//! The synthetic sensors' motion and the frames it gives (see the crate docs).

use imuflow_body::NUM_IMUS;
use imuflow_graph::frames::ImuFrame;

/// Standard gravity, m/s² (docs/architecture.md: gravity (0, −9.81, 0) in M).
pub const GRAVITY_MPS2: f32 = 9.81;

/// The motion of one synthetic sensor.
#[derive(Debug, Clone, Copy)]
pub struct SensorMotion {
    /// Unit rotation axis.
    pub axis: [f32; 3],
    /// Amplitude, rad.
    pub amplitude_rad: f32,
    /// Frequency, Hz.
    pub frequency_hz: f32,
    /// Phase, rad.
    pub phase_rad: f32,
}

impl SensorMotion {
    /// The motions of the six sensors for a seed (a small LCG keeps this free of dependencies
    /// and stable across versions, which recordings rely on).
    pub fn for_seed(seed: u64) -> [SensorMotion; NUM_IMUS] {
        let mut state = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / ((1u64 << 24) as f32)
        };
        std::array::from_fn(|_| {
            let v = [next() - 0.5, next() - 0.5, next() - 0.5];
            let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
            SensorMotion {
                axis: [v[0] / norm, v[1] / norm, v[2] / norm],
                amplitude_rad: 0.2 + 0.8 * next(),
                frequency_hz: 0.2 + 1.3 * next(),
                phase_rad: std::f32::consts::TAU * next(),
            }
        })
    }

    /// (angle θ, rate θ̇) at time `t_s`.
    pub fn angle_and_rate(&self, t_s: f32) -> (f32, f32) {
        let w = std::f32::consts::TAU * self.frequency_hz;
        let arg = w * t_s + self.phase_rad;
        (
            self.amplitude_rad * arg.sin(),
            self.amplitude_rad * w * arg.cos(),
        )
    }
}

/// Rotates `v` by the inverse of the unit quaternion `q` = [w, x, y, z] (i.e. applies Rᵀ).
pub fn rotate_inverse(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
    let [w, x, y, z] = q;
    let u = [-x, -y, -z];
    // v' = v + 2w(u×v) + 2u×(u×v)
    let c1 = cross(u, v);
    let c2 = cross(u, c1);
    [
        v[0] + 2.0 * (w * c1[0] + c2[0]),
        v[1] + 2.0 * (w * c1[1] + c2[1]),
        v[2] + 2.0 * (w * c1[2] + c2[2]),
    ]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Fills the payload of frame `seq` (at `rate_hz`) for the given motions.
pub fn synthesize(
    frame: &mut ImuFrame,
    motions: &[SensorMotion; NUM_IMUS],
    seq: u64,
    rate_hz: f64,
    invalid_every: u64,
) {
    let t = (seq as f64 / rate_hz) as f32;
    let mut valid = 0u32;
    for (i, m) in motions.iter().enumerate() {
        let (angle, rate) = m.angle_and_rate(t);
        let (s, c) = (0.5 * angle).sin_cos();
        let q = [c, m.axis[0] * s, m.axis[1] * s, m.axis[2] * s];
        frame.orientation_wxyz[i] = q;
        frame.angular_rate_radps[i] = [m.axis[0] * rate, m.axis[1] * rate, m.axis[2] * rate];
        frame.specific_force_mps2[i] = rotate_inverse(q, [0.0, GRAVITY_MPS2, 0.0]);
        valid |= 1 << i;
    }
    if invalid_every > 0 && seq % invalid_every == invalid_every - 1 {
        frame.orientation_wxyz[0] = [f32::NAN; 4];
        frame.specific_force_mps2[0] = [f32::NAN; 3];
        frame.angular_rate_radps[0] = [f32::NAN; 3];
        valid &= !1;
    }
    frame.valid_mask = valid;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
        rotate_inverse([q[0], -q[1], -q[2], -q[3]], v)
    }

    #[test]
    fn quarter_turn_about_y_maps_z_to_x() {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let q = [s, 0.0, s, 0.0]; // 90° about +y
        let v = rotate(q, [0.0, 0.0, 1.0]);
        assert!(
            (v[0] - 1.0).abs() < 1e-6 && v[1].abs() < 1e-6 && v[2].abs() < 1e-6,
            "{v:?}"
        );
        let back = rotate_inverse(q, v);
        assert!((back[2] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn angular_rate_matches_finite_difference_of_orientation() {
        let motions = SensorMotion::for_seed(3);
        let rate = 1000.0;
        let (mut a, mut b) = (ImuFrame::default(), ImuFrame::default());
        synthesize(&mut a, &motions, 500, rate, 0);
        synthesize(&mut b, &motions, 501, rate, 0);
        for i in 0..NUM_IMUS {
            // Relative rotation q_a⁻¹ q_b ≈ [1, ω dt / 2] for small dt (sensor-frame rate).
            let (qa, qb) = (a.orientation_wxyz[i], b.orientation_wxyz[i]);
            let inv = [qa[0], -qa[1], -qa[2], -qa[3]];
            let rel = [
                inv[0] * qb[0] - inv[1] * qb[1] - inv[2] * qb[2] - inv[3] * qb[3],
                inv[0] * qb[1] + inv[1] * qb[0] + inv[2] * qb[3] - inv[3] * qb[2],
                inv[0] * qb[2] - inv[1] * qb[3] + inv[2] * qb[0] + inv[3] * qb[1],
                inv[0] * qb[3] + inv[1] * qb[2] - inv[2] * qb[1] + inv[3] * qb[0],
            ];
            for k in 0..3 {
                let fd = 2.0 * rel[k + 1] * rate as f32;
                let mid = 0.5 * (a.angular_rate_radps[i][k] + b.angular_rate_radps[i][k]);
                assert!(
                    (fd - mid).abs() < 2e-2,
                    "sensor {i} axis {k}: fd {fd} vs {mid}"
                );
            }
        }
    }

    #[test]
    fn specific_force_has_gravity_magnitude_and_points_up_in_world() {
        let motions = SensorMotion::for_seed(9);
        let mut f = ImuFrame::default();
        synthesize(&mut f, &motions, 77, 60.0, 0);
        for i in 0..NUM_IMUS {
            let s = f.specific_force_mps2[i];
            let norm = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            assert!((norm - GRAVITY_MPS2).abs() < 1e-4);
            let world = rotate(f.orientation_wxyz[i], s);
            assert!((world[1] - GRAVITY_MPS2).abs() < 1e-4 && world[0].abs() < 1e-4);
        }
        assert_eq!(f.valid_mask, 0b11_1111);
    }

    #[test]
    fn invalid_every_marks_sensor_zero() {
        let motions = SensorMotion::for_seed(0);
        let mut f = ImuFrame::default();
        synthesize(&mut f, &motions, 4, 60.0, 5);
        assert_eq!(f.valid_mask, 0b11_1110);
        assert!(f.orientation_wxyz[0][0].is_nan());
        synthesize(&mut f, &motions, 5, 60.0, 5);
        assert_eq!(f.valid_mask, 0b11_1111);
    }
}
