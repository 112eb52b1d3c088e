//! Mode `slimevr`: live SlimeVR trackers over UDP. The stage plays the SlimeVR server's part of
//! the protocol ([`packets`]): it answers the handshake of every tracker the `trackers` file maps
//! ([`mapping`]), keeps them streaming with heartbeats, acknowledges their sensor info and
//! feature-flags packets, and publishes each sensor's samples as `RawImuFrame`s on `raw`.
//!
//! # What a frame carries
//!
//! A sample is a sensor's rotation and acceleration packets of one fusion update (the firmware
//! sends them back to back): it sets its site's bit in `orientation_mask` and `valid_mask`. A
//! rotation whose acceleration does not follow within [`receiver::PAIR_WAIT`] is a sample alone
//! (orientation bit only); an acceleration on its own (older firmware sends one when the rotation
//! did not change) is one with the valid bit only. The stage reads every datagram the socket holds
//! and publishes their samples at once, nothing waiting for more: samples read together share a
//! frame ([`Assembler`]; a tick of six trackers usually does); a frame never holds two samples of
//! one site.
//!
//! Sources: SlimeVR/SlimeVR-Tracker-ESP `src/sensors/sensor.cpp` (`setFusedRotation`,
//! `setAcceleration`, `sendData`), `src/sensors/SensorFusion.cpp` (`calcGravityVec`,
//! `calcLinearAcc`), `src/sensors/softfusion/softfusionsensor.h` (units, send rate),
//! `src/consts.h` (`CONST_EARTH_GRAVITY`); SlimeVR/SlimeVR-Server
//! `server/core/src/main/java/dev/slimevr/tracking/trackers/udp/TrackersUDPServer.kt`
//! (`AXES_OFFSET`). In the firmware's terms the frame's `R_IS` is `R_IT`:
//!
//! - `orientation_wxyz`: the on-board fused orientation as received, reordered from the
//!   firmware's x, y, z, w to w, x, y, z: `R_IT`, tracker frame T to the tracker's own inertial
//!   frame I. I is z-up (x, y horizontal; the SlimeVR server turns it into its y-up frame with
//!   a −90° rotation about x, `AXES_OFFSET`), so the calibration stage's `frame` is `z-up`. Its
//!   heading is arbitrary and differs from tracker to tracker (6-axis fusion has no north),
//!   which walking calibration's per-sensor heading corrections absorb. T is the IMU chip's
//!   frame turned by the board's mounting rotation (`setFusedRotation`: `r · sensorOffset`).
//! - `accelerometer_mps2`: specific force in T, `f = a + g·R_ITᵀ·e_z`
//!   ([`receiver::specific_force`]), from the packet's linear acceleration a (m/s², gravity
//!   removed by the firmware with its own orientation and g = 9.80665 m/s²) and the same sample's
//!   rotation. Approximations: BNO08x chips remove gravity with their internal estimate, which
//!   the game rotation vector sent matches only to the chip's precision; and the firmware turns
//!   the acceleration by the mounting rotation (`sensorOffset.sandwich`) where the orientation
//!   gets its inverse, so on boards mounted at 90° or 270° the acceleration arrives turned 180°
//!   about z (x and y negated; 0° and 180° agree); older firmware sends it in the chip frame.
//! - `gyroscope_radps`: zero, with the site's bit in `no_gyroscope_mask`: the protocol carries no
//!   angular rate (only the firmware's inspection packets, which release builds do not send), so
//!   the fusion stage derives it from consecutive orientations.
//! - `sample_time_ns`: when the tracker sent the sample's first packet, on the host clock (Unix
//!   epoch ns), from its packet number and the pace of the numbers ([`clock::PacketClock`]):
//!   tracker packets carry no sample time, and a backlog delivered at once after a stall must not
//!   look simultaneous. `header.capture_ns`: the earliest arrival among the frame's
//!   samples.
//! - `seq`: frame counter from 0.
//!
//! A rotation that is not finite or whose norm is not within 0.9–1.1, or a specific force that is
//! not finite, leaves its bit clear and flags the frame INVALID.

