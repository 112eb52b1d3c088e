//! The `calibration` stage process: reads `imu`, writes `body_imu`, logs what the calibration
//! does, saves / loads calibration files.

use std::collections::VecDeque;
use std::path::PathBuf;

use anyhow::{Context, bail};
use imuflow_graph::frames::{BodyImuFrame, FrameHeader, ImuFrame, flags};
use imuflow_graph::params::StageParams;
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::stage::Params;
use imuflow_graph::transport::Output;
use imuflow_graph::{FrameType, Mode, StageContext};

use crate::calibration::{Calibration, Method};
use crate::calibrator::{Calibrator, CalibratorConfig, Event};
use crate::convention::{InertialFrame, ReferencePose};
use crate::walking::WalkDirection;
use crate::{file, sensor_name};

imuflow_graph::stage_params! {
    /// The calibration stage's parameters, and so [`CalibratorConfig::default`].
    pub struct CalibrationParams {
        /// tpose: held pose with a known inertial frame; walking: stand, one step forward, stand;
        /// none: readings are already R_MB in M
        method: Method = "tpose", choice(&Method::NAMES);
        /// load this calibration file (JSON) and skip calibrating
        from_file: Option<PathBuf>, path;
        /// write the accepted calibration (and later heading updates) to this JSON file
        save_to: Option<PathBuf>, path;
        /// with from_file: file takes the whole calibration; recording keeps the file's sensor
        /// mountings (R_SB) and finds the headings and offsets from this recording's own start
        /// (one calibration per capture day; needed with 6D fusion, whose headings differ per
        /// recording)
        headings: String = "file", choice(&["file", "recording"]);
        /// sensors' inertial-frame convention: model (I = M), z-up (Xsens-like), z-down
        /// (Noitom-like)
        frame: InertialFrame = "model", choice(&InertialFrame::NAMES);
        /// tpose: direction the subject faces in I, right-handed about up from the convention's
        /// forward axis (model: +z, z-up/z-down: +x)
        heading_deg: f64 = 0, float(-360.0, 360.0);
        /// the pose held (tpose) or stood in (walking): t = arms out, n = arms down and straight,
        /// relaxed = arms down with the elbows bent 25°
        pose: Option<ReferencePose> = computed("t for tpose, n for a stand-step-stand, relaxed for a natural start"), choice(&["t", "n", "relaxed"]);
        /// estimate the accelerometer offset while still and subtract it
        accel_offset: bool = true, bool;
        /// walking: re-estimate the heading corrections at every later stand-step-stand
        drift_update: bool = true, bool;
        /// a still period counts as a hold / stand after this long, s
        hold_s: f64 = 1.5, float(0.3, 60.0);
        /// the end of a hold averaged for orientations and offsets, s
        average_s: f64 = 1.0, float(0.1, 60.0);
        /// trailing window of the stillness test, s
        still_window_s: f64 = 0.25, float(0.05, 5.0);
        // A standing person sways at a few 0.01 rad/s and ~0.1 m/s²; a step turns the shanks at
        // several rad/s.
        /// still: mean angular-rate norm of every sensor below this, rad/s
        still_gyro_radps: f64 = 0.3, float(0.0, 10.0);
        /// still: std of every sensor's specific force below this, m/s²
        still_accel_std_mps2: f64 = 0.4, float(0.0, 10.0);
        /// walking: longest motion between two stands that counts as one step, s
        max_step_s: f64 = 3.0, float(0.2, 30.0);
        // Reference §4: GlobalPose's gravity sanity check (8°), walking_6dof's thresholds (20°,
        // 0.1 m).
        /// largest angle between measured gravity and the frame's down axis, deg
        max_gravity_deg: f64 = 8, float(0.0, 180.0);
        /// walking: largest orientation change of a sensor between the stands, deg
        max_pose_change_deg: f64 = 20, float(0.0, 180.0);
        /// walking: largest vertical displacement of a sensor over the step, m
        max_vertical_m: f64 = 0.1, float(0.0, 10.0);
        /// walking: shortest pelvis step, m
        min_step_m: f64 = 0.2, float(0.0, 10.0);
        /// walking: longest pelvis step, m
        max_step_m: f64 = 1.5, float(0.0, 10.0);
        /// walking: largest difference of a sensor's step length from the pelvis's, m
        max_step_mismatch_m: f64 = 0.15, float(0.0, 10.0);
        /// walking: also calibrate from a stand followed by natural walking (no step, no stand
        /// after); the heading corrections come from the walk
        walk_start: bool = true, bool;
        /// walking (natural start): standing still this long counts as the stand before walking
        /// (the still samples, the stillness window included), s
        walk_stand_s: f64 = 0.3, float(crate::calibrator::MIN_WALK_STAND_S, 60.0);
        /// walking (natural start): walking integrated after the stand, s
        walk_s: f64 = 3.0, float(0.5, 30.0);
        /// walking (natural start): direction of that walk relative to the way the subject faces,
        /// right-handed about up: 0 forward, 90 left, -90 right, 180 backwards; unset, the legs
        /// tell (a warning when a set direction contradicts them)
        walk_direction_deg: Option<f64> = computed("from the legs"), float(-360.0, 360.0);
        /// walking (natural start): shortest pelvis displacement over the walk, m
        min_walk_m: f64 = 0.5, float(0.0, 100.0);
        /// walking (natural start): largest RMS distance of a sensor's path from the pelvis's, m
        max_walk_mismatch_m: f64 = 0.5, float(0.0, 100.0);
        /// walking (natural start): largest vertical displacement of a sensor over the walk, m
        max_walk_vertical_m: f64 = 0.3, float(0.0, 100.0);
        /// walking (natural start): largest turn of the walking direction, deg
        max_walk_turn_deg: f64 = 25, float(0.0, 180.0);
        /// offline: hold the frames until the calibration is accepted, then release them
        /// calibrated, so a recording is estimated from its first frame (live graphs never hold)
        backfill: bool = true, bool;
        /// offline: the most a backfill holds, s; older frames go out uncalibrated
        backfill_max_s: f64 = 600, float(1.0, 86400.0);
    }
}

