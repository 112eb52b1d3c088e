//! Which Unity humanoid bone each SMPL joint drives, and the bones' offsets in Unity axes.
//!
//! VMC names bones by Unity's `HumanBodyBones` enum. imuflow's skeleton has SMPL's 24 joints
//! (`imuflow_body::skeleton`); 22 of them are humanoid bones, and their parents are the same
//! bones' parents in Unity's humanoid hierarchy (Hips → Spine → Chest → UpperChest → Neck → Head;
//! UpperChest → Shoulder → UpperArm → LowerArm → Hand; Hips → UpperLeg → LowerLeg → Foot → Toes),
//! so a local rotation relative to the SMPL parent is one relative to the Unity parent. SMPL's
//! `left_hand`/`right_hand` (22, 23) sit at the knuckles, where a humanoid has finger bones and no
//! bone of its own; their local rotations are identity in every imuflow estimate (the networks do
//! not predict them), so nothing is lost by leaving them out.

use imuflow_body::skeleton::{JointId, Skeleton};

use crate::convert::unity_point;

/// Humanoid bones sent per frame.
pub const NUM_BONES: usize = 22;

/// (SMPL joint, Unity `HumanBodyBones` name), in SMPL order: every bone after its parent.
pub const BONES: [(JointId, &str); NUM_BONES] = [
    (JointId::PELVIS, "Hips"),
    (JointId::LEFT_HIP, "LeftUpperLeg"),
    (JointId::RIGHT_HIP, "RightUpperLeg"),
    (JointId::SPINE1, "Spine"),
    (JointId::LEFT_KNEE, "LeftLowerLeg"),
    (JointId::RIGHT_KNEE, "RightLowerLeg"),
    (JointId::SPINE2, "Chest"),
    (JointId::LEFT_ANKLE, "LeftFoot"),
    (JointId::RIGHT_ANKLE, "RightFoot"),
    (JointId::SPINE3, "UpperChest"),
    (JointId::LEFT_FOOT, "LeftToes"),
    (JointId::RIGHT_FOOT, "RightToes"),
    (JointId::NECK, "Neck"),
    (JointId::LEFT_COLLAR, "LeftShoulder"),
    (JointId::RIGHT_COLLAR, "RightShoulder"),
    (JointId::HEAD, "Head"),
    (JointId::LEFT_SHOULDER, "LeftUpperArm"),
    (JointId::RIGHT_SHOULDER, "RightUpperArm"),
    (JointId::LEFT_ELBOW, "LeftLowerArm"),
    (JointId::RIGHT_ELBOW, "RightLowerArm"),
    (JointId::LEFT_WRIST, "LeftHand"),
    (JointId::RIGHT_WRIST, "RightHand"),
];

/// Each bone's rest offset from its parent in Unity axes (m), in [`BONES`] order; the Hips entry
/// is zero (its position is the root joint's, sent per frame). The body model's offsets are in
/// the parent's frame at rest, which is M because the rest pose (the T-pose) has identity local
/// rotations; so the offset is also the bone's `localPosition` in a Unity rig whose rest pose
/// has identity local rotations.
pub fn unity_offsets_m(skeleton: &Skeleton) -> [[f32; 3]; NUM_BONES] {
    BONES.map(|(joint, _)| {
        let o = skeleton.offset_in_parent_m(joint);
        unity_point([o.x as f32, o.y as f32, o.z as f32])
    })
}

#[cfg(test)]
mod tests {
    use imuflow_body::{BodyModel, BodyParams};

    use super::*;

    #[test]
    fn each_joint_once_in_smpl_order_and_hands_left_out() {
        let joints: Vec<usize> = BONES.iter().map(|(j, _)| j.index()).collect();
        assert_eq!(joints, (0..22).collect::<Vec<_>>());
    }

    /// The Unity parent of each bone (Unity's humanoid hierarchy, written out here by name) is
    /// the bone of the SMPL parent joint.
    #[test]
    fn the_parents_are_unitys() {
        let unity_parent = |name: &str| -> Option<&str> {
            Some(match name {
                "Hips" => return None,
                "Spine" | "LeftUpperLeg" | "RightUpperLeg" => "Hips",
                "Chest" => "Spine",
                "UpperChest" => "Chest",
                "Neck" | "LeftShoulder" | "RightShoulder" => "UpperChest",
                "Head" => "Neck",
                "LeftUpperArm" => "LeftShoulder",
                "RightUpperArm" => "RightShoulder",
                "LeftLowerArm" => "LeftUpperArm",
                "RightLowerArm" => "RightUpperArm",
                "LeftHand" => "LeftLowerArm",
                "RightHand" => "RightLowerArm",
                "LeftLowerLeg" => "LeftUpperLeg",
                "RightLowerLeg" => "RightUpperLeg",
                "LeftFoot" => "LeftLowerLeg",
                "RightFoot" => "RightLowerLeg",
                "LeftToes" => "LeftFoot",
                "RightToes" => "RightFoot",
                other => panic!("not a humanoid bone here: {other}"),
            })
        };
        let name_of = |joint: JointId| BONES.iter().find(|(j, _)| *j == joint).map(|(_, n)| *n);
        for (joint, name) in BONES {
            assert_eq!(
                joint.parent().and_then(name_of),
                unity_parent(name),
                "{name}"
            );
        }
    }

    #[test]
    fn offsets_put_left_limbs_at_unitys_minus_x() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let offsets = unity_offsets_m(&body.skeleton);
        let at = |name: &str| offsets[BONES.iter().position(|(_, n)| *n == name).unwrap()];
        assert_eq!(at("Hips"), [0.0, 0.0, 0.0]);
        assert!(at("LeftUpperLeg")[0] < 0.0 && at("RightUpperLeg")[0] > 0.0);
        assert!(at("LeftLowerArm")[0] < 0.0 && at("RightLowerArm")[0] > 0.0);
        assert!(at("Spine")[1] > 0.0 && at("LeftLowerLeg")[1] < 0.0);
        // Mirror images of each other, and the lengths the body model has.
        assert_eq!(at("LeftLowerArm")[0], -at("RightLowerArm")[0]);
        let upper_arm = body.skeleton.offset_in_parent_m(JointId::LEFT_ELBOW).norm() as f32;
        assert!((at("LeftLowerArm")[0] + upper_arm).abs() < 1e-6);
    }
}
