//! Per-frame time of the three methods on one synthetic workload (`imuflow bench physics`).
//!
//! The workload is a slow march in place (20 s at 60 Hz by default): both hips and knees swing
//! alternately, the arms swing, the supporting foot is stationary and in contact per the networks'
//! probabilities, the swinging one is not. It exercises contact changes every step, both feet in the
//! QP during double support, and the re-tracking with one and two contacts.

use std::time::Instant;

use imuflow_body::JointId;
use nalgebra::{Rotation3, Vector3};

use crate::globalpose::{GlobalPose, GlobalPoseConfig};
use crate::integrate::Integrate;
use crate::pip::{Pip, PipConfig};
use crate::{DT_S, Method, MotionEstimate, PhysicsBody, Reference};

/// Timings of one method over the workload.
#[derive(Clone, Debug, Default)]
pub struct Timings {
    /// Wall time of each `step` after the first (µs).
    pub step_us: Vec<f64>,
    /// Frames that used the solver fallback.
    pub fallbacks: usize,
    /// PIP only: the QP's own time per frame (µs) and interior-point iterations.
    pub solver_us: Vec<f64>,
    pub iterations: Vec<f64>,
}

/// The reference of frame `k` of the march (see the module docs).
pub fn march_reference(k: usize) -> Reference {
    let phase = k as f64 * DT_S * std::f64::consts::TAU * 0.5;
    let (l, r) = (phase.sin().max(0.0), (-phase.sin()).max(0.0));
    let mut reference = Reference::default();
    let p = &mut reference.pose.parent_from_joint;
    p[JointId::LEFT_HIP.index()] = Rotation3::new(Vector3::new(-0.6 * l, 0.0, 0.0));
    p[JointId::LEFT_KNEE.index()] = Rotation3::new(Vector3::new(1.0 * l, 0.0, 0.0));
    p[JointId::RIGHT_HIP.index()] = Rotation3::new(Vector3::new(-0.6 * r, 0.0, 0.0));
    p[JointId::RIGHT_KNEE.index()] = Rotation3::new(Vector3::new(1.0 * r, 0.0, 0.0));
    let swing = 0.4 * phase.sin();
    p[JointId::LEFT_SHOULDER.index()] = Rotation3::new(Vector3::new(swing, 0.0, -1.2));
    p[JointId::RIGHT_SHOULDER.index()] = Rotation3::new(Vector3::new(-swing, 0.0, 1.2));
    let (left_down, right_down) = (l < 0.05, r < 0.05);
    let prob = |down: bool| if down { 0.9 } else { 0.1 };
    reference.foot_contact_prob = [prob(left_down), prob(right_down)];
    reference.stationary_prob = [0.0, prob(left_down), prob(right_down), 0.0, 0.0];
    reference
}

/// Runs `method` over `frames` frames of the march; `after_step` sees the method after each step
/// (to read solver statistics).
pub fn time_method<M: Method>(
    method: &mut M,
    frames: usize,
    mut after_step: impl FnMut(&M, &mut Timings),
) -> anyhow::Result<Timings> {
    let mut timings = Timings::default();
    let mut out = MotionEstimate::default();
    method.reset();
    for k in 0..frames {
        let reference = march_reference(k);
        let start = Instant::now();
        let report = method.step(&reference, None, &mut out)?;
        let us = start.elapsed().as_secs_f64() * 1e6;
        timings.fallbacks += usize::from(report.fallback);
        if k > 0 {
            timings.step_us.push(us);
            after_step(method, &mut timings);
        }
    }
    Ok(timings)
}

/// Times all three methods (integrate, pip, globalpose) on the march.
pub fn run_all(frames: usize) -> anyhow::Result<Vec<(&'static str, Timings)>> {
    let physics = PhysicsBody::new(1.75, 70.0)?;
    let mut integrate = Integrate::new(physics.clone());
    let mut pip = Pip::new(physics.clone(), PipConfig::default())?;
    let mut globalpose = GlobalPose::new(physics, GlobalPoseConfig::default())?;
    Ok(vec![
        ("integrate", time_method(&mut integrate, frames, |_, _| {})?),
        (
            "pip",
            time_method(&mut pip, frames, |pip, t| {
                if let Some(s) = pip.last_solve() {
                    t.solver_us.push(s.solve_time_s * 1e6);
                    t.iterations.push(f64::from(s.iterations));
                }
            })?,
        ),
        (
            "globalpose",
            time_method(&mut globalpose, frames, |_, _| {})?,
        ),
    ])
}

/// Mean, median, 99th percentile and maximum of `values`.
pub fn summary(values: &[f64]) -> [f64; 4] {
    if values.is_empty() {
        return [0.0; 4];
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    [
        v.iter().sum::<f64>() / n as f64,
        v[n / 2],
        v[(n * 99 / 100).min(n - 1)],
        v[n - 1],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_march_alternates_its_supporting_foot() {
        // Half a period is one second: the left foot swings in the first, the right in the second.
        let a = march_reference(30);
        let b = march_reference(90);
        assert_eq!(a.foot_contact_prob, [0.1, 0.9]);
        assert_eq!(b.foot_contact_prob, [0.9, 0.1]);
        let knee = |r: &Reference, j: JointId| r.pose.parent_from_joint[j.index()].angle();
        assert!((knee(&a, JointId::LEFT_KNEE) - 1.0).abs() < 1e-9);
        assert!(knee(&a, JointId::RIGHT_KNEE) < 1e-12);
    }

    #[test]
    fn summary_is_mean_median_p99_max() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(summary(&v), [50.5, 51.0, 100.0, 100.0]);
    }
}
