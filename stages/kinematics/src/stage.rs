//! The `kinematics` stage: calibrated IMU frames in, the nets' estimate out, one step per frame.
//!
//! - Frames flagged CALIBRATING pass through as the start pose (flagged CALIBRATING | INVALID); the nets
//!   start (learned initialization from the start pose) at the first calibrated frame, from the
//!   pose its forearm sensors show (T-pose or N-pose, `start_pose = "auto"`) unless one is set.
//! - The bones that carry a sensor take its calibrated orientation, or stay within
//!   `sensor_bone_tolerance_deg` of it (`sensor_bones = "measured"`, [`SensorBones`]);
//!   `"network"` keeps the networks' own estimate, as in the papers.
//! - The knees are hinges and the elbows flex and twist (`limb_joints = "anatomical"`,
//!   [`imuflow_body::limb_joints`]): what the networks' pose asks of them beyond that moves to the
//!   hips and shoulders, and each flexion turns the upper bone toward the knee or elbow position
//!   the networks predict (`"anatomical-rotations"`: from their rotations alone). `"free"` keeps
//!   the networks' 3-DoF joints, as in the papers.
//! - A sensor without a valid sample holds its last valid one, and the output is flagged INVALID; before
//!   any valid sample of a sensor the frame is not fed to the nets at all (the start pose goes out).
//! - Restarted mid-stream (its `restart` policy), the subject is no longer in the start pose: the
//!   nets start from the pose the sensors show instead ([`pose_from_sensors`]).

use std::path::PathBuf;

use anyhow::{Context, bail};
use imuflow_graph::frames::{BodyImuFrame, KinematicsFrame, flags};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, StageContext};
use nalgebra::{Rotation3, UnitQuaternion};

use crate::features::{HeldSamples, ImuInput};
use crate::infer::{
    Estimate, LIMB_JOINTS, LimbJoints, SENSOR_BONE_TOLERANCE_PARAM, SensorBones, StartPose,
    Streamer, impose_measured_bones, sensor_rotation,
};
use crate::method::Method;
use crate::sensed::SensedEstimator;
use crate::weights::Weights;

imuflow_graph::stage_params! {
    /// The kinematics stage's parameters.
    pub struct KinematicsParams {
        /// which paper's networks; sensed: no networks, the pose from the sensed bones'
        /// orientations and the root moved by the standing foot (sensor sets that sense their
        /// legs: lower-body, full-suit)
        net: String = "pip", choice(&["pip", "globalpose", "sensed"]);
        /// weight file (safetensors from `imuflow train` or `imuflow import-checkpoint`)
        weights: Option<PathBuf> = computed("models/<net>.safetensors"), path;
        /// the pose the subject holds when calibration ends (initializes the networks' state);
        /// auto: the one the calibrated forearm sensors show
        start_pose: String = "auto", choice(&["auto", "tpose", "npose"]);
        /// orientation of the bones that carry a sensor (forearms, lower legs, head): measured
        /// (the calibrated sensor's orientation, or the networks' estimate turned to within
        /// sensor_bone_tolerance_deg of it) or network (the networks' own, as in the papers)
        sensor_bones: String = "measured", choice(&["measured", "network"]);
        sensor_bone_tolerance_deg: f64 = use SENSOR_BONE_TOLERANCE_PARAM;
        /// anatomical: knees turn about one axis, elbows flex and twist, neither more than 10°
        /// past straight, and what the networks' pose asks beyond that moves to the hips and
        /// shoulders (the lower legs and forearms keep their orientation), each flexion set so
        /// the upper bone points at the networks' predicted knee or elbow;
        /// anatomical-rotations: the same joints, the flexion from the networks' rotations alone;
        /// free: the networks' 3-DoF joints, as in the papers
        limb_joints: String = "anatomical", choice(&LIMB_JOINTS);
        /// also run the networks on the stream mirrored left-right and average the two estimates
        /// (test-time mirroring; twice the networks' time per frame)
        mirror_ensemble: bool = false, bool;
        /// a second weight file of the same net: both run on every frame and their estimates are
        /// averaged (a weight ensemble; twice the networks' time per frame, four times with
        /// mirror_ensemble)
        ensemble_weights: Option<PathBuf>, path;
        /// live: read the networks' weights into cache just before each frame is due (the stage
        /// idles 16 ms between frames and the other processes evict them)
        warm_weights: bool = true, bool;
    }
}