pub mod clock;
pub mod mapping;
pub mod packets;
pub mod receiver;
pub mod sim;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_graph::StageContext;
use imuflow_graph::frames::{RawImuFrame, flags};

use crate::publisher::Publisher;
use mapping::Mapping;
use receiver::{Receiver, Sample, specific_force};

/// Default address the `slimevr` mode listens on: every interface, the SlimeVR server's port
/// (trackers broadcast their handshake there).
pub const DEFAULT_BIND: &str = "0.0.0.0:6969";

/// Settings of the slimevr mode.
#[derive(Debug, Clone)]
pub struct Options {
    pub bind: String,
    /// The trackers file.
    pub trackers: PathBuf,
    /// End of stream after this long without a packet from a mapped tracker.
    pub timeout: Duration,
    /// End after this many frames (0: no limit).
    pub frames: u64,
}

/// How long one wait for a datagram lasts at most (the stop flag is checked in between).
const POLL: Duration = Duration::from_millis(20);

/// Receives from the trackers of the sites of `sites` (the graph's sensor set) and publishes
/// their samples until timeout, `frames` or stop.
pub fn run(
    ctx: StageContext,
    options: &Options,
    sites: imuflow_body::SiteMask,
) -> anyhow::Result<()> {
    let mut mapping = Mapping::load(&options.trackers)?;
    let left_out = mapping.keep_only(sites);
    if !left_out.is_empty() {
        tracing::info!(
            "the trackers on {} are left out: not sites of the graph's sensor set",
            left_out.join(", ")
        );
    }
    let missing = mapping.missing_sites(sites);
    if !missing.is_empty() {
        tracing::warn!(
            "the trackers file maps nothing to {}: those sites get no samples",
            missing.join(", ")
        );
    }
    let mut receiver = Receiver::bind(&options.bind, mapping)
        .with_context(|| format!("cannot bind UDP socket to '{}'", options.bind))?;
    let Some(out) = Publisher::start(ctx, options.frames)? else {
        return Ok(());
    };
    let mut out = Frames {
        out,
        assembler: Assembler::default(),
        seq: 0,
        limit: options.frames,
    };
    let mut samples = Vec::new();
    let mut last_heard = Instant::now();
    while !out.out.ctx.should_stop() && !out.full() {
        // Everything that arrived is published at once: the datagrams the socket holds are read
        // together, so a tick of six trackers usually shares a frame, and nothing waits for more.
        if receiver
            .poll(POLL, &mut samples)
            .context("receiving from the trackers")?
        {
            last_heard = Instant::now();
        } else if last_heard.elapsed() >= options.timeout {
            tracing::info!("no tracker packet for {:?}: end of stream", options.timeout);
            break;
        }
        out.add(&mut samples)?;
        out.flush()?;
    }
    receiver.flush_all(&mut samples);
    out.add(&mut samples)?;
    out.flush()?;
    let summary = report(&receiver);
    out.out.ctx.set_summary_detail(summary);
    out.out.finish()
}

/// The publishing end: samples into frames, frames numbered and published up to the limit.
struct Frames {
    out: Publisher,
    assembler: Assembler,
    seq: u64,
    /// `frames` (0: no limit).
    limit: u64,
}

impl Frames {
    fn full(&self) -> bool {
        self.limit > 0 && self.seq >= self.limit
    }

    /// Adds the samples (drained) and publishes every frame they complete.
    fn add(&mut self, samples: &mut Vec<Sample>) -> anyhow::Result<()> {
        for sample in samples.drain(..) {
            if let Some(done) = self.assembler.push(&sample) {
                self.publish(done)?;
            }
        }
        Ok(())
    }

    /// Publishes the frame still collecting, if any.
    fn flush(&mut self) -> anyhow::Result<()> {
        match self.assembler.take() {
            Some(done) => self.publish(done),
            None => Ok(()),
        }
    }

