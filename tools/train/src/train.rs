//! `imuflow train`: trains one method's nets on the dataset shards, on the CPU, with candle autograd.
//!
//! As in the TransPose/PIP papers, every net is trained on its own, fed ground-truth inputs from the
//! previous stage with Gaussian noise (TransPose paper §4.2: σ = 0.04 on leaf positions, 0.025 on joint
//! positions) so that it tolerates the errors of the net before it at run time. The nets are independent
//! given their inputs, so one optimizer step trains them all on the same batch of sequence chunks
//! (the sum of their losses has each net's own gradient).
//!
//! - Chunks of `chunk` frames cut at a random phase each epoch; nets with a learned initialization get
//!   the chunk's first ground-truth frame as init input (reference §2.0 `RNNWithInit`).
//! - Losses: L2 on positions and rotations; TransPose's cumulative velocity loss (n ∈ {1, 3, 9, 27}) on
//!   velocities; binary cross-entropy on contacts and stationarity.
//! - Adam (lr 1e-3 as the reference's `train()` helper), global gradient-norm clipping.
//! - After every epoch: validation loss per net, a CSV row, a resumable checkpoint (parameters and
//!   Adam moments) in the checkpoint folder, and the best-so-far weights exported to `--out`.
//!
//! Hand-written here rather than candle-nn's `AdamW`: its moments can't be saved, so a run could not
//! resume where it stopped.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use candle_core::{DType, Device, Tensor, Var};
use indicatif::{ProgressBar, ProgressStyle};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::data::{TrainSet, load_split};
use imuflow_kinematics::method::Method;
use imuflow_kinematics::net::{Rnn, RnnSpec, init_parameters};
use imuflow_kinematics::weights::{self, WeightsMetadata};

/// Options of one training run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainOptions {
    pub method: Method,
    pub data: PathBuf,
    pub out: PathBuf,
    pub checkpoint_dir: PathBuf,
    /// Start from these weights instead of random ones (a new checkpoint folder only): training
    /// goes on across sessions whose checkpoints are gone, from the committed weight files.
    pub init_weights: Option<PathBuf>,
    pub hidden: usize,
    pub layers: usize,
    pub epochs: usize,
    pub batch: usize,
    pub chunk: usize,
    pub lr: f64,
    pub dropout: f32,
    pub clip_norm: f64,
    pub max_train_frames: usize,
    pub max_val_frames: usize,
    pub max_minutes: f64,
    pub seed: u64,
    pub progress: bool,
    /// Where the nets train: the CPU (default) or a CUDA GPU (a build with the `cuda` feature).
    #[serde(default)]
    pub device: TrainDevice,
}

/// The device a training run computes on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TrainDevice {
    #[default]
    Cpu,
    /// CUDA GPU number N (`cuda` or `cuda:N`).
    Cuda(usize),
}

impl TrainDevice {
    /// `cpu`, `cuda` or `cuda:N`.
    pub fn parse(text: &str) -> Option<TrainDevice> {
        match text {
            "cpu" => Some(TrainDevice::Cpu),
            "cuda" => Some(TrainDevice::Cuda(0)),
            _ => text
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .map(TrainDevice::Cuda),
        }
    }

    /// Opens the device; a CUDA device in a build without the `cuda` feature, or on a machine
    /// without a usable GPU, is an error that says which.
    pub fn open(self) -> anyhow::Result<Device> {
        match self {
            TrainDevice::Cpu => Ok(Device::Cpu),
            TrainDevice::Cuda(n) => {
                if !candle_core::utils::cuda_is_available() {
                    bail!(
                        "--device cuda:{n}: this imuflow was built without CUDA; build it with `cargo build --release --features cuda` (needs the CUDA toolkit, nvcc on the PATH)"
                    );
                }
                Device::new_cuda(n).with_context(|| {
                    format!("--device cuda:{n}: no usable CUDA GPU number {n} on this machine")
                })
            }
        }
    }
}

impl std::fmt::Display for TrainDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TrainDevice::Cpu => write!(f, "CPU"),
            TrainDevice::Cuda(n) => write!(f, "CUDA GPU {n}"),
        }
    }
}

/// How a net's loss is computed.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Loss {
    Mse,
    /// TransPose's cumulative loss (paper Eq. 5, used there for the root velocity) plus plain L2.
    CumulativeVelocity,
    Bce,
    /// GlobalPose OV: the first 4 outputs are velocities (cumulative loss), the last 5 stationary
    /// logits (BCE).
    VelocityAndStationary,
}

/// What one net reads and predicts during training.
struct Task {
    net: &'static str,
    /// Arrays concatenated as input, each with its Gaussian input noise σ.
    inputs: &'static [(&'static str, f32)],
    target: &'static str,
    init: Option<&'static str>,
    loss: Loss,
}

