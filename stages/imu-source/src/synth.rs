//! Mode `synthesize`: publishes a synthesized motion (imuflow-synth) frame by frame: oriented IMU
//! frames on `imu`, or with `raw` the raw sensor frames on `raw`, and the truth on `truth`.

use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_graph::StageContext;
use imuflow_synth::Motion;
use imuflow_synth::raw::RawSession;

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

/// What to publish next in a raw stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Next {
    /// Raw frame at this index.
    Raw(usize),
    /// Truth frame of this seq.
    Truth(usize),
}

/// The raw frames (capture times `raw_ns`, non-decreasing) and the truth frames (capture times
/// `truth_ns`, increasing) merged in time order; a truth frame goes before a raw frame captured
/// at the same time.
fn interleave(raw_ns: &[u64], truth_ns: &[u64]) -> Vec<Next> {
    let mut order = Vec::with_capacity(raw_ns.len() + truth_ns.len());
    let mut truth = 0;
    for (i, &capture) in raw_ns.iter().enumerate() {
        while truth < truth_ns.len() && truth_ns[truth] <= capture {
            order.push(Next::Truth(truth));
            truth += 1;
        }
        order.push(Next::Raw(i));
    }
    order.extend((truth..truth_ns.len()).map(Next::Truth));
    order
}

/// Publishes the raw frames of `session` on `raw` and the truth of `motion` on `truth`, in time
/// order (paced at their capture times when `realtime`). `imu` carries, with each truth frame, the
/// ideal oriented sensors of the same seq (the `synthesize` mode's frames without raw): what the
/// same motion gives with perfect sensors, so a graph can compare both paths on one input.
pub fn run_raw(
    ctx: StageContext,
    motion: &Motion,
    session: &RawSession,
    realtime: bool,
) -> anyhow::Result<()> {
    let Some(mut out) = Publisher::start(ctx, session.frames.len() as u64)? else {
        return Ok(());
    };
    let raw_ns: Vec<u64> = session.frames.iter().map(|f| f.header.capture_ns).collect();
    let truth_ns: Vec<u64> = (0..motion.len() as u64)
        .map(|seq| motion.capture_ns(seq))
        .collect();
    for next in interleave(&raw_ns, &truth_ns) {
        if out.ctx.should_stop() {
            break;
        }
        let offset = Duration::from_nanos(match next {
            Next::Raw(i) => raw_ns[i],
            Next::Truth(seq) => truth_ns[seq],
        });
        if realtime {
            out.pace(offset);
        }
        let t0 = Instant::now();
        match next {
            Next::Raw(i) => {
                let mut frame = session.frames[i];
                frame.header.capture_ns = out.capture_ns(offset, frame.header.capture_ns);
                out.publish_raw(&frame, t0)?;
            }
            Next::Truth(seq) => {
                let Some(mut truth) = motion.truth_frame(seq) else {
                    break;
                };
                truth.header.capture_ns = out.capture_ns(offset, truth.header.capture_ns);
                out.publish_truth(&truth)?;
                if let Some(mut imu) = motion.imu_frame(seq) {
                    imu.header.capture_ns = truth.header.capture_ns;
                    out.imu
                        .publish(imu.header, |f| *f = imu)
                        .with_context(|| format!("publishing imu frame {seq}"))?;
                }
            }
        }
    }
    out.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truth_goes_out_once_the_raw_stream_reaches_its_time() {
        // Truth at 0, 10, 20, 30; raw frames around them, one at exactly 20.
        let order = interleave(&[3, 9, 12, 20, 20, 25], &[0, 10, 20, 30]);
        use Next::{Raw, Truth};
        assert_eq!(
            order,
            [
                Truth(0),
                Raw(0),
                Raw(1),
                Truth(1),
                Raw(2),
                Truth(2),
                Raw(3),
                Raw(4),
                Raw(5),
                Truth(3)
            ]
        );
        // Every frame once, in capture order.
        assert_eq!(interleave(&[], &[0, 5]), [Truth(0), Truth(1)]);
        assert_eq!(interleave(&[1, 2], &[]), [Raw(0), Raw(1)]);
    }
}
