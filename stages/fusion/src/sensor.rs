//! One sensor's stream: its samples checked, counted and dated on the source clock, fused into an
//! orientation at the sensor's own rate, band-limited, and kept until the output grid has passed
//! them.

use std::collections::VecDeque;

use crate::clock::ClockFit;
use crate::filter::{OrientationFilter, VqfParams};
use crate::lowpass::{Butterworth2, VecLowpass};
use crate::quat::{
    Quat, Vec3, conj, from_rotation_vector, lerp, mul, normalized, rotation_vector, slerp,
};
use crate::{FusionError, sensor_name};

/// Sample intervals whose median is the sensor's period when `sensor_rate_hz` is not given (9
/// samples: 45 ms at 200 Hz, 160 ms at 50 Hz). A median ignores a lost sample or two among them.
pub const RATE_INTERVALS: usize = 8;
/// The cutoff of the accelerometer and gyroscope low-pass as a share of the output rate: below the
/// output's Nyquist frequency (0.5), with room for the filter's roll-off.
pub const CUTOFF_SHARE: f64 = 0.4;
/// A rate is derived from two on-board orientations only when their stamps lie at least this share
/// of a sample interval apart (a turn over a few microseconds is mostly the stamps' error).
const MIN_DERIVE_SHARE: f64 = 0.25;
/// How fast the mean sample interval (what lost samples are counted in) follows the stamps:
/// about the last 50 intervals.
const MEAN_INTERVAL_GAIN: f64 = 0.02;
/// A sensor timestamp that jumps back by more, or ahead by more than the source clock advanced
/// plus this, is a restarted sensor clock (reboot, reconnect), not a late or lost sample, s.
pub const CLOCK_JUMP_S: f64 = 1.0;
/// Most samples filled into one gap: a gap that needs more (a very fast or mis-stamped sensor) is
/// treated as a long one, so that one sample never costs unbounded work.
const MAX_FILL: usize = 64;
/// Measured rates outside this range are reported (a timestamp unit mistake is the usual cause), Hz.
const PLAUSIBLE_RATE_HZ: std::ops::RangeInclusive<f64> = 5.0..=5000.0;
/// Fused samples kept before the newest output time (the clock fit can move the query time back
/// a little), s.
const KEEP_S: f64 = 0.25;
/// Most fused samples kept (about 40 s at 400 Hz): bounds memory when a sensor's clock is mapped
/// far ahead of the output.
const MAX_BUFFER: usize = 1 << 14;
/// A query time this close to a sample counts as that sample (float rounding of the mapping), s.
const SAME_TIME_S: f64 = 1e-6;

/// Where a sensor's orientation comes from (the stage's `orientation` parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OrientationSource {
    /// The on-board orientation when the sensor's first sample has one, else fused.
    Auto,
    /// Always fused from accelerometer, gyroscope (and magnetometer).
    Fuse,
    /// Always the on-board orientation; a sample without one is an error.
    Onboard,
}

/// What an output frame waits for (the stage's `latency` parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Latency {
    /// A frame goes out as soon as a sample from half an interval before its time on has
    /// arrived; sensors whose newest sample is older are extrapolated (at most one sample
    /// interval, then held); the accelerometer and gyroscope are not band-limited.
    Low,
    /// Accelerometer and gyroscope band-limited below the output's Nyquist frequency, and a
    /// frame waits until every sensor's samples describe its time (at most `max_latency_ms`).
    Smooth,
}

/// A sensor whose newest sample is this many intervals older than a frame is stale there (at
/// least one sample is overdue): it is extrapolated by one interval, then held.
pub const STALE_INTERVALS: f64 = 2.0;
/// ([`Latency::Low`]) A frame waits a little for a sensor whose newest sample is this many
/// intervals older (its next sample is late; extrapolation covers one interval).
pub const WAIT_INTERVALS: f64 = 1.5;
/// ([`Latency::Low`]) A tracker that sends only its orientation (no gyroscope: SlimeVR) and falls
/// silent is held, not missing, this long, s: its firmware sends a rotation only when it changed
/// (`OPTIMIZE_UPDATES` in SlimeVR-Tracker-ESP), so silence from a still tracker means "unchanged".
/// Held beyond two intervals it is stale (the frame DEGRADED); past this, missing.
pub const ORIENTATION_ONLY_HOLD_S: f64 = 1.0;

