//! Mode `file`: a recorded session read by imuflow-sensor-files (CSV/TSV exports described by a
//! layout TOML, or Xsens MVNX). Publishes its raw samples on `raw` in capture order, keeping the
//! recording's `seq` and capture times (the shared clock that starts at 0 with the first sample);
//! the fusion stage turns them into IMU frames at the graph's rate. A recording with a truth
//! (MVNX) also publishes it on `truth`, resampled to the graph's rate: frame k at k/rate_hz with
//! seq k, as the fusion stage numbers its output, so scores align truth and estimate by seq.

use std::time::{Duration, Instant};

use imuflow_body::SensorSet;
use imuflow_graph::StageContext;
use imuflow_graph::frames::MotionFrame;
use imuflow_sensor_files::{SensorRecording, resample_truth};

use crate::publisher::Publisher;

/// Refuses a recording without samples of some of the graph's set's sites (a layout that leaves
/// sites out, a lower-body recording in a six-site graph): the estimators need every site of
/// their set, and a site that never delivers would only show up later as INVALID frames or a
/// calibration that waits forever.
pub fn check_sites(recording: &SensorRecording, set: &SensorSet) -> anyhow::Result<()> {
    let missing: Vec<&str> = set
        .sites()
        .filter(|s| recording.counts[s.index()].samples == 0)
        .map(|s| s.name())
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    anyhow::bail!(
        "no samples of {}: the graph's sensor set {set} needs every one of its sites; for a recording of fewer sensors the graph names a set of fewer sites (`sensors`: lower-body, a set file)",
        missing.join(", "),
    )
}

/// Publishes `recording` (paced by its capture times when `realtime`); `limit` > 0 ends the
/// stream after that many raw frames (and the truth with it).
pub fn run(
    ctx: StageContext,
    recording: &SensorRecording,
    realtime: bool,
    limit: u64,
) -> anyhow::Result<()> {
    let total = match limit {
        0 => recording.frames.len(),
        n => recording.frames.len().min(n as usize),
    };
    let frames = &recording.frames[..total];
    let until = frames.last().map(|f| f.header.capture_ns);
    let truth: Vec<MotionFrame> = match (&recording.truth, until) {
        (Some(t), Some(until)) => resample_truth(t, ctx.graph().rate_hz, Some(until)),
        _ => Vec::new(),
    };
    tracing::info!(
        source = %recording.source.display(),
        raw_frames = total,
        truth_frames = truth.len(),
        "{}",
        recording.summary()
    );
    let Some(mut out) = Publisher::start(ctx, total as u64)? else {
        return Ok(());
    };
    out.ctx.set_summary_detail(recording.summary());
    let mut truth = truth.iter().peekable();
    for frame in frames {
        if out.ctx.should_stop() {
            break;
        }
        // Truth frames due by this sample leave first, paced like it: the estimate of a truth
        // frame comes from samples up to its time.
        while let Some(t) = truth.next_if(|t| t.header.capture_ns <= frame.header.capture_ns) {
            let offset = Duration::from_nanos(t.header.capture_ns);
            if realtime {
                out.pace(offset);
            }
            let mut t = *t;
            t.header.capture_ns = out.capture_ns(offset, t.header.capture_ns);
            out.publish_truth(&t)?;
        }
        let offset = Duration::from_nanos(frame.header.capture_ns);
        if realtime {
            out.pace(offset);
        }
        let started = Instant::now();
        let mut f = *frame;
        f.header.capture_ns = out.capture_ns(offset, f.header.capture_ns);
        out.publish_raw(&f, started)?;
    }
    out.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recording_without_some_sites_is_refused_naming_them() {
        let mut r = SensorRecording::default();
        for (i, c) in r.counts.iter_mut().enumerate() {
            // Lower body only: the legs (2, 3) and the pelvis (5).
            c.samples = if [2, 3, 5].contains(&i) { 10 } else { 0 };
        }
        let six = SensorSet::six();
        let e = check_sites(&r, &six).unwrap_err().to_string();
        assert!(
            e.contains("no samples of left_forearm, right_forearm, head:")
                && e.contains("set six (left_forearm, right_forearm"),
            "{e}"
        );
        // The thighs (6, 7) too: a lower-body set's recording.
        r.counts[6].samples = 10;
        r.counts[7].samples = 10;
        check_sites(&r, &SensorSet::builtin("lower-body").unwrap()).unwrap();
        for c in r.counts.iter_mut() {
            c.samples = 10;
        }
        check_sites(&r, &six).unwrap();
    }
}
