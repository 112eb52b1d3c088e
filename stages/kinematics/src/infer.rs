//! Streaming inference: one step per frame with persistent LSTM states, for both methods.
//!
//! PIP (reference §2.2): x → rnn1 (leaf positions) → rnn2 (all joint positions) → rnn3 (reduced
//! rotations) / rnn4 (joint velocities) / rnn5 (foot contacts), all in the root IMU's frame.
//! GlobalPose (reference §2.4, paper Eq. 1-3): plnet (IMU positions + gravity) → iknet.net1 (joint
//! positions + gravity) → iknet.net2 (reduced rotations) → root-orientation correction from the
//! refined gravity → vrnet (root velocity, stationary probabilities).

use candle_core::{Device, Tensor};
use imuflow_body::kinematics::{FkData, forward_kinematics, imu_positions_in_world};
use imuflow_body::limb_joints::{flex_toward_positions, limit_hyperextension, project_limb_joints};
use imuflow_body::rotation::{from_to, rotation_from_r6d};
use imuflow_body::skeleton::{CONTACT_JOINTS, FULL_JOINTS, REDUCED_JOINTS};
use imuflow_body::{BodyModel, BodyParams, Imu, JointId, NUM_JOINTS, Pose};
use imuflow_graph::params::Param;
use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion, Vector3};

use crate::features::{FPS, PIP_VELOCITY_SCALE};
use crate::features::{
    GLOBALPOSE_INPUT, ImuInput, InputOrder, ROOT_IMU, globalpose_input, pip_input, pip_input_len,
};
use crate::lean::LeanRnn;
use crate::method::Method;
use crate::mirror;
use crate::net::{LstmState, Rnn};
use crate::weights::Weights;

/// Gravity magnitude used for `gravity_in_root` (m/s², the body model's).
const G: f64 = 9.81;

/// What the nets estimate for one frame (the KinematicsFrame payload, f64).
#[derive(Clone, Debug)]
pub struct Estimate {
    /// Local pose; joint 0 is the root's orientation in M.
    pub pose: [Rotation3<f64>; NUM_JOINTS],
    /// Joint positions relative to the root, M axes (m).
    pub joint_position: [Vector3<f64>; NUM_JOINTS],
    /// Joint velocities in M (m/s). PIP predicts them; for GlobalPose they are the predicted root
    /// velocity plus the frame-to-frame change of the root-relative joint positions.
    pub joint_velocity: [Vector3<f64>; NUM_JOINTS],
    /// [left, right] foot contact probability.
    pub foot_contact: [f64; 2],
    /// [pelvis, left foot, right foot, left hand, right hand] stationary probability.
    pub stationary: [f64; 5],
    /// Root velocity in M (m/s).
    pub root_velocity: Vector3<f64>,
    /// Gravity in the (corrected) root frame (m/s²).
    pub gravity_in_root: Vector3<f64>,
}

/// The pose a session starts from (the calibration pose).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StartPose {
    /// Every joint at identity, arms out.
    TPose,
    /// Arms down along the body (GlobalPose's N-pose: shoulders turned ∓90° about M's z).
    NPose,
}

impl StartPose {
    pub fn pose(self) -> Pose {
        let mut pose = Pose::t_pose(Vector3::zeros());
        if self == StartPose::NPose {
            // The N-pose references of the reference file §4 (IMU0 = Rz(−90°), IMU1 = Rz(+90°)) put
            // the forearms down; turning the shoulders does that for the whole arm.
            let z = Vector3::z_axis();
            pose.parent_from_joint[JointId::LEFT_SHOULDER.index()] =
                Rotation3::from_axis_angle(&z, -std::f64::consts::FRAC_PI_2);
            pose.parent_from_joint[JointId::RIGHT_SHOULDER.index()] =
                Rotation3::from_axis_angle(&z, std::f64::consts::FRAC_PI_2);
        }
        pose
    }

    /// The start pose the calibrated sensors show: the one whose forearms, relative to the pelvis,
    /// lie nearer the forearm sensors' orientations (T-pose: arms out; N-pose: arms down). A T-pose
    /// calibration ends with the subject holding the T-pose, a walking calibration standing with the
    /// arms down, and a network started from the other pose carries that error for a long while
    /// (end to end on 40 clips of the validation split: PIP's networks 6.98° SIP after a T-pose
    /// calibration, 10.56° after a walking one when both started from the T-pose; GlobalPose's
    /// networks 6.20° after walking, 8.37° after a T-pose when both started from the N-pose).
    /// A set without forearm sensors shows neither: the N-pose (arms down, as people stand).
    pub fn shown_by(imu: &ImuInput) -> StartPose {
        let pelvis = sensor_rotation(imu.root_orientation());
        let forearms: Vec<usize> = [Imu::LeftForearm, Imu::RightForearm]
            .into_iter()
            .filter_map(|site| imu.order.index_of(site))
            .collect();
        if forearms.is_empty() {
            return StartPose::NPose;
        }
        let mismatch = |start: StartPose| -> f64 {
            // The start poses' root is at identity: their global rotations are relative to it.
            let expected = global_rotations(&start.pose().parent_from_joint);
            forearms
                .iter()
                .map(|&sensor| {
                    let joint = imu.order.site(sensor).joint();
                    let measured = pelvis.transpose() * sensor_rotation(&imu.orientation[sensor]);
                    (measured * expected[joint.index()].transpose()).angle()
                })
                .sum()
        };
        if mismatch(StartPose::NPose) < mismatch(StartPose::TPose) {
            StartPose::NPose
        } else {
            StartPose::TPose
        }
    }
}

/// Where the output pose takes the orientation of the bones that carry a sensor (forearms, lower
/// legs, head) from.
///
/// Both papers let the networks estimate every reduced joint, the instrumented ones included, so
/// the estimate can contradict the sensor on that very bone (measured through the graphs: 22° on
/// the forearms of a standing person with the hands in front, 12.6° on the head, while calibration
/// put those sensors within 2.5–3.8° of their bones). TransPose and PIP already take the root's
/// orientation straight from the pelvis sensor (reference §2.1 "Pose assembly"); `Measured`
/// extends that to the other five sensors, up to a tolerance: the bone keeps the networks' estimate
/// while it is within `tolerance` of the measurement, and is turned onto the edge of that cone
/// when it is not. The default is the measurement itself ([`SENSOR_BONE_TOLERANCE_DEG`]): through
/// the graphs, with the calibration in front, the calibrated sensor is a better estimate of its
/// bone than the networks' (end to end on the held-out contents, 5° -> 0°: angle error −1.2 to
/// −1.6°, SIP −0.4 to −0.7°, jitter +8-29 %). Without a calibration (the networks-alone test
/// copies with 0.1 rad mounting errors) a cone of a few degrees filters the mounting error better.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SensorBones {
    /// Within `tolerance_rad` of the calibrated measurement (0: the measurement itself).
    Measured { tolerance_rad: f64 },
    /// The networks' own estimate (the papers' behaviour).
    Network,
}

/// The kinematics stage's `sensor_bone_tolerance_deg`, the tolerance of [`SensorBones::Measured`]:
/// by default 0°, the calibrated measurement itself (see [`SensorBones`]; it was 5° until
/// 2026-11-26, before the knees and elbows were made anatomical joints, through which the lower
/// legs' and forearms' orientations also set the bones above).
pub const SENSOR_BONE_TOLERANCE_PARAM: Param<f64> = imuflow_graph::param! {
    /// with sensor_bones = measured: how far a bone may stay from its sensor (0: the measurement
    /// itself)
    sensor_bone_tolerance_deg: f64 = 0, float(0.0, 180.0)
};

