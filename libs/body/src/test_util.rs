//! Helpers shared by unit tests.

use nalgebra::{Quaternion, Rotation3, UnitQuaternion};

/// Deterministic pseudo-random rotations (xorshift64 → normalized Gaussian-free 4-vectors; not exactly
/// uniform, but covering all of SO(3), which is what the round-trip tests need).
pub(crate) fn random_rotations(n: usize, seed: u64) -> Vec<Rotation3<f64>> {
    let mut rng = XorShift(seed.max(1));
    (0..n)
        .map(|_| {
            let q = Quaternion::new(rng.signed(), rng.signed(), rng.signed(), rng.signed());
            UnitQuaternion::new_normalize(q).to_rotation_matrix()
        })
        .collect()
}

/// Tiny deterministic generator for tests.
pub(crate) struct XorShift(pub u64);

impl XorShift {
    /// Uniform in [-1, 1).
    pub(crate) fn signed(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}
