//! imuflow-dataset: motion files → synthetic-IMU training shards (safetensors). See `README.md` beside
//! this crate for the split rule, the shard layout and every tensor's unit and frame.
//!
//! Per clip (BVH, Bandai Namco skeleton): retarget onto the body model → resample to 60 Hz → forward
//! kinematics → IMU synthesis (ideal, plus `augment_copies` augmented copies) → append to the shard of the
//! clip's split. A clip that fails to read, retarget or synthesize is reported and skipped.

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod shard;
pub mod split;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use imuflow_body::rotation::row_major_from_rotation;
use imuflow_body::{BodyModel, BodyParams, FkData, SensorSet, forward_kinematics};
use imuflow_motion::augment;
use imuflow_motion::bvh::Bvh;
use imuflow_motion::imu_synthesis::{
    AccelStencil, Augmentation, AugmentationConfig, SynthesisOptions, SyntheticImus,
    synthesize_imus,
};
use imuflow_motion::npz::{AmassOptions, read_amass_npz};
use imuflow_motion::retarget::{
    MotionClip, RetargetOptions, SourceSkeleton, median_lowest_foot_height, resample, retarget_bvh,
};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

pub use shard::{
    BYTES_PER_FRAME, BodyModelInfo, FRAME_TENSORS, METADATA_KEY, OFFSETS_TENSOR, SequenceInfo,
    ShardFile, ShardMetadata, SynthesisInfo, frame_tensors,
};
pub use split::{
    HELD_OUT_CONTENTS, Split, SplitRule, augmentation_seed, clip_key, content_of, fnv1a64,
    split_of, split_under,
};

use shard::{SequenceData, ShardAccumulator};

/// Frame rate of every shard (Hz).
pub const FPS: f64 = 60.0;

/// Licence recorded in every shard (the Bandai Namco data's).
pub const LICENCE: &str = "CC BY-NC 4.0 (Bandai-Namco-Research-Motiondataset)";

/// Format name and version recorded in every shard.
pub const FORMAT: &str = "imuflow-dataset/1";

/// Default shard size limit in frames: 100,000 frames × 1,524 bytes ≈ 152 MB.
pub const DEFAULT_MAX_SHARD_FRAMES: usize = 100_000;

/// Default subject the clips are retargeted onto (as the body crate's tests).
pub const DEFAULT_STATURE_M: f64 = 1.75;
/// Default subject mass (kg).
pub const DEFAULT_MASS_KG: f64 = 70.0;

/// IMU synthesis stencil of the shards (TransPose/PIP's smoothed free acceleration).
pub const STENCIL: AccelStencil = AccelStencil::SmoothedTransPose;

