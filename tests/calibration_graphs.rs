//! The calibration example graphs validate against the stage specs, with the method switched by `--set`, and
//! run end to end through the calibrator (in process).

use std::path::{Path, PathBuf};

use imuflow_calibration::stage::config_from_params;
use imuflow_calibration::{Calibrator, Event, Method};
use imuflow_graph::spec::Registry;
use imuflow_graph::stage::Params;
use imuflow_graph::{Graph, frames::BodyImuFrame};

fn registry() -> Registry {
    Registry::new([
        imuflow_imu_source::SPEC,
        imuflow_calibration::SPEC,
        imuflow_recorder::SPEC,
        imuflow_rerun_logger::SPEC,
    ])
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

fn load(name: &str, sets: &[&str]) -> Graph {
    let path = root().join("configs/examples").join(name);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    Graph::load(&path, &sets, &registry()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Synthesizes what the graph's source would publish and runs the graph's calibration on it.
fn run_graph(graph: &Graph) -> Vec<Event> {
    let source = Params(&graph.stages["source"].params);
    let calib = Params(&graph.stages["calib"].params);
    let config = config_from_params(&calib, graph.rate_hz).expect("config");
    let options = imuflow_synth::Options {
        augment: source.bool("augment", false),
        seed: source.int("seed", 0) as u64,
        prelude: imuflow_synth::prelude::PreludeOptions {
            kind: imuflow_synth::prelude::PreludeKind::parse(
                source.str("prelude").expect("prelude"),
            )
            .expect("known"),
            ..Default::default()
        },
        sensors: imuflow_synth::SensorSetup {
            random_mounting: source.str("mounting") == Some("random"),
            frame: imuflow_synth::InertialFrame::parse(source.str("frame").expect("frame"))
                .expect("known"),
            frame_heading_deg: source.float("frame_heading_deg", 0.0),
            heading_offset_deg: source.float("heading_offset_deg", 0.0),
        },
        ..Default::default()
    };
    let bvh = root().join(source.str("path").expect("path"));
    let motion = imuflow_synth::Motion::load(&bvh, &options, graph.rate_hz).expect("synthesizes");
    let mut calibrator = Calibrator::new(config);
    let mut events = Vec::new();
    for t in 0..motion.len() {
        let mut out = BodyImuFrame::default();
        events.extend(calibrator.push(&motion.imu_frame(t).expect("frame"), &mut out));
    }
    assert!(calibrator.finish().is_ok(), "{events:?}");
    events
}

#[test]
fn example_graphs_validate_and_switch_method_with_set() {
    for name in ["calibrate-tpose.toml", "calibrate-walking.toml"] {
        for method in ["tpose", "walking"] {
            let set = format!("stages.calib.params.method={method}");
            let graph = load(name, &[&set]);
            let params = Params(&graph.stages["calib"].params);
            let config = config_from_params(&params, graph.rate_hz).expect("config");
            assert_eq!(config.method, Method::parse(method).expect("known"));
        }
    }
    let err = Graph::load(
        &root().join("configs/examples/calibrate-tpose.toml"),
        &["stages.calib.params.method=magic".to_owned()],
        &registry(),
    )
    .expect_err("unknown method");
    assert!(err.to_string().contains("calibrate-tpose.toml"), "{err}");
}

#[test]
fn example_graphs_calibrate_with_either_method() {
    let tpose = run_graph(&load("calibrate-tpose.toml", &[]));
    assert!(
        matches!(tpose.last(), Some(Event::Calibrated { .. })),
        "{tpose:?}"
    );
    let walking = run_graph(&load("calibrate-walking.toml", &[]));
    // The T-pose hold followed by the N-pose stand is refused first; the real step is accepted.
    let kinds: Vec<&str> = walking
        .iter()
        .map(|e| match e {
            Event::Stand { .. } => "stand",
            Event::Rejected { .. } => "rejected",
            Event::Calibrated { .. } => "calibrated",
            _ => "other",
        })
        .collect();
    assert_eq!(kinds, ["stand", "rejected", "calibrated"], "{walking:?}");
    let switched = run_graph(&load(
        "calibrate-tpose.toml",
        &["stages.calib.params.method=walking"],
    ));
    assert!(
        switched
            .iter()
            .any(|e| matches!(e, Event::Calibrated { .. })),
        "{switched:?}"
    );
}
