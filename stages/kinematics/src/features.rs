//! Per-frame network inputs from calibrated IMU data, one function per method (reference file §2.2 and
//! §2.4: the two methods normalize differently). Shared by the trainer and the stage, so training and
//! inference see the same numbers.
//!
//! Inputs are what a `BodyImuFrame` carries, in IMU order (left forearm, right forearm, left lower leg,
//! right lower leg, head, pelvis = root): bone orientations `R_MB` as row-major 3×3, free accelerations
//! and angular velocities in M. Matrices are flattened row-major (reference §0).

use imuflow_body::NUM_IMUS;
use imuflow_graph::frames::BodyImuFrame;
use nalgebra::{Quaternion, UnitQuaternion};

/// Index of the root (pelvis) IMU: always last (reference §1).
pub const ROOT_IMU: usize = 5;
/// PIP input size: 6 accelerations + 6 orientations (reference §2.2).
pub const PIP_INPUT: usize = 72;
/// GlobalPose input size: [aRB 18, wRB 18, RRB 45, gR0 3] (reference §2.4).
pub const GLOBALPOSE_INPUT: usize = 84;
/// Frame rate of the shards and the networks (reference §0).
pub const FPS: f32 = 60.0;
/// PIP's joint velocities are predicted divided by this (reference §2.2, `vel_scale = 3`).
pub const PIP_VELOCITY_SCALE: f32 = 3.0;

/// Row-major 3×3.
pub type Mat3 = [f32; 9];

/// `Rᵀ·v`.
pub fn rt_mul_vec(r: &Mat3, v: &[f32; 3]) -> [f32; 3] {
    [
        r[0] * v[0] + r[3] * v[1] + r[6] * v[2],
        r[1] * v[0] + r[4] * v[1] + r[7] * v[2],
        r[2] * v[0] + r[5] * v[1] + r[8] * v[2],
    ]
}

/// `R·v`.
pub fn mul_vec(r: &Mat3, v: &[f32; 3]) -> [f32; 3] {
    [
        r[0] * v[0] + r[1] * v[1] + r[2] * v[2],
        r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
        r[6] * v[0] + r[7] * v[1] + r[8] * v[2],
    ]
}

/// `Aᵀ·B`.
pub fn rt_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[r * 3 + c] = (0..3).map(|k| a[k * 3 + r] * b[k * 3 + c]).sum();
        }
    }
    out
}

/// `A·B`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[r * 3 + c] = (0..3).map(|k| a[r * 3 + k] * b[k * 3 + c]).sum();
        }
    }
    out
}

/// One frame of calibrated IMU data.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuInput {
    /// `R_MB` per sensor, row-major.
    pub orientation: [Mat3; 6],
    /// Free acceleration in M, m/s².
    pub acceleration: [[f32; 3]; 6],
    /// Angular velocity in M, rad/s.
    pub angular_velocity: [[f32; 3]; 6],
}

/// The last valid sample of each sensor, as the networks take them: a sensor without a valid,
/// finite sample in a frame keeps its last one.
#[derive(Clone, Copy, Debug, Default)]
pub struct HeldSamples {
    pub input: ImuInput,
    seen: u32,
}

impl HeldSamples {
    /// Takes the frame's valid, finite samples; true once every sensor has had one.
    pub fn update(&mut self, frame: &BodyImuFrame) -> bool {
        for i in 0..NUM_IMUS {
            let q = frame.bone_orientation_wxyz[i];
            let (a, w) = (
                frame.free_acceleration_mps2[i],
                frame.angular_velocity_radps[i],
            );
            let finite = q.iter().chain(&a).chain(&w).all(|v| v.is_finite());
            let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            if frame.valid_mask & (1 << i) == 0 || !finite || !(0.5..1.5).contains(&norm) {
                continue;
            }
            let r = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
                .to_rotation_matrix();
            let m = r.matrix();
            for row in 0..3 {
                for col in 0..3 {
                    self.input.orientation[i][row * 3 + col] = m[(row, col)];
                }
            }
            self.input.acceleration[i] = a;
            self.input.angular_velocity[i] = w;
            self.seen |= 1 << i;
        }
        self.seen == (1 << NUM_IMUS) - 1
    }
}

