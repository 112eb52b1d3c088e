//! `imuflow`: the command line. A thin dispatcher: the work lives in the crates.

mod compare;
mod eval_cmd;
mod export_cmd;
mod kinematics_cmd;
mod registry;

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use imuflow_graph::launch::{self, LaunchOptions, RunError};
use imuflow_graph::{Graph, GraphLoadError};

/// Every stage runs in this binary. The rerun logger spent half its time in glibc's malloc under
/// the SDK's many small allocations (`perf`, offline pip graph); mimalloc serves them faster.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Full-body motion from six IMUs, as a dataflow of stages over shared memory.
///
/// A graph file (configs/*.toml) names the stages and wires their ports; `imuflow run` starts one
/// process per stage and streams frames between them. Swap the graph file to swap the method.
#[derive(Parser)]
#[command(name = "imuflow", version, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a graph: validate it, start one process per stage, stream until the sources end.
    ///
    /// Offline graphs run as fast as the slowest stage allows; live graphs run at sensor rate.
    /// Ctrl-C ends the stream at the sources, so every recorder finalizes its file. Prints a
    /// per-stage summary at the end (frames, drops, processing time and input latency).
    Run {
        #[command(flatten)]
        graph: GraphArgs,
        /// Don't show the progress bar.
        #[arg(long)]
        no_progress: bool,
        /// Don't forward the stages' log lines.
        #[arg(long, short)]
        quiet: bool,
        /// Stream every rerun-logger to a running rerun viewer instead of its file
        /// ("default" = the local viewer, or a URL like rerun+http://127.0.0.1:9876/proxy).
        #[arg(long, value_name = "URL", num_args = 0..=1, default_missing_value = "default")]
        connect: Option<String>,
    },
    /// Run variant graphs on identical input in one run and compare them (A/B).
    ///
    /// The first variant's source (or --input) and every stage the same in all variants are
    /// shared; each variant's own stages run as an isolated branch. Writes the combined graph, one
    /// rerun recording and one mcap with every variant, and a report under --out.
    Compare(compare::CompareArgs),
    /// Inspect graph files.
    #[command(subcommand)]
    Graph(GraphCommand),
    /// Run one stage process (used by `imuflow run`; not for direct use).
    ///
    /// With --list, prints every built-in stage kind with its ports and parameters; with
    /// --layouts, every frame type's byte layout as JSON (what stages in other languages and
    /// readers of recordings build their views from).
    Stage {
        /// The stage kind to run.
        kind: Option<String>,
        /// List the built-in stage kinds.
        #[arg(long)]
        list: bool,
        /// Print every frame layout as JSON (type name, size, fields with offset, scalar type,
        /// shape and meaning).
        #[arg(long)]
        layouts: bool,
    },
    /// Remove shared-memory files left by imuflow processes that died (a crash, kill -9).
    Clean,
    /// Write a recording's motion (a MotionFrame channel) as BVH, glb (glTF 2.0) or AMASS-style npz.
    Export(export_cmd::ExportArgs),
    /// Benchmarks.
    #[command(subcommand)]
    Bench(imuflow_bench::BenchCommand),
    /// Training data: motion files to synthetic-IMU shards.
    #[command(subcommand)]
    Dataset(DatasetCommand),
    /// Train a method's kinematics networks on the dataset shards (CPU, resumable).
    Train(kinematics_cmd::TrainArgs),
    /// Score the kinematics nets on the dataset's test split (SIP, angle, joint position error, jitter).
    Eval(eval_cmd::EvalArgs),
    /// Convert the authors' PyTorch checkpoint (PIP or GlobalPose) to an imuflow weight file.
    ImportCheckpoint(kinematics_cmd::ImportArgs),
    /// Average weight files fine-tuned from one start (element-wise mean, equal weights).
    AverageWeights(kinematics_cmd::AverageArgs),
    /// The body model.
    #[command(subcommand)]
    Body(BodyCommand),
    /// Score the physics methods (integrate, pip, globalpose) on the dataset's test split with the
    /// same kinematics: jitter, foot skating, penetration, translation, standing ground forces.
    EvalPhysics(eval_cmd::EvalPhysicsArgs),
}

