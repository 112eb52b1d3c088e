//! `imuflow train` end to end on a tiny dataset built from the committed walking fixture (no external
//! data): the loss goes down, the run checkpoints and resumes where it stopped, and the exported
//! weights load into the streaming inference.

use std::path::{Path, PathBuf};

use imuflow_body::Pose;
use imuflow_kinematics::Method;
use imuflow_kinematics::infer::Streamer;
use imuflow_kinematics::weights::Weights;
use imuflow_train::train::{TrainOptions, train};
use nalgebra::Vector3;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

/// Copies of the fixture under names whose split hashes put clips in train and validation
/// (tools/dataset/tests/build.rs: hash mod 100 = 57, 80, 2, 16, 28, 17, 98).
const NAMES: [&str; 7] = [
    "set-a/walk_01.bvh",
    "set-a/walk_02.bvh",
    "set-b/walk_03.bvh",
    "set-b/deep/walk_04.bvh",
    "walk_05.bvh",
    "walk_06.BVH",
    "set-b/walk_07.bvh",
];

/// The fixture copied under [`NAMES`] into `dir/bvh`.
fn input_clips(dir: &Path) -> PathBuf {
    let input = dir.join("bvh");
    for name in NAMES {
        let p = input.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::copy(fixture(), &p).unwrap();
    }
    input
}

fn dataset(dir: &Path) -> PathBuf {
    let input = input_clips(dir);
    let out = dir.join("dataset");
    let mut options = imuflow_dataset::BuildOptions::new(&input, &out);
    options.progress = false;
    imuflow_dataset::build(&options).unwrap();
    out
}

fn options(data: &Path, dir: &Path, epochs: usize) -> TrainOptions {
    TrainOptions {
        method: Method::Pip,
        data: data.to_owned(),
        out: dir.join("pip-small.safetensors"),
        checkpoint_dir: dir.join("ckpt"),
        init_weights: None,
        hidden: 16,
        layers: 1,
        epochs,
        batch: 4,
        chunk: 30,
        lr: 1e-2,
        dropout: 0.0,
        clip_norm: 1.0,
        max_train_frames: usize::MAX,
        max_val_frames: usize::MAX,
        max_minutes: f64::INFINITY,
        seed: 1,
        progress: false,
        device: Default::default(),
    }
}

/// The rows of loss.csv: (epoch, sum of the validation losses).
fn validation_totals(ckpt: &Path) -> Vec<(usize, f64)> {
    let text = std::fs::read_to_string(ckpt.join("loss.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let val: Vec<usize> = (0..header.len())
        .filter(|&i| header[i].starts_with("val_"))
        .collect();
    assert_eq!(val.len(), 5, "PIP has five nets: {header:?}");
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            let total = val.iter().map(|&i| cells[i].parse::<f64>().unwrap()).sum();
            (cells[0].parse().unwrap(), total)
        })
        .collect()
}

