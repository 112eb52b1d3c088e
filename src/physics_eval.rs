//! `imuflow eval-physics`: the physics methods on the dataset's test split, with the same kinematics
//! weights, scored with the motion metrics the physics is meant to improve.
//!
//! Every test sequence (augmented copies: sensor noise and mounting errors) is streamed through the
//! kinematics nets exactly as `imuflow eval` does (seeded with the true first pose), each frame's
//! estimate goes through the wire form (`KinematicsFrame` → `Reference`, as in a graph), and each
//! method runs on the same references. PIP applies its contact rule to its own previous state, which
//! is what the contact stage computes from the feedback edge in `configs/pip.toml`.
//!
//! Metrics, per method, averaged over frames:
//! - jitter of the world joint positions and of the root (km/s³, reference §6);
//! - foot skating (m/s: horizontal speed of a foot joint within 5 cm of its resting height in two
//!   consecutive frames) and ground penetration (m: depth of the lowest foot joint below its resting
//!   height), both `imuflow_body::metrics` definitions with the foot's clearance as the floor;
//! - translation: cumulative error at 2 m of travel (reference §6 protocol, shorter window because the
//!   test clips are short), m;
//! - ground-reaction force during standing: on frames where the truth stands still (both feet and the
//!   root slower than 0.1 m/s), Σ vertical GRF / body weight; and the share of those frames within 10 %;
//! - solver fallbacks, and the method's own time per frame (µs);
//! - with `--validate`: the validation stage's rapier3d simulation tracks every method's output (and
//!   the truth, the reference floor) per sequence: falls per minute and tracking error with the
//!   root unactuated (`torques`), and the mean residual root force / mg the body needed to follow
//!   (`residual`). Each sequence starts a fresh simulation in the estimate's first pose.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use bytemuck::Zeroable;
use clap::Args;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::metrics::{
    cumulative_translation_error_m, foot_skating_mps, ground_penetration_m, jitter_km_per_s3,
    root_jitter_km_per_s3,
};
use imuflow_body::{JointId, NUM_JOINTS, Pose};
use imuflow_graph::frames::KinematicsFrame;
use imuflow_kinematics::data::{FPS, Shard, pose_of};
use imuflow_kinematics::eval::{Copies, for_each_test_sequence, sequence_bar};
use imuflow_kinematics::infer::Streamer;
use imuflow_kinematics::weights::Weights;
use imuflow_optimizer::globalpose::{GlobalPose, GlobalPoseConfig};
use imuflow_optimizer::integrate::Integrate;
use imuflow_optimizer::pip::{Pip, PipConfig};
use imuflow_optimizer::{Method, MotionEstimate, PhysicsBody, Reference};
use imuflow_validation::{FallRule, Mode, SimConfig, SimModel, Validator};
use nalgebra::Vector3;

/// Options of `imuflow eval-physics`.
#[derive(Args)]
pub struct EvalPhysicsArgs {
    /// The dataset folder (`imuflow dataset build --out`); its test shards are used.
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// Which kinematics networks feed the physics: pip or globalpose.
    #[arg(long, default_value = "globalpose", value_parser = ["pip", "globalpose"])]
    net: String,
    /// Their weights (default: models/<net>.safetensors).
    #[arg(long, value_name = "FILE")]
    weights: Option<PathBuf>,
    /// Methods to compare (comma-separated): integrate, pip, globalpose.
    #[arg(
        long,
        default_value = "integrate,pip,globalpose",
        value_delimiter = ','
    )]
    methods: Vec<String>,
    /// Evaluate at most this many sequences.
    #[arg(long, default_value_t = usize::MAX)]
    limit: usize,
    /// Also track every method's output (and the truth) with the validation stage's simulation.
    #[arg(long)]
    validate: bool,
    /// Don't show the progress bar.
    #[arg(long)]
    no_progress: bool,
}