fn tasks(method: Method) -> &'static [Task] {
    match method {
        Method::Pip => &[
            Task {
                net: "rnn1",
                inputs: &[("imu", 0.0)],
                target: "leaf",
                init: Some("leaf"),
                loss: Loss::Mse,
            },
            Task {
                net: "rnn2",
                inputs: &[("leaf", 0.04), ("imu", 0.0)],
                target: "full",
                init: None,
                loss: Loss::Mse,
            },
            Task {
                net: "rnn3",
                inputs: &[("full", 0.025), ("imu", 0.0)],
                target: "r6d",
                init: None,
                loss: Loss::Mse,
            },
            // PIP initializes rnn4 from zeros(72) (reference §2.2); chunks start mid-motion here, so the
            // init input is the chunk's true first-frame velocity (zeros for a subject at rest, which is
            // what the stage feeds).
            Task {
                net: "rnn4",
                inputs: &[("full", 0.025), ("imu", 0.0)],
                target: "vel",
                init: Some("vel"),
                loss: Loss::CumulativeVelocity,
            },
            Task {
                net: "rnn5",
                inputs: &[("full", 0.025), ("imu", 0.0)],
                target: "contact",
                init: None,
                loss: Loss::Bce,
            },
        ],
        Method::GlobalPose => &[
            Task {
                net: "plnet",
                inputs: &[("gp_imu", 0.0)],
                target: "pl",
                init: Some("pl"),
                loss: Loss::Mse,
            },
            Task {
                net: "iknet.net1",
                inputs: &[("rrb_true", 0.0), ("grav", 0.02), ("prb", 0.04)],
                target: "ik1",
                init: None,
                loss: Loss::Mse,
            },
            Task {
                net: "iknet.net2",
                inputs: &[("rrb_true", 0.0), ("grav", 0.02), ("full", 0.025)],
                target: "r6d",
                init: None,
                loss: Loss::Mse,
            },
            Task {
                net: "vrnet",
                inputs: &[
                    ("rrj", 0.0),
                    ("full", 0.025),
                    ("arb_true", 0.0),
                    ("wrb_true", 0.0),
                    ("grav", 0.02),
                ],
                target: "vr",
                init: Some("vr"),
                loss: Loss::VelocityAndStationary,
            },
        ],
    }
}

/// Parameters and Adam moments.
struct Optimizer {
    names: Vec<String>,
    /// Index of the net each parameter belongs to (gradient clipping is per net).
    group: Vec<usize>,
    vars: Vec<Var>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    step: usize,
}

impl Optimizer {
    const BETA1: f64 = 0.9;
    const BETA2: f64 = 0.999;
    const EPS: f64 = 1e-8;

    fn new(params: Vec<(String, Var)>, specs: &[RnnSpec]) -> candle_core::Result<Optimizer> {
        let (names, vars): (Vec<String>, Vec<_>) = params.into_iter().unzip();
        let group = names
            .iter()
            .map(|n| {
                specs
                    .iter()
                    .position(|s| n.starts_with(&format!("{}.", s.name)))
                    .unwrap_or(0)
            })
            .collect();
        let zeros = |v: &Var| v.as_tensor().zeros_like();
        Ok(Optimizer {
            group,
            m: vars.iter().map(zeros).collect::<Result<_, _>>()?,
            v: vars.iter().map(zeros).collect::<Result<_, _>>()?,
            names,
            vars,
            step: 0,
        })
    }

    fn tensors(&self) -> HashMap<String, Tensor> {
        self.names
            .iter()
            .zip(&self.vars)
            .map(|(n, v)| (n.clone(), v.as_tensor().clone()))
            .collect()
    }

    /// One Adam step, each net's gradients clipped to a norm of `clip` on their own (the nets are
    /// independent; one global norm would let the net with the largest loss, e.g. the cumulative
    /// velocity loss, throttle the others). A net whose gradient is not finite is left as it is
    /// for this step: one NaN would otherwise pass the clipping (`NaN > clip` is false) and turn
    /// every weight of that net into NaN for the rest of the run, as a GlobalPose run's velocity
    /// net did in its third epoch. Returns, per net, whether it was skipped.
    fn step(
        &mut self,
        grads: &candle_core::backprop::GradStore,
        lr: f64,
        clip: f64,
    ) -> candle_core::Result<Vec<bool>> {
        let gs: Vec<Option<Tensor>> = self.vars.iter().map(|v| grads.get(v).cloned()).collect();
        let groups = 1 + self.group.iter().copied().max().unwrap_or(0);
        let mut sq = vec![0.0f64; groups];
        for (i, g) in gs.iter().enumerate() {
            if let Some(g) = g {
                sq[self.group[i]] += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
            }
        }
        let skipped: Vec<bool> = sq.iter().map(|s| !s.is_finite()).collect();
        self.step += 1;
        let t = self.step as i32;
        let bc1 = 1.0 - Self::BETA1.powi(t);
        let bc2 = 1.0 - Self::BETA2.powi(t);
        for (i, g) in gs.into_iter().enumerate() {
            let Some(g) = g else { continue };
            if skipped[self.group[i]] {
                continue;
            }
            let norm = sq[self.group[i]].sqrt();
            let scale = if norm > clip { clip / norm } else { 1.0 };
            let g = (g * scale)?;
            self.m[i] = ((&self.m[i] * Self::BETA1)? + (&g * (1.0 - Self::BETA1))?)?;
            self.v[i] = ((&self.v[i] * Self::BETA2)? + (g.sqr()? * (1.0 - Self::BETA2))?)?;
            let denom = ((&self.v[i] / bc2)?.sqrt()? + Self::EPS)?;
            let update = ((&self.m[i] / bc1)? / denom)?;
            let next = (self.vars[i].as_tensor() - (update * lr)?)?;
            self.vars[i].set(&next)?;
        }
        Ok(skipped)
    }
}

