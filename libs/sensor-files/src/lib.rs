//! imuflow-sensor-files: recorded IMU sessions read from files, as `RawImuFrame`s (a library, no
//! process). Two readers:
//!
//! - [`read_csv`]: CSV/TSV exports (Movella DOT, x-io, Noraxon, OpenSense `.sto`, or any table of
//!   numbers) described by a layout TOML ([`layout::Layout`]; every key in the crate README);
//! - [`read_mvnx`]: Xsens MVN's XML export, with the suit's segment poses mapped onto imuflow's
//!   24-joint body as the truth ([`mvn`]).
//!
//! Both give a [`SensorRecording`]: every sample in SI units and its sensor's frame, merged into
//! frames on one clock that starts at 0, with each sensor's own time kept. Bad input is an
//! [`Error`] that names the file and line; empty or NaN cells are missing values, counted in
//! [`SensorCounts`].

// Library code returns errors; panicking helpers are for tests only.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

mod delimited;
mod error;
pub mod layout;
pub mod mvn;
mod mvnx;
mod recording;
pub mod sample;
pub mod sites;
mod table;
pub mod units;

use std::path::Path;

pub use error::Error;
pub use imuflow_body::NUM_IMUS;
pub use layout::Layout;
pub use mvn::resample_truth;
pub use recording::{SensorCounts, SensorRecording};

/// The six sensor sites, in imuflow's IMU order (docs/architecture.md, "Conventions"); the
/// layout's `[sensors.<site>]` names.
pub const SITES: [&str; NUM_IMUS] = {
    let mut names = [""; NUM_IMUS];
    let mut i = 0;
    while i < NUM_IMUS {
        names[i] = imuflow_body::Imu::SIX[i].name();
        i += 1;
    }
    names
};

/// A recording's file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// CSV/TSV described by a layout TOML.
    Csv,
    /// Xsens MVN XML.
    Mvnx,
}

impl Format {
    /// By extension: `.mvnx` (or `.mvnx.gz`) is MVNX, anything else (files or folders) CSV/TSV.
    pub fn detect(path: &Path) -> Format {
        let mvnx = plain_extension(path).eq_ignore_ascii_case("mvnx");
        if mvnx { Format::Mvnx } else { Format::Csv }
    }
}

/// A file's extension as if it were not compressed: `csv` for `a.csv.gz`.
pub(crate) fn plain_extension(path: &Path) -> String {
    let ext = |p: &Path| {
        p.extension()
            .map(|e| e.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    match ext(path) {
        e if e.eq_ignore_ascii_case("gz") => ext(&path.with_extension("")),
        e => e,
    }
}

/// Reads a recording: MVNX as is, CSV/TSV with the layout at `layout`.
pub fn read(path: &Path, format: Format, layout: Option<&Path>) -> Result<SensorRecording, Error> {
    match format {
        Format::Mvnx => read_mvnx(path),
        Format::Csv => {
            let Some(layout) = layout else {
                return Err(Error::file(
                    path,
                    "a CSV/TSV recording needs a layout TOML that describes its columns",
                ));
            };
            read_csv(path, &Layout::load(layout)?)
        }
    }
}

/// Reads a CSV/TSV recording (a file, or a folder of per-sensor files) as `layout` describes it.
pub fn read_csv(path: &Path, layout: &Layout) -> Result<SensorRecording, Error> {
    if !path.exists() {
        return Err(Error::file(path, "no such file or folder"));
    }
    delimited::read(path, layout)
}

/// Reads an Xsens MVNX file: the sensors on imuflow's six sites and the segment poses as truth.
pub fn read_mvnx(path: &Path) -> Result<SensorRecording, Error> {
    mvnx::read(path)
}
