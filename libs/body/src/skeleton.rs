//! The 24-joint SMPL topology: joint handles, names, parents, joint sets and IMU placement joints.
//!
//! Topology, joint order and joint sets follow SMPL's kinematic tree as used by TransPose/PIP/GlobalPose
//! (shared/reference/original-implementations.md §1). Geometry (bone lengths) lives in [`crate::body_model`].

use std::fmt;

use nalgebra::Vector3;

/// Number of joints in the skeleton (SMPL's 24).
pub const NUM_JOINTS: usize = 24;

/// Sites of the six-site set (PIP's and GlobalPose's sensors): the first six slots of the wire.
pub const NUM_IMUS: usize = 6;

/// Sites of the site catalogue ([`Imu::CATALOGUE`]): the slots of every IMU frame, enough for a
/// full suit.
pub const MAX_SITES: usize = 17;

/// Handle to one of the 24 joints. Only valid handles can be constructed (the constants below or
/// [`JointId::from_index`] / [`JointId::from_name`]), so indexing a `[T; NUM_JOINTS]` with
/// [`JointId::index`] never goes out of bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(transparent)]
pub struct JointId(u8);

const NAMES: [&str; NUM_JOINTS] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
];

/// SMPL parent array (reference §1); -1 marks the root.
const PARENT_INDEX: [i8; NUM_JOINTS] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
];

impl JointId {
    pub const PELVIS: JointId = JointId(0);
    pub const LEFT_HIP: JointId = JointId(1);
    pub const RIGHT_HIP: JointId = JointId(2);
    pub const SPINE1: JointId = JointId(3);
    pub const LEFT_KNEE: JointId = JointId(4);
    pub const RIGHT_KNEE: JointId = JointId(5);
    pub const SPINE2: JointId = JointId(6);
    pub const LEFT_ANKLE: JointId = JointId(7);
    pub const RIGHT_ANKLE: JointId = JointId(8);
    pub const SPINE3: JointId = JointId(9);
    pub const LEFT_FOOT: JointId = JointId(10);
    pub const RIGHT_FOOT: JointId = JointId(11);
    pub const NECK: JointId = JointId(12);
    pub const LEFT_COLLAR: JointId = JointId(13);
    pub const RIGHT_COLLAR: JointId = JointId(14);
    pub const HEAD: JointId = JointId(15);
    pub const LEFT_SHOULDER: JointId = JointId(16);
    pub const RIGHT_SHOULDER: JointId = JointId(17);
    pub const LEFT_ELBOW: JointId = JointId(18);
    pub const RIGHT_ELBOW: JointId = JointId(19);
    pub const LEFT_WRIST: JointId = JointId(20);
    pub const RIGHT_WRIST: JointId = JointId(21);
    pub const LEFT_HAND: JointId = JointId(22);
    pub const RIGHT_HAND: JointId = JointId(23);

    /// The root joint (pelvis); its global transform is the body's placement in the world.
    pub const ROOT: JointId = JointId::PELVIS;

    /// Index into per-joint arrays, in SMPL order (0..24).
    pub const fn index(self) -> usize {
        self.0 as usize
    }

    /// Handle for an SMPL joint index, `None` when `index >= 24`.
    pub const fn from_index(index: usize) -> Option<JointId> {
        if index < NUM_JOINTS {
            Some(JointId(index as u8))
        } else {
            None
        }
    }

    /// Handle for a joint name as returned by [`JointId::name`] (e.g. `"left_elbow"`).
    pub fn from_name(name: &str) -> Option<JointId> {
        NAMES
            .iter()
            .position(|n| *n == name)
            .and_then(JointId::from_index)
    }

