//! A real recording as it comes, end to end with the defaults: the Xsens MTw Awinda walk (MT
//! Manager CSV per sensor, 17 MTw, sensor ids mapped to sites by the folder's `sensors.csv`;
//! fixture in libs/sensor-files/tests/fixtures/xsens-mtw-awinda-walk) through
//! `configs/examples/xsens-mtw.toml` (fusion, walking calibration, GlobalPose on the six sites;
//! and as a full suit, all 17, estimated from the sensed bones). The recording has no truth: what
//! is checked is what a person sees in it (about 5 s standing in an N-pose, walking out, turning,
//! walking back).

mod common;

use std::path::Path;

use common::{Sandbox, text};
use imuflow_body::{BodyModel, BodyParams, FkData, JointId, Pose, forward_kinematics};
use imuflow_graph::frames::{BodyImuFrame, Frame, MotionFrame, flags};
use imuflow_recording::{channels, decode, for_each_record};

const RATE_HZ: f64 = 60.0;

/// Every frame of type `T` on the channel whose topic ends with `port`, end-of-stream left out.
fn frames<T: Frame>(bytes: &[u8], port: &str) -> Vec<T> {
    let channels = channels(bytes).expect("mcap channels");
    let channel = channels
        .values()
        .find(|c| c.topic.ends_with(&format!(".{port}")))
        .unwrap_or_else(|| {
            let topics: Vec<&str> = channels.values().map(|c| c.topic.as_str()).collect();
            panic!("no {port} channel among {topics:?}")
        });
    let mut out = Vec::new();
    for_each_record(bytes, |_, record| {
        if let mcap::records::Record::Message { header, data } = record
            && header.channel_id == channel.id
        {
            let f: T = decode(&data, &channel.topic, out.len() as u64)?;
            out.push(f);
        }
        Ok(())
    })
    .expect("mcap records");
    out.retain(|f| !f.header().is_end());
    out
}

#[test]
fn xsens_mtw_walk_calibrates_stays_on_the_floor_and_walks_out_and_back() {
    let sb = Sandbox::new("xsens-mtw");
    mtw_walk_out_and_back(&sb, &[]);
}

/// The same walk as a full suit (`sensors = "full-suit"`: all 17 MTw read, fused and
/// calibrated) estimated from the sensed bones without networks (`net = "sensed"`).
#[test]
fn xsens_mtw_walk_as_a_full_suit_from_its_sensed_bones_walks_out_and_back() {
    let sb = Sandbox::new("xsens-mtw-suit");
    mtw_walk_out_and_back(
        &sb,
        &[
            "sensors=full-suit",
            "stages.kin.params.net=sensed",
            "stages.opt.params.method=integrate",
        ],
    );
}

/// The same walk as a full suit estimated by PIP's networks trained for that set
/// (`models/full-suit/pip.safetensors`) with PIP's physics.
#[test]
fn xsens_mtw_walk_as_a_full_suit_with_its_networks_walks_out_and_back() {
    let sb = Sandbox::new("xsens-mtw-suit-pip");
    mtw_walk_out_and_back(
        &sb,
        &[
            "sensors=full-suit",
            "stages.kin.params.net=pip",
            "stages.kin.params.weights=models/full-suit/pip.safetensors",
            "stages.opt.params.method=pip",
        ],
    );
}

