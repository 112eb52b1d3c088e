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
pub use imuflow_body::{MAX_SITES, SiteMask};
pub use layout::Layout;
pub use mvn::resample_truth;
pub use recording::{SensorCounts, SensorRecording};

/// The sensor sites of the body model's catalogue, in wire slot order (docs/architecture.md,
/// "Conventions"); the layout's `[sensors.<site>]` names.
pub const SITES: [&str; MAX_SITES] = imuflow_body::Imu::NAMES;

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

/// Reads the sensors of `sites` (a graph's sensor set) from a recording: MVNX as is, CSV/TSV with
/// the layout at `layout`. A site of `sites` the recording or the layout lacks is an error naming
/// it; sensors on other sites are left out ([`SensorRecording::left_out`]).
pub fn read(
    path: &Path,
    format: Format,
    layout: Option<&Path>,
    sites: SiteMask,
) -> Result<SensorRecording, Error> {
    match format {
        Format::Mvnx => mvnx::read(path, sites),
        Format::Csv => {
            let Some(layout) = layout else {
                return Err(Error::file(
                    path,
                    "a CSV/TSV recording needs a layout TOML that describes its columns",
                ));
            };
            read_csv_sites(path, &Layout::load(layout)?, sites)
        }
    }
}

/// Reads a CSV/TSV recording (a file, or a folder of per-sensor files) as `layout` describes it:
/// every site the layout lists.
pub fn read_csv(path: &Path, layout: &Layout) -> Result<SensorRecording, Error> {
    read_csv_sites(path, layout, layout.site_mask())
}

/// [`read_csv`] of the sensors of `sites` only, each of which the layout must list.
pub fn read_csv_sites(
    path: &Path,
    layout: &Layout,
    sites: SiteMask,
) -> Result<SensorRecording, Error> {
    if !path.exists() {
        return Err(Error::file(path, "no such file or folder"));
    }
    delimited::read(path, layout, sites)
}

/// Reads an Xsens MVNX file: the sensors on the six-site set's sites and the segment poses as
/// truth ([`read`] reads another set's).
pub fn read_mvnx(path: &Path) -> Result<SensorRecording, Error> {
    mvnx::read(path, SiteMask::of(imuflow_body::Imu::SIX))
}
