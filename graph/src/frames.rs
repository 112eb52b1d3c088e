//! The wire contract: every frame that travels between stages.
//!
//! Every frame is `#[repr(C)]`, fixed size, free of pointers and padding (checked at compile time by
//! `bytemuck::Pod`), and starts with the same [`FrameHeader`]. Frames are shared between processes
//! without copying through iceoryx2; each type carries a versioned type name
//! (`imuflow.ImuFrame.v1`, ...) so a process built with a different layout fails when it connects
//! instead of reading garbage. Change a layout only together with its version.
//!
//! The wire contract and its conventions are described in docs/architecture.md ("The wire contract",
//! "Conventions"): model frame M as in SMPL (x = left, y = up, z = forward, gravity (0, -9.81, 0));
//! SI units; quaternions are `[w, x, y, z]`; one IMU slot per site of the body model's site
//! catalogue ([`MAX_SITES`]; the first six [left forearm, right forearm, left lower leg, right lower
//! leg, head, pelvis], the six-site set), a graph's sensor set filling some; 24 joints in SMPL
//! order. Each field's doc says its frame of reference and unit.
//!
//! Recordings made before a layout changed still read: a frame type names its earlier versions
//! ([`Frame::EARLIER_TYPE_NAMES`]) and widens their bytes ([`frame_from_recorded`]).

use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::ZeroCopySend;

/// IMU slots in every IMU frame: one per site of the body model's site catalogue (enough for a
/// full suit; `imuflow_body::MAX_SITES`). A graph's sensor set fills the slots of its sites; the
/// frame's `valid_mask` says which slots hold a sample.
pub const MAX_SITES: usize = 17;
/// Number of joints of the body model (SMPL topology).
pub const NUM_JOINTS: usize = 24;
/// Generalized velocities of the floating-base body: root translation + 3 rotational DoF per joint.
pub const NUM_DOFS: usize = 3 + 3 * NUM_JOINTS;
/// Most contact points a [`ContactFrame`] carries (PIP uses 4 per contact joint: 8 joints' worth).
pub const MAX_CONTACT_POINTS: usize = 32;
/// Joints GlobalPose treats as possibly stationary: pelvis, left foot, right foot, left hand, right hand.
pub const NUM_STATIONARY_JOINTS: usize = 5;

/// Header flags (bit set in [`FrameHeader::flags`]).
pub mod flags {
    /// The last frame of the stream; its payload is meaningless. Every stage forwards it and exits.
    pub const END_OF_STREAM: u32 = 1 << 0;
    /// Carry on, but don't trust the payload (a sensor dropped out, an unusable input, ...).
    pub const INVALID: u32 = 1 << 1;
    /// The calibration stage is still calibrating; the payload is not yet calibrated.
    pub const CALIBRATING: u32 = 1 << 2;
    /// The value a feedback input delivers before its producer has published anything.
    pub const FEEDBACK_INITIAL: u32 = 1 << 3;
    /// Produced by a stage that was restarted during the run.
    pub const RESTARTED: u32 = 1 << 4;
    /// Part of a constructed calibration prelude that a synthesizing source put in front of the
    /// clip (T-pose hold, stand, step): the subject's motion, but not the clip's, so scores of the
    /// clip leave it out. Only sources set it (and the fusion stage, which resamples a source's
    /// raw frames, on the frames it makes of them); other stages do not carry it to their outputs.
    pub const PRELUDE: u32 = 1 << 5;
    /// A usable estimate of lower quality: a stage that could not do its full computation for
    /// this frame published its best simpler one instead (the optimizer: the networks' pose with
    /// the root integrated, where its physics could not be solved; the fusion stage, live: a
    /// sensor whose newest sample was overdue, held). Unlike INVALID, the payload is the stage's
    /// output for this frame, and scores keep it.
    pub const DEGRADED: u32 = 1 << 6;

    /// Every flag with its name, for logs and recorders.
    pub const NAMES: [(u32, &str); 7] = [
        (END_OF_STREAM, "END_OF_STREAM"),
        (INVALID, "INVALID"),
        (CALIBRATING, "CALIBRATING"),
        (FEEDBACK_INITIAL, "FEEDBACK_INITIAL"),
        (RESTARTED, "RESTARTED"),
        (PRELUDE, "PRELUDE"),
        (DEGRADED, "DEGRADED"),
    ];
}

