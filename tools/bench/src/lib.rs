//! `imuflow bench`: the benchmarks a user runs on their machine (docs/performance.md).
//!
//! - `transport`: per-hop latency and throughput of a chain of stage processes exchanging
//!   MotionFrame-sized frames, through the same launcher and ports real graphs use (its two stage
//!   kinds, `bench-source` and `bench-relay`, are built-in kinds of the binary).
//! - `kinematics`, `physics`, `validation`: one stage's per-frame work in a loop.
//! - `graph`: a whole graph live at sensor rate, then offline.
//! - `live`: glass-to-glass latency with third-party clients at both ends: SlimeVR's tracker
//!   emulator (or raw sensors) in, an independent VMC receiver out ([`live`],
//!   docs/live-latency.md).
//!
//! The binary hands in its registry of stage kinds: this crate links no stage crate's process.

pub mod live;

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::Subcommand;
use imuflow_graph::frames::{FrameHeader, MotionFrame};
use imuflow_graph::launch::{self, LaunchOptions};
use imuflow_graph::spec::Registry;
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::stage::Step;
use imuflow_graph::transform::load_without;
use imuflow_graph::transport::now_ns;
use imuflow_graph::{FrameType, Graph, StageContext};

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Latency per hop (p50/p99) and throughput of a chain of stage processes.
    ///
    /// Two runs: a paced one (frames at --rate-hz, each stage idle between frames, as in a live
    /// graph) for latency and CPU cost, and an unpaced offline one for throughput.
    Transport {
        /// Stages in the chain (one source, the rest relays).
        #[arg(long, default_value_t = 6)]
        stages: usize,
        /// Frames in the paced latency run.
        #[arg(long, default_value_t = 3000)]
        frames: u64,
        /// Rate of the paced latency run, Hz.
        #[arg(long, default_value_t = 200.0)]
        rate_hz: f64,
        /// Frames in the unpaced throughput run.
        #[arg(long, default_value_t = 30000)]
        throughput_frames: u64,
        /// Run every relay as this command instead of the built-in relay (program and arguments,
        /// split at spaces), e.g. "python3 python/examples/relay.py": what a stage in another
        /// language costs per hop.
        #[arg(long, value_name = "COMMAND")]
        relay_exec: Option<String>,
    },
    /// Per-frame time of the physics methods (integrate, pip, globalpose) on a synthetic march in
    /// place (contacts change every step), PIP's QP apart. Build with --release.
    Physics {
        /// Frames (60 Hz).
        #[arg(long, default_value_t = 1200)]
        frames: usize,
    },
    /// Per-frame time of the validation stage's simulation (rapier3d) in both modes, on the true
    /// motion of a recording (default: the bundled sample, calibration prelude and walk). Build
    /// with --release.
    Validation {
        /// Recording whose truth (MotionFrame channel) is tracked.
        #[arg(long, default_value = "models/sample/walk.mcap")]
        input: String,
    },
    /// A whole graph, twice: live for --seconds (sources paced at their sensor rate) for the
    /// end-to-end latency from capture to every sink input and each stage's cost per frame, then
    /// offline over its whole input for frames per second. Recordings go to a temporary folder,
    /// not the graph's paths. Build with --release.
    Graph {
        /// The graph file.
        file: std::path::PathBuf,
        /// Override any graph key, as `imuflow run --set` (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Leave a stage out, as `imuflow run --without` (repeatable).
        #[arg(long, value_name = "STAGE")]
        without: Vec<String>,
        /// Length of the live run, s of input (0: skip it).
        #[arg(long, default_value_t = 20.0)]
        seconds: f64,
        /// Skip the offline run.
        #[arg(long)]
        no_offline: bool,
    },
    /// Per-frame inference time of the kinematics networks, both methods: streaming, one frame at
    /// a time, in this process, on the lean f32 step (--candle: through candle). Set
    /// RAYON_NUM_THREADS=1 (candle's small-op threading costs more than it gains). Build with
    /// --release.
    Kinematics {
        /// PIP weights ("none" to skip).
        #[arg(long, default_value = "models/pip.safetensors")]
        pip: String,
        /// GlobalPose weights ("none" to skip).
        #[arg(long, default_value = "models/globalpose.safetensors")]
        globalpose: String,
        /// Timed frames per method.
        #[arg(long, default_value_t = 3000)]
        frames: usize,
        /// Sleep between frames as a live stage does at this sensor rate, Hz (0: back to back, the
        /// hot loop). The difference between the two is the cost of idling between frames.
        #[arg(long, default_value_t = 0.0)]
        pace_hz: f64,
        /// Step the nets with candle (the training path) instead of the lean f32 step streaming
        /// inference uses: the difference is candle's per-op overhead at batch 1.
        #[arg(long)]
        candle: bool,
    },
    /// Glass-to-glass latency with real clients: SlimeVR's tracker emulator drives the slimevr
    /// source (or raw sensors are synthesized in real time), an independent VMC implementation
    /// (PyPI vmcp) receives the vmc stage's bundles; per bundle its receive time minus the moment
    /// its pose describes, both on the host clock (docs/live-latency.md).
    Live(live::LiveArgs),
}

