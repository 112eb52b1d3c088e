//! The output grid: raw frames in, one `ImuFrame` per output period out, in order, none skipped.
//!
//! Output frame k stands for source time `t_k = origin + k / rate_hz` (origin 0 offline, the first
//! raw frame's capture time live) and carries `seq = k`, `capture_ns = t_k`. With
//! [`Latency::Smooth`] it is emitted as soon as every sensor can be resampled at `t_k` (it has a
//! sample stamped at or after `t_k` plus its low-pass delay plus half its sample interval), or once
//! a raw frame captured more than `max_latency` after `t_k` arrived; with [`Latency::Low`] as soon
//! as a sample from half an interval before `t_k` on has come (`Assembler::low_latency_due`).
//! The sensors that cannot be resampled then are written as identity / zeros with their bit
//! cleared and the frame is flagged INVALID.

use imuflow_body::{Imu, SiteMask};
use imuflow_graph::frames::{ImuFrame, MAX_SITES, RawImuFrame, flags};

use crate::quat::IDENTITY;
use crate::sensor::{
    Latency, RawSample, STALE_INTERVALS, SensorCounters, SensorSettings, SensorTrack,
    WAIT_INTERVALS,
};
use crate::{FusionError, sensor_name};

/// Offline, a first capture time later than this is not "near 0": the grid starts there instead
/// of emitting this long a run of empty frames first, s.
pub const MAX_ZERO_ORIGIN_S: f64 = 60.0;
/// A raw frame captured this much after the newest one so far is refused (a corrupt timestamp
/// would otherwise make the stage emit empty frames for years), s.
pub const MAX_CAPTURE_JUMP_S: f64 = 3600.0;
/// ([`Latency::Low`]) A frame is due once a sensor's newest sample lies this share of its interval
/// before the frame's time or later.
pub const LEAD_INTERVALS: f64 = 0.5;
/// ([`Latency::Low`]) ... and never before a raw frame captured this close to its time, ns (a
/// sensor clock mapped ahead of the arrivals does not release frames early).
const MAX_LEAD_NS: i128 = 20_000_000;
/// ([`Latency::Low`]) A sensor silent longer than this before a frame is not waited for, s (a
/// stall whose backlog is on its way lasts up to about 100 ms).
const MAX_WAITED_SILENCE_S: f64 = 0.15;
/// ([`Latency::Low`]) How long, in arrivals, a frame waits for a sensor that is behind it, s.
pub const STALE_GRACE_S: f64 = 0.005;
/// A sensor that has never been usable this long after another one was is reported missing, s.
const NEVER_SEEN_S: f64 = 1.0;

/// Where output frame 0 lies on the source clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// Offline: source time 0, so that output seq k is the source's frame k (the synthesizing
    /// source numbers its truth frames so).
    Zero,
    /// Live: the first raw frame's capture time.
    FirstCapture,
}

/// The whole stage's configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub sensor: SensorSettings,
    /// A frame waits for late sensors at most this long after its time, s.
    pub max_latency_s: f64,
    pub origin: Origin,
    /// The sites fused: the graph's sensor set's. A raw sample of another slot is ignored (and
    /// said once); a frame missing one of these is INVALID.
    pub sites: SiteMask,
}

/// Something worth a log line.
#[derive(Clone, Debug, PartialEq)]
pub struct Notice {
    pub warning: bool,
    pub text: String,
}

