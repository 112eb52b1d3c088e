//! The validated graph: what the launcher runs and every stage process reads.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use crate::frames::FrameType;
use crate::spec::{Registry, Role};
use crate::{overrides, schema, validate};

/// Whether sources pace themselves and how late frames are treated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Sources run as fast as the slowest stage allows (back-pressure); nothing is dropped.
    Offline,
    /// Sources run at sensor rate; a stage that falls behind drops the oldest frames and counts them.
    Live,
}

/// How a stage process is started.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Runner {
    /// A built-in kind, run as `imuflow stage <kind>`.
    Builtin { kind: String },
    /// An external executable using the Stage API.
    Exec { path: PathBuf, args: Vec<String> },
}

/// One input of a stage: which output it reads.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct InputEdge {
    pub from_stage: String,
    pub from_port: String,
    pub frame: FrameType,
    /// The edge closes a cycle: the reader gets the previous frame's value.
    pub feedback: bool,
}

/// A reader of an output.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Reader {
    pub stage: String,
    pub input: String,
}

/// What a failure of a stage does to the run (`on_failure` in the graph file).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnFailure {
    /// The launcher stops every stage and the run fails (the default: a crash is a bug to report).
    #[default]
    StopRun,
    /// The stage's branch (it and every stage that reads only from the branch) is stopped and
    /// reported; stages that also read from elsewhere see the branch's inputs end; the rest of the
    /// graph runs to the end.
    StopBranch,
}

impl OnFailure {
    pub const NAMES: [&str; 2] = ["stop-run", "stop-branch"];

    pub fn from_name(name: &str) -> Option<OnFailure> {
        match name {
            "stop-run" => Some(OnFailure::StopRun),
            "stop-branch" => Some(OnFailure::StopBranch),
            _ => None,
        }
    }
}

/// A stage's restart policy (`restart = { max = 3, within_s = 60, backoff_ms = 200 }`): a stage
/// that fails is started again, up to `max` times within any `within_s` seconds, each after
/// `backoff_ms`; one failure more is handled by `on_failure`. No restarts by default: offline, a
/// crash is a bug to report; a live graph may opt in per stage.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RestartPolicy {
    pub max: u32,
    pub within_s: f64,
    pub backoff_ms: u64,
}

impl Default for RestartPolicy {
    fn default() -> Self {
        RestartPolicy {
            max: 3,
            within_s: 60.0,
            backoff_ms: 200,
        }
    }
}

/// One stage of a validated graph.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct StageNode {
    pub id: String,
    pub runner: Runner,
    pub role: Role,
    pub inputs: BTreeMap<String, InputEdge>,
    pub outputs: BTreeMap<String, FrameType>,
    /// Who reads each output (fan-out), by output name.
    pub readers: BTreeMap<String, Vec<Reader>>,
    pub params: toml::Table,
    #[serde(default)]
    pub on_failure: OnFailure,
    /// Overrides the graph's `stall_timeout_s` for this stage.
    #[serde(default)]
    pub stall_timeout_s: Option<f64>,
    /// Started again when it fails ([`RestartPolicy`]); `None`: never.
    #[serde(default)]
    pub restart: Option<RestartPolicy>,
    /// How the kernel schedules the stage's process (`nice` in the graph file).
    #[serde(default)]
    pub nice: Nice,
    /// The sensor set this stage works with when it is not the graph's ([`Graph::sensors_of`]).
    #[serde(default)]
    pub sensors: Option<String>,
}

/// How the kernel schedules a stage's process (`nice = 10` or `nice = "idle"` in the graph file):
/// a stage off the path from the sensors to the output (viewer, validation) yields the cores to
/// the ones on it, so they keep their latency.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Nice {
    /// Unix niceness, 0 (the default: the launcher's own) to 19: the kernel gives a stage with a
    /// higher value less of a contended core.
    Level(u8),
    /// Live runs: Linux's `SCHED_IDLE`, the stage runs only on a core no other stage wants and
    /// gives it up the moment one wakes (a niced stage may keep the core for part of its time
    /// slice). Offline runs: niceness 0, since there the judge is the slowest stage and starving
    /// it slows the whole run (measured: half the frames per second).
    Idle,
}