/// Whether magnetometer readings are fused (the stage's `magnetometer` parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MagnetometerUse {
    /// 9D for samples with a reading.
    Auto,
    /// 6D always.
    Ignore,
}

/// What every sensor is configured with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorSettings {
    pub vqf: VqfParams,
    pub orientation: OrientationSource,
    pub magnetometer: MagnetometerUse,
    /// The sensors' sample rate when known; `None`: measured from the timestamps.
    pub sensor_rate_hz: Option<f64>,
    /// A sensor without a sample for longer than this is missing; shorter gaps are filled, s.
    pub max_gap_s: f64,
    /// The output grid's rate, Hz (decides whether and where the low-pass cuts).
    pub output_rate_hz: f64,
    pub latency: Latency,
}

/// One delivered sample of one sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawSample {
    /// On the sensor's own clock, ns.
    pub sample_ns: u64,
    /// When the source captured the frame that carried it (source clock), ns.
    pub capture_ns: i128,
    pub acc: Vec3,
    pub gyr: Vec3,
    pub mag: Option<Vec3>,
    pub onboard: Option<Quat>,
    /// The sample carries no gyroscope reading (`gyr` is zero): the angular rate is derived from
    /// consecutive on-board orientations.
    pub no_gyroscope: bool,
}

/// What happened to one sensor's samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SensorCounters {
    /// Samples delivered with a new sample time (duplicates and out-of-order ones not included).
    pub samples: u64,
    /// Samples fed to the filter (finite and usable).
    pub fused: u64,
    /// Samples never delivered: the gaps in the sample times, in measured sample intervals.
    pub lost: u64,
    /// Gaps longer than `max_gap_ms` (not filled; the sensor is missing during them).
    pub long_gaps: u64,
    /// Dropped: the same sample time as the previous sample.
    pub duplicates: u64,
    /// Dropped: a sample time before the previous sample's.
    pub out_of_order: u64,
    /// Skipped: a non-finite accelerometer or gyroscope value, or an unusable on-board orientation.
    pub nonfinite: u64,
    /// Magnetometer readings ignored for a non-finite value (the sample was fused 6D).
    pub nonfinite_mag: u64,
    /// Skipped (orientation `auto` with an on-board sensor): a sample without its orientation.
    pub no_orientation: u64,
    /// The sensor's clock restarted (jumped by more than [`CLOCK_JUMP_S`]).
    pub clock_resets: u64,
    /// Angular rates derived from on-board orientations (samples without a gyroscope reading).
    pub derived_rates: u64,
}

/// How the sensor's orientation is made, decided at its first usable sample.
enum Source {
    Fused(Box<OrientationFilter>),
    Onboard,
}

/// A sample as the filter takes it: finite, with the parts this sensor uses.
#[derive(Clone, Copy, Debug)]
struct Input {
    acc: Vec3,
    gyr: Vec3,
    mag: Option<Vec3>,
    onboard: Option<Quat>,
}

impl Input {
    fn between(&self, other: &Input, u: f64) -> Input {
        Input {
            acc: lerp(&self.acc, &other.acc, u),
            gyr: lerp(&self.gyr, &other.gyr, u),
            mag: self.mag.zip(other.mag).map(|(a, b)| lerp(&a, &b, u)),
            onboard: self
                .onboard
                .zip(other.onboard)
                .map(|(a, b)| slerp(&a, &b, u)),
        }
    }
}

/// One fused sample at sensor time `x` (s since the sensor's first sample). `acc` and `gyr` are
/// band-limited and so describe the time `x − delay`.
#[derive(Clone, Copy, Debug)]
struct Fused {
    x: f64,
    q: Quat,
    acc: Vec3,
    gyr: Vec3,
}

