//! The CMU / iClone joint mapping (`mappings/cmu-iclone.toml`) on the committed CMU walking fixture (no
//! external data needed): the whole rig is covered, the prepended T-pose is dropped, the knees and elbows
//! are the anatomical joints of the body model, bending the way people bend, and the feet stay on the
//! floor. The geometric checks use joint positions, independent of the local frames the mapping sets.

use std::path::{Path, PathBuf};

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::limb_joints::{flexion, hinge_elbow, hinge_knee};
use imuflow_body::rotation::angle_between;
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{
    MotionClip, RetargetError, RetargetOptions, SourceSkeleton, estimate_twists_deg, retarget_bvh,
};
use nalgebra::{Rotation3, Vector3};

fn manifest() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn fixture() -> PathBuf {
    manifest().join("tests/fixtures/cmu-007-03-walk-trimmed.bvh")
}

fn mapping() -> SourceSkeleton {
    SourceSkeleton::load(&manifest().join("mappings/cmu-iclone.toml")).unwrap()
}

fn body() -> BodyModel {
    BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
}

fn walk() -> MotionClip {
    let bvh = Bvh::read(&fixture()).unwrap();
    retarget_bvh(&bvh, &mapping(), &body(), &RetargetOptions::default()).unwrap()
}

/// The part of `v` perpendicular to the unit direction `d`.
fn perpendicular(v: Vector3<f64>, d: Vector3<f64>) -> Vector3<f64> {
    v - d * v.dot(&d)
}

/// Where the middle joint of a limb (knee, elbow) sits off the straight line its two neighbours would
/// make if the limb were straight: the middle joint's offset from the line upper -> lower for a knee,
/// the lower joint's offset from the upper bone's continuation for an elbow (the upper arm swings
/// freely, so the forearm's bend is measured against it).
fn bend_direction(fk: &FkData, upper: JointId, middle: JointId, lower: JointId) -> Vector3<f64> {
    let (a, b, c) = (fk.position(upper), fk.position(middle), fk.position(lower));
    let upper_dir = (b - a).normalize();
    perpendicular(c - b, upper_dir)
}

/// The body's facing direction: the pelvis's +z in the world, made horizontal.
fn forward(fk: &FkData) -> Vector3<f64> {
    let z = fk.world_from(JointId::PELVIS) * Vector3::z();
    Vector3::new(z.x, 0.0, z.z).normalize()
}

#[test]
fn the_mapping_covers_the_whole_rig_and_drops_the_prepended_t_pose() {
    let bvh = Bvh::read(&fixture()).unwrap();
    assert_eq!(
        bvh.joints.len(),
        100,
        "the full iClone rig, fingers and face"
    );
    assert_eq!(bvh.num_frames(), 48);
    let map = mapping();
    assert_eq!(map.skip_frames, 1);
    let clip = walk();
    assert_eq!(clip.poses.len(), 47);
    // Without the skip the T-pose is the first frame, 2 m from where the walk starts: a jump no
    // body makes in 1/60 s.
    let mut keep = map.clone();
    keep.skip_frames = 0;
    let with_t_pose = retarget_bvh(&bvh, &keep, &body(), &RetargetOptions::default()).unwrap();
    assert_eq!(with_t_pose.poses.len(), 48);
    let jump = (with_t_pose.poses[1].root_in_world_m - with_t_pose.poses[0].root_in_world_m).norm();
    assert!(jump > 1.0, "T-pose frame {jump} m from the walk");
    // After the skip the root moves like a walk: under 3 cm per frame (1.8 m/s).
    for (k, w) in clip.poses.windows(2).enumerate() {
        let step = (w[1].root_in_world_m - w[0].root_in_world_m).norm();
        assert!(step < 0.03, "frame {k}: root step {step} m");
    }
}

