//! Times PIP's per-frame QP: `cargo run --release -p imuflow-optimizer --example pip_timing [TOL]`.
//!
//! 600 frames (10 s at 60 Hz) of a synthetic motion: standing, then the left knee bending and
//! stretching at 0.5 Hz with the left foot free and the right foot planted, the arms swinging.
//! Prints the median and 95th percentile of the whole `step` and of clarabel's solve.

use std::time::Instant;

use imuflow_body::JointId;
use imuflow_optimizer::pip::{Pip, PipConfig};
use imuflow_optimizer::{Method, MotionEstimate, PhysicsBody, Reference};
use nalgebra::{Rotation3, Vector3};

fn main() -> anyhow::Result<()> {
    // Optional argument: clarabel's tolerance (default PipConfig's).
    let mut config = PipConfig::default();
    if let Some(tol) = std::env::args().nth(1) {
        config.solver_tolerance = tol.parse()?;
    }
    println!("solver tolerance {}", config.solver_tolerance);
    let mut pip = Pip::new(PhysicsBody::new(1.75, 70.0)?, config)?;
    let mut out = MotionEstimate::default();
    let mut step_ms = Vec::new();
    let mut solve_ms = Vec::new();
    let mut iterations = Vec::new();
    let mut fallbacks = 0;
    for k in 0..600 {
        let t = k as f64 / 60.0;
        let mut r = Reference {
            foot_contact_prob: [if t > 1.0 { 0.1 } else { 0.9 }, 0.9],
            ..Reference::default()
        };
        if t > 1.0 {
            let bend = 0.6 * (1.0 - (std::f64::consts::PI * (t - 1.0)).cos());
            r.pose.parent_from_joint[JointId::LEFT_KNEE.index()] =
                Rotation3::new(Vector3::new(bend, 0.0, 0.0));
            let swing = 0.5 * (std::f64::consts::PI * t).sin();
            r.pose.parent_from_joint[JointId::LEFT_SHOULDER.index()] =
                Rotation3::new(Vector3::new(0.0, 0.0, swing));
            r.pose.parent_from_joint[JointId::RIGHT_SHOULDER.index()] =
                Rotation3::new(Vector3::new(0.0, 0.0, -swing));
        }
        let t0 = Instant::now();
        let report = pip.step(&r, None, &mut out)?;
        let dt = t0.elapsed().as_secs_f64() * 1e3;
        if report.fallback {
            fallbacks += 1;
        }
        if k > 0 {
            step_ms.push(dt);
            if let Some(s) = pip.last_solve() {
                solve_ms.push(s.solve_time_s * 1e3);
                iterations.push(s.iterations as f64);
            }
        }
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (
            v[v.len() / 2],
            v[v.len() * 95 / 100],
            v.iter().sum::<f64>() / v.len() as f64,
        )
    };
    let (s50, s95, smean) = stats(&mut step_ms);
    let (q50, q95, qmean) = stats(&mut solve_ms);
    let (i50, _, imean) = stats(&mut iterations);
    println!("frames {} fallbacks {fallbacks}", step_ms.len());
    println!("step   ms: median {s50:.3} p95 {s95:.3} mean {smean:.3}");
    println!("solver ms: median {q50:.3} p95 {q95:.3} mean {qmean:.3}");
    println!("iterations: median {i50} mean {imean:.1}");
    let s = pip.last_solve().unwrap();
    println!(
        "last QP: {} variables, {} constraint rows",
        s.variables, s.constraints
    );
    println!("final root {:?}", out.pose.root_in_world_m);
    Ok(())
}