/// Settings of [`build`].
#[derive(Clone, Debug, PartialEq)]
pub struct BuildOptions {
    /// Directory searched recursively for `.bvh` files.
    pub bvh_dir: PathBuf,
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Augmented copies per clip, besides the ideal one.
    pub augment_copies: u32,
    /// Base seed of the augmentation seeds.
    pub seed: u64,
    /// Use only the first N clips (in sorted order).
    pub limit: Option<usize>,
    /// Training clips also enter mirrored left–right ([`augment::mirror`]).
    pub mirror: bool,
    /// Each further motion augmentation (speeds, recombined, perturbed, standing idle) of a
    /// training clip enters mirrored for a seeded half of the clips, so that the recorded
    /// handedness does not outnumber the mirrored one (with `mirror` alone the recorded side
    /// enters once per augmentation and the mirrored side once).
    pub mirror_augmentations: bool,
    /// Training clips also enter at each of these speeds ([`augment::time_warp`]; 1 is
    /// the clip itself).
    pub speeds: Vec<f64>,
    /// Training clips also enter with the upper body of another training clip
    /// ([`augment::recombine`]; the partner is picked by a hash of the clip and the seed).
    pub recombine: bool,
    /// Training clips also enter with smooth random offsets on the spine, neck, head and arms
    /// ([`augment::perturb`]; seeded by the clip and the seed).
    pub perturb: bool,
    /// [`augment::perturb`]'s `arm_scale`: how far the perturbed copies' arms are moved (1: the
    /// listed ranges).
    pub perturb_arm_scale: f64,
    /// One training clip in [`STANDING_IDLE_EVERY`] (by a hash of the clip and the seed) also
    /// enters as [`augment::STANDING_IDLE_S`] of standing idle with weight shifts in its
    /// first standing posture ([`augment::standing_idle`]), the upper body moved by
    /// [`augment::perturb`].
    pub standing_idle: bool,
    /// The augmented IMU copies of training clips are synthesized on a body of a stature drawn
    /// uniformly from this range, m (mass in proportion to stature², the same build), instead
    /// of the subject's: people come in all sizes. `None`: every sequence on the subject.
    pub vary_stature: Option<(f64, f64)>,
    /// Joint mapping of the clips' skeleton (`libs/motion/mappings/bandai-namco.toml` documents the
    /// format); `None`: the built-in Bandai Namco mapping.
    pub mapping: Option<PathBuf>,
    /// A shard is closed before it would exceed this many frames.
    pub max_shard_frames: usize,
    /// Subject stature (m).
    pub stature_m: f64,
    /// Subject mass (kg).
    pub mass_kg: f64,
    /// Where the held-out contents go: the holdout ([`SplitRule::Protocol`], the default) or
    /// train/validation/test by hash like every other content ([`SplitRule::EveryContent`], for
    /// the shipped weights).
    pub split_rule: SplitRule,
    /// Show a progress bar.
    pub progress: bool,
    /// The sensor set synthesized (its sites; the shards' `sensors`).
    pub sensors: SensorSet,
}

impl BuildOptions {
    /// Defaults: one augmented copy, seed 0, no limit, [`DEFAULT_MAX_SHARD_FRAMES`], the default subject,
    /// a progress bar.
    pub fn new(bvh_dir: impl Into<PathBuf>, out_dir: impl Into<PathBuf>) -> BuildOptions {
        BuildOptions {
            bvh_dir: bvh_dir.into(),
            out_dir: out_dir.into(),
            augment_copies: 1,
            seed: 0,
            limit: None,
            mirror: false,
            mirror_augmentations: false,
            speeds: Vec::new(),
            recombine: false,
            perturb: false,
            perturb_arm_scale: 1.0,
            standing_idle: false,
            vary_stature: None,
            mapping: None,
            max_shard_frames: DEFAULT_MAX_SHARD_FRAMES,
            stature_m: DEFAULT_STATURE_M,
            mass_kg: DEFAULT_MASS_KG,
            split_rule: SplitRule::Protocol,
            progress: true,
            sensors: SensorSet::six(),
        }
    }
}

/// A failure that stops the whole build (a bad clip does not: it is skipped).
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// The input directory does not exist or is not a directory.
    #[error("--bvh-dir {dir}: no such directory")]
    MissingInput { dir: String },
    /// No motion file (`.bvh`, `.npz`) under the input directory.
    #[error("--bvh-dir {dir}: no .bvh or .npz files found")]
    NoClips { dir: String },
    /// Every clip failed.
    #[error("all {count} clips failed; first: {first}")]
    AllFailed { count: usize, first: String },
    /// File system error.
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// Writing a shard failed.
    #[error("{path}: writing the shard failed: {message}")]
    Shard { path: String, message: String },
    /// The body model could not be built.
    #[error("body model: {0}")]
    Body(String),
    /// The joint mapping could not be read (the message names the file and line).
    #[error("{0}")]
    Mapping(String),
}

/// A clip that was skipped, with why.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Skipped {
    /// Its path relative to the input directory.
    pub clip: String,
    /// The error, naming the file.
    pub error: String,
}

