//! The publishing side the modes share: both outputs, pacing and progress.

use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_graph::frames::{ImuFrame, MotionFrame, RawImuFrame};
use imuflow_graph::stage::Step;
use imuflow_graph::transport::Output;
use imuflow_graph::{Mode, StageContext};

/// How often (frames) a source reports progress to the launcher.
const PROGRESS_EVERY: u64 = 30;

/// The publishing side shared by the modes: both outputs, pacing and progress.
pub(crate) struct Publisher {
    pub ctx: StageContext,
    pub imu: Output<ImuFrame>,
    pub truth: Output<MotionFrame>,
    pub raw: Output<RawImuFrame>,
    start: Instant,
    /// Live graphs: the Unix-epoch time of `start`, the clock capture times are stamped on.
    live_start_ns: Option<u64>,
    total: u64,
    published: u64,
}

impl Publisher {
    /// Opens both outputs and does the start handshake; `None` when told to stop first (the
    /// outputs are already closed then).
    pub fn start(ctx: StageContext, total: u64) -> anyhow::Result<Option<Self>> {
        let imu = ctx.output::<ImuFrame>("imu")?;
        let truth = ctx.output::<MotionFrame>("truth")?;
        let raw = ctx.output::<RawImuFrame>("raw")?;
        let mut p = Publisher {
            ctx,
            imu,
            truth,
            raw,
            start: Instant::now(),
            live_start_ns: None,
            total,
            published: 0,
        };
        if !p.ctx.ready()? {
            p.finish()?;
            return Ok(None);
        }
        p.start = Instant::now();
        if p.ctx.mode() == Mode::Live {
            p.live_start_ns = Some(imuflow_graph::transport::now_ns());
        }
        Ok(Some(p))
    }

    /// The capture time of a sample due `offset` after the start of the stream: in a live graph
    /// the Unix-epoch instant it is due, as a live sensor's capture time is (every stage then
    /// measures its latency from capture); offline `recorded_ns`, its time in the recording.
    pub fn capture_ns(&self, offset: Duration, recorded_ns: u64) -> u64 {
        match self.live_start_ns {
            Some(start) => start + offset.as_nanos() as u64,
            None => recorded_ns,
        }
    }

    /// Sleeps until `offset` after the start of the stream.
    pub fn pace(&self, offset: Duration) {
        imuflow_graph::wait::sleep_until(self.start + offset);
    }

    /// Publishes one IMU frame: `frame`'s payload with its header's seq, capture time and flags.
    pub fn publish_imu(&mut self, frame: &ImuFrame, started: Instant) -> anyhow::Result<()> {
        // `publish` keeps seq, capture time and flags and stamps publish_ns anew.
        let header = frame.header;
        self.imu
            .publish(header, |f| *f = *frame)
            .with_context(|| format!("publishing imu frame {}", header.seq))?;
        self.count_step(header, started)
    }

    /// Publishes one raw-sample frame (its header's seq, capture time and flags), counted as the
    /// source's step like an IMU frame.
    pub fn publish_raw(&mut self, frame: &RawImuFrame, started: Instant) -> anyhow::Result<()> {
        let header = frame.header;
        self.raw
            .publish(header, |f| *f = *frame)
            .with_context(|| format!("publishing raw frame {}", header.seq))?;
        self.count_step(header, started)
    }

    fn count_step(
        &mut self,
        header: imuflow_graph::frames::FrameHeader,
        started: Instant,
    ) -> anyhow::Result<()> {
        self.ctx.record_source_step(
            Step {
                seq: header.seq,
                capture_ns: header.capture_ns,
                flags: header.flags,
            },
            started.elapsed(),
        );
        self.published += 1;
        if self.published % PROGRESS_EVERY == 1 || self.published == self.total {
            self.ctx.progress(self.published, self.total)?;
        }
        Ok(())
    }

    /// Publishes one truth frame (its header's seq, capture time and flags).
    pub fn publish_truth(&mut self, frame: &MotionFrame) -> anyhow::Result<()> {
        self.truth
            .publish(frame.header, |f| *f = *frame)
            .with_context(|| format!("publishing truth frame {}", frame.header.seq))?;
        Ok(())
    }

    /// END_OF_STREAM on every output and the summary to the launcher.
    pub fn finish(self) -> anyhow::Result<()> {
        let Publisher {
            ctx,
            mut imu,
            mut truth,
            mut raw,
            ..
        } = self;
        ctx.finish(&mut [&mut imu, &mut truth, &mut raw])?;
        Ok(())
    }
}
