//! `imuflow compare`'s evaluation: [`report::write`] scores every variant of a finished run from
//! its recording and writes `report.md`, `results.json` and the [`plots`]; [`batch::run`] does it
//! for every clip of a dataset split and reports means and paired differences over clips.

pub mod batch;
pub mod plots;
pub mod report;

pub use report::write;