imuflow_graph::stage_params! {
    /// The benchmark source's parameters.
    pub struct BenchSourceParams {
        /// frames to send
        frames: u64 = 1000, int(1, 1 << 40);
        /// send rate; 0 = as fast as possible
        rate_hz: f64 = 0, float(0.0, 1e6);
        /// wait this long before opening the output (a stage slow to set up)
        setup_delay_ms: u64 = 0, int(0, 60_000);
    }
}

imuflow_graph::stage_params! {
    /// The benchmark relay's parameters.
    pub struct BenchRelayParams {
        /// wait this long after the start before reading (a stage slow to start, e.g. loading a model)
        start_delay_ms: u64 = 0, int(0, 60_000);
    }
}

pub const SOURCE_SPEC: StageSpec = StageSpec {
    kind: "bench-source",
    role: Role::Source,
    summary: "benchmark source: MotionFrames at a fixed rate (or as fast as possible); used by `imuflow bench`",
    inputs: InputsSpec::Fixed(&[]),
    outputs: &[PortSpec {
        name: "out",
        frame: FrameType::Motion,
        required: false,
        doc: "MotionFrames with a counter payload",
    }],
    params: BenchSourceParams::SPECS,
};

pub const RELAY_SPEC: StageSpec = StageSpec {
    kind: "relay",
    role: Role::Transform,
    summary: "copies each MotionFrame from its input to its output; used by `imuflow bench`",
    inputs: InputsSpec::Fixed(&[PortSpec {
        name: "in",
        frame: FrameType::Motion,
        required: true,
        doc: "frames to forward",
    }]),
    outputs: &[PortSpec {
        name: "out",
        frame: FrameType::Motion,
        required: false,
        doc: "the same frames",
    }],
    params: BenchRelayParams::SPECS,
};

pub fn run_source() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let BenchSourceParams {
        frames,
        rate_hz,
        setup_delay_ms,
    } = BenchSourceParams::from_params(ctx.params());
    std::thread::sleep(Duration::from_millis(setup_delay_ms));
    let mut out = ctx.output::<MotionFrame>("out")?;
    if ctx.ready()? {
        let start = Instant::now();
        for seq in 0..frames {
            if ctx.should_stop() {
                break;
            }
            if rate_hz > 0.0 {
                let due = start + Duration::from_secs_f64(seq as f64 / rate_hz);
                imuflow_graph::wait::sleep_until(due);
            }
            let t0 = Instant::now();
            let capture_ns = now_ns();
            out.publish(
                FrameHeader {
                    seq,
                    capture_ns,
                    ..Default::default()
                },
                |f| {
                    f.q[0] = seq as f32;
                },
            )?;
            ctx.record_source_step(
                Step {
                    seq,
                    capture_ns,
                    flags: 0,
                },
                t0.elapsed(),
            );
        }
    }
    ctx.finish(&mut [&mut out])?;
    Ok(())
}

pub fn run_relay() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let input = ctx.input::<MotionFrame>("in")?;
    let mut out = ctx.output::<MotionFrame>("out")?;
    let start_delay =
        Duration::from_millis(BenchRelayParams::from_params(ctx.params()).start_delay_ms);
    if ctx.ready()? {
        std::thread::sleep(start_delay);
        while let Some(step) = ctx.next()? {
            let frame = *ctx.get(&input);
            out.publish(step.header(), |o| *o = frame)?;
        }
    }
    ctx.finish(&mut [&mut out])?;
    Ok(())
}

