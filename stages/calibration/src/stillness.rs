//! Stillness from the data: the subject stands still when, over a short trailing window, every
//! sensor turns slowly (mean gyro norm) and its specific force hardly changes (standard deviation of
//! the accelerometer vector). A frame where any sensor is unusable is never still.

use std::collections::VecDeque;

use nalgebra::Vector3;

use crate::NUM_IMUS;
use crate::sample::Sample;

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
    /// Per frame in the window: per sensor (gyro norm, specific force).
    window: VecDeque<[(f64, Vector3<f64>); NUM_IMUS]>,
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
        self.window.push_back(std::array::from_fn(|i| {
            let s = &sample.sensors[i];
            (s.angular_rate_radps.norm(), s.specific_force_mps2)
        }));
        self.window.len() == self.config.window_frames && self.window_is_still()
    }

    fn window_is_still(&self) -> bool {
        let n = self.window.len() as f64;
        (0..NUM_IMUS).all(|i| {
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
