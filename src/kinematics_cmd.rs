//! `imuflow train`, `imuflow import-checkpoint` and `imuflow average-weights`: the kinematics nets'
//! command lines (the work is in imuflow-train; `imuflow eval` is in `eval_cmd`).

use std::path::PathBuf;

use clap::Args;
use imuflow_kinematics::Method;
use imuflow_train::train::{TrainDevice, TrainOptions, train};

/// Options of `imuflow train`.
#[derive(Args)]
pub struct TrainArgs {
    /// Which networks: pip or globalpose.
    #[arg(long, value_parser = parse_method)]
    method: Method,
    /// The dataset folder (`imuflow dataset build --out`).
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// Where the best weights go (safetensors with metadata).
    #[arg(long, short, value_name = "FILE")]
    out: PathBuf,
    /// Checkpoints and the loss log (loss.csv); a run resumes from here. Keep it outside the repository.
    #[arg(long, value_name = "DIR")]
    checkpoint_dir: PathBuf,
    /// Start from these weights (e.g. models/pip.safetensors) instead of random ones, when the
    /// checkpoint folder is new: training continues in a later session from the committed
    /// weights (Adam starts afresh; pass another --seed for new chunk orders).
    #[arg(long, value_name = "FILE")]
    init_weights: Option<PathBuf>,
    /// LSTM hidden size of every net (PIP's contact net uses a quarter). Papers: PIP 256, GlobalPose 512.
    #[arg(long, default_value_t = 128)]
    hidden: usize,
    /// LSTM layers. Papers: PIP 2, GlobalPose 3.
    #[arg(long, default_value_t = 2)]
    layers: usize,
    /// Epochs (passes over the training chunks).
    #[arg(long, default_value_t = 20)]
    epochs: usize,
    /// Sequence chunks per batch.
    #[arg(long, default_value_t = 32)]
    batch: usize,
    /// Frames per chunk (at least 27, the longest block of the cumulative velocity loss).
    #[arg(long, default_value_t = 162)]
    chunk: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Dropout after the input layer and between LSTM layers while training (articulate uses 0.4 at
    /// the papers' sizes).
    #[arg(long, default_value_t = 0.1)]
    dropout: f32,
    /// Clip the global gradient norm to this.
    #[arg(long, default_value_t = 1.0)]
    clip_norm: f64,
    /// Use about this many training frames: a uniform sample of the sequences of all shards (memory:
    /// about 1.3 KB per frame for pip, 2.3 KB for globalpose)
    #[arg(long, default_value_t = usize::MAX)]
    max_train_frames: usize,
    /// Use at most this many validation frames.
    #[arg(long, default_value_t = 200_000)]
    max_val_frames: usize,
    /// Stop (checkpointed, resumable) after this many minutes of training in total.
    #[arg(long, default_value_t = f64::INFINITY)]
    max_minutes: f64,
    /// Seed of chunking and input noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Don't show progress bars.
    #[arg(long)]
    no_progress: bool,
    /// Where to train: cpu, or cuda / cuda:N for a CUDA GPU (an imuflow built with
    /// `--features cuda`; stages/kinematics/README.md, "Training on a GPU").
    #[arg(long, default_value = "cpu", value_parser = parse_device)]
    device: TrainDevice,
}

fn parse_device(text: &str) -> Result<TrainDevice, String> {
    TrainDevice::parse(text).ok_or_else(|| format!("unknown device '{text}' (cpu, cuda or cuda:N)"))
}

fn parse_method(text: &str) -> Result<Method, String> {
    Method::parse(text).ok_or_else(|| format!("unknown method '{text}' (pip or globalpose)"))
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let options = TrainOptions {
        method: args.method,
        data: args.data,
        out: args.out,
        checkpoint_dir: args.checkpoint_dir,
        init_weights: args.init_weights,
        hidden: args.hidden,
        layers: args.layers,
        epochs: args.epochs,
        batch: args.batch,
        chunk: args.chunk,
        lr: args.lr,
        dropout: args.dropout,
        clip_norm: args.clip_norm,
        max_train_frames: args.max_train_frames,
        max_val_frames: args.max_val_frames,
        max_minutes: args.max_minutes,
        seed: args.seed,
        progress: !args.no_progress,
        device: args.device,
    };
    train(&options)?;
    Ok(())
}

/// Options of `imuflow import-checkpoint`.
#[derive(Args)]
pub struct ImportArgs {
    /// Which networks the checkpoint holds: pip or globalpose.
    #[arg(long, value_parser = parse_method)]
    method: Method,
    /// The authors' PyTorch checkpoint (`torch.save(state_dict)`).
    checkpoint: PathBuf,
    /// The weight file to write.
    #[arg(long, short, value_name = "FILE")]
    out: PathBuf,
}

pub fn import(args: ImportArgs) -> anyhow::Result<()> {
    imuflow_train::import::import_checkpoint(args.method, &args.checkpoint, &args.out)?;
    println!(
        "wrote {} ({} networks from {})",
        args.out.display(),
        args.method.name(),
        args.checkpoint.display()
    );
    Ok(())
}

/// Options of `imuflow average-weights`.
#[derive(Args)]
pub struct AverageArgs {
    /// The weight files (at least two) of one method and architecture, fine-tuned from one start
    /// (e.g. a committed file and runs continued from it with `train --init-weights`).
    #[arg(required = true, num_args = 2.., value_name = "FILE")]
    inputs: Vec<PathBuf>,
    /// The weight file to write.
    #[arg(long, short, value_name = "FILE")]
    out: PathBuf,
}

pub fn average(args: AverageArgs) -> anyhow::Result<()> {
    // The command as run, for the provenance, with files named as the user named them (absolute
    // paths as their names: weight files never carry a machine's folders).
    let name =
        |p: &PathBuf| imuflow_kinematics::weights::without_machine_path(&p.display().to_string());
    let command = std::iter::once("imuflow average-weights".to_owned())
        .chain(args.inputs.iter().map(name))
        .chain(["-o".to_owned(), name(&args.out)])
        .collect::<Vec<_>>()
        .join(" ");
    imuflow_train::average::average_weights(&args.inputs, &args.out, &command)?;
    println!(
        "wrote {} (the mean of {} weight files)",
        args.out.display(),
        args.inputs.len()
    );
    Ok(())
}
