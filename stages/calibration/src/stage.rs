//! The `calibration` stage process: reads `imu`, writes `body_imu`, logs what the calibration
//! does, saves / loads calibration files.

use std::path::PathBuf;

use anyhow::{Context, bail};
use imuflow_graph::frames::{BodyImuFrame, ImuFrame};
use imuflow_graph::spec::{InputsSpec, ParamSpec, ParamType, PortSpec, Role, StageSpec};
use imuflow_graph::stage::Params;
use imuflow_graph::{FrameType, StageContext};

use crate::calibration::{Calibration, Method};
use crate::calibrator::{Calibrator, CalibratorConfig, Event};
use crate::convention::{InertialFrame, ReferencePose};
use crate::{NUM_IMUS, file, sensor_name};

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
    params: &[
        ParamSpec {
            name: "method",
            ty: ParamType::Choice(&Method::NAMES),
            required: false,
            default: "tpose",
            doc: "tpose: held pose with a known inertial frame; walking: stand, one step forward, stand; none: readings are already R_MB in M",
        },
        ParamSpec {
            name: "from_file",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: "load this calibration file (JSON) and skip calibrating",
        },
        ParamSpec {
            name: "save_to",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: "write the accepted calibration (and later heading updates) to this JSON file",
        },
        ParamSpec {
            name: "frame",
            ty: ParamType::Choice(&InertialFrame::NAMES),
            required: false,
            default: "model",
            doc: "sensors' inertial-frame convention: model (I = M), z-up (Xsens-like), z-down (Noitom-like)",
        },
        ParamSpec::float(
            "heading_deg",
            -360.0,
            360.0,
            "0",
            "tpose: direction the subject faces in I, right-handed about up from the convention's forward axis (model: +z, z-up/z-down: +x)",
        ),
        ParamSpec {
            name: "pose",
            ty: ParamType::Choice(&["t", "n"]),
            required: false,
            default: "t for tpose, n for walking",
            doc: "the pose held (tpose) or stood in (walking): t = arms out, n = arms down",
        },
        ParamSpec {
            name: "accel_offset",
            ty: ParamType::Bool,
            required: false,
            default: "true",
            doc: "estimate the accelerometer offset while still and subtract it",
        },
        ParamSpec {
            name: "drift_update",
            ty: ParamType::Bool,
            required: false,
            default: "true",
            doc: "walking: re-estimate the heading corrections at every later stand-step-stand",
        },
        ParamSpec::float(
            "hold_s",
            0.3,
            60.0,
            "1.5",
            "a still period counts as a hold / stand after this long, s",
        ),
        ParamSpec::float(
            "average_s",
            0.1,
            60.0,
            "1.0",
            "the end of a hold averaged for orientations and offsets, s",
        ),
        ParamSpec::float(
            "still_window_s",
            0.05,
            5.0,
            "0.25",
            "trailing window of the stillness test, s",
        ),
        ParamSpec::float(
            "still_gyro_radps",
            0.0,
            10.0,
            "0.3",
            "still: mean angular-rate norm of every sensor below this, rad/s",
        ),
        ParamSpec::float(
            "still_accel_std_mps2",
            0.0,
            10.0,
            "0.4",
            "still: std of every sensor's specific force below this, m/s²",
        ),
        ParamSpec::float(
            "max_step_s",
            0.2,
            30.0,
            "3.0",
            "walking: longest motion between two stands that counts as one step, s",
        ),
        ParamSpec::float(
            "max_gravity_deg",
            0.0,
            180.0,
            "8",
            "largest angle between measured gravity and the frame's down axis, deg",
        ),
        ParamSpec::float(
            "max_pose_change_deg",
            0.0,
            180.0,
            "20",
            "walking: largest orientation change of a sensor between the stands, deg",
        ),
        ParamSpec::float(
            "max_vertical_m",
            0.0,
            10.0,
            "0.1",
            "walking: largest vertical displacement of a sensor over the step, m",
        ),
        ParamSpec::float(
            "min_step_m",
            0.0,
            10.0,
            "0.2",
            "walking: shortest pelvis step, m",
        ),
        ParamSpec::float(
            "max_step_m",
            0.0,
            10.0,
            "1.5",
            "walking: longest pelvis step, m",
        ),
        ParamSpec::float(
            "max_step_mismatch_m",
            0.0,
            10.0,
            "0.15",
            "walking: largest difference of a sensor's step length from the pelvis's, m",
        ),
    ],
};