impl CalibrationParams {
    /// The session configuration at the graph's rate, which must be positive.
    pub fn config(&self, rate_hz: f64) -> anyhow::Result<CalibratorConfig> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            bail!("the graph's rate_hz must be positive, got {rate_hz}");
        }
        Ok(self.config_at(rate_hz))
    }

    /// The session configuration at `rate_hz`, unchecked.
    pub(crate) fn config_at(&self, rate_hz: f64) -> CalibratorConfig {
        let pose = self.pose.unwrap_or(match self.method {
            Method::Walking => ReferencePose::N,
            Method::Tpose | Method::None => ReferencePose::T,
        });
        CalibratorConfig {
            method: self.method,
            frame: self.frame,
            pose,
            // Told nothing, people stand with their elbows bent; the forearms' mountings cannot
            // tell the bend (journal 2026-11-29-the-standing-elbow), so it is assumed.
            walk_start_pose: self.pose.unwrap_or(ReferencePose::Relaxed),
            heading_rad: self.heading_deg.to_radians(),
            accel_offset: self.accel_offset,
            drift_update: self.drift_update,
            nominal_rate_hz: rate_hz,
            hold_s: self.hold_s,
            average_s: self.average_s,
            still_window_s: self.still_window_s,
            still_gyro_radps: self.still_gyro_radps,
            still_accel_std_mps2: self.still_accel_std_mps2,
            max_step_s: self.max_step_s,
            max_gravity_deg: self.max_gravity_deg,
            max_pose_change_deg: self.max_pose_change_deg,
            max_vertical_m: self.max_vertical_m,
            min_step_m: self.min_step_m,
            max_step_m: self.max_step_m,
            max_step_mismatch_m: self.max_step_mismatch_m,
            walk_start: self.walk_start,
            walk_stand_s: self.walk_stand_s,
            walk_s: self.walk_s,
            walk_direction_rad: self.walk_direction_deg.map(f64::to_radians),
            min_walk_m: self.min_walk_m,
            max_walk_mismatch_m: self.max_walk_mismatch_m,
            max_walk_vertical_m: self.max_walk_vertical_m,
            max_walk_turn_deg: self.max_walk_turn_deg,
            sites: imuflow_body::SiteMask::of(imuflow_body::Imu::SIX),
        }
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "calibration",
    role: Role::Transform,
    summary: "T-pose or walking calibration (GlobalPose §3.4): raw IMUs -> bone orientations, free acceleration and angular velocity in M",
    inputs: InputsSpec::Fixed(&[PortSpec {
        name: "imu",
        frame: FrameType::Imu,
        required: true,
        doc: "raw IMUs: orientation R_IS, specific force and angular rate in the sensor frame",
    }]),
    outputs: &[PortSpec {
        name: "body_imu",
        frame: FrameType::BodyImu,
        required: false,
        doc: "calibrated: R_MB, free acceleration and angular velocity in M, heading corrections; CALIBRATING | INVALID until calibrated",
    }],
    params: CalibrationParams::SPECS,
};

