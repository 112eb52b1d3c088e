//! `imuflow eval`: the nets over the dataset's **test** split, scored with the papers' pose metrics.
//!
//! Each test sequence is streamed frame by frame through the same [`Streamer`] the kinematics stage
//! runs (calibrated IMU data in, as the calibration stage delivers it), seeded with the sequence's
//! true first pose like the papers' evaluations (reference §6, "Initial pose"). Metrics follow the
//! reduced/local protocol of TransPose/PIP (reference §6): ignored joints, the root included, set to
//! identity in prediction and truth; SIP and global angle error (degrees), joint position error (cm),
//! jitter of the predicted joints (km/s³, PIP's unit), next to the truth's own jitter.

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::metrics::{
    IGNORED_JOINTS, apply_ignored_joints, global_angle_error_deg, jitter_km_per_s3,
    joint_position_error_m, sip_error_deg,
};
use imuflow_body::{BodyModel, BodyParams, NUM_JOINTS, Pose};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;

use crate::data::{FPS, Shard, pose_of, shard_files};
use crate::infer::Streamer;
use crate::method::Method;
use crate::weights::Weights;

/// Which copies of each test clip to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Copies {
    /// The noise-free synthesis.
    Ideal,
    /// With the reference augmentation (mounting error, noise, bias walks, heading drift).
    Augmented,
    All,
}

/// Scores of one method.
#[derive(Clone, Debug, Default)]
pub struct Scores {
    pub sequences: usize,
    pub frames: usize,
    pub sip_deg: f64,
    pub angle_deg: f64,
    pub joint_cm: f64,
    pub jitter_km_s3: f64,
    pub truth_jitter_km_s3: f64,
    pub us_per_frame: f64,
}

/// Evaluate `weights` on the test shards in `data`.
pub fn evaluate(
    method: Method,
    weights: &Path,
    data: &Path,
    copies: Copies,
    limit: usize,
    progress: bool,
) -> anyhow::Result<Scores> {
    let loaded = Weights::load(weights, method)
        .with_context(|| format!("loading weights {}", weights.display()))?;
    let mut streamer = Streamer::new(loaded, Pose::t_pose(Vector3::zeros()))?;
    let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
    let bar = sequence_bar(method.name(), progress);
    let mut totals = Scores::default();
    let (mut fk_pred, mut fk_true) = (FkData::new(), FkData::new());
    let mut infer_s = 0.0;
    for_each_test_sequence(data, copies, 4, limit, &bar, |shard, a, b| {
        streamer.set_start(pose_of(shard, a));
        let mut predicted_positions = Vec::with_capacity(b - a);
        let mut true_positions = Vec::with_capacity(b - a);
        for f in a..b {
            let t0 = Instant::now();
            let est = streamer.step(&shard.imu(f))?;
            infer_s += t0.elapsed().as_secs_f64();
            let mut pred = Pose::t_pose(Vector3::zeros());
            pred.parent_from_joint = est.pose;
            let mut truth = pose_of(shard, f);
            truth.root_in_world_m = Vector3::zeros();
            apply_ignored_joints(&mut pred, &IGNORED_JOINTS);
            apply_ignored_joints(&mut truth, &IGNORED_JOINTS);
            forward_kinematics(&body.skeleton, &pred, &mut fk_pred);
            forward_kinematics(&body.skeleton, &truth, &mut fk_true);
            totals.sip_deg += sip_error_deg(&fk_pred, &fk_true);
            totals.angle_deg += global_angle_error_deg(&fk_pred, &fk_true);
            totals.joint_cm += 100.0 * joint_position_error_m(&fk_pred, &fk_true);
            predicted_positions.push(positions(&fk_pred));
            true_positions.push(positions(&fk_true));
            totals.frames += 1;
        }
        let n = (b - a) as f64;
        totals.jitter_km_s3 += jitter_km_per_s3(&predicted_positions, FPS as f64) * n;
        totals.truth_jitter_km_s3 += jitter_km_per_s3(&true_positions, FPS as f64) * n;
        totals.sequences += 1;
        Ok(())
    })?;
    bar.finish_and_clear();
    let n = totals.frames.max(1) as f64;
    Ok(Scores {
        sip_deg: totals.sip_deg / n,
        angle_deg: totals.angle_deg / n,
        joint_cm: totals.joint_cm / n,
        jitter_km_s3: totals.jitter_km_s3 / n,
        truth_jitter_km_s3: totals.truth_jitter_km_s3 / n,
        us_per_frame: infer_s * 1e6 / n,
        ..totals
    })
}

