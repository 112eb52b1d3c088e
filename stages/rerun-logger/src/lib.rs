//! The rerun-logger stage: logs the frames it receives to a `.rrd` file or a live rerun viewer.
//!
//! Time axes: `seq` (the source's frame index) and `capture_time` (the frame's capture timestamp:
//! time since the start of the recording offline, wall-clock time live).
//!
//! What is logged per frame type (entity paths start with the input's name):
//! - ImuFrame / BodyImuFrame: each sensor's orientation as a transform with axes (sensors laid
//!   out side by side along x so they do not overlap), and its acceleration, angular rate and
//!   valid flag as time series under `plots/`.
//! - MotionFrame: the skeleton (bones as lines, joints as points whose radius grows with the joint's
//!   torque) at its global position, ground-reaction forces as arrows from the joints, and the torque
//!   magnitude per joint as a bar chart under `plots/<input>/torque_norm_nm`.
//! - KinematicsFrame: the networks' joint positions relative to the root (points and bones), drawn
//!   at the root of the estimate (`motion`) of the same frame, or at the origin without one.
//! - ContactFrame: contact points, and their forces as arrows.
//! - ValidationFrame: a warning text entry under `<input>/events` at every frame where the
//!   simulated body lost its balance (the scores are time series, as every small field). The
//!   validation stage's simulated body is a MotionFrame: wire it to an input named `validation`
//!   and it is drawn in its own colour with its floor forces as arrows.
//! - Errors against the truth: with an input named `truth` (a MotionFrame), every other motion
//!   input named `motion` (or `<group>__motion`) gets its SIP error (deg), root-aligned mean joint
//!   position error (cm) and its root distance (m) per frame under `plots/error_vs_truth/<entity>/`. Without a
//!   truth, a comparison's variants get the same against the first variant, under
//!   `plots/disagreement_vs_<first>/<group>/`. With a truth, each estimate's latency from the
//!   source publishing a frame to the estimate's publishing: `plots/latency_ms/<group or input>`.
//! - Every frame type: each small field (up to 6 scalars, e.g. stationary probabilities, root
//!   velocity) as a time series under `plots/<input>/<field>`, once it has changed (a constant
//!   series is never logged: [`Plots`]); the INVALID flag as text events under `<input>/events`
//!   where it turns on and off.
//!
//! Writing a file, the log calls are gathered and written as columns every `batch_frames` frames
//! ([`columns`]); a live viewer gets them call by call.
//!
//! A single run's recording carries a blueprint ([`send_single_run_blueprint`]): the scene and a
//! view that follows the estimate's pelvis (entity `follow`), a legend (`legend`, markdown), and
//! tabs of time series (the errors against the truth first). Fixed colours: `motion` blue,
//! `kinematics` pink (drawn at the estimate's root), `truth` green, `validation` orange.
//!
//! Groups (A/B comparisons, `imuflow compare`): an input named `<group>__<what>` is logged under
//! `<group>/<what>`, every group's skeletons get their own colour (its simulated body a lighter
//! tint), and the recording carries a blueprint: one 3D view per group with the truth, or all in
//! one view with `views = "overlaid"`, above the error and validation time series.
//!
//! The model frame M is x = left, y = up, z = forward (SMPL), logged as the world's view
//! coordinates so the viewer shows "up" correctly.

use anyhow::{Context, bail};
use imuflow_body::rotation::angle_between;
use imuflow_body::skeleton::SIP_JOINTS;
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS, Pose, forward_kinematics};
use imuflow_graph::frames::{
    BodyImuFrame, ContactFrame, FrameLayout, FrameType, ImuFrame, KinematicsFrame, MotionFrame,
    NUM_IMUS, ScalarType, ValidationFrame, flags,
};
use imuflow_graph::spec::{InputsSpec, ParamSpec, ParamType, Role, StageSpec};
use imuflow_graph::stage::Params;
use imuflow_graph::transport::{HeldFrame, frame_ref};
use imuflow_graph::{Mode, StageContext};

mod columns;
use columns::{FrameTime, Log};

/// Sensor names in IMU order (ARCHITECTURE.md).
pub const SENSOR_NAMES: [&str; NUM_IMUS] = [
    "left_forearm",
    "right_forearm",
    "left_lower_leg",
    "right_lower_leg",
    "head",
    "pelvis",
];
/// rerun application id: groups imuflow recordings in the viewer.
pub const APPLICATION_ID: &str = "imuflow";
/// Spacing of the sensors' display positions along x, m.
const SENSOR_SPACING_M: f32 = 0.3;
/// Length of the drawn axes, m.
const AXIS_LENGTH_M: f32 = 0.1;
/// `batch_frames`' default: two seconds at 60 Hz (see [`columns`]).
const DEFAULT_BATCH_FRAMES: i64 = 120;
/// How long the end of a run waits for the log to reach its file or viewer.
const FLUSH_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);
/// Fields with at most this many scalars are logged as time series.
const MAX_SERIES_SCALARS: usize = 6;
/// Drawn length of a force arrow per newton (1 m per 1000 N: body weight is about 0.7 m).
const FORCE_ARROW_M_PER_N: f32 = 1e-3;
/// Joint point radius: base, and extra per N·m of joint torque.
const JOINT_RADIUS_M: f32 = 0.015;
const JOINT_RADIUS_M_PER_NM: f32 = 2e-4;
/// Radius of drawn bones, m.
const BONE_RADIUS_M: f32 = 0.008;
/// Fixed colours of a single run's skeletons, by input name (the legend names them): `motion` (the
/// estimate: physics, or the integrated networks), `kinematics` (the networks' pose), `truth`,
/// `validation` (the simulated body). Other skeletons get rerun's automatic colours, or their
/// group's. Okabe & Ito's colour-blind-safe palette (2008), green kept for the truth.
const MOTION_RGB: [u8; 3] = [0, 114, 178];
const NETWORK_RGB: [u8; 3] = [204, 121, 167];
const VALIDATION_RGB: [u8; 3] = [240, 150, 30];
const TRUTH_RGB: [u8; 3] = [120, 200, 120];
/// Group colours, in the order the groups first appear among the inputs (a colour-blind-safe
/// qualitative palette: Okabe & Ito, 2008; green left out for the truth).
const GROUP_PALETTE: [[u8; 3]; 6] = [
    [0, 114, 178],
    [213, 94, 0],
    [204, 121, 167],
    [230, 159, 0],
    [86, 180, 233],
    [240, 228, 66],
];
/// The input whose pelvis the follow view moves with (a single run's estimate), and the entity
/// that carries its position.
const FOLLOWED: &str = "motion";
const FOLLOW_ENTITY: &str = "follow";
/// With `truth = "beside"`: the truth's pose is drawn this far along +x from the estimate's root,
/// a body width and a half apart, so the two skeletons never overlap.
const TRUTH_BESIDE_M: f32 = 0.8;
/// Truth frames kept for the error series (motion arrives a pipeline's latency after its truth).
const TRUTH_FRAMES_KEPT: usize = 1200;

