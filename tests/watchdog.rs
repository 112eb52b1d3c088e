//! The launcher's stall watchdog: a stage that holds unconsumed input and takes none of it for its
//! `stall_timeout_s` is named, with what it waited on, and handled by its `on_failure` policy;
//! recordings are finalized and nothing is left behind.

mod common;

use std::time::{Duration, Instant};

use common::{Sandbox, assert_clean, count, example_exe, mcap_messages, text};

/// source -> counter (user stage, `counter_args`) -> recorder; a second recorder joins the source
/// and the counter.
fn graph(sb: &Sandbox, frames: u64, counter_args: &str, counter_extra: &str) -> std::path::PathBuf {
    sb.graph(
        "watchdog.toml",
        &format!(
            r#"
name = "watchdog-test"
[stages.source]
kind = "test-source"
params = {{ frames = {frames} }}
[stages.counter]
exec = "{}"
args = {counter_args}
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
stall_timeout_s = 1.0
{counter_extra}
[stages.all]
kind = "recorder"
inputs = {{ imu = "source.imu", count = "counter.count" }}
params = {{ path = "{{dir}}/all.mcap" }}
"#,
            example_exe("external_counter").display()
        ),
    )
}

/// The failure was found within seconds (not at some global timeout), the recording holds the
/// counter's `frames` frames, and nothing is left behind.
fn ended_quickly_with_a_finalized_recording(sb: &Sandbox, started: Instant, frames: usize) {
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "{:?}",
        started.elapsed()
    );
    let messages = mcap_messages(&sb.path("all.mcap"));
    assert_eq!(count(&messages, "counter.count"), frames);
    assert_clean(sb);
}

#[test]
fn a_hung_stage_stops_the_run_with_its_name_and_the_recording_is_finalized() {
    let sb = Sandbox::new("stall-run");
    let file = graph(&sb, 1500, r#"["--hang-at", "100"]"#, "");
    let started = Instant::now();
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("stage 'counter' stalled"), "{stderr}");
    assert!(stderr.contains("stall_timeout_s = 1"), "{stderr}");
    // It took frames 0..=100 and hung with more waiting from the source.
    assert!(stderr.contains("it took frames up to 100"), "{stderr}");
    assert!(stderr.contains("(from 'source')"), "{stderr}");
    assert!(stderr.contains("the process is alive"), "{stderr}");
    assert!(
        stderr.contains("hanging at frame 100"),
        "its stderr tail: {stderr}"
    );
    // Found within about a second of the hang, not at some global timeout.
    ended_quickly_with_a_finalized_recording(&sb, started, 101);
}

#[test]
fn a_hung_isolated_stage_stops_only_its_branch() {
    let sb = Sandbox::new("stall-branch");
    let file = graph(
        &sb,
        1500,
        r#"["--hang-at", "100"]"#,
        r#"on_failure = "stop-branch""#,
    );
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("warning: stage 'counter'"), "{stderr}");
    assert!(stderr.contains("stalled: took no frame"), "{stderr}");
    // The join recorder keeps recording the source to its end.
    let messages = mcap_messages(&sb.path("all.mcap"));
    assert_eq!(count(&messages, "source.imu"), 1500);
    assert_eq!(count(&messages, "counter.count"), 101);
    assert_clean(&sb);
}

