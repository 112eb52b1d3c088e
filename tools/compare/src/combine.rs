//! Combining variant graphs into one A/B graph (`imuflow compare`): one shared source (and every
//! stage that is identical in all variants) fanned out to a copy of each variant's own stages,
//! each copy an isolated branch, all read by one recorder and one rerun logger.
//!
//! The result is graph-file text, so what runs is exactly what `--print-graph` shows and a user
//! can keep and edit it. Stage ids of copies are `<variant>-<id>`; the sinks read each variant's
//! outputs through inputs named `<variant>__<what>`, which the rerun logger turns into the entity
//! path `<variant>/<what>` (one entity root per variant).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write;
use std::path::Path;

use imuflow_graph::frames::FrameType;
use imuflow_graph::graph::{Graph, OnFailure, Runner, StageNode};
use imuflow_graph::naming::grouped;
use imuflow_graph::spec::Role;

/// Sink kinds that a comparison replaces with its own (one recorder, one logger for all).
const REPLACED_SINKS: [&str; 2] = ["recorder", "rerun-logger"];

/// One variant to compare: its name (an identifier) and its validated graph.
#[derive(Clone)]
pub struct Variant {
    pub name: String,
    pub graph: Graph,
}

/// The combined graph's sinks: where they write and how the viewer lays the variants out.
pub struct SinkPaths {
    pub mcap: String,
    /// The rerun recording; `None` leaves the rerun logger out (batch runs score the mcap only).
    pub rrd: Option<String>,
    /// All variants in one 3D view instead of one view each.
    pub overlaid: bool,
}

/// How a variant's outputs appear in the combined graph.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VariantOutputs {
    pub name: String,
    /// `stage.port` of the variant's motion estimate in the combined graph.
    pub motion: String,
    pub contacts: Option<String>,
    /// The variant's validation stage in the combined graph (ports `sim` and `validation`).
    pub validation: Option<String>,
    /// `stage.port` of the calibrated IMU frames the variant's estimate is made from (the nearest
    /// BodyImuFrame upstream of its motion), recorded as `<variant>__body_imu` so that the report
    /// can say how far the pose is from its own sensors. `None` when the graph has none.
    pub body_imu: Option<String>,
    /// The sensor set the variant estimates from (its graph's `sensors`): the report scores it
    /// on the joints that set observes.
    pub sensors: String,
    /// Every stage of the variant's own branch, in the combined graph.
    pub stages: Vec<String>,
    /// The first stages of the branch (they read only shared stages): where identical input
    /// enters, and where `on_failure = "stop-branch"` isolates the variant.
    pub roots: Vec<String>,
}

/// The combined graph.
#[derive(Debug, Clone)]
pub struct Combined {
    /// Graph-file text (TOML).
    pub text: String,
    /// Stages shared by all variants (the source first).
    pub shared: Vec<String>,
    pub variants: Vec<VariantOutputs>,
    /// The source's `truth` output, when it has one (`source.truth`).
    pub truth: Option<String>,
    /// Things the user should know (a later variant's source replaced, ...).
    pub notes: Vec<String>,
}

/// Why variants cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum CombineError {
    #[error("compare needs at least two variants (got {0})")]
    TooFew(usize),
    #[error("variant '{name}': {why}")]
    NotComparable { name: String, why: String },
}

fn not_comparable(name: &str, why: impl Into<String>) -> CombineError {
    CombineError::NotComparable {
        name: name.to_owned(),
        why: why.into(),
    }
}