use imuflow_graph::naming::entity_of;

/// The group of an entity path, if it has one.
fn group_of(entity: &str) -> Option<&str> {
    entity.split_once('/').map(|(group, _)| group)
}

/// The colour of the skeleton at `entity`, if it has a fixed one.
fn skeleton_colour(entity: &str, groups: &[String]) -> Option<rerun::Color> {
    let what = entity.rsplit('/').next().unwrap_or(entity);
    let [r, g, b] = match (group_of(entity), what) {
        (None, "validation") => VALIDATION_RGB,
        (None, "truth") => TRUTH_RGB,
        (None, "motion") => MOTION_RGB,
        (None, "kinematics") => NETWORK_RGB,
        (None, _) => return None,
        (Some(group), what) => {
            let index = groups.iter().position(|g| g == group)?;
            let base = GROUP_PALETTE[index % GROUP_PALETTE.len()];
            if what == "validation" {
                // The simulated body: the group's colour halfway to white.
                base.map(|c| c / 2 + 128)
            } else {
                base
            }
        }
    };
    Some(rerun::Color::from_rgb(r, g, b))
}

pub const SPEC: StageSpec = StageSpec {
    kind: "rerun-logger",
    role: Role::Sink,
    summary: "logs frames to a rerun .rrd file or a live rerun viewer",
    inputs: InputsSpec::Any,
    outputs: &[],
    params: &[
        ParamSpec {
            name: "path",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: ".rrd file to write (set this or `connect`)",
        },
        ParamSpec {
            name: "stature_m",
            ty: ParamType::Float { min: 1.0, max: 2.5 },
            required: false,
            default: "1.75",
            doc: "stature of the body model used to draw MotionFrame skeletons (m)",
        },
        ParamSpec {
            name: "connect",
            ty: ParamType::String,
            required: false,
            default: "",
            doc: "stream to a running viewer: \"default\" or a URL like rerun+http://127.0.0.1:9876/proxy",
        },
        ParamSpec {
            name: "views",
            ty: ParamType::Choice(&["side-by-side", "overlaid"]),
            required: false,
            default: "side-by-side",
            doc: "with grouped inputs (<group>__<what>): one 3D view per group, or all groups in one",
        },
        ParamSpec {
            name: "group_order",
            ty: ParamType::String,
            required: false,
            default: "",
            doc: "with grouped inputs: the groups in order, comma-separated (colours, views; the first is the reference without truth); default: by name",
        },
        ParamSpec {
            name: "batch_frames",
            ty: ParamType::Int {
                min: 0,
                max: 100_000,
            },
            required: false,
            default: "120",
            doc: "writing a file: log calls are gathered and written as columns every this many frames (much less CPU; 0: call by call through rerun's batcher, as a viewer connection always is)",
        },
        ParamSpec {
            name: "truth",
            ty: ParamType::Choice(&["overlaid", "beside"]),
            required: false,
            default: "overlaid",
            doc: "a single run's truth skeleton: where it is (over the estimate), or its pose beside the estimate (TRUTH_BESIDE_M along +x from the estimate's root, same seq), to compare poses without overlap",
        },
    ],
};

/// Where the log goes, for error messages.
enum Target {
    File(String),
    Viewer(String),
}

/// Runs the logger as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let params = Params(ctx.params());
    let builder = rerun::RecordingStreamBuilder::new(APPLICATION_ID);
    let target = match (params.str("path"), params.str("connect")) {
        (None, Some(url)) => Target::Viewer(url.to_owned()),
        (path, _) => Target::File(path.unwrap_or_default().to_owned()),
    };
    let rec = match (params.str("path"), params.str("connect")) {
        (Some(path), None) => {
            if let Some(dir) = std::path::Path::new(path)
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
            {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
            }
            builder
                .save(path)
                .with_context(|| format!("{path}: cannot open for writing"))?
        }
        (None, Some("default")) => builder
            .connect_grpc()
            .context("cannot connect to the rerun viewer")?,
        (None, Some(url)) => builder
            .connect_grpc_opts(url)
            .with_context(|| format!("cannot connect to the rerun viewer at {url}"))?,
        (Some(_), Some(_)) => bail!(
            "stage '{}': set either params.path or params.connect, not both",
            ctx.id()
        ),
        (None, None) => bail!(
            "stage '{}': set params.path (an .rrd file) or params.connect (a viewer)",
            ctx.id()
        ),
    };
    rec.log_static("/", &rerun::ViewCoordinates::LUF())?;

    // Logged under their entity paths from here on.
    let inputs: Vec<(String, FrameType)> = ctx
        .input_names()
        .into_iter()
        .map(|name| {
            let frame = ctx.node().inputs[&name].frame;
            (entity_of(&name), frame)
        })
        .collect();
    let mut groups: Vec<String> = Vec::new();
    for (entity, _) in &inputs {
        if let Some(group) = group_of(entity)
            && !groups.iter().any(|g| g == group)
        {
            groups.push(group.to_owned());
        }
    }
    // `imuflow compare` names its variants' order, so colours match its report's plots.
    let order: Vec<&str> = params
        .str("group_order")
        .unwrap_or_default()
        .split(',')
        .map(str::trim)
        .filter(|g| !g.is_empty())
        .collect();
    groups.sort_by_key(|g| order.iter().position(|o| o == g).unwrap_or(order.len()));
    // Beside the estimate needs an estimate to stand beside (and a single run: a comparison has a
    // truth in every variant's view already).
    let truth_beside = params.str("truth") == Some("beside")
        && groups.is_empty()
        && inputs
            .iter()
            .any(|(e, f)| e == FOLLOWED && *f == FrameType::Motion);
    if groups.is_empty() {
        rec.log_static(
            LEGEND_ENTITY,
            &rerun::TextDocument::from_markdown(legend(&inputs, truth_beside)),
        )?;
        send_single_run_blueprint(&rec, &inputs)?;
    } else {
        let overlaid = params.str("views") == Some("overlaid");
        send_blueprint(&rec, &groups, overlaid, &inputs)?;
    }
    for (name, frame) in &inputs {
        if matches!(frame, FrameType::Imu | FrameType::BodyImu) {
            for (k, sensor) in SENSOR_NAMES.iter().enumerate() {
                let base = format!("{name}/{sensor}");
                rec.log_static(
                    base.clone(),
                    &rerun::Transform3D::from_translation([k as f32 * SENSOR_SPACING_M, 0.0, 0.0]),
                )?;
                rec.log_static(
                    format!("{base}/orientation"),
                    &rerun::TransformAxes3D::new(AXIS_LENGTH_M),
                )?;
            }
        }
    }

    let body = BodyModel::new(&BodyParams::builtin()?, params_stature(&ctx), 70.0)?;
    let has_truth = inputs
        .iter()
        .any(|(e, f)| e == "truth" && *f == FrameType::Motion);
    let mut drawer = SkeletonDrawer::new(body, groups, has_truth);
    drawer.truth_beside = truth_beside && has_truth;
    drawer.follows_estimate = inputs
        .iter()
        .any(|(e, f)| e == FOLLOWED && *f == FrameType::Motion);
    let live = ctx.mode() == Mode::Live;
    let batch_frames = params.int("batch_frames", DEFAULT_BATCH_FRAMES).max(0) as u64;
    let mut log = match &target {
        Target::File(_) if batch_frames > 0 => Log::in_columns(rec, batch_frames),
        _ => Log::call_by_call(rec),
    };
    let logged = if ctx.ready()? {
        log_frames(&mut ctx, &mut log, &inputs, live, &mut drawer)
    } else {
        Ok(())
    };
    // What was gathered goes out even when logging stopped on an error.
    let sent = log.send_gathered();
    let rec = log.into_stream();
    // Bounded: a viewer that is not running (or went away) must not hang the graph.
    let flushed = rec.flush_with_timeout(FLUSH_TIMEOUT).map_err(|e| match &target {
        Target::Viewer(url) => anyhow::anyhow!(
            "could not deliver the log to the rerun viewer at {url} within {} s (is a viewer running? start one with `rerun`): {e}",
            FLUSH_TIMEOUT.as_secs()
        ),
        Target::File(path) => anyhow::anyhow!("{path}: cannot write the rerun log: {e}"),
    });
    if flushed.is_err() {
        // Dropping (or disconnecting) a stream flushes without a bound; after a failed bounded
        // flush, leave its threads to end with the process instead of blocking here.
        std::mem::forget(rec);
    } else {
        drop(rec);
    }
    logged?;
    sent?;
    flushed?;
    ctx.finish(&mut [])?;
    Ok(())
}