/// The session configuration from a stage's parameters (validated by the graph already; the
/// checks here cover external callers).
pub fn config_from_params(params: &Params<'_>, rate_hz: f64) -> anyhow::Result<CalibratorConfig> {
    let d = CalibratorConfig::default();
    let method = match params.str("method") {
        None => d.method,
        Some(m) => Method::parse(m)
            .with_context(|| format!("unknown method '{m}' ({})", Method::NAMES.join(", ")))?,
    };
    let frame = match params.str("frame") {
        None => d.frame,
        Some(f) => InertialFrame::parse(f).with_context(|| {
            format!("unknown frame '{f}' ({})", InertialFrame::NAMES.join(", "))
        })?,
    };
    let pose = match (params.str("pose"), method) {
        (Some(p), _) => {
            ReferencePose::parse(p).with_context(|| format!("unknown pose '{p}' (t or n)"))?
        }
        (None, Method::Walking) => ReferencePose::N,
        (None, _) => ReferencePose::T,
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        bail!("the graph's rate_hz must be positive, got {rate_hz}");
    }
    Ok(CalibratorConfig {
        method,
        frame,
        pose,
        heading_rad: params.float("heading_deg", 0.0).to_radians(),
        accel_offset: params.bool("accel_offset", d.accel_offset),
        drift_update: params.bool("drift_update", d.drift_update),
        nominal_rate_hz: rate_hz,
        hold_s: params.float("hold_s", d.hold_s),
        average_s: params.float("average_s", d.average_s),
        still_window_s: params.float("still_window_s", d.still_window_s),
        still_gyro_radps: params.float("still_gyro_radps", d.still_gyro_radps),
        still_accel_std_mps2: params.float("still_accel_std_mps2", d.still_accel_std_mps2),
        max_step_s: params.float("max_step_s", d.max_step_s),
        max_gravity_deg: params.float("max_gravity_deg", d.max_gravity_deg),
        max_pose_change_deg: params.float("max_pose_change_deg", d.max_pose_change_deg),
        max_vertical_m: params.float("max_vertical_m", d.max_vertical_m),
        min_step_m: params.float("min_step_m", d.min_step_m),
        max_step_m: params.float("max_step_m", d.max_step_m),
        max_step_mismatch_m: params.float("max_step_mismatch_m", d.max_step_mismatch_m),
    })
}

fn path_param(params: &Params<'_>, key: &str) -> Option<PathBuf> {
    params.str(key).filter(|p| !p.is_empty()).map(PathBuf::from)
}

/// Runs the calibration as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = Params(ctx.params());
    let config = config_from_params(&params, ctx.graph().rate_hz)
        .with_context(|| format!("stage '{stage}'"))?;
    let save_to = path_param(&params, "save_to");
    // A restart (the graph's `restart` policy) reloads the calibration the stage had reached
    // before it failed, instead of asking the subject to calibrate again.
    let kept = ctx.run_file("calibration.json");
    let from_file = match &kept {
        Some(path) if ctx.restarts() > 0 && path.exists() => Some(path.clone()),
        _ => path_param(&params, "from_file"),
    };
    let mut calibrator = match &from_file {
        Some(path) => {
            let calibration =
                file::load(path).with_context(|| format!("stage '{stage}': from_file"))?;
            tracing::info!(
                stage,
                "loaded the {} calibration from {}",
                calibration.method.name(),
                path.display()
            );
            log_calibration(&stage, &calibration);
            Calibrator::with_calibration(config, calibration)
        }
        None => Calibrator::new(config),
    };
    let input = ctx.input::<ImuFrame>("imu")?;
    let mut output = ctx.output::<BodyImuFrame>("body_imu")?;
    if !ctx.ready()? {
        ctx.finish(&mut [&mut output])?;
        return Ok(());
    }
    while let Some(step) = ctx.next()? {
        let frame = *ctx.get(&input);
        let mut body = BodyImuFrame::default();
        if let Some(event) = calibrator.push(&frame, &mut body) {
            on_event(&stage, &event, calibrator.calibration(), save_to.as_deref())?;
            keep_for_restart(&event, calibrator.calibration(), kept.as_deref());
        }
        output
            .publish(step.header(), |f| *f = body)
            .with_context(|| format!("stage '{stage}': publishing frame {}", step.seq))?;
    }
    // END_OF_STREAM goes downstream even when the calibration never completed.
    let outcome = calibrator.finish().map(|_| ());
    ctx.finish(&mut [&mut output])?;
    outcome.with_context(|| format!("stage '{stage}'"))
}

fn on_event(
    stage: &str,
    event: &Event,
    current: Option<&Calibration>,
    save_to: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    match event {
        Event::Stand { seq } => tracing::info!(
            stage,
            seq,
            "standing still: now take one step forward and stand still again"
        ),
        Event::Rejected { seq, reason } => tracing::warn!(stage, seq, "redo calibration: {reason}"),
        Event::HeadingUpdateSkipped { seq, reason } => {
            tracing::debug!(
                stage,
                seq,
                "stand-motion-stand not used for a heading update: {reason}"
            )
        }
        Event::Calibrated { seq, calibration } => {
            tracing::info!(
                stage,
                seq,
                "{} calibration accepted",
                calibration.method.name()
            );
            log_calibration(stage, calibration);
        }
        Event::HeadingUpdated {
            seq,
            previous_rad,
            corrections_rad,
        } => {
            let change: Vec<String> = (0..NUM_IMUS)
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

fn log_calibration(stage: &str, c: &Calibration) {
    for (k, sensor) in c.sensors.iter().enumerate() {
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
