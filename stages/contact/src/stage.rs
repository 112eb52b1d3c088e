//! The `contact` stage (work in progress: filled in with the PIP rule).
