//! BVH round trips and retargeting of the committed Bandai walking fixture (no external data needed).

use std::path::{Path, PathBuf};

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::limb_joints::project_limb_joints;
use imuflow_body::rotation::{angle_between, axis_angle_from_rotation};
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{
    FloorAlignment, LengthUnit, MotionClip, RetargetError, RetargetOptions, SourceSkeleton,
    bvh_from_clip, estimate_twists_deg, resample, retarget_bvh,
};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

fn body() -> BodyModel {
    BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
}

fn walk() -> MotionClip {
    let bvh = Bvh::read(&fixture()).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    retarget_bvh(&bvh, &map, &body(), &RetargetOptions::default()).unwrap()
}

#[test]
fn fixture_import_export_import_is_exact() {
    let a = Bvh::read(&fixture()).unwrap();
    assert_eq!(a.joints.len(), 22);
    assert_eq!(a.num_frames(), 48);
    let b = Bvh::parse(&a.to_bvh_string(), "exported.bvh").unwrap();
    assert_eq!(a.values, b.values);
    assert_eq!(a.frame_time_s, b.frame_time_s);
    for (x, y) in a.joints.iter().zip(&b.joints) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.parent, y.parent);
        assert_eq!(x.offset, y.offset);
        assert_eq!(x.channels, y.channels);
        assert_eq!(x.end_sites, y.end_sites);
    }
}

#[test]
fn retargeted_walk_is_upright_with_feet_on_a_common_floor() {
    let body = body();
    let clip = walk();
    assert_eq!(clip.poses.len(), 48);
    let mut fk = FkData::new();
    for (f, pose) in clip.poses.iter().enumerate() {
        assert!(pose.is_finite());
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let pelvis = fk.position(JointId::PELVIS).y;
        assert!(
            fk.position(JointId::HEAD).y > pelvis + 0.4,
            "frame {f}: head not above pelvis"
        );
        for foot in [
            JointId::LEFT_FOOT,
            JointId::RIGHT_FOOT,
            JointId::LEFT_ANKLE,
            JointId::RIGHT_ANKLE,
        ] {
            assert!(
                fk.position(foot).y < pelvis - 0.6,
                "frame {f}: {foot} not below pelvis"
            );
        }
        // The lower foot touches the common floor (y = 0 after alignment) within 3 cm in every frame.
        let low = fk
            .position(JointId::LEFT_FOOT)
            .y
            .min(fk.position(JointId::RIGHT_FOOT).y);
        assert!(low.abs() < 0.03, "frame {f}: lowest foot at {low} m");
        // Standing height stays plausible: pelvis between 0.8 and 1.0 of the leg + ankle height.
        assert!(
            (0.85..1.0).contains(&(pelvis / body.rest_root_height_m)),
            "frame {f}: pelvis {pelvis}"
        );
    }
    // The subject walks forward (+z) about 1.2-1.6 m/s (Bandai "normal" walk).
    let first = clip.poses[0].root_in_world_m;
    let last = clip.poses[47].root_in_world_m;
    let speed = (last - first).z / (47.0 * clip.frame_time_s);
    assert!((0.8..2.0).contains(&speed), "speed {speed}");
}

#[test]
fn knees_and_elbows_bend_about_their_anatomical_axes() {
    let clip = walk();
    for pose in &clip.poses {
        for knee in [JointId::LEFT_KNEE, JointId::RIGHT_KNEE] {
            let v = axis_angle_from_rotation(&pose.parent_from_joint[knee.index()]);
            // Flexion is a positive rotation about +x (the shank swings backwards); no hyperextension,
            // little twist or ab/adduction.
            assert!(v.x > -0.05, "{knee} hyperextended: {v:?}");
            assert!(v.y.abs() < 0.1 && v.z.abs() < 0.1, "{knee} off-axis: {v:?}");
        }
        let l = axis_angle_from_rotation(&pose.parent_from_joint[JointId::LEFT_ELBOW.index()]);
        let r = axis_angle_from_rotation(&pose.parent_from_joint[JointId::RIGHT_ELBOW.index()]);
        // Elbow flexion brings the forearm forward: about −y on the left, +y on the right.
        assert!(l.y < 0.05 && r.y > -0.05, "elbows {l:?} {r:?}");
    }
}

#[test]
fn the_retargeted_knees_and_elbows_are_the_anatomical_joints_the_estimates_are_projected_on() {
    // imuflow_body::limb_joints makes every estimate's knees x hinges and its elbows Ry·Rx
    // joints. That is only right if the truth is: here it is, to the retargeting's precision.
    let clip = walk();
    let mut largest: f64 = 0.0;
    for pose in &clip.poses {
        let mut projected = pose.parent_from_joint;
        project_limb_joints(&mut projected);
        for j in JointId::all() {
            largest = largest.max(
                angle_between(&projected[j.index()], &pose.parent_from_joint[j.index()])
                    .to_degrees(),
            );
        }
    }
    assert!(
        largest < 1.5,
        "the projection moved a true joint by {largest:.2}°"
    );
}