/// Resumable state next to the checkpoint tensors.
#[derive(Serialize, Deserialize)]
struct CheckpointState {
    epoch: usize,
    step: usize,
    best_val: f64,
    best_epoch: usize,
    elapsed_s: f64,
    specs: Vec<RnnSpec>,
    /// `--init-weights`: the file this run started from and its provenance (its own training).
    #[serde(default)]
    initialized_from: Option<serde_json::Value>,
}

/// One batch: per task its input, init and target tensors.
struct Batch {
    inputs: Vec<Tensor>,
    inits: Vec<Option<Tensor>>,
    targets: Vec<Tensor>,
}

fn make_batch(
    set: &TrainSet,
    tasks: &[Task],
    starts: &[usize],
    chunk: usize,
    noise: Option<&mut StdRng>,
    device: &Device,
) -> anyhow::Result<Batch> {
    let b = starts.len();
    let mut rng = noise;
    let mut batch = Batch {
        inputs: Vec::new(),
        inits: Vec::new(),
        targets: Vec::new(),
    };
    for task in tasks {
        let arrays: Vec<(&crate::data::Array, f32)> = task
            .inputs
            .iter()
            .map(|(n, s)| Ok((set.array(n)?, *s)))
            .collect::<anyhow::Result<_>>()?;
        let width: usize = arrays.iter().map(|(a, _)| a.dim).sum();
        let mut x = Vec::with_capacity(b * chunk * width);
        for &s in starts {
            for f in s..s + chunk {
                for (a, sigma) in &arrays {
                    let row = a.row(f);
                    match rng.as_deref_mut() {
                        Some(r) if *sigma > 0.0 => {
                            let n = Normal::new(0.0f32, *sigma)?;
                            x.extend(row.iter().map(|v| v + n.sample(r)));
                        }
                        _ => x.extend_from_slice(row),
                    }
                }
            }
        }
        batch
            .inputs
            .push(Tensor::from_vec(x, (b, chunk, width), device)?);
        let target = set.array(task.target)?;
        let mut y = Vec::with_capacity(b * chunk * target.dim);
        for &s in starts {
            y.extend_from_slice(&target.data[s * target.dim..(s + chunk) * target.dim]);
        }
        batch
            .targets
            .push(Tensor::from_vec(y, (b, chunk, target.dim), device)?);
        batch.inits.push(match task.init {
            Some(name) => {
                let a = set.array(name)?;
                let v: Vec<f32> = starts.iter().flat_map(|&s| a.row(s).to_vec()).collect();
                Some(Tensor::from_vec(v, (b, a.dim), device)?)
            }
            None => None,
        });
    }
    Ok(batch)
}

/// TransPose's cumulative loss: Σ_n mean over n-frame blocks of ‖Σ_block (ŷ − y)‖², n ∈ {1, 3, 9, 27}
/// (blocks that don't fit the chunk are dropped).
fn cumulative_loss(err: &Tensor) -> candle_core::Result<Tensor> {
    let (b, t, d) = err.dims3()?;
    let mut total = err.sqr()?.mean_all()?;
    for n in [3usize, 9, 27] {
        let blocks = t / n;
        if blocks == 0 {
            continue;
        }
        let e = err
            .narrow(1, 0, blocks * n)?
            .reshape((b, blocks, n, d))?
            .sum(2)?;
        total = (total + e.sqr()?.mean_all()?)?;
    }
    Ok(total)
}

/// Mean binary cross-entropy of `target` probabilities against `logits`, in the stable form
/// `max(x, 0) − x·t + ln(1 + e^(−|x|))`. candle's `binary_cross_entropy_with_logit` takes the
/// log of the sigmoid: once a logit passes about 17 the f32 sigmoid is exactly 1, `ln(1 − 1)` is
/// −∞ and the step's loss and gradient are NaN. Measured on GlobalPose's vrnet (stationary
/// probabilities), continued on the perturbed data: 9, 13, 19, 32, 68 and 119 of ~513 steps per
/// epoch were skipped as the net grew confident.
pub fn bce_with_logits(logits: &Tensor, target: &Tensor) -> candle_core::Result<Tensor> {
    let softplus_of_minus_abs = (logits.abs()?.neg()?.exp()? + 1.0)?.log()?;
    (logits.relu()? - (logits * target)?)?
        .add(&softplus_of_minus_abs)?
        .mean_all()
}

fn task_loss(loss: Loss, y: &Tensor, target: &Tensor) -> candle_core::Result<Tensor> {
    match loss {
        Loss::Mse => (y - target)?.sqr()?.mean_all(),
        Loss::CumulativeVelocity => cumulative_loss(&(y - target)?),
        Loss::Bce => bce_with_logits(&y.flatten_all()?, &target.flatten_all()?),
        Loss::VelocityAndStationary => {
            let vel = cumulative_loss(&(y.narrow(2, 0, 4)? - target.narrow(2, 0, 4)?)?)?;
            let st = bce_with_logits(
                &y.narrow(2, 4, 5)?.flatten_all()?,
                &target.narrow(2, 4, 5)?.flatten_all()?,
            )?;
            vel + st
        }
    }
}

