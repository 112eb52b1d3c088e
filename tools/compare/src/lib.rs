//! imuflow-compare: `imuflow compare`, variants of a capture set-up run on identical input in one
//! graph and scored side by side. A library the CLI calls; see docs/compare.md for the user's view.
//!
//! - [`variants`]: the command line's files (graph files or ablation files) as named variants.
//! - [`combine`]: the variant graphs combined into one A/B graph (shared source and stages, one
//!   isolated branch per variant, one recorder and one rerun logger for all).
//! - [`run`]: [`run::run_combined`], the one path every comparison runs through: the source
//!   replaced by the input, the graphs combined, the combined graph written, validated and launched.
//! - [`single`]: one comparison on one input, then its report.
//! - [`batch`]: every clip of a dataset split through the variants, means over clips and paired
//!   differences with bootstrap intervals, per data set when a batch mixes them.
//! - [`clips`]: which clips a batch runs (`--data` folders and their mappings, `--split`,
//!   `--exclude`, `--limit`).
//! - [`report`], [`plots`]: scores of a finished comparison's recording (report.md, results.json,
//!   the plots).

pub mod batch;
pub mod clips;
pub mod combine;
pub mod plots;
pub mod report;
pub mod run;
pub mod single;
pub mod variants;

pub use combine::{Combined, SensorErrors, SinkPaths, Variant};
