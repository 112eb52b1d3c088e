//! Restart policies: a live stage with `restart = { ... }` that crashes (or hangs, found by the
//! stall watchdog) is started again and rejoins the running graph (its first frame flagged
//! RESTARTED, the run goes on, the summary lists the restart); one failure more than the policy
//! allows is handled like any crash; the graph file's `restart` table is checked.

mod common;

use common::{Sandbox, assert_clean, example_exe, mcap_messages, text};
use imuflow_graph::frames::{FrameHeader, MotionFrame, flags, frame_from_bytes};

/// A live graph at 60 Hz (4 s): source → counter (user stage, `args`, restart policy `restart`) →
/// recorder of both.
fn graph(sb: &Sandbox, args: &str, restart: &str) -> std::path::PathBuf {
    sb.graph(
        "restart.toml",
        &format!(
            r#"
name = "restart-test"
mode = "live"
rate_hz = 60.0
[stages.source]
kind = "test-source"
params = {{ frames = 240 }}
[stages.counter]
exec = "{}"
args = {args}
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
restart = {restart}
[stages.all]
kind = "recorder"
inputs = {{ imu = "source.imu", count = "counter.count" }}
params = {{ path = "{{dir}}/all.mcap" }}
"#,
            example_exe("external_counter").display()
        ),
    )
}

/// The headers of the counter's recorded frames.
fn headers(sb: &Sandbox) -> Vec<FrameHeader> {
    mcap_messages(&sb.path("all.mcap"))
        .into_iter()
        .filter(|m| m.0 == "counter.count")
        .map(|m| {
            frame_from_bytes::<MotionFrame>(&m.2)
                .expect("a MotionFrame")
                .header
        })
        .collect()
}

/// (seq, flags) of the counter's recorded frames.
fn counts(sb: &Sandbox) -> Vec<(u64, u32)> {
    headers(sb).iter().map(|h| (h.seq, h.flags)).collect()
}

#[test]
fn a_crashed_live_stage_restarts_and_rejoins_the_running_graph() {
    let sb = Sandbox::new("restart");
    let file = graph(
        &sb,
        r#"["--fail-at", "60"]"#,
        "{ max = 2, within_s = 60, backoff_ms = 50 }",
    );
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("restarted 'counter' 1 time(s): exited with code 3"),
        "{stdout}"
    );

    // A live graph may drop a frame under load: counts with some room.
    let frames = counts(&sb);
    let before: Vec<_> = frames.iter().filter(|(seq, _)| *seq <= 60).collect();
    let after: Vec<_> = frames.iter().filter(|(seq, _)| *seq > 60).collect();
    assert!(
        before.len() >= 55,
        "{} frames up to the crash",
        before.len()
    );
    assert!(before.iter().all(|(_, f)| f & flags::RESTARTED == 0));
    // The restarted process took over within a fraction of the 4 s stream and ran to the end.
    assert!(
        after.len() > 120,
        "{} frames after the restart",
        after.len()
    );
    assert!(
        after.last().is_some_and(|(seq, _)| *seq == 239),
        "it ran to the end"
    );
    let flagged: Vec<_> = after
        .iter()
        .filter(|(_, f)| f & flags::RESTARTED != 0)
        .collect();
    assert_eq!(flagged.len(), 1, "one RESTARTED frame: {:?}", &after[..5]);
    assert!(
        flagged[0].0 - after[0].0 < 5,
        "the restart's first frames: {:?}",
        &after[..5]
    );
    // Every frame names the process that published it, so a reader that lost the one RESTARTED
    // frame still sees the restart: 0 from the first process, 1 from the restarted one.
    for h in headers(&sb) {
        assert_eq!(h.restarts, u32::from(h.seq > 60), "frame {}", h.seq);
    }
    assert_clean(&sb);
}

