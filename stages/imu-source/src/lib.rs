//! The imu-source stage: six IMUs' frames from a motion file (synthesized), an mcap recording
//! (replayed) or live sensors over UDP, as `ImuFrame`s on output `imu`, plus the ground-truth pose
//! (`MotionFrame`) on output `truth` where one is known.
//!
//! Modes (param `mode`):
//! - `synthesize`: BVH -> 24-joint clip (joint mapping, default the built-in Bandai Namco one) ->
//!   resampled to the graph's rate -> synthetic IMUs ([`imuflow_motion::imu_synthesis`]). By default
//!   the orientation is `R_MS` (the sensor's inertial frame is the model frame M, the sensor frame
//!   the bone frame); specific force and angular rate are in the sensor frame. For calibration
//!   tests: a calibration prelude ([`prelude`]), random mountings and inertial-frame conventions
//!   with per-sensor heading offsets ([`imuflow_imuflow_synth::SensorSetup`]). `truth` carries the pose of the
//!   same `seq`, prelude included.
//! - `replay`: re-publishes the `ImuFrame`s (and `MotionFrame`s, if any) of a recorder's mcap file
//!   in file order, keeping their `seq`, `capture_ns` and flags.
//! - `udp`: receives the packets described in [`udp`] from live sensors.
//!
//! A sample that is not finite clears its sensor's bit of `valid_mask` and flags the frame
//! INVALID; it never stops the stage.

mod replay;
mod synth;
pub mod udp;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use imuflow_graph::frames::{ImuFrame, MotionFrame};
use imuflow_graph::spec::{InputsSpec, ParamSpec, ParamType, PortSpec, Role, StageSpec};
use imuflow_graph::stage::{Params, Step};
use imuflow_graph::transport::Output;
use imuflow_graph::{FrameType, Mode, StageContext};
use imuflow_synth::prelude;
pub use imuflow_synth::{ALL_VALID, mark_invalid_sensors};


/// How often (frames) a source reports progress to the launcher.
const PROGRESS_EVERY: u64 = 30;

