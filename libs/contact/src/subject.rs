//! The subject's body model from a stage's `stature_m` and `mass_kg` parameters: one definition for
//! every stage that models the body in contact with the ground (contact, optimizer, validation), so
//! the parameters' names, ranges and defaults agree between them.

use imuflow_body::{BodyModel, BodyParams};
use imuflow_graph::spec::ParamSpec;
use imuflow_graph::stage::Params;

/// The subject's stature, shared by every stage that builds the body model.
pub const STATURE_PARAM: ParamSpec = ParamSpec::float(
    "stature_m",
    1.0,
    2.5,
    "1.75",
    "subject stature (m): scales the body model",
);
/// The subject's mass, shared by every stage that builds the body model.
pub const MASS_PARAM: ParamSpec = ParamSpec::float(
    "mass_kg",
    20.0,
    250.0,
    "70",
    "subject mass (kg): scales the segment masses",
);

/// The built-in body model scaled by a stage's `stature_m` and `mass_kg`.
pub fn subject_body(params: &Params) -> anyhow::Result<BodyModel> {
    Ok(BodyModel::new(
        &BodyParams::builtin()?,
        params.float(STATURE_PARAM.name, 1.75),
        params.float(MASS_PARAM.name, 70.0),
    )?)
}