/// A chain: the source `s0`, then relays `s1`.. (built-in, or `relay_exec` = program and
/// arguments).
fn chain_graph(stages: usize, frames: u64, rate_hz: f64, relay_exec: Option<&[String]>) -> String {
    let mut toml = format!(
        "name = \"bench-transport\"\n[stages.s0]\nkind = \"bench-source\"\nparams = {{ frames = {frames}, rate_hz = {rate_hz:.1} }}\n"
    );
    let quoted = |s: &str| toml::Value::String(s.to_owned()).to_string();
    for i in 1..stages {
        toml += &format!("[stages.s{i}]\ninputs = {{ in = \"s{}.out\" }}\n", i - 1);
        match relay_exec {
            Some([program, args @ ..]) => {
                let args: Vec<String> = args.iter().map(|a| quoted(a)).collect();
                toml += &format!(
                    "exec = {}\nargs = [{}]\noutputs = {{ out = \"MotionFrame\" }}\n",
                    quoted(program),
                    args.join(", ")
                );
            }
            _ => toml += "kind = \"relay\"\n",
        }
    }
    toml
}

/// User + system CPU time of all reaped children so far.
fn children_cpu() -> Duration {
    // SAFETY: getrusage writes into the zeroed struct we pass; no other memory is touched.
    #[allow(unsafe_code)]
    let usage = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage
    };
    let tv = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec as u64) + Duration::from_micros(t.tv_usec as u64)
    };
    tv(usage.ru_utime) + tv(usage.ru_stime)
}

/// One relay of a chain: the hop into it (transport latency) and its own work per frame, µs.
struct Hop {
    latency_p50_us: f64,
    latency_p99_us: f64,
    work_mean_us: f64,
    work_p99_us: f64,
}

struct ChainResult {
    hops: Vec<Hop>,
    wall_s: f64,
    cpu_s: f64,
    frames: u64,
}

fn run_chain(
    stages: usize,
    frames: u64,
    rate_hz: f64,
    relay_exec: Option<&[String]>,
    registry: &Registry,
) -> anyhow::Result<ChainResult> {
    let graph = Graph::from_str_with(
        Path::new("<bench>"),
        &chain_graph(stages, frames, rate_hz, relay_exec),
        &[],
        registry,
    )?;
    let options = LaunchOptions {
        imuflow_exe: std::env::current_exe().context("cannot find the imuflow executable")?,
        progress: false,
        forward_logs: false,
    };
    let cpu_before = children_cpu();
    let report = launch::run(&graph, &options)?;
    let cpu_s = (children_cpu() - cpu_before).as_secs_f64();
    let mut hops = Vec::new();
    for i in 1..stages {
        let Some((_, s)) = report.stages.get(&format!("s{i}")) else {
            bail!("stage s{i} reported no summary");
        };
        if s.frames_in != frames {
            let counts: Vec<String> = (0..stages)
                .filter_map(|k| {
                    report.stages.get(&format!("s{k}")).map(|(_, s)| {
                        format!(
                            "s{k}: in {} out {} dropped {} unmatched {}",
                            s.frames_in, s.frames_out, s.dropped, s.unmatched
                        )
                    })
                })
                .collect();
            bail!(
                "stage s{i} saw {} of {frames} frames ({})",
                s.frames_in,
                counts.join("; ")
            );
        }
        hops.push(Hop {
            latency_p50_us: s.latency_p50_us,
            latency_p99_us: s.latency_p99_us,
            work_mean_us: s.mean_us,
            work_p99_us: s.p99_us,
        });
    }
    Ok(ChainResult {
        hops,
        wall_s: report.wall.as_secs_f64(),
        cpu_s,
        frames,
    })
}