fn log_frames(
    ctx: &mut StageContext,
    rec: &mut Log,
    inputs: &[(String, FrameType)],
    live: bool,
    drawer: &mut SkeletonDrawer,
) -> anyhow::Result<()> {
    let mut plots = Plots::default();
    while let Some(index) = ctx.next_any()? {
        let (Some(held), Some((name, frame))) = (ctx.held(index), inputs.get(index)) else {
            continue;
        };
        let header = *held.header();
        let time = FrameTime {
            seq: header.seq,
            capture_ns: header.capture_ns,
            live,
        };
        rec.set_time(time)?;
        plots.now = time;
        plots.flag_transition(rec, name, header.seq, header.has(flags::INVALID))?;
        match frame {
            FrameType::Imu => {
                if let Some(f) = frame_ref::<ImuFrame>(held) {
                    log_sensors(
                        rec,
                        &mut plots,
                        name,
                        &f.orientation_wxyz,
                        &f.specific_force_mps2,
                        &f.angular_rate_radps,
                        f.valid_mask,
                        ["specific_force_mps2", "angular_rate_radps"],
                    )?;
                }
            }
            FrameType::BodyImu => {
                if let Some(f) = frame_ref::<BodyImuFrame>(held) {
                    log_sensors(
                        rec,
                        &mut plots,
                        name,
                        &f.bone_orientation_wxyz,
                        &f.free_acceleration_mps2,
                        &f.angular_velocity_radps,
                        f.valid_mask,
                        ["free_acceleration_mps2", "angular_velocity_radps"],
                    )?;
                }
            }
            FrameType::Motion => {
                if let Some(f) = frame_ref::<MotionFrame>(held) {
                    drawer.log_motion(rec, name, f)?;
                }
            }
            FrameType::Kinematics => {
                if let Some(f) = frame_ref::<KinematicsFrame>(held) {
                    drawer.log_kinematics(rec, name, time, &f.joint_position_m)?;
                }
            }
            FrameType::Contact => {
                if let Some(f) = frame_ref::<ContactFrame>(held) {
                    log_contacts(rec, name, f)?;
                }
            }
            FrameType::Validation => {
                if let Some(f) = frame_ref::<ValidationFrame>(held)
                    && f.balance_lost != 0
                {
                    rec.log(
                        format!("{name}/events"),
                        &rerun::TextLog::new(format!(
                            "frame {}: balance lost (fall {}); the simulation was reset to the estimate",
                            header.seq, f.falls
                        ))
                        .with_level(rerun::TextLogLevel::WARN),
                    )?;
                }
            }
        }
        log_small_fields(rec, &mut plots, name, frame.layout(), held)?;
    }
    drawer.place_remaining_kinematics(rec)
}

#[allow(clippy::too_many_arguments)]
fn log_sensors(
    rec: &mut Log,
    plots: &mut Plots,
    input: &str,
    orientation_wxyz: &[[f32; 4]; NUM_IMUS],
    accel: &[[f32; 3]; NUM_IMUS],
    rate: &[[f32; 3]; NUM_IMUS],
    valid_mask: u32,
    names: [&str; 2],
) -> anyhow::Result<()> {
    for (k, sensor) in SENSOR_NAMES.iter().enumerate() {
        let valid = valid_mask & (1 << k) != 0;
        let [w, x, y, z] = orientation_wxyz[k];
        if valid && [w, x, y, z].iter().all(|v| v.is_finite()) {
            rec.log(
                format!("{input}/{sensor}/orientation"),
                &rerun::Transform3D::from_rotation(rerun::Quaternion::from_xyzw([x, y, z, w])),
            )?;
            rec.log(
                format!("plots/{input}/{sensor}/{}", names[0]),
                &rerun::Scalars::new(accel[k]),
            )?;
            rec.log(
                format!("plots/{input}/{sensor}/{}", names[1]),
                &rerun::Scalars::new(rate[k]),
            )?;
        }
        plots.series(
            rec,
            format!("plots/{input}/{sensor}/valid"),
            vec![if valid { 1.0 } else { 0.0 }],
        )?;
    }
    Ok(())
}

