//! Real multi-process graphs: normal completion, a crashing stage, Ctrl-C, determinism, feedback,
//! live mode, and no shared-memory leftovers after any of them.

mod common;

use std::time::{Duration, Instant};

use common::{Sandbox, assert_clean, example_exe, mcap_messages, text};
use imuflow_graph::frames::{FrameHeader, ImuFrame, MotionFrame, flags, frame_from_bytes};

const SMOKE: &str = r#"
name = "smoke-test"
[stages.source]
kind = "test-source"
params = { frames = 120, seed = 4, invalid_every = 40 }
[stages.record]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/out.mcap", json = true }
[stages.viz]
kind = "rerun-logger"
inputs = { imu = "source.imu" }
params = { path = "{dir}/out.rrd" }
"#;

#[test]
fn smoke_graph_records_every_frame_to_mcap_and_rrd() {
    let sb = Sandbox::new("smoke");
    let graph = sb.graph("smoke.toml", SMOKE);
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("graph 'smoke-test' finished"), "{stdout}");
    assert!(
        stdout
            .lines()
            .any(|l| l.starts_with("record") && l.contains(" 120 ")),
        "summary counts frames:\n{stdout}"
    );

    let messages = mcap_messages(&sb.path("out.mcap"));
    let raw: Vec<_> = messages.iter().filter(|m| m.0 == "source.imu").collect();
    let json: Vec<_> = messages
        .iter()
        .filter(|m| m.0 == "source.imu/json")
        .collect();
    assert_eq!(raw.len(), 120);
    assert_eq!(json.len(), 120);
    for (i, (_, seq, data)) in raw.iter().enumerate() {
        let frame: ImuFrame = frame_from_bytes(data).expect("raw message is one ImuFrame");
        assert_eq!(frame.header.seq, i as u64);
        assert_eq!(*seq, i as u32);
        // invalid_every = 40: frames 39, 79, 119 lose sensor 0 and are flagged INVALID.
        let expect_invalid = i % 40 == 39;
        assert_eq!(
            frame.header.has(flags::INVALID),
            expect_invalid,
            "frame {i}"
        );
        assert_eq!(frame.valid_mask & 1 == 0, expect_invalid, "frame {i}");
        // Offline capture time is seq / rate (60 Hz).
        assert_eq!(frame.header.capture_ns, (i as f64 * 1e9 / 60.0) as u64);
    }
    let first: serde_json::Value = serde_json::from_slice(&json[0].2).expect("json message");
    assert_eq!(first["header"]["seq"], 0);
    assert_eq!(
        first["orientation_wxyz"].as_array().map(Vec::len),
        Some(imuflow_graph::frames::MAX_SITES)
    );

    let rrd = std::fs::metadata(sb.path("out.rrd")).expect("rrd written");
    assert!(rrd.len() > 10_000, "rrd has content ({} bytes)", rrd.len());
    assert_clean(&sb);
}

#[test]
fn replaying_the_same_input_twice_records_identical_frames() {
    let sb = Sandbox::new("determinism");
    let graph = sb.graph("smoke.toml", SMOKE);
    let mut runs = Vec::new();
    for name in ["a.mcap", "b.mcap"] {
        let path = sb.path(name);
        let set = format!("stages.record.params.path={}", path.display());
        let out = sb.run(&[
            "run",
            graph.to_str().expect("utf8"),
            "--no-progress",
            "--set",
            &set,
        ]);
        assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
        runs.push(mcap_messages(&path));
    }
    let strip = |msgs: &Vec<(String, u32, Vec<u8>)>| -> Vec<Vec<u8>> {
        msgs.iter()
            .filter(|m| m.0 == "source.imu")
            .map(|m| {
                // publish_ns is wall-clock; everything else must match byte for byte.
                let mut bytes = m.2.clone();
                let at = std::mem::offset_of!(FrameHeader, publish_ns);
                bytes[at..at + 8].fill(0);
                bytes
            })
            .collect()
    };
    let (a, b) = (strip(&runs[0]), strip(&runs[1]));
    assert_eq!(a.len(), 120);
    assert!(
        a == b,
        "recorded frames differ between two runs of the same input"
    );
    assert_clean(&sb);
}