/// The header every frame starts with.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable, ZeroCopySend)]
#[type_name("imuflow.FrameHeader.v1")]
pub struct FrameHeader {
    /// Frame index assigned by the source, starting at 0. Every stage copies it from its inputs, so
    /// the outputs that belong to one sensor sample share one `seq` across the whole graph.
    pub seq: u64,
    /// When the source captured the sample, in nanoseconds. Live sources use the Unix epoch; offline
    /// sources use the time since the start of the recording. Travels unchanged to the last sink.
    pub capture_ns: u64,
    /// When this frame was published, in nanoseconds since the Unix epoch (CLOCK_REALTIME).
    pub publish_ns: u64,
    /// Bit set of [`flags`].
    pub flags: u32,
    /// How many times the launcher had restarted the stage that published this frame (0: the
    /// stage's first process). `RESTARTED` marks one frame, the new process's first; a live reader
    /// that lost that frame (a lagging sink keeps only the newest) still sees the count change.
    /// Sources are never restarted. Recordings made before this field was named have 0 here.
    pub restarts: u32,
}

impl FrameHeader {
    /// Whether every bit of `flag` is set.
    pub fn has(&self, flag: u32) -> bool {
        self.flags & flag == flag
    }

    /// Whether this is the END_OF_STREAM marker.
    pub fn is_end(&self) -> bool {
        self.has(flags::END_OF_STREAM)
    }

    /// Names of the set flags, e.g. `["INVALID", "CALIBRATING"]`.
    pub fn flag_names(&self) -> Vec<&'static str> {
        flags::NAMES
            .iter()
            .filter(|(bit, _)| self.flags & bit != 0)
            .map(|(_, name)| *name)
            .collect()
    }
}

/// The frame types of the wire contract. Graph validation matches edges by this.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub enum FrameType {
    RawImu,
    Imu,
    BodyImu,
    Kinematics,
    Contact,
    Motion,
    Validation,
}

impl FrameType {
    /// Every frame type, in declaration order.
    pub const ALL: [FrameType; 7] = [
        FrameType::RawImu,
        FrameType::Imu,
        FrameType::BodyImu,
        FrameType::Kinematics,
        FrameType::Contact,
        FrameType::Motion,
        FrameType::Validation,
    ];

    /// The struct name, as written in graph files (`outputs = { pose = "MotionFrame" }`).
    pub fn name(self) -> &'static str {
        self.layout().struct_name
    }

    /// Parses a struct name as written in graph files.
    pub fn from_name(name: &str) -> Option<FrameType> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The byte layout of this frame type.
    pub fn layout(self) -> &'static FrameLayout {
        match self {
            FrameType::RawImu => RawImuFrame::layout(),
            FrameType::Imu => ImuFrame::layout(),
            FrameType::BodyImu => BodyImuFrame::layout(),
            FrameType::Kinematics => KinematicsFrame::layout(),
            FrameType::Contact => ContactFrame::layout(),
            FrameType::Motion => MotionFrame::layout(),
            FrameType::Validation => ValidationFrame::layout(),
        }
    }
}

impl std::fmt::Display for FrameType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Element type of a frame field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ScalarType {
    F32,
    U32,
    U64,
}

impl ScalarType {
    /// Size in bytes.
    pub fn size(self) -> usize {
        match self {
            ScalarType::F32 | ScalarType::U32 => 4,
            ScalarType::U64 => 8,
        }
    }
}

/// One field of a frame: where it lies in the bytes and what it means. This is what the recorder
/// writes as the mcap schema so a recording can be decoded without this code.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FieldLayout {
    pub name: &'static str,
    /// Byte offset from the start of the frame.
    pub offset: usize,
    #[serde(rename = "type")]
    pub scalar: ScalarType,
    /// Array shape, outermost first; empty for a scalar. Row-major (C order).
    pub shape: Vec<usize>,
    /// Unit, frame of reference and meaning.
    pub doc: &'static str,
}

impl FieldLayout {
    /// Number of scalars in the field.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    /// Whether the field holds no scalars (never true for the frames here).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The byte layout of a frame type: little-endian, `#[repr(C)]`, no padding.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameLayout {
    /// Rust struct name, e.g. `ImuFrame`.
    pub struct_name: &'static str,
    /// Versioned type name used on the wire, e.g. `imuflow.ImuFrame.v1`.
    pub type_name: &'static str,
    /// Total size in bytes.
    pub size: usize,
    /// Fields in memory order, the header's first.
    pub fields: Vec<FieldLayout>,
}

/// Element types that frame fields are built from.
trait FieldElement {
    fn describe(shape: &mut Vec<usize>) -> ScalarType;
}
impl FieldElement for f32 {
    fn describe(_: &mut Vec<usize>) -> ScalarType {
        ScalarType::F32
    }
}
impl FieldElement for u32 {
    fn describe(_: &mut Vec<usize>) -> ScalarType {
        ScalarType::U32
    }
}
impl FieldElement for u64 {
    fn describe(_: &mut Vec<usize>) -> ScalarType {
        ScalarType::U64
    }
}
impl<T: FieldElement, const N: usize> FieldElement for [T; N] {
    fn describe(shape: &mut Vec<usize>) -> ScalarType {
        shape.push(N);
        T::describe(shape)
    }
}

