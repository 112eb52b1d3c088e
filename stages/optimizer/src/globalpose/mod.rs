//! GlobalPose physics (work in progress).
