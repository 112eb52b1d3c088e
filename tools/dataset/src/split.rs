//! Deterministic split by clip: whole motion contents held out (protocol (b)), the rest
//! train/validation/test from a stable hash of the clip's relative path.

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
    /// Every clip of a held-out motion content ([`HELD_OUT_CONTENTS`]), whatever its hash: never
    /// used for training or model selection. How the networks do on motions they never saw.
    Holdout,
}

/// Motion contents kept out of training and model selection (the generalization protocol's set
/// (b)): dataset-1's bow, guide, kick, punch, slash and dance, every style of them. What is left to
/// train on is locomotion (walks, runs, dash), gestures (bye, call, respond, wave, raise) and their
/// styles. The Bandai annotations name no performer, so there is no held-out-performer set.
pub const HELD_OUT_CONTENTS: [&str; 7] = [
    "bow",
    "dance-long",
    "dance-short",
    "guide",
    "kick",
    "punch",
    "slash",
];

/// A clip's motion content from its Bandai file name `<dataset>_<content>_<style>_<nnn>.bvh`
/// (`dataset-1/data/dataset-1_kick_angry_001.bvh` → `kick`); `None` for other names.
pub fn content_of(key: &str) -> Option<&str> {
    let stem = key.rsplit('/').next()?.split('.').next()?;
    let mut parts = stem.split('_');
    let dataset = parts.next()?;
    let content = parts.next()?;
    (dataset.starts_with("dataset-") && parts.next().is_some()).then_some(content)
}

impl Split {
    /// All splits, in output order.
    pub const ALL: [Split; 4] = [Split::Train, Split::Validation, Split::Test, Split::Holdout];

    /// The name used in file names and metadata.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Validation => "validation",
            Split::Test => "test",
            Split::Holdout => "holdout",
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

/// What happens to the held-out contents ([`HELD_OUT_CONTENTS`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SplitRule {
    /// The protocol's rule: every clip of a held-out content goes to the holdout, so that the
    /// holdout number measures motions the networks never saw. For weights that are measured.
    #[default]
    Protocol,
    /// Every content is split by the hash alone, the held-out ones included: their clips with a
    /// training hash are trained on, and the test split (hash 90–99) stays out as always. For
    /// weights that ship: a user's networks should have seen a kick. The holdout split is empty.
    EveryContent,
}

/// The split of a clip under the protocol's rule ([`SplitRule::Protocol`]): a held-out content
/// ([`HELD_OUT_CONTENTS`]) → holdout; else `fnv1a64(key) % 100` below 80 → train, below 90 →
/// validation, else test. Depends on the key alone, so adding or removing other clips never moves
/// a clip.
pub fn split_of(key: &str) -> Split {
    split_under(key, SplitRule::Protocol)
}

/// The split of a clip under `rule`. A clip that is not of a held-out content gets the same split
/// under either rule, so the validation and test splits of the other contents are the same clips.
pub fn split_under(key: &str, rule: SplitRule) -> Split {
    if rule == SplitRule::Protocol
        && content_of(key).is_some_and(|c| HELD_OUT_CONTENTS.contains(&c))
    {
        return Split::Holdout;
    }
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
    fn every_content_splits_the_held_out_contents_by_hash_and_moves_nothing_else() {
        let mut held_out = [0usize; 4];
        for content in HELD_OUT_CONTENTS {
            for i in 0..200 {
                let key = format!("dataset-1/data/dataset-1_{content}_style{i}_001.bvh");
                assert_eq!(split_of(&key), Split::Holdout);
                let split = split_under(&key, SplitRule::EveryContent);
                // The hash alone decides: the split of the same hash without a held-out content.
                let h = fnv1a64(key.as_bytes()) % 100;
                let expected = if h < 80 {
                    Split::Train
                } else if h < 90 {
                    Split::Validation
                } else {
                    Split::Test
                };
                assert_eq!(split, expected, "{key}");
                held_out[split.index()] += 1;
            }
            let walk = format!("dataset-1/data/dataset-1_walk_{content}_001.bvh");
            assert_eq!(split_under(&walk, SplitRule::EveryContent), split_of(&walk));
        }
        assert_eq!(held_out[Split::Holdout.index()], 0);
        // 1,400 clips: each split's share near 80/10/10.
        assert!((1_050..1_190).contains(&held_out[0]), "{held_out:?}");
        assert!(held_out[1] > 90 && held_out[2] > 90, "{held_out:?}");
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
    fn held_out_contents_go_to_the_holdout_split_whatever_their_hash() {
        let key = "dataset-1/data/dataset-1_kick_angry_001.bvh";
        assert_eq!(content_of(key), Some("kick"));
        assert_eq!(split_of(key), Split::Holdout);
        assert_eq!(
            content_of("dataset-2/data/dataset-2_walk-left_normal_003.bvh"),
            Some("walk-left")
        );
        assert_eq!(content_of("my/clip_one.bvh"), None);
        assert_eq!(content_of("dataset-1_kick.bvh"), None);
        // Every other clip keeps the hash rule.
        for i in 0..200 {
            let walk = format!("dataset-1/data/dataset-1_walk_style{i}_001.bvh");
            assert_ne!(split_of(&walk), Split::Holdout, "{walk}");
            let dance = format!("dataset-1/data/dataset-1_dance-short_style{i}_001.bvh");
            assert_eq!(split_of(&dance), Split::Holdout, "{dance}");
        }
    }

    #[test]
    fn keys_use_forward_slashes() {
        let p: std::path::PathBuf = ["a", "b", "c.bvh"].iter().collect();
        assert_eq!(clip_key(&p), "a/b/c.bvh");
    }
}
