//! `imuflow_export::export` on the bundled sample's true motion (models/sample/walk.mcap, channel
//! `source.truth`): each format read back by an independent reader of it gives the recorded poses;
//! bad input is named and leaves no file behind.

mod common;

use std::path::Path;

use common::{sample, truth_after_prelude};

use imuflow_body::rotation::{angle_between, rotation_from_quat_wxyz};
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_export::{ExportError, ExportOptions, Format, export};
use imuflow_graph::frames::{MotionFrame, flags};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::npz::{AmassOptions, read_amass_npz};
use imuflow_motion::retarget::{
    FloorAlignment, LengthUnit, RetargetOptions, SourceSkeleton, retarget_bvh,
};
use imuflow_recording::{Recorded, Recording};

fn options(out: &Path, format: Format) -> ExportOptions {
    ExportOptions {
        input: sample(),
        channel: "source.truth".into(),
        format,
        out: out.to_owned(),
        unit: LengthUnit::Metre,
        keep_all: false,
        stature_m: 1.75,
        all_joints: false,
    }
}

fn assert_same_motion(truth: &[MotionFrame], poses: &[imuflow_body::Pose], rad: f64, m: f64) {
    assert_eq!(truth.len(), poses.len());
    for (frame, pose) in truth.iter().zip(poses) {
        for j in JointId::all() {
            let q = frame.local_pose_wxyz[j.index()].map(f64::from);
            let want = rotation_from_quat_wxyz(&q).expect("a rotation");
            let e = angle_between(&want, &pose.parent_from_joint[j.index()]);
            assert!(e <= rad, "frame {} joint {j}: {e} rad", frame.header.seq);
        }
        let p = frame.root_position_m.map(f64::from);
        let d = (nalgebra::Vector3::new(p[0], p[1], p[2]) - pose.root_in_world_m).norm();
        assert!(d <= m, "frame {}: root {d} m off", frame.header.seq);
    }
}

#[test]
fn npz_reads_back_as_the_recorded_motion() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("truth.npz");
    let done = export(&options(&out, Format::Npz)).expect("exports");
    let truth = truth_after_prelude();
    assert_eq!(done.frames, truth.len());
    assert_eq!(done.first_seq, truth[0].header.seq);
    // models/sample/README.md: 1511 frames, the prelude and calibration before the walk.
    assert_eq!(done.frames + done.left_out, 1511);
    assert_eq!(done.rate_hz, 60.0);
    let clip = read_amass_npz(&out, &AmassOptions::default()).expect("reads back");
    assert!((clip.rate_hz() - 60.0).abs() < 1e-9);
    // Issue 41: the round trip within 1e-4 rad and 0.1 mm (f32 on the wire).
    assert_same_motion(&truth, &clip.poses, 1e-4, 1e-4);
}

#[test]
fn bvh_reads_back_as_the_recorded_motion_in_either_unit() {
    let dir = tempfile::tempdir().expect("temp dir");
    let body = BodyModel::new(&BodyParams::builtin().expect("body"), 1.75, 70.0).expect("body");
    let truth = truth_after_prelude();
    for unit in [LengthUnit::Metre, LengthUnit::Centimetre] {
        let out = dir.path().join(format!("truth-{unit:?}.bvh"));
        let mut o = options(&out, Format::Bvh);
        o.unit = unit;
        export(&o).expect("exports");
        let bvh = Bvh::read(&out).expect("a BVH");
        assert_eq!(bvh.joints.len(), 24);
        assert!((1.0 / bvh.frame_time_s - 60.0).abs() < 1e-6);
        let keep = RetargetOptions {
            floor: FloorAlignment::Keep,
        };
        let back = retarget_bvh(&bvh, &SourceSkeleton::imuflow(unit), &body, &keep).expect("reads");
        assert_same_motion(&truth, &back.poses, 1e-4, 1e-4);
    }
}

#[test]
fn keep_all_exports_every_recorded_frame() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("all.npz");
    let mut o = options(&out, Format::Npz);
    o.keep_all = true;
    let done = export(&o).expect("exports");
    assert_eq!((done.frames, done.left_out, done.first_seq), (1511, 0, 0));
    assert_eq!(done.first_time_s, 0.0);
}

