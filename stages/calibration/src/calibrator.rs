//! The calibration session, one frame at a time (no IO): detects the calibration phases from the
//! data, calibrates, then turns every frame into a calibrated `BodyImuFrame`.
//!
//! - Before the calibration is accepted, every output frame is flagged CALIBRATING | INVALID with an
//!   empty payload (identity orientations, zeros, `valid_mask` 0).
//! - `tpose`: the first hold (still for `hold_s`) is the held pose; the last `average_s` of it are
//!   averaged.
//! - `walking`: a hold, a motion of at most `max_step_s`, and another hold form one attempt. A
//!   rejected attempt is reported with its reason; the stand after it is the stand before the next
//!   attempt, so the subject simply steps again.
//! - After a walking calibration, with `drift_update`, every later stand–step–stand that passes the
//!   same checks re-estimates the per-sensor heading corrections (the sensors' relative heading
//!   drift, e.g. from magnetic disturbance). `R_MI` and `R_SB` are kept: the pelvis's own heading
//!   drift is not observable this way (the subject may face anywhere by then).

use std::collections::VecDeque;
use std::ops::Range;

use imuflow_graph::frames::{BodyImuFrame, FrameHeader, ImuFrame, flags};

use crate::calibration::{Calibration, Method};
use crate::convention::{InertialFrame, ReferencePose};
use crate::error::{NotCalibrated, Rejection};
use crate::sample::Sample;
use crate::segments::{Hold, Segmenter};
use crate::sensor_name;
use crate::stage::CalibrationParams;
use crate::stillness::{StillnessConfig, StillnessDetector, motion_onset};
use crate::tpose::{TposeConfig, calibrate_tpose};
use crate::walking::{
    StepWindows, WalkDirection, WalkStartConfig, WalkStartWindows, WalkingConfig,
    calibrate_walk_start, calibrate_walking, measure_step,
};
use imuflow_body::{Imu, MAX_SITES, SiteMask};

/// The least of a natural start's stand's end left out of its averages (s): where the stillness
/// test first failed, a sudden motion began at most a few samples earlier.
const STAND_END_SKIP_S: f64 = 0.05;
/// The least of a natural start's stand kept for the accelerometer offset (s), where the stand
/// allows: its noise costs more than the orientations'.
const OFFSET_AVERAGE_MIN_S: f64 = 0.75;
/// The least of a natural start's stand kept for its averages (s), where the stand allows.
const STAND_AVERAGE_MIN_S: f64 = 0.25;

/// The shortest `walk_stand_s` the stage takes (its parameter's lower bound), s.
pub const MIN_WALK_STAND_S: f64 = 0.2;

/// Everything a session needs; [`CalibratorConfig::default`] holds the stage's defaults (its
/// parameters, [`CalibrationParams`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibratorConfig {
    pub method: Method,
    /// Inertial-frame convention of the sensors.
    pub frame: InertialFrame,
    /// `tpose`: the subject's heading in I (rad, see [`InertialFrame::model_from_inertial`]).
    pub heading_rad: f64,
    /// The pose held (`tpose`) or stood in (`walking`'s stand–step–stand: the subject was told).
    pub pose: ReferencePose,
    /// The pose stood in before a natural start's walk (nobody said how to stand).
    pub walk_start_pose: ReferencePose,
    pub accel_offset: bool,
    /// `walking`: re-estimate heading corrections at later stand–step–stands.
    pub drift_update: bool,
    /// Converts the durations below to frames.
    pub nominal_rate_hz: f64,
    /// A still run counts as a hold / stand after this long (s).
    pub hold_s: f64,
    /// The end of a hold averaged for orientations and offsets (s).
    pub average_s: f64,
    /// Trailing window of the stillness test (s).
    pub still_window_s: f64,
    pub still_gyro_radps: f64,
    pub still_accel_std_mps2: f64,
    /// Longest motion between two stands that counts as one step (s).
    pub max_step_s: f64,
    pub max_gravity_deg: f64,
    pub max_pose_change_deg: f64,
    pub max_vertical_m: f64,
    pub min_step_m: f64,
    pub max_step_m: f64,
    pub max_step_mismatch_m: f64,
    /// `walking`: also calibrate from a stand followed by walking, with no stand after.
    pub walk_start: bool,
    /// A still run this long counts as the stand before walking (s).
    pub walk_stand_s: f64,
    /// Walking integrated after that stand (s).
    pub walk_s: f64,
    /// Direction of that walk relative to facing (rad, right-handed about up: 0 forward); `None`:
    /// from the legs.
    pub walk_direction_rad: Option<f64>,
    pub min_walk_m: f64,
    pub max_walk_mismatch_m: f64,
    pub max_walk_vertical_m: f64,
    pub max_walk_turn_deg: f64,
    /// The sites calibrated (the graph's sensor set; the six-site set by default).
    pub sites: SiteMask,
}