    /// Lower-case snake_case joint name (`"pelvis"`, `"left_hip"`, ...).
    pub const fn name(self) -> &'static str {
        NAMES[self.0 as usize]
    }

    /// Parent joint, `None` for the root.
    pub const fn parent(self) -> Option<JointId> {
        let p = PARENT_INDEX[self.0 as usize];
        if p < 0 { None } else { Some(JointId(p as u8)) }
    }

    /// Children of this joint, in index order.
    pub fn children(self) -> impl Iterator<Item = JointId> {
        JointId::all().filter(move |j| j.parent() == Some(self))
    }

    /// The joint on the other side of the body (itself on the midline): the left–right mirror
    /// image across the sagittal plane (x → −x in the model frame, x being the body's left).
    pub const fn mirror(self) -> JointId {
        // SMPL pairs: hips 1/2, knees 4/5, ankles 7/8, feet 10/11, collars 13/14, shoulders
        // 16/17, elbows 18/19, wrists 20/21, hands 22/23.
        match self.0 {
            1 | 4 | 7 | 10 | 13 | 16 | 18 | 20 | 22 => JointId(self.0 + 1),
            2 | 5 | 8 | 11 | 14 | 17 | 19 | 21 | 23 => JointId(self.0 - 1),
            _ => self,
        }
    }

    /// All 24 joints in SMPL order; every joint comes after its parent.
    pub fn all() -> impl DoubleEndedIterator<Item = JointId> + ExactSizeIterator {
        (0..NUM_JOINTS as u8).map(JointId)
    }

    /// Whether `self` lies on the path from `ancestor` down to the leaves (a joint is its own descendant).
    pub fn is_descendant_of(self, ancestor: JointId) -> bool {
        let mut j = Some(self);
        while let Some(k) = j {
            if k == ancestor {
                return true;
            }
            j = k.parent();
        }
        false
    }
}

/// Every joint, as a mask over joint indices (bit i: joint i).
pub const ALL_JOINTS: u32 = (1 << NUM_JOINTS) - 1;

/// The joints of `mask` (over joint indices) whose every ancestor is in it too, and the root: the
/// tree a pose holding `mask`'s joints is exported and drawn as (a sensor set's observed joints
/// are such a tree already).
pub fn joint_tree(mask: u32) -> u32 {
    // Parents come before their children in `JointId::all()`.
    JointId::all().fold(0, |tree, j| {
        let bit = 1 << j.index();
        match j.parent() {
            None => tree | bit,
            Some(p) if tree & (1 << p.index()) != 0 && mask & bit != 0 => tree | bit,
            Some(_) => tree,
        }
    })
}

/// Where the bone that `joint` turns ends when none of its children is in `tree` (a mask over
/// joint indices): its first child, so that a knee's shank reaches the ankle. `None` when a child
/// is in the tree or the joint has none.
pub fn cut_bone_end(joint: JointId, tree: u32) -> Option<JointId> {
    if joint.children().any(|c| tree & (1 << c.index()) != 0) {
        return None;
    }
    joint.children().next()
}

impl fmt::Display for JointId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

const fn ids<const N: usize>(idx: [u8; N]) -> [JointId; N] {
    let mut out = [JointId(0); N];
    let mut i = 0;
    while i < N {
        out[i] = JointId(idx[i]);
        i += 1;
    }
    out
}

/// Leaf joints whose positions PIP/TransPose predict first: L/R ankle, neck (not head), L/R wrist (reference §1).
pub const LEAF_JOINTS: [JointId; 5] = ids([7, 8, 12, 20, 21]);

/// All joints but the root (reference §1, "full").
pub const FULL_JOINTS: [JointId; 23] = ids([
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23,
]);

/// Joints whose local rotations the networks predict (reference §1, "reduced").
pub const REDUCED_JOINTS: [JointId; 15] =
    ids([1, 2, 3, 4, 5, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19]);

/// Joints whose local rotations are forced to identity (reference §1, "ignored"; the root is then
/// overwritten by the pelvis IMU orientation).
pub const IGNORED_JOINTS: [JointId; 9] = ids([0, 7, 8, 10, 11, 20, 21, 22, 23]);

/// Joints of the SIP evaluation metric: hips and shoulders (reference §1/§6).
pub const SIP_JOINTS: [JointId; 4] = ids([1, 2, 16, 17]);

/// GlobalPose contact ("stationary") joints: pelvis, L/R foot, L/R hand (reference §1).
pub const CONTACT_JOINTS: [JointId; 5] = ids([0, 10, 11, 22, 23]);

/// One sensor site of the site catalogue: a place on the body model where an IMU can be worn, named
/// by the bone it rides. The catalogue's order is the wire's slot order: every IMU frame has one
/// slot per site ([`MAX_SITES`]), and a sensor set ([`crate::sensor_set`]) fills some of them. The
/// first six are the six-site set of PIP and GlobalPose, in the order they have always had.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Imu {
    LeftForearm = 0,
    RightForearm = 1,
    LeftLowerLeg = 2,
    RightLowerLeg = 3,
    Head = 4,
    Pelvis = 5,
    LeftUpperLeg = 6,
    RightUpperLeg = 7,
    LeftFoot = 8,
    RightFoot = 9,
    Sternum = 10,
    LeftShoulder = 11,
    RightShoulder = 12,
    LeftUpperArm = 13,
    RightUpperArm = 14,
    LeftHand = 15,
    RightHand = 16,
}

