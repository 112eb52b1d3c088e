//! Per-frame network inputs from calibrated IMU data, one function per method (reference file §2.2 and
//! §2.4: the two methods normalize differently). Shared by the trainer and the stage, so training and
//! inference see the same numbers.
//!
//! Inputs are what a `BodyImuFrame` carries, in the networks' sensor order ([`InputOrder`]: for the
//! six-site set left forearm, right forearm, left lower leg, right lower leg, head, pelvis = root):
//! bone orientations `R_MB` as row-major 3×3, free accelerations and angular velocities in M.
//! Matrices are flattened row-major (reference §0).

use imuflow_body::{Imu, JointId, MAX_SITES, SiteMask};
use imuflow_graph::frames::BodyImuFrame;
use nalgebra::{Quaternion, UnitQuaternion};

/// Index of the root (pelvis) IMU in the six-site set's input: always last (reference §1).
pub const ROOT_IMU: usize = 5;
/// PIP input size for the six-site set: 6 accelerations + 6 orientations (reference §2.2).
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

/// PIP's input size for a set of `sites` sensors: every sensor's acceleration (3) and orientation
/// (9) (reference §2.2, sized by the set).
pub const fn pip_input_len(sites: usize) -> usize {
    12 * sites
}

/// The order in which a set's sensors enter the networks: its sites in wire slot order with the
/// root (pelvis) moved last, as PIP and GlobalPose have it (reference §1). For the six-site set
/// that is the wire order itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputOrder {
    slots: [u8; MAX_SITES],
    len: usize,
}

impl Default for InputOrder {
    fn default() -> InputOrder {
        InputOrder::six()
    }
}

impl InputOrder {
    /// The six-site set's order (wire slots 0..6, the pelvis last).
    pub const fn six() -> InputOrder {
        let mut slots = [0u8; MAX_SITES];
        let mut i = 0;
        while i < 6 {
            slots[i] = i as u8;
            i += 1;
        }
        InputOrder { slots, len: 6 }
    }

    /// The order of a set's `sites`; `None` when it lacks the pelvis (the networks' root).
    pub fn of(sites: SiteMask) -> Option<InputOrder> {
        if !sites.contains(Imu::Pelvis) {
            return None;
        }
        let mut slots = [0u8; MAX_SITES];
        let mut len = 0;
        for site in sites.sites().filter(|&s| s != Imu::Pelvis) {
            slots[len] = site.index() as u8;
            len += 1;
        }
        slots[len] = Imu::Pelvis.index() as u8;
        Some(InputOrder {
            slots,
            len: len + 1,
        })
    }

    /// How many sensors (the root included).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Never: every order holds the root.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The root's input index (the last).
    pub fn root(&self) -> usize {
        self.len - 1
    }

    /// The sites in input order.
    pub fn sites(&self) -> impl Iterator<Item = Imu> + '_ {
        self.slots[..self.len]
            .iter()
            .map(|&s| Imu::CATALOGUE[s as usize])
    }

    /// The site at input index `i`.
    pub fn site(&self, i: usize) -> Imu {
        Imu::CATALOGUE[self.slots[i] as usize]
    }

    /// The set's sites as a mask.
    pub fn mask(&self) -> SiteMask {
        SiteMask::of(self.sites())
    }

    /// The input index of `site`, if the set has it.
    pub fn index_of(&self, site: Imu) -> Option<usize> {
        self.sites().position(|s| s == site)
    }

    /// Whether every site's left–right mirror site is in the set too (test-time mirroring needs
    /// it).
    pub fn is_symmetric(&self) -> bool {
        self.sites().all(|s| self.index_of(s.mirror()).is_some())
    }

    /// Whether the set senses the upper bone of every knee and elbow it observes (the thigh above
    /// a sensed shank, the upper arm above a sensed forearm), so that those joints are measured,
    /// not estimated; never for the six-site set, which senses the forearms and shanks only.
    pub fn measures_every_observed_limb(&self) -> bool {
        let observed = self.mask().observed_joints();
        let sensed = |joint: JointId| self.sites().any(|s| s.joint() == joint);
        let limbs = [
            JointId::LEFT_KNEE,
            JointId::RIGHT_KNEE,
            JointId::LEFT_ELBOW,
            JointId::RIGHT_ELBOW,
        ];
        limbs
            .into_iter()
            .filter(|limb| observed & (1 << limb.index()) != 0)
            .all(|limb| limb.parent().is_some_and(sensed))
    }

    /// Whether this is the six-site set's order.
    pub fn is_six(&self) -> bool {
        *self == InputOrder::six()
    }

    /// The joints whose root-relative positions PIP's first net predicts (its "leaf joints",
    /// reference §2.2): for the six-site set PIP's own (ankles, neck, wrists, in its order); for
    /// another set one per non-root sensor, in input order, the far end of its bone (the
    /// sensed bone's child joint: a thigh's knee, a shank's ankle), or its own joint where the
    /// bone ends the chain (the head).
    pub fn leaf_joints(&self) -> Vec<JointId> {
        if self.is_six() {
            return imuflow_body::skeleton::LEAF_JOINTS.to_vec();
        }
        self.sites()
            .take(self.root())
            .map(|site| {
                let joint = site.joint();
                joint.children().next().unwrap_or(joint)
            })
            .collect()
    }
}

