//! How far two estimates are from each other, for recordings without truth.

use imuflow_body::BodyModel;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_graph::frames::MotionFrame;
use serde::Serialize;

use super::pairing::{pairs, usable};
use crate::metrics::global_angle_error_deg;

/// The mean difference between two estimates over the frames both can be scored on.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Disagreement {
    /// Frames compared (paired by seq, neither flagged nor undecodable).
    pub frames: usize,
    /// Mean global angle between the two poses over all 24 joints, degrees; `None` without frames.
    pub angle_deg: Option<f64>,
    /// Mean distance between the two root positions, m; `None` without frames.
    pub root_distance_m: Option<f64>,
}

/// Compares estimates `a` and `b` frame by frame (paired by seq, skipped as in
/// [`super::score_against_truth`]). Neither is the reference, so the poses are compared whole: no
/// ignored joints, the global rotations of all 24 joints (root orientation included), and the root
/// positions unaligned (their distance is the second number).
pub fn disagreement(a: &[MotionFrame], b: &[MotionFrame], body: &BodyModel) -> Disagreement {
    let (ua, ub) = (usable(a), usable(b));
    let paired = pairs(&ua, &ub);
    if paired.is_empty() {
        return Disagreement::default();
    }
    let (mut fa, mut fb) = (FkData::new(), FkData::new());
    let (mut angle, mut root) = (0.0, 0.0);
    for (x, y) in &paired {
        forward_kinematics(&body.skeleton, &x.pose, &mut fa);
        forward_kinematics(&body.skeleton, &y.pose, &mut fb);
        angle += global_angle_error_deg(&fa, &fb);
        root += (x.pose.root_in_world_m - y.pose.root_in_world_m).norm();
    }
    let n = paired.len() as f64;
    Disagreement {
        frames: paired.len(),
        angle_deg: Some(angle / n),
        root_distance_m: Some(root / n),
    }
}