/// The values of one sensor at one output time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resampled {
    /// `R_IS` as `[w, x, y, z]`.
    pub orientation: Quat,
    /// Specific force in S, m/s².
    pub specific_force: Vec3,
    /// Angular rate in S less the filter's gyroscope bias estimate, rad/s.
    pub angular_rate: Vec3,
    /// How far the time lies after the sensor's newest sample, s (0 when samples lie on both
    /// sides of it; only [`Latency::Low`] resamples there).
    pub ahead_s: f64,
}

/// One sensor's stream.
pub struct SensorTrack {
    index: usize,
    settings: SensorSettings,
    clock: Option<ClockFit>,
    /// The previous sample's (sensor time, capture time), ns.
    last: Option<(u64, i128)>,
    /// Samples waiting for the rate to be measured, with their sensor times (s).
    startup: Vec<(f64, RawSample)>,
    period_s: Option<f64>,
    source: Option<Source>,
    lowpass: Option<(VecLowpass, VecLowpass)>,
    /// The low-pass's group delay, s (0 without the low-pass).
    delay_s: f64,
    last_seen_x: Option<f64>,
    /// The mean interval between consecutive stamps, s (lost samples are counted in it).
    mean_interval_s: Option<f64>,
    /// The sensor sends its on-board orientation without a gyroscope reading (SlimeVR).
    orientation_only: bool,
    last_good: Option<(f64, Input)>,
    buffer: VecDeque<Fused>,
    counters: SensorCounters,
    notices: Vec<String>,
}

impl SensorTrack {
    pub fn new(index: usize, settings: SensorSettings) -> SensorTrack {
        let mut track = SensorTrack {
            index,
            settings,
            clock: None,
            last: None,
            startup: Vec::new(),
            period_s: None,
            source: None,
            lowpass: None,
            delay_s: 0.0,
            last_seen_x: None,
            mean_interval_s: None,
            orientation_only: false,
            last_good: None,
            buffer: VecDeque::new(),
            counters: SensorCounters::default(),
            notices: Vec::new(),
        };
        if let Some(rate) = settings.sensor_rate_hz {
            track.set_period(1.0 / rate);
        }
        track
    }

    pub fn counters(&self) -> &SensorCounters {
        &self.counters
    }

    /// The sample rate in use (given or measured), Hz.
    pub fn rate_hz(&self) -> Option<f64> {
        self.period_s.map(|p| 1.0 / p)
    }

    /// The low-pass's group delay that output waits for, s (0 when not filtered).
    pub fn delay_s(&self) -> f64 {
        self.delay_s
    }