/// Logs every field with few scalars (probabilities, velocities, counters) as a time series, once
/// it has changed (see [`Plots`]).
fn log_small_fields(
    rec: &mut Log,
    plots: &mut Plots,
    input: &str,
    layout: &FrameLayout,
    held: &dyn HeldFrame,
) -> anyhow::Result<()> {
    let bytes = held.bytes();
    for field in layout.fields.iter().filter(|f| {
        !f.name.starts_with("header.")
            && f.len() <= MAX_SERIES_SCALARS
            && !f.name.starts_with("reserved")
    }) {
        let size = field.scalar.size();
        let values: Vec<f64> = (0..field.len())
            .filter_map(|i| bytes.get(field.offset + i * size..field.offset + (i + 1) * size))
            .map(|b| match field.scalar {
                ScalarType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ScalarType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ScalarType::U64 => {
                    u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64
                }
            })
            .collect();
        if values.iter().all(|v| v.is_finite()) {
            plots.series(rec, format!("plots/{input}/{}", field.name), values)?;
        }
    }
    Ok(())
}

/// The time series of a run, logged only once they say something: a series whose values never
/// change (a probability stuck at 0, an unused force, the truth's empty torques) would be a flat
/// plot taking screen space. Each series' first values are held back until a different value
/// arrives; then the held values are logged at their own time and the series is logged from then
/// on. The INVALID flag becomes text events at its changes instead of a 0/1 plot.
#[derive(Default)]
struct Plots {
    now: FrameTime,
    /// Series not yet logged: their first values and when they came.
    held: std::collections::HashMap<String, (FrameTime, Vec<f64>)>,
    logged: std::collections::HashSet<String>,
    /// Inputs whose last frame was flagged INVALID.
    invalid: std::collections::HashSet<String>,
}

impl Plots {
    fn series(&mut self, rec: &mut Log, path: String, values: Vec<f64>) -> anyhow::Result<()> {
        if self.logged.contains(&path) {
            rec.log(path, &rerun::Scalars::new(values))?;
            return Ok(());
        }
        match self.held.get(&path) {
            None => {
                self.held.insert(path, (self.now, values));
            }
            Some((_, first)) if *first == values => {}
            Some(_) => {
                let (then, first) = self.held.remove(&path).expect("held");
                rec.set_time(then)?;
                rec.log(path.clone(), &rerun::Scalars::new(first))?;
                rec.set_time(self.now)?;
                rec.log(path.clone(), &rerun::Scalars::new(values))?;
                self.logged.insert(path);
            }
        }
        Ok(())
    }

    /// A text event where an input's INVALID flag turns on or off.
    fn flag_transition(
        &mut self,
        rec: &mut Log,
        input: &str,
        seq: u64,
        invalid: bool,
    ) -> anyhow::Result<()> {
        let was = self.invalid.contains(input);
        if invalid == was {
            return Ok(());
        }
        let (text, level) = if invalid {
            self.invalid.insert(input.to_owned());
            (
                format!(
                    "frame {seq}: {input} flagged INVALID (calibrating, a sensor missing, or a fallback)"
                ),
                rerun::TextLogLevel::WARN,
            )
        } else {
            self.invalid.remove(input);
            (
                format!("frame {seq}: {input} valid again"),
                rerun::TextLogLevel::INFO,
            )
        };
        rec.log(
            format!("{input}/events"),
            &rerun::TextLog::new(text).with_level(level),
        )?;
        Ok(())
    }
}

fn params_stature(ctx: &StageContext) -> f64 {
    Params(ctx.params()).float("stature_m", 1.75)
}

/// Draws skeletons: forward kinematics of the body model for MotionFrames.
struct SkeletonDrawer {
    body: BodyModel,
    fk: imuflow_body::FkData,
    groups: Vec<String>,
    /// What estimates are measured against, by seq: the truth's joints when there is a truth
    /// input, else (in a comparison) the first group's estimate.
    reference: Option<Reference>,
    /// The source's publish time of each seq (the truth's frames), for the latency series.
    source_publish_ns: std::collections::BTreeMap<u64, u64>,
    /// Whether the run has a followed estimate ([`FOLLOWED`]) to draw kinematics frames at.
    follows_estimate: bool,
    /// The followed estimate's root positions by seq (its valid frames).
    estimate_roots: std::collections::BTreeMap<u64, [f32; 3]>,
    /// Kinematics frames waiting for the estimate of their seq.
    waiting_kinematics: WaitingKinematics,
    /// `truth = "beside"`: the truth is drawn with the followed estimate of its seq, moved beside it.
    truth_beside: bool,
}

/// What the error series compare of one frame: the world positions of the 24 joints (m) and the
/// global rotations of the SIP joints (hips, shoulders).
#[derive(Clone, Copy)]
struct Posed {
    joints: [[f32; 3]; NUM_JOINTS],
    sip: [nalgebra::Rotation3<f64>; SIP_JOINTS.len()],
}

/// The stream estimates are compared with, and its joints by seq.
struct Reference {
    /// `truth`, or the first group's `<group>/motion`.
    entity: String,
    /// Where the series go: `plots/error_vs_truth` or `plots/disagreement_vs_<group>`.
    plots: String,
    joints: std::collections::BTreeMap<u64, Posed>,
    /// Estimates that arrived before the reference's frame of their seq (variants finish frames
    /// in any order), logged when it comes.
    pending: std::collections::BTreeMap<u64, Vec<(String, Posed)>>,
}

impl SkeletonDrawer {
    fn new(body: BodyModel, groups: Vec<String>, has_truth: bool) -> SkeletonDrawer {
        let reference = if has_truth {
            Some(Reference {
                entity: "truth".into(),
                plots: "plots/error_vs_truth".into(),
                joints: Default::default(),
                pending: Default::default(),
            })
        } else {
            // Without truth, a comparison shows how far each variant is from the first.
            groups
                .first()
                .filter(|_| groups.len() > 1)
                .map(|g| Reference {
                    entity: format!("{g}/motion"),
                    plots: format!("plots/disagreement_vs_{g}"),
                    joints: Default::default(),
                    pending: Default::default(),
                })
        };
        SkeletonDrawer {
            body,
            fk: imuflow_body::FkData::new(),
            groups,
            reference,
            source_publish_ns: Default::default(),
            follows_estimate: false,
            estimate_roots: Default::default(),
            waiting_kinematics: Default::default(),
            truth_beside: false,
        }
    }