fn field<T: FieldElement>(name: &'static str, offset: usize, doc: &'static str) -> FieldLayout {
    let mut shape = Vec::new();
    let scalar = T::describe(&mut shape);
    FieldLayout {
        name,
        offset,
        scalar,
        shape,
        doc,
    }
}

/// A frame of the wire contract.
///
/// Implemented only by the frames in this module (the trait is sealed through `frame!`): each is
/// `Pod` (any bit pattern is valid, no padding) and `ZeroCopySend`, so it can live in shared memory.
pub trait Frame: Pod + ZeroCopySend + std::fmt::Debug + Send + Sync + 'static {
    /// Which frame type this is.
    const TYPE: FrameType;
    /// The common header.
    fn header(&self) -> &FrameHeader;
    /// The common header, mutable.
    fn header_mut(&mut self) -> &mut FrameHeader;
    /// Byte layout, for recorders and schema generation.
    fn layout() -> &'static FrameLayout;
    /// Type names of this frame's earlier wire versions, which recordings may hold.
    const EARLIER_TYPE_NAMES: &'static [&'static str] = &[];
    /// A frame of an earlier wire version (told apart by its length), widened to this one.
    fn from_earlier_version(_bytes: &[u8]) -> Option<Self> {
        None
    }
}

/// Defines a frame struct, its `Frame` impl and its byte layout from one field list, so the
/// struct and its documented layout cannot drift apart.
macro_rules! frame {
    (
        $(#[$meta:meta])*
        $name:ident, $type_name:literal, $frame_type:expr, {
            $( #[doc = $doc:literal] $field:ident : $ty:ty, )*
        }
        $( earlier: [$( $earlier_name:literal ),*] from $upgrade:path )?
    ) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
        #[type_name($type_name)]
        pub struct $name {
            /// Common header.
            pub header: FrameHeader,
            $( #[doc = $doc] pub $field: $ty, )*
        }

        impl Frame for $name {
            const TYPE: FrameType = $frame_type;
            $(
                const EARLIER_TYPE_NAMES: &'static [&'static str] = &[$( $earlier_name ),*];
                fn from_earlier_version(bytes: &[u8]) -> Option<Self> {
                    $upgrade(bytes)
                }
            )?
            fn header(&self) -> &FrameHeader {
                &self.header
            }
            fn header_mut(&mut self) -> &mut FrameHeader {
                &mut self.header
            }
            fn layout() -> &'static FrameLayout {
                static LAYOUT: std::sync::OnceLock<FrameLayout> = std::sync::OnceLock::new();
                LAYOUT.get_or_init(|| {
                    let mut fields = vec![
                        field::<u64>("header.seq", std::mem::offset_of!($name, header.seq),
                            "frame index assigned by the source"),
                        field::<u64>("header.capture_ns", std::mem::offset_of!($name, header.capture_ns),
                            "source capture time, ns (Unix epoch live, from recording start offline)"),
                        field::<u64>("header.publish_ns", std::mem::offset_of!($name, header.publish_ns),
                            "publish time, ns since the Unix epoch"),
                        field::<u32>("header.flags", std::mem::offset_of!($name, header.flags),
                            "bit set: 1 END_OF_STREAM, 2 INVALID, 4 CALIBRATING, 8 FEEDBACK_INITIAL, 16 RESTARTED, 32 PRELUDE, 64 DEGRADED"),
                        field::<u32>("header.restarts", std::mem::offset_of!($name, header.restarts),
                            "times the publishing stage had been restarted (0: its first process)"),
                    ];
                    $( fields.push(field::<$ty>(stringify!($field), std::mem::offset_of!($name, $field), $doc.trim())); )*
                    FrameLayout {
                        struct_name: stringify!($name),
                        type_name: $type_name,
                        size: std::mem::size_of::<$name>(),
                        fields,
                    }
                })
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Zeroable::zeroed()
            }
        }
    };
}