impl Imu {
    /// The six-site set's IMUs in wire order: [left forearm, right forearm, left lower leg, right
    /// lower leg, head, pelvis] (PIP's and GlobalPose's sensors; wire slots 0..6).
    pub const SIX: [Imu; NUM_IMUS] = {
        // The catalogue's first six.
        let mut six = [Imu::Pelvis; NUM_IMUS];
        let mut i = 0;
        while i < NUM_IMUS {
            six[i] = Imu::CATALOGUE[i];
            i += 1;
        }
        six
    };

    /// Every site of the catalogue, in wire slot order.
    pub const CATALOGUE: [Imu; MAX_SITES] = [
        Imu::LeftForearm,
        Imu::RightForearm,
        Imu::LeftLowerLeg,
        Imu::RightLowerLeg,
        Imu::Head,
        Imu::Pelvis,
        Imu::LeftUpperLeg,
        Imu::RightUpperLeg,
        Imu::LeftFoot,
        Imu::RightFoot,
        Imu::Sternum,
        Imu::LeftShoulder,
        Imu::RightShoulder,
        Imu::LeftUpperArm,
        Imu::RightUpperArm,
        Imu::LeftHand,
        Imu::RightHand,
    ];

    /// Wire slot (0..[`MAX_SITES`]).
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The site in wire slot `index`, if there is one.
    pub fn from_index(index: usize) -> Option<Imu> {
        Imu::CATALOGUE.get(index).copied()
    }

    /// The site named `name` ([`Imu::name`]), if there is one.
    pub fn from_name(name: &str) -> Option<Imu> {
        Imu::CATALOGUE.into_iter().find(|imu| imu.name() == name)
    }

    /// The IMU on the other side of the body (itself on the midline; see [`JointId::mirror`]).
    pub const fn mirror(self) -> Imu {
        match self {
            Imu::LeftForearm => Imu::RightForearm,
            Imu::RightForearm => Imu::LeftForearm,
            Imu::LeftLowerLeg => Imu::RightLowerLeg,
            Imu::RightLowerLeg => Imu::LeftLowerLeg,
            Imu::Head => Imu::Head,
            Imu::Pelvis => Imu::Pelvis,
            Imu::LeftUpperLeg => Imu::RightUpperLeg,
            Imu::RightUpperLeg => Imu::LeftUpperLeg,
            Imu::LeftFoot => Imu::RightFoot,
            Imu::RightFoot => Imu::LeftFoot,
            Imu::Sternum => Imu::Sternum,
            Imu::LeftShoulder => Imu::RightShoulder,
            Imu::RightShoulder => Imu::LeftShoulder,
            Imu::LeftUpperArm => Imu::RightUpperArm,
            Imu::RightUpperArm => Imu::LeftUpperArm,
            Imu::LeftHand => Imu::RightHand,
            Imu::RightHand => Imu::LeftHand,
        }
    }

    /// The joint whose global rotation is this IMU's bone orientation (the six: reference §1,
    /// joints 18, 19, 4, 5, 15, 0; the others the same way: the joint at the bone's proximal end).
    pub const fn joint(self) -> JointId {
        SITE_JOINTS[self as usize]
    }

    /// Every site's [`Imu::name`], in wire slot order: the site names of sensor files, tracker
    /// maps, calibration files, sensor sets and logs.
    pub const NAMES: [&'static str; MAX_SITES] = {
        let mut names = [""; MAX_SITES];
        let mut i = 0;
        while i < MAX_SITES {
            names[i] = Imu::CATALOGUE[i].name();
            i += 1;
        }
        names
    };

    /// Lower-case snake_case name, also the key in models/body.toml.
    pub const fn name(self) -> &'static str {
        match self {
            Imu::LeftForearm => "left_forearm",
            Imu::RightForearm => "right_forearm",
            Imu::LeftLowerLeg => "left_lower_leg",
            Imu::RightLowerLeg => "right_lower_leg",
            Imu::Head => "head",
            Imu::Pelvis => "pelvis",
            Imu::LeftUpperLeg => "left_upper_leg",
            Imu::RightUpperLeg => "right_upper_leg",
            Imu::LeftFoot => "left_foot",
            Imu::RightFoot => "right_foot",
            Imu::Sternum => "sternum",
            Imu::LeftShoulder => "left_shoulder",
            Imu::RightShoulder => "right_shoulder",
            Imu::LeftUpperArm => "left_upper_arm",
            Imu::RightUpperArm => "right_upper_arm",
            Imu::LeftHand => "left_hand",
            Imu::RightHand => "right_hand",
        }
    }
}