    /// Keeps the reference's joints, or logs this estimate's error against the reference's frame
    /// of the same seq (and, in a comparison, its latency from the source).
    fn track_error(
        &mut self,
        rec: &mut Log,
        entity: &str,
        header: &imuflow_graph::frames::FrameHeader,
        posed: &Posed,
    ) -> anyhow::Result<()> {
        let seq = header.seq;
        if entity == "truth" {
            self.source_publish_ns.insert(seq, header.publish_ns);
            while self.source_publish_ns.len() > TRUTH_FRAMES_KEPT {
                self.source_publish_ns.pop_first();
            }
        }
        // Calibrating and invalid frames are not estimates of the motion: no error for them.
        let is_estimate = (entity == "motion" || entity.ends_with("/motion"))
            && header.flags & (flags::INVALID | flags::CALIBRATING) == 0;
        let group = group_of(entity).unwrap_or(entity);
        if is_estimate
            && let Some(published) = self.source_publish_ns.get(&seq)
            && header.publish_ns >= *published
        {
            // Source publish to this variant's motion publish: the variant's whole pipeline.
            let ms = (header.publish_ns - published) as f64 * 1e-6;
            rec.log(
                format!("plots/latency_ms/{group}"),
                &rerun::Scalars::single(ms),
            )?;
        }
        let Some(reference) = &mut self.reference else {
            return Ok(());
        };
        if entity == reference.entity {
            reference.joints.insert(seq, *posed);
            while reference.joints.len() > TRUTH_FRAMES_KEPT {
                reference.joints.pop_first();
            }
            for (waiting, estimate) in reference.pending.remove(&seq).unwrap_or_default() {
                log_difference(rec, &reference.plots, &waiting, &estimate, posed)?;
            }
            return Ok(());
        }
        if !is_estimate {
            return Ok(());
        }
        match reference.joints.get(&seq) {
            Some(truth) => log_difference(rec, &reference.plots, entity, posed, truth),
            None => {
                reference
                    .pending
                    .entry(seq)
                    .or_default()
                    .push((entity.to_owned(), *posed));
                while reference.pending.len() > TRUTH_FRAMES_KEPT {
                    reference.pending.pop_first();
                }
                Ok(())
            }
        }
    }

    /// Skeleton at its global position, ground-reaction force arrows, torque magnitudes.
    fn log_motion(&mut self, rec: &mut Log, input: &str, f: &MotionFrame) -> anyhow::Result<()> {
        let Ok(pose) = Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m) else {
            return Ok(()); // not a pose (e.g. an all-zero invalid frame): draw nothing
        };
        forward_kinematics(&self.body.skeleton, &pose, &mut self.fk);
        let joints: [[f32; 3]; NUM_JOINTS] =
            self.fk.joint_in_world_m.map(|p| p.cast::<f32>().into());
        // Torque per joint: the norm of its three generalized-force entries (the root's: virtual torque).
        let torque: Vec<f32> = (0..NUM_JOINTS)
            .map(|j| {
                let t = &f.tau[3 + 3 * j..6 + 3 * j];
                (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt()
            })
            .collect();
        // Beside: the truth waits for the estimate of its seq (drawn below, next to it).
        if !(self.truth_beside && input == "truth") {
            self.log_joints(rec, input, &joints, Some(&torque))?;
        }
        let posed = Posed {
            joints,
            sip: SIP_JOINTS.map(|j| *self.fk.world_from(j)),
        };
        self.track_error(rec, input, &f.header, &posed)?;
        if torque.iter().any(|t| *t != 0.0) {
            // Physics estimates only: the truth and the networks carry no torques.
            rec.log(
                format!("plots/{input}/torque_norm_nm"),
                &rerun::BarChart::new(torque),
            )?;
        }
        if input == FOLLOWED {
            // The follow view's origin: the estimate's pelvis, on the floor's height axis.
            let root = joints[JointId::ROOT.index()];
            rec.log(
                FOLLOW_ENTITY,
                &rerun::Transform3D::from_translation([root[0], 0.0, root[2]]),
            )?;
            if self.truth_beside {
                self.log_truth_beside(rec, f.header.seq, root)?;
            }
            self.estimate_roots.insert(f.header.seq, root);
            while self.estimate_roots.len() > TRUTH_FRAMES_KEPT {
                self.estimate_roots.pop_first();
            }
            self.place_waiting_kinematics(rec, f.header.seq, root)?;
        }
        let (origins, vectors): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..NUM_JOINTS)
            .filter(|&j| f.ground_reaction_force_n[j].iter().any(|v| *v != 0.0))
            .map(|j| {
                (
                    joints[j],
                    f.ground_reaction_force_n[j].map(|v| v * FORCE_ARROW_M_PER_N),
                )
            })
            .unzip();
        rec.log(
            format!("{input}/ground_reaction_force"),
            &rerun::Arrows3D::from_vectors(vectors)
                .with_origins(origins)
                .with_colors([rerun::Color::from_rgb(230, 80, 40)]),
        )?;
        Ok(())
    }

    /// A kinematics frame's root-relative joints, drawn at the root of the followed estimate
    /// ([`FOLLOWED`]) of the first valid frame at or after its seq (usually its own), else at
    /// the origin. Frames whose estimate has not come yet wait for it: where a frame is drawn
    /// must not depend on which input the logger happened to read first (the recording would
    /// differ between two runs of the same input).
    fn log_kinematics(
        &mut self,
        rec: &mut Log,
        input: &str,
        time: FrameTime,
        joints: &RelativeJoints,
    ) -> anyhow::Result<()> {
        if !self.follows_estimate {
            return self.log_joints(rec, input, &at_root(joints, [0.0; 3]), None);
        }
        if let Some((_, root)) = self.estimate_roots.range(time.seq..).next() {
            return self.log_joints(rec, input, &at_root(joints, *root), None);
        }
        self.waiting_kinematics.entry(time.seq).or_default().push((
            input.to_owned(),
            time,
            *joints,
        ));
        while self.waiting_kinematics.len() > TRUTH_FRAMES_KEPT {
            self.waiting_kinematics.pop_first();
        }
        Ok(())
    }

    /// Draws the kinematics frames up to `seq` that waited for an estimate, at `root` (the
    /// estimate of `seq`).
    fn place_waiting_kinematics(
        &mut self,
        rec: &mut Log,
        seq: u64,
        root: [f32; 3],
    ) -> anyhow::Result<()> {
        // Called for every estimate frame: nothing to do unless a frame up to `seq` waits.
        if self
            .waiting_kinematics
            .first_key_value()
            .is_none_or(|(first, _)| *first > seq)
        {
            return Ok(());
        }
        let later = self.waiting_kinematics.split_off(&(seq + 1));
        let due = std::mem::replace(&mut self.waiting_kinematics, later);
        self.draw_kinematics(rec, due, root)
    }

    /// At the end of the stream: the kinematics frames no estimate came for, at the last
    /// estimate's root (or the origin).
    fn place_remaining_kinematics(&mut self, rec: &mut Log) -> anyhow::Result<()> {
        let root = self
            .estimate_roots
            .values()
            .last()
            .copied()
            .unwrap_or([0.0; 3]);
        let due = std::mem::take(&mut self.waiting_kinematics);
        self.draw_kinematics(rec, due, root)
    }

    /// Kinematics frames that waited, drawn at `root`, each at its own time; the time is then
    /// set back to the frame being logged.
    fn draw_kinematics(
        &self,
        rec: &mut Log,
        due: WaitingKinematics,
        root: [f32; 3],
    ) -> anyhow::Result<()> {
        let now = rec.now();
        for (input, time, joints) in due.into_values().flatten() {
            rec.set_time(time)?;
            self.log_joints(rec, &input, &at_root(&joints, root), None)?;
        }
        rec.set_time(now)
    }

    /// The truth's pose of `seq`, its root moved horizontally to [`TRUTH_BESIDE_M`] along +x from the
    /// estimate's root (heights kept: both stand on the same floor).
    fn log_truth_beside(
        &self,
        rec: &mut Log,
        seq: u64,
        estimate_root: [f32; 3],
    ) -> anyhow::Result<()> {
        let Some(truth) = self
            .reference
            .as_ref()
            .filter(|r| r.entity == "truth")
            .and_then(|r| r.joints.get(&seq))
        else {
            return Ok(());
        };
        let joints = placed_beside(&truth.joints, estimate_root);
        self.log_joints(rec, "truth", &joints, None)
    }

    /// Joints as points (radius from `torque` when given) and bones as lines.
    fn log_joints(
        &self,
        rec: &mut Log,
        input: &str,
        joints: &[[f32; 3]; NUM_JOINTS],
        torque: Option<&[f32]>,
    ) -> anyhow::Result<()> {
        if !joints.iter().flatten().all(|v| v.is_finite()) {
            return Ok(());
        }
        let radii: Vec<f32> = (0..NUM_JOINTS)
            .map(|j| JOINT_RADIUS_M + torque.map_or(0.0, |t| t[j] * JOINT_RADIUS_M_PER_NM))
            .collect();
        let mut points = rerun::Points3D::new(joints.iter().copied()).with_radii(radii);
        let bones = JointId::all()
            .filter_map(|j| j.parent().map(|p| [joints[p.index()], joints[j.index()]]));
        let mut lines = rerun::LineStrips3D::new(bones).with_radii([BONE_RADIUS_M]);
        if let Some(colour) = skeleton_colour(input, &self.groups) {
            points = points.with_colors([colour]);
            lines = lines.with_colors([colour]);
        }
        rec.log(format!("{input}/skeleton/joints"), &points)?;
        rec.log(format!("{input}/skeleton/bones"), &lines)?;
        Ok(())
    }
}