/// Output counts besides the sensors' own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameCounters {
    /// Output frames emitted.
    pub frames: u64,
    /// Output frames flagged INVALID.
    pub invalid: u64,
    /// Per sensor: output frames where it could not be resampled.
    pub sensor_invalid: [u64; MAX_SITES],
    /// Output frames flagged DEGRADED (a sensor was stale in them).
    pub degraded: u64,
    /// Per sensor ([`Latency::Smooth`]): output frames emitted at their latency deadline before
    /// the samples describing its specific force and angular rate had come (extrapolated from
    /// the newest two).
    pub sensor_held: [u64; MAX_SITES],
    /// Per sensor ([`Latency::Low`]): output frames in which its newest sample was more than
    /// [`STALE_INTERVALS`] intervals old (extrapolated one interval, then held; flagged DEGRADED).
    pub sensor_stale: [u64; MAX_SITES],
    /// Per sensor: samples that arrived after a frame more than one sample interval after their
    /// time had been built (that frame had to do without them).
    pub sensor_late: [u64; MAX_SITES],
    /// Raw frames refused for a capture time more than [`MAX_CAPTURE_JUMP_S`] ahead.
    pub refused_raw: u64,
}

/// Per sensor: whether it was usable in the last frame, and whether its going missing was logged.
#[derive(Clone, Copy, Debug, Default)]
struct Presence {
    ever: bool,
    now: bool,
    warned: bool,
    return_logged: bool,
    missing_since: Option<u64>,
}

pub struct Assembler {
    settings: Settings,
    rate_hz: f64,
    /// One track per wire slot; only [`Assembler::slots`]' are fed and read.
    sensors: Vec<SensorTrack>,
    /// The slots of `settings.sites`, in order.
    slots: Vec<usize>,
    /// Slots outside the set whose samples were ignored (each said once).
    ignored: SiteMask,
    origin_ns: Option<i128>,
    next_k: u64,
    /// The time of the newest frame emitted.
    last_emitted: Option<i128>,
    /// ([`Latency::Low`]) The frame waiting for a stale sensor, and the capture time it began
    /// waiting at.
    waiting_since: Option<(u64, i128)>,
    newest_capture: Option<i128>,
    /// The latest source time a raw frame flagged PRELUDE vouches for (see `mark_prelude`).
    prelude_until: Option<i128>,
    presence: [Presence; MAX_SITES],
    first_usable_ns: Option<i128>,
    /// Flushing at the end of the stream.
    finishing: bool,
    counters: FrameCounters,
    notices: Vec<Notice>,
}

impl Assembler {
    /// An assembler for the output rate `settings.sensor.output_rate_hz` (> 0).
    pub fn new(settings: Settings) -> Assembler {
        Assembler {
            rate_hz: settings.sensor.output_rate_hz,
            sensors: (0..MAX_SITES)
                .map(|i| SensorTrack::new(i, settings.sensor))
                .collect(),
            slots: settings.sites.sites().map(Imu::index).collect(),
            ignored: SiteMask::default(),
            settings,
            origin_ns: None,
            next_k: 0,
            last_emitted: None,
            waiting_since: None,
            newest_capture: None,
            prelude_until: None,
            presence: [Presence::default(); MAX_SITES],
            first_usable_ns: None,
            finishing: false,
            counters: FrameCounters::default(),
            notices: Vec::new(),
        }
    }

    pub fn counters(&self) -> &FrameCounters {
        &self.counters
    }

    /// The wire slots fused (the graph's set's sites), in order.
    pub fn slots(&self) -> &[usize] {
        &self.slots
    }

    /// The tracks of the fused slots.
    fn fused(&self) -> impl Iterator<Item = &SensorTrack> {
        self.slots.iter().map(|&i| &self.sensors[i])
    }

    pub fn sensor(&self, i: usize) -> &SensorTrack {
        &self.sensors[i]
    }

    pub fn sensor_counters(&self, i: usize) -> &SensorCounters {
        self.sensors[i].counters()
    }

    /// The log lines gathered since the last call.
    pub fn take_notices(&mut self) -> Vec<Notice> {
        for &i in &self.slots {
            let s = &mut self.sensors[i];
            self.notices
                .extend(s.take_notices().into_iter().map(|text| Notice {
                    warning: text.contains("jumped") || text.contains("implausible"),
                    text,
                }));
        }
        std::mem::take(&mut self.notices)
    }