#[derive(Subcommand)]
enum BodyCommand {
    /// Write the dynamic body model as URDF (floating root; each spherical joint as three continuous
    /// x/y/z joints with massless links), so other tools (Pinocchio, RBDL, pybullet) load the same
    /// masses and inertias as imuflow's physics.
    ExportUrdf {
        /// Output file.
        #[arg(long, short, value_name = "FILE", default_value = "out/body.urdf")]
        out: PathBuf,
        /// Subject stature, m.
        #[arg(long, default_value_t = 1.75)]
        stature_m: f64,
        /// Subject mass, kg.
        #[arg(long, default_value_t = 70.0)]
        mass_kg: f64,
    },
}

#[derive(Subcommand)]
enum DatasetCommand {
    /// Retarget every .bvh under --bvh-dir (Bandai Namco skeleton, or any with --mapping), resample
    /// to 60 Hz, synthesize the sensor set's IMUs (--sensors, the six by default; ideal plus
    /// augmented copies) and write safetensors shards:
    /// held-out motion contents apart, the rest split 80/10/10 by clip (see
    /// tools/dataset/README.md). Clips that fail are reported and skipped.
    Build {
        /// Directory searched recursively for .bvh files.
        #[arg(long, value_name = "DIR")]
        bvh_dir: PathBuf,
        /// Output directory (shards and split.json of an earlier run there are replaced).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Augmented copies per clip, besides the ideal one.
        #[arg(long, default_value_t = 1)]
        augment_copies: u32,
        /// Base seed of the augmentation.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Use only the first N clips (sorted by path).
        #[arg(long)]
        limit: Option<usize>,
        /// Training clips also enter mirrored left-right (validation, test and holdout stay as
        /// recorded).
        #[arg(long)]
        mirror: bool,
        /// Training clips also enter played at these speeds, comma-separated (e.g. 0.6,1.6: 40 %
        /// slower and 60 % faster).
        #[arg(long, value_delimiter = ',', value_name = "FACTORS")]
        speeds: Vec<f64>,
        /// The other motion augmentations (speeds, recombined, perturbed, standing idle) enter
        /// mirrored for a seeded half of the training clips, so that both sides are seen as often
        /// (without it the recorded side enters once per augmentation, the mirrored one once)
        #[arg(long)]
        mirror_augmentations: bool,
        /// Training clips also enter with the upper body (spine, head, arms) of another training
        /// clip: new combinations of recorded poses (a punch while walking)
        #[arg(long)]
        recombine: bool,
        /// Training clips also enter with smooth random offsets on the spine, neck, head and arms
        /// within joint limits: deeper bows, twists, hands in front of the body or raised, elbows
        /// bent further
        #[arg(long)]
        perturb: bool,
        /// With --perturb: multiply the shoulders' offset ranges and the elbows' flexion range by
        /// this (2: arms swung up to 90° forward and raised or lowered 50°, as in punches,
        /// pointing or arms overhead)
        #[arg(long, default_value_t = 1.0, value_name = "SCALE")]
        perturb_arm_scale: f64,
        /// One training clip in eight also enters as 15 s of standing idle in its first standing
        /// posture: weight shifts from foot to foot (the feet planted, the legs by inverse
        /// kinematics), the upper body moving as with --perturb
        #[arg(long)]
        standing_idle: bool,
        /// The augmented IMU copies of training clips are synthesized on bodies of statures drawn
        /// from this range, m, `LOW,HIGH` (e.g. 1.5,1.95), the mass in proportion to stature²;
        /// ideal copies, validation, test and holdout stay on the 1.75 m subject
        #[arg(long, value_delimiter = ',', value_name = "LOW,HIGH")]
        vary_stature: Option<Vec<f64>>,
        /// Joint mapping TOML of the clips' skeleton (format: libs/motion/mappings/bandai-namco.toml);
        /// default: the built-in Bandai Namco mapping.
        #[arg(long, value_name = "FILE")]
        mapping: Option<PathBuf>,
        /// Split the held-out contents (bow, dance, guide, kick, punch, slash) by the hash like
        /// every other content, so that their training clips are trained on: for the weights that
        /// ship (models/README.md). The test split stays out; the holdout split is then empty.
        /// Without it they all go to the holdout, as the protocol's measured weights need
        #[arg(long)]
        every_content: bool,
        /// Close a shard before it exceeds this many frames (1,524 bytes each with six sensors).
        #[arg(long, default_value_t = imuflow_dataset::DEFAULT_MAX_SHARD_FRAMES)]
        shard_frames: usize,
        /// The sensor set to synthesize: a shipped set (six, lower-body, full-suit) or a set
        /// file (models/sensor-sets.toml shows the form)
        #[arg(long, default_value = "six", value_name = "SET")]
        sensors: String,
        /// Don't show the progress bar.
        #[arg(long)]
        no_progress: bool,
    },
}

