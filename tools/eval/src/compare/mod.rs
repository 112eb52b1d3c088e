//! The report of `imuflow compare`: [`report::write`] scores every variant of a finished run from
//! its recording and writes `report.md`, `results.json` and the [`plots`].

pub mod plots;
pub mod report;

pub use report::write;