/// Counts of one split.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SplitSummary {
    /// Source clips written.
    pub clips: usize,
    /// Sequences written (clips × (1 + augmented copies)).
    pub sequences: usize,
    /// Frames written, all copies.
    pub frames: usize,
    /// Frames of distinct motion (the ideal copies).
    pub motion_frames: usize,
    /// Shard files.
    pub shards: usize,
    /// Bytes of the shard files.
    pub bytes: u64,
}

impl SplitSummary {
    /// Hours of distinct motion.
    pub fn motion_hours(&self) -> f64 {
        self.motion_frames as f64 / FPS / 3600.0
    }
}

/// What [`build`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// `.bvh` files found (after `--limit`).
    pub found: usize,
    /// Per split, in [`Split::ALL`] order.
    pub splits: [SplitSummary; 4],
    /// Skipped clips.
    pub skipped: Vec<Skipped>,
    /// Every shard written.
    pub shards: Vec<ShardFile>,
    /// Bytes written (shards and `split.json`).
    pub output_bytes: u64,
    /// Wall time.
    pub elapsed: Duration,
}

impl Summary {
    /// The summary as a text table.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{:<11} {:>6} {:>9} {:>11} {:>13} {:>7} {:>10}",
            "split", "clips", "sequences", "frames", "motion hours", "shards", "size MB"
        );
        let mut total = SplitSummary::default();
        let rows = Split::ALL
            .iter()
            .map(|s| (s.name(), &self.splits[s.index()]));
        for (name, r) in rows {
            let _ = writeln!(s, "{}", row(name, r));
            total.clips += r.clips;
            total.sequences += r.sequences;
            total.frames += r.frames;
            total.motion_frames += r.motion_frames;
            total.shards += r.shards;
            total.bytes += r.bytes;
        }
        let _ = writeln!(s, "{}", row("total", &total));
        let _ = writeln!(
            s,
            "{} clips found, {} written, {} skipped; output {:.1} MB; elapsed {:.1} s",
            self.found,
            total.clips,
            self.skipped.len(),
            self.output_bytes as f64 / 1e6,
            self.elapsed.as_secs_f64()
        );
        for k in &self.skipped {
            let _ = writeln!(s, "skipped {}: {}", k.clip, k.error);
        }
        s
    }
}

fn row(name: &str, r: &SplitSummary) -> String {
    format!(
        "{:<11} {:>6} {:>9} {:>11} {:>13.3} {:>7} {:>10.1}",
        name,
        r.clips,
        r.sequences,
        r.frames,
        r.motion_hours(),
        r.shards,
        r.bytes as f64 / 1e6
    )
}

/// Every `.bvh` under `dir` (recursively; extension case-insensitive), sorted by [`clip_key`], with its
/// key.
pub fn find_bvh_files(dir: &Path) -> Result<Vec<(String, PathBuf)>, DatasetError> {
    find_files(dir, &["bvh"])
}

/// Every motion file the builder reads under `dir`: `.bvh` and AMASS-style `.npz`, as
/// [`find_bvh_files`].
pub fn find_motion_files(dir: &Path) -> Result<Vec<(String, PathBuf)>, DatasetError> {
    find_files(dir, &["bvh", "npz"])
}