frame! {
    /// Raw inertial samples as real sensors deliver them, before fusion: up to one new sample per
    /// sensor, each stamped by its own clock. Sensors may run at different rates, so a frame holds
    /// whichever sensors had a new sample (`valid_mask`); the fusion stage aligns them by
    /// timestamp and resamples to the graph's rate. Sensors that fuse on board (trackers, vendor
    /// exports) also deliver their orientation (`orientation_mask`).
    RawImuFrame, "imuflow.RawImuFrame.v2", FrameType::RawImu, {
        /// Sample time per sensor, ns, on that sensor's own clock (offset, drift and jitter included); valid where `valid_mask` has the bit.
        sample_time_ns: [u64; MAX_SITES],
        /// Accelerometer: specific force (includes -gravity) in the sensor frame S, m/s².
        accelerometer_mps2: [[f32; 3]; MAX_SITES],
        /// Gyroscope: angular rate in the sensor frame S, rad/s.
        gyroscope_radps: [[f32; 3]; MAX_SITES],
        /// Magnetometer: magnetic field in the sensor frame S, µT; valid where `magnetometer_mask` has the bit.
        magnetometer_ut: [[f32; 3]; MAX_SITES],
        /// Orientation the sensor fused on board, R_IS as a unit quaternion [w, x, y, z]; valid where `orientation_mask` has the bit.
        orientation_wxyz: [[f32; 4]; MAX_SITES],
        /// Bit i set when sensor i has a new sample in this frame (accelerometer and gyroscope).
        valid_mask: u32,
        /// Bit i set when sensor i's sample has a magnetometer reading.
        magnetometer_mask: u32,
        /// Bit i set when sensor i's sample has an on-board orientation.
        orientation_mask: u32,
        /// Bit i set when sensor i's sample carries no gyroscope reading (its gyroscope field is zero): the fusion stage derives the angular rate from consecutive on-board orientations.
        no_gyroscope_mask: u32,
        /// Reserved, zero.
        reserved: u32,
    }
    earlier: ["imuflow.RawImuFrame.v1"] from v1::RawImuFrame::widen
}

frame! {
    /// What real IMUs deliver: orientation, specific force and angular rate, per sensor site.
    ImuFrame, "imuflow.ImuFrame.v2", FrameType::Imu, {
        /// R_IS per sensor as a unit quaternion [w, x, y, z]: sensor frame S to the sensor's own inertial frame I.
        orientation_wxyz: [[f32; 4]; MAX_SITES],
        /// Specific force (what an accelerometer measures, includes -gravity) in the sensor frame S, m/s².
        specific_force_mps2: [[f32; 3]; MAX_SITES],
        /// Angular rate in the sensor frame S, rad/s.
        angular_rate_radps: [[f32; 3]; MAX_SITES],
        /// Bit i set when sensor i delivered a finite sample this frame.
        valid_mask: u32,
        /// Reserved, zero.
        reserved: u32,
    }
    earlier: ["imuflow.ImuFrame.v1"] from v1::ImuFrame::widen
}

frame! {
    /// Calibrated IMU data on the body: bone orientation, free acceleration and angular velocity in M.
    BodyImuFrame, "imuflow.BodyImuFrame.v2", FrameType::BodyImu, {
        /// R_MB per sensor's bone as a unit quaternion [w, x, y, z]: bone frame B to model frame M.
        bone_orientation_wxyz: [[f32; 4]; MAX_SITES],
        /// Free acceleration (gravity removed) of the sensor in model frame M, m/s².
        free_acceleration_mps2: [[f32; 3]; MAX_SITES],
        /// Angular velocity of the bone in model frame M, rad/s.
        angular_velocity_radps: [[f32; 3]; MAX_SITES],
        /// Heading (yaw about M's y axis) correction the calibration currently applies per sensor, rad.
        heading_correction_rad: [f32; MAX_SITES],
        /// Bit i set when sensor i is valid this frame.
        valid_mask: u32,
        /// Reserved, zero.
        reserved: [u32; 2],
    }
    earlier: ["imuflow.BodyImuFrame.v1"] from v1::BodyImuFrame::widen
}

frame! {
    /// What the kinematics networks estimate for one frame.
    KinematicsFrame, "imuflow.KinematicsFrame.v1", FrameType::Kinematics, {
        /// Reference local pose: per joint, rotation relative to its parent as [w, x, y, z] (root: relative to M).
        local_pose_wxyz: [[f32; 4]; NUM_JOINTS],
        /// Joint positions relative to the root joint, expressed in model frame M axes, m.
        joint_position_m: [[f32; 3]; NUM_JOINTS],
        /// Joint velocities in model frame M, m/s.
        joint_velocity_mps: [[f32; 3]; NUM_JOINTS],
        /// Probability that the [left, right] foot is in contact with the ground, 0..1.
        foot_contact_prob: [f32; 2],
        /// Probability that [pelvis, left foot, right foot, left hand, right hand] is stationary, 0..1.
        stationary_prob: [f32; NUM_STATIONARY_JOINTS],
        /// Root (pelvis) velocity in model frame M, m/s.
        root_velocity_mps: [f32; 3],
        /// Gravity direction expressed in the root frame, m/s² (magnitude 9.81 when known).
        gravity_in_root_mps2: [f32; 3],
        /// Reserved, zero.
        reserved: u32,
    }
}

