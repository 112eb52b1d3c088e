//! A graph's sensor set (`sensors` at the top of the graph file) in real multi-process graphs: a
//! lower-body set synthesized through raw sensors and fused carries exactly its sites; a lower-body
//! export reads and fuses as that set; a set the body model lacks is refused before any stage
//! starts; the six-site networks refuse another set, and the walking calibration a set without
//! the pelvis and shanks, naming what they lack.

mod common;

use std::path::{Path, PathBuf};

use common::{Sandbox, assert_clean, mcap_messages, text};
use imuflow_graph::frames::{ImuFrame, RawImuFrame, flags, frame_from_bytes};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

/// Slots of the lower-body set: left and right lower leg (2, 3), pelvis (5), left and right
/// upper leg (6, 7), written out here rather than taken from the body crate.
const LOWER_BODY: u32 = 1 << 2 | 1 << 3 | 1 << 5 | 1 << 6 | 1 << 7;

#[test]
fn a_lower_body_graph_synthesizes_and_fuses_exactly_its_sites() {
    let sb = Sandbox::new("sets-legs");
    let graph = sb.graph(
        "legs.toml",
        &format!(
            r#"
name = "legs"
sensors = "lower-body"
[stages.source]
kind = "imu-source"
params = {{ mode = "synthesize", path = "{}", prelude = "stand", raw = true, raw_noise = 1.0 }}
[stages.fusion]
kind = "fusion"
inputs = {{ raw = "source.raw" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "fusion.imu", raw = "source.raw" }}
params = {{ path = "{{dir}}/legs.mcap" }}
"#,
            fixture().display()
        ),
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let messages = mcap_messages(&sb.path("legs.mcap"));
    let mut raw_sites = 0u32;
    for m in messages.iter().filter(|m| m.0 == "source.raw") {
        let f: RawImuFrame = frame_from_bytes(&m.2).expect("a RawImuFrame");
        raw_sites |= f.valid_mask;
    }
    assert_eq!(raw_sites, LOWER_BODY, "the raw samples' sites");
    let fused: Vec<ImuFrame> = messages
        .iter()
        .filter(|m| m.0 == "fusion.imu")
        .map(|m| frame_from_bytes(&m.2).expect("an ImuFrame"))
        .filter(|f: &ImuFrame| !f.header.is_end())
        .collect();
    assert!(fused.len() > 100, "{} fused frames", fused.len());
    let whole = fused
        .iter()
        .filter(|f| f.valid_mask == LOWER_BODY && !f.header.has(flags::INVALID))
        .count();
    // Every frame but the few before each sensor's rate is measured.
    assert!(
        whole + 10 >= fused.len(),
        "{whole} of {} whole",
        fused.len()
    );
    for f in &fused {
        assert_eq!(f.valid_mask & !LOWER_BODY, 0);
        // The forearms' and the head's slots stay empty.
        for slot in [0, 1, 4] {
            assert_eq!(f.orientation_wxyz[slot], [0.0; 4]);
        }
    }
    assert_clean(&sb);
}

#[test]
fn a_set_the_body_lacks_and_weights_for_another_set_are_refused_naming_both() {
    let sb = Sandbox::new("sets-refused");
    let source = format!(
        r#"
[stages.source]
kind = "imu-source"
params = {{ mode = "synthesize", path = "{}" }}
"#,
        fixture().display()
    );
    let graph = sb.graph(
        "tail.toml",
        &format!("name = \"tail\"\nsensors = \"tail\"\n{source}"),
    );
    let out = sb.run(&["graph", "check", graph.to_str().expect("utf8")]);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("sensors: sensor set 'tail'") && err.contains("full-suit, lower-body, six"),
        "{err}"
    );

    let weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/pip.safetensors");
    let graph = sb.graph(
        "legs-pip.toml",
        &format!(
            r#"name = "legs-pip"
sensors = "lower-body"
{source}
[stages.calib]
kind = "calibration"
inputs = {{ imu = "source.imu" }}
[stages.kin]
kind = "kinematics"
inputs = {{ imu = "calib.body_imu" }}
params = {{ net = "pip", weights = "{}" }}
"#,
            weights.display()
        ),
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let err = text(&out.stderr);
    assert!(!out.status.success(), "{err}");
    // The calibration takes the lower body; the six-site networks refuse it.
    assert!(
        err.contains("stage 'kin'")
            && err.contains(
                "the graph's sensors are lower-body (left_lower_leg, right_lower_leg, pelvis, left_upper_leg, right_upper_leg)"
            ),
        "{err}"
    );

    // A user's set without the shanks: the walking calibration says what it lacks.
    let set = sb.path("hips-set.toml");
    std::fs::write(
        &set,
        "[hips]\nsites = [\"pelvis\", \"left_upper_leg\", \"right_upper_leg\"]\nheading_reference = \"pelvis\"\n",
    )
    .expect("write the set");
    let graph = sb.graph(
        "hips.toml",
        &format!(
            r#"name = "hips"
sensors = "{}"
{source}
[stages.calib]
kind = "calibration"
inputs = {{ imu = "source.imu" }}
params = {{ method = "walking" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "calib.body_imu" }}
params = {{ path = "{{dir}}/hips.mcap" }}
"#,
            set.display()
        ),
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let err = text(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("lack left_lower_leg, right_lower_leg")
            && err.contains("hips (pelvis, left_upper_leg, right_upper_leg)"),
        "{err}"
    );
    assert_clean(&sb);
}

#[test]
fn a_lower_body_export_runs_through_a_lower_body_graph() {
    let sb = Sandbox::new("sets-dot");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let graph = sb.graph(
        "dot.toml",
        &format!(
            r#"
name = "dot-legs"
sensors = "lower-body"
[stages.source]
kind = "imu-source"
params = {{ mode = "file", path = "{}", layout = "{}" }}
[stages.fusion]
kind = "fusion"
inputs = {{ raw = "source.raw" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "fusion.imu" }}
params = {{ path = "{{dir}}/dot.mcap" }}
"#,
            root.join("libs/sensor-files/tests/fixtures/movella-dot-lower-body")
                .display(),
            root.join("configs/sensor-layouts/movella-dot.toml")
                .display()
        ),
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let log = text(&out.stderr);
    assert!(out.status.success(), "stderr:\n{log}");
    let fused: Vec<ImuFrame> = mcap_messages(&sb.path("dot.mcap"))
        .iter()
        .filter(|m| m.0 == "fusion.imu")
        .map(|m| frame_from_bytes(&m.2).expect("an ImuFrame"))
        .filter(|f: &ImuFrame| !f.header.is_end())
        .collect();
    let mut seen = 0;
    for f in &fused {
        assert_eq!(f.valid_mask & !LOWER_BODY, 0);
        seen |= f.valid_mask;
    }
    // Every site of the set fused at some frame (the left femur's sensor lost most of its
    // packets, so frames without it are INVALID and the fusion names it).
    assert_eq!(seen, LOWER_BODY);
    assert!(fused.iter().any(|f| f.valid_mask == LOWER_BODY));
    assert!(log.contains("left_upper_leg"), "{log}");
    assert_clean(&sb);
}
