//! Calibration files: save, load, re-run with the same calibration; malformed files are refused
//! with the file and field named.

mod common;

use std::path::PathBuf;

use common::*;
use imuflow_calibration::file::{load, save};
use imuflow_calibration::{Calibrator, InertialFrame};
use imuflow_graph::frames::{BodyImuFrame, flags};
use imuflow_synth::prelude::PreludeKind;

fn temp_dir(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("imuflow-calibration-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

#[test]
fn a_saved_calibration_reproduces_the_session_s_output() {
    let motion = synthesize(
        short_clip(),
        prelude(PreludeKind::Walk),
        setup(InertialFrame::ZUp, 50.0, 30.0),
        true,
        21,
    );
    let config = walking(InertialFrame::ZUp);
    let session = run(config, &motion);
    let at = session.calibrated_at().expect("calibrated");
    let calibration = session
        .calibrator
        .calibration()
        .expect("calibrated")
        .clone();
    let dir = temp_dir("roundtrip");
    let path = dir.join("nested/calibration.json");
    save(&calibration, &path).expect("saves");
    let loaded = load(&path).expect("loads");
    assert_eq!(loaded.method, calibration.method);
    for (a, b) in loaded.sensors.iter().zip(&calibration.sensors) {
        assert!((a.heading_correction_rad - b.heading_correction_rad).abs() < 1e-12);
        assert!(
            imuflow_body::rotation::angle_between(&a.sensor_from_bone, &b.sensor_from_bone) < 1e-9
        );
        assert!((a.accel_offset_in_model_mps2 - b.accel_offset_in_model_mps2).norm() < 1e-12);
    }
    // Re-running the recording with the loaded calibration: calibrated from the first frame, and
    // identical to the session's output once it had calibrated.
    let mut rerun = Calibrator::with_calibration(config, loaded);
    for t in 0..motion.len() {
        let mut out = BodyImuFrame::default();
        rerun.push(&motion.imu_frame(t).expect("frame"), &mut out);
        assert!(!out.header.has(flags::CALIBRATING));
        if t >= at {
            let a = out.bone_orientation_wxyz.iter().flatten();
            let b = session.outputs[t].bone_orientation_wxyz.iter().flatten();
            assert!(a.zip(b).all(|(x, y)| (x - y).abs() < 1e-6), "frame {t}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn malformed_files_name_the_file_and_the_field() {
    let dir = temp_dir("malformed");
    let motion = synthesize(
        short_clip(),
        prelude(PreludeKind::Tpose),
        setup(InertialFrame::Model, 0.0, 0.0),
        false,
        1,
    );
    let session = run(tpose(InertialFrame::Model, 0.0), &motion);
    let good = dir.join("good.json");
    save(session.calibrator.calibration().expect("calibrated"), &good).expect("saves");
    let text = std::fs::read_to_string(&good).expect("read");
    let json: serde_json::Value = serde_json::from_str(&text).expect("json");

    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "none.json",
            Box::new(|j| {
                j["sensors"].as_array_mut().expect("array").clear();
            }),
            "field `sensors` is empty",
        ),
        (
            "norm.json",
            Box::new(|j| {
                j["sensors"][2]["sensor_from_bone_wxyz"] = serde_json::json!([2.0, 0.0, 0.0, 0.0]);
            }),
            "field `sensors[2].sensor_from_bone_wxyz` is not a unit quaternion (norm 2)",
        ),
        (
            "order.json",
            Box::new(|j| {
                j["sensors"][1]["name"] = serde_json::json!("left_forearm");
            }),
            "field `sensors[1].name` is \"left_forearm\", out of order or twice",
        ),
        (
            "site.json",
            Box::new(|j| {
                j["sensors"][0]["name"] = serde_json::json!("left_wing");
            }),
            "field `sensors[0].name` is \"left_wing\", not a site of the body model",
        ),
        (
            "version.json",
            Box::new(|j| {
                j["version"] = serde_json::json!(7);
            }),
            "field `version` is 7",
        ),
        (
            "missing.json",
            Box::new(|j| {
                j["sensors"][4]
                    .as_object_mut()
                    .expect("object")
                    .remove("accel_offset_mps2");
            }),
            "missing field `accel_offset_mps2`",
        ),
        (
            "method.json",
            Box::new(|j| {
                j["method"] = serde_json::json!("magic");
            }),
            "unknown variant `magic`",
        ),
    ];
    for (name, edit, expected) in cases {
        let mut j = json.clone();
        edit(&mut j);
        let path = dir.join(name);
        std::fs::write(&path, serde_json::to_string(&j).expect("json")).expect("write");
        let msg = load(&path).expect_err(name).to_string();
        assert!(
            msg.contains(name) && msg.contains(expected),
            "{name}: {msg}"
        );
    }
    // A file of fewer sites is another set's calibration: it loads with its sites (the stage then
    // refuses it for a graph of another set, naming both).
    let mut j = json.clone();
    j["sensors"].as_array_mut().expect("array").pop();
    let five = dir.join("five.json");
    std::fs::write(&five, serde_json::to_string(&j).expect("json")).expect("write");
    assert_eq!(load(&five).expect("five sites").sites.0, 0b1_1111);
    let garbage = dir.join("garbage.json");
    std::fs::write(&garbage, "not json at all").expect("write");
    let msg = load(&garbage).expect_err("garbage").to_string();
    assert!(
        msg.contains("garbage.json") && msg.contains("not a calibration"),
        "{msg}"
    );
    let msg = load(&dir.join("absent.json"))
        .expect_err("absent")
        .to_string();
    assert!(msg.contains("absent.json"), "{msg}");
    let _ = std::fs::remove_dir_all(&dir);
}