    fn publish(&mut self, mut frame: RawImuFrame) -> anyhow::Result<()> {
        if self.full() {
            return Ok(());
        }
        let started = Instant::now();
        frame.header.seq = self.seq;
        self.out.publish_raw(&frame, started)?;
        self.seq += 1;
        Ok(())
    }
}

/// Collects the samples read together into frames: samples of different sites share one; a
/// second sample of a site already in it closes it. The frame's `capture_ns` is the earliest
/// arrival among its samples (a rotation that waited for its acceleration may join after a later
/// sample started the frame); `seq` is left to the publisher.
#[derive(Debug, Default)]
pub struct Assembler {
    current: Option<RawImuFrame>,
}

impl Assembler {
    /// Adds a sample; the frame it closed, if any.
    pub fn push(&mut self, sample: &Sample) -> Option<RawImuFrame> {
        // Every sample sets its site's sample time (never 0).
        let closed = match &self.current {
            Some(f) if f.sample_time_ns[sample.site] != 0 => self.take(),
            _ => None,
        };
        let frame = self.current.get_or_insert_with(|| {
            let mut f = RawImuFrame::default();
            f.header.capture_ns = sample.received_ns;
            f
        });
        frame.header.capture_ns = frame.header.capture_ns.min(sample.received_ns);
        if !fill(frame, sample) {
            frame.header.flags |= flags::INVALID;
        }
        closed
    }

    /// The frame collecting now.
    pub fn take(&mut self) -> Option<RawImuFrame> {
        self.current.take()
    }
}

/// Writes one sample into its site's slots (see the module docs); false when a value it brought
/// was not usable (its bit stays clear).
pub fn fill(f: &mut RawImuFrame, sample: &Sample) -> bool {
    let (i, bit) = (sample.site, 1u32 << sample.site);
    let mut usable = true;
    f.sample_time_ns[i] = sample.sent_ns;
    if let Some([x, y, z, w]) = sample.rotation_xyzw {
        let norm = (w * w + x * x + y * y + z * z).sqrt();
        if norm.is_finite() && (0.9..=1.1).contains(&norm) {
            f.orientation_wxyz[i] = [w, x, y, z];
            f.orientation_mask |= bit;
        } else {
            usable = false;
        }
    }
    if let Some((linear, rotation)) = sample.acceleration {
        match specific_force(linear, rotation) {
            Some(force) => {
                f.accelerometer_mps2[i] = force;
                f.valid_mask |= bit;
                f.no_gyroscope_mask |= bit;
            }
            None => usable = false,
        }
    }
    usable
}

/// Logs each tracker's counts and returns the one-line summary for the run.
fn report(receiver: &Receiver) -> String {
    let mut total = receiver::TrackerStats::default();
    let mut trackers = 0;
    for (mac, s) in receiver.tracker_stats() {
        trackers += 1;
        let line = format!(
            "tracker {mac}: {} packets, {} samples, {} lost, {} duplicated, {} out of order, \
             {} of unknown type, {} malformed, {} connection(s) (lost: packet numbers never \
             received; duplicated and out-of-order datagrams discarded)",
            s.packets,
            s.samples,
            s.lost,
            s.duplicated,
            s.out_of_order,
            s.unknown_types,
            s.malformed,
            s.handshakes
        );
        if s.lost + s.duplicated + s.out_of_order + s.unknown_types + s.malformed > 0 {
            tracing::warn!("{line}");
        } else {
            tracing::info!("{line}");
        }
        total.packets += s.packets;
        total.samples += s.samples;
        total.lost += s.lost;
        total.duplicated += s.duplicated;
        total.out_of_order += s.out_of_order;
        total.unknown_types += s.unknown_types;
    }
    format!(
        "{trackers} tracker(s): {} packets, {} samples, {} lost, {} duplicated, {} out of order, \
         {} of unknown type; {} ignored from unconnected or unmapped trackers",
        total.packets,
        total.samples,
        total.lost,
        total.duplicated,
        total.out_of_order,
        total.unknown_types,
        receiver.other_stats().ignored
    )
}

#[cfg(test)]
mod tests;
