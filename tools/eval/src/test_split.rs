//! The dataset's **test** split, sequence by sequence: what `imuflow eval` and `imuflow
//! eval-physics` iterate over (the shards `imuflow dataset build` writes; the trainer never reads
//! this split).

use std::path::Path;

use anyhow::Context;
use imuflow_dataset::Split;
use imuflow_train::data::{Shard, shard_files};
use indicatif::{ProgressBar, ProgressStyle};

/// Which copies of each test clip to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Copies {
    /// The noise-free synthesis.
    Ideal,
    /// With the reference augmentation (mounting error, noise, bias walks, heading drift).
    Augmented,
    All,
}

impl Copies {
    /// Every choice, in the order the command line lists them.
    pub const NAMES: [&str; 3] = ["ideal", "augmented", "all"];

    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Copies::Ideal => "ideal",
            Copies::Augmented => "augmented",
            Copies::All => "all",
        }
    }

    /// Parses one of [`Copies::NAMES`].
    pub fn parse(name: &str) -> Option<Copies> {
        match name {
            "ideal" => Some(Copies::Ideal),
            "augmented" => Some(Copies::Augmented),
            "all" => Some(Copies::All),
            _ => None,
        }
    }
}

/// The progress bar of one pass over the test split (hidden unless `show`).
pub fn sequence_bar(label: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{label} {{bar:30}} {{pos}}/{{len}} sequences [{{elapsed}} < {{eta}}]"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Calls `f(shard, a, b)` for every sequence (frames `a..b` of its shard) of `split` (the test
/// split, the validation split model choices are made on, or the held-out contents) in `data` with the chosen copies and at least `min_frames` frames, at most `limit` of them, advancing
/// `bar`. Returns how many were visited; an error names the shard and the sequence.
pub fn for_each_test_sequence(
    data: &Path,
    split: Split,
    copies: Copies,
    min_frames: usize,
    limit: usize,
    bar: &ProgressBar,
    mut f: impl FnMut(&Shard, usize, usize) -> anyhow::Result<()>,
) -> anyhow::Result<usize> {
    let mut visited = 0;
    anyhow::ensure!(
        split != Split::Train,
        "evaluation reads the test, validation or holdout split, not {split} (the networks trained on it)"
    );
    let files = shard_files(data, split.name())?;
    anyhow::ensure!(
        !files.is_empty(),
        "{}: no {split} shards (is it a dataset folder from `imuflow dataset build`?{})",
        data.display(),
        if split == Split::Holdout {
            " A build from before the held-out contents existed has none: build it again."
        } else {
            ""
        }
    );
    for file in files {
        let bytes = std::fs::read(&file).with_context(|| format!("reading {}", file.display()))?;
        let shard = Shard::parse(&bytes).with_context(|| format!("shard {}", file.display()))?;
        let augmented = sequence_flags(&shard);
        let offsets = shard.offsets();
        bar.inc_length((offsets.len() - 1) as u64);
        for s in 0..offsets.len() - 1 {
            bar.inc(1);
            let keep = match copies {
                Copies::All => true,
                Copies::Ideal => !augmented.get(s).copied().unwrap_or(false),
                Copies::Augmented => augmented.get(s).copied().unwrap_or(true),
            };
            let (a, b) = (offsets[s], offsets[s + 1]);
            if !keep || b - a < min_frames {
                continue;
            }
            f(&shard, a, b).with_context(|| format!("{}: sequence {s}", file.display()))?;
            visited += 1;
            if visited >= limit {
                return Ok(visited);
            }
        }
    }
    Ok(visited)
}

/// Per sequence of a shard: whether it is an augmented copy (from the shard metadata).
fn sequence_flags(shard: &Shard) -> Vec<bool> {
    shard
        .metadata()
        .and_then(|m| m.get("sequences"))
        .and_then(|s| s.as_array())
        .map(|seqs| {
            seqs.iter()
                .map(|s| {
                    s.get("augmented")
                        .and_then(|a| a.as_bool())
                        .unwrap_or(false)
                })
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn visit(split: Split) -> anyhow::Result<usize> {
        let bar = ProgressBar::hidden();
        for_each_test_sequence(
            Path::new("/nonexistent/imuflow-dataset"),
            split,
            Copies::All,
            1,
            usize::MAX,
            &bar,
            |_, _, _| Ok(()),
        )
    }

    #[test]
    fn the_training_split_is_refused_and_the_others_are_looked_for() {
        let refused = visit(Split::Train).unwrap_err().to_string();
        assert!(refused.contains("not train"), "{refused}");
        for split in [Split::Validation, Split::Test, Split::Holdout] {
            let missing = format!("{:#}", visit(split).unwrap_err());
            assert!(
                missing.contains("/nonexistent/imuflow-dataset") && !missing.contains("not "),
                "{split}: {missing}"
            );
        }
    }
}
