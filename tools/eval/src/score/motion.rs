//! Scores of one recorded motion estimate, against the truth or on its own.

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{BodyModel, JointId, NUM_JOINTS, Pose};
use imuflow_contact::geometry::ContactGeometry;
use imuflow_graph::frames::MotionFrame;
use nalgebra::Vector3;
use serde::Serialize;

use super::pairing::{FrameWeighted, Usable, contiguous_runs, pairs, usable};
use crate::limbs::LimbErrors;
use crate::metrics::{
    GLOBALPOSE_IGNORED_JOINTS, apply_ignored_joints, cumulative_translation_error_m,
    foot_skating_mps, global_angle_error_deg, ground_penetration_m, jitter_km_per_s3,
    joint_position_error_m, leg_angle_error_deg, per_joint_angle_error_deg,
    per_joint_position_error_m, root_jitter_km_per_s3, sip_error_deg, translation_drift_percent,
};

/// A foot joint at most this high above its rest clearance is in contact (the metrics module's
/// suggested threshold for the foot joint at the ball of the foot), m.
const CONTACT_HEIGHT_M: f64 = 0.05;
/// Below this speed the truth's pelvis and both feet count as standing still, m/s (as
/// `imuflow eval-physics`).
const STANDING_SPEED_MPS: f64 = 0.1;
/// Standard gravity, m/s² (the body model's |g|; body weight = m·g).
const GRAVITY_MPS2: f64 = 9.81;
/// Travel windows of the cumulative translation error, m: 2 m (short clips; what `imuflow
/// eval-physics` uses) and 7 m, the distance GlobalPose reports drift at (GlobalPose paper §4.2,
/// Fig. 4).
const SHORT_WINDOW_M: f64 = 2.0;
const LONG_WINDOW_M: f64 = 7.0;

/// Scores of one motion estimate. `None` where a score needs the truth and there is none, or the
/// scored frames are too few for it (see each field).
///
/// Protocols (definitions in [`crate::metrics`]):
/// - pose errors (`sip_error_deg`, `angle_error_deg`, `joint_position_error_cm`, `per_frame`,
///   `per_joint`) use GlobalPose's protocol "G" (reference §6): the local rotations of
///   [`GLOBALPOSE_IGNORED_JOINTS`] (ankles, feet, wrists, hands: no sensor observes them) set to
///   identity in estimate and truth, the root rotation kept, angles between **global** joint
///   rotations, positions **root-aligned** (the estimate shifted so its root matches the truth's);
/// - motion metrics (jitter, skating, penetration, translation, forces) use the estimate as
///   recorded (all 24 joints, world positions), like `imuflow eval-physics`.
///
/// Sequence metrics are computed per run of consecutive seqs among the scored frames and combined
/// as a mean weighted by the runs' frames (runs too short for a metric do not count); translation
/// errors are averaged over runs, each counted once (reference §6's mean over sequences). A
/// `rate_hz` that is not a positive number leaves the rate-dependent scores (jitter, skating,
/// standing forces) `None`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MotionScores {
    /// Frames scored.
    pub frames: usize,
    /// Estimate frames not scored: flagged (see [`super::SKIPPED_FLAGS`]), not decodable, or,
    /// against the truth, without a scored truth frame of the same seq.
    pub skipped: usize,
    /// Runs of consecutive seqs the scored frames form (1 for an unbroken recording).
    pub runs: usize,
    /// SIP error, degrees: mean global angle error over hips and shoulders (protocol G).
    pub sip_error_deg: Option<f64>,
    /// Global angle error, degrees: mean over all 24 joints (protocol G).
    pub angle_error_deg: Option<f64>,
    /// Leg angle error, degrees: SIP's measure over the hips and knees
    /// ([`crate::metrics::leg_angle_error_deg`]; protocol G), what a lower-body set estimates.
    pub leg_angle_error_deg: Option<f64>,
    /// Joint position error, cm: mean over all 24 joints, root-aligned (protocol G).
    pub joint_position_error_cm: Option<f64>,
    /// Knee flexion error, degrees: mean |estimate's flexion − truth's| over both knees
    /// ([`crate::limbs`]): with the lower legs on their sensors, the one angle an anatomical knee
    /// leaves its upper leg, which SIP scores.
    pub knee_flexion_error_deg: Option<f64>,
    /// Elbow flexion error, degrees: the same over both elbows (an upper arm's other freedom is
    /// the elbow's twist).
    pub elbow_flexion_error_deg: Option<f64>,
    /// Jitter of the estimate's world joint positions, km/s³ (PIP's absolute jitter, reference §6;
    /// runs of ≥ 4 frames).
    pub jitter_km_s3: Option<f64>,
    /// Jitter of the estimate's root translation, km/s³ (GlobalPose paper §4.1 "Root Jitter";
    /// runs of ≥ 4 frames).
    pub root_jitter_km_s3: Option<f64>,
    /// Cumulative translation error at 2 m of the truth's travel, m (reference §6 protocol with a
    /// 2 m window; the mean over runs, each counted once); `None` when no run of the truth travels
    /// 2 m.
    pub translation_error_2m_m: Option<f64>,
    /// The same at 7 m of travel (GlobalPose paper Fig. 4); `None` when no run travels 7 m.
    pub translation_error_7m_m: Option<f64>,
    /// Translation drift, %: the 7 m error / 7 m × 100, the figure GlobalPose's test.py prints
    /// (reference §6; GlobalPose paper Fig. 4 and Table 5).
    pub translation_drift_percent: Option<f64>,
    /// Distance walked, % of the truth's horizontal displacement (per run from its first to its
    /// last frame, along the truth's; runs whose truth travels ≥ 1 m, weighted by their frames;
    /// [`crate::metrics::distance_walked_percent`]).
    pub distance_walked_percent: Option<f64>,
    /// Foot skating, m/s: horizontal speed of a foot joint within 5 cm of its rest clearance in two
    /// consecutive frames (imuflow's definition; runs of ≥ 2 frames).
    pub foot_skating_mps: Option<f64>,
    /// Ground penetration, m: mean depth of the lowest foot joint below its rest clearance
    /// (imuflow's definition).
    pub ground_penetration_m: Option<f64>,
    /// Mean Σ vertical ground-reaction force / (m·g) over the standing frames: frames where the
    /// truth's pelvis and both feet move slower than 0.1 m/s, after the first second of each run
    /// (the physics state settles). 1 is physically right. `None` without truth, when the truth
    /// never stands, or when the estimate carries no forces at all (no physics).
    pub standing_grf_fraction: Option<f64>,
    /// Mean |Σ vertical GRF / (m·g) − 1| over the same frames (an average of 1.0 can hide
    /// oscillation; this cannot).
    pub standing_grf_deviation: Option<f64>,
    /// Frames counted as standing.
    pub standing_frames: usize,
    /// Per scored frame (with truth; empty without).
    pub per_frame: PerFrame,
    /// Per joint, means over the scored frames (with truth).
    pub per_joint: Option<PerJoint>,
}

