//! What the calibration must be told: the inertial-frame convention of the sensors and the pose the
//! subject holds while standing.

use imuflow_body::rotation::Axis;
use nalgebra::Rotation3;

use crate::NUM_IMUS;

pub use imuflow_body::inertial::InertialFrame;

/// The pose held while the calibration reads the sensors: each IMU bone's `R_MB` is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ReferencePose {
    /// T-pose: arms horizontal to the sides; every bone's `R_MB` is the identity (reference §4).
    #[serde(rename = "t")]
    T,
    /// N-pose: standing straight, arms hanging down; forearms `R_z(∓90°)`, everything else the
    /// identity (GlobalPose's N-pose, reference §4).
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

    /// `R_MB` of each IMU's bone (IMU order) in this pose, facing +z.
    pub fn bone_orientations(self) -> [Rotation3<f64>; NUM_IMUS] {
        let mut r = [Rotation3::identity(); NUM_IMUS];
        if self != ReferencePose::T {
            // Left forearm: the bone's x axis (along the arm, pointing left) turns down.
            r[0] = Axis::Z.rotation(-std::f64::consts::FRAC_PI_2);
            r[1] = Axis::Z.rotation(std::f64::consts::FRAC_PI_2);
        }
        if self == ReferencePose::Relaxed {
            // Bent elbows bring the hands forward: a turn about M's left axis (x).
            let bend = Axis::X.rotation(-RELAXED_ELBOW_DEG.to_radians());
            r[0] = bend * r[0];
            r[1] = bend * r[1];
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
        assert!(
            ReferencePose::T
                .bone_orientations()
                .iter()
                .all(|r| *r == Rotation3::identity())
        );
    }
}
