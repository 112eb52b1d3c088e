//! The wire contract as data, for stages written in other languages (`python/imuflow/stage.py`).
//!
//! The launcher writes it into each run's folder as [`WIRE_JSON`], next to the graph, so such a
//! stage builds its frame types, service names, port settings and flags from what this build
//! speaks instead of copying numbers that could drift: the frame layouts (as `imuflow stage
//! --layouts` prints them), keyed by the frame-type names `graph.json` uses.

use std::collections::BTreeMap;

use crate::frames::{FrameLayout, FrameType, flags};
use crate::stage::{CONTROL_PREFIX, HEARTBEAT};
use crate::transport::{self, TransportSettings};

/// File in the run directory holding the [`WireContract`] as JSON.
pub const WIRE_JSON: &str = "wire.json";

/// The iceoryx2 version this build links (a test checks it against Cargo.lock). Bindings for
/// another language must have the same minor version: iceoryx2's shared-memory layout and service
/// configuration change between minor versions.
pub const ICEORYX2_VERSION: &str = "0.10.0";

/// What a stage needs, besides the graph, to join a run.
#[derive(Debug, serde::Serialize)]
pub struct WireContract {
    /// This build's version.
    pub imuflow: &'static str,
    pub iceoryx2: &'static str,
    /// Prefix of the control lines a stage writes on stdout.
    pub control_prefix: &'static str,
    /// How often a running stage reports `alive <position>`.
    pub heartbeat_ms: u64,
    /// Service-name templates with `{run_id}`, `{stage}` and `{port}`: `output` (one per output
    /// port), `wake` (one per reading stage).
    pub services: BTreeMap<&'static str, String>,
    /// The publish-subscribe and event settings every port of a service must agree on.
    pub transport: TransportSettings,
    /// Header flag bits by name.
    pub flags: BTreeMap<&'static str, u32>,
    /// Every frame type's layout, keyed as in `graph.json` (`"Kinematics"`).
    pub layouts: BTreeMap<FrameType, &'static FrameLayout>,
}

/// The contract of this build.
pub fn contract() -> WireContract {
    let services = BTreeMap::from([
        (
            "output",
            transport::output_service_name("{run_id}", "{stage}", "{port}"),
        ),
        ("wake", transport::wake_service_name("{run_id}", "{stage}")),
    ]);
    WireContract {
        imuflow: env!("CARGO_PKG_VERSION"),
        iceoryx2: ICEORYX2_VERSION,
        control_prefix: CONTROL_PREFIX,
        heartbeat_ms: HEARTBEAT.as_millis() as u64,
        services,
        transport: transport::settings(),
        flags: flags::NAMES
            .iter()
            .map(|&(bit, name)| (name, bit))
            .collect(),
        layouts: FrameType::ALL.iter().map(|&t| (t, t.layout())).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_iceoryx2_version_is_the_one_cargo_locked() {
        let lock = include_str!("../../Cargo.lock");
        let locked = lock
            .split("[[package]]")
            .find(|p| p.contains("\nname = \"iceoryx2\"\n"))
            .and_then(|p| p.lines().find_map(|l| l.strip_prefix("version = ")))
            .map(|v| v.trim_matches('"'));
        assert_eq!(locked, Some(ICEORYX2_VERSION));
    }

    #[test]
    fn layouts_are_keyed_as_the_graph_names_frame_types() {
        let json = serde_json::to_value(contract()).expect("serializes");
        for t in FrameType::ALL {
            // graph.json spells an edge's frame type through the same serde derive.
            let key = serde_json::to_value(t).expect("serializes");
            let key = key.as_str().expect("a unit variant is a string");
            let layout = &json["layouts"][key];
            assert_eq!(layout["type_name"], t.layout().type_name, "{key}");
            assert_eq!(layout["size"], t.layout().size, "{key}");
        }
        assert_eq!(json["flags"]["END_OF_STREAM"], flags::END_OF_STREAM);
        assert_eq!(
            json["services"]["output"],
            "imuflow/{run_id}/{stage}/out/{port}"
        );
        // The templates expand to the names the Rust stages use.
        let expanded = json["services"]["wake"]
            .as_str()
            .expect("a string")
            .replace("{run_id}", "r1")
            .replace("{stage}", "kin");
        assert_eq!(expanded, transport::wake_service_name("r1", "kin"));
    }
}
