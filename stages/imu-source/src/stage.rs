//! The `imu-source` stage process: reads its mode's parameters and runs that mode (see the crate
//! docs).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, Mode, StageContext};
use imuflow_motion::imu_synthesis::AccelStencil;
use imuflow_synth::prelude;
use imuflow_synth::raw::{Magnetometer, RawOptions, RawSession};

use crate::{file, replay, slimevr, synth, udp};

imuflow_graph::stage_params! {
    /// The imu-source's parameters; each doc names the modes that read it.
    pub struct ImuSourceParams {
        /// where the frames come from
        mode: String = "synthesize", choice(&["synthesize", "replay", "udp", "file", "slimevr"]);
        /// synthesize: the motion (.bvh, AMASS-style .npz, or a recording .mcap's truth); replay:
        /// the .mcap recording; file: the recording (a CSV/TSV file or a folder of one file per
        /// sensor, or an .mvnx file) (required for these)
        path: Option<PathBuf>, path;
        /// synthesize: joint-mapping TOML of the BVH skeleton (default: built-in Bandai Namco)
        mapping: Option<PathBuf>, path;
        /// synthesize: subject stature, m (default: the body model's reference subject)
        stature_m: Option<f64>, float(0.5, 2.5);
        /// synthesize: subject mass, kg (default: the body model's reference subject)
        mass_kg: Option<f64>, float(10.0, 300.0);
        /// synthesize: add the reference sensor errors (mounting, noise, bias, heading drift)
        augment: bool = false, bool;
        /// synthesize: seed of the random draws (augmentation, mountings, heading offsets, raw
        /// sensors)
        seed: u64 = 0, int(0, i64::MAX);
        /// synthesize: acceleration stencil (TransPose/PIP smoothed, or central differences)
        stencil: String = "smoothed", choice(&["smoothed", "central"]);
        /// synthesize: calibration poses before the clip: tpose (hold), walk (stand, one step
        /// forward, stand), tpose+walk, stand (N-pose stand, then the clip: a natural start)
        prelude: String = "none", choice(&prelude::PreludeKind::NAMES);
        prelude_stand_s: f64 = use prelude::STAND_PARAM;
        /// synthesize: elbow flexion while standing in the prelude, deg
        prelude_elbow_deg: Option<f64> = computed("25 (relaxed, as people stand unprompted) for stand, 0 (told to straighten) otherwise"), float(0.0, 90.0);
        step_m: f64 = use prelude::STEP_PARAM;
        /// synthesize: sensor frame = bone frame, or each sensor mounted in a random orientation
        /// (seeded by `seed`)
        mounting: String = "bone", choice(&["bone", "random"]);
        /// synthesize: inertial frame the orientations are reported in: model (I = M), z-up
        /// (x forward, z up), z-down (x forward, z down)
        frame: String = "model", choice(&imuflow_synth::InertialFrame::NAMES);
        /// synthesize: direction the subject (facing +z in M) faces in I, right-handed about up
        /// from the frame's forward axis
        frame_heading_deg: f64 = 0, float(-360.0, 360.0);
        /// synthesize: each sensor's inertial frame turned by a further heading offset uniform
        /// in ±this (seeded by `seed`)
        heading_offset_deg: f64 = 0, float(0.0, 180.0);
        /// synthesize: publish raw sensor samples on `raw` (accelerometer, gyroscope, magnetometer
        /// at `raw_rate_hz`, each sensor on its own clock) for a `fusion` stage; `imu` then
        /// carries the same motion's ideal oriented sensors with each truth frame
        raw: bool = false, bool;
        /// synthesize (raw): sensor sample rate, Hz
        raw_rate_hz: f64 = 200, float(10.0, 2000.0);
        /// synthesize (raw): scale of the accelerometer/gyroscope noise and bias model (0: ideal
        /// sensors, 1: consumer-grade MEMS)
        raw_noise: f64 = 0, float(0.0, 10.0);
        /// synthesize (raw): magnetometer: none, clean (earth field only) or disturbed (plus
        /// local disturbances near the floor and ferrous objects)
        raw_magnetometer: String = "clean", choice(&Magnetometer::NAMES);
        /// synthesize (raw): each sensor's clock offset uniform in ±this, ms (seeded)
        raw_clock_offset_ms: f64 = 0, float(0.0, 1.0e6);
        /// synthesize (raw): each sensor's clock drift uniform in ±this, parts per million (seeded)
        raw_clock_drift_ppm: f64 = 0, float(0.0, 1.0e4);
        /// synthesize (raw): delivery jitter of each sample (uniform 0..this), ms
        raw_jitter_ms: f64 = 0, float(0.0, 1000.0);
        /// synthesize (raw): probability that a sample is lost (seeded)
        raw_loss: f64 = 0, float(0.0, 0.9);
        /// file: recording format: by extension (auto), csv (CSV/TSV described by `layout`) or mvnx
        format: String = "auto", choice(&["auto", "csv", "mvnx"]);
        /// file (csv): TOML that describes the columns, units and sensor files
        layout: Option<PathBuf>, path;
        /// slimevr: TOML mapping trackers (MAC address and sensor id) to the six sites (required)
        trackers: Option<PathBuf>, path;
        /// synthesize/replay/file: pace frames in real time (graph rate / recorded capture times)
        realtime: Option<bool> = computed("false offline, true live"), bool;
        /// replay: ImuFrame channel (default: the first imuflow.ImuFrame.v1 raw channel)
        topic: Option<String>, string;
        /// replay: MotionFrame channel for `truth` (default: the first imuflow.MotionFrame.v1
        /// raw channel, if any)
        truth_topic: Option<String>, string;
        /// udp, slimevr: local address to receive sensor packets on
        bind: Option<String> = computed("udp 127.0.0.1:8777, slimevr 0.0.0.0:6969"), string;
        /// udp, slimevr: end the stream when no packet arrived for this long
        timeout_ms: u64 = 2000, int(1, 3_600_000);
        /// udp: end the stream after this many packets (0 = only on timeout or stop); slimevr:
        /// after this many frames (0 = no limit); replay: after this many frames (0 = all);
        /// file: after this many raw frames (0 = all)
        frames: u64 = 0, int(0, 1 << 40);
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "imu-source",
    role: Role::Source,
    summary: "IMUs from a BVH motion (synthesized, any sensor set), an mcap recording (replayed), UDP sensors, sensor files (CSV/TSV, MVNX) or SlimeVR trackers (the six-site set)",
    inputs: InputsSpec::Fixed(&[]),
    outputs: &[
        PortSpec {
            name: "imu",
            frame: FrameType::Imu,
            required: false,
            doc: "per sensor of the graph's set: orientation R_IS, specific force and angular rate in the sensor frame",
        },
        PortSpec {
            name: "truth",
            frame: FrameType::Motion,
            required: false,
            doc: "ground-truth pose of the same seq (synthesize; replay when recorded); physics fields zero",
        },
        PortSpec {
            name: "raw",
            frame: FrameType::RawImu,
            required: false,
            doc: "raw sensor samples on each sensor's clock (synthesize with raw, file, slimevr); the fusion stage makes IMU frames of them",
        },
    ],
    params: ImuSourceParams::SPECS,
};

/// Runs the imu-source as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = ImuSourceParams::from_params(ctx.params());
    let mode = params.mode.as_str();
    let realtime = params.realtime.unwrap_or(ctx.mode() == Mode::Live);
    let sensors = imuflow_body::SensorSet::resolve(ctx.sensors())
        .with_context(|| format!("stage '{stage}': `sensors`"))?;
    match mode {
        "synthesize" => {
            let (motion, raw) = synthesize(&params, &stage, ctx.graph().rate_hz, &sensors)?;
            match raw {
                None => synth::run(ctx, &motion, realtime),
                Some(session) => synth::run_raw(ctx, &motion, &session, realtime),
            }
        }
        "replay" => {
            let path = required_path(&params, &stage, mode)?;
            let recording = imuflow_recording::Recording::load(
                &path,
                params.topic.as_deref().filter(|t| !t.is_empty()),
                params.truth_topic.as_deref().filter(|t| !t.is_empty()),
            )
            .with_context(|| format!("stage '{stage}': cannot replay"))?;
            let held = replay::sites_held(&recording);
            let missing = sensors.mask().missing_from(held);
            if !missing.is_empty() {
                bail!(
                    "stage '{stage}': {} ({}) never carries {} of the stage's sensors {sensors}; \
                     it holds {} (replay a recording of that set, or set `sensors` to a set of \
                     the sites it holds)",
                    path.display(),
                    recording.imu_topic,
                    missing.names(),
                    if held.is_empty() {
                        "no valid sensor".to_owned()
                    } else {
                        held.names()
                    }
                );
            }
            replay::run(ctx, &recording, realtime, params.frames)
        }
        "udp" => {
            let options = udp::Options {
                sites: sensors.mask(),
                bind: params
                    .bind
                    .clone()
                    .unwrap_or_else(|| "127.0.0.1:8777".to_owned()),
                timeout: Duration::from_millis(params.timeout_ms),
                frames: params.frames,
            };
            udp::run(ctx, &options)
                .with_context(|| format!("stage '{stage}': udp source on '{}'", options.bind))
        }
        "slimevr" => {
            let Some(trackers) = params
                .trackers
                .clone()
                .filter(|p| !p.as_os_str().is_empty())
            else {
                bail!("stage '{stage}': mode 'slimevr' needs param `trackers` (the trackers file)");
            };
            let options = slimevr::Options {
                bind: params
                    .bind
                    .clone()
                    .unwrap_or_else(|| slimevr::DEFAULT_BIND.to_owned()),
                trackers,
                timeout: Duration::from_millis(params.timeout_ms),
                frames: params.frames,
            };
            slimevr::run(ctx, &options, sensors.mask())
                .with_context(|| format!("stage '{stage}': slimevr source on '{}'", options.bind))
        }
        "file" => {
            let path = required_path(&params, &stage, mode)?;
            let format = match params.format.as_str() {
                "csv" => imuflow_sensor_files::Format::Csv,
                "mvnx" => imuflow_sensor_files::Format::Mvnx,
                _ => imuflow_sensor_files::Format::detect(&path),
            };
            let recording =
                imuflow_sensor_files::read(&path, format, params.layout.as_deref(), sensors.mask())
                    .with_context(|| format!("stage '{stage}': cannot read the recording"))?;
            if !recording.left_out.is_empty() {
                tracing::info!(
                    stage,
                    "the recording's sensors on {} are left out: not sites of the graph's sensor set {sensors}",
                    recording.left_out.join(", ")
                );
            }
            file::check_sites(&recording, &sensors).with_context(|| {
                format!(
                    "stage '{stage}': cannot use the recording '{}'",
                    path.display()
                )
            })?;
            file::run(ctx, &recording, realtime, params.frames)
        }
        other => bail!(
            "stage '{stage}': unknown mode '{other}' (synthesize, replay, udp, file or slimevr)"
        ),
    }
}