/// Bad input: the error names the file (and the channel), and no file is left at the output.
#[test]
fn bad_input_is_named_and_writes_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("x.bvh");
    let check = |o: ExportOptions, expect: &[&str]| {
        let e = export(&o).expect_err("refused");
        let text = e.to_string();
        for part in expect {
            assert!(text.contains(part), "{text:?} lacks {part:?}");
        }
        assert!(
            std::fs::read_dir(dir.path()).expect("dir").next().is_none(),
            "nothing left behind after: {text}"
        );
        e
    };
    let mut o = options(&out, Format::Bvh);
    o.channel = "source.imu".into();
    let e = check(
        o,
        &[
            "walk.mcap",
            "'source.imu'",
            "ImuFrame",
            "MotionFrame channels: source.truth",
        ],
    );
    assert!(matches!(e, ExportError::NotMotion { .. }));

    let mut o = options(&out, Format::Bvh);
    o.channel = "opt.motion".into();
    let e = check(o, &["walk.mcap", "no channel 'opt.motion'", "source.truth"]);
    assert!(matches!(e, ExportError::NoChannel { .. }));

    // Inputs live in a folder of their own, so the output folder must stay empty.
    let inputs = tempfile::tempdir().expect("temp dir");
    let text_file = inputs.path().join("notes.txt");
    std::fs::write(&text_file, "not an mcap file\n").expect("write");
    let mut o = options(&out, Format::Bvh);
    o.input = text_file;
    let e = check(o, &["notes.txt", "not a readable imuflow recording"]);
    assert!(matches!(e, ExportError::NotARecording { .. }));

    let mut o = options(&out, Format::Npz);
    o.input = dir.path().join("missing.mcap");
    let e = check(o, &["missing.mcap", "cannot read"]);
    assert!(matches!(e, ExportError::Read { .. }));
}

/// The export is an ordinary file: readable by whoever may read a file its user creates there
/// (not the owner-only mode of the temporary file it is written as).
#[cfg(unix)]
#[test]
fn the_export_has_the_mode_of_a_new_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().expect("temp dir");
    let plain = dir.path().join("plain");
    std::fs::write(&plain, b"").expect("write");
    let mode = |p: &Path| std::fs::metadata(p).expect("metadata").permissions().mode() & 0o777;
    for format in [Format::Bvh, Format::Glb, Format::Npz] {
        let out = dir.path().join(format!("truth.{format:?}"));
        export(&options(&out, format)).expect("exports");
        assert_eq!(mode(&out), mode(&plain), "{format:?}");
    }
}

/// A channel whose frames are all calibration or prelude has nothing to export, and says why.
#[test]
fn a_channel_with_only_left_out_frames_is_empty_and_says_why() {
    let dir = tempfile::tempdir().expect("temp dir");
    // The sample's truth cut to its prelude: written as a recording the way the recorder writes.
    let recording = Recording::load(&sample(), None, None).expect("the sample");
    let prelude: Vec<MotionFrame> = recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) if m.header.flags & flags::PRELUDE != 0 => Some(**m),
            _ => None,
        })
        .take(30)
        .collect();
    assert_eq!(prelude.len(), 30);
    let path = dir.path().join("prelude.mcap");
    write_motion_recording(&path, "source.truth", &prelude);
    let out = dir.path().join("x.npz");
    let mut o = options(&out, Format::Npz);
    o.input = path.clone();
    let e = export(&o).expect_err("nothing to export");
    let text = e.to_string();
    assert!(
        text.contains("prelude.mcap") && text.contains("'source.truth'"),
        "{text}"
    );
    assert!(
        text.contains("30 recorded") && text.contains("--keep-all"),
        "{text}"
    );
    assert!(!out.exists());
    o.keep_all = true;
    assert_eq!(export(&o).expect("kept").frames, 30);
}

/// An mcap file with one raw MotionFrame channel, as the recorder writes it (schema named by the
/// frame type, message encoding `imuflow-raw`).
fn write_motion_recording(path: &Path, topic: &str, frames: &[MotionFrame]) {
    use imuflow_graph::frames::Frame;
    let file = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    let mut writer = mcap::Writer::new(file).expect("writer");
    let schema = writer
        .add_schema(MotionFrame::layout().type_name, "imuflow-layout", b"")
        .expect("schema");
    let channel = writer
        .add_channel(
            schema,
            topic,
            imuflow_recording::RAW_ENCODING,
            &Default::default(),
        )
        .expect("channel");
    for (i, f) in frames.iter().enumerate() {
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: i as u32,
                    log_time: f.header.capture_ns,
                    publish_time: f.header.capture_ns,
                },
                bytemuck::bytes_of(f),
            )
            .expect("message");
    }
    writer.finish().expect("finish");
}
