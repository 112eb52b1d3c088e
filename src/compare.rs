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
use clap::builder::{PossibleValuesParser, TypedValueParser};
use imuflow_dataset::Split;
use imuflow_eval::compare::batch::{self, BatchOptions};
use imuflow_graph::Graph;
use imuflow_graph::combine::{self, AblationVariant, Combined, SensorErrors, SinkPaths, Variant};
use imuflow_graph::launch::{self, LaunchOptions};

use crate::registry;

#[derive(Args)]
pub struct CompareArgs {
    /// Variant graph files (two or more), e.g. configs/pip.toml configs/globalpose.toml, or
    /// ablation files listing variants (configs/ab/physics.toml).
    #[arg(required = true, num_args = 1..)]
    variants: Vec<PathBuf>,
    /// Batch mode: every .bvh clip of a dataset split under DIR (the directory `imuflow dataset
    /// build --bvh-dir` reads, split the same way) through all variants; reports means over clips
    /// and paired differences with 95 % bootstrap intervals. Resumes an interrupted batch in --out.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["input", "print_graph", "overlaid"])]
    data: Option<PathBuf>,
    /// Batch mode: which split of --data (holdout: the motion contents never trained on).
    #[arg(long, default_value = "test", value_parser = ["train", "validation", "test", "holdout"], requires = "data")]
    split: String,
    /// Batch mode: at most N clips, spread evenly over the split's sorted clips.
    #[arg(long, value_name = "N", requires = "data")]
    limit: Option<usize>,
    /// Batch mode: discard the results of an earlier batch in --out instead of resuming it.
    #[arg(long, requires = "data")]
    fresh: bool,
    /// Batch mode: keep every clip's recording (--out/recordings/); deleted once scored otherwise.
    #[arg(long, requires = "data")]
    keep_recordings: bool,
    /// Replace the source: an .mcap recording (replayed) or a .bvh motion (six IMUs synthesized
    /// with the reference sensor errors, a T-pose + walk calibration prelude and the true pose).
    /// Default: the first variant's source (the bundled sample in configs/).
    #[arg(long, value_name = "FILE")]
    input: Option<PathBuf>,
    /// With a .bvh --input or --data: the joint-mapping TOML of the skeleton (default: Bandai Namco).
    #[arg(long, value_name = "FILE")]
    mapping: Option<PathBuf>,
    /// With a .bvh --input or --data: what the synthesized IMUs get wrong besides their random
    /// mounting. `reference`: GlobalPose's model (mounting residual and its walk, noise, bias
    /// walks, heading drift); `none`: exact signals, so the calibration's residual is the only
    /// sensor error (run both on the same clips to see what the sensors cost).
    #[arg(
        long,
        value_name = "ERRORS",
        default_value = "reference",
        value_parser = PossibleValuesParser::new(SensorErrors::NAMES)
            .try_map(|name| SensorErrors::parse(&name).ok_or("not a sensor-error model")),
    )]
    sensor_errors: SensorErrors,
    /// Name of the comparison (the graph's name and its files' stem; default: the ablation
    /// file's name, or "compare").
    #[arg(long)]
    name: Option<String>,
    /// Where the combined graph, recording, report and plots go (default: out/<name>, or
    /// out/<name>-<split> in batch mode).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
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

/// The command line's files as variants: a graph file is one variant (no overrides), an ablation
/// file (configs/ab/) its `[[variant]]`s. Also returns the single ablation file's name, if that is
/// all.
fn variant_sources(files: &[PathBuf]) -> anyhow::Result<(Vec<AblationVariant>, Option<String>)> {
    let mut sources = Vec::new();
    let mut ablation_names = Vec::new();
    for path in files {
        match combine::read_ablation(path)? {
            Some(ablation) => {
                ablation_names.push(ablation.name);
                sources.extend(ablation.variants);
            }
            None => sources.push(AblationVariant {
                name: variant_name(path),
                graph: path.clone(),
                set: Vec::new(),
            }),
        }
    }
    if sources.len() < 2 {
        anyhow::bail!(
            "compare needs two or more variants: graph files, or an ablation file (configs/ab/) that lists them"
        );
    }
    let name = (files.len() == 1).then(|| ablation_names.pop()).flatten();
    Ok((sources, name))
}

