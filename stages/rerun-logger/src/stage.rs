//! The stage: its spec, and the process's run from opening the recording to the last frame.
//! [`run`] opens the file or viewer connection, logs what is static (view coordinates, the
//! blueprint, the sensors' layout), then reads the inputs in arrival order and hands each frame
//! to what draws or plots its type ([`crate::skeleton`], [`crate::plots`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use imuflow_body::{BodyModel, BodyParams};
use imuflow_graph::frames::{
    BodyImuFrame, ContactFrame, FrameType, ImuFrame, KinematicsFrame, MotionFrame, ValidationFrame,
    flags,
};
use imuflow_graph::naming::entity_of;
use imuflow_graph::spec::{InputsSpec, Role, StageSpec};
use imuflow_graph::transport::frame_ref;
use imuflow_graph::{Mode, StageContext};

use crate::blueprint;
use crate::columns::{FrameTime, Log};
use crate::plots::{Plots, group_of, log_small_fields};
use crate::skeleton::{FOLLOWED, SkeletonDrawer, log_contacts, log_sensor_layout, log_sensors};

/// rerun application id: groups imuflow recordings in the viewer.
pub const APPLICATION_ID: &str = "imuflow";
/// How long the end of a run waits for the log to reach its file or viewer.
const FLUSH_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