    /// How the orientation is made: `9D`, `6D`, `on-board`, or `-` before the first sample.
    pub fn source_name(&self) -> &'static str {
        match &self.source {
            Some(Source::Fused(f)) if f.magnetic() => "9D",
            Some(Source::Fused(_)) => "6D",
            Some(Source::Onboard) => "on-board",
            None => "-",
        }
    }

    /// The clock fit's offset (capture − sample at the newest sample, ns) and drift (ppm; `None`
    /// until estimated).
    pub fn clock(&self) -> Option<(f64, Option<f64>)> {
        let clock = self.clock.as_ref()?;
        let x = self.last.map_or(0.0, |(s, _)| clock.sensor_s(s));
        Some((
            clock.offset_ns(x),
            clock.has_drift().then(|| clock.drift_ppm()),
        ))
    }

    /// What this sensor has to say since the last call (logged by the stage).
    pub fn take_notices(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notices)
    }

    /// Takes one delivered sample. Errs only for `orientation = onboard` and a sample without an
    /// on-board orientation.
    pub fn push(&mut self, sample: RawSample) -> Result<(), FusionError> {
        if let Some((last_ns, last_capture)) = self.last {
            let dx = i128::from(sample.sample_ns) - i128::from(last_ns);
            let dc = sample.capture_ns - last_capture;
            let jump = (CLOCK_JUMP_S * 1e9) as i128;
            if dx < -jump || dx - dc > jump {
                self.restart_clock(dx);
            } else if dx == 0 {
                self.counters.duplicates += 1;
                return Ok(());
            } else if dx < 0 {
                self.counters.out_of_order += 1;
                return Ok(());
            }
        }
        self.last = Some((sample.sample_ns, sample.capture_ns));
        let clock = match &mut self.clock {
            Some(clock) => {
                clock.observe(sample.sample_ns, sample.capture_ns);
                clock
            }
            None => self
                .clock
                .insert(ClockFit::new(sample.sample_ns, sample.capture_ns)),
        };
        let x = clock.sensor_s(sample.sample_ns);
        self.counters.samples += 1;
        if self.period_s.is_none() {
            self.startup.push((x, sample));
            if self.startup.len() > RATE_INTERVALS {
                self.start()?;
            }
            return Ok(());
        }
        self.process(x, &sample)
    }

    /// At the end of the stream: a sensor still measuring its rate fuses what it has (its rate from
    /// the intervals seen, when there are any).
    pub fn finish(&mut self) -> Result<(), FusionError> {
        if self.period_s.is_none() && self.startup.len() > 1 {
            self.start()?;
        }
        Ok(())
    }

    /// The sensor's clock restarted: the new clock is fitted from scratch, the samples before it
    /// are not interpolated against, and the filter restarts as after a long gap (how long the
    /// sensor was away is unknown; its rate and bias estimate are kept).
    fn restart_clock(&mut self, dx_ns: i128) {
        self.counters.clock_resets += 1;
        self.notices.push(format!(
            "{}: sample clock jumped by {:.3} s: clock fit restarted",
            sensor_name(self.index),
            dx_ns as f64 * 1e-9
        ));
        self.clock = None;
        self.last = None;
        self.last_seen_x = None;
        self.last_good = None;
        self.buffer.clear();
        self.startup.clear();
        if let Some((acc, gyr)) = &mut self.lowpass {
            acc.reset();
            gyr.reset();
        }
        if let Some(Source::Fused(filter)) = &mut self.source {
            filter.restart();
        }
    }

    /// The rate from the start-up samples' median interval, then those samples fused.
    fn start(&mut self) -> Result<(), FusionError> {
        let mut intervals: Vec<f64> = self.startup.windows(2).map(|w| w[1].0 - w[0].0).collect();
        intervals.sort_by(f64::total_cmp);
        let median = intervals[intervals.len() / 2];
        self.set_period(median);
        let rate = 1.0 / median;
        let check = if PLAUSIBLE_RATE_HZ.contains(&rate) {
            ""
        } else {
            ": implausible, are its timestamps in nanoseconds? (sensor_rate_hz sets the rate)"
        };
        self.notices.push(format!(
            "{}: {rate:.1} Hz measured (median of {} sample intervals){check}",
            sensor_name(self.index),
            intervals.len()
        ));
        for (x, sample) in std::mem::take(&mut self.startup) {
            self.process(x, &sample)?;
        }
        Ok(())
    }

    fn set_period(&mut self, period_s: f64) {
        self.period_s = Some(period_s);
        let rate = 1.0 / period_s;
        let out = self.settings.output_rate_hz;
        // Band-limit only what the output grid would alias: a sensor at or below the output rate
        // carries nothing above the output's Nyquist frequency that interpolation could fold.
        let coeffs = (rate > out && self.settings.latency == Latency::Smooth)
            .then(|| Butterworth2::lowpass(CUTOFF_SHARE * out, rate))
            .flatten();
        self.lowpass = coeffs.map(|c| (VecLowpass::new(c), VecLowpass::new(c)));
        self.delay_s = coeffs.map_or(0.0, |c| c.group_delay_samples() * period_s);
    }

    /// The longest interval between samples that is filled or interpolated over: `max_gap_ms`, but
    /// at least 1.5 sample intervals (a slow sensor is not missing between its samples).
    fn max_gap_s(&self) -> f64 {
        let period = self.period_s.unwrap_or(0.0);
        self.settings.max_gap_s.max(1.5 * period)
    }

    /// ([`Latency::Low`]) How long after its newest sample the sensor is held rather than
    /// missing: the longest gap, or [`ORIENTATION_ONLY_HOLD_S`] for a tracker that sends only its
    /// orientation.
    fn silence_hold_s(&self) -> f64 {
        if self.orientation_only {
            self.max_gap_s().max(ORIENTATION_ONLY_HOLD_S)
        } else {
            self.max_gap_s()
        }
    }

    fn process(&mut self, x: f64, sample: &RawSample) -> Result<(), FusionError> {
        let period = self.period_s.unwrap_or(1.0);
        if let Some(prev) = self.last_seen_x {
            // Counted in the mean interval, which follows the stamps (a rate measured from a few
            // jittery stamps at the start would count jitter as losses, or losses as jitter).
            let interval = self.mean_interval_s.unwrap_or(period);
            let intervals = ((x - prev) / interval).round();
            if intervals > 1.0 {
                self.counters.lost += intervals as u64 - 1;
            } else if intervals == 1.0 {
                let mean = self.mean_interval_s.get_or_insert(period);
                *mean += MEAN_INTERVAL_GAIN * ((x - prev) - *mean);
            }
        }
        self.last_seen_x = Some(x);
        let Some(input) = self.usable(x, sample)? else {
            return Ok(());
        };
        self.counters.fused += 1;
        self.fill_gap(x, &input);
        self.step(x, &input);
        self.last_good = Some((x, input));
        Ok(())
    }

    /// The sample as the filter takes it, or `None` (counted) when it cannot be used.
    fn usable(&mut self, x: f64, sample: &RawSample) -> Result<Option<Input>, FusionError> {
        let onboard_source = self.source_for(sample);
        let finite = |v: &Vec3| v.iter().all(|c| c.is_finite());
        if !finite(&sample.acc) || !finite(&sample.gyr) {
            self.counters.nonfinite += 1;
            return Ok(None);
        }
        let mag = match (self.settings.magnetometer, sample.mag) {
            (MagnetometerUse::Auto, Some(m)) if finite(&m) => Some(m),
            (MagnetometerUse::Auto, Some(_)) => {
                self.counters.nonfinite_mag += 1;
                None
            }
            _ => None,
        };
        let onboard = match (onboard_source, sample.onboard) {
            (false, _) => None,
            (true, Some(q)) => match normalized(q) {
                Some(q) => Some(q),
                None => {
                    self.counters.nonfinite += 1;
                    return Ok(None);
                }
            },
            (true, None) if self.settings.orientation == OrientationSource::Onboard => {
                return Err(FusionError::NoOnboardOrientation {
                    sensor: self.index,
                    sample_ns: sample.sample_ns,
                });
            }
            (true, None) => {
                self.counters.no_orientation += 1;
                return Ok(None);
            }
        };
        self.orientation_only = sample.no_gyroscope && onboard.is_some();
        let gyr = match (sample.no_gyroscope, onboard, self.last_good) {
            // No gyroscope: the mean rate over the interval ending at this sample (the convention
            // VQF's integration and the fusion's gyroscope samples follow), from the turn between
            // the previous on-board orientation and this one, in the sensor frame.
            (
                true,
                Some(q),
                Some((
                    x0,
                    Input {
                        onboard: Some(q0), ..
                    },
                )),
            ) if x - x0 >= MIN_DERIVE_SHARE * self.period_s.unwrap_or(0.0) && x > x0 => {
                self.counters.derived_rates += 1;
                rotation_vector(&mul(&conj(&q0), &q)).map(|c| c / (x - x0))
            }
            // Stamps closer than that say nothing about the rate: the last one is kept.
            (true, Some(_), Some((_, previous))) => previous.gyr,
            _ => sample.gyr,
        };
        Ok(Some(Input {
            acc: sample.acc,
            gyr,
            mag,
            onboard,
        }))
    }

    /// Whether this sensor uses its on-board orientation, decided at its first sample.
    fn source_for(&mut self, sample: &RawSample) -> bool {
        if self.source.is_none() {
            let onboard = match self.settings.orientation {
                OrientationSource::Onboard => true,
                OrientationSource::Fuse => false,
                OrientationSource::Auto => sample.onboard.is_some(),
            };
            let period = self.period_s.unwrap_or(1.0);
            self.source = Some(if onboard {
                Source::Onboard
            } else {
                Source::Fused(Box::new(OrientationFilter::new(period, &self.settings.vqf)))
            });
        }
        matches!(self.source, Some(Source::Onboard))
    }

    /// Fills the samples lost since the previous usable one by linear interpolation (slerp for an
    /// on-board orientation), so the filter integrates the gyroscope over the whole interval and
    /// the low-pass keeps its uniform rate. A gap longer than `max_gap_ms` is not filled: the
    /// output is invalid across it, the low-pass starts again after it, and the filter restarts
    /// from its last state ([`OrientationFilter::restart`]).
    fn fill_gap(&mut self, x: f64, input: &Input) {
        let Some((gx, previous)) = self.last_good else {
            return;
        };
        let period = self.period_s.unwrap_or(1.0);
        let span = x - gx;
        let steps = (span / period).round() as usize;
        if span > self.max_gap_s() || steps > MAX_FILL {
            self.counters.long_gaps += 1;
            if let Some((acc, gyr)) = &mut self.lowpass {
                acc.reset();
                gyr.reset();
            }
            if let Some(Source::Fused(filter)) = &mut self.source {
                filter.restart();
            }
            return;
        }
        for j in 1..steps {
            let u = j as f64 / steps as f64;
            self.step(gx + u * span, &previous.between(input, u));
        }
    }

    /// One filter step at sensor time `x`.
    fn step(&mut self, x: f64, input: &Input) {
        let (q, bias) = match &mut self.source {
            Some(Source::Fused(filter)) => {
                filter.update(input.gyr, input.acc, input.mag);
                (filter.orientation(), filter.gyro_bias())
            }
            _ => (input.onboard.unwrap_or(crate::quat::IDENTITY), [0.0; 3]),
        };
        let gyr = [0, 1, 2].map(|i| input.gyr[i] - bias[i]);
        let (acc, gyr) = match &mut self.lowpass {
            Some((lp_acc, lp_gyr)) => (lp_acc.step(input.acc), lp_gyr.step(gyr)),
            None => (input.acc, gyr),
        };
        self.buffer.push_back(Fused { x, q, acc, gyr });
        if self.buffer.len() > MAX_BUFFER {
            self.buffer.pop_front();
        }
    }

    /// How much later than the time it describes a gyroscope sample is stamped: half a sample
    /// interval (it is the mean rate over the interval ending at its stamp, as VQF's strapdown
    /// step takes it), s.
    fn gyro_lag_s(&self) -> f64 {
        self.period_s.unwrap_or(0.0) / 2.0
    }

    /// The latest source time this sensor can be resampled at: its newest sample less the
    /// low-pass delay and the gyroscope's half interval. `None` before its first fused sample.
    pub fn covered_until_ns(&self) -> Option<i128> {
        let clock = self.clock.as_ref()?;
        let newest = self.buffer.back()?;
        Some(clock.source_ns(newest.x - self.delay_s - self.gyro_lag_s()))
    }

    /// The source time of sensor time `sample_ns` by the current clock fit.
    pub fn source_ns_of(&self, sample_ns: u64) -> Option<i128> {
        let clock = self.clock.as_ref()?;
        Some(clock.source_ns(clock.sensor_s(sample_ns)))
    }

    /// The source time of the newest fused sample: the last time the orientation can be
    /// interpolated at (the specific force and angular rate are extrapolated there).
    pub fn newest_ns(&self) -> Option<i128> {
        Some(self.clock.as_ref()?.source_ns(self.buffer.back()?.x))
    }

    /// The sensor at source time `t_ns`: the orientation by slerp between the two fused samples
    /// around it, specific force and angular rate linearly between the two band-limited samples
    /// around the times they describe (their stamps less the low-pass delay, and less half an
    /// interval for the angular rate). `None` when the orientation's pair is missing or further
    /// apart than the longest gap. When the orientation is there but the samples describing the
    /// specific force or angular rate at `t_ns` are not yet (a frame emitted at its latency
    /// deadline), those are extrapolated from the newest two samples.
    pub fn at(&self, t_ns: i128) -> Option<Resampled> {
        let x = self.clock.as_ref()?.sensor_at(t_ns);
        let newest = self.buffer.back()?;
        if self.settings.latency == Latency::Low && x > newest.x + SAME_TIME_S {
            return self.ahead_of_newest(x, newest);
        }
        let (a, b, u) = self.bracket(x)?;
        let orientation = slerp(&a.q, &b.q, u);
        let (a, b, u) = self.bracket_or_newest(x + self.delay_s)?;
        let specific_force = lerp(&a.acc, &b.acc, u);
        let (a, b, u) = self.bracket_or_newest(x + self.delay_s + self.gyro_lag_s())?;
        Some(Resampled {
            orientation,
            specific_force,
            angular_rate: lerp(&a.gyr, &b.gyr, u),
            ahead_s: 0.0,
        })
    }

    /// [`Latency::Low`] at sensor time `x` after the newest sample: its orientation turned on at
    /// its angular rate for at most one sample interval, then held (a sensor a little behind the
    /// others is where its motion has taken it by now), its specific force and angular rate held.
    /// `None` when the newest sample is further back than the sensor is held
    /// ([`Self::silence_hold_s`]: it is missing).
    fn ahead_of_newest(&self, x: f64, newest: &Fused) -> Option<Resampled> {
        let ahead = x - newest.x;
        if ahead > self.silence_hold_s() {
            return None;
        }
        let turn = ahead.min(self.period_s.unwrap_or(0.0));
        let step = from_rotation_vector(&newest.gyr.map(|w| w * turn));
        Some(Resampled {
            orientation: mul(&newest.q, &step),
            specific_force: newest.acc,
            angular_rate: newest.gyr,
            ahead_s: ahead,
        })
    }

    /// How long before source time `t_ns` the newest sample lies, s (`None` without samples).
    pub fn behind_s(&self, t_ns: i128) -> Option<f64> {
        Some((t_ns - self.newest_ns()?) as f64 * 1e-9)
    }

    /// The sample interval in use, s (`None` while the rate is being measured).
    pub fn period_s(&self) -> Option<f64> {
        self.period_s
    }

    /// [`Self::bracket`], or past the newest sample the line through the newest two (at most one
    /// interval beyond the newest, then held; the newest alone when the two are a gap apart).
    fn bracket_or_newest(&self, x: f64) -> Option<(&Fused, &Fused, f64)> {
        let n = self.buffer.len();
        let newest = self.buffer.back()?;
        if x <= newest.x {
            return self.bracket(x);
        }
        let previous = n.checked_sub(2).map(|i| &self.buffer[i]);
        match previous {
            Some(p) if newest.x - p.x <= self.max_gap_s() => {
                let beyond = ((x - newest.x) / (newest.x - p.x)).min(1.0);
                Some((p, newest, 1.0 + beyond))
            }
            _ => Some((newest, newest, 0.0)),
        }
    }

    fn bracket(&self, x: f64) -> Option<(&Fused, &Fused, f64)> {
        let i = self.buffer.partition_point(|f| f.x <= x);
        let (first, last) = (self.buffer.front()?, self.buffer.back()?);
        if i == 0 {
            return (first.x - x < SAME_TIME_S).then_some((first, first, 0.0));
        }
        if i == self.buffer.len() {
            return (x - last.x < SAME_TIME_S).then_some((last, last, 0.0));
        }
        let (a, b) = (&self.buffer[i - 1], &self.buffer[i]);
        let span = b.x - a.x;
        (span <= self.max_gap_s() + SAME_TIME_S).then(|| (a, b, (x - a.x) / span))
    }

    /// Forgets the fused samples the output grid has passed (source time `t_ns`).
    pub fn prune(&mut self, t_ns: i128) {
        let Some(clock) = &self.clock else {
            return;
        };
        let keep_from = clock.sensor_at(t_ns) - KEEP_S;
        while self.buffer.len() > 2 && self.buffer[1].x < keep_from {
            self.buffer.pop_front();
        }
    }
}
