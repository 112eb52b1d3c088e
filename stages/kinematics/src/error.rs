//! Errors of loading and checking weights.

/// Weights that don't fit the network: every variant names the tensor or file.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    #[error("tensor '{name}' is missing from the weights")]
    MissingTensor { name: String },
    #[error("tensor '{name}' has shape {found:?}, expected {expected}")]
    Shape {
        name: String,
        expected: String,
        found: Vec<usize>,
    },
    #[error("tensor '{name}' is {found}, expected f32")]
    DType { name: String, found: String },
    #[error(
        "tensor '{name}' is not used by the {method} networks (wrong method or a corrupt file?)"
    )]
    UnexpectedTensor { name: String, method: String },
    #[error("the weights are for method '{found}', not '{expected}'")]
    WrongMethod { expected: String, found: String },
    #[error(
        "the weights were trained for the sensors {weights}; the stage's sensors are {graph} (train weights for that set with `imuflow train`, or set `sensors`: the graph's, or the stage's own)"
    )]
    WrongSensors { weights: String, graph: String },
    #[error("{method}'s networks cannot be sized for the sensors ({sensors}): {why}")]
    UnsupportedSet {
        method: String,
        sensors: String,
        why: String,
    },
    #[error("the weights' sensors name '{site}', not a site of the body model")]
    UnknownSite { site: String },
    #[error("{path}: {message}")]
    File { path: String, message: String },
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}