impl Default for Nice {
    fn default() -> Self {
        Nice::Level(0)
    }
}

impl Nice {
    /// Whether the stage runs as the launcher would start any process.
    pub fn is_default(self) -> bool {
        self == Nice::Level(0)
    }
}

impl std::fmt::Display for Nice {
    /// As the graph file writes it.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Nice::Level(n) => write!(f, "{n}"),
            Nice::Idle => write!(f, "\"idle\""),
        }
    }
}

/// The watchdog's default for offline graphs (live: [`DEFAULT_LIVE_STALL_TIMEOUT_S`]). Generous:
/// a slow stage is not a hung one, and an offline run has no deadline.
pub const DEFAULT_OFFLINE_STALL_TIMEOUT_S: f64 = 30.0;
/// Live: a stage that takes nothing for 5 s (300 frames at 60 Hz) has lost the session already.
pub const DEFAULT_LIVE_STALL_TIMEOUT_S: f64 = 5.0;

fn default_stall_timeout_s() -> f64 {
    DEFAULT_OFFLINE_STALL_TIMEOUT_S
}

impl StageNode {
    /// How long this stage may sit on unconsumed input before the watchdog stops it.
    pub fn stall_timeout_s(&self, graph: &Graph) -> f64 {
        self.stall_timeout_s.unwrap_or(graph.stall_timeout_s)
    }

    /// The kind for built-ins; for external stages `exec:` and the file name of the program, or
    /// of its first argument unless that is an option (an interpreter's script: `exec:smooth.py`
    /// for `python3 smooth.py`). One word, so a summary row splits into columns at whitespace.
    pub fn kind_label(&self) -> String {
        let file_name = |p: &std::path::Path| {
            p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        };
        let shown = match &self.runner {
            Runner::Builtin { kind } => return kind.clone(),
            Runner::Exec { path, args } => match args.first() {
                Some(script) if !script.starts_with('-') => file_name(std::path::Path::new(script)),
                _ => file_name(path),
            },
        };
        format!("exec:{}", shown.replace(char::is_whitespace, "_"))
    }
}

/// The sensor set of a graph that names none: PIP's and GlobalPose's six.
pub const DEFAULT_SENSORS: &str = "six";

fn default_sensors() -> String {
    DEFAULT_SENSORS.to_owned()
}

/// A graph that passed validation.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Graph {
    pub name: String,
    /// The file it came from.
    pub file: PathBuf,
    pub rate_hz: f64,
    pub mode: Mode,
    /// The sensor set, as the graph file names it ([`DEFAULT_SENSORS`] when it names none): a
    /// shipped set's name or a set file's path, resolved by the stages (`imuflow_body`).
    #[serde(default = "default_sensors")]
    pub sensors: String,
    pub ready_timeout_s: f64,
    /// The launcher's stall watchdog: seconds a stage may hold unconsumed input without taking
    /// any of it (per stage: [`StageNode::stall_timeout_s`]).
    #[serde(default = "default_stall_timeout_s")]
    pub stall_timeout_s: f64,
    /// Stages by id, in id order.
    pub stages: BTreeMap<String, StageNode>,
    /// Non-fatal findings (e.g. a stage whose outputs nobody reads).
    pub warnings: Vec<String>,
}

/// One thing wrong with a graph file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    pub stage: Option<String>,
    /// Dotted key within the stage (or the file), e.g. `inputs.imu` or `params.rate`.
    pub key: Option<String>,
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(stage) = &self.stage {
            write!(f, "stage '{stage}': ")?;
        }
        if let Some(key) = &self.key {
            write!(f, "{key}: ")?;
        }
        f.write_str(&self.message)
    }
}

