//! The optimizer stage (work in progress).

pub mod globalpose;
