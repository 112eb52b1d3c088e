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
//! - KinematicsFrame: the networks' joint positions relative to the root (points and bones).
//! - ContactFrame: contact points, and their forces as arrows.
//! - ValidationFrame: a warning text entry under `<input>/events` at every frame where the
//!   simulated body lost its balance (the scores are time series, as every small field). The
//!   validation stage's simulated body is a MotionFrame: wire it to an input named `validation`
//!   and it is drawn in its own colour with its floor forces as arrows.
//! - Errors against the truth: with an input named `truth` (a MotionFrame), every other motion
//!   input named `motion` (or `<group>__motion`) gets its root-aligned mean joint position error
//!   (cm) and its root distance (m) per frame under `plots/error_vs_truth/<entity>/`. Without a
//!   truth, a comparison's variants get the same against the first variant, under
//!   `plots/disagreement_vs_<first>/<group>/`. With a truth, each variant's latency from the
//!   source publishing a frame to the variant publishing its motion: `plots/latency_ms/<group>`.
//! - Every frame type: each small field (up to 6 scalars, e.g. stationary probabilities, root
//!   velocity) as a time series under `plots/<input>/<field>`, and the INVALID flag.
//!
//! Groups (A/B comparisons, `imuflow compare`): an input named `<group>__<what>` is logged under
//! `<group>/<what>`, every group's skeletons get their own colour (its simulated body a lighter
//! tint), and the recording carries a blueprint: one 3D view per group with the truth, or all in
//! one view with `views = "overlaid"`, above the error and validation time series.
//!
//! The model frame M is x = left, y = up, z = forward (SMPL), logged as the world's view
//! coordinates so the viewer shows "up" correctly.

use anyhow::{Context, bail};
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS, Pose, forward_kinematics};
use imuflow_graph::combine::GROUP_SEPARATOR;
use imuflow_graph::frames::{
    BodyImuFrame, ContactFrame, FrameLayout, FrameType, ImuFrame, KinematicsFrame, MotionFrame,
    NUM_IMUS, ScalarType, ValidationFrame, flags,
};
use imuflow_graph::spec::{InputsSpec, ParamSpec, ParamType, Role, StageSpec};
use imuflow_graph::stage::Params;
use imuflow_graph::transport::{HeldFrame, frame_ref};
use imuflow_graph::{Mode, StageContext};

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
/// Colour of the skeleton drawn from an input named `validation` (the simulated body) and of one
/// named `truth`; other skeletons get rerun's automatic colours, or their group's.
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
/// Truth frames kept for the error series (motion arrives a pipeline's latency after its truth).
const TRUTH_FRAMES_KEPT: usize = 1200;

/// The entity path of an input: `<group>__<what>` becomes `<group>/<what>`.
pub fn entity_of(input: &str) -> String {
    input.replace(GROUP_SEPARATOR, "/")
}

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
    if !groups.is_empty() {
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
    let live = ctx.mode() == Mode::Live;
    let logged = if ctx.ready()? {
        log_frames(&mut ctx, &rec, &inputs, live, &mut drawer)
    } else {
        Ok(())
    };
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
    flushed?;
    ctx.finish(&mut [])?;
    Ok(())
}