/// Combines `variants` (the first one's source feeds all) into one graph named `name`.
pub fn combine(
    name: &str,
    variants: &[Variant],
    sinks: &SinkPaths,
) -> Result<Combined, CombineError> {
    if variants.len() < 2 {
        return Err(CombineError::TooFew(variants.len()));
    }
    let first = &variants[0];
    let mut notes = Vec::new();
    let sources: Vec<String> = variants
        .iter()
        .map(|v| single_source(v).map(|s| s.id.clone()))
        .collect::<Result<_, _>>()?;
    for v in variants {
        check_comparable(first, v)?;
    }
    let sensors = union_of_sets(variants)?;
    // The set a stage of variant `v` works with: its own, else its graph's.
    let set_of = |v: &Variant, node: &StageNode| -> String {
        node.sensors
            .clone()
            .unwrap_or_else(|| v.graph.sensors.clone())
    };
    // Written on a stage of the combined graph when it is not the combined graph's.
    let own_set = |set: String| (set != sensors).then_some(set);
    for v in variants {
        motion_output(v)?;
    }
    let source = first.graph.stages[&sources[0]].clone();
    for (v, id) in variants.iter().zip(&sources).skip(1) {
        let other = &v.graph.stages[id];
        if other.runner != source.runner || other.params != source.params {
            notes.push(format!(
                "variant '{}' has its own source '{id}'; every variant gets the source of '{}' (stage '{}')",
                v.name, first.name, source.id
            ));
        }
    }

    // Shared: the source, then every non-sink stage that is the same in every variant and reads
    // only shared stages, in flow order.
    let mut shared: Vec<String> = vec![source.id.clone()];
    for node in first.graph.topological_order() {
        if node.role == Role::Source || is_replaced_sink(node) {
            continue;
        }
        let same_everywhere = variants.iter().zip(&sources).all(|(v, src)| {
            v.graph.stages.get(&node.id).is_some_and(|other| {
                same_stage(node, other, src, &source.id)
                    && set_of(v, other) == set_of(first, node)
                    && other
                        .inputs
                        .values()
                        .all(|e| e.from_stage == *src || shared.contains(&e.from_stage))
            })
        });
        if same_everywhere {
            shared.push(node.id.clone());
        }
    }

    let mut text = String::new();
    let _ = writeln!(
        text,
        "# imuflow compare: {} on identical input (generated; keep and edit it freely).\n# Shared: {}. Each variant's own stages are copied as <variant>-<stage>, isolated with\n# on_failure = \"stop-branch\" at their first stages.",
        variants
            .iter()
            .map(|v| v.name.as_str())
            .collect::<Vec<_>>()
            .join(" vs "),
        shared.join(", ")
    );
    let _ = writeln!(text, "name = {}", quote(name));
    let _ = writeln!(text, "rate_hz = {}", float(first.graph.rate_hz));
    if sensors != imuflow_graph::graph::DEFAULT_SENSORS {
        let _ = writeln!(text, "sensors = {}", quote(&sensors));
    }
    if first.graph.mode == imuflow_graph::Mode::Live {
        let _ = writeln!(text, "mode = \"live\"");
    }
    let ready = variants
        .iter()
        .map(|v| v.graph.ready_timeout_s)
        .fold(0.0, f64::max);
    let _ = writeln!(text, "ready_timeout_s = {}", float(ready));
    let stall = variants
        .iter()
        .map(|v| v.graph.stall_timeout_s)
        .fold(0.0, f64::max);
    let _ = writeln!(text, "stall_timeout_s = {}", float(stall));

    for id in &shared {
        let (node, set) = if *id == source.id {
            // The source delivers every variant's sites: the combined graph's set.
            (&source, source.sensors.clone())
        } else {
            let node = &first.graph.stages[id];
            (node, own_set(set_of(first, node)))
        };
        write_stage(
            &mut text,
            id,
            node,
            &|from| from.to_owned(),
            None,
            set.as_deref(),
        );
    }

    let mut outputs = Vec::new();
    for (v, src) in variants.iter().zip(&sources) {
        let rename = |from: &str| -> String {
            if from == src {
                source.id.clone()
            } else if shared.iter().any(|s| s == from) {
                from.to_owned()
            } else {
                prefixed(&v.name, from)
            }
        };
        let own: Vec<&StageNode> = v
            .graph
            .topological_order()
            .into_iter()
            .filter(|n| n.id != *src && !shared.contains(&n.id) && !is_replaced_sink(n))
            .collect();
        let mut roots = Vec::new();
        for node in &own {
            let forward_from_shared = node
                .inputs
                .values()
                .filter(|e| !e.feedback)
                .all(|e| e.from_stage == *src || shared.contains(&e.from_stage));
            if forward_from_shared {
                roots.push(prefixed(&v.name, &node.id));
            }
            let isolate = forward_from_shared.then_some(OnFailure::StopBranch);
            write_stage(
                &mut text,
                &prefixed(&v.name, &node.id),
                node,
                &rename,
                isolate,
                own_set(set_of(v, node)).as_deref(),
            );
        }
        let (motion_stage, motion_port) = motion_output(v)?;
        if shared.contains(&motion_stage) {
            return Err(not_comparable(
                &v.name,
                format!(
                    "its motion comes from '{motion_stage}', which is the same in every variant: there is nothing to compare"
                ),
            ));
        }
        let motion_node = &v.graph.stages[&motion_stage];
        let contacts = (motion_node.outputs.get("contacts") == Some(&FrameType::Contact))
            .then(|| format!("{}.contacts", rename(&motion_stage)));
        let validation = v
            .graph
            .stages
            .values()
            .find(|n| {
                n.runner
                    == Runner::Builtin {
                        kind: "validation".into(),
                    }
                    && n.inputs
                        .get("motion")
                        .is_some_and(|e| e.from_stage == motion_stage && e.from_port == motion_port)
            })
            .map(|n| rename(&n.id));
        let body_imu = nearest_body_imu(v, &motion_stage)
            .map(|(stage, port)| format!("{}.{port}", rename(&stage)));
        outputs.push(VariantOutputs {
            name: v.name.clone(),
            motion: format!("{}.{motion_port}", rename(&motion_stage)),
            contacts,
            validation,
            body_imu,
            sensors: set_of(v, motion_node),
            stages: own.iter().map(|n| prefixed(&v.name, &n.id)).collect(),
            roots,
        });
    }

    let truth = (source.outputs.get("truth") == Some(&FrameType::Motion))
        .then(|| format!("{}.truth", source.id));
    let mut sink_inputs: Vec<(String, String)> = Vec::new();
    if let Some(t) = &truth {
        sink_inputs.push(("truth".into(), t.clone()));
    }
    for o in &outputs {
        let group = |what: &str| grouped(&o.name, what);
        sink_inputs.push((group("motion"), o.motion.clone()));
        if let Some(c) = &o.contacts {
            sink_inputs.push((group("contacts"), c.clone()));
        }
        if let Some(val) = &o.validation {
            sink_inputs.push((group("validation"), format!("{val}.sim")));
            sink_inputs.push((group("validation_scores"), format!("{val}.validation")));
        }
    }
    let inline = |inputs: &[(String, String)]| {
        inputs
            .iter()
            .map(|(k, v)| format!("{k} = {}", quote(v)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let inline_inputs = inline(&sink_inputs);
    // The calibrated IMUs go to the recorder only (the viewer draws the skeletons); a calibration
    // shared by the variants is recorded once.
    let mut recorded = sink_inputs.clone();
    let mut body_imus = BTreeSet::new();
    for o in &outputs {
        if let Some(b) = o.body_imu.as_ref().filter(|b| body_imus.insert(b.as_str())) {
            recorded.push((grouped(&o.name, "body_imu"), b.clone()));
        }
    }
    if let Some(rrd) = &sinks.rrd {
        let _ = writeln!(
            text,
            "\n[stages.viz]\nkind = \"rerun-logger\"\ninputs = {{ {inline_inputs} }}\nparams = {{ path = {}, views = {}, group_order = {} }}",
            quote(rrd),
            quote(if sinks.overlaid {
                "overlaid"
            } else {
                "side-by-side"
            }),
            quote(
                &outputs
                    .iter()
                    .map(|o| o.name.as_str())
                    .collect::<Vec<_>>()
                    .join(",")
            )
        );
    }
    let _ = writeln!(
        text,
        "\n[stages.record]\nkind = \"recorder\"\ninputs = {{ {} }}\nparams = {{ path = {} }}",
        inline(&recorded),
        quote(&sinks.mcap)
    );
    Ok(Combined {
        text,
        shared,
        variants: outputs,
        truth,
        notes,
    })
}

/// An ablation file (`configs/ab/*.toml`): a comparison as data. Each variant is a graph file
/// (relative to the ablation file) plus `--set` overrides, so "GlobalPose with PIP's networks" is
/// two lines, not a copy of a graph that drifts from the original.
///
/// ```toml
/// name = "nets"
/// description = "PIP's against GlobalPose's networks under GlobalPose's physics"
///
/// [[variant]]
/// name = "pip-nets"
/// graph = "../globalpose.toml"
/// set = ["stages.kin.params.net=pip", "stages.kin.params.weights=models/pip.safetensors"]
/// ```
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AblationFile {
    pub name: String,
    #[serde(default)]
    pub description: String,
    #[serde(rename = "variant")]
    pub variants: Vec<AblationVariant>,
}

/// One variant of an ablation file.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AblationVariant {
    pub name: String,
    /// The graph file; relative paths are resolved against the ablation file's folder.
    pub graph: std::path::PathBuf,
    /// Overrides in `--set` syntax (`stages.<id>.params.<key>=<value>`).
    #[serde(default)]
    pub set: Vec<String>,
}

/// Why an ablation file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum AblationError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: String, message: String },
}

/// Reads `path` as an ablation file: `Ok(None)` when it is a graph file instead (no `[[variant]]`).
pub fn read_ablation(path: &Path) -> Result<Option<AblationFile>, AblationError> {
    let shown = path.display().to_string();
    let invalid = |message: String| AblationError::Invalid {
        path: shown.clone(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|source| AblationError::Io {
        path: shown.clone(),
        source,
    })?;
    // A graph file that does not parse is the graph loader's to report, with its own context.
    let Ok(table) = text.parse::<toml::Table>() else {
        return Ok(None);
    };
    if !table.contains_key("variant") {
        return Ok(None);
    }
    let mut file: AblationFile = toml::from_str(&text).map_err(|e| invalid(e.to_string()))?;
    if file.variants.len() < 2 {
        return Err(invalid(format!(
            "an ablation needs at least two [[variant]]s (got {})",
            file.variants.len()
        )));
    }
    let base = path.parent().unwrap_or(Path::new(""));
    let mut seen = BTreeSet::new();
    for v in &mut file.variants {
        let valid = !v.name.is_empty()
            && v.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !valid {
            return Err(invalid(format!(
                "variant name '{}' must be letters, digits, '_' or '-'",
                v.name
            )));
        }
        if !seen.insert(v.name.clone()) {
            return Err(invalid(format!("variant '{}' is named twice", v.name)));
        }
        if v.graph.is_relative() {
            v.graph = base.join(&v.graph);
        }
    }
    Ok(Some(file))
}

/// Why an input cannot replace the source.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(String);

/// What the IMUs synthesized from a BVH input get wrong, beyond their random mounting (which the
/// calibrations must find either way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SensorErrors {
    /// The reference model (GlobalPose §3): a residual mounting error and its slow walk, sensor
    /// noise and bias walks, heading drift. What the published comparisons use.
    #[default]
    Reference,
    /// Exact signals: the only error left is what the calibration makes of the prelude. Against
    /// `Reference` on the same clips it separates what the sensors cost from what the rest costs.
    None,
}

impl SensorErrors {
    /// The names the command line takes, in the order of [`SensorErrors::ALL`].
    pub const NAMES: [&'static str; 2] = ["reference", "none"];
    /// Every model, in variant order.
    const ALL: [SensorErrors; 2] = [SensorErrors::Reference, SensorErrors::None];

    /// Parses one of [`SensorErrors::NAMES`].
    pub fn parse(name: &str) -> Option<SensorErrors> {
        let k = Self::NAMES.iter().position(|n| *n == name)?;
        Some(Self::ALL[k])
    }

    /// How a report describes the synthesized signals.
    pub fn describe(self) -> &'static str {
        match self {
            SensorErrors::Reference => "the reference noise",
            SensorErrors::None => "no sensor errors (exact signals)",
        }
    }
}

/// Points the first variant's source at `input`: an mcap replay, or IMUs synthesized from a BVH
/// with `errors` (an mcap replays what was recorded: `errors` does not apply); then sets the
/// parameters of `set` on it, in order (`--source-set`: another prelude, raw sensors, ...).
pub fn replace_source(
    graph: &mut Graph,
    input: &Path,
    mapping: Option<&Path>,
    errors: SensorErrors,
    set: &[(String, toml::Value)],
) -> Result<(), InputError> {
    if !input.is_file() {
        return Err(InputError(format!("{}: no such file", input.display())));
    }
    let source = graph
        .stages
        .values_mut()
        .find(|n| n.role == Role::Source)
        .ok_or_else(|| InputError("the first variant has no source".into()))?;
    if source.runner
        != (Runner::Builtin {
            kind: "imu-source".into(),
        })
    {
        return Err(InputError(format!(
            "an input replaces an imu-source, but the first variant's source '{}' is {}",
            source.id,
            source.kind_label()
        )));
    }
    let path = toml::Value::String(input.display().to_string());
    let extension = input
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let mut params = toml::Table::new();
    match extension.as_str() {
        "mcap" => {
            params.insert("mode".into(), "replay".into());
            params.insert("path".into(), path);
        }
        "bvh" => {
            // What a real session looks like to the calibrations: a T-pose hold and a few steps
            // first, sensors mounted at random, the reference noise, a z-up inertial frame.
            params.insert("mode".into(), "synthesize".into());
            params.insert("path".into(), path);
            params.insert("prelude".into(), "tpose+walk".into());
            params.insert("augment".into(), (errors == SensorErrors::Reference).into());
            params.insert("mounting".into(), "random".into());
            params.insert("frame".into(), "z-up".into());
            // The facing the shipped graphs' T-pose calibration assumes (`heading_deg = 30.0`).
            params.insert("frame_heading_deg".into(), 30.0.into());
            if let Some(m) = mapping {
                params.insert("mapping".into(), m.display().to_string().into());
            }
        }
        other => {
            return Err(InputError(format!(
                "{}: expected an .mcap recording or a .bvh motion (got '.{other}')",
                input.display()
            )));
        }
    }
    for (key, value) in set {
        params.insert(key.clone(), value.clone());
    }
    source.params = params;
    Ok(())
}

/// Parses one `--source-set KEY=VALUE`, the value as `--set` reads it (a TOML value, or the text as
/// a string: `prelude=stand`).
pub fn parse_source_set(arg: &str) -> Result<(String, toml::Value), String> {
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| format!("--source-set {arg}: expected KEY=VALUE"))?;
    let key = key.trim();
    if key.is_empty() || !key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!(
            "--source-set {arg}: '{key}' is not a parameter name"
        ));
    }
    let parsed = imuflow_graph::overrides::parse_value(value.trim());
    Ok((key.to_owned(), parsed))
}

