//! Where the upper legs' and upper arms' error comes from: per knee and elbow, how far the upper
//! bone points off, how far the joint's flexion is off, and how often it bends the wrong way.
//!
//! Why: with the lower legs and forearms on their sensors and anatomical knees and elbows
//! (imuflow_body::limb_joints), a knee leaves its upper leg one free angle, the flexion; an elbow
//! leaves its upper arm two, the flexion and the twist. SIP scores those upper bones, so this
//! breakdown says which of the networks' guesses a SIP error is made of.

use std::fmt::Write as _;

use imuflow_body::kinematics::{FkData, Pose};
use imuflow_body::limb_joints::flexion;
use imuflow_body::skeleton::JointId;
use nalgebra::Vector3;

/// The knees and elbows, in the order of [`LimbErrors`]' arrays.
pub const LIMBS: [JointId; 4] = [
    JointId::LEFT_KNEE,
    JointId::RIGHT_KNEE,
    JointId::LEFT_ELBOW,
    JointId::RIGHT_ELBOW,
];

/// How far the truth must bend a limb for an estimate bent backwards there to count as bent the
/// wrong way (rad): 20°, well clear of a straight limb, where a few degrees either way are noise.
pub const WRONG_WAY_TRUE_FLEXION_RAD: f64 = 20.0 * std::f64::consts::PI / 180.0;

/// Sums over frames of the per-limb errors ([`LimbErrors::add`]); [`LimbErrors::means`] averages.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LimbErrors {
    pub frames: usize,
    /// Angle between the estimate's and the truth's upper bone (hip → knee, shoulder → elbow), rad.
    upper_direction: [f64; 4],
    /// |estimate's flexion − truth's|, rad.
    flexion_abs: [f64; 4],
    /// estimate's flexion − truth's, rad.
    flexion_signed: [f64; 4],
    /// Frames where the truth bends the limb past [`WRONG_WAY_TRUE_FLEXION_RAD`] ...
    truth_flexed: [usize; 4],
    /// ... and, of those, the estimate bends it backwards (a negative flexion).
    wrong_way: [usize; 4],
}

/// One limb's means over the frames, degrees and percent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LimbMeans {
    pub upper_direction_deg: f64,
    pub flexion_error_deg: f64,
    /// Mean of estimate − truth: positive, the estimate bends the limb further.
    pub flexion_bias_deg: f64,
    /// Share of the frames where the truth bends the limb past 20° in which the estimate bends it
    /// backwards; `None` when the truth never bends it that far.
    pub wrong_way_percent: Option<f64>,
}

impl LimbErrors {
    /// Adds one frame: the estimate's and the truth's local rotations and their forward
    /// kinematics (on the same body, with the same root).
    pub fn add(&mut self, estimate: &Pose, fk_estimate: &FkData, truth: &Pose, fk_truth: &FkData) {
        for (k, limb) in LIMBS.into_iter().enumerate() {
            let upper = limb.parent().expect("knees and elbows have parents");
            let bone = |fk: &FkData| fk.position(limb) - fk.position(upper);
            self.upper_direction[k] += angle(&bone(fk_estimate), &bone(fk_truth));
            let flexion_of = |pose: &Pose| {
                flexion(limb, &pose.parent_from_joint[limb.index()])
                    .expect("LIMBS are knees and elbows")
            };
            let (estimated, true_flexion) = (flexion_of(estimate), flexion_of(truth));
            self.flexion_abs[k] += (estimated - true_flexion).abs();
            self.flexion_signed[k] += estimated - true_flexion;
            if true_flexion > WRONG_WAY_TRUE_FLEXION_RAD {
                self.truth_flexed[k] += 1;
                if estimated < 0.0 {
                    self.wrong_way[k] += 1;
                }
            }
        }
        self.frames += 1;
    }

    /// Each limb's means, in [`LIMBS`] order.
    pub fn means(&self) -> [LimbMeans; 4] {
        let n = self.frames.max(1) as f64;
        std::array::from_fn(|k| LimbMeans {
            upper_direction_deg: (self.upper_direction[k] / n).to_degrees(),
            flexion_error_deg: (self.flexion_abs[k] / n).to_degrees(),
            flexion_bias_deg: (self.flexion_signed[k] / n).to_degrees(),
            wrong_way_percent: (self.truth_flexed[k] > 0)
                .then(|| 100.0 * self.wrong_way[k] as f64 / self.truth_flexed[k] as f64),
        })
    }
}

/// The angle between two directions, rad (0 when either has no length).
fn angle(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let lengths = a.norm() * b.norm();
    if lengths < 1e-12 {
        return 0.0;
    }
    // atan2 of |a×b| and a·b: exact near 0 and π, where acos of the dot product is not.
    a.cross(b).norm().atan2(a.dot(b))
}

