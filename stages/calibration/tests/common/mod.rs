//! Simulation with known truth: the imu-source's synthesize mode (prelude, random mountings,
//! inertial frames with heading offsets, the reference noise model) and helpers to compare the
//! calibration's output with the true bone orientations.
#![allow(dead_code)]

use std::path::Path;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::rotation::{angle_between, rotation_from_quat_wxyz};
use imuflow_body::{BodyModel, Imu, Pose};
use imuflow_calibration::{
    Calibrator, CalibratorConfig, Event, InertialFrame, Method, NUM_IMUS, PELVIS,
};
use imuflow_graph::frames::{BodyImuFrame, ImuFrame};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{
    MotionClip, RetargetOptions, SourceSkeleton, resample, retarget_bvh,
};
use imuflow_synth::prelude::{PreludeKind, PreludeOptions};
use imuflow_synth::{self as synth, Motion, Options, SensorSetup};
use nalgebra::Rotation3;

pub const RATE_HZ: f64 = 60.0;

pub fn body() -> BodyModel {
    synth::body_model(&Options::default()).expect("builtin body")
}

/// The committed walking fixture (1.6 s) at 60 Hz.
pub fn fixture_clip(body: &BodyModel) -> MotionClip {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh");
    let bvh = Bvh::read(&path).expect("fixture");
    let source = SourceSkeleton::bandai_namco().expect("mapping");
    let clip = retarget_bvh(&bvh, &source, body, &RetargetOptions::default()).expect("retarget");
    resample(&clip, RATE_HZ).expect("resample")
}

/// `clip` played forwards, backwards, forwards, ... until it lasts `secs` (continuous poses: the
/// subject walks there and back).
pub fn ping_pong(clip: &MotionClip, secs: f64) -> MotionClip {
    let n = clip.poses.len();
    let want = (secs * RATE_HZ) as usize;
    let cycle: Vec<usize> = (0..n).chain((1..n - 1).rev()).collect();
    let poses = cycle
        .iter()
        .cycle()
        .take(want)
        .map(|&i| clip.poses[i].clone())
        .collect();
    MotionClip {
        frame_time_s: clip.frame_time_s,
        poses,
    }
}

pub fn prelude(kind: PreludeKind) -> PreludeOptions {
    PreludeOptions {
        kind,
        ..PreludeOptions::default()
    }
}

/// Random mountings; the given convention, heading and ±offset.
pub fn setup(frame: InertialFrame, heading_deg: f64, offset_deg: f64) -> SensorSetup {
    SensorSetup {
        random_mounting: true,
        frame,
        frame_heading_deg: heading_deg,
        heading_offset_deg: offset_deg,
    }
}

/// Synthesizes `clip` (with a prelude) on the reference body.
pub fn synthesize(
    clip: MotionClip,
    prelude: PreludeOptions,
    sensors: SensorSetup,
    augment: bool,
    seed: u64,
) -> Motion {
    let options = Options {
        prelude,
        sensors,
        augment,
        seed,
        ..Options::default()
    };
    Motion::from_clip(clip, &body(), &options).expect("synthesis")
}

pub fn walking(frame: InertialFrame) -> CalibratorConfig {
    CalibratorConfig {
        method: Method::Walking,
        frame,
        pose: imuflow_calibration::ReferencePose::N,
        // The synthetic subjects stand with straight arms unless a test bends them.
        walk_start_pose: imuflow_calibration::ReferencePose::N,
        ..CalibratorConfig::default()
    }
}

pub fn tpose(frame: InertialFrame, heading_deg: f64) -> CalibratorConfig {
    CalibratorConfig {
        method: Method::Tpose,
        frame,
        heading_rad: heading_deg.to_radians(),
        ..CalibratorConfig::default()
    }
}

/// What a session produced, frame by frame.
pub struct Session {
    pub outputs: Vec<BodyImuFrame>,
    pub events: Vec<(usize, Event)>,
    pub calibrator: Calibrator,
}

impl Session {
    /// Index of the frame at which the calibration was (first) accepted.
    pub fn calibrated_at(&self) -> Option<usize> {
        self.events
            .iter()
            .find(|(_, e)| matches!(e, Event::Calibrated { .. }))
            .map(|(i, _)| *i)
    }

    pub fn rejections(&self) -> Vec<String> {
        self.events
            .iter()
            .filter_map(|(_, e)| match e {
                Event::Rejected { reason, .. } => Some(reason.to_string()),
                _ => None,
            })
            .collect()
    }
}

pub fn run_frames(config: CalibratorConfig, frames: impl IntoIterator<Item = ImuFrame>) -> Session {
    let mut calibrator = Calibrator::new(config);
    let mut outputs = Vec::new();
    let mut events = Vec::new();
    for (i, frame) in frames.into_iter().enumerate() {
        let mut out = BodyImuFrame::default();
        if let Some(e) = calibrator.push(&frame, &mut out) {
            events.push((i, e));
        }
        outputs.push(out);
    }
    Session {
        outputs,
        events,
        calibrator,
    }
}

