//! Graph files as written: the raw TOML shape, parsed with unknown keys rejected. `validate` turns
//! this into a checked [`crate::Graph`].

use std::collections::BTreeMap;

/// A graph file (`configs/*.toml`).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphFile {
    /// Name of the graph, shown in logs and summaries.
    pub name: String,
    /// Nominal frame rate of the sources, Hz. Default 60 (both papers run at 60 Hz).
    #[serde(default)]
    pub rate_hz: Option<toml::Value>,
    /// `offline` (default): sources run as fast as the slowest stage allows, nothing is dropped.
    /// `live`: sources run at sensor rate; a late stage drops frames and counts them.
    #[serde(default)]
    pub mode: Option<String>,
    /// The sensor set the graph's sensors are: a shipped set's name (`six`, the default;
    /// `lower-body`, `full-suit`) or the path of a user's set file (`models/sensor-sets.toml`
    /// shows the form). Every stage follows it; the graph crate keeps it as written.
    #[serde(default)]
    pub sensors: Option<String>,
    /// Seconds to wait for every stage to report ready. Default 30.
    #[serde(default)]
    pub ready_timeout_s: Option<toml::Value>,
    /// Seconds a stage may hold unconsumed input without consuming any before the watchdog
    /// treats it as failed. Default 30 offline, 5 live.
    #[serde(default)]
    pub stall_timeout_s: Option<toml::Value>,
    /// The stages, by id.
    #[serde(default)]
    pub stages: BTreeMap<String, StageEntry>,
}

/// One `[stages.<id>]` table.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageEntry {
    /// A built-in stage kind (`imuflow stage --list`). Exactly one of `kind` and `exec`.
    pub kind: Option<String>,
    /// An external executable built on imuflow-graph's Stage API.
    pub exec: Option<String>,
    /// Extra command-line arguments for `exec`.
    #[serde(default)]
    pub args: Vec<String>,
    /// `input = "stage.port"` pairs, plus `feedback = ["input", ...]` naming inputs that read the
    /// previous frame's value (the edges that close a cycle).
    #[serde(default)]
    pub inputs: toml::Table,
    /// For `exec` stages only: `port = "FrameType"` for each output.
    #[serde(default)]
    pub outputs: BTreeMap<String, String>,
    /// Kind-specific parameters.
    #[serde(default)]
    pub params: toml::Table,
    /// `stop-run` (default): a failure of this stage stops the whole run. `stop-branch`: it stops
    /// only this stage and what reads nothing but its outputs; the rest runs to the end.
    #[serde(default)]
    pub on_failure: Option<String>,
    /// This stage's stall timeout (overrides the graph's `stall_timeout_s`).
    #[serde(default)]
    pub stall_timeout_s: Option<toml::Value>,
    /// Restart policy: `{ max = 3, within_s = 60, backoff_ms = 200 }` (none by default).
    #[serde(default)]
    pub restart: Option<toml::Value>,
    /// Scheduling niceness of the stage's process, 0 (default) to 19, or "idle" (live runs only
    /// on cores no other stage wants): a stage off the latency-critical path (viewer,
    /// validation) yields the cores to the ones on it.
    #[serde(default)]
    pub nice: Option<toml::Value>,
    /// The sensor set this stage works with, when it is not the graph's (`sensors` at the top):
    /// a set whose sites the graph's set holds (`imuflow compare` of variants with different
    /// sets gives each variant's stages its own).
    #[serde(default)]
    pub sensors: Option<String>,
}
