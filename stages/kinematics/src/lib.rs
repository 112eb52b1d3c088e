//! imuflow-kinematics: the PIP (CVPR 2022) and GlobalPose (SIGGRAPH 2025) networks in candle and the
//! `kinematics` stage. Training and checkpoint import are in tools/train (imuflow-train). See `README.md` in this crate.
//!
//! - [`net`]: the recurrent block (articulate `RNN`/`RNNWithInit`) with PyTorch's parameter names.
//! - [`method`]: each method's line-up of nets and their sizes.
//! - [`features`]: per-frame network inputs (the two methods normalize differently).
//! - [`weights`]: weight files (safetensors + metadata), loading with shape checks.
//! - [`lean`]: the per-frame forward pass streaming inference uses (plain f32 over the nets' weights).

pub mod bench;
pub mod error;
pub mod features;
pub mod infer;
pub mod lean;
pub mod method;
pub mod mirror;
pub mod net;
pub mod sensed;
pub mod stage;
pub mod weights;

pub use error::WeightsError;
pub use method::Method;
pub use stage::{SPEC, run};
