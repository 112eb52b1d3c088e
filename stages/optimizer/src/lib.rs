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
//! body and rigid-body model) and [`Method`] (what the stage calls once per frame).
//!
//! World: model frame M (x left, y up, z forward), floor at y = 0, gravity (0, −9.81, 0).

pub mod bench;
pub mod estimate;
pub mod globalpose;
pub mod integrate;
pub mod pip;
pub mod reference;
pub mod stage;

pub use estimate::MotionEstimate;
pub use reference::Reference;
pub use stage::{SPEC, run};

use imuflow_body::dynamics::RigidBodyModel;
use imuflow_body::{BodyModel, BodyParams};
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

/// What a method reports about one step besides its estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepReport {
    /// The solver failed (infeasible, not converged, non-finite) and the method's documented fallback
    /// produced this frame. Counted by the stage and reported in its summary; the frame is flagged INVALID.
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