#[derive(Subcommand)]
enum GraphCommand {
    /// Validate a graph file and report every problem (file, stage, key).
    Check {
        #[command(flatten)]
        graph: GraphArgs,
    },
    /// Print a graph's wiring: stages in flow order, their inputs, outputs and readers.
    Show {
        #[command(flatten)]
        graph: GraphArgs,
    },
}

/// The graph `imuflow run` runs when given none: the bundled sample.
const DEFAULT_GRAPH: &str = "configs/examples/sample.toml";

#[derive(Args)]
struct GraphArgs {
    /// The graph file. Default: the bundled sample (configs/examples/sample.toml, run from the
    /// repository root).
    #[arg(default_value = DEFAULT_GRAPH)]
    file: PathBuf,
    /// Override any graph key, e.g. --set stages.kin.params.net=globalpose (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Leave a stage out, and every input that reads it, e.g. --without val for a run without
    /// the rapier judge (repeatable).
    #[arg(long, value_name = "STAGE")]
    without: Vec<String>,
}

impl GraphArgs {
    /// The graph, validated, with its sensor set found (a shipped set or a readable set file),
    /// so that a wrong `sensors` is refused before any stage starts.
    fn load(&self) -> Result<Graph, GraphLoadError> {
        let graph = imuflow_graph::transform::load_without(
            &self.file,
            &self.sets,
            &self.without,
            &registry::registry(),
        )?;
        let problems = sensor_set_problems(&graph);
        if !problems.is_empty() {
            return Err(GraphLoadError::Invalid {
                path: self.file.clone(),
                problems,
            });
        }
        Ok(graph)
    }
}

/// `imuflow body export-urdf`.
fn export_urdf(out: &std::path::Path, stature_m: f64, mass_kg: f64) -> anyhow::Result<()> {
    use anyhow::Context;
    let params = imuflow_body::BodyParams::builtin()?;
    let body = imuflow_body::BodyModel::new(&params, stature_m, mass_kg)?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    std::fs::write(out, imuflow_body::urdf::export_urdf(&body))
        .with_context(|| format!("{}: cannot write", out.display()))?;
    println!(
        "{}: {:.1} kg, {:.2} m ({} joints)",
        out.display(),
        body.mass_kg,
        body.stature_m,
        imuflow_body::NUM_JOINTS
    );
    Ok(())
}