imuflow_graph::stage_params! {
    /// The rerun logger's parameters.
    pub struct RerunLoggerParams {
        /// .rrd file to write (set this or `connect`)
        path: Option<PathBuf>, path;
        /// stature of the body model used to draw MotionFrame skeletons (m)
        stature_m: f64 = 1.75, float(1.0, 2.5);
        /// stream to a running viewer: "default" or a URL like rerun+http://127.0.0.1:9876/proxy
        connect: Option<String>, string;
        /// with grouped inputs (<group>__<what>): one 3D view per group, or all groups in one
        views: String = "side-by-side", choice(&["side-by-side", "overlaid"]);
        /// with grouped inputs: the groups in order, comma-separated (colours, views; the first is
        /// the reference without truth); default: by name
        group_order: Option<String>, string;
        // 120: two seconds at 60 Hz (see columns.rs).
        /// writing a file: log calls are gathered and written as columns every this many frames
        /// (much less CPU; 0: call by call through rerun's batcher, as a viewer connection always
        /// is)
        batch_frames: u64 = 120, int(0, 100_000);
        /// a single run's truth skeleton: where it is (over the estimate), or its pose beside the
        /// estimate (TRUTH_BESIDE_M along +x from the estimate's root, same seq), to compare poses
        /// without overlap
        truth: String = "overlaid", choice(&["overlaid", "beside"]);
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "rerun-logger",
    role: Role::Sink,
    summary: "logs frames to a rerun .rrd file or a live rerun viewer",
    inputs: InputsSpec::Any,
    outputs: &[],
    params: RerunLoggerParams::SPECS,
};

/// Where the log goes, for error messages.
enum Target {
    File(PathBuf),
    Viewer(String),
}

/// Runs the logger as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let params = RerunLoggerParams::from_params(ctx.params());
    let builder = rerun::RecordingStreamBuilder::new(APPLICATION_ID);
    let (path, connect) = (params.path.as_deref(), params.connect.as_deref());
    let target = match (path, connect) {
        (None, Some(url)) => Target::Viewer(url.to_owned()),
        (path, _) => Target::File(path.unwrap_or(Path::new("")).to_owned()),
    };
    let rec = match (path, connect) {
        (Some(path), None) => {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
            }
            builder
                .save(path)
                .with_context(|| format!("{}: cannot open for writing", path.display()))?
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
        .group_order
        .as_deref()
        .unwrap_or_default()
        .split(',')
        .map(str::trim)
        .filter(|g| !g.is_empty())
        .collect();
    groups.sort_by_key(|g| order.iter().position(|o| o == g).unwrap_or(order.len()));
    // Beside the estimate needs an estimate to stand beside (and a single run: a comparison has a
    // truth in every variant's view already).
    let truth_beside = params.truth == "beside"
        && groups.is_empty()
        && inputs
            .iter()
            .any(|(e, f)| e == FOLLOWED && *f == FrameType::Motion);
    let single_run = groups.is_empty();
    let estimated = estimated_joints(&ctx)?;
    if single_run {
        blueprint::log_legend(&rec, &inputs, truth_beside)?;
        // Without the errors tab until a truth pose is logged (see `log_frames`).
        let sip = follows_sip(&estimated);
        blueprint::send_single_run(&rec, &inputs, false, sip)?;
    } else {
        let overlaid = params.views == "overlaid";
        blueprint::send_grouped(&rec, &groups, overlaid, &inputs)?;
    }
    let sensors = imuflow_body::SensorSet::resolve(ctx.sensors()).context("`sensors`")?;
    let sites: Vec<imuflow_body::Imu> = sensors.sites().collect();
    log_sensor_layout(&rec, &inputs, &sites)?;

    let body = BodyModel::new(&BodyParams::builtin()?, params.stature_m, 70.0)?;
    let has_truth = inputs
        .iter()
        .any(|(e, f)| e == "truth" && *f == FrameType::Motion);
    let mut drawer = SkeletonDrawer::new(body, groups, has_truth);
    drawer.drawn = estimated;
    drawer.truth_beside = truth_beside && has_truth;
    drawer.follows_estimate = inputs
        .iter()
        .any(|(e, f)| e == FOLLOWED && *f == FrameType::Motion);
    let live = ctx.mode() == Mode::Live;
    let mut log = match &target {
        Target::File(_) if params.batch_frames > 0 => Log::in_columns(rec, params.batch_frames),
        _ => Log::call_by_call(rec),
    };
    let logged = if ctx.ready()? {
        log_frames(
            &mut ctx,
            &mut log,
            &inputs,
            &sites,
            live,
            single_run,
            &mut drawer,
        )
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
        Target::File(path) => {
            anyhow::anyhow!("{}: cannot write the rerun log: {e}", path.display())
        }
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

/// Per motion or kinematics input (by entity) whose publishing stage estimates from a sensor set other than the
/// six (and is not a source: a truth holds every joint), the joints drawn and measured
/// ([`crate::skeleton::drawn_joints`] of the set's observed joints). The six's estimates are
/// drawn whole, as before.
fn estimated_joints(
    ctx: &StageContext,
) -> anyhow::Result<BTreeMap<String, crate::skeleton::Estimated>> {
    let mut drawn = BTreeMap::new();
    for name in ctx.input_names() {
        let edge = &ctx.node().inputs[&name];
        let posed = matches!(edge.frame, FrameType::Motion | FrameType::Kinematics);
        let Some(sensors) = ctx
            .graph()
            .estimated_from(&edge.from_stage)
            .filter(|_| posed)
        else {
            continue;
        };
        let set = imuflow_body::SensorSet::resolve(sensors)
            .with_context(|| format!("stage '{}': `sensors`", edge.from_stage))?;
        if !set.is_six() {
            drawn.insert(
                entity_of(&name),
                crate::skeleton::Estimated::of(set.observed_joints()),
            );
        }
    }
    Ok(drawn)
}

/// Whether the followed estimate ([`FOLLOWED`]) has a SIP error: its set observes the hips and
/// shoulders (every set that is not listed in `estimated` does).
fn follows_sip(estimated: &BTreeMap<String, crate::skeleton::Estimated>) -> bool {
    estimated.get(FOLLOWED).is_none_or(|e| {
        imuflow_body::skeleton::SIP_JOINTS
            .iter()
            .all(|j| e.observed & (1 << j.index()) != 0)
    })
}

/// Logs each frame as it arrives, at its own time, until every input has ended: the frame's
/// type decides what draws it; every type's small fields and INVALID flag are plotted. A single
/// run's layout gets its errors tab with the first truth pose.
fn log_frames(
    ctx: &mut StageContext,
    rec: &mut Log,
    inputs: &[(String, FrameType)],
    sites: &[imuflow_body::Imu],
    live: bool,
    single_run: bool,
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
            // Raw samples have no pose to draw; their small fields are plotted below.
            FrameType::RawImu => {}
            FrameType::Imu => {
                if let Some(f) = frame_ref::<ImuFrame>(held) {
                    log_sensors(
                        rec,
                        &mut plots,
                        name,
                        sites,
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
                        sites,
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
                    let had_truth = drawer.truth_seen;
                    drawer.log_motion(rec, name, f)?;
                    if single_run && drawer.truth_seen && !had_truth {
                        let sip = follows_sip(&drawer.drawn);
                        blueprint::send_single_run(rec.stream(), inputs, true, sip)?;
                    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<RerunLoggerParams>().unwrap();
    }
}