/// Why a graph could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum GraphLoadError {
    /// The file could not be read: check the path.
    #[error("{path}: cannot read graph file: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not valid TOML or has keys the schema does not know.
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    /// A `--set key=value` override could not be applied.
    #[error("{path}: --set {assignment}: {message}")]
    Override {
        path: PathBuf,
        assignment: String,
        message: String,
    },
    /// The graph parsed but is not consistent; every problem is listed.
    #[error("{path}: {} problem(s) in the graph:\n{}", problems.len(), problems.iter().map(|p| format!("  - {p}")).collect::<Vec<_>>().join("\n"))]
    Invalid {
        path: PathBuf,
        problems: Vec<Problem>,
    },
}

impl Graph {
    /// Reads, overrides, parses and validates a graph file.
    ///
    /// `sets` are `key=value` overrides (`stages.kin.params.net=globalpose`); values parse as TOML,
    /// falling back to a plain string.
    pub fn load(
        path: &Path,
        sets: &[String],
        registry: &Registry,
    ) -> Result<Graph, GraphLoadError> {
        let text = std::fs::read_to_string(path).map_err(|source| GraphLoadError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_str_with(path, &text, sets, registry)
    }

    /// Like [`Graph::load`], with the text given (`path` only names it in errors).
    pub fn from_str_with(
        path: &Path,
        text: &str,
        sets: &[String],
        registry: &Registry,
    ) -> Result<Graph, GraphLoadError> {
        let mut table: toml::Table =
            text.parse()
                .map_err(|e: toml::de::Error| GraphLoadError::Parse {
                    path: path.to_owned(),
                    message: e.to_string().trim_end().to_owned(),
                })?;
        for assignment in sets {
            overrides::apply(&mut table, assignment).map_err(|message| {
                GraphLoadError::Override {
                    path: path.to_owned(),
                    assignment: assignment.clone(),
                    message,
                }
            })?;
        }
        let file: schema::GraphFile =
            toml::Value::Table(table)
                .try_into()
                .map_err(|e: toml::de::Error| GraphLoadError::Parse {
                    path: path.to_owned(),
                    message: e.to_string().trim_end().to_owned(),
                })?;
        validate::validate(path, file, registry).map_err(|problems| GraphLoadError::Invalid {
            path: path.to_owned(),
            problems,
        })
    }

    /// The sensor set stage `id` works with: its own `sensors`, else the graph's.
    pub fn sensors_of(&self, id: &str) -> &str {
        self.stages
            .get(id)
            .and_then(|n| n.sensors.as_deref())
            .unwrap_or(&self.sensors)
    }

    /// The sensor set the frames of stage `id` are estimated from: [`Graph::sensors_of`], for a
    /// stage that is not a source (a source delivers the sensors themselves and the truth, which
    /// holds every joint); `None` for a source or a stage the graph lacks.
    pub fn estimated_from(&self, id: &str) -> Option<&str> {
        self.stages
            .get(id)
            .filter(|n| n.role != Role::Source)
            .map(|_| self.sensors_of(id))
    }

    /// Stages in an order where every stage comes after the stages it reads through non-feedback
    /// edges (validation guarantees one exists).
    pub fn topological_order(&self) -> Vec<&StageNode> {
        let mut placed: Vec<&StageNode> = Vec::with_capacity(self.stages.len());
        let mut done = std::collections::BTreeSet::new();
        while placed.len() < self.stages.len() {
            let before = placed.len();
            for node in self.stages.values() {
                if done.contains(node.id.as_str()) {
                    continue;
                }
                let ready = node
                    .inputs
                    .values()
                    .all(|e| e.feedback || done.contains(e.from_stage.as_str()));
                if ready {
                    done.insert(node.id.as_str());
                    placed.push(node);
                }
            }
            if placed.len() == before {
                // Unreachable for validated graphs; keep the rest in id order rather than loop.
                placed.extend(
                    self.stages
                        .values()
                        .filter(|n| !done.contains(n.id.as_str())),
                );
                break;
            }
        }
        placed
    }

    /// The branch that `root` heads: `root` and every stage whose non-feedback inputs all come
    /// from the branch (so it has nothing left to work on once the branch stops).
    pub fn branch(&self, root: &str) -> BTreeSet<String> {
        let mut branch = BTreeSet::from([root.to_owned()]);
        // Topological order: a stage's forward inputs are decided before the stage itself.
        for node in self.topological_order() {
            let mut forward = node.inputs.values().filter(|e| !e.feedback).peekable();
            if forward.peek().is_some() && forward.all(|e| branch.contains(&e.from_stage)) {
                branch.insert(node.id.clone());
            }
        }
        branch
    }

    /// The isolated branch a failure of `stage` stops: the smallest branch headed by a
    /// `stop-branch` stage that contains it, or `None` when the failure stops the run.
    pub fn isolated_branch_of(&self, stage: &str) -> Option<(String, BTreeSet<String>)> {
        self.stages
            .values()
            .filter(|n| n.on_failure == OnFailure::StopBranch)
            .map(|n| (n.id.clone(), self.branch(&n.id)))
            .filter(|(_, branch)| branch.contains(stage))
            .min_by_key(|(_, branch)| branch.len())
    }

    /// The wiring as text, one stage per block, in flow order.
    pub fn describe(&self) -> String {
        use std::fmt::Write;
        let mut out = String::new();
        let mode = match self.mode {
            Mode::Offline => "offline",
            Mode::Live => "live",
        };
        let _ = writeln!(
            out,
            "graph '{}' ({}), {} stages, {} Hz, {mode}, sensors {}",
            self.name,
            self.file.display(),
            self.stages.len(),
            self.rate_hz,
            self.sensors
        );
        for node in self.topological_order() {
            let _ = writeln!(
                out,
                "\n[{}] {} ({:?})",
                node.id,
                node.kind_label(),
                node.role
            );
            for (name, edge) in &node.inputs {
                let fb = if edge.feedback {
                    "  (feedback: previous frame)"
                } else {
                    ""
                };
                let _ = writeln!(
                    out,
                    "  in  {name:<12} <- {}.{}  {}{fb}",
                    edge.from_stage, edge.from_port, edge.frame
                );
            }
            for (name, frame) in &node.outputs {
                let readers = node
                    .readers
                    .get(name)
                    .map(Vec::as_slice)
                    .unwrap_or_default();
                let to = if readers.is_empty() {
                    "(not read)".to_owned()
                } else {
                    readers
                        .iter()
                        .map(|r| format!("{}.{}", r.stage, r.input))
                        .collect::<Vec<_>>()
                        .join(", ")
                };
                let _ = writeln!(out, "  out {name:<12} -> {to}  {frame}");
            }
            match node.nice {
                Nice::Idle => {
                    let _ = writeln!(
                        out,
                        "  nice = \"idle\": live, runs only on cores no other stage wants"
                    );
                }
                n if !n.is_default() => {
                    let _ = writeln!(out, "  nice = {n}: yields contended cores");
                }
                _ => {}
            }
            if let Some(sensors) = &node.sensors {
                let _ = writeln!(out, "  sensors = {sensors} (the graph's: {})", self.sensors);
            }
            if node.on_failure == OnFailure::StopBranch {
                let branch = self.branch(&node.id);
                let _ = writeln!(
                    out,
                    "  on_failure = stop-branch: a failure stops {}",
                    branch.into_iter().collect::<Vec<_>>().join(", ")
                );
            }
            if !node.params.is_empty() {
                let params = node
                    .params
                    .iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect::<Vec<_>>()
                    .join(", ");
                let _ = writeln!(out, "  params {{ {params} }}");
            }
        }
        for w in &self.warnings {
            let _ = writeln!(out, "\nwarning: {w}");
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(id: &str, inputs: &[(&str, &str, bool)], on_failure: OnFailure) -> StageNode {
        StageNode {
            id: id.into(),
            runner: Runner::Builtin { kind: "k".into() },
            role: if inputs.is_empty() {
                Role::Source
            } else {
                Role::Transform
            },
            inputs: inputs
                .iter()
                .map(|(name, from, feedback)| {
                    let edge = InputEdge {
                        from_stage: (*from).into(),
                        from_port: "out".into(),
                        frame: FrameType::Motion,
                        feedback: *feedback,
                    };
                    ((*name).into(), edge)
                })
                .collect(),
            outputs: BTreeMap::new(),
            readers: BTreeMap::new(),
            params: toml::Table::new(),
            on_failure,
            nice: Nice::default(),
            sensors: None,
            stall_timeout_s: None,
            restart: None,
        }
    }

    /// source -> calib -> {a: kin_a -> opt_a (-> contact_a, feedback), b: kin_b -> opt_b},
    /// val <- opt_a, val_rec <- val, viz <- {source, opt_a, opt_b, val}.
    fn ab_graph() -> Graph {
        use OnFailure::*;
        let nodes = [
            node("source", &[], StopRun),
            node("calib", &[("imu", "source", false)], StopRun),
            node("kin_a", &[("imu", "calib", false)], StopBranch),
            node(
                "contact_a",
                &[("kin", "kin_a", false), ("state", "opt_a", true)],
                StopRun,
            ),
            node(
                "opt_a",
                &[("kin", "kin_a", false), ("contacts", "contact_a", false)],
                StopRun,
            ),
            node("kin_b", &[("imu", "calib", false)], StopBranch),
            node("opt_b", &[("kin", "kin_b", false)], StopRun),
            node("val", &[("motion", "opt_a", false)], StopBranch),
            node("val_rec", &[("v", "val", false)], StopRun),
            node(
                "viz",
                &[
                    ("truth", "source", false),
                    ("a", "opt_a", false),
                    ("b", "opt_b", false),
                    ("v", "val", false),
                ],
                StopRun,
            ),
        ];
        Graph {
            name: "ab".into(),
            file: PathBuf::from("ab.toml"),
            rate_hz: 60.0,
            sensors: DEFAULT_SENSORS.to_owned(),
            mode: Mode::Offline,
            ready_timeout_s: 30.0,
            stall_timeout_s: DEFAULT_OFFLINE_STALL_TIMEOUT_S,
            stages: nodes.into_iter().map(|n| (n.id.clone(), n)).collect(),
            warnings: Vec::new(),
        }
    }

    fn set(ids: &[&str]) -> BTreeSet<String> {
        ids.iter().map(|s| (*s).to_owned()).collect()
    }

    #[test]
    fn a_branch_is_its_root_and_what_reads_only_from_it() {
        let g = ab_graph();
        // The contact stage's feedback from opt_a does not keep it out of kin_a's branch; the
        // viewer reads other stages too, so it is never part of a branch.
        assert_eq!(
            g.branch("kin_a"),
            set(&["kin_a", "contact_a", "opt_a", "val", "val_rec"])
        );
        assert_eq!(g.branch("kin_b"), set(&["kin_b", "opt_b"]));
        assert_eq!(g.branch("val"), set(&["val", "val_rec"]));
        assert_eq!(g.branch("source").len(), g.stages.len());
    }

    #[test]
    fn a_failure_stops_the_smallest_isolated_branch_holding_it() {
        let g = ab_graph();
        let root = |stage: &str| g.isolated_branch_of(stage).map(|(root, _)| root);
        assert_eq!(root("val_rec").as_deref(), Some("val"));
        assert_eq!(root("opt_a").as_deref(), Some("kin_a"));
        assert_eq!(root("opt_b").as_deref(), Some("kin_b"));
        // Shared stages and the viewer join the branches: their failure stops the run.
        assert_eq!(root("calib"), None);
        assert_eq!(root("viz"), None);
    }
}