/// The session configuration from a stage's parameters (validated by the graph already; the
/// checks here cover external callers: a value of the wrong type or choice is an error).
pub fn config_from_params(params: &Params<'_>, rate_hz: f64) -> anyhow::Result<CalibratorConfig> {
    CalibrationParams::try_from_params(params.0)
        .map_err(anyhow::Error::msg)?
        .config(rate_hz)
}

/// A path parameter, where it names a file (an empty string does not).
fn path_param(path: &Option<PathBuf>) -> Option<PathBuf> {
    path.clone().filter(|p| !p.as_os_str().is_empty())
}

/// Runs the calibration as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = CalibrationParams::from_params(ctx.params());
    let mut config = params
        .config(ctx.graph().rate_hz)
        .with_context(|| format!("stage '{stage}'"))?;
    let sensors = imuflow_body::SensorSet::resolve(ctx.sensors())
        .with_context(|| format!("stage '{stage}': `sensors`"))?;
    config.sites = sensors.mask();
    if config.method == Method::Walking && sensors.heading_reference() != imuflow_body::Imu::Pelvis
    {
        bail!(
            "stage '{stage}': method = \"walking\" takes the body's heading from the pelvis sensor; \
             the sensor set {} names {} as its heading_reference (set heading_reference = \"pelvis\" \
             in the set file, or calibrate with method = \"tpose\", which takes no sensor's heading)",
            sensors.name(),
            sensors.heading_reference().name()
        );
    }
    if let Some(missing) = method_needs(config.method, &sensors) {
        bail!(
            "stage '{stage}': method = \"walking\" takes the body's heading from the pelvis and \
             the walk's direction from both lower legs; the stage's sensors {sensors} lack {missing} \
             (method = \"tpose\" calibrates any set)"
        );
    }
    let save_to = path_param(&params.save_to);
    // A restart (the graph's `restart` policy) reloads the calibration the stage had reached
    // before it failed, instead of asking the subject to calibrate again.
    let kept = ctx.run_file("calibration.json");
    let from_file = match &kept {
        Some(path) if ctx.restarts() > 0 && path.exists() => Some(path.clone()),
        _ => path_param(&params.from_file),
    };
    if params.headings == "recording" && from_file.is_none() {
        bail!(
            "stage '{stage}': params.headings = \"recording\" keeps the sensor mountings of a \
             calibration file: set params.from_file (the capture day's calibration) or \
             headings = \"file\""
        );
    }
    let mut calibrator = match &from_file {
        Some(path) => {
            let calibration =
                file::load(path).with_context(|| format!("stage '{stage}': from_file"))?;
            if calibration.sites != sensors.mask() {
                bail!(
                    "stage '{stage}': from_file '{}' calibrates the sensors ({}); the stage's sensors are {sensors}",
                    path.display(),
                    calibration.sites.names()
                );
            }
            tracing::info!(
                stage,
                "loaded the {} calibration from {}",
                calibration.method.name(),
                path.display()
            );
            log_calibration(&stage, &calibration);
            // A restart reloads what this run had reached, whole.
            if params.headings == "recording" && Some(path) != kept.as_ref() {
                tracing::info!(
                    stage,
                    "keeping its sensor mountings (R_SB); headings and offsets from this recording"
                );
                Calibrator::with_mounting(config, calibration)
            } else {
                Calibrator::with_calibration(config, calibration)
            }
        }
        None => Calibrator::new(config),
    };
    let input = ctx.input::<ImuFrame>("imu")?;
    let mut output = ctx.output::<BodyImuFrame>("body_imu")?;
    if !ctx.ready()? {
        ctx.finish(&mut [&mut output])?;
        return Ok(());
    }
    let live = ctx.mode() == Mode::Live;
    // A prompt is for a subject standing there: live only. With the natural start on, walking on
    // calibrates, so it does not ask for a step.
    let stand_prompt = match (live, params.walk_start) {
        (false, _) => None,
        (true, true) => Some("standing still: now walk straight on for a few seconds"),
        (true, false) => Some("standing still: now take one step forward and stand still again"),
    };
    let mut backfill = Backfill {
        holding: params.backfill && !live && calibrator.calibration().is_none(),
        max_frames: (params.backfill_max_s * ctx.graph().rate_hz).ceil() as usize,
        held: VecDeque::new(),
    };
    while let Some(step) = ctx.next()? {
        let frame = *ctx.get(&input);
        let mut body = BodyImuFrame::default();
        if let Some(event) = calibrator.push(&frame, &mut body) {
            on_event(
                &stage,
                &event,
                calibrator.calibration(),
                save_to.as_deref(),
                stand_prompt,
            )?;
            keep_for_restart(&event, calibrator.calibration(), kept.as_deref());
        }
        if backfill.hold(step.header(), frame, &calibrator, &mut output)? {
            continue;
        }
        output
            .publish(step.header(), |f| *f = body)
            .with_context(|| format!("stage '{stage}': publishing frame {}", step.seq))?;
    }
    // Whatever is still held goes out, calibrated if the calibration came at the very end.
    backfill.release(&calibrator, &mut output)?;
    // END_OF_STREAM goes downstream even when the calibration never completed.
    let outcome = calibrator.finish().map(|_| ());
    ctx.finish(&mut [&mut output])?;
    outcome.with_context(|| format!("stage '{stage}'"))
}