/// The graph's sensor sets that do not resolve, and stages whose own set wears a site the
/// graph's set (what its sources deliver) lacks.
fn sensor_set_problems(graph: &imuflow_graph::Graph) -> Vec<imuflow_graph::graph::Problem> {
    use imuflow_graph::graph::Problem;
    let graph_set = match imuflow_body::SensorSet::resolve(&graph.sensors) {
        Ok(set) => set,
        Err(e) => {
            return vec![Problem {
                stage: None,
                key: Some("sensors".to_owned()),
                message: e.to_string(),
            }];
        }
    };
    let mut problems = Vec::new();
    for node in graph.stages.values() {
        let Some(name) = &node.sensors else { continue };
        let message = match imuflow_body::SensorSet::resolve(name) {
            Err(e) => e.to_string(),
            Ok(set) => {
                let missing = set.mask().missing_from(graph_set.mask());
                if missing.is_empty() {
                    continue;
                }
                format!(
                    "its set {set} wears {} that the graph's set {graph_set} lacks; the graph's \
                     sources deliver the graph's set (set the graph's `sensors` to hold both, \
                     for example \"{}+{}\")",
                    missing.names(),
                    graph.sensors,
                    name
                )
            }
        };
        problems.push(Problem {
            stage: Some(node.id.clone()),
            key: Some("sensors".to_owned()),
            message,
        });
    }
    problems
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(matches!(cli.command, Command::Stage { .. }));
    match cli.command {
        Command::Run {
            graph,
            no_progress,
            quiet,
            connect,
        } => run(&graph, !no_progress, !quiet, connect.as_deref()),
        Command::Graph(GraphCommand::Check { graph }) => match graph.load() {
            Ok(g) => {
                for w in &g.warnings {
                    eprintln!("warning: {w}");
                }
                println!("{}: ok ({} stages)", graph.file.display(), g.stages.len());
                ExitCode::SUCCESS
            }
            Err(e) => invalid(e),
        },
        Command::Graph(GraphCommand::Show { graph }) => match graph.load() {
            Ok(g) => {
                print!("{}", g.describe());
                ExitCode::SUCCESS
            }
            Err(e) => invalid(e),
        },
        Command::Stage { list: true, .. } => {
            print!("{}", registry::describe_kinds());
            ExitCode::SUCCESS
        }
        Command::Stage { layouts: true, .. } => {
            let layouts: Vec<_> = imuflow_graph::FrameType::ALL
                .iter()
                .map(|t| t.layout())
                .collect();
            exit_code(serde_json::to_string_pretty(&layouts).map(|text| {
                // A closed pipe (`| head`) ends the output, not in a panic.
                let _ = writeln!(std::io::stdout(), "{text}");
            }))
        }
        Command::Stage {
            kind: Some(kind), ..
        } => match registry::run_stage(&kind) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                tracing::error!("{e:#}");
                ExitCode::FAILURE
            }
        },
        Command::Stage { kind: None, .. } => {
            eprintln!("error: name a stage kind, or use --list");
            ExitCode::from(2)
        }
        Command::Clean => clean(),
        Command::Compare(args) => compare::run(args),
        Command::Export(args) => export_cmd::run(args),
        Command::EvalPhysics(args) => exit_code(eval_cmd::eval_physics(args)),
        Command::Body(BodyCommand::ExportUrdf {
            out,
            stature_m,
            mass_kg,
        }) => exit_code(export_urdf(&out, stature_m, mass_kg)),
        Command::Dataset(cmd) => dataset(cmd),
        Command::ImportCheckpoint(args) => exit_code(kinematics_cmd::import(args)),
        Command::AverageWeights(args) => exit_code(kinematics_cmd::average(args)),
        Command::Eval(args) => exit_code(eval_cmd::eval(args)),
        Command::Train(args) => exit_code(kinematics_cmd::run(args)),
        Command::Bench(cmd) => exit_code(imuflow_bench::run(cmd, &registry::registry())),
    }
}

/// A command's result as the process's exit status: 0, or the error with its causes on stderr and
/// 1. (An invalid graph or command line is 2, an interrupted run 130: those commands say so.)
fn exit_code<E: Into<anyhow::Error>>(result: Result<(), E>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {:#}", e.into());
            ExitCode::FAILURE
        }
    }
}

