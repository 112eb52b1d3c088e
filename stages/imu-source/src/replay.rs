//! Mode `replay`: the frames of a recorder's mcap file (read by imuflow-recording), published
//! again in file order. Frames keep their recorded `seq`, `capture_ns` and flags; `publish_ns` is
//! stamped anew.

use std::time::{Duration, Instant};

use imuflow_body::SiteMask;
use imuflow_graph::StageContext;
use imuflow_recording::{Recorded, Recording};

use crate::publisher::Publisher;

/// The sites any of `recording`'s IMU frames holds a valid sample of.
pub fn sites_held(recording: &Recording) -> SiteMask {
    SiteMask(recording.frames.iter().fold(0, |mask, f| match f {
        Recorded::Imu(f) => mask | f.valid_mask,
        Recorded::Truth(_) => mask,
    }))
}

/// Publishes the recording (paced by the recorded capture times when `realtime`).
/// Replays `recording`; `limit` > 0 ends the stream after that many IMU frames.
pub fn run(
    ctx: StageContext,
    recording: &Recording,
    realtime: bool,
    limit: u64,
) -> anyhow::Result<()> {
    if let Some(t) = &recording.truth_topic {
        tracing::debug!(imu = %recording.imu_topic, truth = %t, "replaying");
    }
    let total = match limit {
        0 => recording.imu_frames,
        n => n.min(recording.imu_frames),
    };
    // The last seq replayed: that of the `total`-th IMU frame (its truth may come before or after it).
    let last_seq = (total < recording.imu_frames)
        .then(|| {
            recording
                .frames
                .iter()
                .filter_map(|f| match f {
                    Recorded::Imu(f) => Some(f.header.seq),
                    Recorded::Truth(_) => None,
                })
                .nth((total as usize).saturating_sub(1))
        })
        .flatten();
    let Some(mut out) = Publisher::start(ctx, total)? else {
        return Ok(());
    };
    let first_capture = recording.frames.iter().find_map(|f| match f {
        Recorded::Imu(f) => Some(f.header.capture_ns),
        Recorded::Truth(_) => None,
    });
    for frame in &recording.frames {
        if out.ctx.should_stop() {
            break;
        }
        let header = frame.header();
        if last_seq.is_some_and(|last| header.seq > last) {
            continue;
        }
        // Truth frames are paced like their IMU frame (the same capture time), so that truth and
        // estimate of one sample leave together instead of the truth a frame early.
        let offset =
            Duration::from_nanos(header.capture_ns.saturating_sub(first_capture.unwrap_or(0)));
        if realtime && first_capture.is_some() {
            out.pace(offset);
        }
        let capture_ns = out.capture_ns(offset, header.capture_ns);
        match frame {
            Recorded::Imu(f) => {
                let mut f = **f;
                f.header.capture_ns = capture_ns;
                out.publish_imu(&f, Instant::now())?
            }
            Recorded::Truth(f) => {
                let mut f = **f;
                f.header.capture_ns = capture_ns;
                out.publish_truth(&f)?
            }
        }
    }
    out.finish()
}