/// Mode `synthesize`: the motion at the graph's `rate_hz` worn with `sensors`, and
/// with `raw` its raw sensor samples.
fn synthesize(
    params: &ImuSourceParams,
    stage: &str,
    rate_hz: f64,
    sensors: &imuflow_body::SensorSet,
) -> anyhow::Result<(imuflow_synth::Motion, Option<RawSession>)> {
    let path = required_path(params, stage, "synthesize")?;
    let options = imuflow_synth::Options {
        mapping: params.mapping.clone(),
        stature_m: params.stature_m,
        mass_kg: params.mass_kg,
        augment: params.augment,
        seed: params.seed,
        central_stencil: stencil(params) == AccelStencil::Central,
        prelude: prelude_options(params, stage)?,
        sensors: sensor_setup(params, stage)?,
        sites: Some(sensors.mask()),
    };
    let motion = imuflow_synth::Motion::load(&path, &options, rate_hz).with_context(|| {
        format!(
            "stage '{stage}': cannot synthesize IMUs from '{}'",
            path.display()
        )
    })?;
    if !params.raw {
        return Ok((motion, None));
    }
    let body = imuflow_synth::body_model(&options)
        .with_context(|| format!("stage '{stage}': the body model"))?;
    let session = RawSession::synthesize(&motion, &body, &raw_options(params, stage)?)
        .with_context(|| {
            format!(
                "stage '{stage}': cannot synthesize raw sensors from '{}'",
                path.display()
            )
        })?;
    Ok((motion, Some(session)))
}

