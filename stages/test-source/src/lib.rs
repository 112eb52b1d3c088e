//! The test-source stage: a deterministic synthetic IMU stream, so graphs run end to end without
//! sensors or motion files.
//!
//! Sensor i turns about a fixed unit axis a_i with angle θ_i(t) = A_i sin(2π f_i t + φ_i) and does
//! not translate. Everything it reports follows from that motion, so downstream stages can be
//! checked against it: orientation R_IS = exp(θ_i [a_i]×); angular rate in the sensor frame
//! ω_S = θ̇_i a_i (a rotation about a fixed axis has the same axis in both frames); specific force
//! f_S = R_ISᵀ (a − g) with a = 0 and g = (0, −9.81, 0), i.e. gravity's reaction seen by the sensor.
//! Amplitudes, frequencies and phases come from `seed`.

mod motion;
pub mod stage;

pub use motion::{GRAVITY_MPS2, SensorMotion, rotate_inverse, synthesize};
pub use stage::{SPEC, run};