frame! {
    /// Contacts a contact stage estimated: which joints touch what, where, and with which forces.
    ContactFrame, "imuflow.ContactFrame.v1", FrameType::Contact, {
        /// Bit j set when joint j is in contact.
        contact_mask: u32,
        /// Number of valid entries in the contact point arrays.
        num_points: u32,
        /// Contact points in model frame M, m (first `num_points` valid).
        point_position_m: [[f32; 3]; MAX_CONTACT_POINTS],
        /// Joint index each contact point belongs to.
        point_joint: [u32; MAX_CONTACT_POINTS],
        /// Contact force at each point in model frame M, N.
        point_force_n: [[f32; 3]; MAX_CONTACT_POINTS],
        /// Total contact force per joint in model frame M, N.
        joint_force_n: [[f32; 3]; NUM_JOINTS],
        /// Estimated proxy-surface height (M's y) under each contact joint, m; 0 where no contact.
        surface_height_m: [f32; NUM_JOINTS],
        /// Residual root wrench the contacts did not explain: [force x, y, z (N), torque x, y, z (N·m)] in M.
        residual_root_wrench: [f32; 6],
    }
}

frame! {
    /// The final motion estimate.
    MotionFrame, "imuflow.MotionFrame.v1", FrameType::Motion, {
        /// Local pose: per joint, rotation relative to its parent as [w, x, y, z] (root: relative to M).
        local_pose_wxyz: [[f32; 4]; NUM_JOINTS],
        /// Root joint position in model frame M, m.
        root_position_m: [f32; 3],
        /// Generalized coordinates: root position (m, M) then per joint the local rotation vector (axis·angle, rad).
        q: [f32; NUM_DOFS],
        /// Generalized velocities: root linear velocity (m/s, M) then per joint angular velocity (rad/s, local).
        qdot: [f32; NUM_DOFS],
        /// Generalized forces: root force (N) then per joint torque (N·m), same coordinates as `qdot`.
        tau: [f32; NUM_DOFS],
        /// Ground-reaction force acting on each joint in model frame M, N.
        ground_reaction_force_n: [[f32; 3]; NUM_JOINTS],
        /// Bit j set when joint j is in contact.
        contact_mask: u32,
        /// Proxy-surface height (M's y) under each contact joint, m; 0 where no contact.
        surface_height_m: [f32; NUM_JOINTS],
        /// Residual force on the root the contacts could not explain, model frame M, N.
        residual_root_force_n: [f32; 3],
    }
}

frame! {
    /// What the independent physics simulation measured while tracking the estimate.
    ValidationFrame, "imuflow.ValidationFrame.v3", FrameType::Validation, {
        /// Mean distance between the simulated and the estimated joint positions in model frame M, m.
        tracking_error_m: f32,
        /// The same with both root positions removed (how well the joints follow), m.
        pose_error_m: f32,
        /// Distance between the simulated and the estimated root joint, m.
        root_error_m: f32,
        /// Mean horizontal speed of the simulated feet that touch the floor, m/s (0 when none does).
        foot_skate_mps: f32,
        /// Deepest ground penetration in the simulation this frame, m (0 when none).
        penetration_m: f32,
        /// 1 on the frame the simulated body lost its balance (it was then reset to the estimate).
        balance_lost: u32,
        /// Falls since the start of the stream.
        falls: u32,
        /// Times the simulation was re-anchored to the estimate after drifting away without falling.
        resyncs: u32,
        /// Bit j set when simulated joint j touches the floor.
        sim_contact_mask: u32,
        /// Distance of the centre of pressure the estimate needs (inverse dynamics, no simulation) outside its soles on the floor, m (0 inside or unless `support` is 1); for the frame 2 frames earlier.
        support_gap_m: f32,
        /// That frame's support: 0 not judged (start, gap), 1 feet push (`support_gap_m`), 2 little or no floor force needed (flight), 3 unsupported (no foot down, or the floor would have to pull).
        support: u32,
        /// Residual force the root needed to follow the estimate, model frame M, N (0 in torques mode).
        residual_root_force_n: [f32; 3],
        /// Residual torque on the root, model frame M, N·m (0 in torques mode).
        residual_root_torque_nm: [f32; 3],
        /// Simulated root position in model frame M, m.
        sim_root_position_m: [f32; 3],
        /// Floor contact force on each simulated joint in model frame M, N.
        sim_contact_force_n: [[f32; 3]; NUM_JOINTS],
    }
}