pub const SPEC: StageSpec = StageSpec {
    kind: "imu-source",
    role: Role::Source,
    summary: "six IMUs from a BVH motion (synthesized), an mcap recording (replayed) or UDP sensors",
    inputs: InputsSpec::Fixed(&[]),
    outputs: &[
        PortSpec {
            name: "imu",
            frame: FrameType::Imu,
            required: false,
            doc: "six IMUs: orientation R_IS, specific force and angular rate in the sensor frame",
        },
        PortSpec {
            name: "truth",
            frame: FrameType::Motion,
            required: false,
            doc: "ground-truth pose of the same seq (synthesize; replay when recorded); physics fields zero",
        },
    ],
    params: &[
        ParamSpec {
            name: "mode",
            ty: ParamType::Choice(&["synthesize", "replay", "udp"]),
            required: false,
            default: "synthesize",
            doc: "where the frames come from",
        },
        ParamSpec {
            name: "path",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: "synthesize: the .bvh motion; replay: the .mcap recording (required for both)",
        },
        ParamSpec {
            name: "mapping",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: "synthesize: joint-mapping TOML of the BVH skeleton (default: built-in Bandai Namco)",
        },
        ParamSpec {
            name: "stature_m",
            ty: ParamType::Float { min: 0.5, max: 2.5 },
            required: false,
            default: "",
            doc: "synthesize: subject stature, m (default: the body model's reference subject)",
        },
        ParamSpec {
            name: "mass_kg",
            ty: ParamType::Float {
                min: 10.0,
                max: 300.0,
            },
            required: false,
            default: "",
            doc: "synthesize: subject mass, kg (default: the body model's reference subject)",
        },
        ParamSpec {
            name: "augment",
            ty: ParamType::Bool,
            required: false,
            default: "false",
            doc: "synthesize: add the reference sensor errors (mounting, noise, bias, heading drift)",
        },
        ParamSpec {
            name: "seed",
            ty: ParamType::Int {
                min: 0,
                max: i64::MAX,
            },
            required: false,
            default: "0",
            doc: "synthesize: seed of the augmentation's random draws",
        },
        ParamSpec {
            name: "stencil",
            ty: ParamType::Choice(&["smoothed", "central"]),
            required: false,
            default: "smoothed",
            doc: "synthesize: acceleration stencil (TransPose/PIP smoothed, or central differences)",
        },
        ParamSpec {
            name: "prelude",
            ty: ParamType::Choice(&prelude::PreludeKind::NAMES),
            required: false,
            default: "none",
            doc: "synthesize: calibration poses before the clip: tpose (hold), walk (stand, one step forward, stand), tpose+walk",
        },
        ParamSpec {
            name: "prelude_stand_s",
            ty: ParamType::Float {
                min: 0.5,
                max: 60.0,
            },
            required: false,
            default: "3",
            doc: "synthesize: length of each prelude hold / stand, s",
        },
        ParamSpec {
            name: "step_m",
            ty: ParamType::Float { min: 0.1, max: 1.5 },
            required: false,
            default: "0.6",
            doc: "synthesize: length of the prelude's step forward, m",
        },
        ParamSpec {
            name: "mounting",
            ty: ParamType::Choice(&["bone", "random"]),
            required: false,
            default: "bone",
            doc: "synthesize: sensor frame = bone frame, or each sensor mounted in a random orientation (seeded by `seed`)",
        },
        ParamSpec {
            name: "frame",
            ty: ParamType::Choice(&imuflow_synth::InertialFrame::NAMES),
            required: false,
            default: "model",
            doc: "synthesize: inertial frame the orientations are reported in: model (I = M), z-up (x forward, z up), z-down (x forward, z down)",
        },
        ParamSpec {
            name: "frame_heading_deg",
            ty: ParamType::Float {
                min: -360.0,
                max: 360.0,
            },
            required: false,
            default: "0",
            doc: "synthesize: direction the subject (facing +z in M) faces in I, right-handed about up from the frame's forward axis",
        },
        ParamSpec {
            name: "heading_offset_deg",
            ty: ParamType::Float {
                min: 0.0,
                max: 180.0,
            },
            required: false,
            default: "0",
            doc: "synthesize: each sensor's inertial frame turned by a further heading offset uniform in ±this (seeded by `seed`)",
        },
        ParamSpec {
            name: "realtime",
            ty: ParamType::Bool,
            required: false,
            default: "false offline, true live",
            doc: "synthesize/replay: pace frames in real time (graph rate / recorded capture times)",
        },
        ParamSpec {
            name: "topic",
            ty: ParamType::String,
            required: false,
            default: "",
            doc: "replay: ImuFrame channel (default: the first imuflow.ImuFrame.v1 raw channel)",
        },
        ParamSpec {
            name: "truth_topic",
            ty: ParamType::String,
            required: false,
            default: "",
            doc: "replay: MotionFrame channel for `truth` (default: the first imuflow.MotionFrame.v1 raw channel, if any)",
        },
        ParamSpec {
            name: "bind",
            ty: ParamType::String,
            required: false,
            default: "127.0.0.1:8777",
            doc: "udp: local address to receive sensor packets on",
        },
        ParamSpec {
            name: "timeout_ms",
            ty: ParamType::Int {
                min: 1,
                max: 3_600_000,
            },
            required: false,
            default: "2000",
            doc: "udp: end the stream when no packet arrived for this long",
        },
        ParamSpec {
            name: "frames",
            ty: ParamType::Int {
                min: 0,
                max: 1 << 40,
            },
            required: false,
            default: "0",
            doc: "udp: end the stream after this many packets (0 = only on timeout or stop); replay: after this many frames (0 = all)",
        },
    ],
};

