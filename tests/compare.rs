//! `imuflow compare`: the combined graph (shared source, one isolated branch per variant), its
//! refusals, and the proof that every variant sees byte-identical input.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{Sandbox, example_exe, mcap_messages, text};
use imuflow_graph::frames::{MotionFrame, frame_from_bytes};

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
    // Each variant's calibrated IMUs go to the recorder (the sensor-bone error), not the viewer.
    let record = &combined[combined.find("[stages.record]").expect("a recorder")..];
    let viz = &combined[combined.find("[stages.viz]").expect("a logger")..];
    let viz = &viz[..viz.find("[stages.record]").unwrap_or(viz.len())];
    for v in ["pip", "globalpose", "no-physics"] {
        assert!(
            record.contains(&format!("{v}__body_imu = \"{v}-calib.body_imu\"")),
            "{record}"
        );
    }
    assert!(!viz.contains("body_imu"), "{viz}");
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
    // Variants of two sensor sets compare on one input: tests/sensor_sets.rs.
    // A stage whose own set wears a site the graph's set lacks: refused before anything starts.
    let wider = sb.graph(
        "wider.toml",
        r#"
name = "wider"
sensors = "lower-body"
[stages.source]
kind = "test-source"
[stages.record]
kind = "recorder"
inputs = { imu = "source.imu" }
params = { path = "{dir}/wider.mcap" }
sensors = "six"
"#,
    );
    let out = sb.run(&["graph", "check", wider.to_str().expect("utf8")]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("record")
            && stderr.contains("sensors")
            && stderr.contains(
                "wears left_forearm, right_forearm, head that the graph's set lower-body"
            ),
        "{stderr}"
    );
    // Variants of one set other than the six: the combined graph names it.
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/lower-body.toml");
    let ablation = sb.graph(
        "legs-ab.toml",
        &format!(
            r#"
name = "legs-physics"
description = "two optimizers on the lower-body example"
[[variant]]
name = "integrate"
graph = "{0}"
[[variant]]
name = "pip"
graph = "{0}"
set = ["stages.opt.params.method=pip"]
"#,
            example.display()
        ),
    );
    let out = sb.run(&["compare", ablation.to_str().expect("utf8"), "--print-graph"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("\nsensors = \"lower-body\"\n"),
        "{}",
        text(&out.stdout)
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

/// `n` file names whose clip keys fall in `split` (the dataset's hash rule).
fn names_in_split(n: usize, split: imuflow_dataset::Split) -> Vec<String> {
    (0..)
        .map(|i| format!("clip_{i:03}.bvh"))
        .filter(|name| imuflow_dataset::split_of(name) == split)
        .take(n)
        .collect()
}

/// Two variants of the same user stage, once with its left knee bent 90°: worse on every clip by
/// construction.
fn straight_and_bent(sb: &Sandbox) -> (std::path::PathBuf, std::path::PathBuf) {
    let root = env!("CARGO_MANIFEST_DIR");
    let counter = example_exe("external_counter");
    let variant = |name: &str, args: &str| {
        sb.graph(
            &format!("{name}.toml"),
            &format!(
                r#"
name = "{name}"
[stages.source]
kind = "imu-source"
params = {{ mode = "replay", path = "{root}/models/sample/walk.mcap" }}
[stages.counter]
exec = "{}"
args = {args}
inputs = {{ imu = "source.imu", prev = "counter.count", feedback = ["prev"] }}
outputs = {{ count = "MotionFrame" }}
[stages.record]
kind = "recorder"
inputs = {{ motion = "counter.count", truth = "source.truth" }}
params = {{ path = "{{dir}}/{name}.mcap" }}
"#,
                counter.display()
            ),
        )
    };
    (
        variant("straight", "[]"),
        variant("bent", r#"["--bend-knee-deg", "90"]"#),
    )
}

#[test]
fn batch_mode_scores_every_clip_pairs_the_variants_and_resumes() {
    let sb = Sandbox::new("compare-batch");
    let root = env!("CARGO_MANIFEST_DIR");
    // Five clips of the test split (a real Bandai walk, enough clips for an interval) and one
    // malformed clip in it.
    let data = sb.path("clips");
    std::fs::create_dir_all(&data).expect("clips dir");
    let names = names_in_split(6, imuflow_dataset::Split::Test);
    let walk = format!("{root}/libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh");
    for name in &names[..5] {
        std::fs::copy(&walk, data.join(name)).expect("copy clip");
    }
    let broken = &names[5];
    std::fs::write(data.join(broken), "HIERARCHY\nROOT broken {\n").expect("write clip");
    // A training clip the test split must not pick up.
    let train = names_in_split(1, imuflow_dataset::Split::Train);
    std::fs::write(data.join(&train[0]), "not read").expect("write clip");
    let (straight, bent) = straight_and_bent(&sb);
    let out_dir = sb.path("batch");
    let args = [
        "compare",
        straight.to_str().expect("utf8"),
        bent.to_str().expect("utf8"),
        "--data",
        data.to_str().expect("utf8"),
        "--out",
        out_dir.to_str().expect("utf8"),
        "--no-progress",
    ];
    let out = sb.run(&args);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        text(&out.stdout).contains("5 clips scored, 1 not scored"),
        "{}",
        text(&out.stdout)
    );
    assert!(
        stderr.contains(&format!("clip {broken} not scored")),
        "{stderr}"
    );

    let results: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("results.json")).expect("results.json"),
    )
    .expect("results.json is JSON");
    assert_eq!(results["clips_scored"], 5);
    assert_eq!(results["clips_failed"][0]["clip"], broken.as_str());
    let error = results["metrics"]
        .as_array()
        .expect("metrics")
        .iter()
        .find(|m| m["metric"] == "joint position error")
        .expect("joint position error");
    let straight_mean = error["stats"][0]["mean"].as_f64().expect("mean");
    let bent_mean = error["stats"][1]["mean"].as_f64().expect("mean");
    assert_eq!(error["stats"][0]["n"], 5);
    // Identical clips and input: each variant scores the same on both, so the spread is 0.
    assert!(error["stats"][0]["std"].as_f64().expect("std") < 1e-9);
    let pair = &error["pairs"][0];
    let diff = pair["difference"]["mean_diff"].as_f64().expect("diff");
    assert!(
        (diff - (bent_mean - straight_mean)).abs() < 1e-9,
        "the pair is bent − straight"
    );
    assert!(diff > 1.0, "a 90° knee bend costs more than 1 cm: {diff}");
    assert!(pair["difference"]["ci95_low"].as_f64().expect("low") > 0.0);
    let report = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    assert!(
        report.contains("| metric | straight | bent | clips |"),
        "{report}"
    );
    assert!(report.contains("| metric | bent − straight |"), "{report}");
    assert!(report.contains(&format!("`{broken}`")), "{report}");
    assert!(out_dir.join("clip_errors.png").is_file());
    // The recordings were scored and deleted; clips.jsonl holds a header and the three clips.
    let log = std::fs::read_to_string(out_dir.join("clips.jsonl")).expect("clips.jsonl");
    assert_eq!(log.lines().count(), 7, "{log}");
    assert_eq!(
        std::fs::read_dir(out_dir.join("recordings"))
            .expect("recordings")
            .count(),
        0
    );

    // Run again: every clip is done, nothing runs, the same report comes out.
    let again = sb.run(&args);
    let stderr = text(&again.stderr);
    assert!(again.status.success(), "{stderr}");
    assert!(stderr.contains("resuming: 6 of 6 clips"), "{stderr}");
    let report_again = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    assert_eq!(report, report_again);

    // Other variants into the same folder are refused rather than mixed.
    let mut swapped = args;
    swapped.swap(1, 2);
    let refused = sb.run(&swapped);
    assert!(!refused.status.success());
    assert!(
        text(&refused.stderr).contains("holds the results of another comparison"),
        "{}",
        text(&refused.stderr)
    );
    let left = sb.leftovers();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn a_batch_mixes_data_sets_each_with_its_mapping_and_reports_each_on_its_own() {
    let sb = Sandbox::new("compare-sources");
    let root = env!("CARGO_MANIFEST_DIR");
    let fixtures = format!("{root}/libs/motion/tests/fixtures");
    // "home": Bandai walks named into the training split, which `--split all` runs all the same.
    let home = sb.path("home");
    std::fs::create_dir_all(&home).expect("home dir");
    let names = names_in_split(2, imuflow_dataset::Split::Train);
    for name in &names {
        std::fs::copy(
            format!("{fixtures}/bandai-walk-normal-trimmed.bvh"),
            home.join(name),
        )
        .expect("copy clip");
    }
    // "away": another rig (the CMU / iClone walk) under a subfolder, and a clip the exclusion list
    // leaves out (unreadable, so running it would fail the clip).
    let away = sb.path("data/away");
    std::fs::create_dir_all(away.join("bvh")).expect("away dir");
    let cmu = format!("{fixtures}/cmu-007-03-walk-trimmed.bvh");
    std::fs::copy(&cmu, away.join("bvh/007_03.bvh")).expect("copy clip");
    std::fs::copy(&cmu, away.join("bvh/007_03b.bvh")).expect("copy clip");
    std::fs::write(away.join("bvh/001_08.bvh"), "climbing").expect("write clip");
    let exclude = sb.path("exclude.txt");
    std::fs::write(&exclude, "# no floor\n001_08.bvh  # climbing\n").expect("exclude list");

    let (straight, bent) = straight_and_bent(&sb);
    let out_dir = sb.path("batch");
    let arg = |p: &std::path::Path| p.to_str().expect("utf8").to_owned();
    let bandai_map = format!("{root}/libs/motion/mappings/bandai-namco.toml");
    let cmu_map = format!("{root}/libs/motion/mappings/cmu-iclone.toml");
    let mut args: Vec<String> = vec!["compare".into(), arg(&straight), arg(&bent)];
    for (data, mapping) in [(arg(&home), &bandai_map), (arg(&away), &cmu_map)] {
        args.extend(["--data".into(), data, "--mapping".into(), mapping.clone()]);
    }
    args.extend(
        [
            "--split",
            "all",
            "--exclude",
            &arg(&exclude),
            "--out",
            &arg(&out_dir),
            "--no-progress",
        ]
        .map(String::from),
    );
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = sb.run_within(&args, 180);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        text(&out.stdout).contains("4 clips scored, 0 not scored"),
        "{}\n{stderr}",
        text(&out.stdout)
    );

    let results: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("results.json")).expect("results.json"),
    )
    .expect("results.json is JSON");
    assert_eq!(results["split"], "all");
    assert_eq!(results["clips_excluded"][0], "away/bvh/001_08.bvh");
    let mean_of = |metrics: &serde_json::Value, k: usize| {
        metrics
            .as_array()
            .expect("metrics")
            .iter()
            .find(|m| m["metric"] == "joint position error")
            .expect("joint position error")["stats"][k]["mean"]
            .as_f64()
            .expect("mean")
    };
    let sources = results["sources"].as_array().expect("sources");
    assert_eq!(sources.len(), 2);
    assert_eq!(
        (&sources[0]["name"], &sources[1]["name"]),
        (&"home".into(), &"away".into())
    );
    assert_eq!(sources[1]["mapping"], cmu_map.as_str());
    assert_eq!(
        (&sources[0]["clips_scored"], &sources[1]["clips_scored"]),
        (&2.into(), &2.into())
    );
    // The pooled mean is the clip-weighted mean of the two data sets' means, for each variant, and
    // the bent knee costs on both rigs.
    for k in 0..2 {
        let (h, a) = (
            mean_of(&sources[0]["metrics"], k),
            mean_of(&sources[1]["metrics"], k),
        );
        let pooled = mean_of(&results["metrics"], k);
        assert!(
            (pooled - (2.0 * h + 2.0 * a) / 4.0).abs() < 1e-9,
            "{pooled} {h} {a}"
        );
    }
    for source in sources {
        assert!(mean_of(&source["metrics"], 1) > mean_of(&source["metrics"], 0) + 1.0);
    }
    let log = std::fs::read_to_string(out_dir.join("clips.jsonl")).expect("clips.jsonl");
    let clips: Vec<serde_json::Value> = log
        .lines()
        .skip(1)
        .map(|l| serde_json::from_str(l).expect("clip record"))
        .collect();
    let labelled: Vec<(&str, &str)> = clips
        .iter()
        .map(|c| {
            (
                c["source"].as_str().expect("source"),
                c["clip"].as_str().expect("clip"),
            )
        })
        .collect();
    assert!(
        labelled.contains(&("home", &format!("home/{}", names[0]))),
        "{labelled:?}"
    );
    assert!(
        labelled.contains(&("away", "away/bvh/007_03b.bvh")),
        "{labelled:?}"
    );
    let report = std::fs::read_to_string(out_dir.join("report.md")).expect("report.md");
    assert!(report.contains("on every clip"), "{report}");
    assert!(
        report.contains("| source | metric | straight | bent | clips |"),
        "{report}"
    );
    assert!(
        report.contains("| home | joint position error (cm) |"),
        "{report}"
    );
    assert!(
        report.contains("| away | joint position error (cm) |"),
        "{report}"
    );
    assert!(report.contains("- `away/bvh/001_08.bvh`"), "{report}");

    // Three mappings for two folders: refused before anything runs.
    let mut wrong = args.clone();
    wrong.extend(["--mapping", &cmu_map]);
    let refused = sb.run(&wrong);
    assert!(!refused.status.success());
    assert!(
        text(&refused.stderr).contains("3 --mapping files for 2 --data folders"),
        "{}",
        text(&refused.stderr)
    );
    let left = sb.leftovers();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn ablation_files_expand_into_variants_and_bad_ones_are_named() {
    let sb = Sandbox::new("compare-ablation");
    let root = env!("CARGO_MANIFEST_DIR");
    for (file, variants) in [
        (
            "physics",
            &["integrate", "pip-physics", "globalpose-physics"][..],
        ),
        ("nets", &["pip-nets", "globalpose-nets"][..]),
        ("calibration", &["tpose", "walking"][..]),
        ("full", &["pip", "globalpose", "no-physics"][..]),
        (
            "lower-body",
            &["sensed", "pip-legs", "pip-legs-physics"][..],
        ),
        ("full-suit", &["sensed", "pip-suit", "pip-suit-physics"][..]),
        ("full-protocol", &["pip", "globalpose", "no-physics"][..]),
        (
            "limb-flexion",
            &[
                "pip-rotations",
                "pip-positions",
                "gp-rotations",
                "gp-positions",
                "nophys-rotations",
                "nophys-positions",
            ][..],
        ),
        (
            "mirror-ensemble",
            &[
                "pip",
                "pip-mirrored",
                "gp",
                "gp-mirrored",
                "nophys",
                "nophys-mirrored",
            ][..],
        ),
        (
            "weights",
            &[
                "pip-protocol",
                "pip",
                "gp-protocol",
                "gp",
                "nophys-protocol",
                "nophys",
            ][..],
        ),
    ] {
        let path = format!("{root}/configs/ab/{file}.toml");
        let out = sb.run(&["compare", &path, "--print-graph"]);
        assert!(out.status.success(), "{file}: {}", text(&out.stderr));
        let combined = text(&out.stdout);
        for v in variants {
            assert!(
                combined.contains(&format!("[stages.{v}-opt]")),
                "{file}: {v}"
            );
        }
        let graph = sb.graph(&format!("{file}.toml"), &combined);
        let show = sb.run(&["graph", "show", graph.to_str().expect("utf8")]);
        assert!(show.status.success(), "{file}: {}", text(&show.stderr));
    }
    // The nets ablation shares the calibration but not the networks; the overrides took effect.
    let nets = text(
        &sb.run(&[
            "compare",
            &format!("{root}/configs/ab/nets.toml"),
            "--print-graph",
        ])
        .stdout,
    );
    assert!(nets.contains("[stages.calib]"), "{nets}");
    assert!(nets.contains("[stages.pip-nets-kin]") && nets.contains("models/pip.safetensors"));
    // The weights ablation gives its protocol variants the protocol's files, full-protocol all
    // three, and those exist.
    for file in ["weights", "full-protocol"] {
        let combined = text(
            &sb.run(&[
                "compare",
                &format!("{root}/configs/ab/{file}.toml"),
                "--print-graph",
            ])
            .stdout,
        );
        assert_eq!(
            combined.matches("models/protocol/").count(),
            3,
            "{file}: {combined}"
        );
    }
    for file in ["pip", "globalpose"] {
        assert!(Path::new(&format!("{root}/models/protocol/{file}.safetensors")).is_file());
    }
    // The mirroring ablation turns the ensemble on in its mirrored variants' kinematics only.
    let mirrored = text(
        &sb.run(&[
            "compare",
            &format!("{root}/configs/ab/mirror-ensemble.toml"),
            "--print-graph",
        ])
        .stdout,
    );
    assert_eq!(
        mirrored.matches("mirror_ensemble = true").count(),
        3,
        "{mirrored}"
    );

    let bad = sb.graph(
        "bad.toml",
        "name = \"bad\"\n[[variant]]\nname = \"a b\"\ngraph = \"x.toml\"\n[[variant]]\nname = \"c\"\ngraph = \"y.toml\"\n",
    );
    let out = sb.run(&["compare", bad.to_str().expect("utf8"), "--print-graph"]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("bad.toml") && stderr.contains("'a b'"),
        "{stderr}"
    );
    let one = sb.graph(
        "one.toml",
        "name = \"one\"\n[[variant]]\nname = \"a\"\ngraph = \"x.toml\"\nsurprise = 1\n",
    );
    let out = sb.run(&["compare", one.to_str().expect("utf8"), "--print-graph"]);
    let stderr = text(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("one.toml") && stderr.contains("surprise"),
        "{stderr}"
    );
}