impl Default for CalibratorConfig {
    /// The calibration stage's defaults ([`CalibrationParams`]) at 60 Hz.
    fn default() -> CalibratorConfig {
        CalibrationParams::default().config_at(60.0)
    }
}

impl CalibratorConfig {
    fn frames(&self, secs: f64) -> u64 {
        (secs * self.nominal_rate_hz).round().max(1.0) as u64
    }

    /// Frames integrated before the first and after the last detected still frame of a step: the
    /// stillness test lags by its window, and a slow start of the step must not be missed.
    fn margin_frames(&self) -> u64 {
        self.frames((2.0 * self.still_window_s).max(0.5))
    }

    fn tpose(&self) -> TposeConfig {
        TposeConfig {
            frame: self.frame,
            heading_rad: self.heading_rad,
            pose: self.pose,
            accel_offset: self.accel_offset,
            max_gravity_deg: self.max_gravity_deg,
        }
    }

    fn walk_start_config(&self) -> WalkStartConfig {
        WalkStartConfig {
            walking: WalkingConfig {
                pose: self.walk_start_pose,
                ..self.walking()
            },
            walk_direction_rad: self.walk_direction_rad,
            walk_s: self.walk_s,
            min_walk_m: self.min_walk_m,
            max_walk_mismatch_m: self.max_walk_mismatch_m,
            max_walk_vertical_m: self.max_walk_vertical_m,
            max_walk_turn_deg: self.max_walk_turn_deg,
        }
    }

    fn walking(&self) -> WalkingConfig {
        WalkingConfig {
            frame: self.frame,
            pose: self.pose,
            accel_offset: self.accel_offset,
            max_gravity_deg: self.max_gravity_deg,
            max_pose_change_deg: self.max_pose_change_deg,
            max_vertical_m: self.max_vertical_m,
            min_step_m: self.min_step_m,
            max_step_m: self.max_step_m,
            max_step_mismatch_m: self.max_step_mismatch_m,
        }
    }
}

/// Something that happened at a frame, for the log.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A hold was seen (`tpose`: being calibrated now; `walking`: waiting for the step).
    Stand { seq: u64 },
    /// A calibration was accepted.
    Calibrated {
        seq: u64,
        calibration: Box<Calibration>,
        /// A natural start: which way the walk went relative to facing, and who said so.
        walk_direction: Option<WalkDirection>,
    },
    /// An attempt must be redone.
    Rejected { seq: u64, reason: Rejection },
    /// A later stand–step–stand re-estimated the heading corrections (rad, IMU order).
    HeadingUpdated {
        seq: u64,
        /// The sites calibrated.
        sites: SiteMask,
        previous_rad: [f64; MAX_SITES],
        corrections_rad: [f64; MAX_SITES],
    },
    /// A later stand–motion–stand did not qualify for a heading update.
    HeadingUpdateSkipped { seq: u64, reason: Rejection },
}

/// Maps capture timestamps to seconds, falling back to the nominal period when a timestamp does
/// not move forward plausibly (a replay glitch must not produce a zero or negative dt).
#[derive(Debug)]
struct Clock {
    nominal_dt_s: f64,
    last: Option<(u64, f64)>,
}

impl Clock {
    /// Longest gap between frames taken at face value (s).
    const MAX_GAP_S: f64 = 0.5;