fn prefixed(variant: &str, stage: &str) -> String {
    format!("{variant}-{stage}")
}

fn is_replaced_sink(node: &StageNode) -> bool {
    matches!(&node.runner, Runner::Builtin { kind } if REPLACED_SINKS.contains(&kind.as_str()))
}

fn single_source(v: &Variant) -> Result<&StageNode, CombineError> {
    let sources: Vec<&StageNode> = v
        .graph
        .stages
        .values()
        .filter(|n| n.role == Role::Source)
        .collect();
    match sources.as_slice() {
        [one] => Ok(one),
        _ => Err(not_comparable(
            &v.name,
            format!(
                "has {} sources ({}); compare feeds every variant from one source",
                sources.len(),
                sources
                    .iter()
                    .map(|s| s.id.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

fn check_comparable(first: &Variant, v: &Variant) -> Result<(), CombineError> {
    if (v.graph.rate_hz - first.graph.rate_hz).abs() > 1e-9 {
        return Err(not_comparable(
            &v.name,
            format!(
                "runs at {} Hz, '{}' at {} Hz; variants must share a rate to see the same frames",
                v.graph.rate_hz, first.name, first.graph.rate_hz
            ),
        ));
    }
    if v.graph.mode != first.graph.mode {
        return Err(not_comparable(
            &v.name,
            format!("its mode differs from '{}' (offline vs live)", first.name),
        ));
    }
    Ok(())
}

/// The sensor set of the combined graph: what the shared source delivers, every variant's sites.
/// The variants' own set when they share one (the common case, written as they name it), the set
/// among theirs that holds all the others' sites, or their union (`a+b`).
pub(crate) fn union_of_sets(variants: &[Variant]) -> Result<String, CombineError> {
    let mut names: Vec<&str> = Vec::new();
    let mut sets = Vec::new();
    for v in variants {
        for name in std::iter::once(v.graph.sensors.as_str())
            .chain(v.graph.stages.values().filter_map(|n| n.sensors.as_deref()))
        {
            if names.contains(&name) {
                continue;
            }
            let set = imuflow_body::SensorSet::resolve(name)
                .map_err(|e| not_comparable(&v.name, format!("its `sensors`: {e}")))?;
            names.push(name);
            sets.push(set);
        }
    }
    let Some((first, others)) = sets.split_first() else {
        return Err(CombineError::TooFew(variants.len()));
    };
    let union = imuflow_body::SensorSet::union(first, others);
    let holding_all = names
        .iter()
        .zip(&sets)
        .find(|(_, set)| set.mask() == union.mask())
        .map(|(name, _)| (*name).to_owned());
    Ok(holding_all.unwrap_or_else(|| names.join("+")))
}

/// The variant's motion estimate: what its sinks read as `motion`, else the single `motion`
/// output of an optimizer stage.
/// The nearest BodyImuFrame output upstream of `stage` (breadth first over its inputs, feedback
/// edges included: they only lead back to stages already seen).
fn nearest_body_imu(v: &Variant, stage: &str) -> Option<(String, String)> {
    let mut seen = BTreeSet::from([stage.to_owned()]);
    let mut queue = std::collections::VecDeque::from([stage.to_owned()]);
    while let Some(id) = queue.pop_front() {
        let node = v.graph.stages.get(&id)?;
        for edge in node.inputs.values() {
            if edge.frame == FrameType::BodyImu {
                return Some((edge.from_stage.clone(), edge.from_port.clone()));
            }
            if seen.insert(edge.from_stage.clone()) {
                queue.push_back(edge.from_stage.clone());
            }
        }
    }
    None
}

fn motion_output(v: &Variant) -> Result<(String, String), CombineError> {
    let read_by_sinks: BTreeSet<(String, String)> = v
        .graph
        .stages
        .values()
        .filter(|n| is_replaced_sink(n))
        .filter_map(|n| n.inputs.get("motion"))
        .filter(|e| e.frame == FrameType::Motion)
        .map(|e| (e.from_stage.clone(), e.from_port.clone()))
        .collect();
    if read_by_sinks.len() == 1 {
        return Ok(read_by_sinks.into_iter().next().expect("one"));
    }
    let optimizers: Vec<(String, String)> = v
        .graph
        .stages
        .values()
        .filter(|n| {
            n.runner
                == Runner::Builtin {
                    kind: "optimizer".into(),
                }
        })
        .map(|n| (n.id.clone(), "motion".to_owned()))
        .collect();
    match optimizers.as_slice() {
        [one] => Ok(one.clone()),
        _ => Err(not_comparable(
            &v.name,
            "has no single motion output to compare: wire it to a recorder or rerun-logger input named `motion` (or use one optimizer stage)",
        )),
    }
}

/// Same stage in two variants: same runner, parameters, policy and wiring (the variants'
/// sources count as the same stage).
fn same_stage(a: &StageNode, b: &StageNode, b_source: &str, source: &str) -> bool {
    let map = |from: &str| {
        if from == b_source {
            source.to_owned()
        } else {
            from.to_owned()
        }
    };
    a.runner == b.runner
        && a.params == b.params
        && a.on_failure == b.on_failure
        && a.stall_timeout_s == b.stall_timeout_s
        && a.nice == b.nice
        && a.outputs == b.outputs
        && a.inputs.len() == b.inputs.len()
        && a.inputs.iter().all(|(name, ea)| {
            b.inputs.get(name).is_some_and(|eb| {
                ea.from_port == eb.from_port
                    && ea.feedback == eb.feedback
                    && ea.from_stage == map(&eb.from_stage)
            })
        })
}

/// Writes one `[stages.<id>]` table with inline `inputs` and `params`.
fn write_stage(
    text: &mut String,
    id: &str,
    node: &StageNode,
    rename: &dyn Fn(&str) -> String,
    on_failure: Option<OnFailure>,
    sensors: Option<&str>,
) {
    let _ = writeln!(text, "\n[stages.{id}]");
    match &node.runner {
        Runner::Builtin { kind } => {
            let _ = writeln!(text, "kind = {}", quote(kind));
        }
        Runner::Exec { path, args } => {
            let _ = writeln!(text, "exec = {}", quote(&path.display().to_string()));
            if !args.is_empty() {
                let args = args.iter().map(|a| quote(a)).collect::<Vec<_>>().join(", ");
                let _ = writeln!(text, "args = [{args}]");
            }
            let outputs = node
                .outputs
                .iter()
                .map(|(port, frame)| format!("{port} = {}", quote(frame.name())))
                .collect::<Vec<_>>()
                .join(", ");
            let _ = writeln!(text, "outputs = {{ {outputs} }}");
        }
    }
    if !node.inputs.is_empty() {
        let mut parts: Vec<String> = node
            .inputs
            .iter()
            .map(|(name, e)| {
                let from = format!("{}.{}", rename(&e.from_stage), e.from_port);
                format!("{name} = {}", quote(&from))
            })
            .collect();
        let feedback: BTreeMap<&String, ()> = node
            .inputs
            .iter()
            .filter(|(_, e)| e.feedback)
            .map(|(n, _)| (n, ()))
            .collect();
        if !feedback.is_empty() {
            let names = feedback
                .keys()
                .map(|n| quote(n))
                .collect::<Vec<_>>()
                .join(", ");
            parts.push(format!("feedback = [{names}]"));
        }
        let _ = writeln!(text, "inputs = {{ {} }}", parts.join(", "));
    }
    if !node.params.is_empty() {
        let params = node
            .params
            .iter()
            .map(|(k, v)| format!("{k} = {v}"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(text, "params = {{ {params} }}");
    }
    if let Some(stall) = node.stall_timeout_s {
        let _ = writeln!(text, "stall_timeout_s = {}", float(stall));
    }
    if !node.nice.is_default() {
        let _ = writeln!(text, "nice = {}", node.nice);
    }
    if let Some(set) = sensors {
        let _ = writeln!(text, "sensors = {}", quote(set));
    }
    if on_failure.unwrap_or(node.on_failure) == OnFailure::StopBranch {
        let _ = writeln!(text, "on_failure = \"stop-branch\"");
    }
}

/// A TOML basic string.
fn quote(s: &str) -> String {
    toml::Value::String(s.to_owned()).to_string()
}

/// A TOML float (always with a decimal point).
fn float(x: f64) -> String {
    toml::Value::Float(x).to_string()
}
