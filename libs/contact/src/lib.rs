//! Contact estimation for the physics optimizer.
//!
//! - [`geometry`]: where each joint touches the ground (its clearance above the floor when resting on it)
//!   and the contact points of a contact joint.
//! - [`set`]: [`ContactSet`], the result every method produces, and its wire form ([`ContactFrame`]).
//! - [`pip`]: PIP's rule (CVPR 2022 §3.2.3; reference §5.2): joint height plus the networks' foot-contact
//!   probability, 4 points of a 20 cm square per contact joint.
//! - [`force`]: GlobalPose's force-based estimation (SIGGRAPH 2025 §3.3; reference §5.4 steps 7–10):
//!   explain the pre-tracking residual root wrench with friction-cone contact forces.
//! - [`subject`]: the subject's body model from a stage's `stature_m` and `mass_kg` parameters.
//!
//! A library with no process: the `contact` stage (stages/contact), the optimizer and the validation
//! stage link it.
//!
//! The world is the model frame M (y up) with the floor at y = 0 unless a proxy surface says otherwise.
//!
//! [`ContactFrame`]: imuflow_graph::frames::ContactFrame

pub mod force;
pub mod geometry;
pub mod pip;
pub mod set;
pub mod subject;

pub use geometry::ContactGeometry;
pub use set::{ContactPoint, ContactSet};
