//! Xsens MVN's body on imuflow's: the suit's 23 segment poses as a `MotionFrame` on the 24-joint
//! SMPL-topology skeleton, and truth frames resampled to a graph's rate.
//!
//! MVN reports each segment's orientation R_GB in its global frame G (z up, x forward as set by
//! the last reset, y left; MVN User Manual MV0319P, "Coordinate systems"), with every segment
//! frame aligned with G in its identity pose, the T-pose facing +x (arms along ±y, legs down). The
//! SMPL rest pose is the same T-pose in the model frame M (x left, y up, z forward) with every
//! bone frame aligned with M. So a segment's orientation becomes its joint's global orientation in
//! M by the change of frame C (G's axes in M: x→z, y→x, z→y): R_M = C·R_GB·Cᵀ, and positions
//! p_M = C·p_G. Local rotations are relative to the SMPL parent.
//!
//! The mapping is approximate: the skeletons differ (MVN has four spine segments where SMPL has
//! three, no finger segment, its own joint centres), so the truth is the suit's pose expressed on
//! imuflow's body, not a fit of it.

use imuflow_body::rotation::slerp_quaternion;
use imuflow_body::skeleton::JointId;
use imuflow_graph::frames::{MotionFrame, NUM_JOINTS};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The MVN segment whose orientation each SMPL joint takes, in SMPL joint order. SMPL joint j's
/// rotation turns the bone from j to its child, so it takes the MVN segment that starts at j.
/// MVN's lumbar segments L5 and L3 are one SMPL joint: spine1 takes L3, so L5's rotation
/// relative to the pelvis ends up in spine1's local rotation; spine2 takes T12, spine3 T8. The
/// hand joints (SMPL's fingers) have no MVN segment and take the hand's orientation (local
/// rotation identity).
pub const JOINT_SEGMENTS: [&str; NUM_JOINTS] = [
    "Pelvis",        // pelvis
    "LeftUpperLeg",  // left_hip
    "RightUpperLeg", // right_hip
    "L3",            // spine1
    "LeftLowerLeg",  // left_knee
    "RightLowerLeg", // right_knee
    "T12",           // spine2
    "LeftFoot",      // left_ankle
    "RightFoot",     // right_ankle
    "T8",            // spine3
    "LeftToe",       // left_foot
    "RightToe",      // right_foot
    "Neck",          // neck
    "LeftShoulder",  // left_collar
    "RightShoulder", // right_collar
    "Head",          // head
    "LeftUpperArm",  // left_shoulder
    "RightUpperArm", // right_shoulder
    "LeftForeArm",   // left_elbow
    "RightForeArm",  // right_elbow
    "LeftHand",      // left_wrist
    "RightHand",     // right_wrist
    "LeftHand",      // left_hand
    "RightHand",     // right_hand
];

/// The change of frame from MVN's global frame G to the model frame M: the columns are G's x
/// (forward), y (left) and z (up) in M.
pub fn model_from_mvn() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0)
}

/// Which of a file's segments each joint reads.
#[derive(Debug, Clone)]
pub struct SegmentMap {
    /// Index into the file's segment list, per SMPL joint.
    segment_of_joint: [usize; NUM_JOINTS],
    c: UnitQuaternion<f64>,
}

