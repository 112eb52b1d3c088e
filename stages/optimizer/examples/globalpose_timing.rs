//! Times GlobalPose's physics step (both tracking passes, contact estimation, dynamics terms):
//! `cargo run --release -p imuflow-optimizer --example globalpose_timing`.
//!
//! The reference swings both knees and hips (a slow march in place) with the feet alternately
//! stationary, for 1200 frames (20 s at 60 Hz).

use std::time::Instant;

use imuflow_body::JointId;
use imuflow_optimizer::globalpose::{GlobalPose, GlobalPoseConfig};
use imuflow_optimizer::{Method, MotionEstimate, PhysicsBody, Reference};
use nalgebra::{Rotation3, Vector3};

fn main() -> anyhow::Result<()> {
    let mut method = GlobalPose::new(PhysicsBody::new(1.75, 70.0)?, GlobalPoseConfig::default())?;
    let mut out = MotionEstimate::default();
    let frames = 1200;
    let mut times = Vec::with_capacity(frames);
    let mut fallbacks = 0;
    for t in 0..frames {
        let phase = t as f64 / 60.0 * std::f64::consts::TAU * 0.5;
        let (l, r) = (phase.sin().max(0.0), (-phase.sin()).max(0.0));
        let mut reference = Reference::default();
        let p = &mut reference.pose.parent_from_joint;
        p[JointId::LEFT_HIP.index()] = Rotation3::new(Vector3::new(-0.6 * l, 0.0, 0.0));
        p[JointId::LEFT_KNEE.index()] = Rotation3::new(Vector3::new(1.0 * l, 0.0, 0.0));
        p[JointId::RIGHT_HIP.index()] = Rotation3::new(Vector3::new(-0.6 * r, 0.0, 0.0));
        p[JointId::RIGHT_KNEE.index()] = Rotation3::new(Vector3::new(1.0 * r, 0.0, 0.0));
        reference.stationary_prob = [
            0.0,
            if l < 0.05 { 0.9 } else { 0.1 },
            if r < 0.05 { 0.9 } else { 0.1 },
            0.0,
            0.0,
        ];
        let start = Instant::now();
        let report = method.step(&reference, None, &mut out)?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
        fallbacks += report.fallback as usize;
        if t % 60 == 30 {
            let grf: f64 = out.ground_reaction_force_n.iter().map(|f| f.y).sum();
            let r = method.pass_residuals();
            println!(
                "t {:5.2} s: contacts {:#07x}, vertical GRF {grf:7.1} N, root force pre {:7.1} N -> post {:6.1} N, root y {:.4} m",
                t as f64 / 60.0,
                out.contact_mask,
                r.pre_tracking.fixed_rows::<3>(0).norm(),
                r.re_tracking.fixed_rows::<3>(0).norm(),
                out.pose.root_in_world_m.y
            );
        }
    }
    times.sort_by(f64::total_cmp);
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    println!(
        "globalpose step: {frames} frames, mean {mean:.3} ms, median {:.3} ms, p99 {:.3} ms, max {:.3} ms; fallbacks {fallbacks}",
        times[frames / 2],
        times[frames * 99 / 100],
        times[frames - 1]
    );
    println!(
        "final root {:.3?}, contact mask {:#x}",
        out.pose.root_in_world_m, out.contact_mask
    );
    Ok(())
}