#[test]
fn the_prepended_t_pose_is_the_body_models_identity_pose_up_the_spine_with_level_arms() {
    // Frame 0 alone, not skipped: the rig's T-pose. The mapping's [rest_deg] was measured on it, so
    // the pelvis, spine, neck and head are at identity; the limbs follow the rig's bone directions.
    let mut bvh = Bvh::read(&fixture()).unwrap();
    bvh.values.truncate(bvh.num_channels());
    let mut map = mapping();
    map.skip_frames = 0;
    let body = body();
    let clip = retarget_bvh(&bvh, &map, &body, &RetargetOptions::default()).unwrap();
    let pose = &clip.poses[0];
    let from_identity = |j: JointId| {
        angle_between(&pose.parent_from_joint[j.index()], &Rotation3::identity()).to_degrees()
    };
    for j in [
        JointId::PELVIS,
        JointId::SPINE1,
        JointId::SPINE2,
        JointId::SPINE3,
        JointId::NECK,
        JointId::HEAD,
    ] {
        let deg = from_identity(j);
        assert!(deg < 0.3, "{j}: {deg:.2}° from the T-pose");
    }
    // The rig's T-pose stands with the hips flexed 4° and the knees 8-9°, its elbows straight.
    for (j, most) in [
        (JointId::LEFT_HIP, 6.0),
        (JointId::RIGHT_HIP, 6.0),
        (JointId::LEFT_KNEE, 10.0),
        (JointId::RIGHT_KNEE, 10.0),
        (JointId::LEFT_ELBOW, 2.0),
        (JointId::RIGHT_ELBOW, 2.0),
    ] {
        let deg = from_identity(j);
        assert!(deg < most, "{j}: {deg:.1}° from the T-pose");
    }
    // Both arm bones lie along ±x, as in the body model's T-pose.
    let mut fk = FkData::new();
    forward_kinematics(&body.skeleton, pose, &mut fk);
    for (shoulder, elbow, wrist, side) in [
        (
            JointId::LEFT_SHOULDER,
            JointId::LEFT_ELBOW,
            JointId::LEFT_WRIST,
            1.0,
        ),
        (
            JointId::RIGHT_SHOULDER,
            JointId::RIGHT_ELBOW,
            JointId::RIGHT_WRIST,
            -1.0,
        ),
    ] {
        for (a, b) in [(shoulder, elbow), (elbow, wrist)] {
            let d = (fk.position(b) - fk.position(a)).normalize();
            let deg = d
                .dot(&(Vector3::x() * side))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!(
                deg < 3.0,
                "{a} -> {b}: {deg:.1}° off the T-pose's level arm"
            );
        }
    }

    // The twists the mapping holds are what estimate_twists_deg measures on that frame, the arms
    // rolled by the documented 30° that makes the elbows hinges.
    let estimate = estimate_twists_deg(&bvh, &map, &body).unwrap();
    for (joint, deg) in estimate {
        let arm_roll = match joint {
            JointId::LEFT_SHOULDER | JointId::LEFT_ELBOW => -30.0,
            JointId::RIGHT_SHOULDER | JointId::RIGHT_ELBOW => 30.0,
            _ => 0.0,
        };
        let mapped = map.twist_deg.get(&joint).copied().unwrap_or(0.0);
        let diff = (deg + arm_roll - mapped + 540.0).rem_euclid(360.0) - 180.0;
        assert!(
            diff.abs() < 1.5,
            "{joint}: estimated {deg:.1}° ({arm_roll:+}°), mapped {mapped}°"
        );
    }
}

#[test]
fn knees_are_x_hinges_that_bend_forward() {
    let body = body();
    let clip = walk();
    let mut fk = FkData::new();
    let mut most = [0.0f64; 2];
    for (f, pose) in clip.poses.iter().enumerate() {
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let ahead = forward(&fk);
        for (k, (hip, knee, ankle)) in [
            (JointId::LEFT_HIP, JointId::LEFT_KNEE, JointId::LEFT_ANKLE),
            (
                JointId::RIGHT_HIP,
                JointId::RIGHT_KNEE,
                JointId::RIGHT_ANKLE,
            ),
        ]
        .into_iter()
        .enumerate()
        {
            let local = pose.parent_from_joint[knee.index()];
            let off_axis = angle_between(&local, &hinge_knee(&local)).to_degrees();
            assert!(
                off_axis < 3.0,
                "frame {f}: {knee} {off_axis:.1}° off the x hinge"
            );
            let bend = flexion(knee, &local).unwrap().to_degrees();
            assert!(bend > -3.0, "frame {f}: {knee} hyperextended by {bend:.1}°");
            most[k] = most[k].max(bend);
            if bend > 20.0 {
                // A bent knee lies in front of the line from the hip to the ankle: the shank
                // swings back from the thigh, in the body's facing direction.
                let line = (fk.position(ankle) - fk.position(hip)).normalize();
                let off = perpendicular(fk.position(knee) - fk.position(hip), line);
                assert!(
                    off.dot(&ahead) > 0.8 * off.norm(),
                    "frame {f}: {knee} bends {off:?}, the body faces {ahead:?}"
                );
            }
        }
    }
    // A walk bends both knees well past 30° in its swing phases.
    assert!(
        most.iter().all(|m| *m > 30.0),
        "knee flexion maxima {most:?}"
    );
}

