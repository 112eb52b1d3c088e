//! How far a recorded pose is from its own sensors.

use std::collections::BTreeMap;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{BodyModel, JointId, Pose, SiteMask};
use imuflow_graph::frames::{BodyImuFrame, MotionFrame};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion};

use super::pairing::is_scored;
use crate::metrics;

/// Mean sensor-bone error (degrees, [`metrics::sensed_bone_error_deg`]) of `estimate` against the
/// calibrated IMU frames it was made from, paired by seq, over the sensors on `sites` (the
/// variant's sensor set). Frames that are not scored, and measured frames with one of those
/// sensors not valid or not a rotation, are left out. `None` when no frame is left.
pub fn sensor_bone_error_deg(
    estimate: &[MotionFrame],
    measured: &BTreeMap<u64, BodyImuFrame>,
    body: &BodyModel,
    sites: SiteMask,
) -> Option<f64> {
    let mut fk = FkData::new();
    let (mut sum, mut frames) = (0.0, 0usize);
    for frame in estimate.iter().filter(|f| is_scored(&f.header)) {
        let Some(bones) = measured
            .get(&frame.header.seq)
            .and_then(|m| measured_bones(m, sites))
        else {
            continue;
        };
        let Ok(pose) = Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m) else {
            continue;
        };
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        sum += metrics::sensed_bone_error_deg(&fk, bones);
        frames += 1;
    }
    (frames > 0).then(|| sum / frames as f64)
}

/// The bone orientations (with the joint each sensor's bone hangs from) of a frame whose sensors
/// on `sites` are all valid unit quaternions.
fn measured_bones(frame: &BodyImuFrame, sites: SiteMask) -> Option<Vec<(JointId, Rotation3<f64>)>> {
    if sites.is_empty() || frame.valid_mask & sites.0 != sites.0 || !is_scored(&frame.header) {
        return None;
    }
    sites
        .sites()
        .map(|site| {
            let [w, x, y, z] = frame.bone_orientation_wxyz[site.index()];
            let q = Quaternion::new(w, x, y, z).cast::<f64>();
            (0.9..1.1).contains(&q.norm()).then(|| {
                (
                    site.joint(),
                    UnitQuaternion::from_quaternion(q).to_rotation_matrix(),
                )
            })
        })
        .collect()
}