#[test]
fn a_bvh_input_is_synthesized_with_the_sensor_errors_asked_for() {
    let sb = Sandbox::new("compare-sensor-errors");
    let root = env!("CARGO_MANIFEST_DIR");
    let walk = format!("{root}/libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh");
    let (pip, gp) = (
        format!("{root}/configs/pip.toml"),
        format!("{root}/configs/globalpose.toml"),
    );
    let source_params = |errors: Option<&str>| {
        let mut args = vec!["compare", "--print-graph", "--input", &walk, &pip, &gp];
        if let Some(e) = errors {
            args.extend(["--sensor-errors", e]);
        }
        let out = sb.run(&args);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let combined: toml::Table = text(&out.stdout)
            .parse()
            .expect("the combined graph is TOML");
        combined["stages"]["source"]["params"]
            .as_table()
            .expect("source params")
            .clone()
    };
    // The default is the reference model; `none` turns every error off but keeps the mountings
    // random, so the calibrations still have to find them.
    for (errors, augmented) in [
        (None, true),
        (Some("reference"), true),
        (Some("none"), false),
    ] {
        let params = source_params(errors);
        assert_eq!(params["mode"].as_str(), Some("synthesize"), "{errors:?}");
        assert_eq!(params["augment"].as_bool(), Some(augmented), "{errors:?}");
        assert_eq!(params["mounting"].as_str(), Some("random"), "{errors:?}");
    }
    let out = sb.run(&[
        "compare",
        "--print-graph",
        "--input",
        &walk,
        &pip,
        &gp,
        "--sensor-errors",
        "ideal",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("reference, none"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn source_set_overrides_the_replaced_source_s_parameters_in_order() {
    let sb = Sandbox::new("compare-source-set");
    let root = env!("CARGO_MANIFEST_DIR");
    let walk = format!("{root}/libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh");
    let (pip, gp) = (
        format!("{root}/configs/pip.toml"),
        format!("{root}/configs/globalpose.toml"),
    );
    let out = sb.run(&[
        "compare",
        "--print-graph",
        "--input",
        &walk,
        &pip,
        &gp,
        "--source-set",
        "prelude=stand",
        "--source-set",
        "raw_noise=1.5",
        "--source-set",
        "raw=true",
        "--source-set",
        "raw_noise=2",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let combined: toml::Table = text(&out.stdout).parse().expect("TOML");
    let params = combined["stages"]["source"]["params"]
        .as_table()
        .expect("source params");
    // A word is a string, TOML values keep their type, the last of a key wins, and what the
    // input sets itself stays unless overridden.
    assert_eq!(params["prelude"].as_str(), Some("stand"));
    assert_eq!(params["raw"].as_bool(), Some(true));
    assert_eq!(params["raw_noise"].as_integer(), Some(2));
    assert_eq!(params["mounting"].as_str(), Some("random"));
    let out = sb.run(&[
        "compare",
        "--print-graph",
        "--input",
        &walk,
        &pip,
        &gp,
        "--source-set",
        "no-equals-sign",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("KEY=VALUE"),
        "{}",
        text(&out.stderr)
    );
}