/// Runs the graph, freezes (SIGSTOP) the stage process whose command line holds `victim` once
/// the stream flows, and expects the watchdog to end the run naming `stage`.
fn freeze(name: &str, victim: &str, stage: &str) {
    let sb = Sandbox::new(name);
    // Far more frames than can flow before the freeze, on any machine (a debug build streams a
    // few thousand to a few tens of thousands a second); the run ends by the watchdog. Every stage
    // gets 1 s (the source too).
    let file = graph(&sb, 30_000_000, "[]", "");
    let text_in = std::fs::read_to_string(&file).expect("graph");
    std::fs::write(
        &file,
        text_in.replace(
            "name = \"watchdog-test\"",
            "name = \"watchdog-test\"\nstall_timeout_s = 1.0",
        ),
    )
    .expect("graph");
    let mut child = sb.spawn(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    // Freeze the victim once it runs.
    let deadline = Instant::now() + Duration::from_secs(30);
    let pid = loop {
        let found = sb
            .stray_processes()
            .into_iter()
            .find(|p| p.contains(victim));
        if let Some(p) = found {
            break p
                .split(':')
                .next()
                .expect("pid")
                .parse::<i32>()
                .expect("pid");
        }
        assert!(Instant::now() < deadline, "{victim} never started");
        std::thread::sleep(Duration::from_millis(50));
    };
    // Past the start handshake (the watchdog guards the stream, the ready timeout the start).
    std::thread::sleep(Duration::from_secs(3));
    // SAFETY: kill(2) on a stage process of this test's own run.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(pid, libc::SIGSTOP);
    }
    let (tx, rx) = std::sync::mpsc::channel();
    let id = child.id();
    let stdout = child.stdout.take();
    let stderr_pipe = child.stderr.take();
    std::thread::spawn(move || {
        let mut err = String::new();
        if let Some(mut e) = stderr_pipe {
            let _ = std::io::Read::read_to_string(&mut e, &mut err);
        }
        drop(stdout);
        let _ = tx.send((child.wait(), err));
    });
    let Ok((status, stderr)) = rx.recv_timeout(Duration::from_secs(60)) else {
        // SAFETY: kill(2) on the launcher this test started.
        #[allow(unsafe_code)]
        unsafe {
            libc::kill(id as i32, libc::SIGKILL);
            libc::kill(pid, libc::SIGKILL);
        }
        panic!("a frozen stage hung the run");
    };
    assert_eq!(status.expect("wait").code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("stage '{stage}' stalled")),
        "{stderr}"
    );
    assert!(
        stderr.contains("the process is not running (stopped or frozen)"),
        "{stderr}"
    );
    // The recorder was stopped with the run and finalized its file.
    let messages = mcap_messages(&sb.path("all.mcap"));
    assert!(count(&messages, "source.imu") > 0);
    assert_clean(&sb);
}

#[test]
fn a_frozen_process_is_told_apart_from_a_busy_one() {
    freeze("stall-frozen", "external_counter", "counter");
}

#[test]
fn a_frozen_source_is_found_though_it_has_no_input() {
    // Nobody is behind a frozen source: only its silence shows (found by the leak loop, where
    // a stopped live source hung the run).
    freeze("stall-frozen-source", "stage test-source", "source");
}

#[test]
fn stall_timeouts_must_be_positive() {
    let sb = Sandbox::new("stall-invalid");
    let file = graph(&sb, 10, "[]", "");
    let text_in = std::fs::read_to_string(&file).expect("graph");
    let bad = sb.graph(
        "bad.toml",
        &text_in
            .replace("stall_timeout_s = 1.0", "stall_timeout_s = -2")
            .replace(
                "name = \"watchdog-test\"",
                "name = \"w\"\nstall_timeout_s = \"soon\"",
            ),
    );
    let out = sb.run(&["graph", "check", bad.to_str().expect("utf8")]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("stall_timeout_s: must be a positive number of seconds (got \"soon\")"),
        "{stderr}"
    );
    assert!(
        stderr.contains(
            "stage 'counter': stall_timeout_s: must be a positive number of seconds (got -2)"
        ),
        "{stderr}"
    );
}

/// A stage that exits 0 in the middle of its stream (no END_OF_STREAM) is a failure named as
/// such, found at once (not after the stall timeout's wait on its readers), with the recording
/// finalized to its last frame.
#[test]
fn a_stage_that_exits_0_early_is_named_and_the_recording_is_finalized() {
    let sb = Sandbox::new("exit-early");
    let file = graph(&sb, 1500, r#"["--exit-at", "200"]"#, "");
    let started = Instant::now();
    let out = sb.run(&["run", file.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("'counter'"), "{stderr}");
    assert!(
        stderr.contains("exited without ending its stream"),
        "{stderr}"
    );
    assert!(
        stderr.contains("exiting 0 at frame 200"),
        "its stderr tail: {stderr}"
    );
    ended_quickly_with_a_finalized_recording(&sb, started, 201);
}

/// A stage that floods stderr (hundreds of lines per frame) neither blocks on a full pipe nor
/// slows the graph into a stall: the run ends normally with every frame.
#[test]
fn a_stage_that_floods_stderr_does_not_block_the_graph() {
    let sb = Sandbox::new("flood");
    let file = graph(&sb, 600, r#"["--flood-stderr", "300"]"#, "");
    let out = sb.run(&[
        "run",
        file.to_str().expect("utf8"),
        "--no-progress",
        "--quiet",
    ]);
    let stderr = text(&out.stderr);
    assert!(
        out.status.success(),
        "{}",
        &stderr[stderr.len().saturating_sub(2000)..]
    );
    let messages = mcap_messages(&sb.path("all.mcap"));
    assert_eq!(count(&messages, "counter.count"), 600);
    assert_clean(&sb);
}