    fn time_s(&mut self, capture_ns: u64) -> f64 {
        let t = match self.last {
            None => 0.0,
            Some((ns, t)) => {
                let dt = capture_ns.saturating_sub(ns) as f64 * 1e-9;
                t + if dt > 0.0 && dt <= Self::MAX_GAP_S {
                    dt
                } else {
                    self.nominal_dt_s
                }
            }
        };
        self.last = Some((capture_ns, t));
        t
    }
}

/// Follows still runs for the natural start: remembers the last one that lasted a stand's length
/// and ended, and forgets it when a new one of that length begins (the subject stopped again).
///
/// A run's frames are the still *samples*: a frame is still when the stillness window ending at it
/// is, so the run's samples start a window before its first still frame. A person who stood for
/// 0.5 s stood for 0.5 s, not for 0.5 s less the window.
#[derive(Debug, Default)]
struct WalkStartTracker {
    /// First still sample of the current run.
    run_start: Option<u64>,
    stand: Option<Range<u64>>,
    /// The longest still run so far (samples), for the refusal's "what was found".
    longest: Option<Range<u64>>,
}

impl WalkStartTracker {
    /// Takes frame `index`'s stillness (its window: `window_frames` samples ending at `index`);
    /// the stand the motion at `index` follows, if any.
    fn push(
        &mut self,
        index: u64,
        still: bool,
        stand_frames: u64,
        window_frames: u64,
    ) -> Option<Range<u64>> {
        if still {
            let start = *self
                .run_start
                .get_or_insert((index + 1).saturating_sub(window_frames.max(1)));
            let run = start..index + 1;
            if self
                .longest
                .as_ref()
                .is_none_or(|l| l.end - l.start < run.end - run.start)
            {
                self.longest = Some(run);
            }
            if index + 1 - start >= stand_frames {
                self.stand = None;
            }
            return None;
        }
        if let Some(start) = self.run_start.take()
            && index - start >= stand_frames
        {
            self.stand = Some(start..index);
        }
        self.stand.clone()
    }
}

/// One calibration session.
#[derive(Debug)]
pub struct Calibrator {
    config: CalibratorConfig,
    calibration: Option<Calibration>,
    detector: StillnessDetector,
    segmenter: Segmenter,
    /// The natural start (`walk_start`): still runs of at least `walk_stand_s`.
    walk_start: WalkStartTracker,
    clock: Clock,
    /// The recent samples; `buffer[0]` is frame `frames - buffer.len()`.
    buffer: VecDeque<Sample>,
    capacity: usize,
    frames: u64,
    holds: u64,
    /// Per sensor, the first frame in which it was usable. The frames before are a fusing
    /// source's start-up (no sample of a sensor before its first), not bad samples.
    first_usable: [Option<u64>; MAX_SITES],
    /// Per sensor, frames after its first usable one in which it was unusable.
    invalid_frames: [u64; MAX_SITES],
    /// Natural starts attempted (a stand of `walk_stand_s`, then `walk_s` of walking).
    walk_attempts: u64,
    /// A capture day's calibration whose `R_SB` every accepted calibration keeps
    /// ([`Calibrator::with_mounting`]).
    mounting: Option<Calibration>,
    last_rejection: Option<Rejection>,
}

impl Calibrator {
    /// A session that calibrates from the data (`method = none`: calibrated from the start).
    pub fn new(config: CalibratorConfig) -> Calibrator {
        let calibration =
            (config.method == Method::None).then(|| Calibration::identity(config.sites));
        let step_capacity = config.margin_frames()
            + config.frames(config.average_s)
            + config.frames(config.max_step_s)
            + config.frames(config.hold_s)
            + config.frames(config.still_window_s)
            + 2;
        let walk_capacity = config.margin_frames()
            + config.frames(config.average_s)
            + config.frames(config.walk_s)
            + 2;
        let capacity = step_capacity.max(walk_capacity) as usize;
        Calibrator {
            config,
            calibration,
            detector: StillnessDetector::new(StillnessConfig {
                window_frames: config.frames(config.still_window_s) as usize,
                max_gyro_radps: config.still_gyro_radps,
                max_accel_std_mps2: config.still_accel_std_mps2,
            }),
            segmenter: Segmenter::new(config.frames(config.hold_s)),
            walk_start: WalkStartTracker::default(),
            clock: Clock {
                nominal_dt_s: 1.0 / config.nominal_rate_hz,
                last: None,
            },
            buffer: VecDeque::with_capacity(capacity),
            capacity,
            frames: 0,
            holds: 0,
            first_usable: [None; MAX_SITES],
            invalid_frames: [0; MAX_SITES],
            walk_attempts: 0,
            mounting: None,
            last_rejection: None,
        }
    }

