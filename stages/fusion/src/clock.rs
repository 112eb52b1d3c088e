//! One sensor's clock mapped onto the source clock (`header.capture_ns`).
//!
//! A sample stamped `s` on the sensor's clock is captured by the source at
//! `c = s + offset + drift·(s − s₀) + delay`, with the delivery delay `delay ≥ 0` (transport,
//! buffering, jitter). The lower envelope of `c − s` over time is therefore the clock relation
//! without the delay: per window of [`WINDOW_S`] of sensor time the smallest `c − s` is kept,
//! and a least-squares line through the last [`MAX_WINDOWS`] window minima gives the offset and
//! the drift. Until [`MIN_WINDOWS`] windows are complete the drift is taken as 0 and the offset as
//! the smallest `c − s` seen. The constant part of the transport delay cannot be told apart from a
//! clock offset; it ends up in the offset, i.e. the sample is dated at the earliest delivery
//! seen.
//!
//! Times are kept relative to the sensor's first sample (`x`, seconds of sensor time) and to its
//! first `c − s` (`y`, seconds), so that f64 keeps sub-nanosecond precision over hours even for
//! Unix-epoch clocks.

use std::collections::VecDeque;

/// Length of one lower-envelope window, s of sensor time: long enough that some sample in it saw
/// little delay (25 samples at 50 Hz), short enough that drift within it is negligible
/// (0.15 ms at 300 ppm).
pub const WINDOW_S: f64 = 0.5;
/// Windows the line is fitted through (20 s): drift of a few 100 ppm shows as milliseconds.
pub const MAX_WINDOWS: usize = 40;
/// Complete windows before the drift is estimated (2 s).
pub const MIN_WINDOWS: usize = 4;
/// A window with fewer samples says little about the envelope (its minimum is mostly delay).
const MIN_SAMPLES_PER_WINDOW: u32 = 3;

#[derive(Clone, Copy, Debug)]
struct Window {
    index: i64,
    /// Where the smallest `y` lies, and its value.
    x: f64,
    y: f64,
    samples: u32,
}

/// The online fit of one sensor's clock.
#[derive(Clone, Debug)]
pub struct ClockFit {
    /// The first sample's time on the sensor clock, ns.
    s0: u64,
    /// The first sample's `c − s`, ns.
    d0: i128,
    complete: VecDeque<Window>,
    current: Option<Window>,
    /// Smallest `y` seen so far, s.
    lowest: f64,
    /// `y ≈ a + b·x`.
    a: f64,
    b: f64,
}

impl ClockFit {
    /// Starts with the first sample: sensor time `sample_ns`, captured at `capture_ns`.
    pub fn new(sample_ns: u64, capture_ns: i128) -> ClockFit {
        let mut fit = ClockFit {
            s0: sample_ns,
            d0: capture_ns - i128::from(sample_ns),
            complete: VecDeque::new(),
            current: None,
            lowest: f64::INFINITY,
            a: 0.0,
            b: 0.0,
        };
        fit.observe(sample_ns, capture_ns);
        fit
    }

    /// Seconds of sensor time since the first sample (negative before it).
    pub fn sensor_s(&self, sample_ns: u64) -> f64 {
        (i128::from(sample_ns) - i128::from(self.s0)) as f64 * 1e-9
    }

    /// Adds one sample (sensor time, source capture time).
    pub fn observe(&mut self, sample_ns: u64, capture_ns: i128) {
        let x = self.sensor_s(sample_ns);
        let y = (capture_ns - i128::from(sample_ns) - self.d0) as f64 * 1e-9;
        self.lowest = self.lowest.min(y);
        let index = (x / WINDOW_S).floor() as i64;
        match &mut self.current {
            Some(w) if w.index == index => {
                w.samples += 1;
                if y < w.y {
                    (w.x, w.y) = (x, y);
                }
            }
            current => {
                if let Some(done) = current.take()
                    && done.samples >= MIN_SAMPLES_PER_WINDOW
                {
                    self.complete.push_back(done);
                    if self.complete.len() > MAX_WINDOWS {
                        self.complete.pop_front();
                    }
                }
                *current = Some(Window {
                    index,
                    x,
                    y,
                    samples: 1,
                });
            }
        }
        self.refit();
    }