impl SegmentMap {
    /// Finds the segments by label; an error names the labels that are missing.
    pub fn new(labels: &[String]) -> Result<SegmentMap, String> {
        let mut segment_of_joint = [0; NUM_JOINTS];
        let mut missing: Vec<&str> = Vec::new();
        for (slot, want) in segment_of_joint.iter_mut().zip(JOINT_SEGMENTS) {
            match labels.iter().position(|l| l == want) {
                Some(i) => *slot = i,
                None if !missing.contains(&want) => missing.push(want),
                None => {}
            }
        }
        if !missing.is_empty() {
            return Err(format!(
                "no segment {} for the truth (segments: {})",
                missing.join(", "),
                labels.join(", ")
            ));
        }
        let c = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            model_from_mvn(),
        ));
        Ok(SegmentMap {
            segment_of_joint,
            c,
        })
    }

    /// The pose of one frame: local rotations and the root (pelvis segment origin) in M, from the
    /// segments' orientations R_GB and positions in G (file order). Header and physics fields
    /// are left zero.
    pub fn pose(
        &self,
        orientations: &[UnitQuaternion<f64>],
        positions: &[Vector3<f64>],
    ) -> MotionFrame {
        let global: [UnitQuaternion<f64>; NUM_JOINTS] = std::array::from_fn(|j| {
            self.c * orientations[self.segment_of_joint[j]] * self.c.inverse()
        });
        let mut m = MotionFrame::default();
        for joint in JointId::all() {
            let j = joint.index();
            let local = match joint.parent() {
                Some(p) => global[p.index()].inverse() * global[j],
                None => global[j],
            };
            m.local_pose_wxyz[j] = wire(&local);
        }
        let root = model_from_mvn() * positions[self.segment_of_joint[JointId::ROOT.index()]];
        m.root_position_m = [root.x as f32, root.y as f32, root.z as f32];
        m
    }
}

/// `[w, x, y, z]` with w ≥ 0, as f32.
fn wire(q: &UnitQuaternion<f64>) -> [f32; 4] {
    let q = if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    };
    [q.w as f32, q.i as f32, q.j as f32, q.k as f32]
}

fn unit(q: &[f32; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        f64::from(q[0]),
        f64::from(q[1]),
        f64::from(q[2]),
        f64::from(q[3]),
    ))
}

/// The truth at a graph's rate: frame k at k/rate_hz on the recording's clock (`seq` k,
/// `capture_ns` = k·10⁹/rate_hz, as the fusion stage numbers its output), local rotations
/// slerped and the root position interpolated linearly between the file frames around that
/// time; before the first file frame the first is held. Frames up to the last file frame, and
/// not past `until_ns` when given.
pub fn resample_truth(
    frames: &[MotionFrame],
    rate_hz: f64,
    until_ns: Option<u64>,
) -> Vec<MotionFrame> {
    let Some(last) = frames.last() else {
        return Vec::new();
    };
    let end = until_ns.map_or(last.header.capture_ns, |u| u.min(last.header.capture_ns));
    let mut out = Vec::new();
    let mut i = 0;
    for k in 0u64.. {
        let t = (k as f64 * 1e9 / rate_hz) as u64;
        if t > end {
            break;
        }
        while i + 1 < frames.len() && frames[i + 1].header.capture_ns <= t {
            i += 1;
        }
        let a = &frames[i];
        let mut f = match frames.get(i + 1) {
            Some(b) if a.header.capture_ns <= t => {
                let span = (b.header.capture_ns - a.header.capture_ns) as f64;
                interpolate(a, b, (t - a.header.capture_ns) as f64 / span)
            }
            _ => *a,
        };
        f.header = Default::default();
        f.header.seq = k;
        f.header.capture_ns = t;
        out.push(f);
    }
    out
}

