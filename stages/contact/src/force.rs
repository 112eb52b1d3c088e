//! GlobalPose's force-based contact estimation (work in progress).
