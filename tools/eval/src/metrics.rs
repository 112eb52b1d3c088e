//! Evaluation metrics (reference §6, articulate `FullMotionEvaluator`, 60 fps).
//!
//! Per-frame metrics take FK results or poses; sequence metrics take per-frame joint positions. Protocols:
//! - "reduced/local" (TransPose, PIP, PNP): [`apply_ignored_joints`] with [`IGNORED_JOINTS`] on both
//!   prediction and ground truth before FK, no translation;
//! - GlobalPose "G": ignored joints without the root ([`GLOBALPOSE_IGNORED_JOINTS`]), with translation.
//!
//! Position errors are root-position aligned (the prediction is shifted so its root matches the ground
//! truth). Foot skating and ground penetration are imuflow's own definitions (documented below); the
//! reference evaluates neither.

use nalgebra::{Rotation3, Vector3};

use imuflow_body::kinematics::{FkData, Pose};
use imuflow_body::rotation::angle_between;
use imuflow_body::skeleton::{IMU_JOINTS, JointId, NUM_IMUS, NUM_JOINTS, SIP_JOINTS};

pub use imuflow_body::skeleton::IGNORED_JOINTS;

/// GlobalPose's ignored mask: the reduced protocol's without the root (reference §6).
pub const GLOBALPOSE_IGNORED_JOINTS: [JointId; 8] = [
    JointId::LEFT_ANKLE,
    JointId::RIGHT_ANKLE,
    JointId::LEFT_FOOT,
    JointId::RIGHT_FOOT,
    JointId::LEFT_WRIST,
    JointId::RIGHT_WRIST,
    JointId::LEFT_HAND,
    JointId::RIGHT_HAND,
];

/// Set the local rotations of `joints` to identity (applied to prediction AND ground truth).
pub fn apply_ignored_joints(pose: &mut Pose, joints: &[JointId]) {
    for j in joints {
        pose.parent_from_joint[j.index()] = Rotation3::identity();
    }
}

/// Mean geodesic angle (degrees) between `a[j]` and `b[j]` over `joints`; 0 for an empty set.
pub fn mean_angle_error_deg(
    a: &[Rotation3<f64>; NUM_JOINTS],
    b: &[Rotation3<f64>; NUM_JOINTS],
    joints: &[JointId],
) -> f64 {
    if joints.is_empty() {
        return 0.0;
    }
    let sum: f64 = joints
        .iter()
        .map(|j| angle_between(&a[j.index()], &b[j.index()]))
        .sum();
    (sum / joints.len() as f64).to_degrees()
}

/// SIP error (degrees): mean global angle error over hips and shoulders [1, 2, 16, 17].
pub fn sip_error_deg(predicted: &FkData, truth: &FkData) -> f64 {
    mean_angle_error_deg(
        &predicted.world_from_joint,
        &truth.world_from_joint,
        &SIP_JOINTS,
    )
}

/// The legs' joints whose global rotation [`leg_angle_error_deg`] scores: both hips (SIP's lower
/// half) and both knees.
pub const LEG_JOINTS: [JointId; 4] = [
    JointId::LEFT_HIP,
    JointId::RIGHT_HIP,
    JointId::LEFT_KNEE,
    JointId::RIGHT_KNEE,
];

/// Leg angle error (degrees), imuflow's own: SIP's measure (the mean global angle error) over the
/// hips and knees, so that a set that senses only the legs is scored on what it estimates, and a
/// six-site estimate on the same joints.
pub fn leg_angle_error_deg(predicted: &FkData, truth: &FkData) -> f64 {
    mean_angle_error_deg(
        &predicted.world_from_joint,
        &truth.world_from_joint,
        &LEG_JOINTS,
    )
}