/// Default tolerance of [`SensorBones::Measured`], degrees ([`SENSOR_BONE_TOLERANCE_PARAM`]).
pub const SENSOR_BONE_TOLERANCE_DEG: f64 = SENSOR_BONE_TOLERANCE_PARAM.default;

impl Default for SensorBones {
    fn default() -> SensorBones {
        SensorBones::Measured {
            tolerance_rad: SENSOR_BONE_TOLERANCE_DEG.to_radians(),
        }
    }
}

impl SensorBones {
    /// `"measured"` (with `tolerance_deg`) or `"network"`.
    pub fn parse(name: &str, tolerance_deg: f64) -> Option<SensorBones> {
        match name {
            "measured" if tolerance_deg.is_finite() && tolerance_deg >= 0.0 => {
                Some(SensorBones::Measured {
                    tolerance_rad: tolerance_deg.to_radians(),
                })
            }
            "network" => Some(SensorBones::Network),
            _ => None,
        }
    }
}

/// The names of the `limb_joints` choices (kinematics stage param, `imuflow eval --limb-joints`),
/// in the order of [`LimbJoints::NAMES`].
pub const LIMB_JOINTS: [&str; 3] = LimbJoints::NAMES;

/// What the knees and elbows may do (kinematics stage param `limb_joints`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LimbJoints {
    /// Knees as hinges and elbows as flexion-and-twist joints ([`project_limb_joints`]), their
    /// flexion from the networks' joint positions ([`flex_toward_positions`]), neither bent more
    /// than 10° backwards ([`limit_hyperextension`]). The default.
    #[default]
    Anatomical,
    /// The same joints, their flexion from the networks' rotations only (the angle between the
    /// networks' upper bone and the measured lower bone), with the same limit: the default
    /// before 2026-11-26's sixth session.
    AnatomicalRotations,
    /// The networks' free 3-DoF joints, as in the papers.
    Free,
}

impl LimbJoints {
    /// The param values, in declaration order.
    pub const NAMES: [&'static str; 3] = ["anatomical", "anatomical-rotations", "free"];

    /// Every choice, in the order of [`LimbJoints::NAMES`].
    const ALL: [LimbJoints; 3] = [
        LimbJoints::Anatomical,
        LimbJoints::AnatomicalRotations,
        LimbJoints::Free,
    ];

    /// The choice a param value names, if any.
    pub fn parse(name: &str) -> Option<LimbJoints> {
        Self::ALL.into_iter().find(|choice| choice.name() == name)
    }

    /// The param value that names this choice.
    pub fn name(self) -> &'static str {
        match self {
            LimbJoints::Anatomical => Self::NAMES[0],
            LimbJoints::AnatomicalRotations => Self::NAMES[1],
            LimbJoints::Free => Self::NAMES[2],
        }
    }

    /// Makes `pose` what these joints allow; `positions` are the networks' joint positions
    /// relative to the root in the frame `pose[0]` maps to.
    fn impose(
        self,
        pose: &mut [Rotation3<f64>; NUM_JOINTS],
        positions: &[Vector3<f64>; NUM_JOINTS],
        body: &BodyModel,
    ) {
        if self == LimbJoints::Free {
            return;
        }
        project_limb_joints(pose);
        if self == LimbJoints::Anatomical {
            flex_toward_positions(pose, positions, &body.skeleton);
        }
        limit_hyperextension(pose);
    }
}

/// What steps the nets each frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Backend {
    /// [`LeanRnn`]: plain f32 over the same weights, no per-op overhead (the default).
    #[default]
    Lean,
    /// candle's [`Rnn::step`], the training path's arithmetic (kept as the reference the lean path
    /// is tested against, and for `imuflow bench kinematics --candle`).
    Candle,
}

/// One method's nets with their streaming state.
pub struct Streamer {
    method: Method,
    /// The sensors the nets take, in their order (the weights' set).
    order: InputOrder,
    /// For a set other than the six, the joints its sensors do not observe, as a mask over joint
    /// indices: set to rest in every estimate, the joint positions following; `None` for the
    /// six-site set, whose nets' own pose those joints keep.
    at_rest: Option<u32>,
    /// Whether the set measures the upper bone of every limb it observes
    /// ([`InputOrder::measures_every_observed_limb`]): no hinge is imposed then.
    limbs_measured: bool,
    sensor_bones: SensorBones,
    /// What the knees and elbows may do.
    limb_joints: LimbJoints,
    backend: Backend,
    nets: Vec<Rnn>,
    /// The nets' lean copies; they hold their own state.
    lean: Vec<LeanRnn>,
    /// candle's states (the learned initial states, then the state of [`Backend::Candle`]).
    states: Vec<LstmState>,
    /// Time spent stepping the nets since construction (for the benchmark).
    nets_time: std::time::Duration,
    body: BodyModel,
    fk: FkData,
    /// The pose at the first frame (its root orientation is replaced by the root IMU's).
    start: Pose,
    started: bool,
    /// GlobalPose: the previous frame's root-relative joint positions (for the joint velocities).
    previous_joint_position: Option<[Vector3<f64>; NUM_JOINTS]>,
    /// With test-time mirroring ([`crate::mirror`]): the same nets with their own states, stepped
    /// on the mirrored stream.
    mirrored: Option<Box<Streamer>>,
    /// With a weight ensemble: a second set of weights of the same method, with its own states,
    /// stepped on the same stream (and, with test-time mirroring, on its mirror too).
    partner: Option<Box<Streamer>>,
}

fn tensor(values: &[f32]) -> candle_core::Result<Tensor> {
    Tensor::from_slice(values, (1, values.len()), &Device::Cpu)
}

fn values(t: &Tensor) -> candle_core::Result<Vec<f32>> {
    t.flatten_all()?.to_vec1()
}

fn v3(v: &[f32]) -> Vector3<f64> {
    Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64)
}

/// A row-major 3×3 (an [`ImuInput`] orientation) as a rotation, taken as it is (the calibration
/// publishes rotations; no iterative projection, which would never return on a NaN sample).
pub fn sensor_rotation(m: &[f32; 9]) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&m.map(|v| v as f64)))
}

fn row_major(r: &Rotation3<f64>) -> [f32; 9] {
    let m = r.matrix();
    let mut out = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            out[i * 3 + j] = m[(i, j)] as f32;
        }
    }
    out
}

/// The root-relative positions of the [`FULL_JOINTS`] (the first 69 values, root frame) turned
/// into M by `root`; the root's own entry is zero.
fn world_positions(root_frame: &[f32], root: &Rotation3<f64>) -> [Vector3<f64>; NUM_JOINTS] {
    let mut world = [Vector3::zeros(); NUM_JOINTS];
    for (k, j) in FULL_JOINTS.iter().enumerate() {
        world[j.index()] = root * v3(&root_frame[3 * k..3 * k + 3]);
    }
    world
}

fn sigmoid(v: f32) -> f64 {
    1.0 / (1.0 + (-(v as f64)).exp())
}

fn unit(v: Vector3<f64>) -> Unit<Vector3<f64>> {
    Unit::try_new(v, 1e-9).unwrap_or(-Vector3::y_axis())
}

impl Streamer {
    pub fn new(weights: Weights, start: Pose) -> anyhow::Result<Streamer> {
        let params = BodyParams::builtin()?;
        // The subject the training data was synthesized on (tools/dataset/README.md).
        let body = BodyModel::new(&params, 1.75, 70.0)?;
        let states = Vec::new();
        let lean = weights
            .nets
            .iter()
            .map(LeanRnn::new)
            .collect::<candle_core::Result<_>>()?;
        let method = weights.metadata.method;
        let order = crate::weights::input_order(method, weights.metadata.sites()?)?;
        let at_rest =
            (!order.is_six()).then(|| !order.mask().observed_joints() & ((1 << NUM_JOINTS) - 1));
        Ok(Streamer {
            method,
            order,
            at_rest,
            limbs_measured: order.measures_every_observed_limb(),
            sensor_bones: SensorBones::default(),
            limb_joints: LimbJoints::default(),
            backend: Backend::default(),
            nets: weights.nets,
            lean,
            states,
            nets_time: std::time::Duration::ZERO,
            body,
            fk: FkData::new(),
            start,
            started: false,
            previous_joint_position: None,
            mirrored: None,
            partner: None,
        })
    }

