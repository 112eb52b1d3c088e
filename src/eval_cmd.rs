//! `imuflow eval` and `imuflow eval-physics`: their command lines (the work is in imuflow-eval).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use imuflow_eval::nets::{self, NetsEval};
use imuflow_eval::physics::{self, PhysicsEval};
use imuflow_eval::test_split::Copies;
use imuflow_kinematics::Method;
use imuflow_kinematics::infer::SensorBones;

/// Options of `imuflow eval`.
#[derive(Args)]
pub struct EvalArgs {
    /// The dataset folder (`imuflow dataset build --out`); its test shards are used.
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// PIP weights ("none" to skip).
    #[arg(long, value_name = "FILE", default_value = "models/pip.safetensors")]
    pip: String,
    /// GlobalPose weights ("none" to skip).
    #[arg(
        long,
        value_name = "FILE",
        default_value = "models/globalpose.safetensors"
    )]
    globalpose: String,
    /// Which clips: `test` (the test split: contents the networks trained on, other clips),
    /// `validation` (the same kind of clips, the split model choices are made on) or `holdout`
    /// (motion contents never trained on: bow, dance, guide, kick, punch, slash).
    #[arg(long, default_value = "test", value_parser = ["test", "validation", "holdout"])]
    split: String,
    /// Which copies of each test clip: ideal, augmented (sensor noise and mounting errors) or all.
    #[arg(long, default_value = "augmented", value_parser = Copies::NAMES)]
    copies: String,
    /// Orientation of the bones that carry a sensor: the calibrated measurement (the kinematics
    /// stage's default) or the networks' own estimate (the papers').
    #[arg(long, default_value = "measured", value_parser = ["measured", "network"])]
    sensor_bones: String,
    /// With `--sensor-bones measured`: how far (degrees) a bone may stay from its sensor.
    #[arg(long, default_value_t = imuflow_kinematics::infer::SENSOR_BONE_TOLERANCE_DEG)]
    sensor_bone_tolerance_deg: f64,
    /// Knees and elbows: anatomical joints with their flexion from the networks' joint positions
    /// (the kinematics stage's default), the same with the flexion from the rotations alone
    /// (anatomical-rotations), or the networks' free 3-DoF joints (the papers').
    #[arg(long, default_value = "anatomical", value_parser = imuflow_kinematics::infer::LIMB_JOINTS)]
    limb_joints: String,
    /// Also run the networks on the left–right mirrored stream and average the two estimates
    /// (the kinematics stage's `mirror_ensemble`).
    #[arg(long)]
    mirror_ensemble: bool,
    /// Evaluate at most this many sequences per method.
    #[arg(long, default_value_t = usize::MAX)]
    limit: usize,
    /// Also print, per knee and elbow, the upper bone's direction error, the flexion's error and
    /// bias, and how often the estimate bends it backwards where the truth bends it: which of the
    /// networks' guesses the SIP error (upper legs and arms) is made of.
    #[arg(long)]
    limbs: bool,
    /// Don't show progress bars.
    #[arg(long)]
    no_progress: bool,
}

pub fn eval(args: EvalArgs) -> anyhow::Result<()> {
    let options = NetsEval {
        data: args.data,
        weights: [
            (Method::Pip, &args.pip),
            (Method::GlobalPose, &args.globalpose),
        ]
        .into_iter()
        .filter(|(_, weights)| *weights != "none")
        .map(|(method, weights)| (method, PathBuf::from(weights)))
        .collect(),
        split: match args.split.as_str() {
            "holdout" => imuflow_dataset::Split::Holdout,
            "validation" => imuflow_dataset::Split::Validation,
            _ => imuflow_dataset::Split::Test,
        },
        copies: Copies::parse(&args.copies).unwrap_or(Copies::Augmented),
        sensor_bones: SensorBones::parse(&args.sensor_bones, args.sensor_bone_tolerance_deg)
            .context("--sensor-bone-tolerance-deg must be a finite angle ≥ 0")?,
        limb_joints: imuflow_kinematics::infer::LimbJoints::parse(&args.limb_joints)
            .context("--limb-joints must be anatomical, anatomical-rotations or free")?,
        mirror_ensemble: args.mirror_ensemble,
        limit: args.limit,
        limbs: args.limbs,
        progress: !args.no_progress,
    };
    print!("{}", nets::run(&options)?);
    Ok(())
}

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

pub fn eval_physics(args: EvalPhysicsArgs) -> anyhow::Result<()> {
    let options = PhysicsEval {
        data: args.data,
        net: Method::parse(&args.net).context("unknown net")?,
        weights: args.weights,
        methods: args.methods,
        limit: args.limit,
        validate: args.validate,
        progress: !args.no_progress,
    };
    print!("{}", physics::evaluate(&options)?);
    Ok(())
}