/// Sensor-bone error (degrees): mean over the six sensors of the angle between the estimate's
/// global orientation of the bone a sensor sits on (`IMU_JOINTS`: forearms, lower legs, head,
/// pelvis) and that sensor's calibrated measurement `R_MB`. How far the pose contradicts its own
/// inputs; it cannot be below the calibration error on real sensors, and has no reason to be above
/// it. `estimate` is the FK of the pose as output (root orientation included).
pub fn sensor_bone_error_deg(estimate: &FkData, measured: &[Rotation3<f64>; NUM_IMUS]) -> f64 {
    sensed_bone_error_deg(
        estimate,
        IMU_JOINTS.iter().copied().zip(measured.iter().copied()),
    )
}

/// [`sensor_bone_error_deg`] over any sensors: each the joint whose bone it sits on and its
/// calibrated measurement `R_MB` (a sensor set's sensors).
pub fn sensed_bone_error_deg(
    estimate: &FkData,
    sensors: impl IntoIterator<Item = (JointId, Rotation3<f64>)>,
) -> f64 {
    let (sum, n) = sensors.into_iter().fold((0.0, 0usize), |(sum, n), (j, r)| {
        (sum + angle_between(estimate.world_from(j), &r), n + 1)
    });
    (sum / n.max(1) as f64).to_degrees()
}

/// Global angle error (degrees): mean over all 24 joints of the angle between global rotations.
pub fn global_angle_error_deg(predicted: &FkData, truth: &FkData) -> f64 {
    let all: Vec<JointId> = JointId::all().collect();
    mean_angle_error_deg(&predicted.world_from_joint, &truth.world_from_joint, &all)
}

/// Local angle error (degrees): mean over all 24 joints of the angle between local rotations.
pub fn local_angle_error_deg(predicted: &Pose, truth: &Pose) -> f64 {
    let all: Vec<JointId> = JointId::all().collect();
    mean_angle_error_deg(&predicted.parent_from_joint, &truth.parent_from_joint, &all)
}

/// Joint position error (m): mean over all 24 joints of ‖p_pred + (root_truth − root_pred) − p_truth‖
/// (root-position aligned, so the root contributes 0).
pub fn joint_position_error_m(predicted: &FkData, truth: &FkData) -> f64 {
    let shift = truth.position(JointId::ROOT) - predicted.position(JointId::ROOT);
    let sum: f64 = JointId::all()
        .map(|j| (predicted.position(j) + shift - truth.position(j)).norm())
        .sum();
    sum / NUM_JOINTS as f64
}

/// Per joint (m): ‖p_pred + (root_truth − root_pred) − p_truth‖, the terms [`joint_position_error_m`]
/// averages (root-position aligned: the root's entry is 0).
pub fn per_joint_position_error_m(predicted: &FkData, truth: &FkData) -> [f64; NUM_JOINTS] {
    let shift = truth.position(JointId::ROOT) - predicted.position(JointId::ROOT);
    std::array::from_fn(|j| {
        (predicted.joint_in_world_m[j] + shift - truth.joint_in_world_m[j]).norm()
    })
}

/// Per joint (degrees): the geodesic angle between the predicted and true global rotations, the terms
/// [`global_angle_error_deg`] averages.
pub fn per_joint_angle_error_deg(predicted: &FkData, truth: &FkData) -> [f64; NUM_JOINTS] {
    std::array::from_fn(|j| {
        angle_between(&predicted.world_from_joint[j], &truth.world_from_joint[j]).to_degrees()
    })
}

/// Jitter (km/s³): mean over frames t ∈ [0, N−4] and all joints of the finite-difference jerk
/// ‖x(t+3) − 3x(t+2) + 3x(t+1) − x(t)‖·f³, divided by 1000 (PIP/PNP units; reference §6 uses f = 60).
/// `positions[t]` holds the joint positions (m) of frame t. Returns 0 for fewer than 4 frames.
pub fn jitter_km_per_s3(positions: &[[Vector3<f64>; NUM_JOINTS]], rate_hz: f64) -> f64 {
    mean_jerk_km_per_s3(positions, rate_hz)
}