/// A stage with a restart policy that dies during the graph's start-up (before it reported ready)
/// is started again and joins the start-up, and the run streams to its end. (It used to wait for
/// the ready timeout and fail the run as "did not report ready".)
#[test]
fn a_stage_that_dies_during_start_up_is_restarted_into_the_start() {
    let sb = Sandbox::new("restart-start-up");
    let file = graph(&sb, r#"["--fail-before-ready"]"#, "{ max = 1 }");
    let started = std::time::Instant::now();
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
    assert!(stdout.contains("restarted 'counter' 1 time(s)"), "{stdout}");
    // Well within the ready timeout (30 s) it would otherwise have waited out.
    assert!(started.elapsed() < std::time::Duration::from_secs(25));
    let headers = headers(&sb);
    // Every frame came from the restarted process, from the first to the last.
    assert_eq!(headers.first().map(|h| h.seq), Some(0));
    assert_eq!(headers.last().map(|h| h.seq), Some(239));
    assert!(headers.iter().all(|h| h.restarts == 1), "{headers:?}");
    assert_clean(&sb);
}

#[test]
fn a_stage_failing_more_often_than_its_policy_allows_stops_the_run() {
    let sb = Sandbox::new("restart-spent");
    let file = graph(
        &sb,
        r#"["--fail-from", "30"]"#,
        "{ max = 2, backoff_ms = 20 }",
    );
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("'counter'"), "{stderr}");
    assert!(
        stderr.contains("after 2 restart(s) within 60 s (restart.max = 2)"),
        "{stderr}"
    );
    assert!(
        counts(&sb).len() >= 25,
        "the recording is finalized with what came"
    );
    assert_clean(&sb);
}

/// The stall watchdog's finding is a failure like a crash: a hung stage with a restart policy is
/// killed and started again, and the run goes on.
#[test]
fn a_hung_live_stage_is_killed_and_restarted() {
    let sb = Sandbox::new("restart-stall");
    let file = graph(
        &sb,
        r#"["--hang-at", "60"]"#,
        "{ max = 2, within_s = 60, backoff_ms = 50 }",
    );
    let out = sb.run(&[
        "run",
        file.to_str().expect("utf8"),
        "--no-progress",
        "--set",
        "stages.counter.stall_timeout_s=0.5",
    ]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("restarted 'counter' 1 time(s): stalled: took no frame for"),
        "{stdout}"
    );
    let frames = counts(&sb);
    let before = frames.iter().filter(|(seq, _)| *seq <= 60).count();
    let after: Vec<_> = frames.iter().filter(|(seq, _)| *seq > 60).collect();
    assert!(before >= 55, "{before} frames up to the hang");
    // Hung at 1 s, found 0.5 s later, back within a fraction of a second: most of the
    // remaining 3 s are there, RESTARTED on the first, up to the last frame.
    assert!(after.len() > 90, "{} frames after the restart", after.len());
    assert!(after.last().is_some_and(|(seq, _)| *seq == 239));
    assert!(after[0].1 & flags::RESTARTED != 0, "{:?}", &after[..3]);
    assert_eq!(
        after
            .iter()
            .filter(|(_, f)| f & flags::RESTARTED != 0)
            .count(),
        1
    );
    assert_clean(&sb);
}