/// Losses of every task on one batch (and the nets' outputs are discarded).
fn batch_losses(
    nets: &[Rnn],
    tasks: &[Task],
    batch: &Batch,
    dropout: f32,
) -> candle_core::Result<Vec<Tensor>> {
    nets.iter()
        .zip(tasks)
        .enumerate()
        .map(|(i, (net, task))| {
            let b = batch.inputs[i].dim(0)?;
            let state = net.initial_state(b, batch.inits[i].as_ref())?;
            let (y, _) = net.forward(&batch.inputs[i], &state, dropout)?;
            task_loss(task.loss, &y, &batch.targets[i])
        })
        .collect()
}

/// Chunk starts covering every sequence at least `chunk` long, cut at a random phase.
fn chunk_starts(set: &TrainSet, chunk: usize, rng: &mut StdRng) -> Vec<usize> {
    let mut starts = Vec::new();
    for &(s, len) in &set.sequences {
        if len < chunk {
            continue;
        }
        let phase = rng.random_range(0..=(len - chunk).min(chunk - 1));
        let mut o = phase;
        while o + chunk <= len {
            starts.push(s + o);
            o += chunk;
        }
    }
    starts
}

/// Train `options.method`'s nets; returns the path of the exported weights.
pub fn train(options: &TrainOptions) -> anyhow::Result<PathBuf> {
    let started = Instant::now();
    let method = options.method;
    let tasks = tasks(method);
    if options.chunk < 27 {
        bail!(
            "--chunk must be at least 27 frames (the cumulative velocity loss uses 27-frame blocks)"
        );
    }
    std::fs::create_dir_all(&options.checkpoint_dir).with_context(|| {
        format!(
            "creating checkpoint folder {}",
            options.checkpoint_dir.display()
        )
    })?;

    eprintln!("loading training data from {} ...", options.data.display());
    let train_set = load_split(
        &options.data,
        "train",
        method,
        options.max_train_frames,
        |i, n| {
            if i < n {
                eprint!("\r  train shard {}/{n}", i + 1);
            } else {
                eprintln!();
            }
        },
    )?;
    let val_set = load_split(
        &options.data,
        "validation",
        method,
        options.max_val_frames,
        |_, _| {},
    )?;
    let bytes: usize = [&train_set, &val_set]
        .iter()
        .flat_map(|set| set.arrays.values())
        .map(|a| a.data.len() * std::mem::size_of::<f32>())
        .sum();
    eprintln!(
        "  {} train frames in {} sequences, {} validation frames, {:.1} GB in memory ({:.0} s)",
        train_set.frames,
        train_set.sequences.len(),
        val_set.frames,
        bytes as f64 / 1e9,
        started.elapsed().as_secs_f64()
    );

    let device = options.device.open()?;
    if options.device != TrainDevice::Cpu {
        eprintln!("training on {}", options.device);
    }
    if val_set.order != train_set.order {
        bail!(
            "the train split holds the sensors ({}), the validation split ({}): rebuild the dataset",
            train_set.order.mask().names(),
            val_set.order.mask().names()
        );
    }
    if !train_set.order.is_six() {
        eprintln!(
            "  sensors: ({}), {} network inputs",
            train_set.order.mask().names(),
            imuflow_kinematics::features::pip_input_len(train_set.order.len())
        );
    }
    let specs = method.specs(options.hidden, options.layers, &train_set.order);
    let mut params = Vec::new();
    let mut init_rng = StdRng::seed_from_u64(options.seed ^ 0x1417);
    for spec in &specs {
        params.extend(init_parameters(spec, &device, &mut init_rng)?);
    }
    let mut opt = Optimizer::new(params, &specs)?;
    let ckpt_tensors = options.checkpoint_dir.join("latest.safetensors");
    let ckpt_state = options.checkpoint_dir.join("latest.json");
    let mut state = CheckpointState {
        epoch: 0,
        step: 0,
        best_val: f64::INFINITY,
        best_epoch: 0,
        elapsed_s: 0.0,
        specs: specs.clone(),
        initialized_from: None,
    };
    if ckpt_tensors.exists() && ckpt_state.exists() {
        if options.init_weights.is_some() {
            eprintln!(
                "{} holds a checkpoint: resuming it, --init-weights is not used",
                options.checkpoint_dir.display()
            );
        }
        state = resume(&mut opt, &ckpt_tensors, &ckpt_state, &specs, &device)?;
        eprintln!(
            "resuming from {} (epoch {}, step {}, best validation {:.5} at epoch {})",
            options.checkpoint_dir.display(),
            state.epoch,
            state.step,
            state.best_val,
            state.best_epoch
        );
    } else if let Some(path) = &options.init_weights {
        state.initialized_from = Some(init_from_weights(&mut opt, path, method, &device)?);
        eprintln!("starting from the weights in {}", path.display());
    }

    let log_path = options.checkpoint_dir.join("loss.csv");
    let new_log = !log_path.exists();
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .with_context(|| format!("opening {}", log_path.display()))?;
    if new_log {
        let names: Vec<String> = tasks.iter().map(|t| t.net.to_owned()).collect();
        writeln!(
            log,
            "epoch,step,elapsed_s,{},{}",
            names
                .iter()
                .map(|n| format!("train_{n}"))
                .collect::<Vec<_>>()
                .join(","),
            names
                .iter()
                .map(|n| format!("val_{n}"))
                .collect::<Vec<_>>()
                .join(",")
        )?;
    }

    // A fixed validation sample: the same chunks every epoch.
    let mut val_rng = StdRng::seed_from_u64(options.seed ^ 0x5eed);
    let mut val_starts = chunk_starts(&val_set, options.chunk, &mut val_rng);
    val_starts.shuffle(&mut val_rng);
    val_starts.truncate(256);
    if val_starts.is_empty() {
        bail!(
            "the validation split has no sequence of at least {} frames",
            options.chunk
        );
    }

    let deadline_s = options.max_minutes * 60.0;
    let mut stopped_early = false;
    while state.epoch < options.epochs {
        let mut rng = StdRng::seed_from_u64(options.seed.wrapping_add(state.epoch as u64));
        let mut starts = chunk_starts(&train_set, options.chunk, &mut rng);
        starts.shuffle(&mut rng);
        let steps = starts.len() / options.batch;
        if steps == 0 {
            bail!(
                "not enough training chunks for one batch of {}",
                options.batch
            );
        }
        let bar = progress_bar(
            options.progress,
            steps as u64,
            state.epoch + 1,
            options.epochs,
        );
        let mut sums = vec![0.0f64; tasks.len()];
        // Per net: the steps it learned from, and those skipped for a non-finite gradient.
        let mut counted = vec![0usize; tasks.len()];
        let mut skipped = vec![0usize; tasks.len()];
        let mut done = 0usize;
        let epoch_started = Instant::now();
        for batch_starts in starts.chunks_exact(options.batch) {
            let batch = make_batch(
                &train_set,
                tasks,
                batch_starts,
                options.chunk,
                Some(&mut rng),
                &device,
            )?;
            let nets = build_nets(&specs, &opt)?;
            let losses = batch_losses(&nets, tasks, &batch, options.dropout)?;
            let mut total = losses[0].clone();
            for l in &losses[1..] {
                total = (total + l)?;
            }
            let grads = total.backward()?;
            let skipped_now = opt.step(&grads, options.lr, options.clip_norm)?;
            for (net, l) in losses.iter().enumerate() {
                let loss = l.to_scalar::<f32>()? as f64;
                if skipped_now.get(net).copied().unwrap_or(false) || !loss.is_finite() {
                    skipped[net] += 1;
                } else {
                    sums[net] += loss;
                    counted[net] += 1;
                }
            }
            done += 1;
            state.step += 1;
            bar.inc(1);
            bar.set_message(format!(
                "loss {:.4}",
                sums.iter().sum::<f64>() / done as f64
            ));
            if state.elapsed_s + started.elapsed().as_secs_f64() > deadline_s {
                stopped_early = true;
                break;
            }
        }
        bar.finish_and_clear();
        let step_s = epoch_started.elapsed().as_secs_f64() / done.max(1) as f64;
        let train_losses: Vec<f64> = sums
            .iter()
            .zip(&counted)
            .map(|(s, &n)| s / n.max(1) as f64)
            .collect();
        for (task, &n) in tasks.iter().zip(&skipped) {
            if n > 0 {
                eprintln!(
                    "warning: {}: {n} of {done} steps skipped this epoch (loss or gradient not finite)",
                    task.net
                );
            }
        }
        let val_losses = validate(&specs, &opt, &val_set, tasks, &val_starts, options, &device)?;
        let val_total: f64 = val_losses.iter().sum();
        state.epoch += 1;
        let elapsed = state.elapsed_s + started.elapsed().as_secs_f64();
        writeln!(
            log,
            "{},{},{:.1},{},{}",
            state.epoch,
            state.step,
            elapsed,
            join(&train_losses),
            join(&val_losses)
        )?;
        log.flush()?;
        eprintln!(
            "epoch {:>3} ({} steps, {:.2} s each{}): train {}  val {}  [{:.0} min]",
            state.epoch,
            done,
            step_s,
            if stopped_early {
                ", stopped at the time limit"
            } else {
                ""
            },
            join(&train_losses),
            join(&val_losses),
            elapsed / 60.0
        );
        if val_total < state.best_val {
            state.best_val = val_total;
            state.best_epoch = state.epoch;
            export(options, &specs, &opt, &state, &val_losses, &train_set)?;
        }
        let mut run_state = CheckpointState {
            elapsed_s: 0.0,
            specs: specs.clone(),
            initialized_from: state.initialized_from.clone(),
            ..state
        };
        run_state.elapsed_s = elapsed;
        save_checkpoint(&opt, &ckpt_tensors, &ckpt_state, &run_state)?;
        if stopped_early {
            eprintln!(
                "time limit of {} min reached; run again to resume",
                options.max_minutes
            );
            break;
        }
    }
    eprintln!(
        "best validation loss {:.5} at epoch {}: weights in {}",
        state.best_val,
        state.best_epoch,
        options.out.display()
    );
    Ok(options.out.clone())
}