/// Root jitter (km/s³): the jerk of the root translation alone (GlobalPose test.py, reference §6),
/// with the same finite difference and units as [`jitter_km_per_s3`]. `root_positions[t]` is the
/// root position (m) of frame t. Returns 0 for fewer than 4 frames.
pub fn root_jitter_km_per_s3(root_positions: &[Vector3<f64>], rate_hz: f64) -> f64 {
    let as_points: Vec<[Vector3<f64>; 1]> = root_positions.iter().map(|p| [*p]).collect();
    mean_jerk_km_per_s3(&as_points, rate_hz)
}

/// Mean over frames and points of ‖x(t+3) − 3x(t+2) + 3x(t+1) − x(t)‖·f³ / 1000.
fn mean_jerk_km_per_s3<const N: usize>(frames: &[[Vector3<f64>; N]], rate_hz: f64) -> f64 {
    if frames.len() < 4 || N == 0 {
        return 0.0;
    }
    let f3 = rate_hz.powi(3);
    let mut sum = 0.0;
    let mut count = 0usize;
    for w in frames.windows(4) {
        // `windows(4)` yields exactly four frames.
        for (((x0, x1), x2), x3) in w[0].iter().zip(&w[1]).zip(&w[2]).zip(&w[3]) {
            let jerk = x3 - 3.0 * x2 + 3.0 * x1 - x0;
            sum += jerk.norm() * f3;
            count += 1;
        }
    }
    sum / count as f64 / 1000.0
}

/// Cumulative translation error for travelled distance `window_m` (reference §6, the TotalCapture
/// protocol of TransPose/PIP/GlobalPose): with s(t) the ground truth's cumulative path length, scan
/// frame pairs (start, end) whose path s(end) − s(start) first reaches `window_m` (start advancing one
/// frame at a time, a pair skipped when its end repeats the previous pair's), and average
/// ‖Δp_pred − Δp_truth‖ / (s(end) − s(start)) · `window_m` over the pairs. `None` when the ground
/// truth never travels `window_m` or the inputs differ in length. Metres.
pub fn cumulative_translation_error_m(
    predicted_root: &[Vector3<f64>],
    truth_root: &[Vector3<f64>],
    window_m: f64,
) -> Option<f64> {
    let n = truth_root.len();
    if predicted_root.len() != n || n < 2 || !(window_m.is_finite() && window_m > 0.0) {
        return None;
    }
    let mut path = Vec::with_capacity(n);
    let mut travelled = 0.0;
    path.push(0.0);
    for w in truth_root.windows(2) {
        travelled += (w[1] - w[0]).norm();
        path.push(travelled);
    }
    let (mut start, mut end) = (0usize, 1usize);
    let mut last_end: Option<usize> = None;
    let (mut sum, mut pairs) = (0.0, 0usize);
    while end < n {
        if path[end] - path[start] < window_m {
            end += 1;
            continue;
        }
        if last_end != Some(end) {
            let along = path[end] - path[start];
            let predicted = predicted_root[end] - predicted_root[start];
            let truth = truth_root[end] - truth_root[start];
            sum += (predicted - truth).norm() / along * window_m;
            pairs += 1;
            last_end = Some(end);
        }
        start += 1;
    }
    (pairs > 0).then(|| sum / pairs as f64)
}

/// Translation drift in percent: the cumulative error at 7 m of travel / 7 m × 100 (the figure
/// GlobalPose prints, reference §6). `None` when the ground truth travels less than 7 m.
pub fn translation_drift_percent(
    predicted_root: &[Vector3<f64>],
    truth_root: &[Vector3<f64>],
) -> Option<f64> {
    const DRIFT_WINDOW_M: f64 = 7.0;
    cumulative_translation_error_m(predicted_root, truth_root, DRIFT_WINDOW_M)
        .map(|e| e / DRIFT_WINDOW_M * 100.0)
}

