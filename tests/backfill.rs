//! Offline, a recording is estimated from its first frame: the calibration stage holds the frames
//! that come before its calibration and releases them calibrated (issue: recordings as they come).
//! Checked on the raw-sensor example graph (a natural start: a 1 s stand, then the bundled
//! sample's walk, through fusion): every frame after the synthesized prelude reaches the estimate
//! calibrated, in order, none lost; with `backfill = false` the first seconds of the walk are
//! calibrating frames, as live.

mod common;

use common::*;
use imuflow_graph::frames::{BodyImuFrame, ImuFrame, MotionFrame, flags, frame_from_bytes};

/// What a run recorded: the fused IMU frames (which carry the source's PRELUDE flag), the
/// calibrated ones and the estimate.
struct Recorded {
    imu: Vec<ImuFrame>,
    body: Vec<BodyImuFrame>,
    motion: Vec<MotionFrame>,
}

impl Recorded {
    /// Seqs of `headers` flagged CALIBRATING that are not part of the synthesized prelude.
    fn calibrating_after_prelude(&self, headers: impl Iterator<Item = (u64, u32)>) -> Vec<u64> {
        headers
            .filter(|(seq, f)| {
                f & flags::CALIBRATING != 0 && !self.imu[*seq as usize].header.has(flags::PRELUDE)
            })
            .map(|(seq, _)| seq)
            .collect()
    }
}

/// Runs the raw-sensor example with `sets`.
fn run(sb: &Sandbox, sets: &[&str]) -> Recorded {
    let rec = sb.path("raw.mcap");
    let mut args = vec![
        "run".to_owned(),
        "configs/examples/raw-imu.toml".to_owned(),
        "--no-progress".to_owned(),
        "--without".to_owned(),
        "viz".to_owned(),
        "--without".to_owned(),
        "val".to_owned(),
        "--set".to_owned(),
        format!("stages.record.params.path={}", rec.display()),
    ];
    for set in sets {
        args.extend(["--set".to_owned(), (*set).to_owned()]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = sb
        .command(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run imuflow");
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    // The recorder reads the source's raw samples (one frame per sample) and its truth (one per
    // graph frame, far fewer seqs): each input ends after its own last frame, so none is dropped.
    let stdout = text(&out.stdout);
    let record = stdout
        .lines()
        .find(|l| l.starts_with("record "))
        .unwrap_or_else(|| panic!("no recorder row in the summary:\n{stdout}"));
    let dropped: u64 = record
        .split_whitespace()
        .nth(4)
        .and_then(|v| v.parse().ok())
        .expect("dropped");
    assert_eq!(dropped, 0, "{record}");
    let messages = mcap_messages(&rec);
    let frames = |topic: &str| -> Vec<Vec<u8>> {
        messages
            .iter()
            .filter(|m| m.0 == topic)
            .map(|m| m.2.clone())
            .collect()
    };
    let imu = frames("fusion.imu")
        .iter()
        .map(|b| frame_from_bytes::<ImuFrame>(b).expect("ImuFrame"))
        .collect();
    let body = frames("calib.body_imu")
        .iter()
        .map(|b| frame_from_bytes::<BodyImuFrame>(b).expect("BodyImuFrame"))
        .collect();
    let motion = frames("opt.motion")
        .iter()
        .map(|b| frame_from_bytes::<MotionFrame>(b).expect("MotionFrame"))
        .collect();
    Recorded { imu, body, motion }
}

#[test]
fn offline_a_recording_is_estimated_from_its_first_frame() {
    let sb = Sandbox::new("backfill");
    let run1 = run(&sb, &[]);
    let (body, motion) = (&run1.body, &run1.motion);
    assert!(body.len() > 800, "{} calibrated IMU frames", body.len());
    // Every frame, in order, none lost: the held frames went out before the live ones.
    for (i, f) in body.iter().enumerate() {
        assert_eq!(f.header.seq, i as u64, "calib.body_imu out of order at {i}");
    }
    assert_eq!(motion.len(), body.len());
    assert_eq!(run1.imu.len(), body.len());
    let prelude = run1
        .imu
        .iter()
        .filter(|f| f.header.has(flags::PRELUDE))
        .count();
    assert!(prelude > 30, "{prelude} prelude frames");
    let held = run1.calibrating_after_prelude(body.iter().map(|f| (f.header.seq, f.header.flags)));
    assert!(held.is_empty(), "calibrating after the prelude: {held:?}");
    let held =
        run1.calibrating_after_prelude(motion.iter().map(|f| (f.header.seq, f.header.flags)));
    assert!(
        held.is_empty(),
        "motion calibrating after the prelude: {held:?}"
    );
    // The walk's first frames carry real orientations (not the identity of a calibrating frame).
    let first = &body[prelude];
    assert_eq!(first.valid_mask, 0b111111);
    assert!(first.bone_orientation_wxyz.iter().any(|q| q[0] < 0.999));

    // Without the backfill the stage behaves as live: the walk's first ~3 s (the natural start's
    // walk_s) are calibrating.
    let run2 = run(&sb, &["stages.calib.params.backfill=false"]);
    let held =
        run2.calibrating_after_prelude(run2.body.iter().map(|f| (f.header.seq, f.header.flags)));
    assert!(
        (120..300).contains(&held.len()),
        "{} calibrating walk frames without the backfill",
        held.len()
    );
    assert_clean(&sb);
}