fn crash_graph(sb: &Sandbox) -> std::path::PathBuf {
    // A live source (paced at 60 Hz), a recorder, and an external stage that reports ready,
    // then fails after half a second.
    sb.graph(
        "crash.toml",
        r#"
name = "crash-test"
mode = "live"
[stages.source]
kind = "test-source"
params = { frames = 100000 }
[stages.record]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/crash.mcap" }
[stages.crasher]
exec = "/bin/sh"
args = ["-c", "echo '@imuflow ready'; echo '@imuflow connected'; sleep 0.5; echo 'boom: simulated sensor failure' >&2; exit 3"]
inputs = { imu = "source.imu" }
"#,
    )
}

#[test]
fn a_failing_stage_stops_the_run_quickly_naming_it_and_recordings_stay_valid() {
    let sb = Sandbox::new("crash");
    let graph = crash_graph(&sb);
    let start = Instant::now();
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let took = start.elapsed();
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr:\n{stderr}");
    assert!(
        stderr.contains("stage 'crasher' failed: exited with code 3"),
        "{stderr}"
    );
    assert!(
        stderr.contains("boom: simulated sensor failure"),
        "last stderr lines shown:\n{stderr}"
    );
    // Start-up plus 0.5 s of running plus the stop, well under the 100000-frame stream (28 min at
    // 60 Hz): found at the failure, not at the stream's end. The bound leaves room for a debug
    // build's start-up on a loaded machine.
    assert!(took < Duration::from_secs(15), "run took {took:?}");

    let messages = mcap_messages(&sb.path("crash.mcap"));
    let frames = messages.iter().filter(|m| m.0 == "source.imu").count();
    assert!(
        frames >= 10,
        "the recorder kept what it had received ({frames} frames)"
    );
    assert_clean(&sb);
}