/// Interprets `bytes` as a frame of type `T`, if the length matches. Copies (the bytes need not be
/// aligned), so use it for recordings, not on the hot path.
pub fn frame_from_bytes<T: Frame>(bytes: &[u8]) -> Option<T> {
    (bytes.len() == std::mem::size_of::<T>()).then(|| bytemuck::pod_read_unaligned(bytes))
}

/// A recorded frame of type `T`: the current version's bytes, or an earlier version's
/// ([`Frame::EARLIER_TYPE_NAMES`]) widened, told apart by their length.
pub fn frame_from_recorded<T: Frame>(bytes: &[u8]) -> Option<T> {
    frame_from_bytes(bytes).or_else(|| T::from_earlier_version(bytes))
}

/// The IMU frames as they were before the site catalogue (`*.v1`): six slots, the six-site set's
/// order, which are the catalogue's first six. Widened with the other slots empty.
mod v1 {
    use bytemuck::{Pod, Zeroable};

    use super::FrameHeader;

    const SIX: usize = 6;

    /// Copies the six slots of `from` into the first six of `to`.
    fn six<T: Copy, const N: usize>(from: &[T; SIX], to: &mut [T; N]) {
        to[..SIX].copy_from_slice(from);
    }

    /// `bytes` as a `T`, if the length matches.
    fn read<T: Pod>(bytes: &[u8]) -> Option<T> {
        (bytes.len() == std::mem::size_of::<T>()).then(|| bytemuck::pod_read_unaligned(bytes))
    }

    #[repr(C)]
    #[derive(Clone, Copy, Pod, Zeroable)]
    pub struct RawImuFrame {
        header: FrameHeader,
        sample_time_ns: [u64; SIX],
        accelerometer_mps2: [[f32; 3]; SIX],
        gyroscope_radps: [[f32; 3]; SIX],
        magnetometer_ut: [[f32; 3]; SIX],
        orientation_wxyz: [[f32; 4]; SIX],
        valid_mask: u32,
        magnetometer_mask: u32,
        orientation_mask: u32,
        no_gyroscope_mask: u32,
    }

    impl RawImuFrame {
        pub fn widen(bytes: &[u8]) -> Option<super::RawImuFrame> {
            let old: RawImuFrame = read(bytes)?;
            let mut f = super::RawImuFrame {
                header: old.header,
                valid_mask: old.valid_mask,
                magnetometer_mask: old.magnetometer_mask,
                orientation_mask: old.orientation_mask,
                no_gyroscope_mask: old.no_gyroscope_mask,
                ..Default::default()
            };
            six(&old.sample_time_ns, &mut f.sample_time_ns);
            six(&old.accelerometer_mps2, &mut f.accelerometer_mps2);
            six(&old.gyroscope_radps, &mut f.gyroscope_radps);
            six(&old.magnetometer_ut, &mut f.magnetometer_ut);
            six(&old.orientation_wxyz, &mut f.orientation_wxyz);
            Some(f)
        }
    }

    #[repr(C)]
    #[derive(Clone, Copy, Pod, Zeroable)]
    pub struct ImuFrame {
        header: FrameHeader,
        orientation_wxyz: [[f32; 4]; SIX],
        specific_force_mps2: [[f32; 3]; SIX],
        angular_rate_radps: [[f32; 3]; SIX],
        valid_mask: u32,
        reserved: u32,
    }

    impl ImuFrame {
        pub fn widen(bytes: &[u8]) -> Option<super::ImuFrame> {
            let old: ImuFrame = read(bytes)?;
            let mut f = super::ImuFrame {
                header: old.header,
                valid_mask: old.valid_mask,
                ..Default::default()
            };
            six(&old.orientation_wxyz, &mut f.orientation_wxyz);
            six(&old.specific_force_mps2, &mut f.specific_force_mps2);
            six(&old.angular_rate_radps, &mut f.angular_rate_radps);
            Some(f)
        }
    }

    #[repr(C)]
    #[derive(Clone, Copy, Pod, Zeroable)]
    pub struct BodyImuFrame {
        header: FrameHeader,
        bone_orientation_wxyz: [[f32; 4]; SIX],
        free_acceleration_mps2: [[f32; 3]; SIX],
        angular_velocity_radps: [[f32; 3]; SIX],
        heading_correction_rad: [f32; SIX],
        valid_mask: u32,
        reserved: u32,
    }