/// Pose errors per scored frame, in seq order, for plots over time.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PerFrame {
    pub seq: Vec<u64>,
    /// Joint position error, cm (protocol G, root-aligned).
    pub joint_position_error_cm: Vec<f64>,
    /// Global angle error, degrees (protocol G).
    pub angle_error_deg: Vec<f64>,
}

/// Mean pose errors per joint (SMPL order; names from `JointId::name`), protocol G.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PerJoint {
    /// Root-aligned position error, cm (the root's is 0 by construction).
    pub joint_position_error_cm: [f64; NUM_JOINTS],
    /// Global rotation angle error, degrees.
    pub angle_error_deg: [f64; NUM_JOINTS],
}

/// Scores `estimate` against `truth` (frames paired by seq), for a subject with `body`'s
/// dimensions and mass, recorded at `rate_hz`. See [`MotionScores`] for each number's protocol.
pub fn score_against_truth(
    estimate: &[MotionFrame],
    truth: &[MotionFrame],
    body: &BodyModel,
    rate_hz: f64,
) -> MotionScores {
    let (est, tru) = (usable(estimate), usable(truth));
    let paired = pairs(&est, &tru);
    let mut scores = MotionScores {
        frames: paired.len(),
        skipped: estimate.len() - paired.len(),
        ..MotionScores::default()
    };
    if paired.is_empty() {
        return scores;
    }
    let estimates: Vec<&Usable> = paired.iter().map(|(e, _)| *e).collect();
    let truths: Vec<&Usable> = paired.iter().map(|(_, t)| *t).collect();
    pose_errors(&paired, body, &mut scores);
    let est_positions = world_positions(&estimates, body);
    let true_positions = world_positions(&truths, body);
    let seqs: Vec<u64> = estimates.iter().map(|u| u.seq).collect();
    let runs = contiguous_runs(&seqs);
    scores.runs = runs.len();
    own_motion(
        &estimates,
        &est_positions,
        &runs,
        body,
        rate_hz,
        &mut scores,
    );
    translation(&estimates, &truths, &runs, &mut scores);
    if rate_hz.is_finite() && rate_hz > 0.0 {
        standing_forces(
            &estimates,
            &true_positions,
            &runs,
            body,
            rate_hz,
            &mut scores,
        );
    }
    scores
}

