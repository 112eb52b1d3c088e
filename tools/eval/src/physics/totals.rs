//! Running totals of one physics method over the test split (sums; the report divides).

use imuflow_body::Pose;
use imuflow_train::data::FPS;
use imuflow_validation::{FallRule, Mode, SimConfig, SimModel, Validator};

/// Accumulated scores of one method: sums over frames (or sequences, where named) that the report
/// turns into means.
#[derive(Default, Clone, Debug)]
pub struct MethodTotals {
    pub frames: usize,
    /// Σ per-sequence jitter × frames, km/s³.
    pub jitter: f64,
    /// Σ per-sequence root jitter × frames, km/s³.
    pub root_jitter: f64,
    /// Σ per-sequence foot skating × frames, m/s.
    pub skating: f64,
    /// Σ per-sequence ground penetration × frames, m.
    pub penetration: f64,
    /// Σ per-sequence cumulative translation error at 2 m, m, over `translation_sequences`.
    pub translation_sum: f64,
    pub translation_sequences: usize,
    pub standing_frames: usize,
    /// Σ (vertical GRF / body weight) over the standing frames.
    pub standing_ratio_sum: f64,
    /// Standing frames whose ratio is within 10 % of 1.
    pub standing_within_10: usize,
    pub fallbacks: usize,
    /// The method's own time, s.
    pub seconds: f64,
    /// `validate`: the simulation's statistics in both modes, summed over sequences.
    pub validation: Option<ValidationTotals>,
}

/// The validation simulation's scores of one motion over the split.
#[derive(Default, Clone, Debug)]
pub struct ValidationTotals {
    pub simulated_s: f64,
    pub falls: u64,
    pub frames: u64,
    pub tracking_sum_m: f64,
    /// Σ residual root force / mg (residual mode).
    pub residual_sum: f64,
    pub skate_sum: f64,
    pub skate_frames: u64,
    /// Frames judged for support, and those violated (the controller-free score).
    pub support_judged: u64,
    pub support_violated: u64,
}

impl ValidationTotals {
    /// Tracks `poses` in both modes, each with a fresh simulation, and adds the statistics.
    pub fn add(&mut self, model: &SimModel, poses: &[Pose]) {
        for mode in [Mode::Torques, Mode::Residual] {
            let config = SimConfig {
                mode,
                ..SimConfig::default()
            };
            let mut v = Validator::new(model.clone(), config, FallRule::default());
            for pose in poses {
                v.frame(Some(pose), 1.0 / f64::from(FPS));
            }
            let st = &v.stats;
            match mode {
                Mode::Torques => {
                    self.simulated_s += st.simulated_s;
                    self.falls += st.falls;
                    self.frames += st.frames;
                    self.tracking_sum_m += st.tracking_errors_m.iter().sum::<f64>();
                    self.skate_sum += st.skate_sum_mps;
                    self.skate_frames += st.skate_frames;
                    self.support_judged += st.support_judged;
                    self.support_violated += st.support_violated();
                }
                Mode::Residual => self.residual_sum += st.residual_fraction_sum,
            }
        }
    }

    /// Falls/min, tracking cm, skate m/s, residual mg and support violated %, as the report's
    /// columns.
    pub(super) fn columns(&self) -> String {
        let n = self.frames.max(1) as f64;
        format!(
            "{:>10.2} {:>10.1} {:>10.3} {:>11.3} {:>10.1}",
            self.falls as f64 / (self.simulated_s / 60.0).max(1e-9),
            100.0 * self.tracking_sum_m / n,
            self.skate_sum / self.skate_frames.max(1) as f64,
            self.residual_sum / n,
            100.0 * self.support_violated as f64 / self.support_judged.max(1) as f64,
        )
    }
}