/// Runs `configs/examples/xsens-mtw.toml` with `extra` overrides and checks what a person sees.
fn mtw_walk_out_and_back(sb: &Sandbox, extra: &[&str]) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mcap = sb.path("mtw.mcap");
    let mut sets = vec![
        format!("stages.record.params.path={}", mcap.display()),
        format!("stages.viz.params.path={}", sb.path("mtw.rrd").display()),
        format!(
            "stages.calib.params.save_to={}",
            sb.path("calibration.json").display()
        ),
    ];
    sets.extend(extra.iter().map(|s| s.to_string()));
    let graph = root.join("configs/examples/xsens-mtw.toml");
    let mut args = vec![
        "run".to_owned(),
        graph.display().to_string(),
        "--no-progress".to_owned(),
    ];
    for s in &sets {
        args.extend(["--set".to_owned(), s.clone()]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    // The graph runs from the workspace root: the example's paths are relative to it.
    let out = sb
        .command(&args)
        .current_dir(root)
        .env("IMUFLOW_LOG", "info")
        .output()
        .expect("run imuflow");
    let log = format!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    // The sites' files, found by sensors.csv: 1253 samples each, none lost.
    assert!(
        log.contains("left_forearm: 1253 samples, 1253 valid")
            && log.contains("pelvis: 1253 samples, 1253 valid"),
        "{log}"
    );

    assert!(log.contains("walking calibration accepted"), "{log}");
    let bytes = std::fs::read(&mcap).expect("the recording");
    // It calibrates: after some frame the calibrated IMUs are no longer CALIBRATING.
    let body_imu: Vec<BodyImuFrame> = frames(&bytes, "body_imu");
    let calibrating = body_imu
        .iter()
        .filter(|f| f.header.has(flags::CALIBRATING))
        .count();
    let calibrated_from = body_imu
        .iter()
        .rposition(|f| f.header.has(flags::CALIBRATING))
        .map_or(0, |k| k + 1);
    assert!(
        calibrated_from < body_imu.len(),
        "never calibrated: {calibrating} of {} frames CALIBRATING\n{log}",
        body_imu.len()
    );

    let motion: Vec<MotionFrame> = frames(&bytes, "motion");
    assert!(motion.len() > 1200, "{} motion frames", motion.len());
    let first_seq = body_imu.get(calibrated_from).map_or(0, |f| f.header.seq);
    // No INVALID frame one second after the calibration is there.
    let settled = first_seq + RATE_HZ as u64;
    let invalid_after: Vec<u64> = motion
        .iter()
        .filter(|f| f.header.seq >= settled && f.header.has(flags::INVALID))
        .map(|f| f.header.seq)
        .collect();
    let invalid_total = motion
        .iter()
        .filter(|f| f.header.has(flags::INVALID))
        .count();

    // Joint positions of every estimated frame with the body the optimizer uses (reference
    // stature), M's y up with the floor at 0.
    let params = BodyParams::builtin().expect("body params");
    let body = BodyModel::new(
        &params,
        params.reference_stature_m(),
        params.reference_mass_kg(),
    )
    .expect("body model");
    let feet: Vec<JointId> = ["left_ankle", "right_ankle", "left_foot", "right_foot"]
        .iter()
        .map(|n| JointId::from_name(n).expect("joint"))
        .collect();
    let mut fk = FkData::new();
    let mut lowest: Vec<f64> = Vec::new();
    let mut path: Vec<[f64; 2]> = Vec::new();
    for f in motion.iter().filter(|f| {
        f.header.seq >= first_seq
            && !f.header.has(flags::INVALID)
            && !f.header.has(flags::CALIBRATING)
    }) {
        let pose = Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m).expect("a pose");
        forward_kinematics(&body.skeleton, &pose, &mut fk);
        lowest.push(
            feet.iter()
                .map(|j| fk.position(*j).y)
                .fold(f64::INFINITY, f64::min),
        );
        let r = f.root_position_m.map(f64::from);
        path.push([r[0], r[2]]);
    }
    let near_floor = lowest.iter().filter(|h| h.abs() <= 0.05).count();
    let mut sorted = lowest.clone();
    sorted.sort_by(f64::total_cmp);
    let median_lowest = sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN);
    let start = path.first().copied().unwrap_or_default();
    let dist = |p: &[f64; 2]| ((p[0] - start[0]).powi(2) + (p[1] - start[1]).powi(2)).sqrt();
    let (far_k, farthest) = path
        .iter()
        .enumerate()
        .map(|(k, p)| (k, dist(p)))
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let back = path.last().map_or(f64::NAN, dist);
    let travelled: f64 = path
        .windows(2)
        .map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt())
        .sum();
    let report = format!(
        "calibrated from seq {first_seq} ({:.1} s; {calibrating} CALIBRATING frames); motion frames {}, INVALID {invalid_total} in all, {} from seq {settled} on; \
         lowest foot joint: median {median_lowest:.3} m, within 5 cm of the floor in {near_floor} of {} frames; \
         root path: farthest {farthest:.2} m from the start at frame {far_k} of {}, {back:.2} m from it at the end, {travelled:.2} m travelled",
        first_seq as f64 / RATE_HZ,
        motion.len(),
        invalid_after.len(),
        lowest.len(),
        path.len(),
    );
    eprintln!("{report}");
    assert!(
        invalid_after.is_empty(),
        "INVALID at {invalid_after:?}: {report}"
    );
    assert!(
        near_floor * 10 >= lowest.len() * 9,
        "feet off the floor: {report}"
    );
    // Out and back: away by metres, the farthest point in the middle part of the walk, and back
    // within a third of that distance.
    assert!(farthest > 2.0, "{report}");
    assert!(
        far_k > path.len() / 5 && far_k < path.len() * 4 / 5,
        "{report}"
    );
    assert!(back < farthest / 3.0, "{report}");
}

#[test]
fn a_lower_body_export_is_refused_naming_the_missing_sites() {
    let sb = Sandbox::new("x-imu3-lower-body");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let graph = root.join("configs/examples/sensor-file.toml");
    let out = sb
        .command(&[
            "run",
            graph.to_str().expect("utf8"),
            "--no-progress",
            "--set",
            "stages.source.params.path=libs/sensor-files/tests/fixtures/x-io-lower-body",
            "--set",
            "stages.source.params.layout=configs/sensor-layouts/x-imu3.toml",
            "--set",
            &format!("stages.record.params.path={}", sb.path("x.mcap").display()),
            "--set",
            &format!("stages.viz.params.path={}", sb.path("x.rrd").display()),
        ])
        .current_dir(root)
        .output()
        .expect("run imuflow");
    let log = format!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(!out.status.success(), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    for words in [
        "x-io-lower-body",
        "no sensor for left_forearm, right_forearm, head",
        "found left_lower_leg, right_lower_leg, pelvis",
        "needs every one of its sites (left_forearm, right_forearm, left_lower_leg, right_lower_leg, head, pelvis)",
        "`sensors`: lower-body",
    ] {
        assert!(log.contains(words), "'{words}' in: {log}");
    }
}
