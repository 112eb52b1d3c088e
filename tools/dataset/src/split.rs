//! Deterministic train/validation/test split by clip, from a stable hash of the clip's relative path.

use std::fmt;

use serde::Serialize;

/// FNV-1a offset basis (64 bit).
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
/// FNV-1a prime (64 bit).
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a, 64 bit (Fowler–Noll–Vo): stable across platforms, Rust versions and runs, unlike
/// `std::hash`. `h = 0xcbf29ce484222325; for byte b: h = (h ^ b) * 0x100000001b3 (mod 2^64)`.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(FNV_OFFSET, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(FNV_PRIME)
    })
}

/// One of the three dataset splits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// 80 % of the clips.
    Train,
    /// 10 %.
    Validation,
    /// 10 %; never used for training.
    Test,
}

impl Split {
    /// All splits, in output order.
    pub const ALL: [Split; 3] = [Split::Train, Split::Validation, Split::Test];

    /// The name used in file names and metadata.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Validation => "validation",
            Split::Test => "test",
        }
    }

    /// Index into [`Split::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The clip key that is hashed: its path relative to the input directory, UTF-8 (lossy), with `/`
/// separators on every platform.
pub fn clip_key(relative_path: &std::path::Path) -> String {
    relative_path
        .components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

/// The split of a clip: `fnv1a64(key) % 100` below 80 → train, below 90 → validation, else test.
/// Depends on the key alone, so adding or removing other clips never moves a clip.
pub fn split_of(key: &str) -> Split {
    match fnv1a64(key.as_bytes()) % 100 {
        0..80 => Split::Train,
        80..90 => Split::Validation,
        _ => Split::Test,
    }
}

/// Seed of augmented copy `copy` (1-based) of the clip with hash `clip_hash`: FNV-1a 64 over the
/// 24 bytes `seed.to_le_bytes() ‖ clip_hash.to_le_bytes() ‖ copy.to_le_bytes()`.
pub fn augmentation_seed(seed: u64, clip_hash: u64, copy: u64) -> u64 {
    let mut bytes = [0u8; 24];
    bytes[..8].copy_from_slice(&seed.to_le_bytes());
    bytes[8..16].copy_from_slice(&clip_hash.to_le_bytes());
    bytes[16..].copy_from_slice(&copy.to_le_bytes());
    fnv1a64(&bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a64_matches_the_published_test_vectors() {
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn split_proportions_are_about_80_10_10() {
        let mut counts = [0usize; 3];
        for i in 0..10_000 {
            counts[split_of(&format!("dataset/clip_{i:05}.bvh")).index()] += 1;
        }
        assert!((7_700..8_300).contains(&counts[0]), "{counts:?}");
        assert!((800..1_200).contains(&counts[1]), "{counts:?}");
        assert!((800..1_200).contains(&counts[2]), "{counts:?}");
    }

    #[test]
    fn keys_use_forward_slashes() {
        let p: std::path::PathBuf = ["a", "b", "c.bvh"].iter().collect();
        assert_eq!(clip_key(&p), "a/b/c.bvh");
    }
}