/// The name of the site in wire slot `slot` ([`Imu::name`]), or "unknown" past the catalogue: for
/// logs and messages that name a slot.
pub fn site_name(slot: usize) -> &'static str {
    Imu::from_index(slot).map_or("unknown", Imu::name)
}

impl fmt::Display for Imu {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Bone (joint) carrying each site, in wire slot order: L elbow, R elbow, L knee, R knee, head,
/// pelvis (the six-site set, reference §1), then L hip, R hip (thighs), L ankle, R ankle (feet),
/// spine3 (chest), L collar, R collar (shoulders), L shoulder, R shoulder (upper arms), L wrist,
/// R wrist (hands).
const SITE_JOINTS: [JointId; MAX_SITES] =
    ids([18, 19, 4, 5, 15, 0, 1, 2, 7, 8, 9, 13, 14, 16, 17, 20, 21]);

/// Bone (joint) carrying each IMU of the six-site set, in its order: L elbow, R elbow, L knee,
/// R knee, head, pelvis (reference §1).
pub const IMU_JOINTS: [JointId; NUM_IMUS] = ids([18, 19, 4, 5, 15, 0]);

/// Skeleton geometry: the rest (T-pose) offset of every joint from its parent. Immutable model data;
/// per-frame state lives in [`crate::kinematics::FkData`].
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    /// Bone vector from the parent joint to this joint (m), in the parent's frame at rest, which equals
    /// the model frame M because rest local rotations are identity (T-pose). The root's entry is zero.
    offsets_in_parent_m: [Vector3<f64>; NUM_JOINTS],
}

impl Skeleton {
    /// Build from rest offsets (m, model frame M, T-pose). The root offset is ignored (set to zero).
    pub fn from_offsets(mut offsets_in_parent_m: [Vector3<f64>; NUM_JOINTS]) -> Skeleton {
        offsets_in_parent_m[JointId::ROOT.index()] = Vector3::zeros();
        Skeleton {
            offsets_in_parent_m,
        }
    }

    /// Rest offset of `joint` from its parent (m, parent frame = M at rest); zero for the root.
    pub fn offset_in_parent_m(&self, joint: JointId) -> &Vector3<f64> {
        &self.offsets_in_parent_m[joint.index()]
    }

    /// All rest offsets, indexed by [`JointId::index`].
    pub fn offsets_in_parent_m(&self) -> &[Vector3<f64>; NUM_JOINTS] {
        &self.offsets_in_parent_m
    }

