//! The validated graph: what the launcher runs and every stage process reads.

use std::collections::BTreeMap;
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
}

impl StageNode {
    /// The kind for built-ins, the executable's file name for external stages.
    pub fn kind_label(&self) -> String {
        match &self.runner {
            Runner::Builtin { kind } => kind.clone(),
            Runner::Exec { path, .. } => format!("exec:{}", path.display()),
        }
    }
}

/// A graph that passed validation.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Graph {
    pub name: String,
    /// The file it came from.
    pub file: PathBuf,
    pub rate_hz: f64,
    pub mode: Mode,
    pub ready_timeout_s: f64,
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
            "graph '{}' ({}), {} stages, {} Hz, {mode}",
            self.name,
            self.file.display(),
            self.stages.len(),
            self.rate_hz
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