/// Accumulated scores of one method.
#[derive(Default, Clone, Debug)]
struct Scores {
    frames: usize,
    jitter: f64,
    root_jitter: f64,
    skating: f64,
    penetration: f64,
    translation_sum: f64,
    translation_sequences: usize,
    standing_frames: usize,
    standing_ratio_sum: f64,
    standing_within_10: usize,
    fallbacks: usize,
    seconds: f64,
    /// `--validate`: the simulation's statistics in both modes, summed over sequences.
    validation: Option<ValidationScores>,
}

/// The validation simulation's scores of one method over the split.
#[derive(Default, Clone, Debug)]
struct ValidationScores {
    simulated_s: f64,
    falls: u64,
    frames: u64,
    tracking_sum_m: f64,
    residual_sum: f64,
    skate_sum: f64,
    skate_frames: u64,
}

impl ValidationScores {
    /// Tracks `poses` in both modes and adds the statistics.
    fn add(&mut self, model: &SimModel, poses: &[Pose]) {
        for mode in [Mode::Torques, Mode::Residual] {
            let config = SimConfig {
                mode,
                ..SimConfig::default()
            };
            let mut v = Validator::new(model.clone(), config, FallRule::default());
            for pose in poses {
                v.frame(Some(pose), 1.0 / f64::from(FPS));
            }
            let st = &v.stats;
            match mode {
                Mode::Torques => {
                    self.simulated_s += st.simulated_s;
                    self.falls += st.falls;
                    self.frames += st.frames;
                    self.tracking_sum_m += st.tracking_errors_m.iter().sum::<f64>();
                    self.skate_sum += st.skate_sum_mps;
                    self.skate_frames += st.skate_frames;
                }
                Mode::Residual => self.residual_sum += st.residual_fraction_sum,
            }
        }
    }

    fn columns(&self) -> String {
        let n = self.frames.max(1) as f64;
        format!(
            "{:>10.2} {:>10.1} {:>10.3} {:>11.3}",
            self.falls as f64 / (self.simulated_s / 60.0).max(1e-9),
            100.0 * self.tracking_sum_m / n,
            self.skate_sum / self.skate_frames.max(1) as f64,
            self.residual_sum / n,
        )
    }
}

/// Below this speed (m/s) a foot or the root counts as standing still.
const STANDING_SPEED_MPS: f64 = 0.1;
/// Travel over which the cumulative translation error is measured (m).
const TRANSLATION_WINDOW_M: f64 = 2.0;

/// One method under evaluation with the contacts it needs.
struct Candidate {
    name: String,
    method: Box<dyn Method>,
    scores: Scores,
}

