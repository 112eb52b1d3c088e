//! Fault injection over the method graphs: every stage of `configs/pip.toml` and
//! `configs/globalpose.toml`, one run each, killed with SIGKILL (no clean-up of its own) at a
//! pseudo-random moment of a run on the bundled sample. The declared behaviour:
//!
//! - the validation stage (`on_failure = "stop-branch"`): its branch stops, the capture runs to the
//!   end, the run exits 0 with a warning naming the stage, and the recording holds every frame;
//! - any other stage: the run stops with an error naming the stage and how it died, and exits
//!   non-zero; the recording is readable to its last message (finalized, unless the recorder
//!   itself was the one killed, whose file is read as a killed writer's: no footer);
//! - either way nothing is left behind: no shared-memory files, no stage processes;
//! - a stage with a `restart` policy (here the pip graph live, its kinematics or optimizer): it is
//!   started again and the run ends normally with the stream recorded to its end.

mod common;

use std::path::Path;
use std::time::Duration;

use common::{
    Sandbox, assert_clean, count, example_exe, mcap_messages, sample_run_args, text, wait_for_mark,
    wait_for_stage, wait_with_timeout,
};
use imuflow_recording::for_each_record;

/// models/sample/README.md: 1511 frames with the true pose.
const SAMPLE_FRAMES: usize = 1511;

/// The live test runs alone: a live edge keeps only its newest frames, so a recorder slowed by
/// the other tests' graphs on the same cores can drop the one frame that marks the restart (seen
/// once with another process beside the suite). The offline tests share: they never drop.
static LIVE_ALONE: std::sync::RwLock<()> = std::sync::RwLock::new(());

/// When to kill `stage`: 0.3-1.5 s after it started, drawn from its name (FNV-1a), so a failure
/// reproduces. The source is paced at the sample's 60 Hz (`realtime`), so the run lasts 25 s
/// whatever the machine's speed and the kill always lands mid-stream: unpaced, a debug run of the
/// sample takes 1.4 s on a fast machine and ended before the kill.
fn kill_delay(graph: &str, stage: &str) -> Duration {
    let hash = format!("{graph}/{stage}")
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
        });
    Duration::from_millis(300 + hash % 1200)
}

/// Messages in an mcap file read record by record (a killed writer's file has no footer).
fn messages_to_the_last(path: &Path) -> usize {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut n = 0;
    for_each_record(&bytes, |_, record| {
        n += usize::from(matches!(record, mcap::records::Record::Message { .. }));
        Ok(())
    })
    .unwrap_or_else(|e| panic!("{}: readable to its last message: {e:#}", path.display()));
    n
}

fn kill_each_stage(graph_name: &str, stages: &[&str]) {
    let _shared = LIVE_ALONE.read().unwrap_or_else(|e| e.into_inner());
    for stage in stages {
        let sb = Sandbox::new(&format!("fault-{graph_name}-{stage}"));
        let mcap = sb.path("run.mcap");
        let args = sample_run_args(
            graph_name,
            &mcap,
            &sb.path("run.rrd"),
            &["stages.source.params.realtime=true"],
        );
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let child = sb.spawn(&args);
        let pid = wait_for_stage(&sb, stage, Duration::from_secs(60))
            .unwrap_or_else(|| panic!("{graph_name}: stage '{stage}' starts"));
        std::thread::sleep(kill_delay(graph_name, stage));
        // SAFETY: kill(2) on a stage process of this test's own run.
        #[allow(unsafe_code)]
        let killed = unsafe { libc::kill(pid, libc::SIGKILL) } == 0;
        assert!(killed, "{graph_name}: '{stage}' was still running");
        let out = wait_with_timeout(child, Duration::from_secs(240));
        let stderr = text(&out.stderr);
        let named = format!("stage '{stage}' failed: killed by signal 9");
        assert!(
            stderr.contains(&named),
            "{graph_name}, '{stage}' killed: the error names it\n{stderr}"
        );
        if *stage == "val" {
            assert!(
                out.status.success(),
                "{graph_name}: an isolated branch's failure exits 0\n{stderr}"
            );
            let messages = mcap_messages(&mcap);
            assert_eq!(count(&messages, "source.truth"), SAMPLE_FRAMES);
            assert_eq!(count(&messages, "opt.motion"), SAMPLE_FRAMES);
        } else {
            assert!(
                !out.status.success(),
                "{graph_name}: '{stage}' killed must fail the run\n{stderr}"
            );
            if *stage == "record" {
                // Killed mid-write: what reached the file reads back up to its last message.
                messages_to_the_last(&mcap);
            } else {
                // The recorder was stopped and finalized its file (summary, statistics, CRCs).
                let messages = mcap_messages(&mcap);
                assert!(
                    messages.len() < 6 * SAMPLE_FRAMES,
                    "{graph_name}: the run stopped early"
                );
            }
        }
        assert_clean(&sb);
        eprintln!("{graph_name}: '{stage}' killed -> {}", out.status);
    }
}

#[test]
fn killing_any_stage_of_the_pip_graph_fails_or_isolates_as_declared() {
    kill_each_stage(
        "pip",
        &[
            "source", "calib", "kin", "contact", "opt", "val", "viz", "record",
        ],
    );
}

