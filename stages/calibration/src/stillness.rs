//! Stillness from the data: the subject stands still when, over a short trailing window, every
//! sensor turns slowly (mean gyro norm) and its specific force hardly changes (standard deviation of
//! the accelerometer vector). A frame where any sensor is unusable is never still.

use std::collections::VecDeque;

use nalgebra::Vector3;

use crate::sample::Sample;
use imuflow_body::{MAX_SITES, SiteMask};

/// Thresholds of [`StillnessDetector`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StillnessConfig {
    /// Window length in frames.
    pub window_frames: usize,
    /// Largest mean angular-rate norm over the window (rad/s).
    pub max_gyro_radps: f64,
    /// Largest standard deviation of the specific-force vector over the window (m/s², square root
    /// of the summed per-axis variances).
    pub max_accel_std_mps2: f64,
}

/// Per-frame stillness over a trailing window (allocation only at construction).
#[derive(Debug)]
pub struct StillnessDetector {
    config: StillnessConfig,
    /// Per frame in the window: per sensor (gyro norm, specific force), by wire slot.
    window: VecDeque<[(f64, Vector3<f64>); MAX_SITES]>,
    /// The sites judged (the samples' set).
    sites: SiteMask,
}

impl StillnessDetector {
    pub fn new(config: StillnessConfig) -> StillnessDetector {
        let window_frames = config.window_frames.max(2);
        StillnessDetector {
            config: StillnessConfig {
                window_frames,
                ..config
            },
            window: VecDeque::with_capacity(window_frames),
            sites: SiteMask::default(),
        }
    }

    /// Adds a frame; whether the window ending at it is still.
    pub fn push(&mut self, sample: &Sample) -> bool {
        if !sample.all_valid() {
            self.window.clear();
            return false;
        }
        if self.window.len() == self.config.window_frames {
            self.window.pop_front();
        }
        self.sites = sample.sites;
        self.window.push_back(std::array::from_fn(|i| {
            let s = &sample.sensors[i];
            (s.angular_rate_radps.norm(), s.specific_force_mps2)
        }));
        self.window.len() == self.config.window_frames && self.window_is_still()
    }

    fn window_is_still(&self) -> bool {
        let n = self.window.len() as f64;
        self.sites.sites().map(|s| s.index()).all(|i| {
            let gyro = self.window.iter().map(|f| f[i].0).sum::<f64>() / n;
            let mean = self.window.iter().map(|f| f[i].1).sum::<Vector3<f64>>() / n;
            let var = self
                .window
                .iter()
                .map(|f| (f[i].1 - mean).norm_squared())
                .sum::<f64>()
                / n;
            gyro < self.config.max_gyro_radps && var.sqrt() < self.config.max_accel_std_mps2
        })
    }
}

/// How far a sample must stray from the stand's first part to count as motion: this many times the
/// part's own scatter (its noise and sway)...
const ONSET_SCATTERS: f64 = 5.0;
/// ...and at least this much: specific force, m/s² (a tenth of the slowest start's first tenth of a
/// second), and angular rate, rad/s (about 1°/s).
const ONSET_MIN_ACCEL_MPS2: f64 = 0.03;
const ONSET_MIN_GYRO_RADPS: f64 = 0.015;
/// The fewest samples the scatter is measured on.
const ONSET_MIN_REFERENCE: usize = 6;
/// Quiet samples in a row that end the search back from the stand's end.
const ONSET_QUIET_RUN: usize = 3;