/// A kinematics frame's joints, relative to its root (m).
type RelativeJoints = [[f32; 3]; NUM_JOINTS];

/// Kinematics frames by seq: input, time and root-relative joints.
type WaitingKinematics = std::collections::BTreeMap<u64, Vec<(String, FrameTime, RelativeJoints)>>;

/// Root-relative `joints` placed at `root`.
fn at_root(joints: &RelativeJoints, root: [f32; 3]) -> [[f32; 3]; NUM_JOINTS] {
    joints.map(|p| [p[0] + root[0], p[1] + root[1], p[2] + root[2]])
}

/// `joints` moved horizontally so that their root stands [`TRUTH_BESIDE_M`] along +x from
/// `estimate_root` (heights kept: both stand on the same floor).
fn placed_beside(
    joints: &[[f32; 3]; NUM_JOINTS],
    estimate_root: [f32; 3],
) -> [[f32; 3]; NUM_JOINTS] {
    let root = joints[JointId::ROOT.index()];
    let shift = [
        estimate_root[0] + TRUTH_BESIDE_M - root[0],
        0.0,
        estimate_root[2] - root[2],
    ];
    joints.map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]])
}

/// Contact points and their forces.
fn log_contacts(rec: &mut Log, input: &str, f: &ContactFrame) -> anyhow::Result<()> {
    let n = (f.num_points as usize).min(f.point_position_m.len());
    let points = &f.point_position_m[..n];
    if !points.iter().flatten().all(|v| v.is_finite()) {
        return Ok(());
    }
    rec.log(
        format!("{input}/points"),
        &rerun::Points3D::new(points.iter().copied())
            .with_radii([0.02])
            .with_colors([rerun::Color::from_rgb(40, 160, 230)]),
    )?;
    let forces = f.point_force_n[..n]
        .iter()
        .map(|v| v.map(|x| x * FORCE_ARROW_M_PER_N));
    rec.log(
        format!("{input}/forces"),
        &rerun::Arrows3D::from_vectors(forces).with_origins(points.iter().copied()),
    )?;
    Ok(())
}

/// Logs an estimate's SIP error (deg: the mean angle between its and the reference's global
/// rotations of hips and shoulders, as `imuflow compare`), root-aligned mean joint distance (cm)
/// and root distance (m) from the reference under `<plots>/<group>/`.
fn log_difference(
    rec: &mut Log,
    plots: &str,
    entity: &str,
    estimate: &Posed,
    reference: &Posed,
) -> anyhow::Result<()> {
    let (joint_cm, root_m) = error_against_truth(&estimate.joints, &reference.joints);
    let sip_deg = estimate
        .sip
        .iter()
        .zip(&reference.sip)
        .map(|(a, b)| angle_between(a, b).to_degrees())
        .sum::<f64>()
        / SIP_JOINTS.len() as f64;
    let base = format!("{plots}/{}", group_of(entity).unwrap_or(entity));
    rec.log(format!("{base}/sip_deg"), &rerun::Scalars::single(sip_deg))?;
    rec.log(
        format!("{base}/joint_position_cm"),
        &rerun::Scalars::single(joint_cm),
    )?;
    rec.log(
        format!("{base}/root_distance_m"),
        &rerun::Scalars::single(root_m),
    )?;
    Ok(())
}