fn join(values: &[f64]) -> String {
    values
        .iter()
        .map(|v| format!("{v:.5}"))
        .collect::<Vec<_>>()
        .join(",")
}

fn progress_bar(show: bool, steps: u64, epoch: usize, epochs: usize) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(steps);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "epoch {epoch}/{epochs} {{bar:30}} {{pos}}/{{len}} steps {{msg}} [{{elapsed}} < {{eta}}]"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// The nets over the optimizer's current variables (tensors share storage with the `Var`s, so the
/// graph tracks them).
fn build_nets(specs: &[RnnSpec], opt: &Optimizer) -> anyhow::Result<Vec<Rnn>> {
    let tensors = opt.tensors();
    specs
        .iter()
        .map(|s| Rnn::from_tensors(s, &tensors).map_err(anyhow::Error::from))
        .collect()
}

fn validate(
    specs: &[RnnSpec],
    opt: &Optimizer,
    set: &TrainSet,
    tasks: &[Task],
    starts: &[usize],
    options: &TrainOptions,
    device: &Device,
) -> anyhow::Result<Vec<f64>> {
    let nets = build_nets(specs, opt)?;
    let mut sums = vec![0.0f64; tasks.len()];
    let mut n = 0usize;
    for chunk in starts.chunks(options.batch) {
        let batch = make_batch(set, tasks, chunk, options.chunk, None, device)?;
        let losses = batch_losses(&nets, tasks, &batch, 0.0)?;
        for (s, l) in sums.iter_mut().zip(&losses) {
            *s += l.to_scalar::<f32>()? as f64 * chunk.len() as f64;
        }
        n += chunk.len();
    }
    Ok(sums.iter().map(|s| s / n as f64).collect())
}

