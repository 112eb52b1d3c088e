//! A recorded validation stream (`ValidationFrame`s of the validation stage) summed up.
//!
//! The numbers are the stage's own ([`imuflow_validation::Stats`], what its summary line prints):
//! the recorded frames are folded back into a `Stats` and its methods give the means and
//! percentiles, so a recording and a live run are summarized by the same code.

use imuflow_body::JointId;
use imuflow_graph::frames::ValidationFrame;
use imuflow_validation::{Stats, Support, SupportState};
use serde::Serialize;

use super::pairing::is_scored;

/// Standard gravity, m/s², as the validation stage divides the residual force by (m·g).
const GRAVITY_MPS2: f64 = 9.81;

/// Validation scores of one recorded stream (frames the stage flagged, see
/// [`super::SKIPPED_FLAGS`], left out).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ValidationScores {
    /// Frames summarized.
    pub frames: u64,
    /// Frames left out (flagged INVALID, CALIBRATING or END_OF_STREAM).
    pub skipped: usize,
    /// Simulated time, s: summarized frames / rate.
    pub simulated_s: f64,
    /// Frames on which the simulated body lost its balance.
    pub falls: u64,
    pub falls_per_minute: f64,
    /// Re-anchors after drifting away without falling (increase of the stream's counter).
    pub resyncs: u64,
    /// Mean distance between simulated and estimated joints, m.
    pub tracking_error_mean_m: f64,
    /// Its 95th percentile over frames, m.
    pub tracking_error_p95_m: f64,
    /// The same with both roots removed, m.
    pub pose_error_mean_m: f64,
    /// Mean distance between the simulated and estimated roots, m.
    pub root_error_mean_m: f64,
    /// Mean horizontal speed of the simulated feet in floor contact, m/s (over frames with a foot
    /// in contact).
    pub foot_skate_mean_mps: f64,
    /// Mean and deepest penetration of the simulated body into the floor, m.
    pub penetration_mean_m: f64,
    pub penetration_max_m: f64,
    /// Mean residual root force / (m·g): how much help the root needed (0 in torques mode).
    pub residual_force_mean_fraction: f64,
    /// Share of the frames judged for support whose needed centre of pressure lies outside the
    /// feet or that no floor could carry (the controller-free score, `imuflow_validation::support`).
    pub support_violated_fraction: f64,
}

/// A recorded frame's support score, as the stage wrote it.
fn support_of(f: &ValidationFrame) -> Support {
    Support {
        state: SupportState::from_wire(f.support),
        gap_m: f64::from(f.support_gap_m),
        ..Support::default()
    }
}

/// The validation stage's run statistics rebuilt from its recorded frames, at `rate_hz`, for a
/// subject of `mass_kg` (the stage's `mass_kg` parameter; it scales the residual force). Step times
/// are not recorded, so `step_us` stays empty.
pub fn validation_stats(frames: &[ValidationFrame], rate_hz: f64, mass_kg: f64) -> Stats {
    let weight_n = mass_kg * GRAVITY_MPS2;
    let feet = (1u32 << JointId::LEFT_FOOT.index()) | (1u32 << JointId::RIGHT_FOOT.index());
    let mut stats = Stats::default();
    let mut previous_resyncs: Option<u32> = None;
    for f in frames.iter().filter(|f| is_scored(&f.header)) {
        stats.frames += 1;
        stats.falls += u64::from(f.balance_lost != 0);
        // The counter runs from the start of the stream; only what happens between summarized
        // frames counts.
        if let Some(previous) = previous_resyncs {
            stats.resyncs += u64::from(f.resyncs.saturating_sub(previous));
        }
        previous_resyncs = Some(f.resyncs);
        stats.tracking_errors_m.push(f64::from(f.tracking_error_m));
        stats.pose_error_sum_m += f64::from(f.pose_error_m);
        stats.root_error_sum_m += f64::from(f.root_error_m);
        let residual = f.residual_root_force_n.map(f64::from);
        let residual_n = residual.iter().map(|c| c * c).sum::<f64>().sqrt();
        if weight_n > 0.0 {
            stats.residual_fraction_sum += residual_n / weight_n;
        }
        // The stage writes 0 skate when no foot touches; its contact mask tells a standing foot
        // that does not slide from no contact at all.
        if f.sim_contact_mask & feet != 0 {
            stats.skate_sum_mps += f64::from(f.foot_skate_mps);
            stats.skate_frames += 1;
        }
        stats.add_support(&support_of(f));
        let penetration = f64::from(f.penetration_m);
        stats.penetration_sum_m += penetration;
        stats.penetration_max_m = stats.penetration_max_m.max(penetration);
    }
    if rate_hz.is_finite() && rate_hz > 0.0 {
        stats.simulated_s = stats.frames as f64 / rate_hz;
    }
    stats
}

/// Falls per minute, tracking error (mean, p95), foot skate and residual root force / mg of a
/// recorded validation stream; see [`validation_stats`] for the arguments.
pub fn summarize_validation(
    frames: &[ValidationFrame],
    rate_hz: f64,
    mass_kg: f64,
) -> ValidationScores {
    let stats = validation_stats(frames, rate_hz, mass_kg);
    ValidationScores {
        frames: stats.frames,
        skipped: frames.len() - stats.frames as usize,
        simulated_s: stats.simulated_s,
        falls: stats.falls,
        falls_per_minute: stats.falls_per_minute(),
        resyncs: stats.resyncs,
        tracking_error_mean_m: stats.tracking_error_mean_m(),
        tracking_error_p95_m: stats.tracking_error_p95_m(),
        pose_error_mean_m: stats.pose_error_mean_m(),
        root_error_mean_m: stats.root_error_mean_m(),
        foot_skate_mean_mps: stats.foot_skate_mean_mps(),
        penetration_mean_m: stats.penetration_mean_m(),
        penetration_max_m: stats.penetration_max_m,
        residual_force_mean_fraction: stats.residual_force_mean_fraction(),
        support_violated_fraction: stats.support_violated_fraction(),
    }
}