    /// Also step the nets on the stream reflected left–right and average the two estimates
    /// ([`crate::mirror`]; default off). Starts a new session.
    pub fn set_mirror_ensemble(&mut self, on: bool) {
        self.started = false;
        self.mirrored = on.then(|| {
            Box::new(Streamer {
                method: self.method,
                order: self.order,
                at_rest: self.at_rest,
                limbs_measured: self.limbs_measured,
                sensor_bones: self.sensor_bones,
                limb_joints: self.limb_joints,
                backend: self.backend,
                nets: self.nets.clone(),
                lean: self.lean.clone(),
                states: Vec::new(),
                nets_time: std::time::Duration::ZERO,
                body: self.body.clone(),
                fk: FkData::new(),
                start: self.start.mirrored(),
                started: false,
                previous_joint_position: None,
                mirrored: None,
                partner: None,
            })
        });
        if let Some(partner) = &mut self.partner {
            partner.set_mirror_ensemble(on);
        }
    }

    /// Also step a second set of weights of the same method on the same stream and average the
    /// two estimates the way test-time mirroring does (a weight ensemble; default none). The
    /// partner takes this streamer's settings, mirroring included. Starts a new session.
    pub fn set_partner(&mut self, weights: Option<Weights>) -> anyhow::Result<()> {
        self.started = false;
        self.partner = None;
        let Some(weights) = weights else {
            return Ok(());
        };
        if weights.metadata.method != self.method {
            anyhow::bail!(
                "the ensemble's second weights are {}'s, the first {}'s",
                weights.metadata.method.name(),
                self.method.name()
            );
        }
        let mut partner = Streamer::new(weights, self.start.clone())?;
        partner.set_sensor_bones(self.sensor_bones);
        partner.set_limb_joints(self.limb_joints);
        partner.set_backend(self.backend);
        partner.set_mirror_ensemble(self.mirrored.is_some());
        self.partner = Some(Box::new(partner));
        Ok(())
    }

    /// The streamers stepped beside this one: its mirror twin and its weight partner.
    fn companions(&mut self) -> impl Iterator<Item = &mut Box<Streamer>> {
        self.mirrored.iter_mut().chain(self.partner.iter_mut())
    }

    /// Whether the nets also run on the mirrored stream.
    pub fn mirror_ensemble(&self) -> bool {
        self.mirrored.is_some()
    }

    /// The sensors the nets take, in their order (the weights' set).
    pub fn input_order(&self) -> InputOrder {
        self.order
    }

    pub fn method(&self) -> Method {
        self.method
    }

    /// Where the instrumented bones' orientations come from (default: measured).
    pub fn set_sensor_bones(&mut self, sensor_bones: SensorBones) {
        self.sensor_bones = sensor_bones;
        for twin in self.companions() {
            twin.set_sensor_bones(sensor_bones);
        }
    }

    /// What the knees and elbows may do, imposed after the sensor bones are set (default:
    /// anatomical, flexed toward the networks' joint positions; `Free` is the papers' behaviour).
    pub fn set_limb_joints(&mut self, limb_joints: LimbJoints) {
        self.limb_joints = limb_joints;
        for twin in self.companions() {
            twin.set_limb_joints(limb_joints);
        }
    }

    /// Step the nets with `backend` from the next session on (starts one: the two keep separate
    /// states).
    pub fn set_backend(&mut self, backend: Backend) {
        self.backend = backend;
        self.started = false;
        for twin in self.companions() {
            twin.set_backend(backend);
        }
    }

    pub fn backend(&self) -> Backend {
        self.backend
    }

    /// Total time spent in the nets' steps so far (the rest of [`Streamer::step`] is features,
    /// forward kinematics and pose assembly).
    pub fn nets_time(&self) -> std::time::Duration {
        self.nets_time
            + self
                .mirrored
                .iter()
                .chain(&self.partner)
                .map(|t| t.nets_time())
                .sum::<std::time::Duration>()
    }

    /// Forget the state: the next frame starts a new session from the start pose.
    pub fn reset(&mut self) {
        self.started = false;
        for twin in self.companions() {
            twin.reset();
        }
    }

    /// Whether the networks are running: stepped since the last [`Streamer::reset`] or
    /// [`Streamer::set_start`].
    pub fn is_started(&self) -> bool {
        self.started
    }

    /// Start the next session (after [`Streamer::reset`]) from `pose`.
    pub fn set_start(&mut self, pose: Pose) {
        if let Some(twin) = &mut self.mirrored {
            twin.set_start(pose.mirrored());
        }
        if let Some(partner) = &mut self.partner {
            partner.set_start(pose.clone());
        }
        self.start = pose;
        self.started = false;
    }

