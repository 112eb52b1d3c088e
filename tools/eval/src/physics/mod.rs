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
//!   height), both [`crate::metrics`] definitions with the foot's clearance as the floor;
//! - translation: cumulative error at 2 m of travel (reference §6 protocol, shorter window because the
//!   test clips are short), m;
//! - ground-reaction force during standing: on frames where the truth stands still (both feet and the
//!   root slower than 0.1 m/s), Σ vertical GRF / body weight; and the share of those frames within 10 %;
//! - solver fallbacks, and the method's own time per frame (µs);
//! - with `validate`: the validation stage's rapier3d simulation tracks every method's output (and
//!   the truth, the reference floor) per sequence: falls per minute and tracking error with the
//!   root unactuated (`torques`), and the mean residual root force / mg the body needed to follow
//!   (`residual`). Each sequence starts a fresh simulation in the estimate's first pose.
//!
//! [`evaluate`] returns a [`PhysicsReport`]; its `Display` is the text the command prints.

mod report;
mod sequence;
mod totals;

use std::path::{Path, PathBuf};

use anyhow::Context;
use imuflow_body::Pose;
use imuflow_kinematics::infer::Streamer;
use imuflow_kinematics::weights::Weights;
use imuflow_optimizer::globalpose::{GlobalPose, GlobalPoseConfig};
use imuflow_optimizer::integrate::Integrate;
use imuflow_optimizer::pip::{Pip, PipConfig};
use imuflow_optimizer::{Method, PhysicsBody};
use imuflow_train::data::pose_of;
use imuflow_validation::SimModel;
use nalgebra::Vector3;

use crate::test_split::{Copies, for_each_test_sequence, sequence_bar};

pub use totals::{MethodTotals, ValidationTotals};

/// The physics methods `imuflow eval-physics` knows, in its default order.
pub const METHODS: [&str; 3] = ["integrate", "pip", "globalpose"];

/// What `imuflow eval-physics` evaluates.
#[derive(Clone, Debug)]
pub struct PhysicsEval {
    /// The dataset folder (`imuflow dataset build --out`); its test shards are used.
    pub data: PathBuf,
    /// Which kinematics networks feed the physics.
    pub net: imuflow_kinematics::Method,
    /// Their weights (`None`: `models/<net>.safetensors`).
    pub weights: Option<PathBuf>,
    /// Methods to compare, names from [`METHODS`].
    pub methods: Vec<String>,
    /// Evaluate at most this many sequences.
    pub limit: usize,
    /// Also track every method's output (and the truth) with the validation stage's simulation.
    pub validate: bool,
    /// Show the progress bar.
    pub progress: bool,
}

/// Every method's totals over the test split; its `Display` is the command's output.
#[derive(Clone, Debug)]
pub struct PhysicsReport {
    pub data: PathBuf,
    pub net: imuflow_kinematics::Method,
    /// Sequences evaluated.
    pub sequences: usize,
    /// The subject's body mass, kg (GRF ratios are per body weight).
    pub mass_kg: f64,
    /// Per method (in the order asked for): its name and totals.
    pub methods: Vec<(String, MethodTotals)>,
    /// With `validate`: the simulation tracking the true motion, the floor of every score.
    pub truth_validation: Option<ValidationTotals>,
}

/// Below this speed (m/s) a foot or the root counts as standing still.
const STANDING_SPEED_MPS: f64 = 0.1;
/// Travel over which the cumulative translation error is measured (m).
const TRANSLATION_WINDOW_M: f64 = 2.0;

/// One method under evaluation with its running totals.
struct Candidate {
    name: String,
    method: Box<dyn Method>,
    totals: MethodTotals,
}

/// Runs every method of `options` over the test split.
pub fn evaluate(options: &PhysicsEval) -> anyhow::Result<PhysicsReport> {
    check_data(&options.data)?;
    let net = options.net;
    let weights_path = options
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("models/{}.safetensors", net.name())));
    let weights = Weights::load(&weights_path, net)
        .with_context(|| format!("loading weights {}", weights_path.display()))?;
    let mut streamer = Streamer::new(weights, Pose::t_pose(Vector3::zeros()))?;
    let physics = PhysicsBody::new(1.75, 70.0)?;
    let mut candidates = Vec::new();
    for name in &options.methods {
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
            totals: MethodTotals {
                validation: options.validate.then(ValidationTotals::default),
                ..MethodTotals::default()
            },
        });
    }
    let sim_model = SimModel::new(&physics.body);
    let mut truth_validation = options.validate.then(ValidationTotals::default);
    let bar = sequence_bar("physics", options.progress);
    let sequences = for_each_test_sequence(
        &options.data,
        imuflow_dataset::Split::Test,
        Copies::Augmented,
        8,
        options.limit,
        &bar,
        |shard, a, b| {
            sequence::evaluate_sequence(
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
    Ok(PhysicsReport {
        data: options.data.clone(),
        net,
        sequences,
        mass_kg: physics.body.mass_kg,
        methods: candidates.into_iter().map(|c| (c.name, c.totals)).collect(),
        truth_validation,
    })
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