/// Why a session did not calibrate (its refusal), for a failing test's message.
pub fn refusal(session: &Session) -> String {
    session
        .calibrator
        .finish()
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default()
}

pub fn run(config: CalibratorConfig, motion: &Motion) -> Session {
    run_frames(
        config,
        (0..motion.len()).map(|i| motion.imu_frame(i).expect("frame")),
    )
}

/// True `R_MB` of every IMU's bone at frame `t`.
pub fn true_bones(body: &BodyModel, pose: &Pose) -> [Rotation3<f64>; NUM_IMUS] {
    let mut fk = FkData::new();
    forward_kinematics(&body.skeleton, pose, &mut fk);
    Imu::SIX.map(|imu| *fk.world_from(imu.joint()))
}

/// The true `R_SB` at frame `t`: the random mounting composed with the synthesized sensor's own
/// (the augmentation's mounting error, as the sensor reports it at `t`).
pub fn true_sensor_from_bone(
    motion: &Motion,
    body: &BodyModel,
    t: usize,
) -> [Rotation3<f64>; NUM_IMUS] {
    let bones = true_bones(body, &motion.clip.poses[t]);
    std::array::from_fn(|k| {
        let ideal_from_bone = motion.imus[t][k].model_from_sensor.transpose() * bones[k];
        motion.sensors.ideal_from_sensor[k].transpose() * ideal_from_bone
    })
}

/// The heading corrections a walking calibration should find: heading[pelvis] − heading[k].
pub fn true_heading_corrections(motion: &Motion) -> [f64; NUM_IMUS] {
    let h = motion.sensors.heading_rad;
    std::array::from_fn(|k| wrap(h[PELVIS] - h[k]))
}

pub fn wrap(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    a - two_pi * ((a + std::f64::consts::PI) / two_pi).floor()
}

/// Angle (deg) between the output's bone orientation of sensor `k` and the truth.
pub fn bone_error_deg(out: &BodyImuFrame, truth: &[Rotation3<f64>; NUM_IMUS], k: usize) -> f64 {
    let q = out.bone_orientation_wxyz[k].map(f64::from);
    let r = rotation_from_quat_wxyz(&q).expect("unit quaternion");
    angle_between(&r, &truth[k]).to_degrees()
}

/// Per-sensor errors (deg) of the recovered `R_SB` against the truth at frame `t`.
pub fn sensor_from_bone_errors_deg(
    session: &Session,
    motion: &Motion,
    t: usize,
) -> [f64; NUM_IMUS] {
    let truth = true_sensor_from_bone(motion, &body(), t);
    let cal = session.calibrator.calibration().expect("calibrated");
    std::array::from_fn(|k| angle_between(&cal.sensors[k].sensor_from_bone, &truth[k]).to_degrees())
}

/// Per-sensor errors (deg) of the heading corrections.
pub fn heading_errors_deg(session: &Session, motion: &Motion) -> [f64; NUM_IMUS] {
    let truth = true_heading_corrections(motion);
    let cal = session.calibrator.calibration().expect("calibrated");
    std::array::from_fn(|k| {
        wrap(cal.sensors[k].heading_correction_rad - truth[k])
            .abs()
            .to_degrees()
    })
}

pub fn max(values: impl IntoIterator<Item = f64>) -> f64 {
    values.into_iter().fold(0.0, f64::max)
}

/// 1.6 s of the fixture, enough behind a prelude for most tests.
pub fn short_clip() -> MotionClip {
    fixture_clip(&body())
}

/// The frame in the middle of the prelude's first stand.
pub fn first_stand_mid(prelude: &PreludeOptions) -> usize {
    (prelude.stand_s * RATE_HZ / 2.0) as usize
}

/// The bundled sample's true walking (13 s, its calibration prelude left out) at 60 Hz.
pub fn sample_walk_clip() -> MotionClip {
    use imuflow_graph::frames::flags;
    use imuflow_recording::{Recorded, Recording};
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sample/walk.mcap");
    let recording = Recording::load(&path, None, None).expect("bundled sample");
    let poses = recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(t) if !t.header.has(flags::PRELUDE) => Some(t),
            _ => None,
        })
        .map(|t| Pose::from_wire(&t.local_pose_wxyz, &t.root_position_m).expect("true pose"))
        .collect();
    MotionClip {
        frame_time_s: 1.0 / RATE_HZ,
        poses,
    }
}

/// Median and maximum of `values`.
pub fn median_max(values: &[f64]) -> (f64, f64) {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[v.len() - 1])
}