/// The weight file of `method` when the graph names none.
fn default_weights(method: Method) -> PathBuf {
    PathBuf::from(format!("models/{}.safetensors", method.name()))
}

pub const SPEC: StageSpec = StageSpec {
    kind: "kinematics",
    role: Role::Transform,
    summary: "PIP or GlobalPose networks (or the sensed bones, no networks): calibrated IMUs to pose, joint positions/velocities, contacts, root velocity",
    inputs: InputsSpec::Fixed(&[PortSpec {
        name: "imu",
        frame: FrameType::BodyImu,
        required: true,
        doc: "calibrated IMU frames (calibration stage)",
    }]),
    outputs: &[PortSpec {
        name: "kinematics",
        frame: FrameType::Kinematics,
        required: false,
        doc: "the networks' estimate per frame",
    }],
    params: KinematicsParams::SPECS,
};

/// Runs the kinematics stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = KinematicsParams::from_params(ctx.params());
    let sensors = imuflow_body::SensorSet::resolve(ctx.sensors())
        .with_context(|| format!("stage '{stage}': `sensors`"))?;
    if params.net == "sensed" {
        return run_sensed(ctx, &stage, &sensors);
    }
    let method_name = params.net.as_str();
    let Some(method) = Method::parse(method_name) else {
        bail!("stage '{stage}': unknown net '{method_name}' (pip or globalpose)");
    };
    let weights_path = params
        .weights
        .clone()
        .unwrap_or_else(|| default_weights(method));
    // `None`: the pose the sensors show when the calibration ends (see `StartPose::shown_by`).
    let fixed_start = match params.start_pose.as_str() {
        "tpose" => Some(StartPose::TPose),
        "npose" => Some(StartPose::NPose),
        "auto" => None,
        other => {
            bail!("stage '{stage}': unknown start_pose '{other}' (auto, tpose or npose)")
        }
    };
    // Until a calibrated frame shows it: each paper's own calibration pose.
    let mut start = fixed_start.unwrap_or(if method == Method::Pip {
        StartPose::TPose
    } else {
        StartPose::NPose
    });
    let weights = Weights::load(&weights_path, method).with_context(|| {
        format!(
            "stage '{stage}': loading weights '{}'",
            weights_path.display()
        )
    })?;
    weights
        .metadata
        .check_sensors(&sensors)
        .with_context(|| format!("stage '{stage}': weights '{}'", weights_path.display()))?;
    let sensor_bones_name = params.sensor_bones.as_str();
    let tolerance_deg = params.sensor_bone_tolerance_deg;
    let Some(sensor_bones) = SensorBones::parse(sensor_bones_name, tolerance_deg) else {
        bail!("stage '{stage}': unknown sensor_bones '{sensor_bones_name}' (measured or network)");
    };
    let limb_joints = params.limb_joints.as_str();
    let Some(limb_joints) = LimbJoints::parse(limb_joints) else {
        bail!(
            "stage '{stage}': unknown limb_joints '{limb_joints}' ({})",
            LIMB_JOINTS.join(", ")
        );
    };
    let warm_weights = params.warm_weights;
    let mut streamer = Streamer::new(weights, start.pose())
        .with_context(|| format!("stage '{stage}': weights '{}'", weights_path.display()))?;
    // The weights' set, which `check_sensors` made the graph's.
    let order = streamer.input_order();
    if params.mirror_ensemble && !order.is_symmetric() {
        bail!(
            "stage '{stage}': mirror_ensemble needs every sensor's mirror site in the set; {sensors} has ({}) ",
            order.mask().names()
        );
    }
    streamer.set_sensor_bones(sensor_bones);
    streamer.set_limb_joints(limb_joints);
    streamer.set_mirror_ensemble(params.mirror_ensemble);
    if let Some(path) = params
        .ensemble_weights
        .as_deref()
        .filter(|p| !p.as_os_str().is_empty())
    {
        let partner = Weights::load(path, method).with_context(|| {
            format!(
                "stage '{stage}': loading ensemble_weights '{}'",
                path.display()
            )
        })?;
        streamer
            .set_partner(Some(partner))
            .with_context(|| format!("stage '{stage}': ensemble_weights '{}'", path.display()))?;
    }
    let input = ctx.input::<BodyImuFrame>("imu")?;
    let mut output = ctx.output::<KinematicsFrame>("kinematics")?;
    if !ctx.ready()? {
        return Ok(());
    }
    let mut held = HeldSamples::of(order);
    let whole = order.mask().0;
    let mut resume_from_sensors = ctx.restarts() > 0;
    while let Some(step) = ctx.next_warming(&mut |stop| {
        if warm_weights {
            streamer.warm(stop);
        }
    })? {
        let frame = ctx.get(&input);
        let mut header = step.header();
        let complete = held.update(frame);
        let calibrating = step.flags & flags::CALIBRATING != 0;
        // Calibrating again: the subject holds the start pose after all.
        resume_from_sensors &= !calibrating;
        let estimate = if calibrating || !complete {
            streamer.reset();
            header.flags |= flags::INVALID;
            start_estimate(start)
        } else {
            // The first calibrated frame: the networks start from the pose it shows.
            if !streamer.is_started() && fixed_start.is_none() {
                start = StartPose::shown_by(&held.input);
                streamer.set_start(start.pose());
            }
            if std::mem::take(&mut resume_from_sensors) {
                streamer.set_start(pose_from_sensors(start, &held.input));
            }
            if frame.valid_mask & whole != whole {
                header.flags |= flags::INVALID;
            }
            streamer
                .step(&held.input)
                .with_context(|| format!("stage '{stage}': frame {}", step.seq))?
        };
        output.publish(header, |out| fill(out, &estimate))?;
    }
    ctx.finish(&mut [&mut output])?;
    Ok(())
}

