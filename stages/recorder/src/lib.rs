//! The recorder stage: taps any edges of a graph into an mcap file.
//!
//! Per tapped edge, one channel named after the edge (`source.imu`) with the raw frame bytes:
//! message encoding `imuflow-raw` (the `#[repr(C)]` little-endian bytes, exactly what travelled),
//! schema encoding `imuflow-layout` (a JSON description of every field: name, byte offset, scalar
//! type, shape, unit and frame), so a recording replays exactly and decodes without imuflow.
//! With `json = true`, also one `json` channel per edge (`source.imu/json`) with a JSON Schema,
//! which Foxglove and other mcap tools decode without code generation.
//!
//! The file is finalized at END_OF_STREAM, on a stop request (Ctrl-C) and on SIGTERM (another
//! stage crashed).

pub mod json;
pub mod stage;

pub use stage::{SPEC, run};

/// Schema encoding of the raw channels: the frame layout as JSON.
pub const LAYOUT_ENCODING: &str = "imuflow-layout";
/// Message encoding of the raw channels: the frame's `#[repr(C)]` little-endian bytes.
pub const RAW_ENCODING: &str = "imuflow-raw";
/// Suffix of the JSON channels' topics.
pub const JSON_TOPIC_SUFFIX: &str = "/json";
