//! What the export tests share: the bundled sample and its true motion as an export keeps it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use imuflow_graph::frames::{MotionFrame, flags};
use imuflow_recording::{Recorded, Recording};

/// The bundled sample recording (models/sample/walk.mcap).
pub fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sample/walk.mcap")
}

/// The sample's truth frames an export keeps by default (the calibration prelude, calibrating and
/// invalid frames left out), read by the recording reader instead of the exporter.
pub fn truth_after_prelude() -> Vec<MotionFrame> {
    let recording = Recording::load(&sample(), None, None).expect("the sample");
    recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) => Some(**m),
            Recorded::Imu(_) => None,
        })
        .filter(|m| m.header.flags & (flags::PRELUDE | flags::CALIBRATING | flags::INVALID) == 0)
        .collect()
}
