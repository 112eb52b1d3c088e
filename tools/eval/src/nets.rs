//! `imuflow eval`: the nets over the dataset's **test** split (or its validation split, or its held-out contents), scored with the papers' pose metrics.
//!
//! Each test sequence is streamed frame by frame through the same [`Streamer`] the kinematics stage
//! runs (calibrated IMU data in, as the calibration stage delivers it), seeded with the sequence's
//! true first pose like the papers' evaluations (reference §6, "Initial pose"). Metrics follow the
//! reduced/local protocol of TransPose/PIP (reference §6): ignored joints, the root included, set to
//! identity in prediction and truth; SIP and global angle error (degrees), joint position error (cm),
//! jitter of the predicted joints (km/s³, PIP's unit), next to the truth's own jitter.

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{BodyModel, BodyParams, NUM_JOINTS, Pose};
use imuflow_dataset::Split;
use imuflow_kinematics::Method;
use imuflow_kinematics::features::ImuInput;
use imuflow_kinematics::infer::sensor_rotation;
use imuflow_kinematics::infer::{LimbJoints, SensorBones, Streamer};
use imuflow_kinematics::weights::Weights;
use imuflow_train::data::{FPS, pose_of};
use nalgebra::{Rotation3, Vector3};

use crate::limbs::{self, LimbErrors};
use crate::metrics::{
    IGNORED_JOINTS, apply_ignored_joints, global_angle_error_deg, jitter_km_per_s3,
    joint_position_error_m, sensed_bone_error_deg, sip_error_deg,
};
use crate::test_split::{Copies, for_each_test_sequence, sequence_bar};

/// What `imuflow eval` evaluates.
#[derive(Clone, Debug)]
pub struct NetsEval {
    /// The dataset folder (`imuflow dataset build --out`); its test shards are used.
    pub data: PathBuf,
    /// The methods to evaluate with their weight files, in table order.
    pub weights: Vec<(Method, PathBuf)>,
    pub copies: Copies,
    /// The test split (in-distribution contents) or the held-out contents.
    pub split: Split,
    /// Where the instrumented bones' orientations come from (the kinematics stage's
    /// `sensor_bones`).
    pub sensor_bones: SensorBones,
    /// What the knees and elbows may do (the kinematics stage's `limb_joints`).
    pub limb_joints: LimbJoints,
    /// Also step the networks on the mirrored stream and average (the kinematics stage's
    /// `mirror_ensemble`).
    pub mirror_ensemble: bool,
    /// At most this many sequences per method.
    pub limit: usize,
    /// Also print the per-limb table ([`crate::limbs`]).
    pub limbs: bool,
    /// Show a progress bar per method.
    pub progress: bool,
}

/// Every method's scores on the test split, as `imuflow eval` prints them ([`fmt::Display`]).
#[derive(Clone, Debug)]
pub struct NetsReport {
    pub data: PathBuf,
    pub split: Split,
    pub copies: Copies,
    pub sensor_bones: SensorBones,
    pub limb_joints: LimbJoints,
    pub mirror_ensemble: bool,
    /// Print the per-limb table after the scores.
    pub limbs: bool,
    pub rows: Vec<(Method, Scores)>,
}

/// Evaluates every method of `options` in turn.
pub fn run(options: &NetsEval) -> anyhow::Result<NetsReport> {
    let mut rows = Vec::with_capacity(options.weights.len());
    for (method, weights) in &options.weights {
        let scores = evaluate(*method, weights, options)?;
        rows.push((*method, scores));
    }
    Ok(NetsReport {
        data: options.data.clone(),
        split: options.split,
        copies: options.copies,
        sensor_bones: options.sensor_bones,
        limb_joints: options.limb_joints,
        mirror_ensemble: options.mirror_ensemble,
        limbs: options.limbs,
        rows,
    })
}

impl fmt::Display for NetsReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} split of {} ({} copies; sensor bones {}; {} knees and elbows{}; reduced protocol, reference §6)",
            self.split,
            self.data.display(),
            self.copies.name(),
            match self.sensor_bones {
                SensorBones::Measured { tolerance_rad } =>
                    format!("within {:.1}° of their sensors", tolerance_rad.to_degrees()),
                SensorBones::Network => "from the networks".to_owned(),
            },
            self.limb_joints.name(),
            if self.mirror_ensemble {
                "; averaged with the mirrored stream"
            } else {
                ""
            }
        )?;
        f.write_str(&table(&self.rows))?;
        if self.limbs {
            writeln!(
                f,
                "\nknees and elbows: the upper bone's direction error, the flexion's mean error and \
                 bias (estimate − truth), and where the truth bends the limb past 20° the share \
                 of frames the estimate bends it backwards"
            )?;
            f.write_str(&limbs::table(
                self.rows.iter().map(|(m, s)| (m.name(), &s.limbs)),
            ))?;
        }
        Ok(())
    }
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
    /// Mean angle between the output pose's instrumented bones and their calibrated sensors
    /// ([`sensed_bone_error_deg`]; on the pose as output, before the protocol's ignored joints).
    pub sensor_bone_deg: f64,
    pub us_per_frame: f64,
    /// The knees' and elbows' errors ([`crate::limbs`]), on the protocol's poses.
    pub limbs: LimbErrors,
}