pub fn run(args: EvalPhysicsArgs) -> anyhow::Result<()> {
    check_data(&args.data)?;
    let net = imuflow_kinematics::Method::parse(&args.net).context("unknown net")?;
    let weights_path = args
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("models/{}.safetensors", net.name())));
    let weights = Weights::load(&weights_path, net)
        .with_context(|| format!("loading weights {}", weights_path.display()))?;
    let mut streamer = Streamer::new(weights, Pose::t_pose(Vector3::zeros()))?;
    let physics = PhysicsBody::new(1.75, 70.0)?;
    let mut candidates = Vec::new();
    for name in &args.methods {
        let method: Box<dyn Method> = match name.as_str() {
            "integrate" => Box::new(Integrate::new(physics.clone())),
            "pip" => Box::new(Pip::new(physics.clone(), PipConfig::default())?),
            "globalpose" => Box::new(GlobalPose::new(
                physics.clone(),
                GlobalPoseConfig::default(),
            )?),
            other => anyhow::bail!("unknown method '{other}' (integrate, pip, globalpose)"),
        };
        candidates.push(Candidate {
            name: name.clone(),
            method,
            scores: Scores {
                validation: args.validate.then(ValidationScores::default),
                ..Scores::default()
            },
        });
    }
    let sim_model = SimModel::new(&physics.body);
    let mut truth_validation = args.validate.then(ValidationScores::default);
    let bar = sequence_bar("physics", !args.no_progress);
    let sequences = for_each_test_sequence(
        &args.data,
        Copies::Augmented,
        8,
        args.limit,
        &bar,
        |shard, a, b| {
            evaluate_sequence(
                shard,
                a,
                b,
                &mut streamer,
                &physics,
                &mut candidates,
                &sim_model,
            )?;
            if let Some(v) = &mut truth_validation {
                let truth: Vec<Pose> = (a..b).map(|f| pose_of(shard, f)).collect();
                v.add(&sim_model, &truth);
            }
            Ok(())
        },
    )?;
    bar.finish_and_clear();
    println!(
        "test split of {} (augmented copies), {} kinematics, {sequences} sequences",
        args.data.display(),
        net.name()
    );
    print!("{}", table(&candidates, physics.body.mass_kg));
    if let Some(truth) = &truth_validation {
        println!(
            "\nvalidation (rapier3d simulation tracking each output; torques mode unless noted)\n{:<11} {:>10} {:>10} {:>10} {:>11}",
            "motion", "falls/min", "track cm", "skate m/s", "resid. mg"
        );
        println!("{:<11} {}", "truth", truth.columns());
        for c in &candidates {
            if let Some(v) = &c.scores.validation {
                println!("{:<11} {}", c.name, v.columns());
            }
        }
        println!(
            "track: mean joint distance simulation-estimate; skate: simulated feet in contact; resid.: residual mode's mean root force / body weight"
        );
    }
    Ok(())
}

/// Runs every candidate over frames `a..b` of a shard and adds to its scores.
fn evaluate_sequence(
    shard: &Shard,
    a: usize,
    b: usize,
    streamer: &mut Streamer,
    physics: &PhysicsBody,
    candidates: &mut [Candidate],
    sim_model: &SimModel,
) -> anyhow::Result<()> {
    streamer.set_start(pose_of(shard, a));
    let mut fk = FkData::new();
    let truth: Vec<[Vector3<f64>; NUM_JOINTS]> = (a..b)
        .map(|f| {
            forward_kinematics(&physics.body.skeleton, &pose_of(shard, f), &mut fk);
            fk.joint_in_world_m
        })
        .collect();
    let standing: Vec<bool> = (0..truth.len())
        .map(|t| {
            let u = t.saturating_sub(1).min(truth.len() - 2);
            [JointId::PELVIS, JointId::LEFT_FOOT, JointId::RIGHT_FOOT]
                .iter()
                .all(|j| {
                    (truth[u + 1][j.index()] - truth[u][j.index()]).norm() * f64::from(FPS)
                        < STANDING_SPEED_MPS
                })
        })
        .collect();
    let mut outputs: Vec<Vec<MotionEstimate>> = vec![Vec::with_capacity(b - a); candidates.len()];
    for c in candidates.iter_mut() {
        c.method.reset();
    }
    let mut frame = KinematicsFrame::zeroed();
    for f in a..b {
        let estimate = streamer.step(&shard.imu(f))?;
        imuflow_kinematics::stage::fill(&mut frame, &estimate);
        let reference = Reference::read(&frame).map_err(|e| anyhow::anyhow!("frame {f}: {e}"))?;
        for (c, out) in candidates.iter_mut().zip(outputs.iter_mut()) {
            let mut estimate = MotionEstimate::default();
            let t0 = Instant::now();
            let report = c.method.step(&reference, None, &mut estimate)?;
            c.scores.seconds += t0.elapsed().as_secs_f64();
            c.scores.fallbacks += usize::from(report.fallback);
            out.push(estimate);
        }
    }
    let weight = physics.body.mass_kg * 9.81;
    let foot_floor = physics.geometry.clearance(JointId::LEFT_FOOT);
    for (c, out) in candidates.iter_mut().zip(&outputs) {
        let positions: Vec<[Vector3<f64>; NUM_JOINTS]> = out
            .iter()
            .map(|e| {
                forward_kinematics(&physics.body.skeleton, &e.pose, &mut fk);
                fk.joint_in_world_m
            })
            .collect();
        let roots: Vec<Vector3<f64>> = out.iter().map(|e| e.pose.root_in_world_m).collect();
        let true_roots: Vec<Vector3<f64>> = truth.iter().map(|p| p[0]).collect();
        let n = positions.len() as f64;
        let s = &mut c.scores;
        s.frames += positions.len();
        s.jitter += jitter_km_per_s3(&positions, f64::from(FPS)) * n;
        s.root_jitter += root_jitter_km_per_s3(&roots, f64::from(FPS)) * n;
        s.skating += foot_skating_mps(&positions, f64::from(FPS), foot_floor, 0.05) * n;
        s.penetration += ground_penetration_m(&positions, foot_floor) * n;
        if let Some(e) = cumulative_translation_error_m(&roots, &true_roots, TRANSLATION_WINDOW_M) {
            s.translation_sum += e;
            s.translation_sequences += 1;
        }
        // The first frames settle the state; judge the forces after one second.
        for (t, e) in out.iter().enumerate().skip(60) {
            if standing[t] {
                let total: f64 = e.ground_reaction_force_n.iter().map(|f| f.y).sum();
                let ratio = total / weight;
                s.standing_frames += 1;
                s.standing_ratio_sum += ratio;
                s.standing_within_10 += usize::from((ratio - 1.0).abs() <= 0.1);
            }
        }
        if let Some(v) = &mut s.validation {
            let poses: Vec<Pose> = out.iter().map(|e| e.pose.clone()).collect();
            v.add(sim_model, &poses);
        }
    }
    Ok(())
}