/// Offline, the frames that arrive before the calibration is accepted: held, then released
/// calibrated (by the calibration accepted later), so a recording is estimated from its first
/// frame. Live graphs never hold: a subject calibrating live sees the avatar once calibrated.
/// A synthesizing source's calibration prelude (frames flagged PRELUDE, which no score counts)
/// is not held: it is the calibration's, not the recording's, and passing it on as before keeps
/// every session whose calibration ends inside its prelude exactly as it was.
struct Backfill {
    holding: bool,
    max_frames: usize,
    held: VecDeque<(FrameHeader, ImuFrame)>,
}

impl Backfill {
    /// Takes the step's input frame while no calibration is accepted (true: held, publish
    /// nothing now). Once one is, releases what it held, calibrated, before the step's own frame.
    fn hold(
        &mut self,
        header: FrameHeader,
        frame: ImuFrame,
        calibrator: &Calibrator,
        output: &mut Output<BodyImuFrame>,
    ) -> anyhow::Result<bool> {
        if !self.holding {
            return Ok(false);
        }
        let prelude = frame.header.flags & flags::PRELUDE != 0;
        if calibrator.calibration().is_none() && !(prelude && self.held.is_empty()) {
            self.held.push_back((header, frame));
            if self.held.len() > self.max_frames {
                // Past the bound the oldest frame goes out as it is now: uncalibrated.
                self.release_one(calibrator, output)?;
            }
            return Ok(true);
        }
        if calibrator.calibration().is_some() {
            self.release(calibrator, output)?;
            self.holding = false;
        }
        Ok(false)
    }