/// Mean joint position error after aligning the roots (cm), and the roots' distance (m).
fn error_against_truth(
    joints: &[[f32; 3]; NUM_JOINTS],
    truth: &[[f32; 3]; NUM_JOINTS],
) -> (f64, f64) {
    let root = JointId::ROOT.index();
    let offset: [f64; 3] = std::array::from_fn(|k| f64::from(joints[root][k] - truth[root][k]));
    let mut sum_m = 0.0;
    for (p, t) in joints.iter().zip(truth) {
        let d: f64 = (0..3)
            .map(|k| (f64::from(p[k] - t[k]) - offset[k]).powi(2))
            .sum();
        sum_m += d.sqrt();
    }
    let root_m = offset.iter().map(|x| x * x).sum::<f64>().sqrt();
    (100.0 * sum_m / NUM_JOINTS as f64, root_m)
}

/// Where the legend (a markdown text document) is logged.
const LEGEND_ENTITY: &str = "legend";

/// A colour's name and swatch for the legend.
fn colour_name(rgb: [u8; 3]) -> &'static str {
    match rgb {
        MOTION_RGB => "blue",
        NETWORK_RGB => "pink",
        VALIDATION_RGB => "orange",
        TRUTH_RGB => "green",
        _ => "",
    }
}

/// The legend of a single run: what each skeleton's colour is, what the views and tabs show.
fn legend(inputs: &[(String, FrameType)], truth_beside: bool) -> String {
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let mut text = String::from("## imuflow\n\n");
    let truth_text = if truth_beside {
        format!(
            "the true motion's pose, drawn beside the estimate ({TRUTH_BESIDE_M} m along +x from its root; the root's own error is in the errors tab)"
        )
    } else {
        "the true motion, when the source has it".to_owned()
    };
    let skeletons = [
        (
            "motion",
            MOTION_RGB,
            "the estimate: the physics optimizer's output (or the integrated networks without physics); joint spheres grow with joint torque, red arrows are ground-reaction forces",
        ),
        (
            "kinematics",
            NETWORK_RGB,
            "the networks' pose alone, drawn at the estimate's root",
        ),
        ("truth", TRUTH_RGB, truth_text.as_str()),
        (
            "validation",
            VALIDATION_RGB,
            "the rapier simulation that tried to perform the estimate with joint torques only (the judge)",
        ),
    ];
    for (name, rgb, what) in skeletons.iter().filter(|(name, _, _)| has(name)) {
        text.push_str(&format!("- **{}** `{name}`: {what}\n", colour_name(*rgb)));
    }
    if has("contacts") {
        text.push_str("- light blue points and arrows `contacts`: the contacts the physics used, with their forces\n");
    }
    text.push_str("\n**scene**: the world, floor at y = 0. **follow**: the same, the camera moving with the estimate's pelvis.\n");
    if has("truth") {
        text.push_str("\n**errors** tab: per frame against the truth: SIP error (hips and shoulders, deg), mean joint position error (cm, roots aligned), root distance (m), and the latency from the source to the estimate (ms).\n");
    }
    text.push_str("\nOther tabs: each input's small fields over time (contact and stationary probabilities, root velocity, validation scores, ...). A series that never changes is not logged. Times: `seq` (frame) and `capture_time`.\n");
    text
}

/// The layout of a single run, derived from its inputs: the scene and a view that follows the
/// estimate side by side (with the legend), above tabs of time series: the errors against the truth
/// when there is one, then one tab per input with plotted fields, the joint torques of a physics
/// estimate.
fn send_single_run_blueprint(
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
) -> anyhow::Result<()> {
    use rerun::blueprint::components::PanelState;
    use rerun::blueprint::{
        BarChartView, Blueprint, BlueprintActivation, BlueprintPanel, ContainerLike, Horizontal,
        SelectionPanel, Spatial3DView, Tabs, TextDocumentView, TimePanel, TimeSeriesView, Vertical,
    };
    let has = |name: &str| inputs.iter().any(|(e, _)| e == name);
    let scene_contents = ["+ /**", "- /plots/**", "- /legend"];
    let mut top: Vec<ContainerLike> = vec![
        Spatial3DView::new("scene")
            .with_origin("/")
            .with_contents(scene_contents)
            .into(),
    ];
    if has(FOLLOWED) {
        top.push(
            Spatial3DView::new("follow")
                .with_origin(format!("/{FOLLOW_ENTITY}"))
                .with_contents(scene_contents)
                .into(),
        );
    }
    top.push(
        TextDocumentView::new("legend")
            .with_origin(format!("/{LEGEND_ENTITY}"))
            .into(),
    );
    let shares: Vec<f32> = match top.len() {
        3 => vec![3.0, 3.0, 1.2],
        _ => vec![5.0, 1.2],
    };
    let mut tabs: Vec<ContainerLike> = Vec::new();
    if has("truth") && has(FOLLOWED) {
        tabs.push(
            Vertical::new([
                TimeSeriesView::new("SIP error vs truth (deg)")
                    .with_contents([format!("+ /plots/error_vs_truth/{FOLLOWED}/sip_deg")])
                    .into(),
                TimeSeriesView::new("joint position error vs truth (cm)")
                    .with_contents([format!(
                        "+ /plots/error_vs_truth/{FOLLOWED}/joint_position_cm"
                    )])
                    .into(),
                TimeSeriesView::new("root distance from truth (m)")
                    .with_contents([format!(
                        "+ /plots/error_vs_truth/{FOLLOWED}/root_distance_m"
                    )])
                    .into(),
                TimeSeriesView::new("latency, source to estimate (ms)")
                    .with_contents(["+ /plots/latency_ms/**"])
                    .into(),
            ])
            .with_name("errors")
            .into(),
        );
    }
    for (name, frame) in inputs {
        let plotted = match frame {
            FrameType::Imu | FrameType::BodyImu => "IMU signals",
            FrameType::Motion if name == "truth" => continue,
            _ => "fields",
        };
        let series = TimeSeriesView::new(format!("{name}: {plotted}"))
            .with_origin(format!("/plots/{name}"))
            .with_contents(["+ $origin/**"]);
        let tab: ContainerLike = if *frame == FrameType::Motion {
            Horizontal::new([
                series.into(),
                BarChartView::new(format!("{name}: joint torque (N·m)"))
                    .with_origin(format!("/plots/{name}/torque_norm_nm"))
                    .into(),
            ])
            .with_name(name.as_str())
            .into()
        } else {
            Vertical::new([series.into()])
                .with_name(name.as_str())
                .into()
        };
        tabs.push(tab);
    }
    let top: ContainerLike = Horizontal::new(top).with_column_shares(shares).into();
    let root: ContainerLike = if tabs.is_empty() {
        top
    } else {
        Vertical::new([top, Tabs::new(tabs).into()])
            .with_row_shares([3.0, 2.0])
            .into()
    };
    // The views get the screen: the viewer's own side panels start collapsed (a click opens them).
    Blueprint::new(root)
        .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
        .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
        .with_time_panel(TimePanel::new().with_timeline("seq"))
        .send(rec, BlueprintActivation::default())?;
    Ok(())
}

