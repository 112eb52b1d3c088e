//! One comparison on one input: the variants combined and run (the combined graph written next to
//! the results as `<out>/<name>.toml`, so what ran can be read and run again), then the report
//! computed from its recording.

use std::path::{Path, PathBuf};

use imuflow_graph::launch::LaunchOptions;
use imuflow_graph::spec::Registry;

use crate::combine::{Combined, SinkPaths, Variant};
use crate::run::{CombinedRun, Input, RunError, run_combined};

/// What to compare and where the results go.
pub struct SingleOptions {
    /// The comparison's name (the combined graph's name and its files' stem).
    pub name: String,
    /// The folder of the combined graph, recording, report and plots.
    pub out: PathBuf,
    /// Replaces the first variant's source; `None` keeps it.
    pub input: Option<Input>,
    /// Every variant in one 3D view of the rerun recording, instead of one view each.
    pub overlaid: bool,
    pub launch: LaunchOptions,
}

impl SingleOptions {
    /// The recording and rerun files of this comparison.
    pub fn sinks(&self) -> SinkPaths {
        let stem = self.out.join(&self.name);
        SinkPaths {
            mcap: stem.with_extension("mcap").display().to_string(),
            rrd: Some(stem.with_extension("rrd").display().to_string()),
            overlaid: self.overlaid,
        }
    }

    /// Where the combined graph is written.
    pub fn graph_path(&self) -> PathBuf {
        self.out.join(&self.name).with_extension("toml")
    }
}

/// How a single comparison ended.
pub enum Outcome {
    /// Ran to its end; the report is at this path.
    Reported(PathBuf),
    /// Stopped by the user; the recordings were finalized, no report was written.
    Interrupted,
}

/// Runs the comparison: prints what runs (shared stages, each variant's branch), the run's
/// summary, the files written, then writes the report.
pub fn run(
    options: &SingleOptions,
    variants: &[Variant],
    registry: &Registry,
) -> Result<Outcome, SingleError> {
    let sinks = options.sinks();
    let graph_path = options.graph_path();
    let run = CombinedRun {
        name: &options.name,
        variants,
        input: options.input.as_ref(),
        sinks: &sinks,
        graph_path: &graph_path,
        registry,
        launch: &options.launch,
    };
    let ran = run_combined(&run, |combined, graph| {
        for note in &combined.notes {
            eprintln!("note: {note}");
        }
        for w in &graph.warnings {
            eprintln!("warning: {w}");
        }
        describe(combined);
    })?;
    println!("{}", ran.report);
    for branch in &ran.report.failed_branches {
        eprintln!("warning: {branch}");
    }
    println!(
        "wrote {} (graph), {} and {}",
        graph_path.display(),
        sinks.rrd.as_deref().unwrap_or_default(),
        sinks.mcap
    );
    if ran.report.interrupted {
        return Ok(Outcome::Interrupted);
    }
    let written = crate::report::write(
        &options.name,
        &options.out,
        Path::new(&sinks.mcap),
        &ran.combined,
        &ran.report,
        ran.graph.rate_hz,
    )
    .map_err(SingleError::Report)?;
    Ok(Outcome::Reported(written))
}

/// Why a single comparison gave no report.
#[derive(Debug, thiserror::Error)]
pub enum SingleError {
    #[error(transparent)]
    Run(#[from] RunError),
    #[error("cannot write the report: {0:#}")]
    Report(anyhow::Error),
}

/// What runs: shared stages and each variant's branch.
fn describe(combined: &Combined) {
    println!("shared by all variants: {}", combined.shared.join(", "));
    for v in &combined.variants {
        println!(
            "{}: {} (motion {}{})",
            v.name,
            v.stages.join(", "),
            v.motion,
            v.validation
                .as_ref()
                .map_or(String::new(), |val| format!(", validation {val}"))
        );
    }
}
