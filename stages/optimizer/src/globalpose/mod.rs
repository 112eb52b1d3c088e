//! GlobalPose's physics (SIGGRAPH 2025 §3.3, Eq. 7–16; reference §5.4). Work in progress: the
//! configuration below is the contract with the stage.

/// GlobalPose's gains and weights. `Default` is the paper's/code's values (reference §5.4).
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalPoseConfig {
    /// Pose PD stiffness (kp_pose = 3600).
    pub kp_rotation: f64,
    /// Pose PD damping (kd_pose = 60).
    pub kd_rotation: f64,
    /// Contact-joint position PD stiffness (kp_tran = 3600).
    pub kp_position: f64,
    /// Contact-joint position PD damping (kd_tran = 60).
    pub kd_position: f64,
    /// Friction coefficient (μ = 0.7).
    pub friction: f64,
}
