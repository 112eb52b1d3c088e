//! The kinematics stage (work in progress).