/// One frame of calibrated IMU data, in the networks' sensor order ([`InputOrder`]; entries past
/// its length are unused).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuInput {
    /// `R_MB` per sensor, row-major.
    pub orientation: [Mat3; MAX_SITES],
    /// Free acceleration in M, m/s².
    pub acceleration: [[f32; 3]; MAX_SITES],
    /// Angular velocity in M, rad/s.
    pub angular_velocity: [[f32; 3]; MAX_SITES],
    /// Which sensor each entry is (the six-site set's unless set).
    pub order: InputOrder,
}

impl ImuInput {
    /// An input of the sensors of `order`, all zero.
    pub fn of(order: InputOrder) -> ImuInput {
        ImuInput {
            order,
            ..ImuInput::default()
        }
    }

    /// The root (pelvis) sensor's orientation `R_MB`.
    pub fn root_orientation(&self) -> &Mat3 {
        &self.orientation[self.order.root()]
    }
}

/// The last valid sample of each sensor, as the networks take them: a sensor without a valid,
/// finite sample in a frame keeps its last one.
#[derive(Clone, Copy, Debug, Default)]
pub struct HeldSamples {
    pub input: ImuInput,
    seen: u32,
}

impl HeldSamples {
    /// Samples of the sensors of `order`.
    pub fn of(order: InputOrder) -> HeldSamples {
        HeldSamples {
            input: ImuInput::of(order),
            seen: 0,
        }
    }