fn save_checkpoint(
    opt: &Optimizer,
    tensors_path: &Path,
    state_path: &Path,
    state: &CheckpointState,
) -> anyhow::Result<()> {
    let mut all = Vec::new();
    for (i, name) in opt.names.iter().enumerate() {
        all.push((format!("param/{name}"), opt.vars[i].as_tensor().clone()));
        all.push((format!("adam_m/{name}"), opt.m[i].clone()));
        all.push((format!("adam_v/{name}"), opt.v[i].clone()));
    }
    let mut st = serde_json::to_value(state)?;
    st["adam_step"] = opt.step.into();
    weights::save_with_metadata(tensors_path, &all, None)?;
    let tmp = state_path.with_extension("partial");
    std::fs::write(&tmp, serde_json::to_string_pretty(&st)?)?;
    std::fs::rename(&tmp, state_path)?;
    Ok(())
}

/// Sets every parameter from the weight file `path` (checked for `method`: every tensor with its
/// shape); the Adam moments start from zero. Returns what the provenance records: the file and
/// how its weights were trained.
fn init_from_weights(
    opt: &mut Optimizer,
    path: &Path,
    method: Method,
    device: &Device,
) -> anyhow::Result<serde_json::Value> {
    let weights = imuflow_kinematics::weights::Weights::load(path, method)
        .with_context(|| format!("--init-weights {}", path.display()))?;
    let tensors = candle_core::safetensors::load(path, device)
        .with_context(|| format!("reading {}", path.display()))?;
    for (i, name) in opt.names.iter().enumerate() {
        let tensor = tensors
            .get(name)
            .with_context(|| format!("--init-weights {}: no tensor {name}", path.display()))?;
        let want = opt.vars[i].as_tensor().dims().to_vec();
        if tensor.dims() != want.as_slice() {
            bail!(
                "--init-weights {}: tensor {name} is {:?}, this run's networks need {want:?} (give --hidden/--layers as the file's)",
                path.display(),
                tensor.dims()
            );
        }
        opt.vars[i].set(&tensor.to_dtype(opt.vars[i].as_tensor().dtype())?)?;
    }
    Ok(serde_json::json!({
        "file": path.display().to_string(),
        "steps": weights.metadata.provenance.get("steps"),
        "provenance": weights.metadata.provenance,
    }))
}

