//! What the calibration must be told: the inertial-frame convention of the sensors and the pose the
//! subject holds while standing.

use imuflow_body::rotation::Axis;
use nalgebra::Rotation3;

use imuflow_body::{Imu, MAX_SITES};

pub use imuflow_body::inertial::InertialFrame;

/// The pose held while the calibration reads the sensors: each IMU bone's `R_MB` is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ReferencePose {
    /// T-pose: arms horizontal to the sides; every bone's `R_MB` is the identity (reference §4).
    #[serde(rename = "t")]
    T,
    /// N-pose: standing straight, arms hanging down; forearms `R_z(∓90°)` (and upper arms and
    /// hands with them), everything else the identity (GlobalPose's N-pose, reference §4).
    #[serde(rename = "n")]
    N,
    /// Relaxed N-pose: arms hanging with the elbows bent [`RELAXED_ELBOW_DEG`] (hands forward),
    /// how people stand when not told to straighten their arms.
    #[serde(rename = "relaxed")]
    Relaxed,
}

/// Elbow flexion of the relaxed pose, deg (people standing at ease).
pub use imuflow_body::limb_joints::RELAXED_ELBOW_DEG;

impl ReferencePose {
    /// Parses `t` or `n`.
    pub fn parse(name: &str) -> Option<ReferencePose> {
        match name {
            "t" => Some(ReferencePose::T),
            "n" => Some(ReferencePose::N),
            "relaxed" => Some(ReferencePose::Relaxed),
            _ => None,
        }
    }

    /// The pose's name.
    pub fn name(self) -> &'static str {
        match self {
            ReferencePose::T => "t",
            ReferencePose::N => "n",
            ReferencePose::Relaxed => "relaxed",
        }
    }

    /// `R_MB` of each site's bone (by wire slot) in this pose, facing +z.
    pub fn bone_orientations(self) -> [Rotation3<f64>; MAX_SITES] {
        let mut r = [Rotation3::identity(); MAX_SITES];
        let (left_arm, right_arm) = (
            [Imu::LeftUpperArm, Imu::LeftForearm, Imu::LeftHand],
            [Imu::RightUpperArm, Imu::RightForearm, Imu::RightHand],
        );
        if self != ReferencePose::T {
            // Left arm: the bones' x axis (along the arm, pointing left) turns down.
            for bone in left_arm {
                r[bone.index()] = Axis::Z.rotation(-std::f64::consts::FRAC_PI_2);
            }
            for bone in right_arm {
                r[bone.index()] = Axis::Z.rotation(std::f64::consts::FRAC_PI_2);
            }
        }
        if self == ReferencePose::Relaxed {
            // Bent elbows bring the forearms and hands forward: a turn about M's left axis (x).
            let bend = Axis::X.rotation(-RELAXED_ELBOW_DEG.to_radians());
            for bone in [left_arm, right_arm].iter().flat_map(|arm| &arm[1..]) {
                r[bone.index()] = bend * r[bone.index()];
            }
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn n_pose_forearms_hang_down() {
        let r = ReferencePose::N.bone_orientations();
        assert!((r[0] * Vector3::x() - (-Vector3::y())).norm() < 1e-12);
        assert!((r[1] * (-Vector3::x()) - (-Vector3::y())).norm() < 1e-12);
        // The whole arm hangs: upper arms and hands as the forearms; legs, trunk, head, shoulders
        // upright.
        for (left, right) in [
            (Imu::LeftUpperArm, Imu::RightUpperArm),
            (Imu::LeftHand, Imu::RightHand),
        ] {
            assert_eq!(r[left.index()], r[0]);
            assert_eq!(r[right.index()], r[1]);
        }
        for upright in [
            Imu::Pelvis,
            Imu::LeftUpperLeg,
            Imu::RightFoot,
            Imu::Sternum,
            Imu::LeftShoulder,
        ] {
            assert_eq!(r[upright.index()], Rotation3::identity());
        }
        // Relaxed: the forearms and hands bent forward, the upper arms hanging straight.
        let relaxed = ReferencePose::Relaxed.bone_orientations();
        assert_eq!(relaxed[Imu::LeftUpperArm.index()], r[0]);
        assert_eq!(relaxed[Imu::LeftHand.index()], relaxed[0]);
        let pointing: Vector3<f64> = relaxed[0] * Vector3::x();
        assert!(
            pointing.z > 0.3,
            "the left forearm points forward: {pointing:?}"
        );
        assert!(
            ReferencePose::T
                .bone_orientations()
                .iter()
                .all(|r| *r == Rotation3::identity())
        );
    }
}