pub fn run(cmd: BenchCommand, registry: &Registry) -> anyhow::Result<()> {
    let (stages, frames, rate_hz, throughput_frames, relay_exec) = match cmd {
        BenchCommand::Transport {
            stages,
            frames,
            rate_hz,
            throughput_frames,
            relay_exec,
        } => (stages, frames, rate_hz, throughput_frames, relay_exec),
        BenchCommand::Kinematics {
            pip,
            globalpose,
            frames,
            pace_hz,
            candle,
        } => return bench_kinematics(&pip, &globalpose, frames, pace_hz, candle),
        BenchCommand::Physics { frames } => return bench_physics(frames),
        BenchCommand::Validation { input } => return bench_validation(Path::new(&input)),
        BenchCommand::Graph {
            file,
            sets,
            without,
            seconds,
            no_offline,
        } => return bench_graph(&file, &sets, &without, seconds, !no_offline, registry),
        BenchCommand::Live(args) => return live::run(args, registry),
    };
    if stages < 2 {
        bail!("--stages must be at least 2 (a source and a relay)");
    }
    let relay_exec: Option<Vec<String>> = relay_exec
        .map(|c| c.split_whitespace().map(str::to_owned).collect())
        .filter(|c: &Vec<String>| !c.is_empty());
    let relay_exec = relay_exec.as_deref();
    println!(
        "transport benchmark: {stages} stage processes, {} hops, MotionFrame = {} bytes, relays: {}",
        stages - 1,
        std::mem::size_of::<MotionFrame>(),
        relay_exec.map_or("built-in (Rust)".to_owned(), |c| c.join(" "))
    );
    let paced = run_chain(stages, frames, rate_hz, relay_exec, registry)?;
    println!(
        "\npaced run: {} frames at {rate_hz} Hz ({:.1} s)",
        paced.frames, paced.wall_s
    );
    println!(
        "{:<8} {:>10} {:>10} {:>14} {:>13}",
        "hop", "p50 µs", "p99 µs", "relay mean µs", "relay p99 µs"
    );
    for (i, hop) in paced.hops.iter().enumerate() {
        println!(
            "{:<8} {:>10.1} {:>10.1} {:>14.1} {:>13.1}",
            format!("s{i}->s{}", i + 1),
            hop.latency_p50_us,
            hop.latency_p99_us,
            hop.work_mean_us,
            hop.work_p99_us
        );
    }
    let mut p50s: Vec<f64> = paced.hops.iter().map(|h| h.latency_p50_us).collect();
    let mut p99s: Vec<f64> = paced.hops.iter().map(|h| h.latency_p99_us).collect();
    p50s.sort_by(f64::total_cmp);
    p99s.sort_by(f64::total_cmp);
    println!(
        "per hop: median of p50 {:.1} µs, worst p50 {:.1} µs, median of p99 {:.1} µs, worst p99 {:.1} µs",
        p50s[p50s.len() / 2],
        p50s[p50s.len() - 1],
        p99s[p99s.len() / 2],
        p99s[p99s.len() - 1]
    );
    println!(
        "CPU: {:.2} s over {:.1} s for {stages} processes = {:.1}% of one core per stage",
        paced.cpu_s,
        paced.wall_s,
        100.0 * paced.cpu_s / paced.wall_s / stages as f64
    );

    let fast = run_chain(stages, throughput_frames, 0.0, relay_exec, registry)?;
    println!(
        "\nthroughput run: {} frames through {} hops in {:.2} s = {:.0} frames/s ({:.1} MB/s per hop)",
        fast.frames,
        stages - 1,
        fast.wall_s,
        fast.frames as f64 / fast.wall_s,
        fast.frames as f64 * std::mem::size_of::<MotionFrame>() as f64 / fast.wall_s / 1e6
    );
    Ok(())
}