#[test]
fn elbows_flex_forward_about_their_hinge_and_the_arms_are_untwisted() {
    let body = body();
    let clip = walk();
    let mut fk = FkData::new();
    let mut bent_frames = 0;
    for (f, pose) in clip.poses.iter().enumerate() {
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let ahead = forward(&fk);
        for (shoulder, elbow, wrist) in [
            (
                JointId::LEFT_SHOULDER,
                JointId::LEFT_ELBOW,
                JointId::LEFT_WRIST,
            ),
            (
                JointId::RIGHT_SHOULDER,
                JointId::RIGHT_ELBOW,
                JointId::RIGHT_WRIST,
            ),
        ] {
            let local = pose.parent_from_joint[elbow.index()];
            // Ry(flexion)·Rx(twist): the Rz left between them is what the hinge cannot do.
            let off_axis = angle_between(&local, &hinge_elbow(&local)).to_degrees();
            assert!(
                off_axis < 2.0,
                "frame {f}: {elbow} {off_axis:.1}° off Ry·Rx"
            );
            let bend = flexion(elbow, &local).unwrap().to_degrees();
            assert!(
                bend > -3.0,
                "frame {f}: {elbow} hyperextended by {bend:.1}°"
            );
            // The forearm's own twist (the Rx of Ry·Rz·Rx, its second row (sin b, cos b cos c,
            // −cos b sin c)) stays small in a walk: the forearm is not rolled against the upper arm.
            let m = local.matrix();
            let rx = (-m[(1, 2)]).atan2(m[(1, 1)]).to_degrees();
            assert!(
                rx.abs() < 15.0,
                "frame {f}: {elbow} forearm twisted {rx:.1}°"
            );
            if bend > 15.0 {
                // Hanging arms flex forward: the forearm leaves the upper arm's line towards
                // where the body faces, not sideways (a rolled upper arm would swing it sideways).
                bent_frames += 1;
                let off = bend_direction(&fk, shoulder, elbow, wrist);
                assert!(
                    off.dot(&ahead) > 0.8 * off.norm(),
                    "frame {f}: {elbow} bends {off:?}, the body faces {ahead:?}"
                );
            }
        }
    }
    assert!(bent_frames > 20, "only {bent_frames} bent-elbow samples");
}

#[test]
fn the_walk_stands_on_the_floor_and_goes_where_it_faces() {
    let body = body();
    let clip = walk();
    let mut fk = FkData::new();
    let mut facing = Vector3::zeros();
    for (f, pose) in clip.poses.iter().enumerate() {
        assert!(pose.is_finite());
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let pelvis = fk.position(JointId::PELVIS).y;
        assert!(
            fk.position(JointId::HEAD).y > pelvis + 0.4,
            "frame {f}: head not above pelvis"
        );
        // The lower foot touches the floor (y = 0 after alignment) within 3 cm in every frame.
        let low = fk
            .position(JointId::LEFT_FOOT)
            .y
            .min(fk.position(JointId::RIGHT_FOOT).y);
        assert!(low.abs() < 0.03, "frame {f}: lowest foot at {low} m");
        facing += forward(&fk);
        assert!(
            (0.85..1.0).contains(&(pelvis / body.rest_root_height_m)),
            "frame {f}: pelvis {pelvis}"
        );
    }
    // The walk goes forward, where the pelvis faces, at a walking speed.
    let travel = clip.poses[46].root_in_world_m - clip.poses[0].root_in_world_m;
    let travel = Vector3::new(travel.x, 0.0, travel.z);
    let along = travel.dot(&facing.normalize());
    assert!(
        along > 0.9 * travel.norm(),
        "travel {travel:?}, facing {facing:?}"
    );
    let speed = along / (46.0 * clip.frame_time_s);
    assert!((0.6..2.0).contains(&speed), "speed {speed} m/s");
}

#[test]
fn a_clip_with_nothing_after_the_skipped_frames_is_refused_with_its_counts() {
    let mut bvh = Bvh::read(&fixture()).unwrap();
    bvh.values.truncate(bvh.num_channels());
    let err = retarget_bvh(&bvh, &mapping(), &body(), &RetargetOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            RetargetError::NoFrames {
                frames: 1,
                skipped: 1,
                ..
            }
        ),
        "{err}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("cmu-007-03-walk-trimmed.bvh") && msg.contains("skips 1"),
        "{msg}"
    );
    // A negative count is not a count: refused with the file and line.
    let text = std::fs::read_to_string(manifest().join("mappings/cmu-iclone.toml"))
        .unwrap()
        .replace("skip_frames = 1", "skip_frames = -1");
    let err = SourceSkeleton::from_toml_str(&text, "neg.toml").unwrap_err();
    let line = text
        .lines()
        .position(|l| l.contains("skip_frames"))
        .unwrap()
        + 1;
    assert!(
        err.to_string().contains("neg.toml") && err.to_string().contains(&format!("line {line}")),
        "{err}"
    );
}