/// Runs the imu-source as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = Params(ctx.params());
    let mode = params.str("mode").unwrap_or("synthesize").to_owned();
    let realtime = params.bool("realtime", ctx.mode() == Mode::Live);
    match mode.as_str() {
        "synthesize" => {
            let path = required_path(&params, &stage, &mode)?;
            let options = imuflow_synth::Options {
                mapping: params.str("mapping").map(PathBuf::from),
                stature_m: params
                    .0
                    .get("stature_m")
                    .map(|_| params.float("stature_m", 0.0)),
                mass_kg: params
                    .0
                    .get("mass_kg")
                    .map(|_| params.float("mass_kg", 0.0)),
                augment: params.bool("augment", false),
                seed: params.int("seed", 0).max(0) as u64,
                central_stencil: params.str("stencil") == Some("central"),
                prelude: prelude_options(&params, &stage)?,
                sensors: sensor_setup(&params, &stage)?,
            };
            let rate_hz = ctx.graph().rate_hz;
            let motion = imuflow_synth::Motion::load(&path, &options, rate_hz).with_context(|| {
                format!(
                    "stage '{stage}': cannot synthesize IMUs from '{}'",
                    path.display()
                )
            })?;
            synth::run(ctx, &motion, realtime)
        }
        "replay" => {
            let path = required_path(&params, &stage, &mode)?;
            let recording = imuflow_recording::Recording::load(
                &path,
                params.str("topic").filter(|t| !t.is_empty()),
                params.str("truth_topic").filter(|t| !t.is_empty()),
            )
            .with_context(|| format!("stage '{stage}': cannot replay"))?;
            let limit = params.int("frames", 0).max(0) as u64;
            replay::run(ctx, &recording, realtime, limit)
        }
        "udp" => {
            let options = udp::Options {
                bind: params.str("bind").unwrap_or("127.0.0.1:8777").to_owned(),
                timeout: Duration::from_millis(params.int("timeout_ms", 2000).max(1) as u64),
                frames: params.int("frames", 0).max(0) as u64,
            };
            udp::run(ctx, &options)
                .with_context(|| format!("stage '{stage}': udp source on '{}'", options.bind))
        }
        other => bail!("stage '{stage}': unknown mode '{other}' (synthesize, replay or udp)"),
    }
}

fn prelude_options(params: &Params<'_>, stage: &str) -> anyhow::Result<prelude::PreludeOptions> {
    let d = prelude::PreludeOptions::default();
    let name = params.str("prelude").unwrap_or("none");
    let Some(kind) = prelude::PreludeKind::parse(name) else {
        bail!(
            "stage '{stage}': unknown prelude '{name}' ({})",
            prelude::PreludeKind::NAMES.join(", ")
        );
    };
    Ok(prelude::PreludeOptions {
        kind,
        stand_s: params.float("prelude_stand_s", d.stand_s),
        step_m: params.float("step_m", d.step_m),
        ..d
    })
}

fn sensor_setup(params: &Params<'_>, stage: &str) -> anyhow::Result<imuflow_synth::SensorSetup> {
    let name = params.str("frame").unwrap_or("model");
    let Some(frame) = imuflow_synth::InertialFrame::parse(name) else {
        bail!(
            "stage '{stage}': unknown frame '{name}' ({})",
            imuflow_synth::InertialFrame::NAMES.join(", ")
        );
    };
    Ok(imuflow_synth::SensorSetup {
        random_mounting: params.str("mounting") == Some("random"),
        frame,
        frame_heading_deg: params.float("frame_heading_deg", 0.0),
        heading_offset_deg: params.float("heading_offset_deg", 0.0),
    })
}

fn required_path(params: &Params<'_>, stage: &str, mode: &str) -> anyhow::Result<PathBuf> {
    match params.str("path") {
        Some(p) if !p.is_empty() => Ok(PathBuf::from(p)),
        _ => bail!("stage '{stage}': mode '{mode}' needs param `path`"),
    }
}


/// The publishing side shared by the modes: both outputs, pacing and progress.
pub(crate) struct Publisher {
    pub ctx: StageContext,
    pub imu: Output<ImuFrame>,
    pub truth: Output<MotionFrame>,
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
        let mut p = Publisher {
            ctx,
            imu,
            truth,
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

    /// END_OF_STREAM on both outputs and the summary to the launcher.
    pub fn finish(self) -> anyhow::Result<()> {
        let Publisher {
            ctx,
            mut imu,
            mut truth,
            ..
        } = self;
        ctx.finish(&mut [&mut imu, &mut truth])?;
        Ok(())
    }
}