/// Scores what needs no truth: jitter, root jitter, foot skating and ground penetration of
/// `estimate` (every scored frame). The truth's fields stay `None` and `per_frame` empty.
pub fn score_without_truth(
    estimate: &[MotionFrame],
    body: &BodyModel,
    rate_hz: f64,
) -> MotionScores {
    let est = usable(estimate);
    let estimates: Vec<&Usable> = est.values().collect();
    let mut scores = MotionScores {
        frames: estimates.len(),
        skipped: estimate.len() - estimates.len(),
        ..MotionScores::default()
    };
    let positions = world_positions(&estimates, body);
    let seqs: Vec<u64> = estimates.iter().map(|u| u.seq).collect();
    let runs = contiguous_runs(&seqs);
    scores.runs = runs.len();
    own_motion(&estimates, &positions, &runs, body, rate_hz, &mut scores);
    scores
}

/// World joint positions of each frame's pose as recorded.
fn world_positions(frames: &[&Usable], body: &BodyModel) -> Vec<[Vector3<f64>; NUM_JOINTS]> {
    let mut fk = FkData::new();
    frames
        .iter()
        .map(|u| {
            forward_kinematics(&body.skeleton, &u.pose, &mut fk);
            fk.joint_in_world_m
        })
        .collect()
}

/// The pose under protocol G: GlobalPose's ignored joints set to identity.
fn protocol_g(pose: &Pose) -> Pose {
    let mut p = pose.clone();
    apply_ignored_joints(&mut p, &GLOBALPOSE_IGNORED_JOINTS);
    p
}

/// SIP, angle and joint position errors: means, per frame and per joint.
fn pose_errors(paired: &[(&Usable, &Usable)], body: &BodyModel, scores: &mut MotionScores) {
    let (mut fk_est, mut fk_true) = (FkData::new(), FkData::new());
    let (mut sip, mut legs, mut angle, mut joint) = (0.0, 0.0, 0.0, 0.0);
    let mut per_joint = PerJoint::default();
    let mut limbs = LimbErrors::default();
    for (e, t) in paired {
        let (estimate, truth) = (protocol_g(&e.pose), protocol_g(&t.pose));
        forward_kinematics(&body.skeleton, &estimate, &mut fk_est);
        forward_kinematics(&body.skeleton, &truth, &mut fk_true);
        limbs.add(&estimate, &fk_est, &truth, &fk_true);
        let frame_angle = global_angle_error_deg(&fk_est, &fk_true);
        let frame_joint_cm = 100.0 * joint_position_error_m(&fk_est, &fk_true);
        sip += sip_error_deg(&fk_est, &fk_true);
        legs += leg_angle_error_deg(&fk_est, &fk_true);
        angle += frame_angle;
        joint += frame_joint_cm;
        scores.per_frame.seq.push(e.seq);
        scores
            .per_frame
            .joint_position_error_cm
            .push(frame_joint_cm);
        scores.per_frame.angle_error_deg.push(frame_angle);
        let positions = per_joint_position_error_m(&fk_est, &fk_true);
        let angles = per_joint_angle_error_deg(&fk_est, &fk_true);
        for j in 0..NUM_JOINTS {
            per_joint.joint_position_error_cm[j] += 100.0 * positions[j];
            per_joint.angle_error_deg[j] += angles[j];
        }
    }
    let n = paired.len() as f64;
    scores.sip_error_deg = Some(sip / n);
    scores.leg_angle_error_deg = Some(legs / n);
    scores.angle_error_deg = Some(angle / n);
    scores.joint_position_error_cm = Some(joint / n);
    let [left_knee, right_knee, left_elbow, right_elbow] = limbs.means();
    scores.knee_flexion_error_deg =
        Some((left_knee.flexion_error_deg + right_knee.flexion_error_deg) / 2.0);
    scores.elbow_flexion_error_deg =
        Some((left_elbow.flexion_error_deg + right_elbow.flexion_error_deg) / 2.0);
    for j in 0..NUM_JOINTS {
        per_joint.joint_position_error_cm[j] /= n;
        per_joint.angle_error_deg[j] /= n;
    }
    scores.per_joint = Some(per_joint);
}

