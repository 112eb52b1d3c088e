//! Graph validation through the CLI: every invalid fixture in tests/graphs/ must fail with the
//! messages its `# expect:` lines state (naming file, stage and key); valid ones must pass.
//! Also the shipped configs, `--set` overrides and `graph show`.

mod common;

use std::path::{Path, PathBuf};

use common::{Sandbox, text};

fn fixtures(prefix: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/graphs");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("tests/graphs exists")
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with(prefix))
        })
        .collect();
    files.sort();
    files
}

#[test]
fn every_invalid_graph_is_rejected_with_its_expected_messages() {
    let sb = Sandbox::new("check-invalid");
    let files = fixtures("invalid-");
    assert!(files.len() >= 20, "fixtures found: {}", files.len());
    for file in files {
        let source = std::fs::read_to_string(&file).expect("read fixture");
        let expected: Vec<&str> = source
            .lines()
            .filter_map(|l| l.strip_prefix("# expect: "))
            .collect();
        assert!(
            !expected.is_empty(),
            "{}: no `# expect:` line",
            file.display()
        );
        let out = sb.run(&["graph", "check", file.to_str().expect("utf8")]);
        let stderr = text(&out.stderr);
        assert_eq!(
            out.status.code(),
            Some(2),
            "{}: must fail with exit code 2\n{stderr}",
            file.display()
        );
        let name = file.file_name().expect("name").to_string_lossy();
        assert!(
            stderr.contains(name.as_ref()),
            "{}: error names the file:\n{stderr}",
            file.display()
        );
        for want in expected {
            assert!(
                stderr.contains(want),
                "{}: expected\n  {want}\nin\n{stderr}",
                file.display()
            );
        }
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

#[test]
fn valid_graphs_and_shipped_configs_pass() {
    let sb = Sandbox::new("check-valid");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = fixtures("valid-");
    for dir in ["configs", "configs/examples"] {
        for entry in std::fs::read_dir(root.join(dir))
            .expect("configs exist")
            .flatten()
        {
            if entry.path().extension().is_some_and(|e| e == "toml") {
                files.push(entry.path());
            }
        }
    }
    assert!(files.len() >= 3);
    for file in files {
        let out = sb.run(&["graph", "check", file.to_str().expect("utf8")]);
        assert!(
            out.status.success(),
            "{}:\n{}",
            file.display(),
            text(&out.stderr)
        );
        assert!(
            text(&out.stdout).contains(": ok ("),
            "{}",
            text(&out.stdout)
        );
    }
}

#[test]
fn nice_takes_a_level_or_idle_and_names_anything_else() {
    let sb = Sandbox::new("check-nice");
    let graph = sb.graph(
        "g.toml",
        "name = \"g\"\n[stages.src]\nkind = \"test-source\"\n[stages.rec]\nkind = \"recorder\"\ninputs = { imu = \"src.imu\" }\nparams = { path = \"x.mcap\" }\n",
    );
    let g = graph.to_str().expect("utf8");
    // `graph show` prints the wiring with each stage's scheduling; `graph check` the problems.
    let run = |command: &str, nice: &str| {
        sb.run(&[
            "graph",
            command,
            g,
            "--set",
            &format!("stages.rec.nice={nice}"),
        ])
    };
    for (nice, shown) in [
        (
            "\"idle\"",
            "nice = \"idle\": live, runs only on cores no other stage wants",
        ),
        ("12", "nice = 12: yields contended cores"),
    ] {
        let out = run("show", nice);
        assert!(out.status.success(), "{nice}: {}", text(&out.stderr));
        assert!(
            text(&out.stdout).contains(shown),
            "{nice}: {}",
            text(&out.stdout)
        );
    }
    for nice in ["\"fast\"", "20"] {
        let out = run("check", nice);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{nice}: {stderr}");
        assert!(
            stderr.contains(
                "stage 'rec': nice: must be an integer from 0 (the default) to 19, or \"idle\""
            ),
            "{nice}: {stderr}"
        );
    }
}

#[test]
fn set_overrides_are_validated_like_written_values() {
    let sb = Sandbox::new("check-set");
    let graph = sb.graph(
        "g.toml",
        "name = \"g\"\n[stages.src]\nkind = \"test-source\"\n[stages.rec]\nkind = \"recorder\"\ninputs = { imu = \"src.imu\" }\n",
    );
    let g = graph.to_str().expect("utf8");
    // The file lacks the recorder's path: an override supplies it.
    let out = sb.run(&["graph", "check", g]);
    assert_eq!(out.status.code(), Some(2));
    let out = sb.run(&[
        "graph",
        "check",
        g,
        "--set",
        "stages.rec.params.path=x.mcap",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Typed values parse as TOML; wrong ones are reported with the key.
    let out = sb.run(&[
        "graph",
        "check",
        g,
        "--set",
        "stages.rec.params.path=x.mcap",
        "--set",
        "stages.src.params.frames=ten",
    ]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr.contains("stage 'src': params.frames: must be an integer"),
        "{stderr}"
    );
    // A malformed assignment names itself.
    let out = sb.run(&["graph", "check", g, "--set", "name.inner=3"]);
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("--set name.inner=3: 'name' is a string, not a table"),
        "{stderr}"
    );
    let out = sb.run(&["graph", "check", g, "--set", "stages.rec.params.path"]);
    assert!(text(&out.stderr).contains("expected KEY=VALUE"));
}

#[test]
fn graph_show_prints_the_wiring_in_flow_order() {
    let sb = Sandbox::new("show");
    let file =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/graphs/valid-feedback-fanout.toml");
    let out = sb.run(&["graph", "show", file.to_str().expect("utf8")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    let src = s.find("[src]").expect("src listed");
    let mine = s.find("[mine]").expect("mine listed");
    let sink = s.find("[sink]").expect("sink listed");
    assert!(src < mine && mine < sink, "flow order:\n{s}");
    assert!(
        s.contains("in  prev         <- mine.count  MotionFrame  (feedback: previous frame)"),
        "{s}"
    );
    assert!(
        s.contains("out imu          -> mine.imu, sink.imu  ImuFrame"),
        "fan-out shown:\n{s}"
    );
}

#[test]
fn missing_graph_file_is_named() {
    let sb = Sandbox::new("missing");
    let out = sb.run(&["graph", "check", "/no/such/graph.toml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("/no/such/graph.toml: cannot read graph file"));
}