    /// The source time of output frame `k`, ns.
    pub fn time_of(&self, k: u64) -> Option<i128> {
        let origin = self.origin_ns?;
        Some(origin + (k as f64 * 1e9 / self.rate_hz).round() as i128)
    }

    /// Takes one raw frame; the output frames it completes go to `out`.
    pub fn push(&mut self, raw: &RawImuFrame, out: &mut Vec<ImuFrame>) -> Result<(), FusionError> {
        let capture = i128::from(raw.header.capture_ns);
        if let Some(newest) = self.newest_capture
            && capture - newest > (MAX_CAPTURE_JUMP_S * 1e9) as i128
        {
            self.counters.refused_raw += 1;
            self.notices.push(Notice {
                warning: true,
                text: format!(
                    "raw frame {} refused: captured {:.0} s after the newest one",
                    raw.header.seq,
                    (capture - newest) as f64 * 1e-9
                ),
            });
            return Ok(());
        }
        self.start_grid(capture);
        self.newest_capture = Some(self.newest_capture.map_or(capture, |n| n.max(capture)));
        let mut earliest = None::<i128>;
        for (i, sample) in samples(raw) {
            if !self.settings.sites.contains_slot(i) {
                if !self.ignored.contains_slot(i) {
                    self.ignored = SiteMask(self.ignored.0 | 1 << i);
                    self.notices.push(Notice {
                        warning: true,
                        text: format!(
                            "raw frame {} carries a {} sample, a site outside the graph's sensor set \
                             ({}): its samples are ignored",
                            raw.header.seq,
                            sensor_name(i),
                            self.settings.sites.names()
                        ),
                    });
                }
                continue;
            }
            self.sensors[i].push(sample)?;
            if let Some(t) = self.sensors[i].source_ns_of(sample.sample_ns) {
                earliest = Some(earliest.map_or(t, |e| e.min(t)));
                let interval = self.sensors[i].period_s().unwrap_or(0.0);
                if self
                    .last_emitted
                    .is_some_and(|e| e as f64 > t as f64 + interval * 1e9)
                {
                    self.counters.sensor_late[i] += 1;
                }
            }
        }
        if raw.header.has(flags::PRELUDE) {
            self.mark_prelude(earliest.unwrap_or(capture));
        }
        self.emit_ready(out);
        Ok(())
    }

    /// At the end of the stream: every frame up to the newest sample of any sensor.
    pub fn finish(&mut self, out: &mut Vec<ImuFrame>) -> Result<(), FusionError> {
        for &i in &self.slots {
            self.sensors[i].finish()?;
        }
        self.emit_ready(out);
        // The sensors' last samples lie a few milliseconds apart: the flush flags the ones that
        // ended first without calling them missing.
        self.finishing = true;
        let end = self.fused().filter_map(|s| s.newest_ns()).max();
        while let (Some(t), Some(end)) = (self.time_of(self.next_k), end)
            && t <= end
        {
            self.emit(t, out);
        }
        Ok(())
    }

    fn start_grid(&mut self, capture: i128) {
        if self.origin_ns.is_some() {
            return;
        }
        let far = capture as f64 * 1e-9 > MAX_ZERO_ORIGIN_S;
        self.origin_ns = Some(match self.settings.origin {
            Origin::Zero if !far => 0,
            Origin::Zero => {
                self.notices.push(Notice {
                    warning: false,
                    text: format!(
                        "the first capture time is {:.1} s, not near 0: output frame 0 is at it",
                        capture as f64 * 1e-9
                    ),
                });
                capture
            }
            Origin::FirstCapture => capture,
        });
    }

    /// A raw frame flagged PRELUDE holds a sample taken before the clip (the synthesizing
    /// source's rule), so the prelude lasts at least until its earliest sample's time (source
    /// clock; its capture time when it holds none).
    fn mark_prelude(&mut self, t: i128) {
        self.prelude_until = Some(self.prelude_until.map_or(t, |u| u.max(t)));
    }

