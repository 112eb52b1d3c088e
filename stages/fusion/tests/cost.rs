//! The stage's own cost per raw sample (not a check; run it with
//! `cargo test --release -p imuflow-fusion --test cost -- --ignored --nocapture`).

use std::time::Instant;

mod common;

use imuflow_fusion::assembler::{Assembler, Origin};
use imuflow_graph::frames::RawImuFrame;

/// Six sensors at `rate_hz` for 60 s, every sample in its own raw frame (the most frames per
/// sample), turning at 1 rad/s about x, with a magnetometer reading when `magnetometer`.
fn session(rate_hz: f64, magnetometer: bool) -> Vec<RawImuFrame> {
    let n = (60.0 * rate_hz) as usize;
    let mut out = Vec::with_capacity(n * 6);
    for k in 0..n {
        let t = k as f64 / rate_hz;
        for i in 0..6 {
            let mut raw = RawImuFrame::default();
            raw.header.seq = out.len() as u64;
            raw.header.capture_ns = ((t + 0.001 + 1e-4 * i as f64) * 1e9) as u64;
            raw.sample_time_ns[i] = ((t + 10.0) * 1e9) as u64;
            let (s, c) = t.sin_cos();
            raw.gyroscope_radps[i] = [1.0, 0.0, 0.0];
            raw.accelerometer_mps2[i] = [0.0, 9.81 * s as f32, 9.81 * c as f32];
            raw.magnetometer_ut[i] = [0.0, 20.0, -40.0];
            raw.valid_mask = 1 << i;
            raw.magnetometer_mask = if magnetometer { 1 << i } else { 0 };
            out.push(raw);
        }
    }
    out
}

#[test]
#[ignore = "a measurement, not a check"]
fn per_sample_cost() {
    for (rate, magnetometer) in [(100.0, true), (200.0, true), (200.0, false), (400.0, true)] {
        let raw = session(rate, magnetometer);
        let settings = common::settings(Origin::Zero);
        let mut best = f64::INFINITY;
        let mut frames = 0;
        for _ in 0..3 {
            let mut assembler = Assembler::new(settings);
            let mut out = Vec::new();
            let started = Instant::now();
            for frame in &raw {
                assembler.push(frame, &mut out).unwrap();
                frames += out.len();
                out.clear();
            }
            best = best.min(started.elapsed().as_secs_f64());
        }
        eprintln!(
            "{rate} Hz, {}: {:.2} µs per sample ({} samples, {} output frames a run)",
            if magnetometer { "9D" } else { "6D" },
            best * 1e6 / raw.len() as f64,
            raw.len(),
            frames / 3
        );
    }
}
