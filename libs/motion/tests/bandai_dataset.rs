//! Whole-dataset check of BVH parsing and retargeting on the Bandai Namco motion data. Ignored by default
//! because the data lives outside the repository; run it with
//! `IMUFLOW_BANDAI_DIR=/path/to/extracted cargo test -p imuflow-motion --test bandai_dataset -- --ignored`
//! (the directory that `shared/data/bandai-namco-motion/extract.sh` filled).

mod common;

use std::path::Path;

use common::bvh_files;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{RetargetOptions, SourceSkeleton, retarget_bvh};

#[test]
#[ignore = "needs the extracted Bandai Namco data set (IMUFLOW_BANDAI_DIR)"]
fn every_bandai_clip_parses_and_retargets_upright() {
    let dir = std::env::var("IMUFLOW_BANDAI_DIR")
        .expect("set IMUFLOW_BANDAI_DIR to the extracted data set");
    let filter = std::env::var("IMUFLOW_BANDAI_FILTER").unwrap_or_default();
    let mut files = Vec::new();
    bvh_files(Path::new(&dir), &mut files);
    files.retain(|f| f.to_string_lossy().contains(&filter));
    files.sort();
    assert!(!files.is_empty(), "no .bvh files under {dir}");
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    let mut fk = FkData::new();
    let (mut frames, mut far_from_floor) = (0usize, 0usize);
    for f in &files {
        let bvh = Bvh::read(f).unwrap_or_else(|e| panic!("{e}"));
        let clip = retarget_bvh(&bvh, &map, &body, &RetargetOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        for (k, pose) in clip.poses.iter().enumerate() {
            assert!(pose.is_finite(), "{}: frame {k} not finite", f.display());
            forward_kinematics(&body.skeleton, pose, &mut fk);
            let pelvis = fk.position(JointId::PELVIS).y;
            assert!(
                fk.position(JointId::HEAD).y > pelvis,
                "{}: frame {k}: head below pelvis",
                f.display()
            );
            let low = fk
                .position(JointId::LEFT_FOOT)
                .y
                .min(fk.position(JointId::RIGHT_FOOT).y);
            frames += 1;
            if low.abs() > 0.05 {
                far_from_floor += 1;
            }
        }
    }
    let share = far_from_floor as f64 / frames as f64;
    println!(
        "{} clips, {frames} frames, {:.2}% with the lower foot > 5 cm from the floor",
        files.len(),
        share * 100.0
    );
    // The data set has no jumps, sitting or lying (data README); running has flight phases.
    assert!(share < 0.2, "{share}");
}
