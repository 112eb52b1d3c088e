//! The calibration stage (work in progress).