    fn release(
        &mut self,
        calibrator: &Calibrator,
        output: &mut Output<BodyImuFrame>,
    ) -> anyhow::Result<()> {
        if !self.held.is_empty() && calibrator.calibration().is_some() {
            tracing::info!(
                "the {} frames before the calibration was accepted go out calibrated by it",
                self.held.len()
            );
        }
        while !self.held.is_empty() {
            self.release_one(calibrator, output)?;
        }
        Ok(())
    }

    fn release_one(
        &mut self,
        calibrator: &Calibrator,
        output: &mut Output<BodyImuFrame>,
    ) -> anyhow::Result<()> {
        let Some((header, frame)) = self.held.pop_front() else {
            return Ok(());
        };
        let mut body = BodyImuFrame::default();
        calibrator.calibrate_held(&frame, &mut body);
        output
            .publish(header, |f| *f = body)
            .with_context(|| format!("publishing held frame {}", header.seq))?;
        Ok(())
    }
}

fn on_event(
    stage: &str,
    event: &Event,
    current: Option<&Calibration>,
    save_to: Option<&std::path::Path>,
    stand_prompt: Option<&str>,
) -> anyhow::Result<()> {
    match event {
        Event::Stand { seq } => match stand_prompt {
            Some(prompt) => tracing::info!(stage, seq, "{prompt}"),
            None => tracing::debug!(stage, seq, "a stand of hold_s"),
        },
        Event::Rejected { seq, reason } => tracing::warn!(stage, seq, "redo calibration: {reason}"),
        Event::HeadingUpdateSkipped { seq, reason } => {
            tracing::debug!(
                stage,
                seq,
                "stand-motion-stand not used for a heading update: {reason}"
            )
        }
        Event::Calibrated {
            seq,
            calibration,
            walk_direction,
        } => {
            tracing::info!(
                stage,
                seq,
                "{} calibration accepted",
                calibration.method.name()
            );
            if let Some(direction) = walk_direction {
                log_walk_direction(stage, direction);
            }
            log_calibration(stage, calibration);
        }
        Event::HeadingUpdated {
            seq,
            sites,
            previous_rad,
            corrections_rad,
        } => {
            let change: Vec<String> = (sites.sites().map(|s| s.index()))
                .map(|k| {
                    format!(
                        "{} {:+.1}°",
                        sensor_name(k),
                        (corrections_rad[k] - previous_rad[k]).to_degrees()
                    )
                })
                .collect();
            tracing::info!(
                stage,
                seq,
                "heading drift re-estimated: {}",
                change.join(", ")
            );
        }
    }
    let changed = matches!(
        event,
        Event::Calibrated { .. } | Event::HeadingUpdated { .. }
    );
    if let (true, Some(path), Some(calibration)) = (changed, save_to, current) {
        file::save(calibration, path).with_context(|| format!("stage '{stage}': save_to"))?;
        tracing::info!(stage, "calibration saved to {}", path.display());
    }
    Ok(())
}

/// Every accepted or updated calibration goes to the run folder too, for a restart of this stage
/// to reload (best effort: a run folder that cannot be written only costs a recalibration).
fn keep_for_restart(event: &Event, current: Option<&Calibration>, path: Option<&std::path::Path>) {
    let changed = matches!(
        event,
        Event::Calibrated { .. } | Event::HeadingUpdated { .. }
    );
    if let (true, Some(path), Some(calibration)) = (changed, path, current)
        && let Err(e) = file::save(calibration, path)
    {
        tracing::warn!(
            "cannot keep the calibration for a restart in {}: {e:#}",
            path.display()
        );
    }
}

