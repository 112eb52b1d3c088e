//! The contact stage (work in progress).