/// The progress bar of one pass over the test split (hidden unless `show`).
pub fn sequence_bar(label: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{label} {{bar:30}} {{pos}}/{{len}} sequences [{{elapsed}} < {{eta}}]"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}

/// Calls `f(shard, a, b)` for every sequence (frames `a..b` of its shard) of the test split in
/// `data` with the chosen copies and at least `min_frames` frames, at most `limit` of them, advancing
/// `bar`. Returns how many were visited; an error names the shard and the sequence.
pub fn for_each_test_sequence(
    data: &Path,
    copies: Copies,
    min_frames: usize,
    limit: usize,
    bar: &ProgressBar,
    mut f: impl FnMut(&Shard, usize, usize) -> anyhow::Result<()>,
) -> anyhow::Result<usize> {
    let mut visited = 0;
    for file in shard_files(data, "test")? {
        let bytes = std::fs::read(&file).with_context(|| format!("reading {}", file.display()))?;
        let shard = Shard::parse(&bytes).with_context(|| format!("shard {}", file.display()))?;
        let augmented = sequence_flags(&shard);
        bar.inc_length((shard.offsets.len() - 1) as u64);
        for s in 0..shard.offsets.len() - 1 {
            bar.inc(1);
            let keep = match copies {
                Copies::All => true,
                Copies::Ideal => !augmented.get(s).copied().unwrap_or(false),
                Copies::Augmented => augmented.get(s).copied().unwrap_or(true),
            };
            let (a, b) = (shard.offsets[s], shard.offsets[s + 1]);
            if !keep || b - a < min_frames {
                continue;
            }
            f(&shard, a, b).with_context(|| format!("{}: sequence {s}", file.display()))?;
            visited += 1;
            if visited >= limit {
                return Ok(visited);
            }
        }
    }
    Ok(visited)
}

fn positions(fk: &FkData) -> [Vector3<f64>; NUM_JOINTS] {
    std::array::from_fn(|j| {
        *fk.position(imuflow_body::JointId::from_index(j).unwrap_or(imuflow_body::JointId::ROOT))
    })
}

/// Per sequence of a shard: whether it is an augmented copy (from the shard metadata).
fn sequence_flags(shard: &Shard) -> Vec<bool> {
    shard
        .metadata
        .as_ref()
        .and_then(|m| m.get("sequences"))
        .and_then(|s| s.as_array())
        .map(|seqs| {
            seqs.iter()
                .map(|s| {
                    s.get("augmented")
                        .and_then(|a| a.as_bool())
                        .unwrap_or(false)
                })
                .collect()
        })
        .unwrap_or_default()
}

/// The table `imuflow eval` prints.
pub fn table(rows: &[(Method, Scores)]) -> String {
    let mut out = format!(
        "{:<11} {:>5} {:>8} {:>9} {:>10} {:>10} {:>14} {:>14} {:>9}\n",
        "method",
        "seqs",
        "frames",
        "SIP (°)",
        "angle (°)",
        "joint (cm)",
        "jitter km/s³",
        "truth jitter",
        "µs/frame"
    );
    for (m, s) in rows {
        out.push_str(&format!(
            "{:<11} {:>5} {:>8} {:>9.2} {:>10.2} {:>10.2} {:>14.3} {:>14.3} {:>9.0}\n",
            m.name(),
            s.sequences,
            s.frames,
            s.sip_deg,
            s.angle_deg,
            s.joint_cm,
            s.jitter_km_s3,
            s.truth_jitter_km_s3,
            s.us_per_frame
        ));
    }
    out
}
