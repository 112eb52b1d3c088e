//! The physics optimizer: turns the kinematics networks' estimate (and contacts) into motion with
//! global translation, joint torques and ground-reaction forces.
//!
//! Three methods, one per graph variant:
//! - [`integrate`]: the no-physics baseline: the networks' pose, root translation by integrating the
//!   root velocity with GlobalPose's stationary-joint refinement (SIGGRAPH 2025 Eq. 4/25).
//! - [`pip`]: PIP's dual PD controller and QP (CVPR 2022 Eq. 3–13), solved with clarabel.
//! - [`globalpose`]: GlobalPose's pre-tracking, force-based contact estimation and re-tracking
//!   (SIGGRAPH 2025 §3.3, Eq. 7–16; reference §5.4), least squares on the normal equations.
//!
//! Shared pieces: [`Reference`] (what the networks say, decoded from a `KinematicsFrame`),
//! [`MotionEstimate`] (a method's result, written into a `MotionFrame`), [`PhysicsBody`] (the subject's
//! body and rigid-body model), [`Method`] (what the stage calls once per frame) and
//! [`degraded::Degraded`] (what `pip` and `globalpose` publish for a frame they cannot solve).
//!
//! World: model frame M (x left, y up, z forward), floor at y = 0, gravity (0, −9.81, 0).

pub mod bench;
mod cholesky;
pub mod degraded;
pub mod estimate;
pub mod globalpose;
pub mod integrate;
pub mod pip;
pub mod reference;
pub mod stage;
mod wide;

#[cfg(test)]
mod test_random;

pub use estimate::MotionEstimate;
pub use reference::Reference;
pub use stage::{SPEC, run};

use imuflow_body::dynamics::{DofVector, RigidBodyModel, joint_dof};
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_contact::{ContactGeometry, ContactSet};

/// Frame period of the networks and the physics (s): 60 Hz, as in both papers.
pub const DT_S: f64 = 1.0 / 60.0;

/// The subject's body: kinematic model, rigid-body model and contact geometry.
#[derive(Clone, Debug)]
pub struct PhysicsBody {
    pub body: BodyModel,
    pub model: RigidBodyModel,
    pub geometry: ContactGeometry,
}

impl PhysicsBody {
    /// The built-in body model scaled to a subject (stature in m, mass in kg).
    pub fn new(stature_m: f64, mass_kg: f64) -> anyhow::Result<PhysicsBody> {
        let body = BodyModel::new(&BodyParams::builtin()?, stature_m, mass_kg)?;
        Ok(PhysicsBody::from_body(body))
    }

    /// The rigid-body model and contact geometry of a body model.
    pub fn from_body(body: BodyModel) -> PhysicsBody {
        PhysicsBody {
            model: RigidBodyModel::new(&body),
            geometry: ContactGeometry::new(&body),
            body,
        }
    }
}

/// What the ground under the subject may be, for the methods that place the root from contacts
/// (`integrate`, `globalpose`; PIP's QP keeps its own floor).
///
/// Repeated jumps showed why it matters: a network's vertical root velocity is biased on motions it
/// never saw, each flight lands a little higher (or lower), and GlobalPose's proxy surface (§3.3)
/// then holds the feet at that new height as if it were a step: the root climbed 2.8 m in 14 s of
/// jumps on flat ground. With only six IMUs a real step and an accumulated error look alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Terrain {
    /// Flat ground (default): stationary feet are pulled to the floor at y = 0 wherever they land
    /// ([`FLAT_FLOOR_PULL_RATE`] of their height a frame; GlobalPose's step-10 pull without its
    /// 0.15 m limit), so the root height cannot ratchet up or sink.
    #[default]
    Flat,
    /// GlobalPose's proxy surfaces (reference §5.4 step 10): contacts more than 0.15 m above the
    /// floor are held where they are (steps, seats), and the no-physics integrator follows the
    /// network's vertical velocity alone.
    Proxy,
}

/// On flat terrain, the fraction of a planted foot's height above the floor removed per frame.
/// GlobalPose's step-10 pull removes 10 % (reference §5.4), but only within 0.15 m of the floor;
/// a landing after a biased flight is several centimetres off, and at 10 % a frame it was still
/// half off when the next jump started (repeated-hop test: 5.9 cm mean root height error at 10 %,
/// 3.6 cm at 20 %). 20 % is back within 1 cm in about 10 frames (0.17 s).
pub const FLAT_FLOOR_PULL_RATE: f64 = 0.2;

/// A planted foot's new height above the floor (m) on flat terrain: pulled down by
/// [`FLAT_FLOOR_PULL_RATE`] when `in_contact`, never below the floor.
pub fn pull_to_floor(height_m: f64, in_contact: bool) -> f64 {
    let h = if in_contact {
        height_m * (1.0 - FLAT_FLOOR_PULL_RATE)
    } else {
        height_m
    };
    h.max(0.0)
}

impl Terrain {
    /// The choices of the optimizer stage's `terrain` parameter.
    pub const NAMES: [&str; 2] = ["flat", "proxy"];

    pub fn parse(name: &str) -> Option<Terrain> {
        match name {
            "flat" => Some(Terrain::Flat),
            "proxy" => Some(Terrain::Proxy),
            _ => None,
        }
    }
}

/// Faster than a sprinter's pelvis (about 12 m/s at top speed): a step that leaves the root moving
/// faster has diverged (GlobalPose's root reached 1e39 m within frames of committing one, on a bow
/// with exact sensor signals, 2026-11-26).
pub const MAX_ROOT_SPEED_MPS: f64 = 15.0;

/// Faster than a pitcher's shoulder (about 120 rad/s, the fastest human joint motion): a step that
/// leaves a joint turning faster has diverged.
pub const MAX_JOINT_SPEED_RADPS: f64 = 150.0;

/// Whether a generalized velocity is finite and within what a human body can do
/// ([`MAX_ROOT_SPEED_MPS`], [`MAX_JOINT_SPEED_RADPS`]).
pub fn within_human_speeds(v: &DofVector) -> bool {
    let root = v.fixed_rows::<3>(0).norm();
    let fastest_joint = JointId::all()
        .map(|j| v.fixed_rows::<3>(joint_dof(j)).norm())
        .fold(0.0, f64::max);
    v.iter().all(|x| x.is_finite())
        && root <= MAX_ROOT_SPEED_MPS
        && fastest_joint <= MAX_JOINT_SPEED_RADPS
}

/// What a method reports about one step besides its estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepReport {
    /// The solver failed (not converged, non-finite, a diverged step) and this frame is the method's
    /// degraded estimate ([`degraded::Degraded`]): the networks' pose with the root integrated, no
    /// dynamics. The next step continues the physics from it. The stage flags such a frame DEGRADED,
    /// counts it and reports the count in its summary.
    pub fallback: bool,
}

/// A physics method, stepped once per frame by the optimizer stage.
pub trait Method {
    /// The contacts the last `step` used, with the forces the method found (`integrate`: its
    /// stationary joints, without forces).
    fn contacts(&self) -> &ContactSet;

    /// Start over: the next `step` is a first frame (state from the reference pose, placed on the floor).
    fn reset(&mut self);

    /// Advance one frame (`DT_S`). `contacts` is the contact stage's estimate for this frame, where the
    /// graph wires one (PIP); methods that estimate contacts themselves ignore it. Writes the new state
    /// into `out`.
    fn step(
        &mut self,
        reference: &Reference,
        contacts: Option<&ContactSet>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<StepReport>;
}
