//! Bad input, fuzzed: the parsers of everything a user hands imuflow (BVH motion, graph files,
//! joint-mapping TOML, mcap recordings to replay, UDP sensor packets) take valid inputs mutated at
//! random (bytes replaced, inserted, deleted, the file cut short, lines repeated) and never panic;
//! every rejection of a file names it.
//!
//! proptest rather than cargo-fuzz: it runs on stable Rust inside `cargo test`, bounded (a fixed
//! number of cases per target, seeded per run), and it shrinks a failure to a small input and
//! stores it under `tests/fuzzed_inputs.proptest-regressions`, which every later run replays
//! first: the crash corpus is kept as regression tests. Raise the cases for a longer hunt:
//! `PROPTEST_CASES=20000 cargo test --release --test fuzzed_inputs`.

use std::path::Path;

use imuflow_graph::Graph;
use imuflow_graph::spec::Registry;
use imuflow_imu_source::udp::{PACKET_SIZE, Packet, packet_size};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::retarget::{BANDAI_NAMCO_MAPPING_TOML, SourceSkeleton};
use imuflow_recording::Recording;
use proptest::prelude::*;
use proptest::sample::Index;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// One edit of an input.
#[derive(Debug, Clone)]
enum Edit {
    Replace(Index, u8),
    Insert(Index, u8),
    Delete(Index),
    Truncate(Index),
    /// Repeat the line that holds this byte (a duplicated key, joint or frame).
    RepeatLine(Index),
    /// An ASCII digit run at this byte (huge counts, sizes and indices).
    Digits(Index, u64),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Replace(i, b)),
        (any::<Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Insert(i, b)),
        any::<Index>().prop_map(Edit::Delete),
        any::<Index>().prop_map(Edit::Truncate),
        any::<Index>().prop_map(Edit::RepeatLine),
        (any::<Index>(), any::<u64>()).prop_map(|(i, n)| Edit::Digits(i, n)),
    ]
}

fn mutate(mut bytes: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for e in edits {
        if bytes.is_empty() {
            break;
        }
        let at = |i: &Index| i.index(bytes.len());
        match e {
            Edit::Replace(i, b) => {
                let k = at(i);
                bytes[k] = *b;
            }
            Edit::Insert(i, b) => {
                let k = at(i);
                bytes.insert(k, *b);
            }
            Edit::Delete(i) => {
                let k = at(i);
                bytes.remove(k);
            }
            Edit::Truncate(i) => {
                let k = at(i);
                bytes.truncate(k);
            }
            Edit::RepeatLine(i) => {
                let k = at(i);
                let start = bytes[..k]
                    .iter()
                    .rposition(|&b| b == b'\n')
                    .map_or(0, |p| p + 1);
                let end = bytes[k..]
                    .iter()
                    .position(|&b| b == b'\n')
                    .map_or(bytes.len(), |p| k + p + 1);
                let line = bytes[start..end].to_vec();
                bytes.splice(end..end, line);
            }
            Edit::Digits(i, n) => {
                let k = at(i);
                let digits = n.to_string().into_bytes();
                bytes.splice(k..k, digits);
            }
        }
    }
    bytes
}

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    prop::collection::vec(edit(), 1..12)
}

fn read(path: &str) -> Vec<u8> {
    std::fs::read(Path::new(ROOT).join(path)).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// `PROPTEST_CASES` when set (a longer hunt), else the bounded default for `cargo test`.
fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn registry() -> Registry {
    Registry::new(vec![
        imuflow_test_source::SPEC,
        imuflow_recorder::SPEC,
        imuflow_rerun_logger::SPEC,
        imuflow_imu_source::SPEC,
        imuflow_calibration::SPEC,
        imuflow_kinematics::SPEC,
        imuflow_contact_stage::SPEC,
        imuflow_optimizer::SPEC,
        imuflow_validation::SPEC,
    ])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(256), ..ProptestConfig::default() })]

    #[test]
    fn bvh_files(edits in edits()) {
        let text = mutate(read("libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh"), &edits);
        let text = String::from_utf8_lossy(&text);
        if let Err(e) = Bvh::parse(&text, "fuzzed.bvh") {
            prop_assert!(e.to_string().contains("fuzzed.bvh"), "{e}");
        }
    }

    #[test]
    fn mapping_files(edits in edits()) {
        let text = mutate(BANDAI_NAMCO_MAPPING_TOML.as_bytes().to_vec(), &edits);
        let text = String::from_utf8_lossy(&text);
        if let Err(e) = SourceSkeleton::from_toml_str(&text, "fuzzed-mapping.toml") {
            prop_assert!(e.to_string().contains("fuzzed-mapping.toml"), "{e}");
        }
    }

    #[test]
    fn graph_files(edits in edits(), which in 0usize..3) {
        let file = ["configs/pip.toml", "configs/globalpose.toml", "configs/ab/physics.toml"][which];
        let text = mutate(read(file), &edits);
        let text = String::from_utf8_lossy(&text);
        let path = Path::new("fuzzed-graph.toml");
        if let Err(e) = Graph::from_str_with(path, &text, &[], &registry()) {
            prop_assert!(e.to_string().contains("fuzzed-graph.toml"), "{e}");
        }
    }

    #[test]
    fn ablation_files(edits in edits()) {
        let text = mutate(read("configs/ab/nets.toml"), &edits);
        let dir = std::env::temp_dir().join(format!("imuflow-fuzz-ab-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("fuzzed-ablation.toml");
        std::fs::write(&path, &text).expect("write");
        if let Err(e) = imuflow_compare::combine::read_ablation(&path) {
            prop_assert!(e.to_string().contains("fuzzed-ablation.toml"), "{e}");
        }
    }

    #[test]
    fn udp_packets(bytes in prop::collection::vec(any::<u8>(), 0..PACKET_SIZE * 2)) {
        let _ = Packet::decode(&bytes, 6);
        let _ = Packet::decode(&bytes, 17);
    }

    #[test]
    fn udp_packets_of_the_right_size(bytes in prop::collection::vec(any::<u8>(), PACKET_SIZE)) {
        let _ = Packet::decode(&bytes, 6);
    }

    #[test]
    fn udp_packets_of_a_full_suits_size(bytes in prop::collection::vec(any::<u8>(), packet_size(17))) {
        let _ = Packet::decode(&bytes, 17);
    }
}

proptest! {
    // The sample recording is 0.7 MB: fewer cases keep this target's time near the others'.
    #![proptest_config(ProptestConfig { cases: cases(48), ..ProptestConfig::default() })]

    #[test]
    fn mcap_recordings(edits in edits()) {
        let bytes = mutate(read("models/sample/walk.mcap"), &edits);
        let _ = Recording::parse(&bytes, None, None);
    }
}