#[test]
fn training_lowers_the_loss_resumes_and_exports_loadable_weights() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path());

    let first = options(&data, dir.path(), 4);
    train(&first).unwrap();
    let rows = validation_totals(&first.checkpoint_dir);
    assert_eq!(rows.iter().map(|r| r.0).collect::<Vec<_>>(), [1, 2, 3, 4]);
    for (_, total) in &rows {
        assert!(total.is_finite(), "{rows:?}");
    }
    // Randomly initialized nets predict nothing useful; a few epochs on one motion must help.
    assert!(
        rows[3].1 < 0.8 * rows[0].1,
        "validation loss should fall: {rows:?}"
    );

    // The same command with more epochs resumes at epoch 5 instead of starting over.
    let more = options(&data, dir.path(), 5);
    train(&more).unwrap();
    let rows = validation_totals(&more.checkpoint_dir);
    assert_eq!(
        rows.iter().map(|r| r.0).collect::<Vec<_>>(),
        [1, 2, 3, 4, 5]
    );

    // The exported weights carry their sizes and load into streaming inference.
    let weights = Weights::load(&more.out, Method::Pip).unwrap();
    let mut streamer = Streamer::new(weights, Pose::t_pose(Vector3::zeros())).unwrap();
    // Standing still in the T-pose: every bone's R_MB is the identity, no acceleration or rotation.
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let still = imuflow_kinematics::features::ImuInput {
        orientation: [identity; imuflow_body::MAX_SITES],
        ..Default::default()
    };
    let estimate = streamer.step(&still).unwrap();
    assert!(
        estimate
            .joint_velocity
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
    );
    // The wrong method is refused by name.
    let err = match Weights::load(&more.out, Method::GlobalPose) {
        Ok(_) => panic!("PIP weights loaded as GlobalPose"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("pip") || err.contains("method"), "{err}");

    // A new checkpoint folder started from the exported weights (a later session, its
    // checkpoints gone) goes on from where they were, not from random nets: its first epoch
    // ends below the first run's first epoch, and the weights say where they came from.
    let continued = TrainOptions {
        checkpoint_dir: dir.path().join("ckpt-continued"),
        out: dir.path().join("pip-continued.safetensors"),
        init_weights: Some(more.out.clone()),
        seed: 7,
        ..options(&data, dir.path(), 1)
    };
    train(&continued).unwrap();
    let first_epoch_from_scratch = validation_totals(&more.checkpoint_dir)[0].1;
    let continued_rows = validation_totals(&continued.checkpoint_dir);
    assert!(
        continued_rows[0].1 < 0.8 * first_epoch_from_scratch,
        "from the weights {continued_rows:?}, from scratch {first_epoch_from_scratch}"
    );
    let weights = Weights::load(&continued.out, Method::Pip).unwrap();
    let from = &weights.metadata.provenance["initialized_from"];
    // The provenance names the file, not where it lay (models/README.md, "Provenance").
    let file_name = more.out.file_name().unwrap().to_string_lossy().into_owned();
    assert_eq!(from["file"], file_name, "{from}");
    let text = weights.metadata.provenance.to_string();
    assert!(!text.contains(&dir.path().display().to_string()), "{text}");
    assert_eq!(from["steps"], rows_steps(&more.out), "{from}");
    // The split it names is the build's own rule (its split.json), not one assumed.
    let split = weights.metadata.provenance["split"].as_str().unwrap();
    assert!(
        split.starts_with(imuflow_dataset::SPLIT_RULE)
            && split.contains("test and holdout splits never read"),
        "{split}"
    );
    // Other network sizes than the file's are refused by name.
    let mismatched = TrainOptions {
        checkpoint_dir: dir.path().join("ckpt-mismatched"),
        hidden: 8,
        ..continued
    };
    let err = format!("{:#}", train(&mismatched).unwrap_err());
    assert!(
        err.contains("--init-weights") && err.contains("rnn1"),
        "{err}"
    );
}