#[test]
fn bad_restart_tables_are_named() {
    let sb = Sandbox::new("restart-bad");
    for (restart, expected) in [
        ("{ max = 0 }", "max = 0 is out of range"),
        ("{ tries = 3 }", "unknown key 'tries'"),
        ("3", "must be a table"),
    ] {
        let file = graph(&sb, "[]", restart);
        let out = sb.run(&["graph", "check", file.to_str().expect("utf8")]);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{restart}: {stderr}");
        assert!(
            stderr.contains("counter") && stderr.contains(expected),
            "{restart}: {stderr}"
        );
    }
    let source = sb.graph(
        "source.toml",
        r#"
name = "restart-source"
[stages.source]
kind = "test-source"
restart = { max = 1 }
[stages.all]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/x.mcap" }
"#,
    );
    let out = sb.run(&["graph", "check", source.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("a source cannot restart"),
        "{}",
        text(&out.stderr)
    );
}

/// A restarted calibration stage reloads the calibration it had reached (kept in the run folder),
/// so the subject need not calibrate again: after a kill -9 mid-walk, its frames are calibrated
/// again from the restart on (without the reload they would stay CALIBRATING: the T-pose is over).
#[test]
fn a_restarted_calibration_reloads_its_calibration() {
    use common::{wait_for_mark, wait_for_stage, wait_with_timeout};
    use imuflow_graph::frames::BodyImuFrame;
    use std::time::Duration;
    /// 5.5 s into the sample: past the T-pose hold and its calibration.
    const KILL_FROM: u64 = 330;
    let sb = Sandbox::new("restart-calib");
    let sample = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/sample/walk.mcap");
    let file = sb.graph(
        "calib.toml",
        &format!(
            r#"
name = "restart-calibration"
mode = "live"
[stages.source]
kind = "imu-source"
params = {{ mode = "replay", path = "{}", frames = 720 }}
[stages.calib]
kind = "calibration"
inputs = {{ imu = "source.imu" }}
params = {{ method = "tpose", frame = "z-up", heading_deg = 30.0 }}
restart = {{ max = 1, backoff_ms = 50 }}
[stages.marker]
exec = "{}"
args = ["--mark-from", "{KILL_FROM}", "{{dir}}/marked"]
inputs = {{ imu = "source.imu", prev = "marker.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.all]
kind = "recorder"
inputs = {{ body = "calib.body_imu" }}
params = {{ path = "{{dir}}/all.mcap" }}
"#,
            sample.display(),
            example_exe("external_counter").display()
        ),
    );
    let mut child = sb.spawn(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let pid = wait_for_stage(&sb, "calib", Duration::from_secs(10)).expect("the calibration stage");
    // The T-pose hold is over and calibrated, the subject is walking.
    wait_for_mark(&mut child, &sb.path("marked"), KILL_FROM, "");
    // SAFETY: kill(2) of a process this test's graph started.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
    let out = wait_with_timeout(child, Duration::from_secs(60));
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
    assert!(stdout.contains("restarted 'calib' 1 time(s)"), "{stdout}");
    let headers: Vec<FrameHeader> = mcap_messages(&sb.path("all.mcap"))
        .into_iter()
        .filter(|m| m.0 == "calib.body_imu")
        .map(|m| {
            frame_from_bytes::<BodyImuFrame>(&m.2)
                .expect("a BodyImuFrame")
                .header
        })
        .collect();
    // The restarted process's frames carry restart count 1. The one frame flagged RESTARTED
    // may be among those a live recorder drops under load; where it was kept, it is the new
    // process's first.
    let restart = headers
        .iter()
        .position(|h| h.restarts == 1)
        .expect("frames from the restarted calibration");
    let flagged: Vec<usize> = (0..headers.len())
        .filter(|&i| headers[i].has(flags::RESTARTED))
        .collect();
    assert!(
        flagged.is_empty() || flagged == [restart],
        "RESTARTED on frames {flagged:?}, the restarted process's first is {restart}"
    );
    let frames: Vec<(u64, u32)> = headers.iter().map(|h| (h.seq, h.flags)).collect();
    let (before, after) = frames.split_at(restart);
    assert!(
        headers[..restart].iter().all(|h| h.restarts == 0)
            && headers[restart..].iter().all(|h| h.restarts == 1),
        "one restart"
    );
    assert!(
        before.iter().any(|(_, f)| f & flags::CALIBRATING == 0),
        "calibrated before the kill"
    );
    assert!(
        after.len() > 100,
        "{} frames after the restart",
        after.len()
    );
    assert!(
        after.iter().all(|(_, f)| f & flags::CALIBRATING == 0),
        "calibrated from the restart on"
    );
    assert_clean(&sb);
}
