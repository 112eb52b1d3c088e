//! Mode `synthesize`: publishes a synthesized motion (imuflow-synth) frame by frame.

use std::time::{Duration, Instant};

use imuflow_graph::StageContext;
use imuflow_synth::Motion;

use crate::publisher::Publisher;

/// Publishes every frame of `motion` (paced at its rate when `realtime`).
pub fn run(ctx: StageContext, motion: &Motion, realtime: bool) -> anyhow::Result<()> {
    let total = motion.len();
    let Some(mut out) = Publisher::start(ctx, total as u64)? else {
        return Ok(());
    };
    let period = Duration::from_secs_f64(1.0 / motion.rate_hz);
    for seq in 0..total {
        if out.ctx.should_stop() {
            break;
        }
        let offset = period.mul_f64(seq as f64);
        if realtime {
            out.pace(offset);
        }
        let t0 = Instant::now();
        let (Some(mut imu), Some(mut truth)) = (motion.imu_frame(seq), motion.truth_frame(seq))
        else {
            break;
        };
        let capture_ns = out.capture_ns(offset, imu.header.capture_ns);
        imu.header.capture_ns = capture_ns;
        truth.header.capture_ns = capture_ns;
        out.publish_truth(&truth)?;
        out.publish_imu(&imu, t0)?;
    }
    out.finish()
}