    /// Whether source time `t` lies in the prelude: at or before a sample of a PRELUDE frame. The
    /// source's truth frame k is PRELUDE when it lies before the clip, and the last prelude sample
    /// lies less than a sample interval before the clip, so output frame k is PRELUDE exactly
    /// when the truth's is (for sensors faster than the output).
    fn prelude_at(&self, t: i128) -> bool {
        self.prelude_until.is_some_and(|u| t <= u)
    }

    /// Emits every frame that is due. [`Latency::Smooth`]: when every sensor's samples describe
    /// its time, or at its latency deadline. [`Latency::Low`]: as soon as any sensor has a sample
    /// from half an interval before its time on ([`Self::low_latency_due`]; by the sample times,
    /// not the arrivals: a stall's backlog releases its frames one by one as its samples come,
    /// not all at its first).
    fn emit_ready(&mut self, out: &mut Vec<ImuFrame>) {
        let latency = (self.settings.max_latency_s * 1e9).round() as i128;
        while let (Some(t), Some(newest)) = (self.time_of(self.next_k), self.newest_capture) {
            let due = match self.settings.sensor.latency {
                Latency::Low => self.low_latency_due(t, newest),
                Latency::Smooth => {
                    newest - t > latency
                        || self
                            .fused()
                            .all(|s| s.covered_until_ns().is_some_and(|c| c >= t))
                }
            };
            if !due {
                break;
            }
            self.emit(t, out);
        }
    }

    /// [`Latency::Low`]: frame `t` is due once a sample at or after [`LEAD_INTERVALS`] of an
    /// interval before it has come (it is extrapolated that far at most); but while a
    /// sensor that was usable in the last frame lies more than [`WAIT_INTERVALS`] behind it (its
    /// next sample is late), it waits for that sensor up to [`STALE_GRACE_S`] of arrivals (the
    /// trackers' backlogs after a common stall come one after the other, within a millisecond).
    fn low_latency_due(&mut self, t: i128, newest_capture: i128) -> bool {
        // Due from half an interval before its time: the label then lies as often after the
        // newest sample as before it (trackers that tick together would otherwise leave each
        // frame waiting up to a whole interval for the tick after it).
        let sampled = self.fused().any(|s| {
            let lead = (LEAD_INTERVALS * s.period_s().unwrap_or(0.0) * 1e9) as i128;
            s.newest_ns().is_some_and(|n| n + lead >= t)
        });
        if !sampled || newest_capture + MAX_LEAD_NS < t {
            return false;
        }
        // Not for one silent longer than a stall lasts: it rests (a tracker that sends only what
        // changed) or is gone, and every frame would wait for it.
        let waiting = self.slots.iter().any(|&i| {
            let s = &self.sensors[i];
            match (s.behind_s(t), s.period_s()) {
                (Some(behind), Some(period)) => {
                    self.presence[i].now
                        && behind > WAIT_INTERVALS * period
                        && behind <= MAX_WAITED_SILENCE_S
                }
                _ => false,
            }
        });
        if !waiting {
            self.waiting_since = None;
            return true;
        }
        let k = self.next_k;
        let since = match self.waiting_since {
            Some((frame, since)) if frame == k => since,
            _ => self.waiting_since.insert((k, newest_capture)).1,
        };
        (newest_capture - since) as f64 * 1e-9 >= STALE_GRACE_S
    }

