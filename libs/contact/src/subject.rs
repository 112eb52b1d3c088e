//! The subject's body model from a stage's `stature_m` and `mass_kg` parameters: one definition for
//! every stage that models the body in contact with the ground (contact, optimizer, validation), so
//! the parameters' names, ranges and defaults agree between them.

use imuflow_body::{BodyModel, BodyParams};
use imuflow_graph::params::Param;

/// The subject's stature, shared by every stage that builds the body model.
pub const STATURE_PARAM: Param<f64> = imuflow_graph::param! {
    /// subject stature (m): scales the body model
    stature_m: f64 = 1.75, float(1.0, 2.5)
};

/// The subject's mass, shared by every stage that builds the body model.
pub const MASS_PARAM: Param<f64> = imuflow_graph::param! {
    /// subject mass (kg): scales the segment masses
    mass_kg: f64 = 70, float(20.0, 250.0)
};

/// The built-in body model scaled to a stage's `stature_m` (m) and `mass_kg` (kg).
pub fn subject_body(stature_m: f64, mass_kg: f64) -> anyhow::Result<BodyModel> {
    Ok(BodyModel::new(&BodyParams::builtin()?, stature_m, mass_kg)?)
}