    /// A session that starts calibrated (a calibration loaded from a file).
    pub fn with_calibration(config: CalibratorConfig, calibration: Calibration) -> Calibrator {
        let mut c = Calibrator::new(config);
        c.calibration = Some(calibration);
        c
    }

    /// A session that calibrates from the data but keeps `mounting`'s sensor-to-bone rotations
    /// (`R_SB`): a lab's workflow, one careful calibration per capture day applied to every
    /// recording of that day, each recording's headings (`R_MI`, the heading corrections) and
    /// accelerometer offsets found from its own start. `R_SB` is how a sensor sits on its bone,
    /// the same in any inertial frame while the sensors stay where they were strapped; a
    /// recording's own stand then only has to be long enough to integrate from.
    pub fn with_mounting(config: CalibratorConfig, mounting: Calibration) -> Calibrator {
        let mut c = Calibrator::new(config);
        c.mounting = Some(mounting);
        c
    }

    /// The accepted calibration, if any (with the latest heading corrections).
    pub fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }

    /// Takes one input frame, writes its output frame into `out` (header included) and says what
    /// happened, if anything.
    pub fn push(&mut self, frame: &ImuFrame, out: &mut BodyImuFrame) -> Option<Event> {
        let time_s = self.clock.time_s(frame.header.capture_ns);
        let sample = Sample::from_frame(frame, time_s, self.config.sites);
        self.count_invalid(&sample);
        let still = self.detector.push(&sample);
        let index = self.frames;
        self.frames += 1;
        if self.buffer.len() == self.capacity {
            self.buffer.pop_front();
        }
        self.buffer.push_back(sample);
        let hold = self
            .segmenter
            .push(index, still)
            .and_then(|hold| self.on_hold(&hold, sample.seq));
        // A hold is reported on a still frame, a natural start's attempt on a moving one: never
        // both at once.
        let event = self.on_walk(index, still, sample.seq).or(hold);
        self.write_output(frame, &sample, out);
        event
    }

    /// Writes `frame`'s output with the calibration as it is now (flagged CALIBRATING | INVALID
    /// when there is none), without taking the frame into the session: offline, the frames held
    /// while calibrating are released calibrated by the calibration accepted after them.
    pub fn calibrate_held(&self, frame: &ImuFrame, out: &mut BodyImuFrame) {
        let sample = Sample::from_frame(frame, 0.0, self.config.sites);
        self.write_output(frame, &sample, out);
    }

    /// Ends the session: the calibration, or why there is none.
    pub fn finish(&self) -> Result<&Calibration, NotCalibrated> {
        self.calibration.as_ref().ok_or_else(|| NotCalibrated {
            method: self.config.method.name(),
            frames: self.frames,
            reason: self.reason(),
        })
    }

    fn count_invalid(&mut self, sample: &Sample) {
        for k in self.config.sites.sites().map(Imu::index) {
            let usable = sample.valid_mask & (1 << k) != 0;
            match self.first_usable[k] {
                None if usable => self.first_usable[k] = Some(self.frames),
                Some(_) if !usable => self.invalid_frames[k] += 1,
                _ => {}
            }
        }
    }

    fn write_output(&self, frame: &ImuFrame, sample: &Sample, out: &mut BodyImuFrame) {
        *out = BodyImuFrame {
            header: FrameHeader {
                flags: frame.header.flags & (flags::INVALID | flags::CALIBRATING),
                ..frame.header
            },
            ..Default::default()
        };
        match &self.calibration {
            Some(c) => c.apply(sample, out),
            None => {
                out.header.flags |= flags::CALIBRATING | flags::INVALID;
                for k in self.config.sites.sites().map(Imu::index) {
                    out.bone_orientation_wxyz[k] = [1.0, 0.0, 0.0, 0.0];
                }
            }
        }
    }

    fn on_hold(&mut self, hold: &Hold, seq: u64) -> Option<Event> {
        self.holds += 1;
        // Holds are rare (seconds apart): one O(buffer) move makes every window a plain slice.
        self.buffer.make_contiguous();
        match (self.config.method, self.calibration.is_some()) {
            (Method::Tpose, false) => Some(self.try_tpose(hold, seq)),
            (Method::Walking, false) => Some(self.try_walking(hold, seq)),
            (Method::Walking, true) if self.config.drift_update => {
                self.try_heading_update(hold, seq)
            }
            _ => None,
        }
    }

    fn try_tpose(&mut self, hold: &Hold, seq: u64) -> Event {
        let window = self.average_window(&hold.hold, 0);
        let result = calibrate_tpose(self.slice(window), &self.config.tpose()).map(|c| (c, None));
        self.accept(result, seq)
    }

    fn try_walking(&mut self, hold: &Hold, seq: u64) -> Event {
        let result = match self.step_windows(hold) {
            None => return Event::Stand { seq },
            Some(Err(reason)) => Err(reason),
            Some(Ok(w)) => calibrate_walking(&self.windows(&w), &self.config.walking())
                .map(|e| (e.calibration, e.walk_direction)),
        };
        self.accept(result, seq)
    }

    fn try_heading_update(&mut self, hold: &Hold, seq: u64) -> Option<Event> {
        let result = match self.step_windows(hold)? {
            Err(reason) => Err(reason),
            Ok(w) => measure_step(&self.windows(&w), &self.config.walking()),
        };
        let calibration = self.calibration.as_mut()?;
        Some(match result {
            Err(reason) => Event::HeadingUpdateSkipped { seq, reason },
            Ok(geometry) => {
                let previous_rad = calibration.heading_corrections_rad();
                for (s, psi) in calibration
                    .sensors
                    .iter_mut()
                    .zip(geometry.heading_to_pelvis_rad)
                {
                    s.heading_correction_rad = psi;
                }
                Event::HeadingUpdated {
                    seq,
                    sites: self.config.sites,
                    previous_rad,
                    corrections_rad: geometry.heading_to_pelvis_rad,
                }
            }
        })
    }

    /// Takes an attempt's outcome: a calibration (with a natural start's walking direction, for
    /// the log) or why it must be redone.
    fn accept(
        &mut self,
        result: Result<(Calibration, Option<WalkDirection>), Rejection>,
        seq: u64,
    ) -> Event {
        match result {
            Ok((mut calibration, walk_direction)) => {
                if let Some(mounting) = &self.mounting {
                    for (sensor, kept) in calibration.sensors.iter_mut().zip(&mounting.sensors) {
                        sensor.sensor_from_bone = kept.sensor_from_bone;
                    }
                }
                self.calibration = Some(calibration.clone());
                Event::Calibrated {
                    seq,
                    calibration: Box::new(calibration),
                    walk_direction,
                }
            }
            Err(reason) => {
                self.last_rejection = Some(reason.clone());
                Event::Rejected { seq, reason }
            }
        }
    }

    /// The natural start: a stand of at least `walk_stand_s`, then `walk_s` of motion with no
    /// stand of that length in between, is one attempt (once per stand).
    fn on_walk(&mut self, index: u64, still: bool, seq: u64) -> Option<Event> {
        let config = self.config;
        let stand_frames = config.frames(config.walk_stand_s);
        let window_frames = config.frames(config.still_window_s);
        let stand = self
            .walk_start
            .push(index, still, stand_frames, window_frames)?;
        if config.method != Method::Walking || !config.walk_start || self.calibration.is_some() {
            return None;
        }
        if index + 1 - stand.end != config.frames(config.walk_s) {
            return None;
        }
        self.walk_attempts += 1;
        self.buffer.make_contiguous();
        // The stand's end is where the stillness test saw motion start; a slow start began up to
        // a window before it, and `motion_onset` finds where, sample by sample. The orientations
        // are averaged skipping up to a window before that onset where the stand is long enough,
        // else less, down to STAND_END_SKIP_S, keeping STAND_AVERAGE_MIN_S (a 0.3 s stand kept 3
        // samples otherwise); the accelerometer offset, whose noise matters more, keeping
        // OFFSET_AVERAGE_MIN_S (both measured in the calibration README, "How short a stand").
        // The walk is integrated from a margin before the stand's end.
        let end_skip = config.frames(STAND_END_SKIP_S).min(window_frames);
        let onset =
            stand.start + motion_onset(self.slice(stand.clone()), window_frames as usize) as u64;
        let still = stand.start..onset.max(stand.start + 1);
        let skip_keeping = |keep_s: f64| {
            (still.end - still.start)
                .saturating_sub(config.frames(keep_s))
                .clamp(end_skip, window_frames)
        };
        let stand_window = self.average_window(&still, skip_keeping(STAND_AVERAGE_MIN_S));
        let offset_window = self.average_window(&still, skip_keeping(OFFSET_AVERAGE_MIN_S));
        let walk_window = stand
            .end
            .saturating_sub(config.margin_frames())
            .max(stand.start)..index + 1;
        let windows = WalkStartWindows {
            stand: self.slice(stand_window),
            offset_stand: self.slice(offset_window),
            walk: self.slice(walk_window),
        };
        let result = calibrate_walk_start(&windows, &config.walk_start_config())
            .map(|e| (e.calibration, e.walk_direction));
        Some(self.accept(result, seq))
    }

    /// The three windows of a stand–motion–stand (`None` for a first stand).
    fn step_windows(&self, hold: &Hold) -> Option<Result<[Range<u64>; 3], Rejection>> {
        let previous = hold.previous.as_ref()?;
        let motion_frames = hold.motion_frames()?;
        if motion_frames > self.config.frames(self.config.max_step_s) {
            return Some(Err(Rejection::MotionTooLong {
                secs: motion_frames as f64 / self.config.nominal_rate_hz,
                max_s: self.config.max_step_s,
            }));
        }
        let margin = self.config.margin_frames();
        let motion = previous.end.saturating_sub(margin).max(previous.start)
            ..(hold.hold.start + margin).min(hold.hold.end);
        Some(Ok([
            self.average_window(previous, margin),
            motion,
            self.average_window(&hold.hold, 0),
        ]))
    }

    fn windows(&self, w: &[Range<u64>; 3]) -> StepWindows<'_> {
        StepWindows {
            before: self.slice(w[0].clone()),
            motion: self.slice(w[1].clone()),
            after: self.slice(w[2].clone()),
        }
    }

    /// The last `average_s` of `hold`, ending `skip_end` frames before its end (kept inside it).
    fn average_window(&self, hold: &Range<u64>, skip_end: u64) -> Range<u64> {
        let end = hold.end.saturating_sub(skip_end).max(hold.start + 1);
        end.saturating_sub(self.config.frames(self.config.average_s))
            .max(hold.start)..end
    }

    /// The buffered samples of frames `range`, clipped to what the buffer still holds. Call
    /// `make_contiguous` on the buffer first (`on_hold` does).
    fn slice(&self, range: Range<u64>) -> &[Sample] {
        let first = self.frames - self.buffer.len() as u64;
        let (held, _) = self.buffer.as_slices();
        let start = (range.start.max(first) - first) as usize;
        let end = (range.end.saturating_sub(first) as usize).min(held.len());
        held.get(start..end).unwrap_or_default()
    }

    /// Why there is no calibration: one line per cause, each naming the rule of the method in
    /// use, what the data held, and the parameter that would change it.
    fn reason(&self) -> String {
        let config = &self.config;
        if self.frames == 0 {
            return "- no frames arrived".into();
        }
        let rate = config.nominal_rate_hz;
        let secs = |frames: u64| frames as f64 / rate;
        let never: Vec<&str> = (config.sites.sites().map(Imu::index))
            .filter(|&k| self.first_usable[k].is_none())
            .map(sensor_name)
            .collect();
        if !never.is_empty() {
            return format!(
                "- {} never had a usable sample (missing, NaN, infinite or a zero quaternion) in \
                 {} frames: is the sensor mapped to that site, and did it record?",
                never.join(", "),
                self.frames
            );
        }
        let mut causes = Vec::new();
        if let Some(rejection) = &self.last_rejection {
            causes.push(format!("last attempt rejected: {rejection}"));
        }
        let longest = self.walk_start.longest.clone();
        let longest_s = longest.as_ref().map(|run| secs(run.end - run.start));
        let longest_text = match &longest {
            Some(run) => format!(
                "the longest still period was {:.2} s (at {:.1}–{:.1} s)",
                secs(run.end - run.start),
                secs(run.start),
                secs(run.end)
            ),
            None => "no still period at all".to_owned(),
        };
        let stillness = format!(
            "still: every sensor's mean angular rate < still_gyro_radps = {} rad/s and its \
             accelerometer std < still_accel_std_mps2 = {} m/s² over still_window_s = {} s",
            config.still_gyro_radps, config.still_accel_std_mps2, config.still_window_s
        );
        match config.method {
            Method::Walking => {
                if config.walk_start {
                    let rule = format!(
                        "natural start (a still period of walk_stand_s = {} s, then walk_s = {} s \
                         of walking)",
                        config.walk_stand_s, config.walk_s
                    );
                    let found = match longest_s {
                        _ if self.walk_attempts > 0 => format!(
                            "{} attempt(s), none accepted (the last attempt's reason is above)",
                            self.walk_attempts
                        ),
                        Some(s) if s >= config.walk_stand_s => format!(
                            "{longest_text}, but walk_s = {} s of walking never followed a stand \
                             (the data ended, or the subject stood still again first)",
                            config.walk_s
                        ),
                        Some(s) if s >= MIN_WALK_STAND_S => format!(
                            "{longest_text}; walk_stand_s = {:.2} would take it ({stillness})",
                            (s * 100.0).floor() / 100.0
                        ),
                        Some(_) => format!(
                            "{longest_text}, shorter than any walk_stand_s allows \
                             ({MIN_WALK_STAND_S} s): stand still before walking ({stillness})"
                        ),
                        None => format!("{longest_text} ({stillness})"),
                    };
                    causes.push(format!("{rule}: {found}"));
                }
                causes.push(format!(
                    "stand–step–stand (two stands of hold_s = {} s, at most max_step_s = {} s of \
                     motion between): {} stand(s) seen{}",
                    config.hold_s,
                    config.max_step_s,
                    self.holds,
                    if self.holds == 1 {
                        ", no step and second stand after it"
                    } else {
                        ""
                    }
                ));
            }
            Method::Tpose if self.holds == 0 => causes.push(format!(
                "tpose: no still period of hold_s = {} s in {:.1} s of data: {longest_text} \
                 ({stillness})",
                config.hold_s,
                secs(self.frames)
            )),
            Method::Tpose | Method::None => {}
        }
        let invalid: Vec<String> = (config.sites.sites().map(Imu::index))
            .filter(|&k| self.invalid_frames[k] > 0)
            .map(|k| {
                let since = self.first_usable[k].unwrap_or(0);
                format!(
                    "{} in {} of {} frames",
                    sensor_name(k),
                    self.invalid_frames[k],
                    self.frames - since
                )
            })
            .collect();
        if !invalid.is_empty() {
            causes.push(format!(
                "unusable samples after a sensor's first (lost, NaN, infinite or a zero \
                 quaternion; each breaks stillness and spoils an attempt): {}",
                invalid.join(", ")
            ));
        }
        let lines: Vec<String> = causes.iter().map(|c| format!("- {c}")).collect();
        lines.join("\n")
    }
}