/// Where the motion after a stand began, as an index into `stand` (the stand's samples up to where
/// the stillness test saw it end). The trailing-window test ends a stand only once the motion is
/// well under way; a slow start (the arms already where they will swing from, the legs starting
/// to move) stays under its thresholds for a fifth of a second or more, and those samples would
/// enter the stand's averages as if still. Measured per sample instead, within the last
/// `window` samples (the stillness test's window: the last still frame's window was quiet by
/// its thresholds, so a slow start began within it): the reference is the stand's first half
/// (at least [`ONSET_MIN_REFERENCE`] samples, else the stand's end stands), each sensor's mean
/// specific force and angular rate there and their scatter; going back from the end, the motion
/// began after the last [`ONSET_QUIET_RUN`] samples in a row within [`ONSET_SCATTERS`] scatters
/// (at least the floors) of that mean on every sensor.
pub fn motion_onset(stand: &[Sample], window: usize) -> usize {
    let reference = stand.len() / 2;
    if reference < ONSET_MIN_REFERENCE {
        return stand.len();
    }
    let earliest = stand.len().saturating_sub(window).max(reference);
    let part = &stand[..reference];
    let n = reference as f64;
    let sites = stand[0].sites;
    let limits: [(Vector3<f64>, f64, Vector3<f64>, f64); MAX_SITES] = std::array::from_fn(|k| {
        let force = part
            .iter()
            .map(|s| s.sensors[k].specific_force_mps2)
            .sum::<Vector3<f64>>()
            / n;
        let rate = part
            .iter()
            .map(|s| s.sensors[k].angular_rate_radps)
            .sum::<Vector3<f64>>()
            / n;
        let scatter = |f: &dyn Fn(&Sample) -> f64| (part.iter().map(f).sum::<f64>() / n).sqrt();
        let force_scatter = scatter(&|s| (s.sensors[k].specific_force_mps2 - force).norm_squared());
        let rate_scatter = scatter(&|s| (s.sensors[k].angular_rate_radps - rate).norm_squared());
        (
            force,
            (ONSET_SCATTERS * force_scatter).max(ONSET_MIN_ACCEL_MPS2),
            rate,
            (ONSET_SCATTERS * rate_scatter).max(ONSET_MIN_GYRO_RADPS),
        )
    });
    let quiet = |s: &Sample| {
        limits
            .iter()
            .enumerate()
            .filter(|(k, _)| sites.contains_slot(*k))
            .all(|(k, (force, max_force, rate, max_rate))| {
                (s.sensors[k].specific_force_mps2 - force).norm() <= *max_force
                    && (s.sensors[k].angular_rate_radps - rate).norm() <= *max_rate
            })
    };
    let mut run = 0;
    for i in (earliest..stand.len()).rev() {
        if quiet(&stand[i]) {
            run += 1;
            if run == ONSET_QUIET_RUN {
                return i + ONSET_QUIET_RUN;
            }
        } else {
            run = 0;
        }
    }
    earliest
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NUM_IMUS;
    use imuflow_graph::frames::ImuFrame;

    fn sample(gyro: f32, accel_x: f32, valid_mask: u32) -> Sample {
        let mut f = ImuFrame {
            valid_mask,
            ..Default::default()
        };
        for k in 0..NUM_IMUS {
            f.orientation_wxyz[k] = [1.0, 0.0, 0.0, 0.0];
            f.specific_force_mps2[k] = [accel_x, 9.81, 0.0];
            f.angular_rate_radps[k] = [0.0, 0.0, gyro];
        }
        Sample::from_frame(&f, 0.0, SiteMask::of(imuflow_body::Imu::SIX))
    }

    fn detector() -> StillnessDetector {
        StillnessDetector::new(StillnessConfig {
            window_frames: 4,
            max_gyro_radps: 0.3,
            max_accel_std_mps2: 0.4,
        })
    }

    #[test]
    fn still_once_the_window_is_full_and_quiet() {
        let mut d = detector();
        let still: Vec<bool> = (0..6)
            .map(|_| d.push(&sample(0.1, 0.0, 0b111111)))
            .collect();
        assert_eq!(still, [false, false, false, true, true, true]);
        // Fast turning, then a shaking accelerometer, break stillness.
        assert!(!d.push(&sample(1.5, 0.0, 0b111111)));
        let mut d = detector();
        let shaking: Vec<bool> = (0..8)
            .map(|i| d.push(&sample(0.0, if i % 2 == 0 { 1.0 } else { -1.0 }, 0b111111)))
            .collect();
        assert!(shaking.iter().all(|s| !s));
    }

    /// A stand of `n` samples whose sensor 2 starts moving at sample `onset`: its specific force
    /// departs along x as 0.5·j·t² (a start from rest with jerk j = 40 m/s³), its rate as 2·t;
    /// every value carries the noise `noise` (a fixed pseudo-random sequence).
    fn slow_start(n: usize, onset: usize, noise: f32) -> Vec<Sample> {
        (0..n)
            .map(|i| {
                let mut f = ImuFrame {
                    valid_mask: 0b111111,
                    ..Default::default()
                };
                let wobble = |k: usize| noise * (((i * 7 + k * 13) % 11) as f32 / 5.0 - 1.0);
                // Sample `onset` is the first that moved.
                let t = if i >= onset {
                    (i + 1 - onset) as f32 / 60.0
                } else {
                    0.0
                };
                for k in 0..NUM_IMUS {
                    f.orientation_wxyz[k] = [1.0, 0.0, 0.0, 0.0];
                    let moving = if k == 2 { 1.0 } else { 0.0 };
                    f.specific_force_mps2[k] = [
                        moving * 0.5 * 40.0 * t * t + wobble(k),
                        9.81 + wobble(k + 1),
                        0.0,
                    ];
                    f.angular_rate_radps[k] = [0.0, 0.0, moving * 2.0 * t + wobble(k + 2) * 0.1];
                }
                Sample::from_frame(&f, i as f64 / 60.0, SiteMask::of(imuflow_body::Imu::SIX))
            })
            .collect()
    }

    #[test]
    fn a_slow_start_is_found_where_it_began() {
        // 40 samples, the motion from sample 28 on: the trailing-window test (4 samples here)
        // would have called most of it still. Without noise the onset is exact; with noise the
        // floors and the scatter keep it from coming early, and it lands within a few samples.
        assert_eq!(motion_onset(&slow_start(40, 28, 0.0), 15), 28);
        let noisy = motion_onset(&slow_start(40, 28, 0.01), 15);
        assert!((28..=31).contains(&noisy), "{noisy}");
        // Never further back than the window, never before the reference half.
        assert_eq!(motion_onset(&slow_start(40, 10, 0.0), 15), 25);
        // No motion: the stand's end.
        assert_eq!(motion_onset(&slow_start(40, 40, 0.01), 15), 40);
        // Too short to measure a scatter on: the stand's end.
        assert_eq!(motion_onset(&slow_start(10, 6, 0.0), 15), 10);
    }

    #[test]
    fn an_unusable_sensor_restarts_the_window() {
        let mut d = detector();
        for _ in 0..5 {
            d.push(&sample(0.0, 0.0, 0b111111));
        }
        assert!(!d.push(&sample(0.0, 0.0, 0b011111)));
        let again: Vec<bool> = (0..4)
            .map(|_| d.push(&sample(0.0, 0.0, 0b111111)))
            .collect();
        assert_eq!(again, [false, false, false, true]);
    }
}