/// A lower-body set's PIP networks: `dataset build --sensors lower-body` shards train nets whose
/// inputs are the set's five sensors (60 inputs, four leaf joints), the weights record the set,
/// and the streaming inference runs them, the joints the set does not observe at rest.
/// GlobalPose's networks, six-site only, are refused on those shards by name.
#[test]
fn a_lower_body_sets_pip_networks_train_and_run() {
    let dir = tempfile::tempdir().unwrap();
    let input = input_clips(dir.path());
    let data = dir.path().join("dataset");
    let mut build = imuflow_dataset::BuildOptions::new(&input, &data);
    build.progress = false;
    build.sensors = imuflow_body::SensorSet::builtin("lower-body").unwrap();
    imuflow_dataset::build(&build).unwrap();
    let run = TrainOptions {
        out: dir.path().join("pip-legs.safetensors"),
        ..options(&data, dir.path(), 1)
    };
    train(&run).unwrap();
    let weights = Weights::load(&run.out, Method::Pip).unwrap();
    assert_eq!(
        weights.metadata.sensors,
        [
            "left_lower_leg",
            "right_lower_leg",
            "pelvis",
            "left_upper_leg",
            "right_upper_leg"
        ]
    );
    // 5 sensors × (3 + 9) inputs; rnn1 predicts the knees and ankles (4 × 3).
    assert_eq!(weights.nets[0].spec.input, 60);
    assert_eq!(weights.nets[0].spec.output, 12);
    assert_eq!(weights.nets[1].spec.input, 12 + 60);
    let legs = imuflow_body::SensorSet::builtin("lower-body").unwrap();
    weights.metadata.check_sensors(&legs).unwrap();
    assert!(
        weights
            .metadata
            .check_sensors(&imuflow_body::SensorSet::six())
            .is_err()
    );

    let order =
        imuflow_kinematics::features::InputOrder::of(legs.mask()).expect("the set has the pelvis");
    let mut streamer = Streamer::new(weights, Pose::t_pose(Vector3::zeros())).unwrap();
    // A six-site input is refused naming both sets.
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let six = imuflow_kinematics::features::ImuInput {
        orientation: [identity; imuflow_body::MAX_SITES],
        ..Default::default()
    };
    let err = streamer.step(&six).unwrap_err().to_string();
    assert!(
        err.contains("left_forearm") && err.contains("left_upper_leg"),
        "{err}"
    );
    let mut still = imuflow_kinematics::features::ImuInput::of(order);
    still.orientation = [identity; imuflow_body::MAX_SITES];
    let estimate = streamer.step(&still).unwrap();
    let observed = legs.observed_joints();
    for j in imuflow_body::JointId::all() {
        if observed & (1 << j.index()) == 0 {
            assert!(
                estimate.pose[j.index()].angle() < 1e-12,
                "{} is not observed but turned",
                j.name()
            );
        }
    }
    assert!(
        estimate
            .joint_position
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
    );

    let globalpose = TrainOptions {
        method: Method::GlobalPose,
        checkpoint_dir: dir.path().join("ckpt-gp"),
        out: dir.path().join("gp-legs.safetensors"),
        ..options(&data, dir.path(), 1)
    };
    let err = format!("{:#}", train(&globalpose).unwrap_err());
    assert!(
        err.contains("six-site set only") && err.contains("left_upper_leg"),
        "{err}"
    );
}

/// The training steps a weight file's provenance records.
fn rows_steps(weights: &Path) -> serde_json::Value {
    Weights::load(weights, Method::Pip)
        .unwrap()
        .metadata
        .provenance["steps"]
        .clone()
}

/// `--max-train-frames` takes a uniform sample of sequences across all shards (not the first
/// shards), the same sample every time, and the arrays hold exactly the frames loaded.
#[test]
fn a_frame_budget_samples_sequences_across_all_shards() {
    use imuflow_train::data::load_split;
    let dir = tempfile::tempdir().unwrap();
    let input = input_clips(dir.path());
    let out = dir.path().join("dataset");
    let mut build = imuflow_dataset::BuildOptions::new(&input, &out);
    build.progress = false;
    build.augment_copies = 3;
    build.max_shard_frames = 1; // one clip (its four sequences) per shard
    imuflow_dataset::build(&build).unwrap();

    let all = load_split(&out, "train", Method::Pip, usize::MAX, |_, _| {}).unwrap();
    assert!(
        all.shard_metadata.len() >= 3,
        "{} shards",
        all.shard_metadata.len()
    );
    let budget = all.frames / 2;
    let half = load_split(&out, "train", Method::Pip, budget, |_, _| {}).unwrap();
    let again = load_split(&out, "train", Method::Pip, budget, |_, _| {}).unwrap();
    assert_eq!(
        half.sequences, again.sequences,
        "the sample is deterministic"
    );
    assert!(
        half.frames > 0 && half.frames < all.frames,
        "{} of {}",
        half.frames,
        all.frames
    );
    // Not the first shards: the last shard contributes too (the first-shards rule would stop
    // after the shard that crosses the budget).
    assert!(
        half.shard_metadata
            .contains(all.shard_metadata.last().unwrap()),
        "the last shard is in the sample"
    );
    for (name, a) in half.arrays.iter().chain(all.arrays.iter()) {
        assert_eq!(a.data.len() % a.dim, 0, "{name}");
        assert_eq!(a.data.capacity(), a.data.len(), "{name}: reserved exactly");
    }
    assert_eq!(
        half.arrays["imu"].data.len() / half.arrays["imu"].dim,
        half.frames
    );
}