/// PIP's 72 inputs (reference §2.2, TransPose §2.1 layout **without** its /30 scaling):
/// `acc_i = R_rootᵀ(a_i − a_root)` for the five non-root sensors, `acc_5 = R_rootᵀ·a_root`;
/// `ori_i = R_rootᵀ·R_i`, `ori_5 = R_root`; `x = [acc 18, ori 54]`.
pub fn pip_input(imu: &ImuInput, out: &mut [f32; PIP_INPUT]) {
    let root = &imu.orientation[ROOT_IMU];
    let a_root = imu.acceleration[ROOT_IMU];
    for i in 0..6 {
        let a = if i == ROOT_IMU {
            a_root
        } else {
            let a = imu.acceleration[i];
            [a[0] - a_root[0], a[1] - a_root[1], a[2] - a_root[2]]
        };
        out[3 * i..3 * i + 3].copy_from_slice(&rt_mul_vec(root, &a));
        let ori = if i == ROOT_IMU {
            *root
        } else {
            rt_mul(root, &imu.orientation[i])
        };
        out[18 + 9 * i..18 + 9 * i + 9].copy_from_slice(&ori);
    }
}

/// GlobalPose's 84 inputs (reference §2.4, no scaling): `aRB_i = R_rootᵀa_i` and `wRB_i = R_rootᵀω_i`
/// for all six sensors, `RRB_i = R_rootᵀR_i` for the five non-root sensors, and
/// `gR0 = −(row 1 of R_root)`, the world down-vector in the root frame.
pub fn globalpose_input(imu: &ImuInput, out: &mut [f32; GLOBALPOSE_INPUT]) {
    let root = &imu.orientation[ROOT_IMU];
    for i in 0..6 {
        out[3 * i..3 * i + 3].copy_from_slice(&rt_mul_vec(root, &imu.acceleration[i]));
        out[18 + 3 * i..18 + 3 * i + 3]
            .copy_from_slice(&rt_mul_vec(root, &imu.angular_velocity[i]));
    }
    for i in 0..5 {
        out[36 + 9 * i..36 + 9 * i + 9].copy_from_slice(&rt_mul(root, &imu.orientation[i]));
    }
    out[81..84].copy_from_slice(&[-root[3], -root[4], -root[5]]);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot_y(angle: f32) -> Mat3 {
        let (s, c) = angle.sin_cos();
        [c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c]
    }

    fn rot_x(angle: f32) -> Mat3 {
        let (s, c) = angle.sin_cos();
        [1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c]
    }

    fn sample() -> ImuInput {
        let mut imu = ImuInput::default();
        for i in 0..6 {
            imu.orientation[i] = mul(&rot_y(0.3 * i as f32), &rot_x(0.1 * i as f32));
            imu.acceleration[i] = [i as f32, 1.0 - i as f32, 0.5 * i as f32];
            imu.angular_velocity[i] = [0.2 * i as f32, 0.1, -0.3];
        }
        imu
    }

    /// Turning the whole subject (every sensor and every world vector) about the vertical leaves the
    /// root-relative PIP features unchanged except the root's own absolute orientation.
    #[test]
    fn pip_features_are_root_relative() {
        let imu = sample();
        let turn = rot_y(1.1);
        let mut turned = imu;
        for i in 0..6 {
            turned.orientation[i] = mul(&turn, &imu.orientation[i]);
            turned.acceleration[i] = mul_vec(&turn, &imu.acceleration[i]);
        }
        let (mut a, mut b) = ([0.0; PIP_INPUT], [0.0; PIP_INPUT]);
        pip_input(&imu, &mut a);
        pip_input(&turned, &mut b);
        for k in 0..18 + 45 {
            assert!(
                (a[k] - b[k]).abs() < 1e-5,
                "feature {k}: {} vs {}",
                a[k],
                b[k]
            );
        }
        // The root orientation block is absolute: it must change.
        assert!((63..72).any(|k| (a[k] - b[k]).abs() > 0.1));
        // Hand check of one acceleration: sensor 0 minus root, in the root frame.
        let rel = [0.0 - 5.0, 1.0 - (-4.0), 0.0 - 2.5];
        let want = rt_mul_vec(&imu.orientation[5], &rel);
        assert!((a[0] - want[0]).abs() < 1e-6 && (a[2] - want[2]).abs() < 1e-6);
    }

    /// gR0 is the world down-vector seen from the root: rotating it back with R_root gives (0, −1, 0).
    #[test]
    fn globalpose_gravity_is_down_in_root_frame() {
        let imu = sample();
        let mut x = [0.0; GLOBALPOSE_INPUT];
        globalpose_input(&imu, &mut x);
        let g = [x[81], x[82], x[83]];
        let world = mul_vec(&imu.orientation[5], &g);
        assert!(world[0].abs() < 1e-6 && (world[1] + 1.0).abs() < 1e-6 && world[2].abs() < 1e-6);
        // Root angular velocity back in M.
        let w = mul_vec(&imu.orientation[5], &[x[33], x[34], x[35]]);
        for (got, want) in w.iter().zip(&imu.angular_velocity[5]) {
            assert!((got - want).abs() < 1e-5);
        }
    }
}
