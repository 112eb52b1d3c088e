//! imuflow-kinematics: the PIP (CVPR 2022) and GlobalPose (SIGGRAPH 2025) networks in candle, their
//! trainer, checkpoint import, and the `kinematics` stage. See `README.md` in this crate.
//!
//! - [`net`]: the recurrent block (articulate `RNN`/`RNNWithInit`) with PyTorch's parameter names.
//! - [`method`]: each method's line-up of nets and their sizes.
//! - [`features`]: per-frame network inputs (the two methods normalize differently).
//! - [`weights`]: weight files (safetensors + metadata), loading with shape checks.
//! - [`lean`]: the per-frame forward pass streaming inference uses (plain f32 over the nets' weights).
//! - [`data`], [`train`]: training data from the dataset shards, and `imuflow train`.

pub mod bench;
pub mod data;
pub mod error;
pub mod features;
pub mod import;
pub mod infer;
pub mod lean;
pub mod method;
pub mod mirror;
pub mod net;
pub mod stage;
pub mod train;
pub mod weights;

pub use error::WeightsError;
pub use method::Method;
pub use stage::{SPEC, run};