#[test]
fn built_in_twists_agree_with_the_fixture_estimate() {
    let bvh = Bvh::read(&fixture()).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    let est = estimate_twists_deg(&bvh, &map, &body()).unwrap();
    for (joint, deg) in est {
        let built_in = map.twist_deg.get(&joint).copied().unwrap_or(0.0);
        let diff = (deg - built_in + 540.0).rem_euclid(360.0) - 180.0;
        // Shoulders are the least constrained in a walk (arms hang), hence the wider margin.
        let tol = if matches!(joint, JointId::LEFT_SHOULDER | JointId::RIGHT_SHOULDER) {
            35.0
        } else {
            25.0
        };
        assert!(
            diff.abs() < tol,
            "{joint}: estimated {deg:.0}°, built in {built_in}°"
        );
    }
}

#[test]
fn resampling_to_60_hz_interpolates_between_frames() {
    let clip = walk();
    let up = resample(&clip, 60.0).unwrap();
    assert_eq!(up.poses.len(), 2 * 48 - 1);
    assert!((up.frame_time_s - 1.0 / 60.0).abs() < 1e-12);
    // The fixture's frame time is 0.0333333 s (not exactly 1/30), so output frame 2k sits within
    // 1e-5 frames of input frame k; compare with a tolerance accordingly.
    for k in 0..47 {
        let (a, b, mid) = (&clip.poses[k], &clip.poses[k + 1], &up.poses[2 * k + 1]);
        for j in JointId::all() {
            let (ra, rb, rm) = (
                a.parent_from_joint[j.index()],
                b.parent_from_joint[j.index()],
                mid.parent_from_joint[j.index()],
            );
            let half = angle_between(&ra, &rb) / 2.0;
            assert!(
                (angle_between(&ra, &rm) - half).abs() < 1e-3,
                "frame {k} {j}"
            );
            assert!(
                (angle_between(&rm, &rb) - half).abs() < 1e-3,
                "frame {k} {j}"
            );
        }
        let lerp = (a.root_in_world_m + b.root_in_world_m) / 2.0;
        assert!((mid.root_in_world_m - lerp).norm() < 1e-4);
        assert!(
            angle_between(
                &up.poses[2 * k].parent_from_joint[3],
                &a.parent_from_joint[3]
            ) < 1e-3
        );
    }
}

#[test]
fn exported_24_joint_bvh_reads_back_as_the_same_motion() {
    let body = body();
    let clip = walk();
    for unit in [LengthUnit::Metre, LengthUnit::Centimetre] {
        let bvh = bvh_from_clip(&body, &clip, unit, "walk-24.bvh").unwrap();
        let text = bvh.to_bvh_string();
        let parsed = Bvh::parse(&text, "walk-24.bvh").unwrap();
        assert_eq!(parsed.joints.len(), 24);
        let options = RetargetOptions {
            floor: FloorAlignment::Keep,
        };
        let back = retarget_bvh(&parsed, &SourceSkeleton::imuflow(unit), &body, &options).unwrap();
        assert_eq!(back.poses.len(), clip.poses.len());
        for (p, q) in clip.poses.iter().zip(&back.poses) {
            assert!((p.root_in_world_m - q.root_in_world_m).norm() < 1e-9);
            for j in JointId::all() {
                let e = angle_between(
                    &p.parent_from_joint[j.index()],
                    &q.parent_from_joint[j.index()],
                );
                assert!(e < 1e-7, "{j}: {e}");
            }
        }
    }
}

#[test]
fn unknown_source_joint_names_file_line_and_joint() {
    let text = std::fs::read_to_string(fixture())
        .unwrap()
        .replace("JOINT Toes_R", "JOINT Tail");
    let bvh = Bvh::parse(&text, "renamed.bvh").unwrap();
    let err = retarget_bvh(
        &bvh,
        &SourceSkeleton::bandai_namco().unwrap(),
        &body(),
        &RetargetOptions::default(),
    )
    .unwrap_err();
    let line = text.lines().position(|l| l.contains("JOINT Tail")).unwrap() + 1;
    assert!(
        matches!(&err, RetargetError::UnmappedSourceJoint { line: l, joint, .. } if *l == line && joint == "Tail")
    );
    let msg = err.to_string();
    assert!(
        msg.starts_with(&format!("renamed.bvh:{line}:")) && msg.contains("'Tail'"),
        "{msg}"
    );
}

#[test]
fn mapping_to_a_missing_source_joint_names_the_mapping_line() {
    let toml =
        imuflow_motion::retarget::BANDAI_NAMCO_MAPPING_TOML.replace("\"Toes_R\"", "\"Toe_R\"");
    let mut map = SourceSkeleton::from_toml_str(&toml, "my-map.toml").unwrap();
    map.ignore.push("Toes_R".into());
    let bvh = Bvh::read(&fixture()).unwrap();
    let err = retarget_bvh(&bvh, &map, &body(), &RetargetOptions::default()).unwrap_err();
    let line = toml.lines().position(|l| l.contains("\"Toe_R\"")).unwrap() + 1;
    let msg = err.to_string();
    assert!(
        msg.starts_with(&format!("my-map.toml:{line}:")) && msg.contains("Toe_R"),
        "{msg}"
    );
}
