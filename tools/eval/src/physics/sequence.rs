//! One test sequence through the nets and every physics method.

use std::time::Instant;

use bytemuck::Zeroable;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{JointId, NUM_JOINTS, Pose};
use imuflow_graph::frames::KinematicsFrame;
use imuflow_kinematics::infer::Streamer;
use imuflow_optimizer::{MotionEstimate, PhysicsBody, Reference};
use imuflow_train::data::{FPS, Shard, pose_of};
use imuflow_validation::SimModel;
use nalgebra::Vector3;

use super::{Candidate, STANDING_SPEED_MPS, TRANSLATION_WINDOW_M};
use crate::metrics::{
    cumulative_translation_error_m, foot_skating_mps, ground_penetration_m, jitter_km_per_s3,
    root_jitter_km_per_s3,
};

/// Runs every candidate over frames `a..b` of a shard and adds to its totals.
pub(super) fn evaluate_sequence(
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
            c.totals.seconds += t0.elapsed().as_secs_f64();
            c.totals.fallbacks += usize::from(report.fallback);
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
        let s = &mut c.totals;
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
