//! Per-stage counters and processing-time statistics, reported to the launcher at the end.

use std::time::Duration;

/// Counters a stage keeps while it runs.
#[derive(Debug, Default)]
pub struct StageStats {
    /// Aligned input steps processed (sources: frames produced).
    pub frames_in: u64,
    /// Frames written to outputs (END_OF_STREAM markers not counted).
    pub frames_out: u64,
    /// Frames that never arrived (gaps in `seq`; live graphs drop when a stage lags).
    pub dropped: u64,
    /// Frames discarded because another input had no frame with the same `seq`.
    pub unmatched: u64,
    /// One line of the stage's own results, shown under the run summary.
    pub detail: String,
    processing_us: Vec<f32>,
    latency_us: Vec<f32>,
    /// Live graphs: capture (the source's Unix-epoch capture time) to arrival here, per input.
    from_capture_us: std::collections::BTreeMap<String, Vec<f32>>,
}

impl StageStats {
    /// Records the time one step took, from receiving its inputs to asking for the next.
    pub fn record_processing(&mut self, elapsed: Duration) {
        self.processing_us.push(elapsed.as_secs_f32() * 1e6);
    }

    /// Records how long an input frame took from its publisher to this stage (transport latency).
    pub fn record_latency(&mut self, publish_ns: u64, received_ns: u64) {
        if publish_ns > 0 {
            self.latency_us
                .push(received_ns.saturating_sub(publish_ns) as f32 / 1e3);
        }
    }

    /// Records how long an input frame took from its capture (a live source's Unix-epoch
    /// `capture_ns`) to its arrival at this stage on input `input`: the end-to-end latency.
    pub fn record_from_capture(&mut self, input: &str, capture_ns: u64, received_ns: u64) {
        if capture_ns == 0 {
            return;
        }
        let us = received_ns.saturating_sub(capture_ns) as f32 / 1e3;
        match self.from_capture_us.get_mut(input) {
            Some(v) => v.push(us),
            None => {
                self.from_capture_us.insert(input.to_owned(), vec![us]);
            }
        }
    }

    /// The summary the launcher prints.
    pub fn summary(&self, wall: Duration) -> StageSummary {
        let mut sorted = self.processing_us.clone();
        sorted.sort_by(f32::total_cmp);
        let mean_us = if sorted.is_empty() {
            0.0
        } else {
            sorted.iter().map(|&x| f64::from(x)).sum::<f64>() / sorted.len() as f64
        };
        let mut latency = self.latency_us.clone();
        latency.sort_by(f32::total_cmp);
        let busy_s = sorted.iter().map(|&x| f64::from(x)).sum::<f64>() * 1e-6;
        StageSummary {
            busy_fraction: if wall.is_zero() {
                0.0
            } else {
                busy_s / wall.as_secs_f64()
            },
            latency_p50_us: f64::from(percentile(&latency, 0.5)),
            latency_p99_us: f64::from(percentile(&latency, 0.99)),
            frames_in: self.frames_in,
            frames_out: self.frames_out,
            dropped: self.dropped,
            unmatched: self.unmatched,
            mean_us,
            p99_us: f64::from(percentile(&sorted, 0.99)),
            max_us: f64::from(sorted.last().copied().unwrap_or(0.0)),
            wall_s: wall.as_secs_f64(),
            detail: self.detail.clone(),
            from_capture: self
                .from_capture_us
                .iter()
                .map(|(input, values)| {
                    let mut sorted = values.clone();
                    sorted.sort_by(f32::total_cmp);
                    InputLatency {
                        input: input.clone(),
                        frames: sorted.len() as u64,
                        p50_us: f64::from(percentile(&sorted, 0.5)),
                        p99_us: f64::from(percentile(&sorted, 0.99)),
                        max_us: f64::from(sorted.last().copied().unwrap_or(0.0)),
                    }
                })
                .collect(),
        }
    }
}

/// Nearest-rank percentile of sorted values (0 for none).
pub fn percentile(sorted: &[f32], p: f64) -> f32 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (p * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// What a stage reports when it ends.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StageSummary {
    pub frames_in: u64,
    pub frames_out: u64,
    pub dropped: u64,
    pub unmatched: u64,
    /// Mean processing time per step, µs.
    pub mean_us: f64,
    /// 99th percentile processing time per step, µs.
    pub p99_us: f64,
    pub max_us: f64,
    /// Time from the start signal to the end, s.
    pub wall_s: f64,
    /// Share of `wall_s` spent processing steps: the stage nearest 1 is an offline graph's
    /// bottleneck; in a live graph it is the load the stage puts on a core.
    #[serde(default)]
    pub busy_fraction: f64,
    /// Median transport latency of input frames (publisher to this stage), µs; 0 for sources.
    pub latency_p50_us: f64,
    /// 99th percentile transport latency of input frames, µs.
    pub latency_p99_us: f64,
    /// The stage's own end-of-run result in one line (e.g. the validation scores); empty if none.
    #[serde(default)]
    pub detail: String,
    /// Live graphs: end-to-end latency of each input, from the source's capture to arrival here.
    #[serde(default)]
    pub from_capture: Vec<InputLatency>,
}

/// Latency of one input's frames from capture to arrival, µs.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InputLatency {
    pub input: String,
    pub frames: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f32> = (1..=100).map(|x| x as f32).collect();
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&v, 0.5), 50.0);
        assert_eq!(percentile(&v, 1.0), 100.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert_eq!(percentile(&[], 0.99), 0.0);
    }

    #[test]
    fn summary_mean_and_counts() {
        let mut s = StageStats {
            frames_in: 3,
            ..Default::default()
        };
        for us in [10, 20, 30] {
            s.record_processing(Duration::from_micros(us));
        }
        let sum = s.summary(Duration::from_secs(1));
        assert!((sum.mean_us - 20.0).abs() < 1e-3);
        assert!((sum.max_us - 30.0).abs() < 1e-3);
        assert_eq!(sum.frames_in, 3);
        // 60 µs of work in one second.
        assert!((sum.busy_fraction - 60e-6).abs() < 1e-9);
        assert_eq!(s.summary(Duration::ZERO).busy_fraction, 0.0);
    }

    #[test]
    fn capture_latency_per_input() {
        let mut s = StageStats::default();
        // Captured at 1 s; arrivals 1..=100 µs later on `motion`, 5 ms later on `truth`.
        let capture = 1_000_000_000;
        for us in 1..=100u64 {
            s.record_from_capture("motion", capture, capture + us * 1000);
        }
        s.record_from_capture("truth", capture, capture + 5_000_000);
        s.record_from_capture("truth", 0, capture); // no capture clock: not recorded
        let sum = s.summary(Duration::from_secs(1));
        assert_eq!(sum.from_capture.len(), 2);
        let motion = &sum.from_capture[0];
        assert_eq!((motion.input.as_str(), motion.frames), ("motion", 100));
        assert_eq!(
            (motion.p50_us, motion.p99_us, motion.max_us),
            (50.0, 99.0, 100.0)
        );
        let truth = &sum.from_capture[1];
        assert_eq!((truth.frames, truth.max_us), (1, 5000.0));
    }
}
