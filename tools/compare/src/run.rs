//! The one path every comparison runs through, a single run and each clip of a batch alike:
//! replace the first variant's source by the input (if any), combine the variants, write the
//! combined graph, validate it, launch it.

use std::path::{Path, PathBuf};

use imuflow_graph::Graph;
use imuflow_graph::launch::{self, LaunchOptions, RunReport};
use imuflow_graph::spec::Registry;

use crate::combine::{self, Combined, SensorErrors, SinkPaths, Variant};

/// The file that replaces the first variant's source.
#[derive(Clone, Debug)]
pub struct Input {
    /// An .mcap recording (replayed) or a .bvh motion (IMUs synthesized).
    pub path: PathBuf,
    /// The BVH skeleton's joint mapping (default: Bandai Namco).
    pub mapping: Option<PathBuf>,
    /// What the synthesized IMUs get wrong besides their mounting.
    pub sensor_errors: SensorErrors,
    /// Source parameters set after the input replaced the source (`--source-set`), in order.
    pub source_set: Vec<(String, toml::Value)>,
}

/// One comparison to run.
pub struct CombinedRun<'a> {
    /// The comparison's name (the combined graph's name).
    pub name: &'a str,
    pub variants: &'a [Variant],
    /// Replaces the first variant's source; `None` keeps it.
    pub input: Option<&'a Input>,
    pub sinks: &'a SinkPaths,
    /// Where the combined graph's text is written (it runs from this file).
    pub graph_path: &'a Path,
    pub registry: &'a Registry,
    pub launch: &'a LaunchOptions,
}

/// Why a comparison did not run, by whose fault: the user's input, variants that cannot be
/// compared, a combined graph that is invalid (a bug in compare), or the run itself.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("--input: {0}")]
    Input(String),
    #[error("cannot compare: {0}")]
    Incomparable(String),
    #[error("the combined graph is invalid (a bug in compare): {0}")]
    InvalidCombination(String),
    #[error("cannot write {path}: {source}")]
    Write {
        path: String,
        source: std::io::Error,
    },
    #[error("{0}")]
    Launch(String),
}

/// A comparison that ran (to its end, or stopped by the user: `report.interrupted`).
pub struct Ran {
    pub combined: Combined,
    pub graph: Graph,
    pub report: RunReport,
}

/// The variants with the input in place of the first one's source, combined; nothing written or
/// run (`--print-graph` shows this).
pub fn combine_variants(
    name: &str,
    variants: &[Variant],
    input: Option<&Input>,
    sinks: &SinkPaths,
) -> Result<Combined, RunError> {
    let mut variants = variants.to_vec();
    if let Some(input) = input {
        combine::replace_source(
            &mut variants[0].graph,
            &input.path,
            input.mapping.as_deref(),
            input.sensor_errors,
            &input.source_set,
        )
        .map_err(|e| RunError::Input(e.to_string()))?;
    }
    combine::combine(name, &variants, sinks).map_err(|e| RunError::Incomparable(e.to_string()))
}

/// Combines, writes, validates and launches one comparison. `announce` sees the combined graph
/// once it is valid and before it starts (the single run prints what runs there).
pub fn run_combined(
    run: &CombinedRun<'_>,
    announce: impl FnOnce(&Combined, &Graph),
) -> Result<Ran, RunError> {
    let combined = combine_variants(run.name, run.variants, run.input, run.sinks)?;
    if let Some(dir) = run
        .graph_path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
    {
        std::fs::create_dir_all(dir).map_err(|source| RunError::Write {
            path: dir.display().to_string(),
            source,
        })?;
    }
    std::fs::write(run.graph_path, &combined.text).map_err(|source| RunError::Write {
        path: run.graph_path.display().to_string(),
        source,
    })?;
    // The combination of valid graphs must itself be valid: say so rather than blame the user.
    let graph = Graph::from_str_with(run.graph_path, &combined.text, &[], run.registry)
        .map_err(|e| RunError::InvalidCombination(e.to_string()))?;
    announce(&combined, &graph);
    let report = launch::run(&graph, run.launch).map_err(|e| RunError::Launch(e.to_string()))?;
    Ok(Ran {
        combined,
        graph,
        report,
    })
}
