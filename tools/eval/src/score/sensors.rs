//! How far a recorded pose is from its own sensors.

use std::collections::BTreeMap;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::skeleton::NUM_IMUS;
use imuflow_body::{BodyModel, Pose};
use imuflow_graph::frames::{BodyImuFrame, MotionFrame};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion};

use super::pairing::is_scored;
use crate::metrics;

/// Mean sensor-bone error (degrees, [`metrics::sensor_bone_error_deg`]) of `estimate` against the
/// calibrated IMU frames it was made from, paired by seq. Frames that are not scored, and measured
/// frames with a sensor not valid or not a rotation, are left out. `None` when no frame is left.
pub fn sensor_bone_error_deg(
    estimate: &[MotionFrame],
    measured: &BTreeMap<u64, BodyImuFrame>,
    body: &BodyModel,
) -> Option<f64> {
    let mut fk = FkData::new();
    let (mut sum, mut frames) = (0.0, 0usize);
    for frame in estimate.iter().filter(|f| is_scored(&f.header)) {
        let Some(bones) = measured.get(&frame.header.seq).and_then(measured_bones) else {
            continue;
        };
        let Ok(pose) = Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m) else {
            continue;
        };
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        sum += metrics::sensor_bone_error_deg(&fk, &bones);
        frames += 1;
    }
    (frames > 0).then(|| sum / frames as f64)
}

/// The six bone orientations of a frame whose sensors are all valid unit quaternions.
fn measured_bones(frame: &BodyImuFrame) -> Option<[Rotation3<f64>; NUM_IMUS]> {
    if frame.valid_mask & ((1 << NUM_IMUS) - 1) != (1 << NUM_IMUS) - 1 || !is_scored(&frame.header)
    {
        return None;
    }
    let mut bones = [Rotation3::identity(); NUM_IMUS];
    for (bone, [w, x, y, z]) in bones.iter_mut().zip(frame.bone_orientation_wxyz) {
        let q = Quaternion::new(w, x, y, z).cast::<f64>();
        if !(0.9..1.1).contains(&q.norm()) {
            return None;
        }
        *bone = UnitQuaternion::from_quaternion(q).to_rotation_matrix();
    }
    Some(bones)
}