/// Which way the natural start's walk went, and on whose word; a warning when a set
/// `walk_direction_deg` contradicts the legs.
fn log_walk_direction(stage: &str, d: &WalkDirection) {
    let deg = |rad: f64| rad.to_degrees().round();
    let legs = match d.from_legs_rad {
        Some(rad) => format!(
            "the legs say {} ({:+.0}°, {:+.0}° before rounding; mean shank lean {:.1}°; {})",
            WalkDirection::name(rad),
            deg(rad),
            deg(d.legs_rad),
            d.lean.asin().to_degrees(),
            match d.flexion_rad {
                Some(f) => format!("their flexion axes: {:+.1}° from facing", f.to_degrees()),
                None => "their flexion axes cannot tell".to_owned(),
            }
        ),
        None => format!(
            "the legs cannot tell (mean shank lean {:.1}°)",
            d.lean.asin().to_degrees()
        ),
    };
    if let Some((given, from_legs)) = d.contradiction() {
        tracing::warn!(
            stage,
            "walk_direction_deg = {} ({}) but the legs say {} ({:+.0}°): used the setting; \
             unset it to follow the legs",
            deg(given),
            WalkDirection::name(given),
            WalkDirection::name(from_legs),
            deg(from_legs)
        );
    } else if d.given_rad.is_none() && d.from_legs_rad.is_none() {
        tracing::warn!(
            stage,
            "the walk's direction: {legs}; assumed forward (set walk_direction_deg if not)"
        );
    } else {
        tracing::info!(
            stage,
            "the walk went {} relative to facing: {legs}",
            WalkDirection::name(d.used_rad)
        );
    }
}

/// The sites `method` needs that `sensors` lacks (their names), if any: the walking calibrations
/// take the heading from the pelvis and the walk's direction from the shanks.
fn method_needs(method: Method, sensors: &imuflow_body::SensorSet) -> Option<String> {
    use imuflow_body::Imu;
    if method != Method::Walking {
        return None;
    }
    let needed = imuflow_body::SiteMask::of([Imu::Pelvis, Imu::LeftLowerLeg, Imu::RightLowerLeg]);
    let missing = needed.missing_from(sensors.mask());
    (!missing.is_empty()).then(|| missing.names())
}

fn log_calibration(stage: &str, c: &Calibration) {
    for k in c.sites.sites().map(|s| s.index()) {
        let sensor = &c.sensors[k];
        let v = imuflow_body::rotation::axis_angle_from_rotation(&sensor.sensor_from_bone);
        let axis = v / v.norm().max(1e-12);
        tracing::info!(
            stage,
            "{}: heading correction {:+.1}°, R_SB {:.1}° about ({:.2}, {:.2}, {:.2})",
            sensor_name(k),
            sensor.heading_correction_rad.to_degrees(),
            v.norm().to_degrees(),
            axis.x,
            axis.y,
            axis.z,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<CalibrationParams>().unwrap();
    }

    #[test]
    fn the_pose_is_t_for_tpose_n_for_a_step_and_relaxed_for_a_natural_start_unless_set() {
        let at = |method, pose| {
            let config = CalibrationParams {
                method,
                pose,
                ..CalibrationParams::default()
            }
            .config_at(60.0);
            (config.pose, config.walk_start_pose)
        };
        use ReferencePose::{N, Relaxed, T};
        assert_eq!(at(Method::Tpose, None), (T, Relaxed));
        assert_eq!(at(Method::None, None), (T, Relaxed));
        assert_eq!(at(Method::Walking, None), (N, Relaxed));
        assert_eq!(at(Method::Walking, Some(N)), (N, N));
        assert_eq!(at(Method::Tpose, Some(N)), (N, N));
        assert_eq!(
            SPEC.params
                .iter()
                .find(|p| p.name == "pose")
                .map(|p| p.default),
            Some("t for tpose, n for a stand-step-stand, relaxed for a natural start"),
            "the text names what config_at computes"
        );
    }

    #[test]
    fn external_callers_get_an_error_for_a_value_the_validator_refuses() {
        use imuflow_graph::params::toml;
        let mut table = toml::Table::new();
        table.insert("method".into(), toml::Value::String("magic".into()));
        let err = config_from_params(&Params(&table), 60.0).unwrap_err();
        assert!(err.to_string().contains("params.method"), "{err}");
        assert!(config_from_params(&Params(&toml::Table::new()), 0.0).is_err());
    }
}