/// Shortest horizontal travel of the truth for [`distance_walked_percent`], m.
pub const MIN_WALKED_M: f64 = 1.0;

/// Distance walked, %: the estimate's horizontal root displacement from the first to the last
/// frame, projected on the truth's, over the truth's length × 100. 100 is right; below 100 the
/// estimate walks short (or off to the side), above it too far. Heading is not aligned: a walk
/// estimated in the wrong direction counts as short. `None` when the truth travels less than
/// [`MIN_WALKED_M`] horizontally (imuflow's definition, for walking in any direction).
pub fn distance_walked_percent(
    predicted_root: &[Vector3<f64>],
    truth_root: &[Vector3<f64>],
) -> Option<f64> {
    let horizontal = |roots: &[Vector3<f64>]| {
        let d = roots.last()? - roots.first()?;
        Some(Vector3::new(d.x, 0.0, d.z))
    };
    let truth = horizontal(truth_root)?;
    let estimate = horizontal(predicted_root)?;
    let length = truth.norm();
    (length >= MIN_WALKED_M).then(|| estimate.dot(&truth) / (length * length) * 100.0)
}

/// Foot joints used by the contact metrics.
pub const FOOT_JOINTS: [JointId; 2] = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT];

/// Foot skating (m/s): mean horizontal (x–z) speed of a foot joint over the consecutive-frame pairs in
/// which it is in contact, i.e. at most `contact_height_m` above `floor_y_m` in both frames (imuflow's
/// definition; 0.05 m is a sensible threshold for the foot joint at the ball of the foot). Returns 0
/// when no foot is ever in contact.
pub fn foot_skating_mps(
    positions: &[[Vector3<f64>; NUM_JOINTS]],
    rate_hz: f64,
    floor_y_m: f64,
    contact_height_m: f64,
) -> f64 {
    let mut sum = 0.0;
    let mut count = 0usize;
    for w in positions.windows(2) {
        for foot in FOOT_JOINTS {
            let (a, b) = (w[0][foot.index()], w[1][foot.index()]);
            if a.y - floor_y_m <= contact_height_m && b.y - floor_y_m <= contact_height_m {
                let d = b - a;
                sum += (d.x * d.x + d.z * d.z).sqrt() * rate_hz;
                count += 1;
            }
        }
    }
    if count == 0 { 0.0 } else { sum / count as f64 }
}