    impl BodyImuFrame {
        pub fn widen(bytes: &[u8]) -> Option<super::BodyImuFrame> {
            let old: BodyImuFrame = read(bytes)?;
            let mut f = super::BodyImuFrame {
                header: old.header,
                valid_mask: old.valid_mask,
                ..Default::default()
            };
            six(&old.bone_orientation_wxyz, &mut f.bone_orientation_wxyz);
            six(&old.free_acceleration_mps2, &mut f.free_acceleration_mps2);
            six(&old.angular_velocity_radps, &mut f.angular_velocity_radps);
            six(&old.heading_correction_rad, &mut f.heading_correction_rad);
            Some(f)
        }
    }

    // The v1 sizes, as they were asserted before the site catalogue.
    const _: () = assert!(std::mem::size_of::<RawImuFrame>() == 32 + 48 + 72 * 3 + 96 + 16);
    const _: () = assert!(std::mem::size_of::<ImuFrame>() == 32 + 96 + 72 + 72 + 8);
    const _: () = assert!(std::mem::size_of::<BodyImuFrame>() == 32 + 96 + 72 + 72 + 24 + 8);
}

// Sizes are part of the contract: a change here is a wire change and needs a version bump.
const _: () = assert!(std::mem::size_of::<FrameHeader>() == 32);
const _: () = assert!(MAX_SITES <= 32); // the masks are u32
const _: () = assert!(std::mem::size_of::<RawImuFrame>() == 32 + 136 + 204 * 3 + 272 + 16 + 4);
const _: () = assert!(std::mem::size_of::<ImuFrame>() == 32 + 272 + 204 + 204 + 8);
const _: () = assert!(std::mem::size_of::<BodyImuFrame>() == 32 + 272 + 204 + 204 + 68 + 12);
const _: () =
    assert!(std::mem::size_of::<KinematicsFrame>() == 32 + 384 + 288 + 288 + 8 + 20 + 24 + 4);
