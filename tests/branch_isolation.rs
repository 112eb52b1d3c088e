//! `on_failure = "stop-branch"`: a failing stage stops only its branch; the rest of the graph runs
//! to the end with complete recordings, and the run exits 0 with a warning naming the stage.

mod common;

use std::time::Duration;

use common::{
    Sandbox, assert_clean, count, example_exe, mcap_messages, text, wait_for_mark, wait_for_stage,
    wait_with_timeout,
};
use imuflow_graph::frames::{MotionFrame, frame_from_bytes};

#[test]
fn a_failing_isolated_stage_stops_its_branch_and_the_rest_finishes() {
    let sb = Sandbox::new("branch");
    let counter = example_exe("external_counter");
    // counter fails after frame 150; `counts` reads only the counter (its branch); `all` reads the
    // source and the counter (a join: it keeps recording the source to the end).
    let graph = sb.graph(
        "branch.toml",
        &format!(
            r#"
name = "branch-test"
[stages.source]
kind = "test-source"
params = {{ frames = 1500 }}
[stages.counter]
exec = "{}"
args = ["--fail-at", "150"]
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
on_failure = "stop-branch"
[stages.counts]
kind = "recorder"
inputs = {{ count = "counter.count" }}
params = {{ path = "{{dir}}/counts.mcap" }}
[stages.all]
kind = "recorder"
inputs = {{ imu = "source.imu", count = "counter.count" }}
params = {{ path = "{{dir}}/all.mcap" }}
"#,
            counter.display()
        ),
    );
    let check = sb.run(&["graph", "show", graph.to_str().expect("utf8")]);
    let shown = text(&check.stdout);
    assert!(
        shown.contains("on_failure = stop-branch: a failure stops counter, counts"),
        "graph show names the branch:\n{shown}"
    );

    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert!(
        out.status.success(),
        "exit 0 when only a branch failed:\n{stderr}"
    );
    assert!(
        stderr.contains("warning: stage 'counter' failed: exited with code 3")
            && stderr.contains("counter, counts")
            && stderr.contains("failing at frame 150 as asked"),
        "the warning names the stage, its branch and its last stderr lines:\n{stderr}"
    );
    assert!(
        text(&out.stdout).contains("branch of 'counter' stopped (counter failed): counter, counts"),
        "{}",
        text(&out.stdout)
    );

    // The join recorded the whole source stream and the counter's frames up to its failure.
    let all = mcap_messages(&sb.path("all.mcap"));
    assert_eq!(count(&all, "source.imu"), 1500);
    assert_eq!(count(&all, "counter.count"), 151);
    // The branch's own recorder was stopped, and finalized what it had: a readable file whose
    // counts are the frame numbers (nothing from after the failure).
    let counts = mcap_messages(&sb.path("counts.mcap"));
    assert!(counts.len() <= 151, "{} frames", counts.len());
    for (_, seq, data) in &counts {
        let frame: MotionFrame = frame_from_bytes(data).expect("one MotionFrame");
        assert_eq!(frame.q[0] as u32, *seq);
    }
    assert_clean(&sb);
}

#[test]
fn a_killed_validation_stage_leaves_the_capture_running_to_the_end() {
    let sb = Sandbox::new("kill-val");
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/models/sample/walk.mcap");
    let marker = example_exe("external_counter");
    let marker = marker.display();
    let graph = sb.graph(
        "kill.toml",
        &format!(
            r#"
name = "kill-validation"
[stages.source]
kind = "imu-source"
# Paced at the sample's 60 Hz: the stream lasts 25 s on any machine, so the kill lands mid-stream.
params = {{ mode = "replay", path = "{sample}", realtime = true }}
[stages.val]
kind = "validation"
inputs = {{ motion = "source.truth" }}
on_failure = "stop-branch"
# Says when the stream has passed frame 60 (the kill waits for it, not for a time).
[stages.marker]
exec = "{marker}"
args = ["--mark-from", "60", "{{dir}}/marked"]
inputs = {{ imu = "source.imu", prev = "marker.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.record]
kind = "recorder"
inputs = {{ truth = "source.truth", sim = "val.sim", validation = "val.validation" }}
params = {{ path = "{{dir}}/kill.mcap" }}
[stages.viz]
kind = "rerun-logger"
inputs = {{ truth = "source.truth", validation = "val.sim", validation_scores = "val.validation" }}
params = {{ path = "{{dir}}/kill.rrd" }}
"#
        ),
    );
    let mut child = sb.spawn(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    // Let the simulation run a while, then kill -9 it: no END_OF_STREAM, no clean-up of its own.
    let val = wait_for_stage(&sb, "val", Duration::from_secs(30)).expect("the val stage starts");
    wait_for_mark(&mut child, &sb.path("marked"), 60, "");
    // SAFETY: kill(2) on a stage process of this test's own run.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(val, libc::SIGKILL);
    }
    let out = wait_with_timeout(child, Duration::from_secs(90));
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "exit 0:\n{stderr}");
    assert!(
        stderr.contains("warning: stage 'val' failed: killed by signal 9"),
        "{stderr}"
    );
    let messages = mcap_messages(&sb.path("kill.mcap"));
    // models/sample/README.md: 1511 frames with the true pose; all of them recorded.
    assert_eq!(count(&messages, "source.truth"), 1511);
    let sim = count(&messages, "val.sim");
    assert!(
        (1..1511).contains(&sim),
        "the simulation's frames up to the kill ({sim})"
    );
    assert!(std::fs::metadata(sb.path("kill.rrd")).is_ok_and(|m| m.len() > 10_000));
    assert_clean(&sb);
}