/// `imuflow dataset build --vary-stature` puts augmented training copies on smaller or larger
/// bodies; the loader must compute GlobalPose's IMU-position targets on each sequence's own body.
#[test]
fn resized_sequences_get_imu_positions_of_their_own_body() {
    use imuflow_train::data::load_split;
    let dir = tempfile::tempdir().unwrap();
    let input = input_clips(dir.path());
    let out = dir.path().join("dataset");
    let mut build = imuflow_dataset::BuildOptions::new(&input, &out);
    build.progress = false;
    build.vary_stature = Some((1.5, 1.6));
    imuflow_dataset::build(&build).unwrap();

    let set = load_split(&out, "train", Method::GlobalPose, usize::MAX, |_, _| {}).unwrap();
    let statures: Vec<f64> = set
        .shard_metadata
        .iter()
        .flat_map(|m| m["sequences"].as_array().unwrap().clone())
        .map(|s| s["stature_m"].as_f64().unwrap_or(1.75))
        .collect();
    assert_eq!(statures.len(), set.sequences.len());
    let prb = &set.arrays["prb"];
    // The spread of the five IMUs around the pelvis IMU at a sequence's first frame.
    let spread = |first: usize| -> f64 {
        prb.data[first * prb.dim..(first + 1) * prb.dim]
            .chunks(3)
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() as f64)
            .sum()
    };
    let mut pairs = 0;
    // Each clip's ideal copy (the subject, 1.75 m) is followed by its augmented one.
    for (k, w) in set.sequences.windows(2).enumerate() {
        let (ideal, resized) = (statures[k], statures[k + 1]);
        if ideal != 1.75 || resized == 1.75 {
            continue;
        }
        assert!((1.5..=1.6).contains(&resized), "{resized}");
        let ratio = spread(w[1].0) / spread(w[0].0);
        let want = resized / 1.75;
        assert!(
            (ratio - want).abs() < 0.02,
            "IMU spread ratio {ratio:.4}, bodies {want:.4}"
        );
        pairs += 1;
    }
    assert!(pairs >= 2, "{pairs} resized sequences");
}

#[test]
fn a_lower_body_shard_enters_the_networks_with_the_pelvis_last() {
    let input = tempfile::tempdir().unwrap();
    std::fs::copy(fixture(), input.path().join("walk_01.bvh")).unwrap();
    let out = tempfile::tempdir().unwrap();
    let mut options = imuflow_dataset::BuildOptions::new(input.path(), out.path());
    options.progress = false;
    options.sensors = imuflow_body::SensorSet::builtin("lower-body").unwrap();
    imuflow_dataset::build(&options).unwrap();
    let shard = std::fs::read_dir(out.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "safetensors"))
        .unwrap();
    let bytes = std::fs::read(&shard).unwrap();
    let parsed = imuflow_train::data::Shard::parse(&bytes).unwrap();
    let names: Vec<&str> = parsed.order.sites().map(|s| s.name()).collect();
    assert_eq!(
        names,
        [
            "left_lower_leg",
            "right_lower_leg",
            "left_upper_leg",
            "right_upper_leg",
            "pelvis"
        ]
    );
    // The shard's sensor axis is in wire slot order (left lower leg, right lower leg, pelvis,
    // left upper leg, right upper leg): the networks' pelvis is the shard's third column, their
    // left upper leg its fourth.
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let raw = tensors.tensor("imu_orientation").unwrap();
    assert_eq!(raw.shape()[1..], [5, 3, 3]);
    let column = |f: usize, c: usize| -> Vec<f32> {
        let o = (f * 45 + c * 9) * 4;
        raw.data()[o..o + 36]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect()
    };
    for f in [0, 100] {
        let imu = parsed.imu(f);
        assert_eq!(imu.orientation[4].to_vec(), column(f, 2));
        assert_eq!(imu.orientation[2].to_vec(), column(f, 3));
        assert_eq!(imu.orientation[0].to_vec(), column(f, 0));
    }
}