    /// Learned initial states from the start pose (reference §2.2, §2.4: PIP rnn1 from the leaf
    /// positions with the root at identity, rnn4 from zero velocity; GlobalPose plnet from the IMU
    /// positions and gravity in the root frame, vrnet from zero velocity and "stationary").
    fn initialize(&mut self, root_orientation: &Rotation3<f64>) -> anyhow::Result<()> {
        let mut pose = self.start.clone();
        pose.parent_from_joint[0] = Rotation3::identity();
        pose.root_in_world_m = Vector3::zeros();
        forward_kinematics(&self.body.skeleton, &pose, &mut self.fk);
        let rel =
            |fk: &FkData, j: JointId| (fk.position(j) - fk.position(JointId::ROOT)).cast::<f32>();
        let mut inits: Vec<Option<Vec<f32>>> = vec![None; self.nets.len()];
        match self.method {
            Method::Pip => {
                inits[0] = Some(
                    self.order
                        .leaf_joints()
                        .iter()
                        .flat_map(|&j| rel(&self.fk, j).data.0[0])
                        .collect(),
                );
                inits[3] = Some(vec![0.0; 72]);
            }
            Method::GlobalPose => {
                pose.parent_from_joint[0] = *root_orientation;
                forward_kinematics(&self.body.skeleton, &pose, &mut self.fk);
                let mut imu = [Vector3::zeros(); 6];
                imu_positions_in_world(&self.body, &self.fk, &mut imu);
                let root_t = root_orientation.transpose();
                let mut pl: Vec<f32> = (0..5)
                    .flat_map(|i| (root_t * (imu[i] - imu[ROOT_IMU])).cast::<f32>().data.0[0])
                    .collect();
                let g = root_t * Vector3::new(0.0, -1.0, 0.0);
                pl.extend(g.cast::<f32>().iter());
                inits[0] = Some(pl);
                // Training initializes vrnet from the chunk's first true frame; a subject standing
                // still has zero velocity and every contact joint stationary.
                inits[3] = Some(vec![0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
            }
        }
        self.states = self
            .nets
            .iter()
            .zip(&inits)
            .map(|(net, init)| {
                let t = init.as_deref().map(tensor).transpose()?;
                net.initial_state(1, t.as_ref())
            })
            .collect::<candle_core::Result<_>>()?;
        for (lean, state) in self.lean.iter_mut().zip(&self.states) {
            lean.set_state(state)?;
        }
        self.started = true;
        self.previous_joint_position = None;
        Ok(())
    }

    /// Brings the lean nets' weights into cache ahead of the next [`Streamer::step`] (see
    /// [`LeanRnn::warm`]); stops as soon as `stop()` says so (the frame came).
    pub fn warm(&self, stop: &mut dyn FnMut() -> bool) {
        if self.backend == Backend::Lean {
            self.warm_nets(stop);
        }
    }

    /// This streamer's lean nets, then its mirror twin's and its partner's (and theirs); false
    /// once `stop()` said so.
    fn warm_nets(&self, stop: &mut dyn FnMut() -> bool) -> bool {
        self.lean.iter().all(|net| net.warm(stop))
            && self
                .mirrored
                .iter()
                .chain(&self.partner)
                .all(|companion| companion.warm_nets(stop))
    }

    /// One frame. For a set other than the six, the joints its sensors do not observe
    /// ([`imuflow_body::SiteMask::observed_joints`]) are at rest, whatever the nets say, and the
    /// joint positions follow that pose.
    pub fn step(&mut self, imu: &ImuInput) -> anyhow::Result<Estimate> {
        let mut estimate = self.step_ensemble(imu)?;
        if let Some(at_rest) = self.at_rest {
            for j in (0..NUM_JOINTS).filter(|j| at_rest & (1 << j) != 0) {
                estimate.pose[j] = Rotation3::identity();
            }
            let positions = self.positions_in_root_frame(&estimate.pose);
            estimate.joint_position = world_positions(&positions, &estimate.pose[0]);
        }
        Ok(estimate)
    }

    /// One frame of the nets, their mirror twin and their partner.
    fn step_ensemble(&mut self, imu: &ImuInput) -> anyhow::Result<Estimate> {
        let mut estimate = self.step_own(imu)?;
        if self.mirrored.is_none() && self.partner.is_none() {
            return Ok(estimate);
        }
        if let Some(twin) = &mut self.mirrored {
            let seen = mirror::mirrored_estimate(&twin.step(&mirror::mirrored_input(imu))?);
            estimate = mirror::average(&estimate, &seen);
        }
        if let Some(partner) = &mut self.partner {
            estimate = mirror::average(&estimate, &partner.step(imu)?);
        }
        self.impose_limb_joints(&mut estimate.pose, &estimate.joint_position);
        if self.method == Method::GlobalPose {
            // GlobalPose's joint positions are its output pose's (forward kinematics).
            let positions = self.positions_in_root_frame(&estimate.pose);
            estimate.joint_position = world_positions(&positions, &estimate.pose[0]);
        }
        Ok(estimate)
    }

    /// The knees and elbows as [`LimbJoints`] allow, where the networks estimate them: a set
    /// that measures the upper bone of every limb it observes (a lower-body set: thighs and
    /// shanks; a full suit) has its knees and elbows measured, and a hinge imposed on them would
    /// only move its thighs off their sensors (the lower body after one epoch, 40 test clips:
    /// hips and knees 4.3° from the truth with the hinge, 2.6° without).
    fn impose_limb_joints(
        &self,
        pose: &mut [Rotation3<f64>; NUM_JOINTS],
        positions: &[Vector3<f64>; NUM_JOINTS],
    ) {
        if !self.limbs_measured {
            self.limb_joints.impose(pose, positions, &self.body);
        }
    }

    /// One frame of this stream's own nets.
    fn step_own(&mut self, imu: &ImuInput) -> anyhow::Result<Estimate> {
        if imu.order != self.order {
            anyhow::bail!(
                "the input holds the sensors ({}), the nets take ({})",
                imu.order.mask().names(),
                self.order.mask().names()
            );
        }
        let root = sensor_rotation(imu.root_orientation());
        if !self.started {
            self.initialize(&root)?;
        }
        match self.method {
            Method::Pip => self.step_pip(imu, &root),
            Method::GlobalPose => self.step_globalpose(imu, &root),
        }
    }

    fn run(&mut self, net: usize, input: &[f32]) -> anyhow::Result<Vec<f32>> {
        let t0 = std::time::Instant::now();
        let y = match self.backend {
            Backend::Lean => self.lean[net].step(input).to_vec(),
            Backend::Candle => {
                let y = self.nets[net].step(&tensor(input)?, &mut self.states[net])?;
                values(&y)?
            }
        };
        self.nets_time += t0.elapsed();
        Ok(y)
    }

    fn step_pip(&mut self, imu: &ImuInput, root: &Rotation3<f64>) -> anyhow::Result<Estimate> {
        let mut x = vec![0.0; pip_input_len(imu.order.len())];
        pip_input(imu, &mut x);
        let leaf = self.run(0, &x)?;
        let full = self.run(1, &[leaf.as_slice(), &x].concat())?;
        let full_x = [full.as_slice(), &x].concat();
        let r6d = self.run(2, &full_x)?;
        let vel = self.run(3, &full_x)?;
        let contact = self.run(4, &full_x)?;
        let joint_position = world_positions(&full, root);
        let mut pose = pose_from_reduced_r6d(&r6d, root);
        if let SensorBones::Measured { tolerance_rad } = self.sensor_bones {
            impose_measured_bones(&mut pose, imu, tolerance_rad);
        }
        self.impose_limb_joints(&mut pose, &joint_position);
        let mut joint_velocity = [Vector3::zeros(); NUM_JOINTS];
        for (j, v) in joint_velocity.iter_mut().enumerate() {
            // Reference §2.2: v_j = 3·R_root·out_j (m/s).
            *v = root * v3(&vel[3 * j..3 * j + 3]) * PIP_VELOCITY_SCALE as f64;
        }
        let foot_contact = [sigmoid(contact[0]), sigmoid(contact[1])];
        Ok(Estimate {
            pose,
            joint_position,
            root_velocity: joint_velocity[0],
            joint_velocity,
            foot_contact,
            stationary: [0.0, foot_contact[0], foot_contact[1], 0.0, 0.0],
            gravity_in_root: root.transpose() * Vector3::new(0.0, -G, 0.0),
        })
    }

    /// Forward kinematics of `pose` with the root at the origin and unturned, left in `self.fk`:
    /// the positions of [`FULL_JOINTS`] in the root's frame, flattened (GlobalPose's pRJ).
    fn positions_in_root_frame(&mut self, pose: &[Rotation3<f64>; NUM_JOINTS]) -> Vec<f32> {
        let mut local = Pose::t_pose(Vector3::zeros());
        local.parent_from_joint = *pose;
        local.parent_from_joint[0] = Rotation3::identity();
        forward_kinematics(&self.body.skeleton, &local, &mut self.fk);
        FULL_JOINTS
            .iter()
            .flat_map(|&j| self.fk.position(j).cast::<f32>().data.0[0])
            .collect()
    }

    fn step_globalpose(
        &mut self,
        imu: &ImuInput,
        root: &Rotation3<f64>,
    ) -> anyhow::Result<Estimate> {
        let mut x = [0.0; GLOBALPOSE_INPUT];
        globalpose_input(imu, &mut x);
        let g0 = unit(v3(&x[81..84]));
        let pl = self.run(0, &x)?;
        let g1 = unit(v3(&pl[15..18]));
        // Tilt-correct the relative orientations onto each refined gravity (reference §2.4).
        let rrb = |tilt: &Rotation3<f64>| -> Vec<f32> {
            (0..5)
                .flat_map(|i| {
                    row_major(
                        &(tilt
                            * sensor_rotation(
                                &x[36 + 9 * i..45 + 9 * i].try_into().unwrap_or([0.0; 9]),
                            )),
                    )
                })
                .collect()
        };
        let rrb1 = rrb(&from_to(&g0, &g1));
        let ik1_in = [
            rrb1.as_slice(),
            &[g1.x as f32, g1.y as f32, g1.z as f32],
            &pl[..15],
        ]
        .concat();
        let ik1 = self.run(1, &ik1_in)?;
        let g2 = unit(v3(&ik1[69..72]));
        let rrb2 = rrb(&(from_to(&g1, &g2) * from_to(&g0, &g1)));
        let g2f = [g2.x as f32, g2.y as f32, g2.z as f32];
        let r6d = self.run(2, &[rrb2.as_slice(), &g2f, &ik1[..69]].concat())?;
        // Paper Eq. 1-3: the corrected root orientation R_root' = R_root·FromTo(gR2 → gR0).
        let root_c = root * from_to(&g2, &g0);
        let mut pose = pose_from_reduced_r6d(&r6d, &root_c);
        if let SensorBones::Measured { tolerance_rad } = self.sensor_bones {
            // Before the FK that feeds vrnet: its joint inputs then agree with the sensors too.
            // The root keeps GlobalPose's gravity-corrected orientation (paper Eq. 1-3) for the
            // networks; the output pose takes the pelvis's sensor below.
            impose_measured_bones(&mut pose, imu, tolerance_rad);
        }
        // iknet.net1's joint positions, in the frame of the root its pose is assembled on.
        self.impose_limb_joints(&mut pose, &world_positions(&ik1, &root_c));
        // pRJ recomputed by FK of the pose with the root at identity (reference §2.4).
        let prj = self.positions_in_root_frame(&pose);
        let rrj: Vec<f32> = REDUCED_JOINTS
            .iter()
            .flat_map(|&j| row_major(self.fk.world_from(j)))
            .collect();
        let root_ct = root_c.transpose();
        let arb: Vec<f32> = (0..6)
            .flat_map(|i| (root_ct * v3(&imu.acceleration[i])).cast::<f32>().data.0[0])
            .collect();
        let wrb: Vec<f32> = (0..6)
            .flat_map(|i| {
                (root_ct * v3(&imu.angular_velocity[i]))
                    .cast::<f32>()
                    .data
                    .0[0]
            })
            .collect();
        let vr = self.run(3, &[rrj.as_slice(), &prj, &arb, &wrb, &g2f].concat())?;
        // v = R_root'·v_H with its vertical component replaced by v_V (reference §2.4).
        let mut root_velocity = root_c * v3(&vr[1..4]);
        root_velocity.y = vr[0] as f64;
        let mut stationary = [0.0; 5];
        for (s, v) in stationary.iter_mut().zip(&vr[4..9]) {
            *s = sigmoid(*v);
        }
        // The pelvis carries a sensor too. With the instrumented bones on their sensors it takes
        // its calibrated orientation (within the tolerance) instead of the gravity-corrected
        // root_c; every other bone keeps its orientation in M, and the network inputs above stay
        // GlobalPose's. Positions follow the output pose (the hips turn with the pelvis).
        let pelvis_on_sensor = match self.sensor_bones {
            SensorBones::Measured { tolerance_rad } => toward_within(&root_c, root, tolerance_rad),
            SensorBones::Network => None,
        };
        let (root_out, joint_position) = match pelvis_on_sensor {
            Some(pelvis) => {
                reroot(&mut pose, &pelvis);
                let positions = self.positions_in_root_frame(&pose);
                (pelvis, world_positions(&positions, &pelvis))
            }
            None => (root_c, world_positions(&prj, &root_c)),
        };
        // GlobalPose predicts the root velocity only. The other joints' velocities (which the frame
        // promises, and PIP's physics tracks) follow from it and the change of the root-relative
        // positions: v_j = v_root + d(p_j − p_root)/dt (backward difference; root velocity only on
        // the first frame).
        let mut joint_velocity = [root_velocity; NUM_JOINTS];
        if let Some(previous) = &self.previous_joint_position {
            for j in 1..NUM_JOINTS {
                joint_velocity[j] += (joint_position[j] - previous[j]) * f64::from(FPS);
            }
        }
        self.previous_joint_position = Some(joint_position);
        let _ = CONTACT_JOINTS;
        Ok(Estimate {
            pose,
            joint_position,
            joint_velocity,
            foot_contact: [stationary[1], stationary[2]],
            stationary,
            root_velocity,
            gravity_in_root: root_out.transpose() * Vector3::new(0.0, -G, 0.0),
        })
    }
}

/// `from` turned toward `to` until it is within `tolerance_rad` of it (about the axis of their
/// difference); `None` when it already is.
fn toward_within(
    from: &Rotation3<f64>,
    to: &Rotation3<f64>,
    tolerance_rad: f64,
) -> Option<Rotation3<f64>> {
    // Through the quaternion: `Rotation3::angle` takes the acos of the trace, NaN when a sensor's
    // f32 matrix, not quite orthonormal, is within ~1e-8 of `from` (trace just above 3).
    let difference = UnitQuaternion::from_rotation_matrix(&(to * from.transpose()));
    let (axis, angle) = difference.axis_angle()?;
    (angle > tolerance_rad).then(|| Rotation3::from_axis_angle(&axis, angle - tolerance_rad) * from)
}

/// Gives the pose the root orientation `root`, keeping every other bone's orientation in M: the
/// root's children take the change.
fn reroot(pose: &mut [Rotation3<f64>; NUM_JOINTS], root: &Rotation3<f64>) {
    let turn = root.transpose() * pose[0];
    for child in JointId::all().filter(|j| j.parent() == Some(JointId::ROOT)) {
        pose[child.index()] = turn * pose[child.index()];
    }
    pose[0] = *root;
}

/// Turns each bone that carries a non-root sensor onto the cone of half-angle `tolerance_rad`
/// around the sensor's calibrated orientation `R_MB` (in M) when it lies outside it (the smallest
/// rotation that does: about the axis of the difference); a bone inside the cone is left alone.
/// Only the bones' local rotations change, against their parents' global orientation; their
/// children (wrists, hands, ankles, feet: identity in the networks' pose) follow them. A set that
/// senses a bone and one below it (a thigh and its shank) has them turned parent first, each
/// against its parent as already turned, so that both end on their sensors.
pub fn impose_measured_bones(
    pose: &mut [Rotation3<f64>; NUM_JOINTS],
    imu: &ImuInput,
    tolerance_rad: f64,
) {
    let mut sensor_of = [None; NUM_JOINTS];
    for (sensor, site) in imu.order.sites().enumerate() {
        sensor_of[site.joint().index()] = Some(sensor);
    }
    // One pass in joint order (parents before children), each global orientation from its
    // parent's as already turned.
    let mut global = *pose;
    for j in JointId::all() {
        let Some(parent) = j.parent() else {
            continue; // the root: each method sets its own
        };
        let (j, parent) = (j.index(), parent.index());
        global[j] = global[parent] * pose[j];
        let Some(sensor) = sensor_of[j] else {
            continue;
        };
        let measured = sensor_rotation(&imu.orientation[sensor]);
        if let Some(turned) = toward_within(&global[j], &measured, tolerance_rad) {
            pose[j] = global[parent].transpose() * turned;
            global[j] = turned;
        }
    }
}

/// Global (M) rotations of a local pose whose entry 0 is the root's orientation in M.
pub fn global_rotations(local: &[Rotation3<f64>; NUM_JOINTS]) -> [Rotation3<f64>; NUM_JOINTS] {
    let mut global = *local;
    for j in JointId::all() {
        if let Some(parent) = j.parent() {
            global[j.index()] = global[parent.index()] * local[j.index()];
        }
    }
    global
}

/// Local pose from the 15 reduced joints' rotations in the root frame (6D each): ignored joints get
/// identity, the root gets `root` (reference §2.1 "Pose assembly").
pub fn pose_from_reduced_r6d(r6d: &[f32], root: &Rotation3<f64>) -> [Rotation3<f64>; NUM_JOINTS] {
    let mut global = [Rotation3::identity(); NUM_JOINTS];
    for (k, j) in REDUCED_JOINTS.iter().enumerate() {
        let v: [f64; 6] = std::array::from_fn(|i| r6d[6 * k + i] as f64);
        let r = rotation_from_r6d(&v);
        // A degenerate output decodes to zero columns; keep the joint at identity instead.
        global[j.index()] = if r.matrix().determinant() > 0.5 {
            r
        } else {
            Rotation3::identity()
        };
    }
    let mut local = [Rotation3::identity(); NUM_JOINTS];
    for j in REDUCED_JOINTS {
        let parent = j.parent().map_or(0, |p| p.index());
        local[j.index()] = global[parent].transpose() * global[j.index()];
    }
    local[0] = *root;
    local
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use imuflow_body::Imu;
    use imuflow_body::skeleton::{IMU_JOINTS, LEAF_JOINTS};

    /// python/examples/pip_numpy.py starts PIP's rnn1 from these positions written out (numpy
    /// has no body model): they must be this body's T-pose leaf joints, relative to the root.
    #[test]
    fn the_numpy_example_starts_from_this_bodys_tpose() {
        let source = include_str!("../../../python/examples/pip_numpy.py");
        let block = source
            .split("TPOSE_LEAF_POSITIONS_M = [")
            .nth(1)
            .and_then(|rest| rest.split("]\n\n").next())
            .expect("the constant");
        let written: Vec<f64> = block
            .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
            .filter(|t| !t.is_empty())
            .map(|t| t.parse().expect("a number"))
            .collect();
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &Pose::t_pose(Vector3::zeros()), &mut fk);
        let expected: Vec<f64> = LEAF_JOINTS
            .iter()
            .flat_map(|&j| (fk.position(j) - fk.position(JointId::ROOT)).data.0[0])
            .collect();
        assert_eq!(written.len(), expected.len());
        let off = written
            .iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(off < 1e-5, "written {written:?}\nexpected {expected:.5?}");
    }

    /// A weight file of models/ (path relative to the repository root).
    pub(crate) fn committed_weights(method: Method, path: &str) -> Weights {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(path);
        Weights::load(&path, method).unwrap()
    }

    /// Every field of an estimate as one list of numbers, to compare two estimates.
    pub(crate) fn flat(e: &Estimate) -> Vec<f64> {
        let (mut v, velocities) = flat_apart_from_joint_velocities(e);
        v.extend(velocities);
        v
    }

    /// [`flat`] in two lists: every field but the joint velocities, and the joint velocities
    /// (which some comparisons hold to their own tolerance).
    pub(crate) fn flat_apart_from_joint_velocities(e: &Estimate) -> (Vec<f64>, Vec<f64>) {
        let mut v: Vec<f64> = e
            .pose
            .iter()
            .flat_map(|r| r.matrix().iter().copied())
            .collect();
        v.extend(e.joint_position.iter().flat_map(|p| p.iter().copied()));
        v.extend(e.foot_contact.iter().chain(&e.stationary).copied());
        v.extend(e.root_velocity.iter().chain(e.gravity_in_root.iter()));
        let velocities = e
            .joint_velocity
            .iter()
            .flat_map(|p| p.iter().copied())
            .collect();
        (v, velocities)
    }

    /// The largest entry-wise difference of two [`flat`] estimates.
    pub(crate) fn largest_gap(a: &[f64], b: &[f64]) -> f64 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    /// Asserts what every ensemble keeps of the stage's defaults: each instrumented bone on its
    /// sensor in `input`, each knee a hinge (`what` names the case in a failure).
    pub(crate) fn assert_on_sensors_with_hinged_knees(e: &Estimate, input: &ImuInput, what: &str) {
        let global = global_rotations(&e.pose);
        for sensor in Imu::SIX {
            let m = input.orientation[sensor.index()].map(f64::from);
            let d = (global[sensor.joint().index()].matrix() - Matrix3::from_row_slice(&m)).norm();
            assert!(d < 1e-5, "{what}: {} off its sensor by {d}", sensor.name());
        }
        for knee in [JointId::LEFT_KNEE, JointId::RIGHT_KNEE] {
            let v = e.pose[knee.index()].scaled_axis();
            assert!(
                v.y.abs() < 1e-9 && v.z.abs() < 1e-9,
                "{what}: {knee}: {v:?}"
            );
        }
    }

    /// The whole streaming inference with the committed weights: the lean nets give the candle
    /// nets' estimates, every field of every frame within 1e-5. GlobalPose's joint velocities are
    /// the exception: they are FPS × the frame-to-frame change of the (compared) positions, so a
    /// position difference δ shows there as up to 2·60·δ; they get FPS × 1e-5 (measured: PIP
    /// 2.6e-7 on every field; GlobalPose 1.1e-6, 1.4e-5 on those velocities). The
    /// frames must also differ from each other (a comparison of constants would prove nothing).
    fn lean_streaming_matches_candle(method: Method, path: &str) {
        let load = || committed_weights(method, path);
        let mut candle = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        candle.set_backend(Backend::Candle);
        let mut lean = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        assert_eq!(lean.backend(), Backend::Lean);
        let velocity_tolerance = match method {
            Method::Pip => 1e-5,
            Method::GlobalPose => 1e-5 * f64::from(FPS),
        };
        let (mut worst, mut worst_velocity, mut moved) = (0.0f64, 0.0f64, 0.0f64);
        let mut first = None;
        for f in 0..240 {
            let input = crate::bench::swaying_sensors(f);
            let (want, want_velocity) =
                flat_apart_from_joint_velocities(&candle.step(&input).unwrap());
            let (got, got_velocity) = flat_apart_from_joint_velocities(&lean.step(&input).unwrap());
            worst = worst.max(largest_gap(&got, &want));
            worst_velocity = worst_velocity.max(largest_gap(&got_velocity, &want_velocity));
            moved = moved.max(largest_gap(
                &want,
                first.get_or_insert_with(|| want.clone()),
            ));
        }
        assert!(
            worst <= 1e-5,
            "{method:?}: lean differs from candle by {worst}"
        );
        assert!(
            worst_velocity <= velocity_tolerance,
            "{method:?}: joint velocities differ by {worst_velocity}"
        );
        assert!(
            moved > 0.05,
            "{method:?}: the estimates hardly change ({moved})"
        );
    }

    #[test]
    fn lean_streaming_matches_candle_pip() {
        lean_streaming_matches_candle(Method::Pip, "models/pip.safetensors");
    }

    #[test]
    fn lean_streaming_matches_candle_globalpose() {
        lean_streaming_matches_candle(Method::GlobalPose, "models/globalpose.safetensors");
    }

    /// The streamer's knees and elbows, with and without `limb_joints`, on the committed weights:
    /// anatomical joints on every frame, the lower legs' and forearms' global orientations the
    /// same either way, the networks' own (free) joints visibly not anatomical, or the step
    /// would have nothing to do, and the flexion toward the joint positions visibly not the
    /// rotations' flexion, or that step would have nothing to do.
    fn anatomical_joints_are_imposed(method: Method, path: &str) {
        let load = || committed_weights(method, path);
        let mut anatomical = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        let mut rotations = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        rotations.set_limb_joints(LimbJoints::AnatomicalRotations);
        let mut free = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        free.set_limb_joints(LimbJoints::Free);
        let knees = [JointId::LEFT_KNEE, JointId::RIGHT_KNEE];
        let elbows = [JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW];
        let mut free_off_axis_deg: f64 = 0.0;
        let mut flexion_moved_deg: f64 = 0.0;
        for f in 0..240 {
            let input = crate::bench::swaying_sensors(f);
            let a = anatomical.step(&input).unwrap();
            let b = free.step(&input).unwrap();
            let r = rotations.step(&input).unwrap();
            for j in knees.into_iter().chain(elbows) {
                let moved = (a.pose[j.index()].transpose() * r.pose[j.index()]).angle();
                flexion_moved_deg = flexion_moved_deg.max(moved.to_degrees());
            }
            for knee in knees {
                let v = a.pose[knee.index()].scaled_axis();
                assert!(v.y.abs() < 1e-9 && v.z.abs() < 1e-9, "{knee}: {v:?}");
                let w = b.pose[knee.index()].scaled_axis();
                free_off_axis_deg = free_off_axis_deg.max(w.y.hypot(w.z).to_degrees());
            }
            for elbow in elbows {
                // Ry(a)·Rz(b)·Rx(c) has m[(1, 0)] = sin b.
                assert!(a.pose[elbow.index()].matrix()[(1, 0)].abs() < 1e-9);
            }
            // The lower bones hold their sensors' orientations, which arrive as f32 matrices
            // (orthonormal to about 1e-7): re-expressing them through a new flexion keeps them to
            // that precision, not to f64's.
            let (ga, gb) = (global_rotations(&a.pose), global_rotations(&b.pose));
            for j in knees.into_iter().chain(elbows) {
                let d = (ga[j.index()].matrix() - gb[j.index()].matrix()).norm();
                assert!(d < 1e-6, "{method:?} frame {f}: {j} moved by {d}");
            }
        }
        assert!(
            flexion_moved_deg > 1.0,
            "{method:?}: the joint positions flex as the rotations do ({flexion_moved_deg:.2}°)"
        );
        assert!(
            free_off_axis_deg > 1.0,
            "{method:?}: the networks' knees are hinges already ({free_off_axis_deg:.2}°)"
        );
    }

    #[test]
    fn every_limb_joints_name_parses_to_the_choice_that_gives_it_back() {
        for (k, name) in LIMB_JOINTS.iter().enumerate() {
            let choice = LimbJoints::parse(name).unwrap();
            assert_eq!(choice.name(), *name);
            assert_eq!(LimbJoints::ALL[k], choice);
        }
        assert_eq!(LimbJoints::parse("anatomical"), Some(LimbJoints::default()));
        assert_eq!(LimbJoints::parse("hinged"), None);
    }

    #[test]
    fn anatomical_joints_are_imposed_pip() {
        anatomical_joints_are_imposed(Method::Pip, "models/pip.safetensors");
    }

    #[test]
    fn anatomical_joints_are_imposed_globalpose() {
        anatomical_joints_are_imposed(Method::GlobalPose, "models/globalpose.safetensors");
    }

    fn some_rotation(k: usize) -> Rotation3<f64> {
        let axis = Unit::new_normalize(Vector3::new(1.0 + k as f64, -0.5, 0.3 * k as f64 - 1.0));
        Rotation3::from_axis_angle(&axis, 0.2 + 0.37 * k as f64)
    }

    /// Every joint turned by its own [`some_rotation`].
    fn some_pose() -> Pose {
        let mut pose = Pose::t_pose(Vector3::zeros());
        for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
            *r = some_rotation(j);
        }
        pose
    }