/// The layout of a grouped recording: a 3D view per group (each with the truth) or one overlaid
/// view, above time series of the errors against the truth and of the validation scores.
fn send_blueprint(
    rec: &rerun::RecordingStream,
    groups: &[String],
    overlaid: bool,
    inputs: &[(String, FrameType)],
) -> anyhow::Result<()> {
    use rerun::blueprint::{
        Blueprint, BlueprintActivation, ContainerLike, Horizontal, Spatial3DView, TimeSeriesView,
        Vertical,
    };
    let has_truth = inputs.iter().any(|(e, _)| e == "truth");
    let shared: Vec<String> = if has_truth {
        vec!["+ /truth/**".into()]
    } else {
        Vec::new()
    };
    let views: Vec<ContainerLike> = if overlaid {
        let mut contents = shared.clone();
        contents.extend(groups.iter().map(|g| format!("+ /{g}/**")));
        vec![
            Spatial3DView::new("all variants")
                .with_origin("/")
                .with_contents(contents)
                .into(),
        ]
    } else {
        groups
            .iter()
            .map(|g| {
                let mut contents = shared.clone();
                contents.push(format!("+ /{g}/**"));
                Spatial3DView::new(g.as_str())
                    .with_origin("/")
                    .with_contents(contents)
                    .into()
            })
            .collect()
    };
    let mut series: Vec<ContainerLike> = Vec::new();
    if has_truth {
        series.push(
            TimeSeriesView::new("joint position error vs truth (cm)")
                .with_contents(
                    groups
                        .iter()
                        .map(|g| format!("+ /plots/error_vs_truth/{g}/joint_position_cm")),
                )
                .into(),
        );
        series.push(
            TimeSeriesView::new("latency, source to motion (ms)")
                .with_contents(["+ /plots/latency_ms/**"])
                .into(),
        );
    } else if let Some(first) = groups.first().filter(|_| groups.len() > 1) {
        series.push(
            TimeSeriesView::new(format!("joint position difference vs {first} (cm)"))
                .with_contents(
                    groups
                        .iter()
                        .skip(1)
                        .map(|g| format!("+ /plots/disagreement_vs_{first}/{g}/joint_position_cm")),
                )
                .into(),
        );
    }
    let validated = inputs
        .iter()
        .any(|(e, f)| *f == FrameType::Validation && group_of(e).is_some());
    if validated {
        let tracking: Vec<String> = groups
            .iter()
            .map(|g| format!("+ /plots/{g}/validation_scores/tracking_error_m"))
            .collect();
        series.push(
            TimeSeriesView::new("validation: tracking error (m)")
                .with_contents(tracking)
                .into(),
        );
    }
    let top: ContainerLike = Horizontal::new(views).into();
    let root: ContainerLike = if series.is_empty() {
        top
    } else {
        Vertical::new([top, Horizontal::new(series).into()]).into()
    };
    Blueprint::new(root).send(rec, BlueprintActivation::default())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grouped_inputs_become_entity_paths_with_their_group_colour() {
        assert_eq!(entity_of("pip__motion"), "pip/motion");
        assert_eq!(entity_of("motion"), "motion");
        let groups = vec!["pip".to_owned(), "globalpose".to_owned()];
        let rgb = |e: &str| skeleton_colour(e, &groups).map(|c| c.to_array());
        assert_eq!(rgb("pip/motion"), Some([0, 114, 178, 255]));
        assert_eq!(rgb("globalpose/motion"), Some([213, 94, 0, 255]));
        // The simulated body: halfway to white.
        assert_eq!(rgb("pip/validation"), Some([128, 185, 217, 255]));
        assert_eq!(rgb("truth"), Some([120, 200, 120, 255]));
        assert_eq!(rgb("validation"), Some([240, 150, 30, 255]));
        assert_eq!(rgb("motion"), Some([0, 114, 178, 255]));
        assert_eq!(rgb("kinematics"), Some([204, 121, 167, 255]));
        assert_eq!(rgb("my_filter"), None);
        assert_eq!(rgb("other/motion"), None);
    }

    #[test]
    fn the_truth_beside_keeps_its_pose_and_heights_next_to_the_estimate_root() {
        let truth: [[f32; 3]; NUM_JOINTS] = std::array::from_fn(|j| {
            [
                3.0 + 0.01 * j as f32,
                0.9 + 0.02 * j as f32,
                -2.0 + 0.03 * j as f32,
            ]
        });
        let estimate_root = [10.0, 0.95, 4.0];
        let beside = placed_beside(&truth, estimate_root);
        let root = beside[JointId::ROOT.index()];
        // Hand-derived: x = 10 + 0.8, the truth's own height, z = 4.
        assert!(
            (root[0] - 10.8).abs() < 1e-5 && (root[2] - 4.0).abs() < 1e-5,
            "{root:?}"
        );
        for j in 0..NUM_JOINTS {
            assert_eq!(beside[j][1], truth[j][1], "heights kept");
            for k in [0, 2] {
                let moved = beside[j][k] - root[k];
                let original = truth[j][k] - truth[JointId::ROOT.index()][k];
                assert!((moved - original).abs() < 1e-5, "the pose is kept");
            }
        }
    }

    #[test]
    fn error_against_truth_aligns_roots_and_reports_their_distance() {
        let truth: [[f32; 3]; NUM_JOINTS] = std::array::from_fn(|j| [0.0, j as f32 * 0.1, 0.0]);
        // Shifted 0.3 m sideways, one joint 0.24 m off on top: 0.24 m / 24 joints = 1 cm.
        let mut estimate = truth.map(|[x, y, z]| [x + 0.3, y, z]);
        estimate[5][2] += 0.24;
        let (joint_cm, root_m) = error_against_truth(&estimate, &truth);
        assert!((joint_cm - 1.0).abs() < 1e-4, "{joint_cm}");
        assert!((root_m - 0.3).abs() < 1e-6, "{root_m}");
    }
}