fn compare(args: &CompareArgs) -> anyhow::Result<ExitCode> {
    let registry = registry::registry();
    let (sources, ablation_name) = variant_sources(&args.variants)?;
    let mut variants = Vec::new();
    for source in &sources {
        let graph = match Graph::load(&source.graph, &source.set, &registry) {
            Ok(g) => g,
            Err(e) => {
                eprintln!("error: {e}");
                return Ok(ExitCode::from(2));
            }
        };
        let name = unique_name(&source.name, &variants);
        variants.push(Variant { name, graph });
    }
    let name = args
        .name
        .clone()
        .or(ablation_name)
        .unwrap_or_else(|| "compare".to_owned());

    if let Some(data) = &args.data {
        return batch(args, &name, &sources, data, &variants, &registry);
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("out/{name}")));
    if let Some(input) = &args.input {
        combine::replace_source(
            &mut variants[0].graph,
            input,
            args.mapping.as_deref(),
            args.sensor_errors,
        )
        .context("--input")?;
    }
    let stem = out.join(&name);
    let sinks = SinkPaths {
        mcap: stem.with_extension("mcap").display().to_string(),
        rrd: Some(stem.with_extension("rrd").display().to_string()),
        overlaid: args.overlaid,
    };
    let combined = match combine::combine(&name, &variants, &sinks) {
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
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
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
        sinks.rrd.as_deref().unwrap_or_default(),
        sinks.mcap
    );
    if report.interrupted {
        eprintln!("stopped by the user; outputs were finalized");
        return Ok(ExitCode::from(130));
    }
    let written = imuflow_eval::compare::write(
        &name,
        &out,
        Path::new(&sinks.mcap),
        &combined,
        &report,
        graph.rate_hz,
    )
    .context("cannot write the report")?;
    println!("report: {}", written.display());
    Ok(ExitCode::SUCCESS)
}

/// Batch mode: the variants over every clip of a dataset split (imuflow_eval::compare::batch).
fn batch(
    args: &CompareArgs,
    name: &str,
    sources: &[AblationVariant],
    data: &Path,
    variants: &[Variant],
    registry: &imuflow_graph::spec::Registry,
) -> anyhow::Result<ExitCode> {
    let split = Split::ALL
        .into_iter()
        .find(|s| s.name() == args.split)
        .context("--split")?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("out/{name}-{split}")));
    // Refuse incomparable variants before the first clip, as a single comparison does.
    let probe = SinkPaths {
        mcap: String::new(),
        rrd: None,
        overlaid: false,
    };
    if let Err(e) = combine::combine(name, variants, &probe) {
        eprintln!("error: cannot compare: {e}");
        return Ok(ExitCode::from(2));
    }
    // The variants' files identify the comparison: a resumed batch must run the same graphs.
    let mut fingerprint = String::new();
    for source in sources {
        let path = &source.graph;
        let mut text =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        text.extend(source.set.join("\n").bytes());
        fingerprint.push_str(&format!("{:016x}", imuflow_dataset::fnv1a64(&text)));
    }
    if let Some(m) = &args.mapping {
        let text = std::fs::read(m).with_context(|| format!("cannot read {}", m.display()))?;
        fingerprint.push_str(&format!("{:016x}", imuflow_dataset::fnv1a64(&text)));
    }
    // Other signals are other results: a resumed batch must synthesize the same ones.
    if args.sensor_errors != SensorErrors::default() {
        fingerprint.push_str(&format!("-sensor-errors={:?}", args.sensor_errors));
    }
    let options = BatchOptions {
        name: name.to_owned(),
        out: out.clone(),
        data: data.to_owned(),
        split,
        limit: args.limit,
        mapping: args.mapping.clone(),
        sensor_errors: args.sensor_errors,
        imuflow_exe: std::env::current_exe().context("cannot find the imuflow executable")?,
        progress: !args.no_progress,
        keep_recordings: args.keep_recordings,
        fresh: args.fresh,
        fingerprint,
        command: std::env::args()
            .enumerate()
            .map(|(i, a)| if i == 0 { "imuflow".to_owned() } else { a })
            .collect::<Vec<_>>()
            .join(" "),
    };
    let outcome = batch::run(variants, registry, &options)?;
    println!(
        "{} clips scored, {} not scored; report: {}",
        outcome.scored,
        outcome.failed,
        outcome.report.display()
    );
    if outcome.remaining > 0 {
        eprintln!(
            "stopped by the user with {} clips not run; run the same command again to resume",
            outcome.remaining
        );
        return Ok(ExitCode::from(130));
    }
    if outcome.scored == 0 {
        eprintln!(
            "error: no clip could be scored (reasons in {})",
            outcome.report.display()
        );
        return Ok(ExitCode::FAILURE);
    }
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