/// `net = "sensed"`: the pose of the graph's sensor set from its sensed bones, no networks
/// ([`SensedEstimator`]). A frame still calibrating, or without every sensor of the set, goes out
/// as the rest pose flagged INVALID, and the next whole frame starts standing where it is.
fn run_sensed(
    mut ctx: StageContext,
    stage: &str,
    sensors: &imuflow_body::SensorSet,
) -> anyhow::Result<()> {
    let body = imuflow_body::BodyModel::new(&imuflow_body::BodyParams::builtin()?, 1.75, 70.0)?;
    let mut estimator = SensedEstimator::new(sensors, body, ctx.graph().rate_hz)
        .map_err(|e| anyhow::anyhow!("stage '{stage}': {e}"))?;
    let input = ctx.input::<BodyImuFrame>("imu")?;
    let mut output = ctx.output::<KinematicsFrame>("kinematics")?;
    if !ctx.ready()? {
        return Ok(());
    }
    let whole = sensors.mask().0;
    while let Some(step) = ctx.next()? {
        let frame = *ctx.get(&input);
        let mut header = step.header();
        let estimate = if step.flags & flags::CALIBRATING != 0 || frame.valid_mask & whole != whole
        {
            estimator.reset();
            header.flags |= flags::INVALID;
            start_estimate(StartPose::TPose)
        } else {
            estimator.step(&frame)
        };
        output.publish(header, |out| fill(out, &estimate))?;
    }
    ctx.finish(&mut [&mut output])?;
    Ok(())
}

/// The pose to start the nets from when joining a stream mid-motion (after a restart): the start
/// pose with the root on the pelvis sensor and every instrumented bone (forearms, lower legs,
/// head) on its sensor's calibrated orientation; the joints without a sensor keep the start pose.
/// The issue asks for "the LSTM re-initialised from the current calibrated pose": this is as much
/// of it as the sensors measure.
pub fn pose_from_sensors(start: StartPose, imu: &ImuInput) -> imuflow_body::Pose {
    let mut pose = start.pose();
    pose.parent_from_joint[0] = sensor_rotation(imu.root_orientation());
    impose_measured_bones(&mut pose.parent_from_joint, imu, 0.0);
    pose
}

fn start_estimate(start: StartPose) -> Estimate {
    let pose = start.pose();
    Estimate {
        pose: pose.parent_from_joint,
        joint_position: [nalgebra::Vector3::zeros(); 24],
        joint_velocity: [nalgebra::Vector3::zeros(); 24],
        foot_contact: [1.0, 1.0],
        stationary: [1.0; 5],
        root_velocity: nalgebra::Vector3::zeros(),
        gravity_in_root: nalgebra::Vector3::new(0.0, -9.81, 0.0),
    }
}

fn quat_wxyz(r: &Rotation3<f64>) -> [f32; 4] {
    let q = UnitQuaternion::from_rotation_matrix(r);
    [q.w as f32, q.i as f32, q.j as f32, q.k as f32]
}