fn table(candidates: &[Candidate], mass_kg: f64) -> String {
    let mut out = format!(
        "{:<11} {:>8} {:>9} {:>9} {:>9} {:>11} {:>9} {:>16} {:>9} {:>9}\n",
        "method",
        "frames",
        "jitter",
        "root jit",
        "skate m/s",
        "penetr. cm",
        "TE@2m cm",
        "standing GRF/mg",
        "fallbacks",
        "µs/frame"
    );
    for c in candidates {
        let s = &c.scores;
        let n = s.frames.max(1) as f64;
        let standing = if s.standing_frames > 0 {
            format!(
                "{:.2} ({:.0}%≤10%)",
                s.standing_ratio_sum / s.standing_frames as f64,
                100.0 * s.standing_within_10 as f64 / s.standing_frames as f64
            )
        } else {
            "-".into()
        };
        let te = if s.translation_sequences > 0 {
            format!(
                "{:.1}",
                100.0 * s.translation_sum / s.translation_sequences as f64
            )
        } else {
            "-".into()
        };
        out.push_str(&format!(
            "{:<11} {:>8} {:>9.3} {:>9.3} {:>9.3} {:>11.2} {:>9} {:>16} {:>9} {:>9.0}\n",
            c.name,
            s.frames,
            s.jitter / n,
            s.root_jitter / n,
            s.skating / n,
            100.0 * s.penetration / n,
            te,
            standing,
            s.fallbacks,
            s.seconds * 1e6 / n,
        ));
    }
    out.push_str(&format!(
        "jitter in km/s³ (world joint positions; root: translation only); body mass {mass_kg} kg\n"
    ));
    out
}

/// Whether a dataset folder exists, for a clear message before loading anything.
fn check_data(dir: &Path) -> anyhow::Result<()> {
    if !dir.is_dir() {
        anyhow::bail!(
            "{}: no dataset here; build one with `imuflow dataset build --bvh-dir <bandai data> --out {}` \
             (../shared/data/bandai-namco-motion/extract.sh unpacks the BVH files)",
            dir.display(),
            dir.display()
        );
    }
    Ok(())
}