/// Evaluate `weights` of `method` as `options` say (its data, split, copies, sensor bones, limit,
/// progress; its own weight list is not used).
pub fn evaluate(method: Method, weights: &Path, options: &NetsEval) -> anyhow::Result<Scores> {
    let NetsEval {
        data,
        split,
        copies,
        sensor_bones,
        limb_joints,
        mirror_ensemble,
        limit,
        progress,
        ..
    } = options;
    let (split, copies, sensor_bones, limit, progress) =
        (*split, *copies, *sensor_bones, *limit, *progress);
    let loaded = Weights::load(weights, method)
        .with_context(|| format!("loading weights {}", weights.display()))?;
    let mut streamer = Streamer::new(loaded, Pose::t_pose(Vector3::zeros()))?;
    streamer.set_sensor_bones(sensor_bones);
    streamer.set_limb_joints(*limb_joints);
    streamer.set_mirror_ensemble(*mirror_ensemble);
    let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
    let bar = sequence_bar(method.name(), progress);
    let mut totals = Scores::default();
    let (mut fk_pred, mut fk_true) = (FkData::new(), FkData::new());
    let mut infer_s = 0.0;
    for_each_test_sequence(data, split, copies, 4, limit, &bar, |shard, a, b| {
        streamer.set_start(pose_of(shard, a));
        let mut predicted_positions = Vec::with_capacity(b - a);
        let mut true_positions = Vec::with_capacity(b - a);
        for f in a..b {
            let t0 = Instant::now();
            let imu = shard.imu(f);
            let est = streamer.step(&imu)?;
            infer_s += t0.elapsed().as_secs_f64();
            let mut pred = Pose::t_pose(Vector3::zeros());
            pred.parent_from_joint = est.pose;
            forward_kinematics(&body.skeleton, &pred, &mut fk_pred);
            totals.sensor_bone_deg += sensed_bone_error_deg(&fk_pred, measured_bones(&imu));
            let mut truth = pose_of(shard, f);
            truth.root_in_world_m = Vector3::zeros();
            apply_ignored_joints(&mut pred, &IGNORED_JOINTS);
            apply_ignored_joints(&mut truth, &IGNORED_JOINTS);
            forward_kinematics(&body.skeleton, &pred, &mut fk_pred);
            forward_kinematics(&body.skeleton, &truth, &mut fk_true);
            totals.sip_deg += sip_error_deg(&fk_pred, &fk_true);
            totals.angle_deg += global_angle_error_deg(&fk_pred, &fk_true);
            totals.joint_cm += 100.0 * joint_position_error_m(&fk_pred, &fk_true);
            totals.limbs.add(&pred, &fk_pred, &truth, &fk_true);
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
        sensor_bone_deg: totals.sensor_bone_deg / n,
        truth_jitter_km_s3: totals.truth_jitter_km_s3 / n,
        us_per_frame: infer_s * 1e6 / n,
        ..totals
    })
}

/// The calibrated sensor orientations `R_MB` of one frame's network input with the joints whose
/// bones they sit on, read as the kinematics stage reads them.
fn measured_bones(imu: &ImuInput) -> Vec<(imuflow_body::JointId, Rotation3<f64>)> {
    imu.order
        .sites()
        .zip(&imu.orientation)
        .map(|(site, m)| (site.joint(), sensor_rotation(m)))
        .collect()
}

fn positions(fk: &FkData) -> [Vector3<f64>; NUM_JOINTS] {
    std::array::from_fn(|j| {
        *fk.position(imuflow_body::JointId::from_index(j).unwrap_or(imuflow_body::JointId::ROOT))
    })
}

/// The table `imuflow eval` prints.
pub fn table(rows: &[(Method, Scores)]) -> String {
    let mut out = format!(
        "{:<11} {:>5} {:>8} {:>9} {:>10} {:>10} {:>12} {:>14} {:>14} {:>9}\n",
        "method",
        "seqs",
        "frames",
        "SIP (°)",
        "angle (°)",
        "joint (cm)",
        "sensor (°)",
        "jitter km/s³",
        "truth jitter",
        "µs/frame"
    );
    for (m, s) in rows {
        out.push_str(&format!(
            "{:<11} {:>5} {:>8} {:>9.2} {:>10.2} {:>10.2} {:>12.2} {:>14.3} {:>14.3} {:>9.0}\n",
            m.name(),
            s.sequences,
            s.frames,
            s.sip_deg,
            s.angle_deg,
            s.joint_cm,
            s.sensor_bone_deg,
            s.jitter_km_s3,
            s.truth_jitter_km_s3,
            s.us_per_frame
        ));
    }
    out
}