/// The per-limb table of `imuflow eval --limbs`: one row per method and limb.
pub fn table<'a>(rows: impl IntoIterator<Item = (&'a str, &'a LimbErrors)>) -> String {
    let mut out = format!(
        "{:<11} {:<12} {:>14} {:>12} {:>9} {:>14}\n",
        "method", "limb", "upper bone (°)", "flexion (°)", "bias (°)", "wrong way (%)"
    );
    for (method, errors) in rows {
        for (limb, m) in LIMBS.iter().zip(errors.means()) {
            let wrong_way = m
                .wrong_way_percent
                .map_or_else(|| "–".to_owned(), |p| format!("{p:.1}"));
            let _ = writeln!(
                out,
                "{:<11} {:<12} {:>14.2} {:>12.2} {:>+9.2} {:>14}",
                method,
                limb.name(),
                m.upper_direction_deg,
                m.flexion_error_deg,
                m.flexion_bias_deg,
                wrong_way
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::kinematics::forward_kinematics;
    use imuflow_body::{BodyModel, BodyParams};
    use nalgebra::Rotation3;

    fn fk(pose: &Pose) -> FkData {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut out = FkData::new();
        forward_kinematics(&body.skeleton, pose, &mut out);
        out
    }

    fn bend(pose: &mut Pose, joint: JointId, axis: Vector3<f64>, angle: f64) {
        pose.parent_from_joint[joint.index()] =
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
    }

    #[test]
    fn each_limbs_errors_are_the_angles_it_was_given() {
        // Truth: the left knee bent 50° (about x), the right elbow 40° (+Ry for the right
        // side), everything else straight. Estimate: the left knee bent 10° backwards, the
        // right elbow 70°, and the left hip swung 0.3 rad about z (perpendicular to the upper
        // leg, which hangs along −y): the left upper leg points 0.3 rad off, the right upper
        // arm not at all (its elbow's bend moves only the forearm).
        let mut truth = Pose::t_pose(Vector3::zeros());
        bend(
            &mut truth,
            JointId::LEFT_KNEE,
            Vector3::x(),
            50f64.to_radians(),
        );
        bend(
            &mut truth,
            JointId::RIGHT_ELBOW,
            Vector3::y(),
            40f64.to_radians(),
        );
        let mut estimate = Pose::t_pose(Vector3::zeros());
        bend(
            &mut estimate,
            JointId::LEFT_KNEE,
            Vector3::x(),
            -10f64.to_radians(),
        );
        bend(
            &mut estimate,
            JointId::RIGHT_ELBOW,
            Vector3::y(),
            70f64.to_radians(),
        );
        bend(&mut estimate, JointId::LEFT_HIP, Vector3::z(), 0.3);

        let mut errors = LimbErrors::default();
        for _ in 0..3 {
            errors.add(&estimate, &fk(&estimate), &truth, &fk(&truth));
        }
        // The right knee and the left elbow agree, and the truth never bends them.
        errors.add(&truth, &fk(&truth), &truth, &fk(&truth));
        let [left_knee, right_knee, left_elbow, right_elbow] = errors.means();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(close(
            left_knee.upper_direction_deg,
            0.75 * 0.3f64.to_degrees()
        ));
        assert!(close(left_knee.flexion_error_deg, 0.75 * 60.0));
        assert!(close(left_knee.flexion_bias_deg, -0.75 * 60.0));
        assert_eq!(left_knee.wrong_way_percent, Some(75.0));
        assert!(close(right_elbow.upper_direction_deg, 0.0));
        assert!(close(right_elbow.flexion_error_deg, 0.75 * 30.0));
        assert!(close(right_elbow.flexion_bias_deg, 0.75 * 30.0));
        assert_eq!(right_elbow.wrong_way_percent, Some(0.0));
        for m in [right_knee, left_elbow] {
            assert!(close(m.upper_direction_deg, 0.0) && close(m.flexion_error_deg, 0.0));
            assert_eq!(m.wrong_way_percent, None);
        }
        let printed = table([("pip", &errors)]);
        assert_eq!(printed.lines().count(), 5, "{printed}");
        assert!(printed.contains("-45.00"), "{printed}");
    }

    #[test]
    fn the_angle_between_bones_is_exact_near_parallel_and_opposite() {
        let a = Vector3::new(0.0, -0.4, 0.0);
        for t in [1e-9, 1e-6, 0.3, std::f64::consts::PI - 1e-7] {
            let b = Rotation3::from_axis_angle(&Vector3::z_axis(), t) * (2.0 * a);
            assert!((angle(&a, &b) - t).abs() < 1e-12, "{t}");
        }
        assert_eq!(angle(&a, &Vector3::zeros()), 0.0);
    }
}