fn find_files(dir: &Path, extensions: &[&str]) -> Result<Vec<(String, PathBuf)>, DatasetError> {
    if !dir.is_dir() {
        return Err(DatasetError::MissingInput {
            dir: dir.display().to_string(),
        });
    }
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let entries = std::fs::read_dir(&d).map_err(|source| DatasetError::Io {
            path: d.display().to_string(),
            source,
        })?;
        for entry in entries {
            let path = entry
                .map_err(|source| DatasetError::Io {
                    path: d.display().to_string(),
                    source,
                })?
                .path();
            if path.is_dir() {
                stack.push(path);
            } else if path
                .extension()
                .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
            {
                let rel = path.strip_prefix(dir).unwrap_or(&path);
                out.push((clip_key(rel), path.clone()));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// `split.json`: which clip went where.
#[derive(Serialize)]
struct SplitFile<'a> {
    rule: &'a str,
    train: Vec<&'a str>,
    validation: Vec<&'a str>,
    test: Vec<&'a str>,
    holdout: Vec<&'a str>,
    skipped: Vec<SkippedInSplit<'a>>,
}

#[derive(Serialize)]
struct SkippedInSplit<'a> {
    clip: &'a str,
    split: Split,
    error: &'a str,
}

/// The rule recorded in `split.json`.
pub const SPLIT_RULE: &str = "held-out contents (bow, dance-long, dance-short, guide, kick, punch, slash: the content in a Bandai file name <dataset>_<content>_<style>_<nnn>.bvh) -> holdout; else FNV-1a 64 of the clip's path relative to --bvh-dir (UTF-8, '/' separators) mod 100: 0-79 train, 80-89 validation, 90-99 test";

/// The rule recorded in `split.json` of a build with [`SplitRule::EveryContent`].
pub const SPLIT_RULE_EVERY_CONTENT: &str = "every content, the held-out ones (bow, dance-long, dance-short, guide, kick, punch, slash) included: FNV-1a 64 of the clip's path relative to --bvh-dir (UTF-8, '/' separators) mod 100: 0-79 train, 80-89 validation, 90-99 test";

/// Build the dataset (see the crate docs). Shards and `split.json` of an earlier run in `out_dir` are
/// removed first.
pub fn build(options: &BuildOptions) -> Result<Summary, DatasetError> {
    let start = Instant::now();
    let mut files = find_motion_files(&options.bvh_dir)?;
    if let Some(limit) = options.limit {
        files.truncate(limit);
    }
    if files.is_empty() {
        return Err(DatasetError::NoClips {
            dir: options.bvh_dir.display().to_string(),
        });
    }
    let params = BodyParams::builtin().map_err(|e| DatasetError::Body(e.to_string()))?;
    let body = BodyModel::new(&params, options.stature_m, options.mass_kg)
        .map_err(|e| DatasetError::Body(e.to_string()))?;
    let source = match &options.mapping {
        Some(path) => SourceSkeleton::load(path),
        None => SourceSkeleton::bandai_namco(),
    }
    .map_err(|e| DatasetError::Mapping(format!("--mapping: {e}")))?;
    prepare_out_dir(&options.out_dir)?;

    let meta = ShardMetadata {
        format: FORMAT.into(),
        split: String::new(),
        fps: FPS,
        licence: LICENCE.into(),
        body_model: BodyModelInfo {
            stature_m: body.stature_m,
            mass_kg: body.mass_kg,
        },
        synthesis: SynthesisInfo {
            accel_stencil: format!("{STENCIL:?}"),
            augmentation: "AugmentationConfig::REFERENCE (GlobalPose magnitudes + heading drift)"
                .into(),
            base_seed: options.seed,
        },
        sensors: options.sensors.site_names(),
        sequences: Vec::new(),
    };
    let mut acc: Vec<ShardAccumulator> = Split::ALL
        .iter()
        .map(|&s| ShardAccumulator::new(s, options.max_shard_frames))
        .collect();
    let mut summary = Summary {
        found: files.len(),
        splits: Default::default(),
        skipped: Vec::new(),
        shards: Vec::new(),
        output_bytes: 0,
        elapsed: Duration::ZERO,
    };
    let mut written: [Vec<&str>; 4] = Default::default();
    let mut skipped_split = Vec::new();

    let pb = if options.progress {
        let pb = ProgressBar::new(files.len() as u64);
        if let Ok(style) = ProgressStyle::default_bar()
            .template("{elapsed_precise} [{bar:40}] {pos}/{len} clips, eta {eta} {msg}")
        {
            pb.set_style(style.progress_chars("=> "));
        }
        pb
    } else {
        ProgressBar::hidden()
    };

    // Upper bodies for `recombine` come from training clips only: no validation, test or holdout
    // motion leaks into training.
    let partners: Vec<(String, PathBuf)> = files
        .iter()
        .filter(|(key, _)| split_under(key, options.split_rule) == Split::Train)
        .cloned()
        .collect();
    let mut clip_state = ClipWork::new(partners, params);
    for (key, path) in &files {
        let split = split_under(key, options.split_rule);
        pb.set_message(key.clone());
        match clip_state.process(key, path, split, &body, &source, options) {
            Ok(sequences) => {
                let s = &mut summary.splits[split.index()];
                s.clips += 1;
                for seq in &sequences {
                    s.sequences += 1;
                    s.frames += seq.info.frames;
                    if !seq.info.augmented {
                        s.motion_frames += seq.info.frames;
                    }
                }
                if let Some(f) = acc[split.index()].push_clip(sequences, &options.out_dir, &meta)? {
                    summary.shards.push(f);
                }
                written[split.index()].push(key);
            }
            Err(e) => {
                let error = format!("{e:#}");
                pb.println(format!("skipped {}: {error}", path.display()));
                summary.skipped.push(Skipped {
                    clip: key.clone(),
                    error,
                });
                skipped_split.push(split);
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();

    if summary.skipped.len() == files.len() {
        return Err(DatasetError::AllFailed {
            count: files.len(),
            first: summary
                .skipped
                .first()
                .map(|s| s.error.clone())
                .unwrap_or_default(),
        });
    }
    for a in &mut acc {
        if let Some(f) = a.flush(&options.out_dir, &meta)? {
            summary.shards.push(f);
        }
    }
    for f in &summary.shards {
        // The shard's split is its file-name prefix.
        let name = f
            .path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if let Some(s) = Split::ALL
            .iter()
            .find(|s| name.starts_with(&format!("{}-", s.name())))
        {
            summary.splits[s.index()].shards += 1;
            summary.splits[s.index()].bytes += f.bytes;
        }
        summary.output_bytes += f.bytes;
    }

    let [train, validation, test, holdout] = written;
    let split_file = SplitFile {
        rule: match options.split_rule {
            SplitRule::Protocol => SPLIT_RULE,
            SplitRule::EveryContent => SPLIT_RULE_EVERY_CONTENT,
        },
        train,
        validation,
        test,
        holdout,
        skipped: summary
            .skipped
            .iter()
            .zip(&skipped_split)
            .map(|(k, &split)| SkippedInSplit {
                clip: &k.clip,
                split,
                error: &k.error,
            })
            .collect(),
    };
    let split_path = options.out_dir.join("split.json");
    let json = serde_json::to_string_pretty(&split_file).map_err(|e| DatasetError::Io {
        path: split_path.display().to_string(),
        source: e.into(),
    })?;
    std::fs::write(&split_path, &json).map_err(|source| DatasetError::Io {
        path: split_path.display().to_string(),
        source,
    })?;
    summary.output_bytes += json.len() as u64;
    summary.elapsed = start.elapsed();
    Ok(summary)
}

/// Create `out` and remove the shards and `split.json` of an earlier run.
fn prepare_out_dir(out: &Path) -> Result<(), DatasetError> {
    let io = |source| DatasetError::Io {
        path: out.display().to_string(),
        source,
    };
    std::fs::create_dir_all(out).map_err(io)?;
    for entry in std::fs::read_dir(out).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name == "split.json" || is_shard_name(&name) {
            std::fs::remove_file(&path).map_err(|source| DatasetError::Io {
                path: path.display().to_string(),
                source,
            })?;
        }
    }
    Ok(())
}

/// `train-0003.safetensors` and the like (also `.partial` leftovers).
fn is_shard_name(name: &str) -> bool {
    let name = name.strip_suffix(".partial").unwrap_or(name);
    let Some(stem) = name.strip_suffix(".safetensors") else {
        return false;
    };
    Split::ALL.iter().any(|s| {
        stem.strip_prefix(s.name())
            .and_then(|r| r.strip_prefix('-'))
            .is_some_and(|n| n.len() == 4 && n.bytes().all(|b| b.is_ascii_digit()))
    })
}

/// `--standing-idle` makes a standing-idle sequence from one training clip in this many: 15 s
/// each from about 300 of the Bandai data's 2,400 training clips is 1.25 hours, 7 % of the 18
/// motion hours of a build with every other augmentation.
pub const STANDING_IDLE_EVERY: u64 = 8;

/// Per-clip work buffers, reused between clips.
struct ClipWork {
    fk: FkData,
    /// The training clips, for `recombine`'s upper bodies.
    partners: Vec<(String, PathBuf)>,
    /// The body model's tables, for `--vary-stature`'s other bodies.
    params: BodyParams,
}

impl ClipWork {
    fn new(partners: Vec<(String, PathBuf)>, params: BodyParams) -> ClipWork {
        ClipWork {
            fk: FkData::new(),
            partners,
            params,
        }
    }

    /// The training clip whose upper body `key` gets with `--recombine`, loaded at the shard
    /// rate: a hash of the key and the seed picks it, never the clip itself; a candidate that
    /// does not load (reported on its own turn) passes to the next, a few at most.
    fn upper_body_for(
        &self,
        key: &str,
        seed: u64,
        body: &BodyModel,
        source: &SourceSkeleton,
    ) -> Option<(&str, MotionClip)> {
        let n = self.partners.len();
        if n < 2 {
            return None;
        }
        let start =
            (fnv1a64(key.as_bytes()) ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15)) as usize % n;
        (0..n)
            .map(|k| &self.partners[(start + k) % n])
            .filter(|(other, _)| other != key)
            .take(4)
            .find_map(|(other, path)| {
                let clip = read_clip(path, body, source).ok()?;
                Some((other.as_str(), resample(&clip, FPS).ok()?))
            })
    }

    /// The sequences of one clip: ideal first, then the augmented copies; for a training clip the
    /// same again for each motion augmentation (mirrored, each speed, recombined, perturbed,
    /// standing idle).
    fn process(
        &mut self,
        key: &str,
        path: &Path,
        split: Split,
        body: &BodyModel,
        source: &SourceSkeleton,
        options: &BuildOptions,
    ) -> anyhow::Result<Vec<SequenceData>> {
        let recorded = read_clip(path, body, source)?;
        let clip =
            resample(&recorded, FPS).with_context(|| format!("{}: resampling", path.display()))?;
        let mut motions = Vec::new();
        if split == Split::Train {
            if options.mirror {
                motions.push(("mirrored".to_owned(), augment::mirror(&clip)));
            }
            for &speed in &options.speeds {
                let warped = augment::time_warp(&recorded, speed, FPS)
                    .with_context(|| format!("{}: time warp ×{speed}", path.display()))?;
                motions.push((format!("speed {speed}"), warped));
            }
            if options.recombine
                && let Some((partner, upper)) = self.upper_body_for(key, options.seed, body, source)
            {
                let mixed = augment::recombine(&clip, &upper);
                // Under a second together: too short to teach anything.
                if mixed.poses.len() as f64 >= FPS {
                    motions.push((format!("upper body of {partner}"), mixed));
                }
            }
            if options.perturb {
                let seed = fnv1a64(format!("{key}#perturbed").as_bytes()) ^ options.seed;
                motions.push((
                    "perturbed".to_owned(),
                    augment::perturb(&clip, seed, options.perturb_arm_scale),
                ));
            }
            let idle_seed = fnv1a64(format!("{key}#standing idle").as_bytes()) ^ options.seed;
            if options.standing_idle
                && idle_seed.is_multiple_of(STANDING_IDLE_EVERY)
                && let Some(idle) = augment::standing_idle(&clip, body, idle_seed)
            {
                let moving =
                    augment::perturb(&idle, idle_seed.rotate_left(17), options.perturb_arm_scale);
                motions.push(("standing idle".to_owned(), moving));
            }
        }
        if options.mirror_augmentations {
            motions = motions
                .into_iter()
                .map(|(name, motion)| {
                    let coin = fnv1a64(format!("{key}#{name}#side").as_bytes()) ^ options.seed;
                    match name != "mirrored" && coin % 2 == 1 {
                        true => (format!("{name}, mirrored"), augment::mirror(&motion)),
                        false => (name, motion),
                    }
                })
                .collect();
        }
        motions.insert(0, (String::new(), clip));
        let mut out = Vec::new();
        for (motion, clip) in &motions {
            self.sequences(key, path, motion, clip, body, split, options, &mut out)?;
        }
        Ok(out)
    }

    /// The ideal and augmented IMU copies of one motion (`motion`: "" for the recorded one).
    #[allow(clippy::too_many_arguments)]
    fn sequences(
        &mut self,
        key: &str,
        path: &Path,
        motion: &str,
        clip: &MotionClip,
        body: &BodyModel,
        split: Split,
        options: &BuildOptions,
        out: &mut Vec<SequenceData>,
    ) -> anyhow::Result<()> {
        let motion_tensors = self.motion_tensors(body, clip);
        // The recorded motion's seeds are the clip's (unchanged by augmentation options); each
        // augmented motion gets its own.
        let clip_hash = match motion {
            "" => fnv1a64(key.as_bytes()),
            m => fnv1a64(format!("{key}#{m}").as_bytes()),
        };
        for copy in 0..=options.augment_copies {
            let seed = (copy > 0).then(|| augmentation_seed(options.seed, clip_hash, copy.into()));
            let synthesis = SynthesisOptions {
                stencil: STENCIL,
                augmentation: seed.map(|seed| Augmentation {
                    config: AugmentationConfig::REFERENCE,
                    seed,
                }),
                sites: options.sensors.mask(),
            };
            // Another body size for an augmented training copy (`--vary-stature`).
            let resized = match (seed, options.vary_stature, split) {
                (Some(seed), Some(range), Split::Train) => {
                    Some(resized(clip, body, &self.params, range, seed)?)
                }
                _ => None,
            };
            let (clip, body) = match &resized {
                Some((clip, body)) => (clip, body),
                None => (clip, body),
            };
            let imus = synthesize_imus(clip, body, &synthesis)
                .with_context(|| format!("{}: IMU synthesis", path.display()))?;
            let [pose, root, joints] = match &resized {
                Some(_) => self.motion_tensors(body, clip),
                None => motion_tensors.clone(),
            };
            let [ori, acc, gyro] = imu_tensors(&imus);
            out.push(SequenceData {
                info: SequenceInfo {
                    clip: key.to_string(),
                    copy,
                    augmented: copy > 0,
                    seed,
                    frames: clip.poses.len(),
                    motion: motion.to_owned(),
                    stature_m: resized.as_ref().map(|(_, b)| b.stature_m),
                },
                tensors: [ori, acc, gyro, pose, root, joints],
            });
        }
        Ok(())
    }

    /// `pose_local`, `root_position`, `joint_position` bytes.
    fn motion_tensors(&mut self, body: &BodyModel, clip: &MotionClip) -> [Vec<u8>; 3] {
        let n = clip.poses.len();
        let mut pose = Vec::with_capacity(n * 24 * 9 * 4);
        let mut root = Vec::with_capacity(n * 3 * 4);
        let mut joints = Vec::with_capacity(n * 24 * 3 * 4);
        for p in &clip.poses {
            for r in &p.parent_from_joint {
                push_f32(&mut pose, &row_major_from_rotation(r));
            }
            push_f32(&mut root, p.root_in_world_m.as_slice());
            forward_kinematics(&body.skeleton, p, &mut self.fk);
            for j in &self.fk.joint_in_world_m {
                push_f32(&mut joints, j.as_slice());
            }
        }
        [pose, root, joints]
    }
}

/// `clip` (retargeted on `body`) as retargeted on a body of another stature, drawn uniformly from
/// `[low, high]` by `seed`, with a mass in proportion to the stature squared. Retargeting copies
/// the local rotations and scales the root's path (heights included) by the ratio of leg
/// lengths, so scaling the root's path by the ratio of the two bodies' leg lengths is the same
/// retargeting.
fn resized(
    clip: &MotionClip,
    body: &BodyModel,
    params: &BodyParams,
    (low, high): (f64, f64),
    seed: u64,
) -> anyhow::Result<(MotionClip, BodyModel)> {
    // The seed's top 53 bits as a uniform draw in [0, 1).
    let u = (seed.rotate_left(29) >> 11) as f64 / (1u64 << 53) as f64;
    let stature_m = low + u * (high - low);
    let mass_kg = body.mass_kg * (stature_m / body.stature_m).powi(2);
    let other = BodyModel::new(params, stature_m, mass_kg).context("resized body model")?;
    let scale = other.leg_length_m() / body.leg_length_m();
    let mut clip = clip.clone();
    for pose in &mut clip.poses {
        pose.root_in_world_m *= scale;
    }
    Ok((clip, other))
}

/// A motion file as a clip on the body model at its own rate: a BVH retargeted through `source`, or
/// an AMASS-style `.npz` (SMPL joint order and body frame: no retargeting), both with the floor at
/// the median lowest foot height.
fn read_clip(path: &Path, body: &BodyModel, source: &SourceSkeleton) -> anyhow::Result<MotionClip> {
    if !is_npz(path) {
        let bvh = Bvh::read(path)?;
        return retarget_bvh(&bvh, source, body, &RetargetOptions::default())
            .with_context(|| format!("{}: retargeting", path.display()));
    }
    let mut clip = read_amass_npz(path, &AmassOptions::default())?;
    // SMPL's body is not ours: the feet land near, not on, the AMASS floor.
    let lift = -median_lowest_foot_height(body, &clip);
    for pose in &mut clip.poses {
        pose.root_in_world_m.y += lift;
    }
    Ok(clip)
}

fn is_npz(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npz"))
}

/// `imu_orientation`, `imu_free_accel`, `imu_angular_velocity` bytes: the synthesized sites'
/// signals, in wire slot order.
fn imu_tensors(imus: &SyntheticImus) -> [Vec<u8>; 3] {
    let n = imus.frames.len();
    let sites = imus.sites.len();
    let mut ori = Vec::with_capacity(n * sites * 9 * 4);
    let mut acc = Vec::with_capacity(n * sites * 3 * 4);
    let mut gyro = Vec::with_capacity(n * sites * 3 * 4);
    for frame in &imus.frames {
        for s in imus.sites.sites().map(|site| &frame[site.index()]) {
            push_f32(&mut ori, &row_major_from_rotation(&s.model_from_sensor));
            push_f32(&mut acc, s.free_accel_in_model_mps2.as_slice());
            push_f32(&mut gyro, s.angular_velocity_in_model_radps.as_slice());
        }
    }
    [ori, acc, gyro]
}

fn push_f32(out: &mut Vec<u8>, values: &[f64]) {
    for &v in values {
        out.extend_from_slice(&(v as f32).to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_names_are_recognised() {
        assert!(is_shard_name("train-0000.safetensors"));
        assert!(is_shard_name("test-0012.safetensors.partial"));
        assert!(!is_shard_name("train-00.safetensors"));
        assert!(!is_shard_name("mine.safetensors"));
        assert!(!is_shard_name("validation-0001.json"));
    }

    #[test]
    fn bytes_per_frame_matches_the_tensor_shapes() {
        let floats: usize = FRAME_TENSORS
            .iter()
            .map(|(_, d)| d.iter().product::<usize>())
            .sum();
        assert_eq!(floats * 4, BYTES_PER_FRAME);
    }
}
