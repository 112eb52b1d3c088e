//! `imuflow compare`: the combined graph (shared source, one isolated branch per variant), its
//! refusals, and the proof that every variant sees byte-identical input.

mod common;

use std::collections::BTreeMap;

use common::{Sandbox, mcap_messages, text};
use imuflow_graph::frames::{MotionFrame, frame_from_bytes};

fn example_exe(name: &str) -> std::path::PathBuf {
    let bin = std::path::Path::new(common::IMUFLOW);
    bin.parent()
        .expect("target dir")
        .join("examples")
        .join(name)
}

#[test]
fn the_three_variants_combine_into_one_valid_graph_with_isolated_branches() {
    let sb = Sandbox::new("compare-print");
    let root = env!("CARGO_MANIFEST_DIR");
    let variants = ["pip", "globalpose", "no-physics"].map(|v| format!("{root}/configs/{v}.toml"));
    let mut args = vec!["compare", "--print-graph"];
    args.extend(variants.iter().map(String::as_str));
    let out = sb.run(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let combined = text(&out.stdout);
    let file = sb.graph("combined.toml", &combined);
    let check = sb.run(&["graph", "show", file.to_str().expect("utf8")]);
    let shown = text(&check.stdout);
    assert!(check.status.success(), "{}", text(&check.stderr));
    // One source; every variant's calibration reads it and heads that variant's branch.
    assert_eq!(combined.matches("kind = \"imu-source\"").count(), 1);
    for v in ["pip", "globalpose", "no-physics"] {
        assert!(
            shown.contains(&format!(
                "[{v}-calib] calibration (Transform)\n  in  imu          <- source.imu"
            )),
            "{v}'s calibration reads the shared source:\n{shown}"
        );
        assert!(
            shown.contains(&format!(
                "on_failure = stop-branch: a failure stops {v}-calib, {v}-"
            )),
            "{v}'s calibration heads an isolated branch:\n{shown}"
        );
        assert!(
            combined.contains(&format!("{v}__motion = \"{v}-opt.motion\"")),
            "the sinks read {v}'s motion:\n{combined}"
        );
    }
    // PIP's feedback edge is rewired inside its own copy.
    assert!(combined.contains("state = \"pip-opt.motion\", feedback = [\"state\"]"));
}

#[test]
fn variants_that_cannot_be_compared_are_refused_with_the_reason() {
    let sb = Sandbox::new("compare-refuse");
    let a = sb.graph(
        "a.toml",
        r#"
name = "a"
rate_hz = 60
[stages.source]
kind = "test-source"
[stages.record]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/a.mcap" }
"#,
    );
    let b = sb.graph(
        "b.toml",
        r#"
name = "b"
rate_hz = 100
[stages.source]
kind = "test-source"
[stages.record]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/b.mcap" }
"#,
    );
    let a = a.to_str().expect("utf8");
    let b = b.to_str().expect("utf8");
    let out = sb.run(&["compare", a, b, "--print-graph"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("variant 'b': runs at 100 Hz, 'a' at 60 Hz"),
        "{stderr}"
    );
    let out = sb.run(&["compare", a, a, "--print-graph"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("variant 'a': has no single motion output to compare"),
        "{stderr}"
    );
}

#[test]
fn every_variant_gets_byte_identical_input_and_user_stages_compare_like_built_ins() {
    let sb = Sandbox::new("compare-identical");
    let counter = example_exe("external_counter");
    let variant = |name: &str, args: &str| {
        sb.graph(
            &format!("{name}.toml"),
            &format!(
                r#"
name = "{name}"
[stages.source]
kind = "test-source"
params = {{ frames = 400, seed = 7, invalid_every = 50 }}
[stages.counter]
exec = "{}"
args = {args}
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.record]
kind = "recorder"
inputs = {{ motion = "counter.count" }}
params = {{ path = "{{dir}}/{name}.mcap" }}
"#,
                counter.display()
            ),
        )
    };
    // Two user stages that differ only in an argument that never triggers.
    let a = variant("mine", "[]");
    let b = variant("theirs", r#"["--fail-at", "1000000"]"#);
    let out_dir = sb.path("cmp");
    let out = sb.run(&[
        "compare",
        a.to_str().expect("utf8"),
        b.to_str().expect("utf8"),
        "--out",
        out_dir.to_str().expect("utf8"),
        "--no-progress",
        "--quiet",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let messages = mcap_messages(&out_dir.join("compare.mcap"));
    let by_seq = |topic: &str| -> BTreeMap<u32, MotionFrame> {
        messages
            .iter()
            .filter(|m| m.0 == topic)
            .map(|(_, seq, data)| (*seq, frame_from_bytes(data).expect("MotionFrame")))
            .collect()
    };
    let mine = by_seq("mine-counter.count");
    let theirs = by_seq("theirs-counter.count");
    assert_eq!(mine.len(), 400);
    assert_eq!(theirs.len(), 400);
    let mut distinct = std::collections::BTreeSet::new();
    for (seq, m) in &mine {
        let t = &theirs[seq];
        // q[2]: a checksum of the ImuFrame bytes each copy received.
        assert_eq!(
            m.q[2], t.q[2],
            "seq {seq}: the variants saw different bytes"
        );
        assert_eq!(m.q[0], *seq as f32, "seq {seq}: every frame, in order");
        distinct.insert(m.q[2] as u32);
    }
    assert!(distinct.len() > 390, "checksums vary with the frames");
    assert!(out_dir.join("compare.toml").is_file());
    // The report: no truth in a test source, so the variants are compared with each other.
    let report = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    assert!(
        report.contains("| metric | mine | theirs | best |"),
        "{report}"
    );
    assert!(report.contains("| angle vs mine (deg) |"), "{report}");
    let results: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("results.json")).expect("results.json"),
    )
    .expect("results.json is JSON");
    let frames = results["metrics"]
        .as_array()
        .expect("metrics")
        .iter()
        .find(|m| m["metric"] == "frames scored")
        .expect("a frames row");
    // 400 frames, every 50th flagged INVALID by the source: 392 scored, the same for both.
    assert_eq!(frames["values"]["mine"], 392.0);
    assert_eq!(frames["values"]["theirs"], 392.0);
    assert!(std::fs::metadata(out_dir.join("compare.rrd")).is_ok_and(|m| m.len() > 0));
    let left = sb.leftovers();
    assert!(left.is_empty(), "{left:?}");
}