#[test]
fn sigint_stops_the_graph_cleanly_with_valid_files() {
    let sb = Sandbox::new("sigint");
    let graph = sb.graph(
        "live.toml",
        &SMOKE
            .replace(
                "name = \"smoke-test\"",
                "name = \"sigint-test\"\nmode = \"live\"",
            )
            .replace("frames = 120", "frames = 100000"),
    );
    let mut child = sb.spawn(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    std::thread::sleep(Duration::from_millis(1500));
    // SAFETY: sending SIGINT to the child we just spawned.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "imuflow did not stop within 10 s of SIGINT"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output().expect("output");
    assert_eq!(status.code(), Some(130), "stderr:\n{}", text(&out.stderr));
    let messages = mcap_messages(&sb.path("out.mcap"));
    let frames = messages.iter().filter(|m| m.0 == "source.imu").count();
    // ~1.5 s at 60 Hz, minus start-up.
    assert!((20..200).contains(&frames), "recorded {frames} frames");
    assert!(
        std::fs::metadata(sb.path("out.rrd"))
            .map(|m| m.len())
            .unwrap_or(0)
            > 1000
    );
    assert_clean(&sb);
}

#[test]
fn feedback_edges_deliver_the_previous_frame_to_an_external_stage() {
    let sb = Sandbox::new("feedback");
    let exe = example_exe("external_counter");
    assert!(
        exe.is_file(),
        "cargo test builds examples: {}",
        exe.display()
    );
    let graph = sb.graph(
        "feedback.toml",
        &format!(
            r#"
name = "feedback-test"
[stages.source]
kind = "test-source"
params = {{ frames = 200, invalid_every = 50 }}
[stages.counter]
exec = "{}"
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.record]
kind = "recorder"
inputs = {{ count = "counter.count" }}
params = {{ path = "{{dir}}/count.mcap" }}
"#,
            exe.display()
        ),
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let messages = mcap_messages(&sb.path("count.mcap"));
    assert_eq!(messages.len(), 200);
    for (i, (_, _, data)) in messages.iter().enumerate() {
        let m: MotionFrame = frame_from_bytes(data).expect("MotionFrame");
        assert_eq!(m.header.seq, i as u64);
        assert_eq!(
            m.q[0],
            i as f32,
            "frame {i}: feedback must hold exactly frame {}",
            i as i64 - 1
        );
        // INVALID from the source propagates through the external stage.
        assert_eq!(m.header.has(flags::INVALID), i % 50 == 49, "frame {i}");
        assert_eq!(m.q[1], if i % 50 == 49 { 5.0 } else { 6.0 });
    }
    assert_clean(&sb);
}

#[test]
fn fan_out_delivers_every_frame_to_every_reader() {
    let sb = Sandbox::new("fanout");
    let graph = sb.graph(
        "fanout.toml",
        r#"
name = "fanout-test"
[stages.source]
kind = "test-source"
params = { frames = 300 }
[stages.a]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/a.mcap" }
[stages.b]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/b.mcap" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let a = mcap_messages(&sb.path("a.mcap"));
    let b = mcap_messages(&sb.path("b.mcap"));
    assert_eq!(a.len(), 300);
    assert_eq!(b.len(), 300);
    assert!(
        a.iter().zip(&b).all(|(x, y)| x.2 == y.2),
        "both readers got the same frames"
    );
    assert_clean(&sb);
}

#[test]
fn a_stage_that_fails_before_ready_is_named() {
    let sb = Sandbox::new("early");
    let graph = sb.graph(
        "early.toml",
        r#"
name = "early-failure"
[stages.source]
kind = "test-source"
[stages.broken]
exec = "/bin/sh"
args = ["-c", "echo 'cannot open the sensor port' >&2; exit 7"]
inputs = { imu = "source.imu" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("stage 'broken' failed: exited with code 7"),
        "{stderr}"
    );
    assert!(stderr.contains("cannot open the sensor port"), "{stderr}");
    assert_clean(&sb);
}

#[test]
fn a_run_removes_what_a_killed_earlier_run_left_behind() {
    let sb = Sandbox::new("stale");
    let graph = sb.graph(
        "live.toml",
        &SMOKE
            .replace("name = \"smoke-test\"", "name = \"stale\"\nmode = \"live\"")
            .replace("frames = 120", "frames = 100000"),
    );
    let mut child = sb
        .command(&["run", graph.to_str().expect("utf8"), "--no-progress", "-q"])
        .spawn()
        .expect("start");
    std::thread::sleep(Duration::from_millis(1200));
    // kill -9 the launcher: nobody cleans up; its stages see stdin close and exit.
    child.kill().expect("kill");
    let _ = child.wait();
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        !sb.leftovers().is_empty(),
        "a killed launcher leaves shared memory behind"
    );
    let out = sb.run(&["clean"]);
    assert!(out.status.success());
    assert!(
        text(&out.stdout).contains("removed"),
        "{}",
        text(&out.stdout)
    );
    assert_clean(&sb);
}

#[test]
fn offline_back_pressure_loses_nothing_when_a_reader_starts_late() {
    // The relay subscribes before the source's publisher exists (the source is slow to set up),
    // and reads its first frame long after the source filled its buffer. Offline graphs must
    // block the source, not discard: iceoryx2 discards for a reader that has not completed its
    // half of the connection, which the start handshake (connect before go) rules out.
    let sb = Sandbox::new("late-reader");
    let graph = sb.graph(
        "late.toml",
        r#"
name = "late-reader"
[stages.src]
kind = "bench-source"
params = { frames = 3000, setup_delay_ms = 300 }
[stages.slow]
kind = "relay"
inputs = { in = "src.out" }
params = { start_delay_ms = 400 }
[stages.rec]
kind = "recorder"
inputs = { m = "slow.out" }
params = { path = "{dir}/late.mcap" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let messages = mcap_messages(&sb.path("late.mcap"));
    assert_eq!(messages.len(), 3000, "every frame arrives");
    for (i, (_, _, data)) in messages.iter().enumerate() {
        let m: MotionFrame = frame_from_bytes(data).expect("MotionFrame");
        assert_eq!(m.q[0], i as f32, "frame {i} in order");
    }
    assert_clean(&sb);
}

#[test]
fn a_live_stage_that_falls_behind_drops_and_counts_frames() {
    // Live: the source keeps its 60 Hz pace; the relay starts reading 0.5 s (30 frames) late, its
    // 16-frame buffer overflows, and the oldest frames are dropped and counted, not queued.
    let sb = Sandbox::new("live-drop");
    let graph = sb.graph(
        "live.toml",
        r#"
name = "live-drop"
mode = "live"
[stages.src]
kind = "bench-source"
params = { frames = 90, rate_hz = 60.0 }
[stages.slow]
kind = "relay"
inputs = { in = "src.out" }
params = { start_delay_ms = 500 }
[stages.rec]
kind = "recorder"
inputs = { m = "slow.out" }
params = { path = "{dir}/live.mcap" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let row: Vec<&str> = stdout
        .lines()
        .find(|l| l.starts_with("slow "))
        .expect("summary row for 'slow'")
        .split_whitespace()
        .collect();
    let (frames_in, dropped): (u64, u64) = (
        row[2].parse().expect("frames in"),
        row[4].parse().expect("dropped"),
    );
    assert!(
        dropped >= 10,
        "0.5 s late at 60 Hz, 30 frames behind a 16-frame buffer, must drop ~14, counted \
         {dropped}\n{stdout}"
    );
    assert_eq!(
        frames_in + dropped,
        90,
        "every frame is either processed or counted as dropped\n{stdout}"
    );
    // The recorder is live too: when the relay bursts through its backlog the recorder may drop
    // as well. Its file holds exactly what it received, and it accounts for every frame.
    let rec: Vec<&str> = stdout
        .lines()
        .find(|l| l.starts_with("rec "))
        .expect("summary row for 'rec'")
        .split_whitespace()
        .collect();
    let (rec_in, rec_dropped): (u64, u64) = (
        rec[2].parse().expect("frames in"),
        rec[4].parse().expect("dropped"),
    );
    assert_eq!(
        rec_in + rec_dropped,
        90,
        "recorder accounts for every frame\n{stdout}"
    );
    assert!(
        rec_in <= frames_in,
        "the recorder cannot get more than the relay sent\n{stdout}"
    );
    assert_eq!(mcap_messages(&sb.path("live.mcap")).len() as u64, rec_in);
    assert_clean(&sb);
}

#[test]
fn an_unreachable_rerun_viewer_fails_the_logger_clearly_instead_of_hanging() {
    let sb = Sandbox::new("no-viewer");
    let graph = sb.graph("smoke.toml", SMOKE);
    let start = Instant::now();
    // Port 1 on loopback: nothing listens there.
    let out = sb.run(&[
        "run",
        graph.to_str().expect("utf8"),
        "--no-progress",
        "--connect",
        "rerun+http://127.0.0.1:1/proxy",
    ]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("stage 'viz' failed"), "{stderr}");
    assert!(
        stderr.contains(
            "could not deliver the log to the rerun viewer at rerun+http://127.0.0.1:1/proxy"
        ),
        "{stderr}"
    );
    assert!(
        start.elapsed() < Duration::from_secs(30),
        "gave up in {:?}",
        start.elapsed()
    );
    // The recorder beside it still finished its file.
    assert_eq!(
        mcap_messages(&sb.path("out.mcap"))
            .iter()
            .filter(|m| m.0 == "source.imu")
            .count(),
        120
    );
    assert_clean(&sb);
}