    /// Rest (T-pose) joint positions relative to the root joint (m, model frame M).
    pub fn rest_positions_from_root_m(&self) -> [Vector3<f64>; NUM_JOINTS] {
        let mut p = [Vector3::zeros(); NUM_JOINTS];
        for j in JointId::all() {
            if let Some(parent) = j.parent() {
                p[j.index()] = p[parent.index()] + self.offsets_in_parent_m[j.index()];
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joint_tree_keeps_the_chains_from_the_root_and_cut_bones_end_at_their_first_child() {
        let bit = |j: JointId| 1u32 << j.index();
        // The left knee without its hip, and the right hip and knee: the left knee is dropped
        // (its parent is not in the tree), the root is always in it.
        let mask = bit(JointId::LEFT_KNEE) | bit(JointId::RIGHT_HIP) | bit(JointId::RIGHT_KNEE);
        let tree = joint_tree(mask);
        assert_eq!(
            tree,
            bit(JointId::ROOT) | bit(JointId::RIGHT_HIP) | bit(JointId::RIGHT_KNEE)
        );
        assert_eq!(joint_tree(ALL_JOINTS), ALL_JOINTS);
        // The right knee's shank ends at the ankle; the pelvis has a child in the tree; a hand
        // has no child.
        assert_eq!(
            cut_bone_end(JointId::RIGHT_KNEE, tree),
            Some(JointId::RIGHT_ANKLE)
        );
        assert_eq!(cut_bone_end(JointId::ROOT, tree), None);
        assert_eq!(cut_bone_end(JointId::LEFT_HAND, tree), None);
    }

    #[test]
    fn the_catalogue_is_in_slot_order_and_starts_with_the_six() {
        for (slot, imu) in Imu::CATALOGUE.into_iter().enumerate() {
            assert_eq!(imu.index(), slot);
            assert_eq!(Imu::from_index(slot), Some(imu));
            assert_eq!(Imu::from_name(imu.name()), Some(imu));
            assert_eq!(Imu::NAMES[slot], imu.name());
        }
        assert_eq!(Imu::CATALOGUE[..NUM_IMUS], Imu::SIX);
        assert_eq!(Imu::SIX.map(Imu::joint), IMU_JOINTS);
        assert_eq!(Imu::from_index(MAX_SITES), None);
        assert_eq!(Imu::from_name("left_thigh"), None);
        // One site per bone: two sensors on one bone would need two slots for one orientation.
        let mut joints: Vec<JointId> = Imu::CATALOGUE.iter().map(|i| i.joint()).collect();
        joints.sort();
        joints.dedup();
        assert_eq!(joints.len(), MAX_SITES);
    }

    /// `name` with left and right swapped.
    fn other_side(name: &str) -> String {
        name.replace("left", "@")
            .replace("right", "left")
            .replace('@', "right")
    }

    #[test]
    fn the_mirror_maps_pair_left_and_right() {
        assert_eq!(JointId::LEFT_ELBOW.mirror(), JointId::RIGHT_ELBOW);
        assert_eq!(JointId::RIGHT_HAND.mirror(), JointId::LEFT_HAND);
        assert_eq!(JointId::HEAD.mirror(), JointId::HEAD);
        for j in JointId::all() {
            assert_eq!(j.mirror().mirror(), j);
            assert_eq!(j.mirror().name(), other_side(j.name()));
        }
        for imu in Imu::CATALOGUE {
            assert_eq!(imu.mirror().joint(), imu.joint().mirror(), "{}", imu.name());
            assert_eq!(imu.mirror().mirror(), imu);
            assert_eq!(imu.mirror().name(), other_side(imu.name()));
        }
    }

    #[test]
    fn parents_match_the_smpl_array_and_precede_children() {
        let expected: [i32; 24] = [
            -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
        ];
        for j in JointId::all() {
            let p = j.parent().map_or(-1, |p| p.index() as i32);
            assert_eq!(p, expected[j.index()], "{j}");
            assert!(p < j.index() as i32, "parent after child at {j}");
        }
    }

    #[test]
    fn names_round_trip_and_are_unique() {
        for j in JointId::all() {
            assert_eq!(JointId::from_name(j.name()), Some(j));
        }
        assert_eq!(JointId::from_name("nope"), None);
        assert_eq!(JointId::from_index(24), None);
        assert_eq!(JointId::LEFT_ELBOW.name(), "left_elbow");
    }

    #[test]
    fn joint_sets_partition_as_in_the_reference() {
        // reduced and ignored are disjoint and together cover all joints.
        let mut seen = [0u8; NUM_JOINTS];
        for j in REDUCED_JOINTS.iter().chain(IGNORED_JOINTS.iter()) {
            seen[j.index()] += 1;
        }
        assert!(seen.iter().all(|&c| c == 1), "{seen:?}");
        assert_eq!(FULL_JOINTS.len(), 23);
        assert!(!FULL_JOINTS.contains(&JointId::ROOT));
        assert_eq!(LEAF_JOINTS[2], JointId::NECK);
    }

    #[test]
    fn imu_joints_follow_the_wire_order() {
        assert_eq!(Imu::LeftForearm.joint(), JointId::LEFT_ELBOW);
        assert_eq!(Imu::RightLowerLeg.joint(), JointId::RIGHT_KNEE);
        assert_eq!(Imu::Pelvis.joint(), JointId::PELVIS);
        assert_eq!(Imu::SIX.map(|i| i.index()), [0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn children_and_descendants() {
        let c: Vec<_> = JointId::SPINE3.children().collect();
        assert_eq!(
            c,
            vec![JointId::NECK, JointId::LEFT_COLLAR, JointId::RIGHT_COLLAR]
        );
        assert!(JointId::LEFT_HAND.is_descendant_of(JointId::SPINE1));
        assert!(!JointId::LEFT_HAND.is_descendant_of(JointId::LEFT_HIP));
    }
}