/// The pose a fraction `s` of the way from `a` to `b`.
fn interpolate(a: &MotionFrame, b: &MotionFrame, s: f64) -> MotionFrame {
    let mut f = *a;
    for (j, q) in f.local_pose_wxyz.iter_mut().enumerate() {
        let qa = unit(&a.local_pose_wxyz[j]);
        let qb = unit(&b.local_pose_wxyz[j]);
        *q = wire(&slerp_quaternion(&qa, &qb, s));
    }
    for (k, p) in f.root_position_m.iter_mut().enumerate() {
        let (pa, pb) = (
            f64::from(a.root_position_m[k]),
            f64::from(b.root_position_m[k]),
        );
        *p = (pa + (pb - pa) * s) as f32;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    /// MVN's segment labels in the order MVN writes them (MVN User Manual).
    pub(crate) const MVN_SEGMENTS: [&str; 23] = [
        "Pelvis",
        "L5",
        "L3",
        "T12",
        "T8",
        "Neck",
        "Head",
        "RightShoulder",
        "RightUpperArm",
        "RightForeArm",
        "RightHand",
        "LeftShoulder",
        "LeftUpperArm",
        "LeftForeArm",
        "LeftHand",
        "RightUpperLeg",
        "RightLowerLeg",
        "RightFoot",
        "RightToe",
        "LeftUpperLeg",
        "LeftLowerLeg",
        "LeftFoot",
        "LeftToe",
    ];

    fn labels() -> Vec<String> {
        MVN_SEGMENTS.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn the_change_of_frame_takes_mvn_axes_to_the_model_frame() {
        let c = model_from_mvn();
        assert_eq!(c * Vector3::x(), Vector3::z(), "forward");
        assert_eq!(c * Vector3::y(), Vector3::x(), "left");
        assert_eq!(c * Vector3::z(), Vector3::y(), "up");
        assert!((c.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn every_joint_takes_a_segment_on_its_own_side_and_limb() {
        for joint in JointId::all() {
            let name = joint.name();
            let seg = JOINT_SEGMENTS[joint.index()];
            assert_eq!(
                name.starts_with("left"),
                seg.starts_with("Left"),
                "{name} <- {seg}"
            );
            assert_eq!(
                name.starts_with("right"),
                seg.starts_with("Right"),
                "{name} <- {seg}"
            );
        }
        assert!(SegmentMap::new(&labels()).is_ok());
        let mut short = labels();
        short.retain(|l| l != "T12");
        assert!(SegmentMap::new(&short).unwrap_err().contains("T12"));
    }

    #[test]
    fn a_rotated_segment_shows_up_on_its_joint_only() {
        let map = SegmentMap::new(&labels()).unwrap();
        let mut q = vec![UnitQuaternion::identity(); 23];
        // Left forearm bent 90° about MVN's z (up): in M that is a turn about y (up).
        let bend = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        // The forearm and the hand it carries (LeftForeArm, LeftHand).
        q[13] = bend;
        q[14] = bend;
        let m = map.pose(&q, &vec![Vector3::new(1.0, 2.0, 0.9); 23]);
        let elbow = JointId::LEFT_ELBOW.index();
        let s = std::f32::consts::FRAC_1_SQRT_2;
        for (j, got) in m.local_pose_wxyz.iter().enumerate() {
            let want = if j == elbow {
                [s, 0.0, s, 0.0]
            } else {
                [1.0, 0.0, 0.0, 0.0]
            };
            for k in 0..4 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-6,
                    "joint {j}: {got:?} vs {want:?}"
                );
            }
        }
        assert_eq!(m.root_position_m, [2.0, 0.9, 1.0], "p_M = (y, z, x) of p_G");
    }

    fn frame_at(t_ns: u64, angle: f64, x: f32) -> MotionFrame {
        let mut f = MotionFrame::default();
        f.header.capture_ns = t_ns;
        f.local_pose_wxyz = [[1.0, 0.0, 0.0, 0.0]; NUM_JOINTS];
        f.local_pose_wxyz[5] = wire(&UnitQuaternion::from_axis_angle(&Vector3::x_axis(), angle));
        f.root_position_m = [x, 0.0, 0.0];
        f
    }

    #[test]
    fn truth_is_slerped_onto_the_graph_rate() {
        // 100 Hz file, 60 Hz graph: frame 1 at 16.67 ms lies 2/3 of the way from 10 to 20 ms.
        let frames: Vec<MotionFrame> = (0..4)
            .map(|i| frame_at(i * 10_000_000, i as f64 * 0.3, i as f32))
            .collect();
        let out = resample_truth(&frames, 60.0, None);
        assert_eq!(
            out.len(),
            2,
            "0 and 16.7 ms lie within 30 ms; 33.3 ms does not"
        );
        assert_eq!(
            (out[1].header.seq, out[1].header.capture_ns),
            (1, 16_666_666)
        );
        let s = 0.6666666;
        let q = unit(&out[1].local_pose_wxyz[5]);
        assert!((q.angle() - (0.3 + 0.3 * s)).abs() < 1e-5, "{}", q.angle());
        assert!((out[1].root_position_m[0] - (1.0 + s as f32)).abs() < 1e-5);
        assert_eq!(resample_truth(&frames, 60.0, Some(10_000_000)).len(), 1);
    }
}