fn log_frames(
    ctx: &mut StageContext,
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
    live: bool,
    drawer: &mut SkeletonDrawer,
) -> anyhow::Result<()> {
    while let Some(index) = ctx.next_any()? {
        let (Some(held), Some((name, frame))) = (ctx.held(index), inputs.get(index)) else {
            continue;
        };
        let header = *held.header();
        rec.set_time_sequence("seq", header.seq as i64);
        if live {
            rec.set_timestamp_nanos_since_epoch("capture_time", header.capture_ns as i64);
        } else {
            rec.set_duration_secs("capture_time", header.capture_ns as f64 * 1e-9);
        }
        let invalid = if header.has(flags::INVALID) { 1.0 } else { 0.0 };
        rec.log(
            format!("plots/{name}/invalid"),
            &rerun::Scalars::single(invalid),
        )?;
        match frame {
            FrameType::Imu => {
                if let Some(f) = frame_ref::<ImuFrame>(held) {
                    log_sensors(
                        rec,
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
                    drawer.log_joints(rec, name, &f.joint_position_m, None)?;
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
        log_small_fields(rec, name, frame.layout(), held)?;
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn log_sensors(
    rec: &rerun::RecordingStream,
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
        rec.log(
            format!("plots/{input}/{sensor}/valid"),
            &rerun::Scalars::single(if valid { 1.0 } else { 0.0 }),
        )?;
    }
    Ok(())
}

/// Logs every field with few scalars (probabilities, velocities, counters) as a time series.
fn log_small_fields(
    rec: &rerun::RecordingStream,
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
            rec.log(
                format!("plots/{input}/{}", field.name),
                &rerun::Scalars::new(values),
            )?;
        }
    }
    Ok(())
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
}

/// World positions of the 24 joints, m.
type Joints = [[f32; 3]; NUM_JOINTS];

/// The stream estimates are compared with, and its joints by seq.
struct Reference {
    /// `truth`, or the first group's `<group>/motion`.
    entity: String,
    /// Where the series go: `plots/error_vs_truth` or `plots/disagreement_vs_<group>`.
    plots: String,
    joints: std::collections::BTreeMap<u64, [[f32; 3]; NUM_JOINTS]>,
    /// Estimates that arrived before the reference's frame of their seq (variants finish frames
    /// in any order), logged when it comes.
    pending: std::collections::BTreeMap<u64, Vec<(String, Joints)>>,
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
        }
    }

    /// Keeps the reference's joints, or logs this estimate's error against the reference's frame
    /// of the same seq (and, in a comparison, its latency from the source).
    fn track_error(
        &mut self,
        rec: &rerun::RecordingStream,
        entity: &str,
        header: &imuflow_graph::frames::FrameHeader,
        joints: &[[f32; 3]; NUM_JOINTS],
    ) -> anyhow::Result<()> {
        let seq = header.seq;
        if entity == "truth" {
            self.source_publish_ns.insert(seq, header.publish_ns);
            while self.source_publish_ns.len() > TRUTH_FRAMES_KEPT {
                self.source_publish_ns.pop_first();
            }
        }
        let is_estimate = entity == "motion" || entity.ends_with("/motion");
        if is_estimate
            && let Some(group) = group_of(entity)
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
            reference.joints.insert(seq, *joints);
            while reference.joints.len() > TRUTH_FRAMES_KEPT {
                reference.joints.pop_first();
            }
            for (waiting, estimate) in reference.pending.remove(&seq).unwrap_or_default() {
                log_difference(rec, &reference.plots, &waiting, &estimate, joints)?;
            }
            return Ok(());
        }
        if !is_estimate {
            return Ok(());
        }
        match reference.joints.get(&seq) {
            Some(true_joints) => log_difference(rec, &reference.plots, entity, joints, true_joints),
            None => {
                reference
                    .pending
                    .entry(seq)
                    .or_default()
                    .push((entity.to_owned(), *joints));
                while reference.pending.len() > TRUTH_FRAMES_KEPT {
                    reference.pending.pop_first();
                }
                Ok(())
            }
        }
    }

    /// Skeleton at its global position, ground-reaction force arrows, torque magnitudes.
    fn log_motion(
        &mut self,
        rec: &rerun::RecordingStream,
        input: &str,
        f: &MotionFrame,
    ) -> anyhow::Result<()> {
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
        self.log_joints(rec, input, &joints, Some(&torque))?;
        self.track_error(rec, input, &f.header, &joints)?;
        rec.log(
            format!("plots/{input}/torque_norm_nm"),
            &rerun::BarChart::new(torque),
        )?;
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

    /// Joints as points (radius from `torque` when given) and bones as lines.
    fn log_joints(
        &self,
        rec: &rerun::RecordingStream,
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

/// Contact points and their forces.
fn log_contacts(rec: &rerun::RecordingStream, input: &str, f: &ContactFrame) -> anyhow::Result<()> {
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

/// Mean joint position error after aligning the roots (cm), and the roots' distance (m).
/// Logs an estimate's root-aligned mean joint distance (cm) and root distance (m) from the
/// reference's joints under `<plots>/<group>/`.
fn log_difference(
    rec: &rerun::RecordingStream,
    plots: &str,
    entity: &str,
    joints: &[[f32; 3]; NUM_JOINTS],
    reference: &[[f32; 3]; NUM_JOINTS],
) -> anyhow::Result<()> {
    let (joint_cm, root_m) = error_against_truth(joints, reference);
    let base = format!("{plots}/{}", group_of(entity).unwrap_or(entity));
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
                .with_contents(["+ /plots/error_vs_truth/*/joint_position_cm"])
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
                .with_contents([format!(
                    "+ /plots/disagreement_vs_{first}/*/joint_position_cm"
                )])
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
        assert_eq!(rgb("motion"), None);
        assert_eq!(rgb("other/motion"), None);
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
