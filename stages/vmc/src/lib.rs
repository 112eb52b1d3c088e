//! The vmc stage: the motion estimate, live, to avatar apps over the VMC protocol.
//!
//! The Virtual Motion Capture protocol (protocol.vmc.info) is OSC over UDP; a "performer" sends
//! an avatar's bones to a "marionette" (VSeeFace, Warudo, VMagicMirror, ...), usually on port
//! 39539. This stage is a performer: each MotionFrame becomes one OSC bundle ([`bundle`]) with
//! the root transform, the 22 humanoid bones imuflow's SMPL-topology body has ([`bones`]), the
//! "data available" flag and the time, in Unity's coordinates ([`convert`]), sent without ever
//! waiting on the receiver ([`sender`]).
//!
//! Rest pose: a Unity humanoid's bone rotations are relative to its own rest pose. VMC receivers
//! load VRM avatars, whose bones are normalized on export: a T-pose facing +z with every local
//! rotation identity and bone axes along the world's. imuflow's rest pose is a T-pose facing +z
//! with identity local rotations too (`imuflow_body::skeleton::Skeleton`), so its local rotations
//! are the avatar's local rotations, unchanged but for the coordinate change. An avatar whose
//! rig is not normalized (bone axes not along the world's in its T-pose) needs its receiver to
//! retarget, as it would from any VMC performer.
//!
//! Frames flagged INVALID or CALIBRATING, and frames whose payload is no pose, are not sent and
//! are counted: the receiver holds the last pose it got, and no made-up pose goes out.

pub mod bones;
pub mod bundle;
pub mod convert;
pub mod sender;
pub mod stage;

pub use stage::{SPEC, run};