fn bench_kinematics(
    pip: &str,
    globalpose: &str,
    frames: usize,
    pace_hz: f64,
    candle: bool,
) -> anyhow::Result<()> {
    use imuflow_kinematics::Method;
    use imuflow_kinematics::infer::Backend;
    use imuflow_kinematics::lean::Kernel;
    let pace = (pace_hz > 0.0).then(|| std::time::Duration::from_secs_f64(1.0 / pace_hz));
    let backend = if candle {
        Backend::Candle
    } else {
        Backend::Lean
    };
    println!(
        "kinematics benchmark: {frames} streaming frames per method (RAYON_NUM_THREADS={}), {}, nets: {}",
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into()),
        match pace {
            Some(_) => format!("paced at {pace_hz} Hz (idle between frames, as live)"),
            None => "back to back".into(),
        },
        match backend {
            Backend::Candle => "candle".to_owned(),
            Backend::Lean => format!("lean ({} kernel)", Kernel::detect().name()),
        }
    );
    println!(
        "{:<11} {:>10} {:>10} {:>10} {:>10} {:>14} {:>14}",
        "method", "mean µs", "p50 µs", "p99 µs", "max µs", "nets p50 µs", "nets p99 µs"
    );
    for (method, path) in [(Method::Pip, pip), (Method::GlobalPose, globalpose)] {
        if path == "none" {
            continue;
        }
        let t = imuflow_kinematics::bench::step_times_us(
            method,
            std::path::Path::new(path),
            frames,
            100,
            pace,
            backend,
        )?;
        let pct = |t: &[f64], p: f64| t[((t.len() - 1) as f64 * p).round() as usize];
        let (t, nets) = (&t.step_us, &t.nets_us);
        println!(
            "{:<11} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>14.1} {:>14.1}",
            method.name(),
            t.iter().sum::<f64>() / t.len() as f64,
            pct(t, 0.5),
            pct(t, 0.99),
            t[t.len() - 1],
            pct(nets, 0.5),
            pct(nets, 0.99),
        );
    }
    Ok(())
}

/// `imuflow bench physics`.
fn bench_physics(frames: usize) -> anyhow::Result<()> {
    use imuflow_optimizer::bench::{run_all, summary};
    println!("physics benchmark: {frames} frames of a march in place per method (60 Hz)");
    println!(
        "{:<11} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "method", "mean µs", "p50 µs", "p99 µs", "max µs", "fallbacks"
    );
    for (name, t) in run_all(frames)? {
        let [mean, p50, p99, max] = summary(&t.step_us);
        println!(
            "{name:<11} {mean:>10.1} {p50:>10.1} {p99:>10.1} {max:>10.1} {:>10}",
            t.fallbacks
        );
        if !t.solver_us.is_empty() {
            let [smean, s50, s99, _] = summary(&t.solver_us);
            let [imean, _, _, _] = summary(&t.iterations);
            println!(
                "{:<11} QP alone: mean {smean:.1} µs, p50 {s50:.1}, p99 {s99:.1}; {imean:.1} interior-point iterations",
                ""
            );
        }
    }
    if cfg!(debug_assertions) {
        println!(
            "(a debug build: physics runs 20-100x slower; use --release for the real numbers)"
        );
    }
    Ok(())
}