fn prelude_options(
    params: &ImuSourceParams,
    stage: &str,
) -> anyhow::Result<prelude::PreludeOptions> {
    let name = params.prelude.as_str();
    let Some(kind) = prelude::PreludeKind::parse(name) else {
        bail!(
            "stage '{stage}': unknown prelude '{name}' ({})",
            prelude::PreludeKind::NAMES.join(", ")
        );
    };
    Ok(prelude::PreludeOptions {
        kind,
        stand_s: params.prelude_stand_s,
        step_m: params.step_m,
        elbow_deg: params
            .prelude_elbow_deg
            .unwrap_or(prelude::PreludeOptions::default_elbow_deg(kind)),
        ..prelude::PreludeOptions::default()
    })
}

/// The raw synthesis's options: the `raw_*` parameters, the seed, the stencil and the heading.
fn raw_options(params: &ImuSourceParams, stage: &str) -> anyhow::Result<RawOptions> {
    let name = params.raw_magnetometer.as_str();
    let Some(magnetometer) = Magnetometer::parse(name) else {
        bail!(
            "stage '{stage}': unknown raw_magnetometer '{name}' ({})",
            Magnetometer::NAMES.join(", ")
        );
    };
    Ok(RawOptions {
        rate_hz: params.raw_rate_hz,
        noise_scale: params.raw_noise,
        magnetometer,
        clock_offset_ms: params.raw_clock_offset_ms,
        clock_drift_ppm: params.raw_clock_drift_ppm,
        jitter_ms: params.raw_jitter_ms,
        loss: params.raw_loss,
        seed: params.seed,
        heading_deg: params.frame_heading_deg,
        stencil: stencil(params),
        ..RawOptions::default()
    })
}