/// Write an estimate into a wire frame (the header is the caller's).
pub fn fill(out: &mut KinematicsFrame, e: &Estimate) {
    for j in 0..24 {
        out.local_pose_wxyz[j] = quat_wxyz(&e.pose[j]);
        out.joint_position_m[j] = e.joint_position[j].cast::<f32>().into();
        out.joint_velocity_mps[j] = e.joint_velocity[j].cast::<f32>().into();
    }
    out.foot_contact_prob = e.foot_contact.map(|v| v as f32);
    out.stationary_prob = e.stationary.map(|v| v as f32);
    out.root_velocity_mps = e.root_velocity.cast::<f32>().into();
    out.gravity_in_root_mps2 = e.gravity_in_root.cast::<f32>().into();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infer::global_rotations;
    use imuflow_body::JointId;
    use imuflow_body::NUM_IMUS;
    use imuflow_body::skeleton::IMU_JOINTS;
    use nalgebra::{Unit, Vector3};

    fn row_major(r: &Rotation3<f64>) -> [f32; 9] {
        std::array::from_fn(|k| r[(k / 3, k % 3)] as f32)
    }

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<KinematicsParams>().unwrap();
        let text = SPEC.param("weights").unwrap().default;
        for method in [Method::Pip, Method::GlobalPose] {
            assert_eq!(
                default_weights(method),
                PathBuf::from(text.replace("<net>", method.name())),
                "the weights' text names the path default_weights builds"
            );
        }
    }

    #[test]
    fn a_restart_starts_from_the_pose_the_sensors_show() {
        let mut imu = ImuInput::default();
        let turned: Vec<Rotation3<f64>> = (0..NUM_IMUS)
            .map(|i| {
                let axis = Unit::new_normalize(Vector3::new(1.0, i as f64 - 2.0, 0.5));
                Rotation3::from_axis_angle(&axis, 0.3 + 0.2 * i as f64)
            })
            .collect();
        for (i, r) in turned.iter().enumerate() {
            imu.orientation[i] = row_major(r);
        }
        let start = StartPose::TPose.pose();
        let pose = pose_from_sensors(StartPose::TPose, &imu);
        let global = global_rotations(&pose.parent_from_joint);
        // Every instrumented bone, the root included, on its sensor (f32 rounding).
        for (sensor, joint) in IMU_JOINTS.iter().enumerate() {
            let off = (global[joint.index()].matrix() - turned[sensor].matrix()).norm();
            assert!(off < 1e-6, "sensor {sensor}: {off} off");
        }
        // Joints whose own rotation no sensor measures keep the start pose (local rotations).
        for j in [3, 6, 9, 12, 13, 14, 16, 17, 1, 2] {
            let off = (pose.parent_from_joint[j].transpose() * start.parent_from_joint[j]).angle();
            assert!(off < 1e-12, "joint {j} moved by {off} rad");
        }
    }

    /// The sensors of a body in `start` turned as a whole by `heading` about the vertical, with the arms
    /// `lowered` radians further down (a subject never holds the reference poses exactly).
    fn sensors_of(start: StartPose, heading: f64, lowered: f64) -> ImuInput {
        let mut pose = start.pose();
        let z = Vector3::z_axis();
        for (joint, sign) in [
            (JointId::LEFT_SHOULDER, -1.0),
            (JointId::RIGHT_SHOULDER, 1.0),
        ] {
            pose.parent_from_joint[joint.index()] *= Rotation3::from_axis_angle(&z, sign * lowered);
        }
        pose.parent_from_joint[0] = Rotation3::from_axis_angle(&Vector3::y_axis(), heading);
        let global = global_rotations(&pose.parent_from_joint);
        let mut imu = ImuInput::default();
        for (sensor, joint) in IMU_JOINTS.iter().enumerate() {
            imu.orientation[sensor] = row_major(&global[joint.index()]);
        }
        imu
    }

    #[test]
    fn the_start_pose_is_the_one_the_forearm_sensors_show() {
        for heading in [0.0, 1.0, -2.5] {
            // Held exactly, or 30° off towards the other pose: still the nearer one.
            for lowered in [0.0, 0.5] {
                let t = sensors_of(StartPose::TPose, heading, lowered);
                assert_eq!(
                    StartPose::shown_by(&t),
                    StartPose::TPose,
                    "{heading} {lowered}"
                );
                let n = sensors_of(StartPose::NPose, heading, -lowered);
                assert_eq!(
                    StartPose::shown_by(&n),
                    StartPose::NPose,
                    "{heading} {lowered}"
                );
            }
        }
    }
}