fn resume(
    opt: &mut Optimizer,
    tensors_path: &Path,
    state_path: &Path,
    specs: &[RnnSpec],
    device: &Device,
) -> anyhow::Result<CheckpointState> {
    let text = std::fs::read_to_string(state_path)
        .with_context(|| format!("reading {}", state_path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", state_path.display()))?;
    let state: CheckpointState = serde_json::from_value(value.clone())
        .with_context(|| format!("parsing {}", state_path.display()))?;
    if state.specs != specs {
        bail!(
            "checkpoint {} was made with other network sizes ({:?}); use another --checkpoint-dir or the same --hidden/--layers",
            state_path.display(),
            state
                .specs
                .iter()
                .map(|s| (s.hidden, s.layers))
                .collect::<Vec<_>>()
        );
    }
    let tensors = candle_core::safetensors::load(tensors_path, device)
        .with_context(|| format!("reading {}", tensors_path.display()))?;
    for (i, name) in opt.names.iter().enumerate() {
        let get = |prefix: &str| {
            tensors
                .get(&format!("{prefix}/{name}"))
                .cloned()
                .with_context(|| {
                    format!("{}: tensor {prefix}/{name} missing", tensors_path.display())
                })
        };
        opt.vars[i].set(&get("param")?)?;
        opt.m[i] = get("adam_m")?;
        opt.v[i] = get("adam_v")?;
    }
    opt.step = value["adam_step"].as_u64().unwrap_or(0) as usize;
    Ok(state)
}

/// What the weights' provenance says about the split: the rule the build wrote into its
/// `split.json` (tools/dataset/README.md, "Split": the protocol's, or every content with
/// `--every-content`), and which parts of it the run read.
fn split_provenance(data: &Path) -> String {
    let rule = std::fs::read_to_string(data.join("split.json"))
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .and_then(|v| v["rule"].as_str().map(str::to_owned));
    let read = "trained on its train split, epochs selected on its validation split; its test and holdout splits never read";
    match rule {
        Some(rule) => format!("{rule}; {read}"),
        None => format!("unknown rule (the data folder has no split.json); {read}"),
    }
}

/// The motion augmentations among the training sequences (`mirrored`, `speed 0.6`, ...; the
/// recombinations as one entry), from the shards' metadata.
fn motion_augmentations(train_set: &TrainSet) -> Vec<String> {
    let mut motions = std::collections::BTreeSet::new();
    for meta in &train_set.shard_metadata {
        for seq in meta["sequences"].as_array().into_iter().flatten() {
            if let Some(m) = seq["motion"].as_str().filter(|m| !m.is_empty()) {
                let m = if m.starts_with("upper body of ") {
                    "upper body of another clip"
                } else {
                    m
                };
                motions.insert(m.to_owned());
            }
        }
    }
    motions.into_iter().collect()
}

fn export(
    options: &TrainOptions,
    specs: &[RnnSpec],
    opt: &Optimizer,
    state: &CheckpointState,
    val_losses: &[f64],
    train_set: &TrainSet,
) -> anyhow::Result<()> {
    let tensors: Vec<(String, Tensor)> = opt
        .names
        .iter()
        .zip(&opt.vars)
        .map(|(n, v)| (n.clone(), v.as_tensor().to_dtype(DType::F32)))
        .map(|(n, t)| t.map(|t| (n, t)))
        .collect::<Result<_, _>>()?;
    let first_meta = train_set
        .shard_metadata
        .first()
        .cloned()
        .unwrap_or_default();
    let metadata = WeightsMetadata {
        format: weights::FORMAT.to_owned(),
        method: options.method,
        nets: specs.to_vec(),
        normalization: if train_set.order.is_six() {
            weights::normalization(options.method)
        } else {
            weights::PIP_SET_NORMALIZATION
        }
        .to_owned(),
        provenance: serde_json::json!({
            "trainer": format!("imuflow train (candle, {})", options.device),
            "data": options.data.display().to_string(),
            "dataset_format": first_meta.get("format"),
            "body_model": first_meta.get("body_model"),
            "synthesis": first_meta.get("synthesis"),
            "split": split_provenance(&options.data),
            "motion_augmentations": motion_augmentations(train_set),
            "train_frames": train_set.frames,
            "epochs": state.epoch,
            "steps": state.step,
            "initialized_from": state.initialized_from,
            "options": {
                "hidden": options.hidden, "layers": options.layers, "batch": options.batch,
                "chunk": options.chunk, "lr": options.lr, "dropout": options.dropout,
                "clip_norm": options.clip_norm, "seed": options.seed,
            },
            "validation_losses": specs.iter().map(|s| s.name.clone()).zip(val_losses.iter().copied())
                .collect::<std::collections::BTreeMap<_, _>>(),
        }),
        licence:
            "CC BY-NC 4.0, inherited from the Bandai-Namco-Research-Motiondataset it was trained on"
                .to_owned(),
        sensors: train_set
            .order
            .mask()
            .sites()
            .map(|s| s.name().to_owned())
            .collect(),
    };
    weights::save(&options.out, &tensors, &metadata)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bce_with_logits_is_finite_where_the_sigmoid_saturates_and_matches_the_definition() {
        let logits = [
            -120.0f32, -30.0, -17.0, -2.0, 0.0, 0.7, 5.0, 17.0, 40.0, 90.0,
        ];
        let targets = [0.0f32, 1.0, 0.0, 1.0, 0.5, 1.0, 0.0, 1.0, 0.0, 1.0];
        let x = Tensor::new(&logits[..], &Device::Cpu).unwrap();
        let t = Tensor::new(&targets[..], &Device::Cpu).unwrap();
        let got = bce_with_logits(&x, &t).unwrap().to_scalar::<f32>().unwrap() as f64;
        // The definition in f64, through ln σ(x) = −ln(1 + e^(−x)) written for either sign.
        let ln_sigmoid = |x: f64| {
            if x >= 0.0 {
                -(-x).exp().ln_1p()
            } else {
                x - x.exp().ln_1p()
            }
        };
        let want = logits
            .iter()
            .zip(&targets)
            .map(|(&x, &t)| {
                let (x, t) = (f64::from(x), f64::from(t));
                -(t * ln_sigmoid(x) + (1.0 - t) * ln_sigmoid(-x))
            })
            .sum::<f64>()
            / logits.len() as f64;
        assert!((got - want).abs() < 1e-4 * want.max(1.0), "{got} vs {want}");
        // The gradient is finite too (σ(x) − t per element).
        let v = candle_core::Var::from_tensor(&x).unwrap();
        let grads = bce_with_logits(v.as_tensor(), &t)
            .unwrap()
            .backward()
            .unwrap();
        let g: Vec<f32> = grads.get(v.as_tensor()).unwrap().to_vec1().unwrap();
        for ((gi, &xi), &ti) in g.iter().zip(&logits).zip(&targets) {
            let want = (1.0 / (1.0 + (-f64::from(xi)).exp()) - f64::from(ti)) / logits.len() as f64;
            assert!(
                (f64::from(*gi) - want).abs() < 1e-6,
                "{gi} vs {want} at {xi}"
            );
        }
    }

    fn spec(name: &str) -> RnnSpec {
        RnnSpec {
            name: name.to_owned(),
            input: 2,
            output: 2,
            hidden: 4,
            layers: 1,
            input_linear: false,
            init_input: None,
        }
    }

    #[test]
    fn devices_parse_and_a_cpu_build_names_the_feature_for_cuda() {
        assert_eq!(TrainDevice::parse("cpu"), Some(TrainDevice::Cpu));
        assert_eq!(TrainDevice::parse("cuda"), Some(TrainDevice::Cuda(0)));
        assert_eq!(TrainDevice::parse("cuda:2"), Some(TrainDevice::Cuda(2)));
        assert_eq!(TrainDevice::parse("gpu"), None);
        assert_eq!(TrainDevice::parse("cuda:x"), None);
        assert!(matches!(TrainDevice::Cpu.open(), Ok(Device::Cpu)));
        if !candle_core::utils::cuda_is_available() {
            let err = TrainDevice::Cuda(0).open().unwrap_err().to_string();
            assert!(err.contains("--features cuda"), "{err}");
        }
    }

    /// The same seed gives the same starting weights (on every device: they are drawn on the
    /// host), another seed others, all within PyTorch's bounds: U(±1/√H) for the LSTM, U(±1/√fan_in)
    /// for a linear layer.
    #[test]
    fn initial_weights_follow_the_seed_and_pytorchs_bounds() -> candle_core::Result<()> {
        let spec = RnnSpec {
            input_linear: true,
            hidden: 16,
            input: 9,
            ..spec("net")
        };
        let draw = |seed: u64| -> candle_core::Result<Vec<(String, Vec<f32>)>> {
            init_parameters(&spec, &Device::Cpu, &mut StdRng::seed_from_u64(seed))?
                .into_iter()
                .map(|(n, v)| Ok((n, v.as_tensor().flatten_all()?.to_vec1::<f32>()?)))
                .collect()
        };
        let (a, b, c) = (draw(5)?, draw(5)?, draw(6)?);
        assert_eq!(a, b);
        assert_ne!(a, c);
        for (name, values) in &a {
            // linear1 reads the 9 inputs; the LSTM's bound is 1/√H, and linear2 reads the H = 16.
            let bound = if name.contains("linear1") {
                1.0 / 9f32.sqrt()
            } else {
                1.0 / 16f32.sqrt()
            };
            let largest = values.iter().fold(0f32, |m, v| m.max(v.abs()));
            assert!(largest <= bound, "{name}: {largest} > {bound}");
            if values.len() >= 30 {
                assert!(
                    largest > 0.8 * bound,
                    "{name}: {largest} fills too little of ±{bound}"
                );
            }
        }
        Ok(())
    }

    /// A net whose gradient is NaN keeps its weights; the other net still takes its Adam step.
    #[test]
    fn a_non_finite_gradient_skips_only_its_own_net() -> candle_core::Result<()> {
        let device = Device::Cpu;
        let a = Var::from_vec(vec![1.0f32, 2.0], 2, &device)?;
        let b = Var::from_vec(vec![3.0f32, 4.0], 2, &device)?;
        let mut opt = Optimizer::new(
            vec![("a.w".to_owned(), a.clone()), ("b.w".to_owned(), b.clone())],
            &[spec("a"), spec("b")],
        )?;
        // d/da Σa² = 2a (finite); d/db of Σ b·NaN is NaN.
        let nan = Tensor::new(&[f32::NAN, f32::NAN], &device)?;
        let loss = (a.as_tensor().sqr()?.sum_all()? + (b.as_tensor() * nan)?.sum_all()?)?;
        let skipped = opt.step(&loss.backward()?, 0.1, 1e9)?;
        assert_eq!(skipped, vec![false, true]);
        assert_eq!(b.as_tensor().to_vec1::<f32>()?, vec![3.0, 4.0]);
        // Adam's first step moves every weight by lr against its gradient's sign.
        let a_now = a.as_tensor().to_vec1::<f32>()?;
        assert!(
            (a_now[0] - 0.9).abs() < 1e-5 && (a_now[1] - 1.9).abs() < 1e-5,
            "{a_now:?}"
        );
        Ok(())
    }
}