/// The `stencil` parameter (a checked choice) as the synthesis's acceleration stencil, for the
/// ideal and the raw sensors alike.
fn stencil(params: &ImuSourceParams) -> AccelStencil {
    match params.stencil.as_str() {
        "central" => AccelStencil::Central,
        _ => AccelStencil::SmoothedTransPose,
    }
}

fn sensor_setup(
    params: &ImuSourceParams,
    stage: &str,
) -> anyhow::Result<imuflow_synth::SensorSetup> {
    let name = params.frame.as_str();
    let Some(frame) = imuflow_synth::InertialFrame::parse(name) else {
        bail!(
            "stage '{stage}': unknown frame '{name}' ({})",
            imuflow_synth::InertialFrame::NAMES.join(", ")
        );
    };
    Ok(imuflow_synth::SensorSetup {
        random_mounting: params.mounting == "random",
        frame,
        frame_heading_deg: params.frame_heading_deg,
        heading_offset_deg: params.heading_offset_deg,
    })
}

fn required_path(params: &ImuSourceParams, stage: &str, mode: &str) -> anyhow::Result<PathBuf> {
    match &params.path {
        Some(p) if !p.as_os_str().is_empty() => Ok(p.clone()),
        _ => bail!("stage '{stage}': mode '{mode}' needs param `path`"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<ImuSourceParams>().unwrap();
    }

    #[test]
    fn the_prelude_defaults_are_the_synthesis_defaults() {
        let (p, d) = (
            ImuSourceParams::default(),
            prelude::PreludeOptions::default(),
        );
        assert_eq!((p.prelude_stand_s, p.step_m), (d.stand_s, d.step_m));
    }

    /// The source of `configs/examples/raw-imu.toml` on its own (the other stages' kinds live in
    /// other crates): its parameters pass this kind's validation and synthesize raw sensors as
    /// they say.
    #[test]
    fn the_raw_example_graphs_source_is_valid_and_synthesizes_raw_sensors() {
        use imuflow_graph::params::toml;
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let file = root.join("configs/examples/raw-imu.toml");
        let text = std::fs::read_to_string(&file).expect("the example graph");
        let mut table: toml::Table = text.parse().expect("TOML");
        let stages = table
            .get_mut("stages")
            .and_then(|s| s.as_table_mut())
            .expect("[stages]");
        stages.retain(|id, _| id == "source");
        let registry = imuflow_graph::Registry::new([SPEC]);
        let graph = imuflow_graph::Graph::from_str_with(&file, &table.to_string(), &[], &registry)
            .expect("the source validates");
        let mut params = ImuSourceParams::from_params(&graph.stages["source"].params);
        assert!(params.raw && params.raw_magnetometer == "disturbed");
        // The graph's paths are relative to the repository root.
        params.path = params.path.map(|p| root.join(p));
        let sensors = imuflow_body::SensorSet::resolve(&graph.sensors).expect("a shipped set");
        let (motion, raw) =
            synthesize(&params, "source", graph.rate_hz, &sensors).expect("synthesizes");
        let raw = raw.expect("raw = true");
        // A 1 s stand, a 1 s blend, then the clip.
        assert_eq!(motion.prelude_frames, 120);
        assert!(raw.frames.len() > motion.len());
        for clock in &raw.clocks {
            assert!(clock.offset_ns.abs() <= 500e6 && clock.drift.abs() <= 100e-6);
        }
        assert!(raw.disturbance.is_some());
        assert!(
            raw.frames
                .iter()
                .all(|f| f.magnetometer_mask == f.valid_mask)
        );
        assert!(
            raw.accel_bias_mps2[..imuflow_body::NUM_IMUS]
                .iter()
                .all(|b| b.norm() > 0.0),
            "noise 1"
        );
    }
}
