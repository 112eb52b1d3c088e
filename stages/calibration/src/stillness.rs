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

#[cfg(test)]
mod tests {
    use super::*;
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
        Sample::from_frame(&f, 0.0)
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