    /// Takes the frame's valid, finite samples; true once every sensor has had one.
    pub fn update(&mut self, frame: &BodyImuFrame) -> bool {
        let order = self.input.order;
        for (i, slot) in order.sites().map(Imu::index).enumerate() {
            let q = frame.bone_orientation_wxyz[slot];
            let (a, w) = (
                frame.free_acceleration_mps2[slot],
                frame.angular_velocity_radps[slot],
            );
            let finite = q.iter().chain(&a).chain(&w).all(|v| v.is_finite());
            let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            if frame.valid_mask & (1 << slot) == 0 || !finite || !(0.5..1.5).contains(&norm) {
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
        self.seen == (1 << order.len()) - 1
    }
}

/// PIP's inputs (reference §2.2, TransPose §2.1 layout **without** its /30 scaling), 72 for the
/// six-site set and [`pip_input_len`] for another: `acc_i = R_rootᵀ(a_i − a_root)` for the non-root
/// sensors, `acc_root = R_rootᵀ·a_root`; `ori_i = R_rootᵀ·R_i`, `ori_root = R_root`;
/// `x = [acc 3n, ori 9n]`. `out` has the input's length.
pub fn pip_input(imu: &ImuInput, out: &mut [f32]) {
    let n = imu.order.len();
    assert_eq!(out.len(), pip_input_len(n), "PIP input of {n} sensors");
    let root_index = imu.order.root();
    let root = imu.root_orientation();
    let a_root = imu.acceleration[root_index];
    for i in 0..n {
        let a = if i == root_index {
            a_root
        } else {
            let a = imu.acceleration[i];
            [a[0] - a_root[0], a[1] - a_root[1], a[2] - a_root[2]]
        };
        out[3 * i..3 * i + 3].copy_from_slice(&rt_mul_vec(root, &a));
        let ori = if i == root_index {
            *root
        } else {
            rt_mul(root, &imu.orientation[i])
        };
        out[3 * n + 9 * i..3 * n + 9 * i + 9].copy_from_slice(&ori);
    }
}

/// GlobalPose's 84 inputs (reference §2.4, no scaling): `aRB_i = R_rootᵀa_i` and `wRB_i = R_rootᵀω_i`
/// for all six sensors, `RRB_i = R_rootᵀR_i` for the five non-root sensors, and
/// `gR0 = −(row 1 of R_root)`, the world down-vector in the root frame. The six-site set's only.
pub fn globalpose_input(imu: &ImuInput, out: &mut [f32; GLOBALPOSE_INPUT]) {
    debug_assert!(
        imu.order.is_six(),
        "GlobalPose's input is the six-site set's"
    );
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

    fn lower_body() -> InputOrder {
        let legs = [
            Imu::Pelvis,
            Imu::LeftLowerLeg,
            Imu::RightLowerLeg,
            Imu::LeftUpperLeg,
            Imu::RightUpperLeg,
        ];
        InputOrder::of(SiteMask::of(legs)).expect("the pelvis is there")
    }

    #[test]
    fn a_sets_sensors_enter_in_wire_order_with_the_pelvis_last() {
        assert_eq!(
            InputOrder::of(SiteMask::of(Imu::SIX)),
            Some(InputOrder::six())
        );
        let legs = lower_body();
        let names: Vec<&str> = legs.sites().map(Imu::name).collect();
        assert_eq!(
            names,
            [
                "left_lower_leg",
                "right_lower_leg",
                "left_upper_leg",
                "right_upper_leg",
                "pelvis"
            ]
        );
        assert_eq!(legs.root(), 4);
        assert!(legs.is_symmetric() && !legs.is_six());
        // The thighs above the shanks are sensed: the knees are measured; the six's are not.
        assert!(legs.measures_every_observed_limb());
        assert!(!InputOrder::six().measures_every_observed_limb());
        // A shank's leaf is its ankle, a thigh's its knee (SMPL: ankles 7/8, knees 4/5); the six
        // keep PIP's own (ankles, neck, wrists).
        assert_eq!(
            legs.leaf_joints(),
            [
                JointId::LEFT_ANKLE,
                JointId::RIGHT_ANKLE,
                JointId::LEFT_KNEE,
                JointId::RIGHT_KNEE
            ]
        );
        assert_eq!(
            InputOrder::six().leaf_joints(),
            imuflow_body::skeleton::LEAF_JOINTS
        );
        // Without the pelvis there is no root; one leg alone is not symmetric.
        assert_eq!(InputOrder::of(SiteMask::of([Imu::LeftLowerLeg])), None);
        let one_leg = InputOrder::of(SiteMask::of([Imu::Pelvis, Imu::LeftLowerLeg])).unwrap();
        assert!(!one_leg.is_symmetric());
    }

    /// PIP's input for a set has the six-site layout sized by the set: every sensor's
    /// acceleration (the non-root ones relative to the root's) then every orientation, all in
    /// the root's frame, the root's own last in each block.
    #[test]
    fn pip_features_of_a_set_follow_the_six_site_layout() {
        let six = sample();
        let mut legs = ImuInput::of(lower_body());
        for i in 0..5 {
            legs.orientation[i] = six.orientation[i + 1];
            legs.acceleration[i] = six.acceleration[i + 1];
        }
        let mut x = vec![0.0; pip_input_len(5)];
        pip_input(&legs, &mut x);
        assert_eq!(x.len(), 60);
        let root = &legs.orientation[4];
        let a = legs.acceleration;
        let rel = [a[1][0] - a[4][0], a[1][1] - a[4][1], a[1][2] - a[4][2]];
        let want = rt_mul_vec(root, &rel);
        for k in 0..3 {
            assert!((x[3 + k] - want[k]).abs() < 1e-6);
            assert!((x[12 + k] - rt_mul_vec(root, &a[4])[k]).abs() < 1e-6);
        }
        let ori = rt_mul(root, &legs.orientation[2]);
        for k in 0..9 {
            assert!((x[15 + 18 + k] - ori[k]).abs() < 1e-6);
            assert!((x[15 + 36 + k] - root[k]).abs() < 1e-6);
        }
    }
}