/// Ground penetration (m): mean over frames of the deepest foot joint's depth below `floor_y_m`
/// (0 for frames with both feet on or above the floor; imuflow's definition).
pub fn ground_penetration_m(positions: &[[Vector3<f64>; NUM_JOINTS]], floor_y_m: f64) -> f64 {
    if positions.is_empty() {
        return 0.0;
    }
    let sum: f64 = positions
        .iter()
        .map(|p| {
            FOOT_JOINTS
                .iter()
                .map(|f| (floor_y_m - p[f.index()].y).max(0.0))
                .fold(0.0, f64::max)
        })
        .sum();
    sum / positions.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_walked_is_the_estimate_along_the_truth() {
        let line = |end: Vector3<f64>| -> Vec<Vector3<f64>> {
            (0..=10).map(|i| end * (i as f64 / 10.0)).collect()
        };
        let truth = line(Vector3::new(3.0, 0.0, 4.0));
        // Half as far, same direction: 50 %; height changes do not count.
        let half = line(Vector3::new(1.5, 0.7, 2.0));
        assert!((distance_walked_percent(&half, &truth).unwrap() - 50.0).abs() < 1e-9);
        // As far but at right angles: nothing along the truth.
        let sideways = line(Vector3::new(4.0, 0.0, -3.0));
        assert!(distance_walked_percent(&sideways, &truth).unwrap().abs() < 1e-9);
        // Backwards: negative.
        let back = line(Vector3::new(-3.0, 0.0, -4.0));
        assert!((distance_walked_percent(&back, &truth).unwrap() + 100.0).abs() < 1e-9);
        // A truth that stays within 1 m has no distance to compare.
        assert!(distance_walked_percent(&half, &line(Vector3::new(0.5, 0.0, 0.0))).is_none());
    }
    use approx::assert_relative_eq;

    #[test]
    fn sensor_bone_error_is_the_mean_angle_over_the_six_instrumented_bones() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut pose = Pose::t_pose(Vector3::zeros());
        pose.parent_from_joint[JointId::LEFT_SHOULDER.index()] =
            Rotation3::from_axis_angle(&Vector3::z_axis(), 0.5);
        let mut fk = FkData::new();
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        // The measurement agrees with every bone but the left forearm, which it sees 0.5 rad
        // back (the shoulder turned the forearm by 0.5 rad) and the head, 0.3 rad about x.
        let mut measured = [Rotation3::identity(); NUM_IMUS];
        measured[4] = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.3);
        let want = (0.5f64 + 0.3) / 6.0;
        assert_relative_eq!(
            sensor_bone_error_deg(&fk, &measured),
            want.to_degrees(),
            epsilon = 1e-9
        );
    }
    /// A left knee bent 0.4 rad more than the truth: the left knee's global rotation (and the
    /// ankle's, not scored) 0.4 rad off, the hips not at all; a hip turned 0.2 rad turns its knee
    /// with it: (0.2 + 0.2 + 0.4) / 4 once both.
    #[test]
    fn leg_angle_error_is_sips_measure_over_hips_and_knees() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let truth = Pose::t_pose(Vector3::zeros());
        let mut bent = truth.clone();
        bent.parent_from_joint[JointId::LEFT_KNEE.index()] =
            Rotation3::from_axis_angle(&Vector3::x_axis(), 0.4);
        let (mut fk_truth, mut fk) = (FkData::new(), FkData::new());
        forward_kinematics(&body.skeleton, &truth, &mut fk_truth);
        forward_kinematics(&body.skeleton, &bent, &mut fk);
        assert_relative_eq!(
            leg_angle_error_deg(&fk, &fk_truth),
            (0.4f64 / 4.0).to_degrees(),
            epsilon = 1e-9
        );
        bent.parent_from_joint[JointId::RIGHT_HIP.index()] =
            Rotation3::from_axis_angle(&Vector3::z_axis(), 0.2);
        forward_kinematics(&body.skeleton, &bent, &mut fk);
        assert_relative_eq!(
            leg_angle_error_deg(&fk, &fk_truth),
            (0.8f64 / 4.0).to_degrees(),
            epsilon = 1e-9
        );
        // SIP sees only the hip of the two.
        assert_relative_eq!(
            sip_error_deg(&fk, &fk_truth),
            (0.2f64 / 4.0).to_degrees(),
            epsilon = 1e-9
        );
    }
    use imuflow_body::kinematics::forward_kinematics;
    use imuflow_body::rotation::Axis;
    use imuflow_body::{BodyModel, BodyParams};

    #[test]
    fn root_jitter_of_a_cubic_is_its_third_derivative() {
        // x(t) = c·t³ along x: the third finite difference is exact, jerk = 6c m/s³.
        let (c, rate) = (2.0, 60.0);
        let roots: Vec<Vector3<f64>> = (0..120)
            .map(|k| Vector3::new(c * (f64::from(k) / rate).powi(3), 0.9, 0.0))
            .collect();
        assert_relative_eq!(
            root_jitter_km_per_s3(&roots, rate),
            6.0 * c / 1000.0,
            max_relative = 1e-6
        );
        assert_eq!(root_jitter_km_per_s3(&roots[..3], rate), 0.0);
    }

    #[test]
    fn drift_of_a_prediction_that_overestimates_distance_by_ten_percent() {
        // Ground truth walks a straight line at 1.2 m/s for 20 s; the prediction covers 1.1× the
        // distance. Every window's error is 0.1·|Δp| = 0.1·W, so drift = 10 % at any window.
        let rate = 60.0;
        let truth: Vec<Vector3<f64>> = (0..1200)
            .map(|k| Vector3::new(0.0, 0.9, 1.2 * f64::from(k) / rate))
            .collect();
        let predicted: Vec<Vector3<f64>> = truth
            .iter()
            .map(|p| Vector3::new(0.0, 0.9, 1.1 * p.z))
            .collect();
        assert_relative_eq!(
            cumulative_translation_error_m(&predicted, &truth, 3.0).unwrap(),
            0.3,
            max_relative = 1e-2
        );
        assert_relative_eq!(
            translation_drift_percent(&predicted, &truth).unwrap(),
            10.0,
            max_relative = 1e-2
        );
        assert_relative_eq!(translation_drift_percent(&truth, &truth).unwrap(), 0.0);
        // 20 s at 1.2 m/s = 24 m: a 30 m window never fits; mismatched lengths are refused.
        assert!(cumulative_translation_error_m(&predicted, &truth, 30.0).is_none());
        assert!(cumulative_translation_error_m(&predicted[..10], &truth, 1.0).is_none());
    }

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
    }

    fn fk(body: &BodyModel, pose: &Pose) -> FkData {
        let mut out = FkData::new();
        forward_kinematics(&body.skeleton, pose, &mut out);
        out
    }

    #[test]
    fn angle_errors_match_hand_counts() {
        let body = body();
        let truth = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
        let mut pred = truth.clone();
        pred.parent_from_joint[JointId::LEFT_HIP.index()] = Axis::X.rotation(10f64.to_radians());
        pred.parent_from_joint[JointId::LEFT_SHOULDER.index()] =
            Axis::Z.rotation(-20f64.to_radians());
        let (p, t) = (fk(&body, &pred), fk(&body, &truth));
        // SIP: hips and shoulders, (10 + 0 + 20 + 0) / 4.
        assert_relative_eq!(sip_error_deg(&p, &t), 7.5, epsilon = 1e-9);
        // Global: the hip error reaches hip, knee, ankle, foot (4 × 10°); the shoulder error reaches
        // shoulder, elbow, wrist, hand (4 × 20°); over 24 joints.
        assert_relative_eq!(global_angle_error_deg(&p, &t), 120.0 / 24.0, epsilon = 1e-9);
        // Local: only the two changed joints.
        assert_relative_eq!(
            local_angle_error_deg(&pred, &truth),
            30.0 / 24.0,
            epsilon = 1e-9
        );
        // The reduced protocol removes differences at ignored joints only.
        let mut a = truth.clone();
        a.parent_from_joint[JointId::LEFT_WRIST.index()] = Axis::Y.rotation(1.0);
        apply_ignored_joints(&mut a, &IGNORED_JOINTS);
        assert_eq!(a, truth);
    }

    #[test]
    fn joint_position_error_is_root_aligned() {
        let body = body();
        let truth = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
        let mut pred = truth.clone();
        pred.root_in_world_m += Vector3::new(1.0, 2.0, 3.0);
        assert_relative_eq!(
            joint_position_error_m(&fk(&body, &pred), &fk(&body, &truth)),
            0.0,
            epsilon = 1e-12
        );
        // Turning the left ankle 180° about the (vertical) shank axis flips the foot joint from +f to
        // −f forward: one joint off by 2f.
        pred.parent_from_joint[JointId::LEFT_ANKLE.index()] =
            Axis::Y.rotation(std::f64::consts::PI);
        let f = body.skeleton.offset_in_parent_m(JointId::LEFT_FOOT).z;
        assert_relative_eq!(
            joint_position_error_m(&fk(&body, &pred), &fk(&body, &truth)),
            2.0 * f / 24.0,
            epsilon = 1e-12
        );
    }

    #[test]
    fn per_joint_errors_average_to_the_frame_errors() {
        let body = body();
        let truth = Pose::t_pose(Vector3::new(0.0, 1.0, 0.0));
        let mut pred = truth.clone();
        pred.root_in_world_m += Vector3::new(0.3, 0.0, -0.2);
        pred.parent_from_joint[JointId::RIGHT_KNEE.index()] = Axis::X.rotation(0.5);
        pred.parent_from_joint[JointId::SPINE1.index()] = Axis::Z.rotation(-0.2);
        let (p, t) = (fk(&body, &pred), fk(&body, &truth));
        let position = per_joint_position_error_m(&p, &t);
        let angle = per_joint_angle_error_deg(&p, &t);
        assert_eq!(position[JointId::ROOT.index()], 0.0);
        assert!(position[JointId::RIGHT_ANKLE.index()] > 0.1);
        assert_relative_eq!(position[JointId::LEFT_ANKLE.index()], 0.0, epsilon = 1e-12);
        assert_relative_eq!(
            position.iter().sum::<f64>() / 24.0,
            joint_position_error_m(&p, &t),
            epsilon = 1e-12
        );
        assert_relative_eq!(
            angle.iter().sum::<f64>() / 24.0,
            global_angle_error_deg(&p, &t),
            epsilon = 1e-9
        );
        assert_relative_eq!(
            angle[JointId::RIGHT_KNEE.index()],
            0.5f64.to_degrees(),
            epsilon = 1e-9
        );
    }

    #[test]
    fn jitter_of_a_cubic_is_its_third_derivative() {
        // x(t) = c t³ has x''' = 6c everywhere, and the third difference of a cubic is exact.
        let c = 1000.0;
        let frames: Vec<[Vector3<f64>; NUM_JOINTS]> = (0..20)
            .map(|k| {
                let t = k as f64 / 60.0;
                [Vector3::new(c * t * t * t, 0.5, 0.0); NUM_JOINTS]
            })
            .collect();
        assert_relative_eq!(
            jitter_km_per_s3(&frames, 60.0),
            6.0 * c / 1000.0,
            epsilon = 1e-6
        );
        // Constant velocity has no jerk.
        let line: Vec<_> = (0..10)
            .map(|k| [Vector3::new(k as f64, 0.0, 0.0); NUM_JOINTS])
            .collect();
        assert_relative_eq!(jitter_km_per_s3(&line, 60.0), 0.0, epsilon = 1e-9);
        assert_eq!(jitter_km_per_s3(&line[..3], 60.0), 0.0);
    }

    #[test]
    fn foot_skating_and_penetration_on_constructed_feet() {
        let mut frames = vec![[Vector3::new(0.0, 1.0, 0.0); NUM_JOINTS]; 3];
        // Left foot on the floor sliding 1 cm per frame along x; right foot lifted (no contact).
        for (k, f) in frames.iter_mut().enumerate() {
            f[JointId::LEFT_FOOT.index()] = Vector3::new(0.01 * k as f64, 0.0, 0.0);
            f[JointId::RIGHT_FOOT.index()] = Vector3::new(0.0, 0.3, 0.1 * k as f64);
        }
        // 0.01 m per 1/60 s.
        assert_relative_eq!(
            foot_skating_mps(&frames, 60.0, 0.0, 0.05),
            0.6,
            epsilon = 1e-12
        );
        assert_eq!(ground_penetration_m(&frames, 0.0), 0.0);
        // Sink the left foot 2 cm in one of the three frames.
        frames[1][JointId::LEFT_FOOT.index()].y = -0.02;
        assert_relative_eq!(
            ground_penetration_m(&frames, 0.0),
            0.02 / 3.0,
            epsilon = 1e-12
        );
        // No contact at all -> 0.
        assert_eq!(foot_skating_mps(&frames, 60.0, -1.0, 0.05), 0.0);
    }
}