#[test]
fn killing_any_stage_of_the_globalpose_graph_fails_or_isolates_as_declared() {
    kill_each_stage(
        "globalpose",
        &["source", "calib", "kin", "opt", "val", "viz", "record"],
    );
}

/// The pip graph live (the sample's first 15 s at sensor rate) with a restart policy on the killed
/// stage: it is back within its backoff, its frames after the restart carry restart count 1 (the
/// first of them RESTARTED, where the live recorder kept it), and the run ends normally with the
/// motion recorded to the last frame. The kill comes once the stream has passed frame
/// [`KILL_FROM`] (a marker stage beside the graph says so), not after a time: under load the
/// graph's start-up alone can take longer than any fixed wait.
#[test]
fn a_killed_stage_with_a_restart_policy_rejoins_the_live_pip_graph() {
    use imuflow_graph::frames::{KinematicsFrame, MotionFrame, flags, frame_from_bytes};
    let _alone = LIVE_ALONE.write().unwrap_or_else(|e| e.into_inner());
    const FRAMES: u64 = 900;
    /// Past the T-pose calibration, mid-walk.
    const KILL_FROM: u64 = 180;
    for (stage, channel) in [("kin", "kin.kinematics"), ("opt", "opt.motion")] {
        let sb = Sandbox::new(&format!("fault-restart-{stage}"));
        let mcap = sb.path("run.mcap");
        let restart = format!("stages.{stage}.restart={{ max = 1, backoff_ms = 50 }}");
        let frames = format!("stages.source.params.frames={FRAMES}");
        let marked = sb.path("marked");
        let marker = format!(
            "stages.marker={{ exec = {:?}, args = [\"--mark-from\", \"{KILL_FROM}\", {:?}], \
             inputs = {{ imu = \"source.imu\", prev = \"marker.count\", feedback = [\"prev\"] }}, \
             outputs = {{ count = \"MotionFrame\" }} }}",
            example_exe("external_counter").display().to_string(),
            marked.display().to_string()
        );
        let extra = [
            "mode=live",
            "stages.source.params.realtime=true",
            // Start-up (nine processes, the networks' weights) under a heavy load can outlast
            // the default 30 s; this test is about the restart, not the start.
            "ready_timeout_s=120",
            frames.as_str(),
            restart.as_str(),
            marker.as_str(),
        ];
        let args = sample_run_args("pip", &mcap, &sb.path("run.rrd"), &extra);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let mut child = sb.spawn(&args);
        let pid = wait_for_stage(&sb, stage, Duration::from_secs(60))
            .unwrap_or_else(|| panic!("stage '{stage}' starts"));
        wait_for_mark(&mut child, &marked, KILL_FROM, &format!("'{stage}': "));
        // SAFETY: kill(2) on a stage process of this test's own run.
        #[allow(unsafe_code)]
        let killed = unsafe { libc::kill(pid, libc::SIGKILL) } == 0;
        assert!(killed, "'{stage}' was still running");
        let out = wait_with_timeout(child, Duration::from_secs(120));
        let stderr = text(&out.stderr);
        assert!(
            out.status.success(),
            "'{stage}' killed and restarted\n{stderr}"
        );
        let headers: Vec<_> = mcap_messages(&mcap)
            .into_iter()
            .filter(|m| m.0 == channel)
            .map(|m| match stage {
                "kin" => frame_from_bytes::<KinematicsFrame>(&m.2).map(|f| f.header),
                _ => frame_from_bytes::<MotionFrame>(&m.2).map(|f| f.header),
            })
            .map(|h| h.expect("a frame of the channel's type"))
            .collect();
        // A live graph drops under load, and the frames in flight at the kill are lost.
        assert!(
            headers.len() as u64 > FRAMES / 2,
            "'{stage}': {} of {FRAMES} frames",
            headers.len()
        );
        assert_eq!(headers.last().map(|h| h.seq), Some(FRAMES - 1), "'{stage}'");
        // The recorder is a live reader: under load it keeps only the newest frames, so it may lose
        // the one frame flagged RESTARTED. Every frame carries the publishing process's restart
        // count (frames.rs), so the restart shows as the count's one step from 0 to 1, and a
        // RESTARTED flag, where it survived, sits on the first frame of the new process.
        let counts: Vec<u32> = headers.iter().map(|h| h.restarts).collect();
        let first_new = counts
            .iter()
            .position(|&c| c == 1)
            .unwrap_or_else(|| panic!("'{stage}': no frame from the restarted process"));
        assert!(
            counts[..first_new].iter().all(|&c| c == 0)
                && counts[first_new..].iter().all(|&c| c == 1),
            "'{stage}': restart counts {counts:?}"
        );
        let restart_seq = headers[first_new].seq;
        assert!(
            (KILL_FROM..FRAMES).contains(&restart_seq),
            "'{stage}' restarted at frame {restart_seq}"
        );
        let flagged: Vec<u64> = headers
            .iter()
            .filter(|h| h.has(flags::RESTARTED))
            .map(|h| h.seq)
            .collect();
        assert!(
            flagged.is_empty() || flagged == [restart_seq],
            "'{stage}': RESTARTED on {flagged:?}, the new process's first recorded frame is {restart_seq}"
        );
        assert_clean(&sb);
        eprintln!(
            "pip live: '{stage}' killed -> restarted at frame {restart_seq} (flag recorded: {})",
            !flagged.is_empty()
        );
    }
}