    #[test]
    fn measured_bones_take_their_sensor_orientation_and_nothing_else_moves() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut pose = some_pose();
        let mut imu = ImuInput::default();
        for sensor in 0..6 {
            imu.orientation[sensor] = row_major(&some_rotation(40 + sensor));
        }
        let mut before = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut before);
        impose_measured_bones(&mut pose.parent_from_joint, &imu, 0.0);
        let mut after = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut after);

        let carried_by_a_sensor = |j: JointId| {
            let mut at = Some(j);
            while let Some(joint) = at {
                if IMU_JOINTS[..5].contains(&joint) {
                    return true;
                }
                at = joint.parent();
            }
            false
        };
        for j in JointId::all() {
            let moved = (after.world_from(j).matrix() - before.world_from(j).matrix()).norm();
            if let Some(sensor) = IMU_JOINTS[..5].iter().position(|&s| s == j) {
                let want = some_rotation(40 + sensor);
                let off = (after.world_from(j).matrix() - want.matrix()).norm();
                assert!(off < 1e-6, "{}: {off} from its sensor", j.name());
            } else if !carried_by_a_sensor(j) {
                assert!(moved < 1e-12, "{} moved by {moved}", j.name());
            }
        }
        // The root keeps the method's orientation (not the pelvis sensor's).
        assert_eq!(pose.parent_from_joint[0], some_rotation(0));
        // Children of a sensor bone keep their local rotation and follow it.
        let wrist = JointId::LEFT_WRIST;
        let want = some_rotation(40) * some_rotation(wrist.index());
        assert!((after.world_from(wrist).matrix() - want.matrix()).norm() < 1e-6);
    }

    /// A lower-body set senses the thighs and the shanks below them: every sensed bone ends on
    /// its sensor, the shanks too after their thighs turned.
    #[test]
    fn measured_bones_of_a_chain_all_end_on_their_sensors() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let legs = imuflow_body::SiteMask::of([
            Imu::Pelvis,
            Imu::LeftLowerLeg,
            Imu::RightLowerLeg,
            Imu::LeftUpperLeg,
            Imu::RightUpperLeg,
        ]);
        let order = InputOrder::of(legs).unwrap();
        let mut pose = some_pose();
        let mut imu = ImuInput::of(order);
        for sensor in 0..order.len() {
            imu.orientation[sensor] = row_major(&some_rotation(40 + sensor));
        }
        impose_measured_bones(&mut pose.parent_from_joint, &imu, 0.0);
        let mut after = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut after);
        for (sensor, site) in order.sites().enumerate().take(order.root()) {
            let off = (after.world_from(site.joint()).matrix()
                - some_rotation(40 + sensor).matrix())
            .norm();
            assert!(off < 1e-6, "{}: {off} from its sensor", site.name());
        }
    }

    #[test]
    fn a_measurement_a_hair_from_the_estimate_is_taken_without_nan() {
        // A sensor's f32 matrix: 1e-9 rad from the estimate and scaled by 1 + 1e-9, so its trace
        // is just above 3 (the acos of the trace would be NaN) while its skew part is not zero.
        let from = some_rotation(3);
        let near = Rotation3::from_axis_angle(&Vector3::z_axis(), 1e-9) * from;
        let to = Rotation3::from_matrix_unchecked(near.matrix() * (1.0 + 1e-9));
        for tolerance in [0.0, 0.1] {
            let got = toward_within(&from, &to, tolerance).unwrap_or(from);
            assert!(got.matrix().iter().all(|v| v.is_finite()), "{got:?}");
            assert!((got.matrix() - from.matrix()).norm() < 1e-8);
        }
    }

    #[test]
    fn rerooting_turns_the_pelvis_alone() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut pose = some_pose();
        let before = global_rotations(&pose.parent_from_joint);
        reroot(&mut pose.parent_from_joint, &some_rotation(50));
        let after = global_rotations(&pose.parent_from_joint);
        assert_eq!(after[0], some_rotation(50));
        for j in JointId::all().skip(1) {
            let d = (after[j.index()].matrix() - before[j.index()].matrix()).norm();
            assert!(d < 1e-12, "{} turned by {d}", j.name());
        }
        // Against forward kinematics, a second algorithm: the hips hang off the turned pelvis.
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        let hip = body.skeleton.offset_in_parent_m(JointId::LEFT_HIP);
        let want = some_rotation(50) * hip;
        let got = fk.position(JointId::LEFT_HIP) - fk.position(JointId::ROOT);
        assert!((got - want).norm() < 1e-12, "{got:?} against {want:?}");
    }

    /// GlobalPose on the committed weights: with the instrumented bones on their sensors the
    /// output's pelvis is the pelvis sensor's orientation, the joint positions and gravity belong
    /// to that pose, and the papers' setting leaves the gravity-corrected root, measurably apart
    /// (or the step would do nothing).
    #[test]
    fn globalpose_pelvis_takes_its_sensor_with_the_instrumented_bones() {
        let load = || committed_weights(Method::GlobalPose, "models/globalpose.safetensors");
        let mut measured = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        let mut papers = Streamer::new(load(), Pose::t_pose(Vector3::zeros())).unwrap();
        papers.set_sensor_bones(SensorBones::Network);
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut fk = FkData::new();
        let mut apart_deg: f64 = 0.0;
        for f in 0..120 {
            let input = crate::bench::swaying_sensors(f);
            let pelvis = sensor_rotation(&input.orientation[5]);
            let e = measured.step(&input).unwrap();
            // The sensor's f32 matrix is orthonormal to about 1e-7 (measured up to 1.1e-6 here).
            let off = (e.pose[0].matrix() - pelvis.matrix()).norm();
            assert!(off < 1e-5, "frame {f}: {off}");
            let down = e.pose[0].transpose() * Vector3::new(0.0, -G, 0.0);
            assert!((e.gravity_in_root - down).norm() < 1e-9);
            let mut pose = Pose::t_pose(Vector3::zeros());
            pose.parent_from_joint = e.pose;
            forward_kinematics(&body.skeleton, &pose, &mut fk);
            for j in FULL_JOINTS {
                let want = fk.position(j) - fk.position(JointId::ROOT);
                let got = e.joint_position[j.index()] - e.joint_position[0];
                assert!(
                    (got - want).norm() < 1e-5,
                    "frame {f}: {j} at {got:?}, FK {want:?}"
                );
            }
            let p = papers.step(&input).unwrap();
            apart_deg = apart_deg.max(p.pose[0].angle_to(&pelvis).to_degrees());
        }
        assert!(
            apart_deg > 0.5,
            "the corrected root is the sensor's ({apart_deg:.3}°)"
        );
    }

    #[test]
    fn within_a_tolerance_a_bone_moves_onto_the_cone_around_its_sensor_or_not_at_all() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut pose = some_pose();
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        // Sensor 0 (left forearm) 20° from its bone about some axis; sensor 1 (right forearm) 3°.
        let axis = Unit::new_normalize(Vector3::new(0.3, -1.0, 0.5));
        let off = |deg: f64| Rotation3::from_axis_angle(&axis, deg.to_radians());
        let bone = |j: JointId| *fk.world_from(j);
        let mut imu = ImuInput::default();
        let measured_left = off(20.0) * bone(JointId::LEFT_ELBOW);
        imu.orientation[0] = row_major(&measured_left);
        imu.orientation[1] = row_major(&(off(3.0) * bone(JointId::RIGHT_ELBOW)));
        for (orientation, joint) in imu.orientation.iter_mut().zip(IMU_JOINTS).skip(2) {
            *orientation = row_major(fk.world_from(joint));
        }
        let right_before = pose.parent_from_joint[JointId::RIGHT_ELBOW.index()];
        impose_measured_bones(&mut pose.parent_from_joint, &imu, 5f64.to_radians());
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        // Left: on the cone's edge, 5° from the measurement, 15° turned toward it (same axis).
        let left = *fk.world_from(JointId::LEFT_ELBOW);
        let to_measurement = left.angle_to(&measured_left).to_degrees();
        assert!((to_measurement - 5.0).abs() < 1e-4, "{to_measurement}");
        let expected = off(15.0) * bone_before_left(&body);
        assert!((left.matrix() - expected.matrix()).norm() < 1e-5);
        // Right: inside the cone, untouched.
        assert_eq!(
            pose.parent_from_joint[JointId::RIGHT_ELBOW.index()],
            right_before
        );
    }

    /// The left forearm's world orientation in the test pose before any change.
    fn bone_before_left(body: &BodyModel) -> Rotation3<f64> {
        let pose = some_pose();
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        *fk.world_from(JointId::LEFT_ELBOW)
    }

    #[test]
    fn global_rotations_match_forward_kinematics() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let pose = some_pose();
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        let global = global_rotations(&pose.parent_from_joint);
        for j in JointId::all() {
            let d = (global[j.index()].matrix() - fk.world_from(j).matrix()).norm();
            assert!(d < 1e-12, "{}: {d}", j.name());
        }
    }

    /// The committed weights with every net's output bias shifted: a second, different set of
    /// weights of the same method.
    fn shifted_weights(method: Method, path: &str) -> Weights {
        let mut weights = committed_weights(method, path);
        for net in &mut weights.nets {
            net.linear2.bias = net.linear2.bias.affine(1.0, 0.02).unwrap();
        }
        weights
    }

    /// A weight ensemble averages two weight sets symmetrically: A with partner B gives what B
    /// with partner A gives (the average does not depend on the order), which is neither alone;
    /// the instrumented bones stay on their sensors and the knees stay hinges; a partner with
    /// the same weights changes nothing; a partner of another method is refused.
    fn a_weight_ensemble_is_symmetric(method: Method, path: &str) {
        let streamer = |weights: Weights, partner: Option<Weights>| {
            let mut s = Streamer::new(weights, Pose::t_pose(Vector3::zeros())).unwrap();
            s.set_partner(partner).unwrap();
            s
        };
        let (a, b) = (
            || committed_weights(method, path),
            || shifted_weights(method, path),
        );
        let mut ab = streamer(a(), Some(b()));
        let mut ba = streamer(b(), Some(a()));
        let (mut alone_a, mut alone_b) = (streamer(a(), None), streamer(b(), None));
        let mut twice_a = streamer(a(), Some(a()));
        let (mut asymmetry, mut from_a, mut from_b, mut same_twice) =
            (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for f in 0..240 {
            let input = crate::bench::swaying_sensors(f);
            let e = ab.step(&input).unwrap();
            asymmetry = asymmetry.max(largest_gap(&flat(&e), &flat(&ba.step(&input).unwrap())));
            let own = alone_a.step(&input).unwrap();
            from_a = from_a.max(largest_gap(&flat(&e), &flat(&own)));
            from_b = from_b.max(largest_gap(
                &flat(&e),
                &flat(&alone_b.step(&input).unwrap()),
            ));
            same_twice = same_twice.max(largest_gap(
                &flat(&own),
                &flat(&twice_a.step(&input).unwrap()),
            ));
            assert_on_sensors_with_hinged_knees(&e, &input, &format!("{method:?} frame {f}"));
        }
        assert!(
            asymmetry < 1e-9,
            "{method:?}: A+B and B+A differ by {asymmetry}"
        );
        assert!(
            from_a > 1e-3 && from_b > 1e-3,
            "{method:?}: {from_a}, {from_b}"
        );
        assert!(
            same_twice < 1e-6,
            "{method:?}: A+A differs from A by {same_twice}"
        );
        let other = match method {
            Method::Pip => committed_weights(Method::GlobalPose, "models/globalpose.safetensors"),
            Method::GlobalPose => committed_weights(Method::Pip, "models/pip.safetensors"),
        };
        let mut refused = streamer(a(), None);
        let message = refused.set_partner(Some(other)).unwrap_err().to_string();
        assert!(message.contains("second weights are"), "{message}");
    }

    #[test]
    fn a_weight_ensemble_is_symmetric_pip() {
        a_weight_ensemble_is_symmetric(Method::Pip, "models/pip.safetensors");
    }

    #[test]
    fn a_weight_ensemble_is_symmetric_globalpose() {
        a_weight_ensemble_is_symmetric(Method::GlobalPose, "models/globalpose.safetensors");
    }
}
