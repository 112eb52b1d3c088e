//! An external stage built on imuflow-graph's Stage API, run by a graph with `exec = "..."`.
//!
//! It reads IMU frames and its own previous output through a feedback edge, and writes a
//! MotionFrame whose `q[0]` counts frames: previous `q[0]` + 1, starting from 0 when the feedback
//! input still holds its initial value. The count equals `seq` only if feedback delivers exactly
//! the previous frame, which the integration tests check.
//!
//! ```toml
//! [stages.counter]
//! exec = "target/debug/examples/external_counter"
//! inputs = { imu = "source.imu", prev = "counter.count", feedback = ["prev"] }
//! outputs = { count = "MotionFrame" }
//! ```
//!
//! `q[2]` is a checksum of the IMU frame's bytes (FNV-1a, folded to 24 bits so an f32 holds it
//! exactly): two copies of this stage fed the same frames write the same checksums, which is how
//! the tests prove that `imuflow compare` gives every variant identical input.
//!
//! `args = ["--fail-at", "N"]` makes it fail (exit code 3) after publishing frame N, for the tests
//! of failure policies. `args = ["--bend-knee-deg", "D"]` bends the left knee of its pose by D
//! degrees (about the knee's x axis), a variant that is worse by construction for the comparison
//! tests. `args = ["--hang-at", "N"]` makes it hang after publishing frame N: alive, taking no
//! more frames, deaf to SIGTERM (a stage stuck in its own code), for the stall watchdog's tests.
//! `args = ["--fail-from", "N"]` fails at the first frame N or later (again after a restart).
//! `args = ["--exit-at", "N"]` makes it exit 0 after publishing frame N without ending its stream
//! (a stage that quits early by mistake); `args = ["--flood-stderr", "K"]` writes K lines of
//! log to stderr per frame (a stage that floods its log). `args = ["--mark-from", "N", "PATH"]`
//! creates the file PATH once it has published a frame N or later: a test that must act on a run
//! at a point of its stream (not after a time that a slow machine may not reach) waits for it.
//! `args = ["--fail-before-ready"]` makes its first process (restart count 0) exit 3 before it
//! reports ready: a stage that dies during the graph's start-up.

use imuflow_graph::StageContext;
use imuflow_graph::frames::{ImuFrame, MotionFrame, flags};

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("external_counter: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let imu = ctx.input::<ImuFrame>("imu")?;
    let prev = ctx.input::<MotionFrame>("prev")?;
    let mut out = ctx.output::<MotionFrame>("count")?;
    let mut fail_at: Option<u64> = None;
    let mut hang_at: Option<u64> = None;
    let mut exit_at: Option<u64> = None;
    let mut fail_from: Option<u64> = None;
    let mut flood_lines = 0usize;
    let mut bend_knee_deg = 0.0f32;
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut mark: Option<(u64, std::path::PathBuf)> = None;
    if let Some(at) = args.iter().position(|a| a == "--fail-before-ready") {
        args.remove(at);
        if ctx.restarts() == 0 {
            eprintln!("external_counter: failing before ready as asked");
            std::process::exit(3);
        }
    }
    if let Some(at) = args.iter().position(|a| a == "--mark-from") {
        let [_, n, path] = args.get(at..at + 3).unwrap_or_default() else {
            anyhow::bail!("--mark-from takes a frame number and a path");
        };
        mark = Some((n.parse()?, path.into()));
        args.drain(at..at + 3);
    }
    for pair in args.chunks(2) {
        match pair {
            [flag, n] if flag == "--fail-at" => fail_at = Some(n.parse()?),
            [flag, n] if flag == "--fail-from" => fail_from = Some(n.parse()?),
            [flag, n] if flag == "--hang-at" => hang_at = Some(n.parse()?),
            [flag, d] if flag == "--bend-knee-deg" => bend_knee_deg = d.parse()?,
            [flag, n] if flag == "--exit-at" => exit_at = Some(n.parse()?),
            [flag, k] if flag == "--flood-stderr" => flood_lines = k.parse()?,
            other => anyhow::bail!(
                "unknown arguments {other:?} (expected --fail-at N, --fail-from N, --hang-at N, --exit-at N, --flood-stderr K, --bend-knee-deg D, --mark-from N PATH, --fail-before-ready)"
            ),
        }
    }
    // SMPL joint 4: the left knee.
    const LEFT_KNEE: usize = 4;
    let half = bend_knee_deg.to_radians() / 2.0;
    let knee = [half.cos(), half.sin(), 0.0, 0.0];
    if ctx.ready()? {
        while let Some(step) = ctx.next()? {
            let last = ctx.get(&prev);
            let count = if last.header.has(flags::FEEDBACK_INITIAL) {
                0.0
            } else {
                last.q[0] + 1.0
            };
            let frame = ctx.get(&imu);
            let valid_imus = frame.valid_mask.count_ones() as f32;
            let checksum = checksum_24(bytemuck::bytes_of(frame));
            out.publish(step.header(), |m| {
                // A valid pose (every joint at identity, the root at the origin), so the frames
                // are motion a recorder, viewer or comparison can read.
                for q in &mut m.local_pose_wxyz {
                    q[0] = 1.0;
                }
                m.local_pose_wxyz[LEFT_KNEE] = knee;
                m.q[0] = count;
                m.q[1] = valid_imus;
                m.q[2] = checksum as f32;
            })?;
            if let Some((from, path)) = &mark
                && step.seq >= *from
            {
                std::fs::write(path, step.seq.to_string())?;
                mark = None;
            }
            if hang_at == Some(step.seq) {
                eprintln!("external_counter: hanging at frame {} as asked", step.seq);
                loop {
                    std::thread::sleep(std::time::Duration::from_secs(1));
                }
            }
            for line in 0..flood_lines {
                eprintln!(
                    "external_counter: frame {} log line {line}: {}",
                    step.seq,
                    "x".repeat(120)
                );
            }
            if exit_at == Some(step.seq) {
                eprintln!("external_counter: exiting 0 at frame {} as asked", step.seq);
                std::process::exit(0);
            }
            if fail_at == Some(step.seq) || fail_from.is_some_and(|n| step.seq >= n) {
                eprintln!("external_counter: failing at frame {} as asked", step.seq);
                std::process::exit(3);
            }
        }
    }
    ctx.finish(&mut [&mut out])?;
    Ok(())
}

/// FNV-1a of `bytes`, folded to 24 bits (exact in an f32).
fn checksum_24(bytes: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for b in bytes {
        h ^= u32::from(*b);
        h = h.wrapping_mul(0x0100_0193);
    }
    (h >> 24) ^ (h & 0x00ff_ffff)
}