/// `imuflow bench validation`: the simulation tracking a recording's true motion, both modes.
fn bench_validation(input: &Path) -> anyhow::Result<()> {
    use imuflow_body::Pose;
    use imuflow_optimizer::bench::summary;
    use imuflow_recording::{Recorded, Recording};
    use imuflow_validation::sim::Joints;
    use imuflow_validation::{FallRule, Mode, SimConfig, SimModel, Validator};

    let recording = Recording::load(input, None, None)?;
    let poses = recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) => Some(m),
            Recorded::Imu(_) => None,
        })
        .enumerate()
        .map(|(i, m)| {
            Pose::from_wire(&m.local_pose_wxyz, &m.root_position_m)
                .with_context(|| format!("{}: truth frame {i}", input.display()))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    if poses.is_empty() {
        bail!(
            "{}: no truth (MotionFrame) channel to track",
            input.display()
        );
    }
    let body = imuflow_body::BodyModel::new(&imuflow_body::BodyParams::builtin()?, 1.75, 70.0)?;
    let model = SimModel::new(&body);
    let defaults = SimConfig::default();
    println!(
        "validation benchmark: {} frames of {} at 60 Hz, {} substeps per frame",
        poses.len(),
        input.display(),
        defaults.substeps
    );
    println!(
        "{:<20} {:>10} {:>10} {:>10} {:>10}  scores",
        "mode, joints", "mean µs", "p50 µs", "p99 µs", "max µs"
    );
    // The default joining first, then the other one for comparison.
    let joinings = [defaults.joints].into_iter().chain(
        [Joints::Impulse, Joints::Multibody]
            .into_iter()
            .filter(|j| *j != defaults.joints),
    );
    for joints in joinings {
        for mode in [Mode::Torques, Mode::Residual] {
            let config = SimConfig {
                mode,
                ..SimConfig::for_joints(joints)
            };
            let mut validator = Validator::new(model.clone(), config, FallRule::default());
            for pose in &poses {
                validator.frame(Some(pose), 1.0 / 60.0);
            }
            // The first frame builds the world; time the steady state.
            let [mean, p50, p99, max] = summary(&validator.stats.step_us[1..]);
            let name = format!(
                "{}, {}",
                Mode::NAMES[mode as usize],
                Joints::NAMES[joints as usize]
            );
            println!(
                "{name:<20} {mean:>10.1} {p50:>10.1} {p99:>10.1} {max:>10.1}  {}",
                validator.stats.summary_line(mode == Mode::Residual)
            );
        }
    }
    // The controller-free support score alone (part of every frame above).
    let mut judge = imuflow_validation::SupportJudge::new(&model);
    let mut support_us = Vec::with_capacity(poses.len());
    for pose in &poses {
        let started = std::time::Instant::now();
        std::hint::black_box(judge.push(Some(pose), 1.0 / 60.0));
        support_us.push(started.elapsed().as_secs_f64() * 1e6);
    }
    let [mean, p50, p99, max] = summary(&support_us[1..]);
    println!(
        "{:<20} {mean:>10.1} {p50:>10.1} {p99:>10.1} {max:>10.1}  (included above)",
        "support"
    );
    if cfg!(debug_assertions) {
        println!("(a debug build: use --release for the real numbers)");
    }
    Ok(())
}

/// `imuflow bench graph`: the graph live (paced sources, `seconds` of input), then offline.
fn bench_graph(
    file: &Path,
    sets: &[String],
    without: &[String],
    seconds: f64,
    offline: bool,
    registry: &Registry,
) -> anyhow::Result<()> {
    let load = |extra: &[String]| -> anyhow::Result<Graph> {
        let all: Vec<String> = sets.iter().chain(extra).cloned().collect();
        load_without(file, &all, without, registry).map_err(|e| anyhow::anyhow!("{e}"))
    };
    let graph = load(&[])?;
    let scratch = tempfile::tempdir().context("temporary folder for the recordings")?;
    // Recordings into the scratch folder, so that a benchmark never overwrites a user's files.
    let mut redirect = Vec::new();
    let mut sources = Vec::new();
    for node in graph.topological_order() {
        let kind = node.kind_label();
        let ext = match kind.as_str() {
            "recorder" => Some("mcap"),
            "rerun-logger" if node.params.contains_key("path") => Some("rrd"),
            _ => None,
        };
        if let Some(ext) = ext {
            let path = scratch.path().join(format!("{}.{ext}", node.id));
            redirect.push(format!("stages.{}.params.path={}", node.id, path.display()));
        }
        if kind == "imu-source" {
            sources.push(node.id.clone());
        }
    }
    let exe = std::env::current_exe().context("finding the imuflow executable")?;
    let options = LaunchOptions {
        imuflow_exe: exe,
        progress: false,
        forward_logs: false,
    };
    println!("graph benchmark: {} ({})", graph.name, file.display());

    if seconds > 0.0 {
        // imuflow-source frames are at 60 Hz (the networks' rate).
        let frames = (seconds * 60.0).round().max(1.0) as u64;
        let mut extra = redirect.clone();
        extra.push("mode=live".into());
        for id in &sources {
            extra.push(format!("stages.{id}.params.realtime=true"));
            extra.push(format!("stages.{id}.params.frames={frames}"));
        }
        let live = load(&extra)?;
        println!(
            "\nlive: sources paced at their sensor rate, {frames} frames ({seconds} s of input)"
        );
        let report = launch::run(&live, &options).map_err(|e| anyhow::anyhow!("{e}"))?;
        println!("{report}");
    }
    if offline {
        let offline = load(&redirect)?;
        println!("\noffline: the whole input as fast as the stages go");
        let report = launch::run(&offline, &options).map_err(|e| anyhow::anyhow!("{e}"))?;
        println!("{report}");
        let frames = sources
            .iter()
            .filter_map(|id| report.stages.get(id))
            .map(|(_, s)| s.frames_in)
            .max()
            .unwrap_or(0);
        let wall = report.wall.as_secs_f64();
        println!(
            "offline: {frames} frames in {wall:.2} s: {:.0} frames/s (start-up before it, not counted: {:.2} s)",
            frames as f64 / wall.max(1e-9),
            report.startup.as_secs_f64()
        );
    }
    Ok(())
}
