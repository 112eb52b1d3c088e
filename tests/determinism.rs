//! Deterministic replay: the same graph run twice offline on the same recording publishes
//! byte-identical frames on every channel, except the publish timestamps. This is what makes an
//! A/B comparison or a regression bisect trustworthy: a difference is the change, not the run.
//!
//! It holds because offline runs lose nothing (back-pressure), every stage is a function of its
//! input frames in seq order (no wall-clock input, seeded randomness), and the numeric kernels
//! run with the same thread counts on the same machine. Different thread counts (candle's matmul
//! splits, `RAYON_NUM_THREADS`) or another CPU may change the last bits.

mod common;

use std::collections::BTreeMap;

use common::{Sandbox, mcap_messages, sample_run_args, text};

/// `header.publish_ns`: bytes 16..24 of every frame (`FrameHeader` leads every frame type).
const PUBLISH_NS: std::ops::Range<usize> = 16..24;

/// Per topic, frames in seq order with the publish time zeroed. The recorder stores frames in
/// arrival order, which interleaves topics differently from run to run; within a topic the order
/// is the seq order either way.
fn frames_by_topic(path: &std::path::Path) -> BTreeMap<String, Vec<(u64, Vec<u8>)>> {
    let mut topics: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    for (topic, _, mut data) in mcap_messages(path) {
        let seq = u64::from_le_bytes(data[0..8].try_into().expect("8 bytes"));
        data[PUBLISH_NS].fill(0);
        topics.entry(topic).or_default().push((seq, data));
    }
    for frames in topics.values_mut() {
        frames.sort_by_key(|(seq, _)| *seq);
    }
    topics
}

fn run_twice(variant: &str) {
    let sb = Sandbox::new(&format!("det-{variant}"));
    let mut recordings = Vec::new();
    for run in ["a", "b"] {
        let mcap = sb.path(&format!("{run}.mcap"));
        let rrd = sb.path(&format!("{run}.rrd"));
        // The calibration prelude (about 600 frames) and some walking after it.
        let args = sample_run_args(variant, &mcap, &rrd, &["stages.source.params.frames=800"]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = sb.run_within(&args, 300);
        assert!(
            out.status.success(),
            "{variant} run {run}: {}",
            text(&out.stderr)
        );
        recordings.push(frames_by_topic(&mcap));
    }
    let (a, b) = (&recordings[0], &recordings[1]);
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{variant}: the same channels"
    );
    for (topic, frames_a) in a {
        let frames_b = &b[topic];
        assert_eq!(
            frames_a.len(),
            frames_b.len(),
            "{variant} {topic}: frame count"
        );
        // The source delivered 800 frames and every stage saw them all.
        assert!(
            frames_a.len() >= 800,
            "{variant} {topic}: {} frames",
            frames_a.len()
        );
        for ((seq, x), (_, y)) in frames_a.iter().zip(frames_b) {
            assert!(
                x == y,
                "{variant} {topic}: frame {seq} differs between two runs"
            );
        }
    }
    assert!(a.contains_key("opt.motion") && a.contains_key("val.validation"));
}

#[test]
fn pip_replays_byte_identically() {
    run_twice("pip");
}

#[test]
fn globalpose_replays_byte_identically() {
    run_twice("globalpose");
}

#[test]
fn no_physics_replays_byte_identically() {
    run_twice("no-physics");
}
