//! The recorded-stream scores on real motion: the bundled sample's true walk
//! (models/sample/walk.mcap, CC BY-NC 4.0), scored as `imuflow compare` would score a variant.

use imuflow_body::{BodyModel, BodyParams};
use imuflow_eval::score::{disagreement, score_against_truth, score_without_truth};
use imuflow_graph::frames::MotionFrame;
use imuflow_recording::{Recorded, Recording};

fn sample_truth() -> Vec<MotionFrame> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/sample/walk.mcap");
    let recording = Recording::load(std::path::Path::new(path), None, None).unwrap();
    recording
        .frames
        .into_iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) => Some(*m),
            Recorded::Imu(_) => None,
        })
        .collect()
}

fn body() -> BodyModel {
    BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
}

#[test]
fn the_truth_scored_against_itself_is_perfect() {
    let truth = sample_truth();
    assert!(truth.len() > 1000, "{} truth frames", truth.len());
    let body = body();
    let s = score_against_truth(&truth, &truth, &body, 60.0);
    // Only the walk is scored: the calibration prelude's 732 frames carry PRELUDE
    // (models/sample/README.md), 779 of the 1511 remain.
    assert_eq!((s.frames, s.runs), (779, 1), "{s:?}");
    assert!(s.joint_position_error_cm.unwrap() < 1e-9);
    assert!(s.angle_error_deg.unwrap() < 1e-4);
    assert!(s.sip_error_deg.unwrap() < 1e-4);
    // The walk travels about 10 m: both windows fit, and a perfect estimate has no error.
    assert!(s.translation_error_2m_m.unwrap() < 1e-9);
    assert!(s.translation_error_7m_m.unwrap() < 1e-9);
    assert_eq!(s.per_frame.seq.len(), s.frames);
    let d = disagreement(&truth, &truth, &body);
    assert_eq!(d.frames, s.frames);
    assert!(d.angle_deg.unwrap() < 1e-4 && d.root_distance_m.unwrap() == 0.0);
}

#[test]
fn real_walking_has_plausible_own_motion_scores() {
    let truth = sample_truth();
    let s = score_without_truth(&truth, &body(), 60.0);
    // Human motion capture at 60 Hz: jitter of a few tenths of a km/s³ (the test split's truth:
    // 0.64, stages/kinematics/README.md); a mistake in units is off by 10³.
    let jitter = s.jitter_km_s3.unwrap();
    assert!((0.05..3.0).contains(&jitter), "jitter {jitter}");
    assert!(s.root_jitter_km_s3.unwrap() < jitter);
    // The height rule also counts the low parts of a swing (toe-off, heel strike) as contact, so
    // real walking scores 0.69 m/s here (the walk alone; 0.36 with the prelude's standing, scored
    // until the PRELUDE flag): the metric's floor, under the walking speed (about 1.3 m/s) that a
    // foot gliding along with the body would score.
    let skating = s.foot_skating_mps.unwrap();
    assert!((0.1..1.0).contains(&skating), "skating {skating}");
    // Real feet barely sink (the foot joint is the ball of the foot, its clearance the floor).
    assert!(s.ground_penetration_m.unwrap() < 0.02, "{s:?}");
}