/// Jitter, root jitter, skating and penetration of the estimate, per run.
fn own_motion(
    frames: &[&Usable],
    positions: &[[Vector3<f64>; NUM_JOINTS]],
    runs: &[std::ops::Range<usize>],
    body: &BodyModel,
    rate_hz: f64,
    scores: &mut MotionScores,
) {
    // The floor under a foot joint is its rest clearance, as the contact stage and `imuflow
    // eval-physics` take it (the foot joint sits above the sole).
    let floor_y_m = ContactGeometry::new(body).clearance(JointId::LEFT_FOOT);
    let mut penetration = FrameWeighted::default();
    for run in runs {
        penetration.add(
            ground_penetration_m(&positions[run.clone()], floor_y_m),
            run.len(),
        );
    }
    scores.ground_penetration_m = penetration.mean();
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return;
    }
    let mut jitter = FrameWeighted::default();
    let mut root_jitter = FrameWeighted::default();
    let mut skating = FrameWeighted::default();
    for run in runs {
        let p = &positions[run.clone()];
        if run.len() >= 2 {
            let speed = foot_skating_mps(p, rate_hz, floor_y_m, CONTACT_HEIGHT_M);
            skating.add(speed, run.len());
        }
        if run.len() >= 4 {
            let roots = roots_of(&frames[run.clone()]);
            jitter.add(jitter_km_per_s3(p, rate_hz), run.len());
            root_jitter.add(root_jitter_km_per_s3(&roots, rate_hz), run.len());
        }
    }
    scores.jitter_km_s3 = jitter.mean();
    scores.root_jitter_km_s3 = root_jitter.mean();
    scores.foot_skating_mps = skating.mean();
}

fn roots_of(frames: &[&Usable]) -> Vec<Vector3<f64>> {
    frames.iter().map(|u| u.pose.root_in_world_m).collect()
}

/// Cumulative translation errors at 2 m and 7 m of the truth's travel, and the drift: averaged
/// within each run, then over the runs where the truth travels the window (each run counts once,
/// as each sequence does in reference §6).
fn translation(
    estimates: &[&Usable],
    truths: &[&Usable],
    runs: &[std::ops::Range<usize>],
    scores: &mut MotionScores,
) {
    let mut short = FrameWeighted::default();
    let mut long = FrameWeighted::default();
    let mut drift = FrameWeighted::default();
    let mut walked = FrameWeighted::default();
    for run in runs {
        let est = roots_of(&estimates[run.clone()]);
        let tru = roots_of(&truths[run.clone()]);
        if let Some(e) = cumulative_translation_error_m(&est, &tru, SHORT_WINDOW_M) {
            short.add(e, 1);
        }
        if let Some(e) = cumulative_translation_error_m(&est, &tru, LONG_WINDOW_M) {
            long.add(e, 1);
        }
        if let Some(d) = translation_drift_percent(&est, &tru) {
            drift.add(d, 1);
        }
        if let Some(w) = crate::metrics::distance_walked_percent(&est, &tru) {
            walked.add(w, run.len());
        }
    }
    scores.distance_walked_percent = walked.mean();
    scores.translation_error_2m_m = short.mean();
    scores.translation_error_7m_m = long.mean();
    scores.translation_drift_percent = drift.mean();
}

/// Vertical ground-reaction force over body weight on the frames where the truth stands still.
fn standing_forces(
    estimates: &[&Usable],
    true_positions: &[[Vector3<f64>; NUM_JOINTS]],
    runs: &[std::ops::Range<usize>],
    body: &BodyModel,
    rate_hz: f64,
    scores: &mut MotionScores,
) {
    let vertical: Vec<f64> = estimates
        .iter()
        .map(|u| {
            u.frame
                .ground_reaction_force_n
                .iter()
                .map(|f| f64::from(f[1]))
                .sum()
        })
        .collect();
    // A stream without a single nonzero force has no physics behind it: no score, not "0 × mg".
    if vertical.iter().all(|f| *f == 0.0) {
        return;
    }
    let weight_n = body.mass_kg * GRAVITY_MPS2;
    // The first second of every run is left out: the optimizer's state settles after a start (as
    // `imuflow eval-physics` does).
    let settle = rate_hz.ceil() as usize;
    let (mut sum, mut deviation, mut count) = (0.0, 0.0, 0usize);
    for run in runs {
        for t in (run.start + settle.max(1))..run.end {
            let still = [JointId::PELVIS, JointId::LEFT_FOOT, JointId::RIGHT_FOOT]
                .iter()
                .all(|j| {
                    (true_positions[t][j.index()] - true_positions[t - 1][j.index()]).norm()
                        * rate_hz
                        < STANDING_SPEED_MPS
                });
            if still {
                let ratio = vertical[t] / weight_n;
                sum += ratio;
                deviation += (ratio - 1.0).abs();
                count += 1;
            }
        }
    }
    scores.standing_frames = count;
    if count > 0 {
        scores.standing_grf_fraction = Some(sum / count as f64);
        scores.standing_grf_deviation = Some(deviation / count as f64);
    }
}