const _: () = assert!(std::mem::align_of::<MotionFrame>() == 8);
const _: () = assert!(std::mem::size_of::<ValidationFrame>() == 32 + 44 + 36 + 288);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_cover_every_byte_exactly_once() {
        for ty in FrameType::ALL {
            let layout = ty.layout();
            let mut covered = vec![0u8; layout.size];
            for f in &layout.fields {
                for b in &mut covered[f.offset..f.offset + f.len() * f.scalar.size()] {
                    *b += 1;
                }
            }
            assert!(
                covered.iter().all(|&c| c == 1),
                "{}: layout fields must tile the struct without gaps or overlaps",
                layout.struct_name
            );
        }
    }

    #[test]
    fn layout_offsets_match_the_struct() {
        let mut f = ImuFrame::zeroed();
        f.angular_rate_radps[2][1] = 1.5;
        let bytes = bytemuck::bytes_of(&f);
        let layout = ImuFrame::layout();
        let field = layout
            .fields
            .iter()
            .find(|f| f.name == "angular_rate_radps")
            .expect("field exists");
        assert_eq!(field.shape, vec![MAX_SITES, 3]);
        let at = field.offset + (2 * 3 + 1) * 4;
        assert_eq!(
            f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")),
            1.5
        );
    }

    #[test]
    fn names_round_trip() {
        for ty in FrameType::ALL {
            assert_eq!(FrameType::from_name(ty.name()), Some(ty));
            assert!(ty.layout().type_name.starts_with("imuflow."));
        }
        assert_eq!(FrameType::from_name("NoSuchFrame"), None);
    }

    #[test]
    fn bytes_round_trip_and_length_check() {
        let mut m = MotionFrame::zeroed();
        m.header.seq = 42;
        m.tau[74] = -3.0;
        let back: MotionFrame = frame_from_bytes(bytemuck::bytes_of(&m)).expect("same length");
        assert_eq!(back, m);
        assert!(frame_from_bytes::<MotionFrame>(&[0u8; 10]).is_none());
    }

    #[test]
    fn a_v1_imu_frame_reads_as_the_first_six_slots() {
        // A v1 ImuFrame's bytes written by hand: header, then 6 quaternions, 6 forces, 6 rates,
        // valid_mask, reserved (its layout before the site catalogue).
        let mut bytes = Vec::new();
        bytes.extend_from_slice(&7u64.to_le_bytes()); // seq
        bytes.extend_from_slice(&[0u8; 24]);
        for i in 0..6 {
            for k in 0..4 {
                bytes.extend_from_slice(&((10 * i + k) as f32).to_le_bytes());
            }
        }
        for i in 0..6 {
            for k in 0..3 {
                bytes.extend_from_slice(&((100 + 10 * i + k) as f32).to_le_bytes());
            }
        }
        for i in 0..6 {
            for k in 0..3 {
                bytes.extend_from_slice(&((200 + 10 * i + k) as f32).to_le_bytes());
            }
        }
        bytes.extend_from_slice(&0b10_1101u32.to_le_bytes());
        bytes.extend_from_slice(&0u32.to_le_bytes());
        assert_eq!(bytes.len(), 280);
        assert!(frame_from_bytes::<ImuFrame>(&bytes).is_none());
        let f: ImuFrame = frame_from_recorded(&bytes).expect("a v1 frame widens");
        assert_eq!(f.header.seq, 7);
        assert_eq!(f.valid_mask, 0b10_1101);
        assert_eq!(f.orientation_wxyz[5], [50.0, 51.0, 52.0, 53.0]);
        assert_eq!(f.specific_force_mps2[2], [120.0, 121.0, 122.0]);
        assert_eq!(f.angular_rate_radps[4], [240.0, 241.0, 242.0]);
        assert!(f.orientation_wxyz[6..].iter().all(|q| *q == [0.0; 4]));
        assert_eq!(ImuFrame::EARLIER_TYPE_NAMES, ["imuflow.ImuFrame.v1"]);
        // The current version reads as itself; a length of neither is no frame.
        assert_eq!(
            frame_from_recorded::<ImuFrame>(bytemuck::bytes_of(&f)),
            Some(f)
        );
        assert!(frame_from_recorded::<ImuFrame>(&bytes[..279]).is_none());
        assert!(frame_from_recorded::<MotionFrame>(&bytes).is_none());
    }

    /// The bytes of `slots`' first six entries, one after the other (a v1 field).
    fn six<T: Pod>(slots: &[T]) -> Vec<u8> {
        bytemuck::cast_slice(&slots[..6]).to_vec()
    }

    #[test]
    fn v1_raw_and_body_imu_frames_read_as_their_first_six_slots() {
        // A v2 frame with the first six slots filled; its v1 bytes written field by field in the
        // v1 order; read back, the same frame.
        let mut raw = RawImuFrame::default();
        raw.header.seq = 3;
        for i in 0..6 {
            let k = i as f32;
            raw.sample_time_ns[i] = 1000 + i as u64;
            raw.accelerometer_mps2[i] = [k, 1.0 + k, 2.0 + k];
            raw.gyroscope_radps[i] = [10.0 + k, 0.0, -k];
            raw.magnetometer_ut[i] = [20.0, k, 0.5];
            raw.orientation_wxyz[i] = [1.0, 0.0, k * 0.1, 0.0];
        }
        (raw.valid_mask, raw.magnetometer_mask) = (0b11_1111, 0b10_1010);
        (raw.orientation_mask, raw.no_gyroscope_mask) = (0b1, 0b10);
        let mut bytes = bytemuck::bytes_of(&raw.header).to_vec();
        bytes.extend(six(&raw.sample_time_ns));
        bytes.extend(six(&raw.accelerometer_mps2));
        bytes.extend(six(&raw.gyroscope_radps));
        bytes.extend(six(&raw.magnetometer_ut));
        bytes.extend(six(&raw.orientation_wxyz));
        for mask in [0b11_1111u32, 0b10_1010, 0b1, 0b10] {
            bytes.extend(mask.to_le_bytes());
        }
        assert_eq!(bytes.len(), 408);
        assert_eq!(frame_from_recorded::<RawImuFrame>(&bytes), Some(raw));

        let mut body = BodyImuFrame::default();
        body.header.seq = 4;
        for i in 0..6 {
            let k = i as f32;
            body.bone_orientation_wxyz[i] = [0.0, 1.0, 0.0, k];
            body.free_acceleration_mps2[i] = [k, -k, 0.25];
            body.angular_velocity_radps[i] = [0.5, k, k * k];
            body.heading_correction_rad[i] = -k;
        }
        body.valid_mask = 0b11_0111;
        let mut bytes = bytemuck::bytes_of(&body.header).to_vec();
        bytes.extend(six(&body.bone_orientation_wxyz));
        bytes.extend(six(&body.free_acceleration_mps2));
        bytes.extend(six(&body.angular_velocity_radps));
        bytes.extend(six(&body.heading_correction_rad));
        bytes.extend(0b11_0111u32.to_le_bytes());
        bytes.extend(0u32.to_le_bytes());
        assert_eq!(bytes.len(), 304);
        assert_eq!(frame_from_recorded::<BodyImuFrame>(&bytes), Some(body));
        assert_eq!(
            BodyImuFrame::EARLIER_TYPE_NAMES,
            ["imuflow.BodyImuFrame.v1"]
        );
    }

    #[test]
    fn flag_names() {
        let h = FrameHeader {
            flags: flags::INVALID | flags::END_OF_STREAM,
            ..Default::default()
        };
        assert_eq!(h.flag_names(), vec!["END_OF_STREAM", "INVALID"]);
        assert!(h.is_end());
    }
}