    fn emit(&mut self, t: i128, out: &mut Vec<ImuFrame>) {
        let k = self.next_k;
        let mut frame = ImuFrame::default();
        frame.header.seq = k;
        frame.header.capture_ns = t.max(0) as u64;
        if self.prelude_at(t) {
            frame.header.flags |= flags::PRELUDE;
        }
        for slot in 0..self.slots.len() {
            let i = self.slots[slot];
            let value = self.sensors[i].at(t);
            match value {
                Some(v) => {
                    let interval = self.sensors[i].period_s().unwrap_or(0.0);
                    match self.settings.sensor.latency {
                        Latency::Low if v.ahead_s > STALE_INTERVALS * interval => {
                            self.counters.sensor_stale[i] += 1;
                            frame.header.flags |= flags::DEGRADED;
                        }
                        Latency::Low => {}
                        Latency::Smooth => {
                            if self.sensors[i].covered_until_ns().is_none_or(|c| c < t) {
                                self.counters.sensor_held[i] += 1;
                            }
                        }
                    }
                    frame.orientation_wxyz[i] = v.orientation.map(|c| c as f32);
                    frame.specific_force_mps2[i] = v.specific_force.map(|c| c as f32);
                    frame.angular_rate_radps[i] = v.angular_rate.map(|c| c as f32);
                    frame.valid_mask |= 1 << i;
                }
                None => {
                    frame.orientation_wxyz[i] = IDENTITY.map(|c| c as f32);
                    self.counters.sensor_invalid[i] += 1;
                }
            }
            self.track_presence(i, k, t, value.is_some());
            self.sensors[i].prune(t);
        }
        if frame.valid_mask != self.settings.sites.0 {
            frame.header.flags |= flags::INVALID;
            self.counters.invalid += 1;
        }
        if frame.header.has(flags::DEGRADED) {
            self.counters.degraded += 1;
        }
        self.last_emitted = Some(t);
        self.counters.frames += 1;
        self.next_k += 1;
        out.push(frame);
    }

    /// Logs a sensor's going missing once (the first time it is not usable after it was, or when
    /// it has never been usable a second after another sensor was), and its first return.
    fn track_presence(&mut self, i: usize, k: u64, t: i128, usable: bool) {
        if usable {
            self.first_usable_ns.get_or_insert(t);
        }
        let p = &mut self.presence[i];
        let never_seen = !p.ever
            && self
                .first_usable_ns
                .is_some_and(|first| (t - first) as f64 * 1e-9 > NEVER_SEEN_S);
        if !usable && p.missing_since.is_none() && (p.now || never_seen) && !self.finishing {
            p.missing_since = Some(k);
            if !p.warned {
                p.warned = true;
                let what = if p.ever {
                    "went missing"
                } else {
                    "has delivered no usable sample"
                };
                self.notices.push(Notice {
                    warning: true,
                    text: format!(
                        "{} {what} at output frame {k} ({:.3} s); its frames are flagged INVALID \
                         while it is missing",
                        sensor_name(i),
                        t as f64 * 1e-9
                    ),
                });
            }
        }
        if usable
            && let Some(since) = p.missing_since.take()
            && !p.return_logged
        {
            p.return_logged = true;
            self.notices.push(Notice {
                warning: false,
                text: format!(
                    "{} is back at output frame {k} after {} frame(s)",
                    sensor_name(i),
                    k - since
                ),
            });
        }
        p.ever |= usable;
        p.now = usable;
    }
}

/// The samples a raw frame carries, per sensor.
fn samples(raw: &RawImuFrame) -> impl Iterator<Item = (usize, RawSample)> + '_ {
    let f64s = |v: [f32; 3]| v.map(f64::from);
    (0..MAX_SITES)
        .filter(|i| raw.valid_mask & (1 << i) != 0)
        .map(move |i| {
            let has = |mask: u32| mask & (1 << i) != 0;
            let sample = RawSample {
                sample_ns: raw.sample_time_ns[i],
                capture_ns: i128::from(raw.header.capture_ns),
                acc: f64s(raw.accelerometer_mps2[i]),
                gyr: f64s(raw.gyroscope_radps[i]),
                mag: has(raw.magnetometer_mask).then(|| f64s(raw.magnetometer_ut[i])),
                onboard: has(raw.orientation_mask).then(|| raw.orientation_wxyz[i].map(f64::from)),
                no_gyroscope: has(raw.no_gyroscope_mask),
            };
            (i, sample)
        })
}
