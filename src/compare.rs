//! `imuflow compare`: the command line of tools/compare (imuflow-compare), which does the work:
//! variants on identical input in one run, then their scores side by side (docs/compare.md).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use imuflow_compare::batch::{self, BatchOptions};
use imuflow_compare::clips::{DataSource, Exclusions, Selection};
use imuflow_compare::run::{Input, RunError};
use imuflow_compare::single::{self, Outcome, SingleError, SingleOptions};
use imuflow_compare::{SensorErrors, SinkPaths, Variant, variants};
use imuflow_graph::launch::LaunchOptions;

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
    /// Repeatable: several data sets side by side, each clip labelled by its folder's name, with
    /// means per folder too.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["input", "print_graph", "overlaid"])]
    data: Vec<PathBuf>,
    /// Batch mode: which split of --data (holdout: the motion contents never trained on; all:
    /// every clip, for data that is not the training set's).
    #[arg(long, default_value = "test", value_parser = Selection::NAMES, requires = "data")]
    split: String,
    /// Batch mode: a list of clips to leave out, one per line (its file name or its path under
    /// --data; `#` starts a comment), e.g. clips with no floor to stand on.
    #[arg(long, value_name = "FILE", requires = "data")]
    exclude: Option<PathBuf>,
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
    /// With a .bvh --input or --data: the joint-mapping TOML of the skeleton (default: Bandai Namco;
    /// libs/motion/mappings/ holds the built-in one and others). With several --data: once for all
    /// folders, or once per folder in the order of --data.
    #[arg(long, value_name = "FILE")]
    mapping: Vec<PathBuf>,
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
    /// With --input or --data: set a parameter of the replaced source, after the input's own
    /// (repeatable), e.g. `prelude=stand`, `raw=true`, `raw_noise=1` (see the imu-source's
    /// parameters: `imuflow stage --list`).
    #[arg(long, value_name = "KEY=VALUE", value_parser = imuflow_compare::combine::parse_source_set)]
    source_set: Vec<(String, toml::Value)>,
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

fn compare(args: &CompareArgs) -> anyhow::Result<ExitCode> {
    let registry = registry::registry();
    let (sources, ablation_name) = variants::variant_sources(&args.variants)?;
    let variants = match variants::load(&sources, &registry) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(ExitCode::from(2));
        }
    };
    let name = args
        .name
        .clone()
        .or(ablation_name)
        .unwrap_or_else(|| "compare".to_owned());
    let launch = LaunchOptions {
        imuflow_exe: std::env::current_exe().context("cannot find the imuflow executable")?,
        progress: !args.no_progress,
        forward_logs: !args.quiet,
    };
    if !args.data.is_empty() {
        return batch(args, &name, &sources, &variants, &registry, launch);
    }
    let mapping = match args.mapping.as_slice() {
        [] => None,
        [one] => Some(one.clone()),
        _ => anyhow::bail!("--mapping is given more than once: one --input has one skeleton"),
    };
    let options = SingleOptions {
        out: args
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from(format!("out/{name}"))),
        name,
        input: args.input.as_ref().map(|path| Input {
            path: path.clone(),
            mapping: mapping.clone(),
            sensor_errors: args.sensor_errors,
            source_set: args.source_set.clone(),
        }),
        overlaid: args.overlaid,
        launch,
    };
    if args.print_graph {
        let combined = imuflow_compare::run::combine_variants(
            &options.name,
            &variants,
            options.input.as_ref(),
            &options.sinks(),
        );
        return Ok(match combined {
            Ok(c) => {
                print!("{}", c.text);
                ExitCode::SUCCESS
            }
            Err(e) => run_error(e),
        });
    }
    match single::run(&options, &variants, &registry) {
        Ok(Outcome::Reported(report)) => {
            println!("report: {}", report.display());
            Ok(ExitCode::SUCCESS)
        }
        Ok(Outcome::Interrupted) => {
            eprintln!("stopped by the user; outputs were finalized");
            Ok(ExitCode::from(130))
        }
        Err(SingleError::Run(e)) => Ok(run_error(e)),
        Err(e @ SingleError::Report(_)) => Err(e.into()),
    }
}

/// A comparison that did not run: variants that cannot be compared are the user's to fix (exit 2,
/// as an invalid graph is); anything else is a failure.
fn run_error(e: RunError) -> ExitCode {
    eprintln!("error: {e}");
    match e {
        RunError::Incomparable(_) => ExitCode::from(2),
        _ => ExitCode::FAILURE,
    }
}

/// Batch mode: the variants over every clip of a dataset split (imuflow_compare::batch).
fn batch(
    args: &CompareArgs,
    name: &str,
    sources: &[imuflow_compare::combine::AblationVariant],
    variants: &[Variant],
    registry: &imuflow_graph::spec::Registry,
    launch: LaunchOptions,
) -> anyhow::Result<ExitCode> {
    let split = Selection::parse(&args.split).context("--split")?;
    let data = DataSource::from_args(&args.data, &args.mapping)?;
    let exclusions = match &args.exclude {
        Some(file) => Exclusions::read(file)?,
        None => Exclusions::default(),
    };
    // Refuse incomparable variants before the first clip, as a single comparison does.
    let probe = SinkPaths {
        mcap: String::new(),
        rrd: None,
        overlaid: false,
    };
    if let Err(e) = imuflow_compare::run::combine_variants(name, variants, None, &probe) {
        return Ok(run_error(e));
    }
    let options = BatchOptions {
        name: name.to_owned(),
        out: args
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from(format!("out/{name}-{split}"))),
        sources: data,
        selection: split,
        exclusions,
        limit: args.limit,
        sensor_errors: args.sensor_errors,
        source_set: args.source_set.clone(),
        imuflow_exe: launch.imuflow_exe,
        progress: launch.progress,
        keep_recordings: args.keep_recordings,
        fresh: args.fresh,
        fingerprint: batch::fingerprint(
            sources,
            &args.mapping,
            args.sensor_errors,
            &args.source_set,
        )?,
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
