//! Per-frame inference time of the streaming nets (`imuflow bench kinematics`).

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use imuflow_body::Pose;
use nalgebra::{Rotation3, Vector3};

use crate::features::ImuInput;
use crate::infer::{Backend, Streamer};
use crate::method::Method;
use crate::weights::Weights;

/// Per-frame times in microseconds, each sorted.
pub struct StepTimes {
    /// The whole [`Streamer::step`].
    pub step_us: Vec<f64>,
    /// The nets' part of it ([`Streamer::nets_time`]).
    pub nets_us: Vec<f64>,
}

/// Timing of `frames` streaming steps (after `warmup` untimed ones).
/// With `pace`, each step starts `pace` after the previous one started (the thread sleeps in
/// between, as a live stage waits for its next frame). `backend` steps the nets.
pub fn step_times_us(
    method: Method,
    weights: &Path,
    frames: usize,
    warmup: usize,
    pace: Option<std::time::Duration>,
    backend: Backend,
) -> anyhow::Result<StepTimes> {
    let weights = Weights::load(weights, method)
        .with_context(|| format!("loading weights {}", weights.display()))?;
    let mut streamer = Streamer::new(weights, Pose::t_pose(Vector3::zeros()))?;
    streamer.set_backend(backend);
    let mut times = Vec::with_capacity(frames);
    let mut nets = Vec::with_capacity(frames);
    let mut last_start: Option<Instant> = None;
    for f in 0..frames + warmup {
        let input = swaying_sensors(f);
        if let Some(pace) = pace {
            // Sleep until this frame's slot (the previous step's start + pace).
            let now = Instant::now();
            let next = last_start.map_or(now, |s| s + pace);
            std::thread::sleep(next.saturating_duration_since(now));
            last_start = Some(Instant::now());
        }
        let nets0 = streamer.nets_time();
        let t0 = Instant::now();
        std::hint::black_box(streamer.step(&input)?);
        if f >= warmup {
            times.push(t0.elapsed().as_secs_f64() * 1e6);
            nets.push((streamer.nets_time() - nets0).as_secs_f64() * 1e6);
        }
    }
    times.sort_by(f64::total_cmp);
    nets.sort_by(f64::total_cmp);
    Ok(StepTimes {
        step_us: times,
        nets_us: nets,
    })
}

/// Six sensors swaying about the vertical (the inputs' values don't change the arithmetic's cost).
pub(crate) fn swaying_sensors(frame: usize) -> ImuInput {
    let t = frame as f64 / 60.0;
    let mut input = ImuInput::default();
    for i in 0..6 {
        let r = Rotation3::from_euler_angles(0.2 * (t + i as f64).sin(), 0.5 * t.sin(), 0.1);
        let m = r.matrix();
        for row in 0..3 {
            for col in 0..3 {
                input.orientation[i][row * 3 + col] = m[(row, col)] as f32;
            }
        }
        input.acceleration[i] = [(2.0 * t).sin() as f32, 0.3, (3.0 * t).cos() as f32];
        input.angular_velocity[i] = [0.1, (t).cos() as f32 * 0.5, 0.0];
    }
    input
}