fn init_logging(stage_process: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("IMUFLOW_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false);
    // Stage processes' lines are prefixed by the launcher with the stage id and time-ordered
    // there; keep them short.
    if stage_process {
        builder.without_time().with_target(false).init();
    } else {
        builder.with_target(false).init();
    }
}

fn invalid(e: GraphLoadError) -> ExitCode {
    eprintln!("error: {e}");
    ExitCode::from(2)
}

fn run(args: &GraphArgs, progress: bool, forward_logs: bool, connect: Option<&str>) -> ExitCode {
    let mut graph = match args.load() {
        Ok(g) => g,
        Err(e) => return invalid(e),
    };
    if let Some(url) = connect {
        let viewers =
            imuflow_graph::transform::connect_viewers(&mut graph, url, &registry::registry());
        if viewers == 0 {
            eprintln!("warning: --connect given but the graph has no rerun-logger stage");
        }
    }
    for w in &graph.warnings {
        eprintln!("warning: {w}");
    }
    let imuflow_exe = match std::env::current_exe() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: cannot find the imuflow executable: {e}");
            return ExitCode::FAILURE;
        }
    };
    let options = LaunchOptions {
        imuflow_exe,
        progress,
        forward_logs,
    };
    match launch::run(&graph, &options) {
        Ok(report) => {
            println!("{report}");
            for branch in &report.failed_branches {
                eprintln!("warning: {branch}");
            }
            if report.interrupted {
                eprintln!("stopped by the user; outputs were finalized");
                ExitCode::from(130)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            if let RunError::StageFailed { .. } = e {
                eprintln!("the other stages were stopped and their outputs finalized");
            }
            ExitCode::FAILURE
        }
    }
}

fn dataset(cmd: DatasetCommand) -> ExitCode {
    let DatasetCommand::Build {
        bvh_dir,
        out,
        augment_copies,
        seed,
        limit,
        mirror,
        speeds,
        mirror_augmentations,
        recombine,
        perturb,
        perturb_arm_scale,
        standing_idle,
        vary_stature,
        mapping,
        every_content,
        shard_frames,
        sensors,
        no_progress,
    } = cmd;
    let mut options = imuflow_dataset::BuildOptions::new(bvh_dir, out);
    options.sensors = match imuflow_body::SensorSet::resolve(&sensors) {
        Ok(set) => set,
        Err(e) => {
            eprintln!("error: --sensors: {e}");
            return ExitCode::FAILURE;
        }
    };
    options.augment_copies = augment_copies;
    options.seed = seed;
    options.limit = limit;
    options.mapping = mapping;
    options.mirror = mirror;
    if let Some(bad) = speeds
        .iter()
        .find(|s| !(s.is_finite() && (0.1..=10.0).contains(*s)))
    {
        eprintln!("error: --speeds: {bad} is not a speed factor between 0.1 and 10");
        return ExitCode::FAILURE;
    }
    options.speeds = speeds;
    options.mirror_augmentations = mirror_augmentations;
    options.recombine = recombine;
    options.perturb = perturb;
    if !(perturb_arm_scale.is_finite() && (0.0..=3.0).contains(&perturb_arm_scale)) {
        eprintln!("error: --perturb-arm-scale: {perturb_arm_scale} is not a scale between 0 and 3");
        return ExitCode::FAILURE;
    }
    options.perturb_arm_scale = perturb_arm_scale;
    options.standing_idle = standing_idle;
    if let Some(range) = vary_stature {
        match range[..] {
            [low, high] if low >= 1.0 && low <= high && high <= 2.5 => {
                options.vary_stature = Some((low, high));
            }
            _ => {
                eprintln!(
                    "error: --vary-stature: {range:?} is not a range LOW,HIGH of statures between 1 and 2.5 m"
                );
                return ExitCode::FAILURE;
            }
        }
    }
    options.max_shard_frames = shard_frames;
    if every_content {
        options.split_rule = imuflow_dataset::SplitRule::EveryContent;
    }
    options.progress = !no_progress;
    match imuflow_dataset::build(&options) {
        Ok(summary) => {
            print!("{}", summary.table());
            println!("wrote {}", options.out_dir.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn clean() -> ExitCode {
    let base = imuflow_graph::transport::base_shm_prefix();
    let removed = launch::remove_stale_runs(&base);
    println!("removed {removed} shared-memory file(s) of imuflow runs that are no longer alive");
    ExitCode::SUCCESS
}
