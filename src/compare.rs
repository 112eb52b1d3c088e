//! `imuflow compare`: variants on identical input in one run, then their scores side by side.
//!
//! The variant graphs are combined (`imuflow_graph::combine`): the first one's source, and every
//! stage the same in all variants, feed a copy of each variant's own stages; one recorder and one
//! rerun logger take every variant's outputs. The combined graph is written next to the results
//! (`<out>/<name>.toml`) and run like any graph; the report is computed from its recording.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use imuflow_graph::Graph;
use imuflow_graph::combine::{self, Combined, SinkPaths, Variant};
use imuflow_graph::launch::{self, LaunchOptions};

use crate::registry;

#[derive(Args)]
pub struct CompareArgs {
    /// Variant graph files (two or more), e.g. configs/pip.toml configs/globalpose.toml.
    #[arg(required = true, num_args = 2..)]
    variants: Vec<PathBuf>,
    /// Replace the source: an .mcap recording (replayed) or a .bvh motion (six IMUs synthesized
    /// with the reference sensor errors, a T-pose + walk calibration prelude and the true pose).
    /// Default: the first variant's source (the bundled sample in configs/).
    #[arg(long, value_name = "FILE")]
    input: Option<PathBuf>,
    /// With a .bvh --input: the joint-mapping TOML of its skeleton (default: Bandai Namco).
    #[arg(long, value_name = "FILE", requires = "input")]
    mapping: Option<PathBuf>,
    /// Name of the comparison (the graph's name and its files' stem).
    #[arg(long, default_value = "compare")]
    name: String,
    /// Where the combined graph, recording, report and plots go.
    #[arg(long, value_name = "DIR", default_value = "out/compare")]
    out: PathBuf,
    /// Print the combined graph (TOML) and exit without running it.
    #[arg(long)]
    print_graph: bool,
    /// In the rerun recording, draw every variant in one 3D view (default: one view each).
    #[arg(long)]
    overlaid: bool,
    /// Don't show the progress bar.
    #[arg(long)]
    no_progress: bool,
    /// Don't forward the stages' log lines.
    #[arg(long, short)]
    quiet: bool,
}

pub fn run(args: CompareArgs) -> ExitCode {
    match compare(&args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn compare(args: &CompareArgs) -> anyhow::Result<ExitCode> {
    let registry = registry::registry();
    let mut variants = Vec::new();
    for path in &args.variants {
        let graph = match Graph::load(path, &[], &registry) {
            Ok(g) => g,
            Err(e) => {
                eprintln!("error: {e}");
                return Ok(ExitCode::from(2));
            }
        };
        let name = unique_name(&variant_name(path), &variants);
        variants.push(Variant { name, graph });
    }
    if let Some(input) = &args.input {
        replace_source(&mut variants[0].graph, input, args.mapping.as_deref())?;
    }
    let stem = args.out.join(&args.name);
    let sinks = SinkPaths {
        mcap: stem.with_extension("mcap").display().to_string(),
        rrd: stem.with_extension("rrd").display().to_string(),
        overlaid: args.overlaid,
    };
    let combined = match combine::combine(&args.name, &variants, &sinks) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: cannot compare: {e}");
            return Ok(ExitCode::from(2));
        }
    };
    if args.print_graph {
        print!("{}", combined.text);
        return Ok(ExitCode::SUCCESS);
    }
    for note in &combined.notes {
        eprintln!("note: {note}");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let graph_path = stem.with_extension("toml");
    std::fs::write(&graph_path, &combined.text)
        .with_context(|| format!("cannot write {}", graph_path.display()))?;
    let graph = match Graph::from_str_with(&graph_path, &combined.text, &[], &registry) {
        Ok(g) => g,
        Err(e) => {
            // The combination of valid graphs must itself be valid: say so rather than blame the user.
            anyhow::bail!("the combined graph is invalid (a bug in compare): {e}");
        }
    };
    for w in &graph.warnings {
        eprintln!("warning: {w}");
    }
    describe(&combined);
    let options = LaunchOptions {
        imuflow_exe: std::env::current_exe().context("cannot find the imuflow executable")?,
        progress: !args.no_progress,
        forward_logs: !args.quiet,
    };
    let report = match launch::run(&graph, &options) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(ExitCode::FAILURE);
        }
    };
    crate::print_summary(&graph, &report);
    for branch in &report.failed_branches {
        eprintln!("warning: {branch}");
    }
    println!(
        "wrote {} (graph), {} and {}",
        graph_path.display(),
        sinks.rrd,
        sinks.mcap
    );
    if report.interrupted {
        eprintln!("stopped by the user; outputs were finalized");
        return Ok(ExitCode::from(130));
    }
    let written = imuflow_eval::compare::write(
        &args.name,
        &args.out,
        Path::new(&sinks.mcap),
        &combined,
        &report,
        graph.rate_hz,
    )
    .context("cannot write the report")?;
    println!("report: {}", written.display());
    Ok(ExitCode::SUCCESS)
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

/// A variant's name from its file: the stem, reduced to the characters stage ids allow.
fn variant_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '-'
            }
        })
        .collect();
    if name.is_empty() {
        "variant".into()
    } else {
        name
    }
}

/// `name`, or `name-2`, `name-3`, ... when an earlier variant has it (the same file twice).
fn unique_name(name: &str, earlier: &[Variant]) -> String {
    let taken = |n: &str| earlier.iter().any(|v| v.name == n);
    if !taken(name) {
        return name.to_owned();
    }
    (2..)
        .map(|i| format!("{name}-{i}"))
        .find(|n| !taken(n))
        .expect("some suffix is free")
}

/// Points the first variant's source at `input`: an mcap replay, or IMUs synthesized from a BVH.
fn replace_source(graph: &mut Graph, input: &Path, mapping: Option<&Path>) -> anyhow::Result<()> {
    if !input.is_file() {
        anyhow::bail!("--input {}: no such file", input.display());
    }
    let source = graph
        .stages
        .values_mut()
        .find(|n| n.role == imuflow_graph::spec::Role::Source)
        .context("the first variant has no source")?;
    if source.runner
        != (imuflow_graph::graph::Runner::Builtin {
            kind: "imu-source".into(),
        })
    {
        anyhow::bail!(
            "--input replaces an imu-source, but the first variant's source '{}' is {}",
            source.id,
            source.kind_label()
        );
    }
    let path = toml::Value::String(input.display().to_string());
    let extension = input
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let mut params = toml::Table::new();
    match extension.as_str() {
        "mcap" => {
            params.insert("mode".into(), "replay".into());
            params.insert("path".into(), path);
        }
        "bvh" => {
            // What a real session looks like to the calibrations: a T-pose hold and a few steps
            // first, sensors mounted at random, the reference noise, a z-up inertial frame.
            params.insert("mode".into(), "synthesize".into());
            params.insert("path".into(), path);
            params.insert("prelude".into(), "tpose+walk".into());
            params.insert("augment".into(), true.into());
            params.insert("mounting".into(), "random".into());
            params.insert("frame".into(), "z-up".into());
            // The facing the shipped graphs' T-pose calibration assumes (`heading_deg = 30.0`).
            params.insert("frame_heading_deg".into(), 30.0.into());
            if let Some(m) = mapping {
                params.insert("mapping".into(), m.display().to_string().into());
            }
        }
        other => anyhow::bail!(
            "--input {}: expected an .mcap recording or a .bvh motion (got '.{other}')",
            input.display()
        ),
    }
    source.params = params;
    Ok(())
}
