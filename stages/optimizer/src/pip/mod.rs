//! PIP's dual PD controller and QP (CVPR 2022 Eq. 3–13; reference §5.2). Work in progress: the
//! configuration below is the contract with the stage.

/// PIP's gains and weights. `Default` is the paper's/code's values (reference §5.2).
#[derive(Clone, Debug, PartialEq)]
pub struct PipConfig {
    /// Joint-rotation PD stiffness (PIP kp_ang = 2400).
    pub kp_rotation: f64,
    /// Joint-rotation PD damping (kd_ang = 60).
    pub kd_rotation: f64,
    /// Joint-position PD stiffness (kp_lin = 3600).
    pub kp_position: f64,
    /// Joint-position PD damping (kd_lin = 60).
    pub kd_position: f64,
    /// Friction coefficient (μ = 0.6).
    pub friction: f64,
}
