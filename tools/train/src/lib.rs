//! Training the kinematics stage's networks (`imuflow train`) and importing the authors' checkpoints
//! (`imuflow import-checkpoint`): everything about making weight files, none of it in the stage
//! process, which only reads them (stages/kinematics).
//!
//! - [`data`]: the dataset shards (`imuflow dataset build`) as the per-frame arrays each method's nets
//!   read and predict.
//! - [`train`]: training on the CPU (or a CUDA GPU with the `cuda` feature) with candle autograd.
//! - [`import`]: the authors' PyTorch checkpoints to our weight files.
//! - [`average`]: the element-wise mean of fine-tuned weight files (`imuflow average-weights`).

pub mod average;
pub mod data;
pub mod import;
pub mod train;
