//! Whole-sample check of the CMU / iClone mapping (`mappings/cmu-iclone.toml`) on the CMU sample.
//! Ignored by default because the data lives outside the repository; run it with
//! `IMUFLOW_CMU_DIR=/path/to/extracted cargo test --release -p imuflow-motion --test cmu_dataset -- --ignored --nocapture`
//! (the directory that `shared/data/cmu-sample/extract.sh` filled). It prints one line per clip (the
//! numbers of `mappings/README.md`) and checks that every clip retargets with hinge knees and elbows,
//! and that the clips `mappings/cmu-sample.exclude` leaves out are exactly those without a floor.

mod common;

use std::path::Path;

use common::bvh_files;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::limb_joints::{flexion, hinge_elbow, hinge_knee};
use imuflow_body::rotation::angle_between;
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{MotionClip, RetargetOptions, SourceSkeleton, retarget_bvh};

/// A clip has a floor when its lower foot is within 5 cm of it (after the median-lowest-foot
/// alignment) in at least this share of frames. Jumps and runs leave it briefly (at most 16 % of
/// the sample's kept clips); climbing and uneven terrain most of the time (59 % and more).
const MAX_OFF_FLOOR: f64 = 0.25;

/// The file names `cmu-sample.exclude` lists.
fn excluded() -> Vec<String> {
    let list = Path::new(env!("CARGO_MANIFEST_DIR")).join("mappings/cmu-sample.exclude");
    std::fs::read_to_string(list)
        .unwrap()
        .lines()
        .filter_map(|l| {
            let entry = l.split('#').next().unwrap_or_default().trim();
            (!entry.is_empty()).then(|| entry.to_owned())
        })
        .collect()
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Per clip: knee and elbow off-axis p99 (deg), least knee and elbow flexion (p1, deg), the
/// share of frames with the lower foot more than 5 cm from the floor.
struct Checks {
    knee_off_p99: f64,
    knee_flex_p1: f64,
    elbow_off_p99: f64,
    elbow_flex_p1: f64,
    off_floor: f64,
}

fn checks(body: &BodyModel, clip: &MotionClip) -> Checks {
    let mut fk = FkData::new();
    let (mut knee_off, mut knee_flex, mut elbow_off, mut elbow_flex) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut off_floor = 0usize;
    for pose in &clip.poses {
        for knee in [JointId::LEFT_KNEE, JointId::RIGHT_KNEE] {
            let l = pose.parent_from_joint[knee.index()];
            knee_off.push(angle_between(&l, &hinge_knee(&l)).to_degrees());
            knee_flex.push(flexion(knee, &l).unwrap_or_default().to_degrees());
        }
        for elbow in [JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW] {
            let l = pose.parent_from_joint[elbow.index()];
            elbow_off.push(angle_between(&l, &hinge_elbow(&l)).to_degrees());
            elbow_flex.push(flexion(elbow, &l).unwrap_or_default().to_degrees());
        }
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let low = fk
            .position(JointId::LEFT_FOOT)
            .y
            .min(fk.position(JointId::RIGHT_FOOT).y);
        if low.abs() > 0.05 {
            off_floor += 1;
        }
    }
    Checks {
        knee_off_p99: percentile(knee_off, 0.99),
        knee_flex_p1: percentile(knee_flex, 0.01),
        elbow_off_p99: percentile(elbow_off, 0.99),
        elbow_flex_p1: percentile(elbow_flex, 0.01),
        off_floor: off_floor as f64 / clip.poses.len() as f64,
    }
}

#[test]
#[ignore = "needs the extracted CMU sample (IMUFLOW_CMU_DIR)"]
fn every_cmu_clip_retargets_with_hinge_limbs_and_the_excluded_ones_have_no_floor() {
    let dir =
        std::env::var("IMUFLOW_CMU_DIR").expect("set IMUFLOW_CMU_DIR to the extracted sample");
    let mut files = Vec::new();
    bvh_files(Path::new(&dir), &mut files);
    files.sort();
    assert!(!files.is_empty(), "no .bvh files under {dir}");
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
    let map = SourceSkeleton::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("mappings/cmu-iclone.toml"),
    )
    .unwrap();
    let excluded = excluded();
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let bvh = Bvh::read(f).unwrap_or_else(|e| panic!("{e}"));
        let clip = retarget_bvh(&bvh, &map, &body, &RetargetOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(clip.poses.iter().all(|p| p.is_finite()), "{name}");
        let c = checks(&body, &clip);
        println!(
            "{name}: {} frames; knee off-axis p99 {:.1}°, flexion p1 {:.0}°; elbow off Ry·Rx p99 {:.1}°, flexion p1 {:.0}°; lower foot > 5 cm off the floor in {:.0} % of frames",
            clip.poses.len(),
            c.knee_off_p99,
            c.knee_flex_p1,
            c.elbow_off_p99,
            c.elbow_flex_p1,
            100.0 * c.off_floor
        );
        assert!(
            c.knee_off_p99 < 3.0 && c.knee_flex_p1 > -3.0,
            "{name}: knees"
        );
        assert!(
            c.elbow_off_p99 < 1.5 && c.elbow_flex_p1 > -3.0,
            "{name}: elbows"
        );
        let no_floor = c.off_floor > MAX_OFF_FLOOR;
        assert_eq!(
            no_floor,
            excluded.contains(&name),
            "{name}: off the floor in {:.0} % of frames, {} the exclusion list",
            100.0 * c.off_floor,
            if no_floor { "not in" } else { "yet in" }
        );
    }
}