    fn refit(&mut self) {
        let n = self.complete.len();
        if n < MIN_WINDOWS {
            (self.a, self.b) = (self.lowest, 0.0);
            return;
        }
        let mean_x = self.complete.iter().map(|w| w.x).sum::<f64>() / n as f64;
        let mean_y = self.complete.iter().map(|w| w.y).sum::<f64>() / n as f64;
        let (mut sxx, mut sxy) = (0.0, 0.0);
        for w in &self.complete {
            sxx += (w.x - mean_x).powi(2);
            sxy += (w.x - mean_x) * (w.y - mean_y);
        }
        self.b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        self.a = mean_y - self.b * mean_x;
    }

    /// The source time of sensor time `x` (seconds since the first sample), ns.
    pub fn source_ns(&self, x: f64) -> i128 {
        let rel = x + self.a + self.b * x;
        i128::from(self.s0) + self.d0 + (rel * 1e9).round() as i128
    }

    /// The sensor time (seconds since the first sample) of source time `t_ns`.
    pub fn sensor_at(&self, t_ns: i128) -> f64 {
        let rel = (t_ns - i128::from(self.s0) - self.d0) as f64 * 1e-9;
        (rel - self.a) / (1.0 + self.b)
    }

    /// `capture − sample` at sensor time `x`: the sensor clock's offset behind the source clock, ns.
    pub fn offset_ns(&self, x: f64) -> f64 {
        self.d0 as f64 + (self.a + self.b * x) * 1e9
    }

    /// How fast the sensor's clock runs against the source's, parts per million (positive: the
    /// sensor clock gains). 0 until the drift is estimated.
    pub fn drift_ppm(&self) -> f64 {
        (1.0 / (1.0 + self.b) - 1.0) * 1e6
    }

    /// Whether the drift is estimated yet.
    pub fn has_drift(&self) -> bool {
        self.complete.len() >= MIN_WINDOWS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic uniform draw in [0, 1).
    fn uniform(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn offset_and_drift_are_found_under_the_delivery_delay() {
        // Sensor clock: 1.234 s ahead of an Unix-epoch source, gaining 250 ppm; 100 Hz; delays
        // 2..12 ms (a constant 2 ms transport plus 10 ms jitter).
        let source0: i128 = 1_700_000_000_000_000_000;
        let drift = 250e-6;
        let mut rng = 7;
        let sample = |t: f64| (1_234_000_000.0 + t * 1e9 * (1.0 + drift)) as u64;
        let mut fit = None::<ClockFit>;
        for n in 0..3000 {
            let t = n as f64 * 0.01;
            let delay = 0.002 + 0.010 * uniform(&mut rng);
            let capture = source0 + ((t + delay) * 1e9) as i128;
            match &mut fit {
                None => fit = Some(ClockFit::new(sample(t), capture)),
                Some(f) => f.observe(sample(t), capture),
            }
        }
        let fit = fit.unwrap();
        assert!(fit.has_drift());
        // The slope through 40 minima (each ±0.2 ms) over 20 s: a few ppm.
        assert!(
            (fit.drift_ppm() - 250.0).abs() < 20.0,
            "{}",
            fit.drift_ppm()
        );
        // Every sample maps to its true time plus the constant transport delay, within the
        // envelope's granularity (the smallest of ~50 uniform delays: ~0.2 ms).
        for t in [10.0, 20.0, 29.9] {
            let x = fit.sensor_s(sample(t));
            let mapped = fit.source_ns(x) - source0;
            let expected = ((t + 0.002) * 1e9) as i128;
            assert!(
                (mapped - expected).abs() < 500_000,
                "{t}: {mapped} {expected}"
            );
            // And back.
            assert!((fit.sensor_at(fit.source_ns(x)) - x).abs() < 1e-9);
        }
    }

    #[test]
    fn before_the_drift_is_known_the_offset_is_the_smallest_delay_seen() {
        let mut fit = ClockFit::new(5_000, 1_000_000 + 5_000);
        fit.observe(10_005_000, 10_400_000 + 5_000);
        fit.observe(20_005_000, 20_005_000 + 200_000);
        assert!(!fit.has_drift());
        assert_eq!(fit.drift_ppm(), 0.0);
        // c − s: 1 ms, 0.4 ms, 0.2 ms → 0.2 ms.
        assert!((fit.offset_ns(0.0) - 200_000.0).abs() < 1.0);
        assert_eq!(fit.source_ns(fit.sensor_s(30_005_000)), 30_205_000);
    }
}
