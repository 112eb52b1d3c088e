//! Turns a parsed [`GraphFile`] into a validated [`Graph`], in layers: each stage on its own
//! (id, kind, params, input syntax), then the wiring (edges, frame types, cycles), then the file
//! system. Every problem is collected before reporting, so one run of `imuflow graph check` lists
//! them all.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use crate::frames::FrameType;
use crate::graph::{
    Graph, InputEdge, Mode, Nice, OnFailure, Problem, Reader, RestartPolicy, Runner, StageNode,
};
use crate::schema::{GraphFile, StageEntry};
use crate::spec::{InputsSpec, Registry, Role, StageSpec};

/// The reserved key inside `inputs` that lists feedback inputs.
pub const FEEDBACK_KEY: &str = "feedback";

/// Default nominal rate: both papers run at 60 Hz (PIP §4, GlobalPose §4).
const DEFAULT_RATE_HZ: f64 = 60.0;
const DEFAULT_READY_TIMEOUT_S: f64 = 30.0;

struct Problems(Vec<Problem>);

impl Problems {
    fn file(&mut self, key: &str, message: impl Into<String>) {
        self.0.push(Problem {
            stage: None,
            key: Some(key.to_owned()),
            message: message.into(),
        });
    }
    fn stage(&mut self, stage: &str, key: Option<&str>, message: impl Into<String>) {
        self.0.push(Problem {
            stage: Some(stage.to_owned()),
            key: key.map(str::to_owned),
            message: message.into(),
        });
    }
}

/// The largest `nice` (Unix niceness: 19 is the lowest priority).
const MAX_NICE: u8 = 19;

/// A duration key (`ready_timeout_s`, `stall_timeout_s`) of the file (`stage` None) or of a
/// stage: its value, or `None` when absent or invalid (the problem recorded).
fn seconds(
    problems: &mut Problems,
    stage: Option<&str>,
    key: &str,
    value: &Option<toml::Value>,
) -> Option<f64> {
    let v = value.as_ref()?;
    let s = positive_number(v);
    if s.is_none() {
        let message = format!("must be a positive number of seconds (got {v})");
        match stage {
            Some(id) => problems.stage(id, Some(key), message),
            None => problems.file(key, message),
        }
    }
    s
}

/// A stage's `restart` table: `{ max = N, within_s = S, backoff_ms = M }`, each key optional
/// ([`RestartPolicy::default`] fills the rest); `None` when invalid (the problem recorded).
fn restart_policy(
    id: &str,
    role: Role,
    value: &toml::Value,
    problems: &mut Problems,
) -> Option<RestartPolicy> {
    let mut bad = |message: String| {
        problems.stage(id, Some("restart"), message);
        None
    };
    if role == Role::Source {
        return bad(
            "a source cannot restart (it would start its stream again from the beginning)".into(),
        );
    }
    let Some(table) = value.as_table() else {
        return bad(format!(
            "must be a table like {{ max = 3, within_s = 60, backoff_ms = 200 }} (got {value})"
        ));
    };
    let mut policy = RestartPolicy::default();
    for (key, v) in table {
        let in_range = match (key.as_str(), v) {
            ("max", toml::Value::Integer(n)) if (1..=1000).contains(n) => {
                policy.max = *n as u32;
                true
            }
            ("within_s", _) => positive_number(v).map(|s| policy.within_s = s).is_some(),
            ("backoff_ms", toml::Value::Integer(n)) if (0..=600_000).contains(n) => {
                policy.backoff_ms = *n as u64;
                true
            }
            ("max" | "backoff_ms", _) => false,
            _ => {
                return bad(format!(
                    "unknown key '{key}' (keys: max, within_s, backoff_ms)"
                ));
            }
        };
        if !in_range {
            return bad(format!(
                "{key} = {v} is out of range (max: 1 to 1000 restarts, within_s: positive seconds, backoff_ms: 0 to 600000)"
            ));
        }
    }
    Some(policy)
}

/// A stage after the per-stage layer: its declared ports and parsed (not yet resolved) inputs.
struct Declared<'a> {
    id: &'a str,
    runner: Runner,
    role: Role,
    spec: Option<&'a StageSpec>,
    outputs: BTreeMap<String, FrameType>,
    /// input name -> (stage, port)
    inputs: BTreeMap<String, (String, String)>,
    feedback: BTreeSet<String>,
    params: toml::Table,
    on_failure: OnFailure,
    stall_timeout_s: Option<f64>,
    restart: Option<RestartPolicy>,
    nice: Nice,
    sensors: Option<String>,
}

pub fn validate(path: &Path, file: GraphFile, registry: &Registry) -> Result<Graph, Vec<Problem>> {
    let mut problems = Problems(Vec::new());

    let rate_hz = match &file.rate_hz {
        None => DEFAULT_RATE_HZ,
        Some(v) => positive_number(v).unwrap_or_else(|| {
            problems.file(
                "rate_hz",
                format!("must be a positive finite number of Hz (got {v})"),
            );
            DEFAULT_RATE_HZ
        }),
    };
    let ready_timeout_s = seconds(
        &mut problems,
        None,
        "ready_timeout_s",
        &file.ready_timeout_s,
    )
    .unwrap_or(DEFAULT_READY_TIMEOUT_S);
    let mode = match file.mode.as_deref() {
        None | Some("offline") => Mode::Offline,
        Some("live") => Mode::Live,
        Some(other) => {
            problems.file(
                "mode",
                format!("must be \"offline\" or \"live\" (got \"{other}\")"),
            );
            Mode::Offline
        }
    };
    let default_stall = match mode {
        Mode::Offline => crate::graph::DEFAULT_OFFLINE_STALL_TIMEOUT_S,
        Mode::Live => crate::graph::DEFAULT_LIVE_STALL_TIMEOUT_S,
    };
    let stall_timeout_s = seconds(
        &mut problems,
        None,
        "stall_timeout_s",
        &file.stall_timeout_s,
    )
    .unwrap_or(default_stall);
    let sensors = match file.sensors.as_deref().map(str::trim) {
        None => crate::graph::DEFAULT_SENSORS.to_owned(),
        Some("") => {
            problems.file(
                "sensors",
                "must name a sensor set (six, lower-body, full-suit) or a set file",
            );
            crate::graph::DEFAULT_SENSORS.to_owned()
        }
        Some(name) => name.to_owned(),
    };
    if file.name.trim().is_empty() {
        problems.file("name", "must not be empty");
    }
    if file.stages.is_empty() {
        problems.file("stages", "the graph has no stages");
    }

    // Layer 1: each stage on its own.
    let declared: Vec<Declared> = file
        .stages
        .iter()
        .filter_map(|(id, entry)| declare(id, entry, registry, &mut problems))
        .collect();

    // Layer 2: wiring.
    let by_id: BTreeMap<&str, &Declared> = declared.iter().map(|d| (d.id, d)).collect();
    let mut stages: BTreeMap<String, StageNode> = BTreeMap::new();
    for d in &declared {
        let mut inputs = BTreeMap::new();
        for (input, (from_stage, from_port)) in &d.inputs {
            let key = format!("inputs.{input}");
            let Some(upstream) = by_id.get(from_stage.as_str()) else {
                let known = by_id.keys().copied().collect::<Vec<_>>().join(", ");
                problems.stage(
                    d.id,
                    Some(&key),
                    format!("reads '{from_stage}.{from_port}' but there is no stage '{from_stage}' (stages: {known})"),
                );
                continue;
            };
            let Some(&frame) = upstream.outputs.get(from_port) else {
                let known = list_or_none(upstream.outputs.keys().map(String::as_str));
                problems.stage(
                    d.id,
                    Some(&key),
                    format!(
                        "reads '{from_stage}.{from_port}' but stage '{from_stage}' has no output '{from_port}' (outputs: {known})"
                    ),
                );
                continue;
            };
            if let Some(spec) = d.spec
                && let InputsSpec::Fixed(ports) = spec.inputs
                && let Some(port) = ports.iter().find(|p| p.name == input)
                && port.frame != frame
            {
                problems.stage(
                    d.id,
                    Some(&key),
                    format!(
                        "frame type mismatch: input '{input}' takes {} but '{from_stage}.{from_port}' carries {frame}",
                        port.frame
                    ),
                );
                continue;
            }
            inputs.insert(
                input.clone(),
                InputEdge {
                    from_stage: from_stage.clone(),
                    from_port: from_port.clone(),
                    frame,
                    feedback: d.feedback.contains(input),
                },
            );
        }
        stages.insert(
            d.id.to_owned(),
            StageNode {
                id: d.id.to_owned(),
                runner: d.runner.clone(),
                role: d.role,
                inputs,
                outputs: d.outputs.clone(),
                readers: BTreeMap::new(),
                params: d.params.clone(),
                on_failure: d.on_failure,
                stall_timeout_s: d.stall_timeout_s,
                restart: d.restart,
                nice: d.nice,
                sensors: d.sensors.clone(),
            },
        );
    }

    // Readers of each output (fan-out).
    let edges: Vec<(String, String, String, String)> = stages
        .values()
        .flat_map(|n| {
            n.inputs.iter().map(|(input, e)| {
                (
                    e.from_stage.clone(),
                    e.from_port.clone(),
                    n.id.clone(),
                    input.clone(),
                )
            })
        })
        .collect();
    for (from_stage, from_port, stage, input) in edges {
        if let Some(node) = stages.get_mut(&from_stage) {
            node.readers
                .entry(from_port)
                .or_default()
                .push(Reader { stage, input });
        }
    }

    if let Some(cycle) = find_cycle(&stages) {
        problems.0.push(Problem {
            stage: None,
            key: Some("inputs".into()),
            message: format!(
                "cycle {} is not marked as feedback: add `feedback = [\"<input>\"]` to the inputs of the stage that should read the previous frame",
                cycle.join(" -> ")
            ),
        });
    }

    // Layer 3: findings that need the whole graph or the file system.
    let mut warnings = Vec::new();
    for node in stages.values() {
        let read = node.readers.values().any(|r| !r.is_empty());
        if node.role != Role::Sink && !node.outputs.is_empty() && !read {
            warnings.push(format!(
                "stage '{}': none of its outputs ({}) is read by any stage",
                node.id,
                node.outputs.keys().cloned().collect::<Vec<_>>().join(", ")
            ));
        }
        if node.role != Role::Source
            && !node.inputs.is_empty()
            && node.inputs.values().all(|e| e.feedback)
        {
            problems.stage(
                &node.id,
                Some("inputs"),
                "every input is feedback, so nothing would ever drive this stage; it needs at least one input that is not feedback",
            );
        }
        if let Runner::Exec { path: exe, .. } = &node.runner
            && !exe.is_file()
        {
            let why = if is_bare_name(exe) {
                format!(
                    "executable '{}' is not on PATH (give a path, e.g. a virtual environment's bin/python)",
                    exe.display()
                )
            } else {
                format!("executable '{}' does not exist", exe.display())
            };
            problems.stage(&node.id, Some("exec"), why);
        }
    }
    if !stages.is_empty() && !stages.values().any(|n| n.role == Role::Source) {
        problems.file(
            "stages",
            "the graph has no source stage, so nothing would ever flow",
        );
    }

    if problems.0.is_empty() {
        let mut graph = Graph {
            name: file.name,
            file: path.to_owned(),
            rate_hz,
            mode,
            sensors,
            ready_timeout_s,
            stall_timeout_s,
            stages,
            warnings,
        };
        let isolating: Vec<String> = graph
            .stages
            .values()
            .filter(|n| n.on_failure == OnFailure::StopBranch)
            .map(|n| n.id.clone())
            .collect();
        for id in isolating {
            if graph.branch(&id).len() == graph.stages.len() {
                graph.warnings.push(format!(
                    "stage '{id}': on_failure = \"stop-branch\" isolates nothing, every stage of the graph is in its branch"
                ));
            }
        }
        Ok(graph)
    } else {
        Err(problems.0)
    }
}

/// `a, b, c`, or `none` for an empty list (for "known: ..." hints in messages).
fn list_or_none<'a>(names: impl Iterator<Item = &'a str>) -> String {
    let names: Vec<&str> = names.collect();
    if names.is_empty() {
        "none".to_owned()
    } else {
        names.join(", ")
    }
}

fn positive_number(v: &toml::Value) -> Option<f64> {
    let x = match v {
        toml::Value::Float(x) => *x,
        toml::Value::Integer(i) => *i as f64,
        _ => return None,
    };
    (x.is_finite() && x > 0.0).then_some(x)
}

/// Stage ids and port names become parts of shared-memory service names: keep them simple.
fn check_identifier(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("must not be empty".into());
    }
    if let Some(bad) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        return Err(format!(
            "'{name}' contains '{bad}'; use letters, digits, '_' and '-' only"
        ));
    }
    if name.len() > 48 {
        return Err(format!("'{name}' is longer than 48 characters"));
    }
    Ok(())
}

fn declare<'a>(
    id: &'a str,
    entry: &StageEntry,
    registry: &'a Registry,
    problems: &mut Problems,
) -> Option<Declared<'a>> {
    if let Err(why) = check_identifier(id) {
        problems.stage(id, None, format!("invalid stage id: {why}"));
        return None;
    }
    let (runner, spec, role, outputs) = match (&entry.kind, &entry.exec) {
        (Some(_), Some(_)) => {
            problems.stage(
                id,
                Some("kind"),
                "set either `kind` (built-in) or `exec` (external), not both",
            );
            return None;
        }
        (None, None) => {
            problems.stage(
                id,
                Some("kind"),
                "missing: set `kind` to a built-in stage kind or `exec` to an executable",
            );
            return None;
        }
        (Some(kind), None) => {
            let Some(spec) = registry.get(kind) else {
                let known = registry
                    .kinds()
                    .map(|s| s.kind)
                    .collect::<Vec<_>>()
                    .join(", ");
                problems.stage(
                    id,
                    Some("kind"),
                    format!("unknown stage kind '{kind}' (known kinds: {known})"),
                );
                return None;
            };
            if !entry.args.is_empty() {
                problems.stage(id, Some("args"), "only `exec` stages take `args`");
            }
            if !entry.outputs.is_empty() {
                problems.stage(
                    id,
                    Some("outputs"),
                    format!("built-in kind '{kind}' declares its own outputs; remove `outputs`"),
                );
            }
            let outputs = spec
                .outputs
                .iter()
                .map(|p| (p.name.to_owned(), p.frame))
                .collect();
            (
                Runner::Builtin { kind: kind.clone() },
                Some(spec),
                spec.role,
                outputs,
            )
        }
        (None, Some(exec)) => {
            let mut outputs = BTreeMap::new();
            for (port, ty) in &entry.outputs {
                if let Err(why) = check_identifier(port) {
                    problems.stage(
                        id,
                        Some(&format!("outputs.{port}")),
                        format!("invalid port name: {why}"),
                    );
                    continue;
                }
                match FrameType::from_name(ty) {
                    Some(frame) => {
                        outputs.insert(port.clone(), frame);
                    }
                    None => {
                        let known = FrameType::ALL.map(|t| t.name()).join(", ");
                        problems.stage(
                            id,
                            Some(&format!("outputs.{port}")),
                            format!("unknown frame type '{ty}' (known: {known})"),
                        );
                    }
                }
            }
            let role = match (entry.inputs.is_empty(), outputs.is_empty()) {
                (true, _) => Role::Source,
                (false, true) => Role::Sink,
                (false, false) => Role::Transform,
            };
            let runner = Runner::Exec {
                path: resolve_exec(exec),
                args: entry.args.clone(),
            };
            (runner, None, role, outputs)
        }
    };

    let (inputs, feedback) = parse_inputs(id, &entry.inputs, problems);
    if let Some(spec) = spec {
        check_inputs_against_spec(id, spec, &inputs, problems);
        check_params(id, spec, &entry.params, problems);
    }
    for name in &feedback {
        if !inputs.contains_key(name) {
            problems.stage(
                id,
                Some("inputs.feedback"),
                format!("names '{name}', which is not an input of this stage"),
            );
        }
    }
    let on_failure = match entry.on_failure.as_deref() {
        None => OnFailure::default(),
        Some(name) => OnFailure::from_name(name).unwrap_or_else(|| {
            problems.stage(
                id,
                Some("on_failure"),
                format!(
                    "must be one of {} (got \"{name}\")",
                    OnFailure::NAMES.map(|n| format!("\"{n}\"")).join(", ")
                ),
            );
            OnFailure::default()
        }),
    };
    let stall_timeout_s = seconds(
        problems,
        Some(id),
        "stall_timeout_s",
        &entry.stall_timeout_s,
    );
    let restart = entry
        .restart
        .as_ref()
        .and_then(|v| restart_policy(id, role, v, problems));
    let nice = match &entry.nice {
        None => Nice::default(),
        Some(v) if v.as_str() == Some("idle") => Nice::Idle,
        Some(v) => match v.as_integer().and_then(|n| u8::try_from(n).ok()) {
            Some(n) if n <= MAX_NICE => Nice::Level(n),
            _ => {
                problems.stage(
                    id,
                    Some("nice"),
                    format!(
                        "must be an integer from 0 (the default) to {MAX_NICE}, or \"idle\" (got {v}): how much of a contended core the stage yields to the others; raising a priority (below 0) needs privileges imuflow does not ask for"
                    ),
                );
                Nice::default()
            }
        },
    };
    let sensors = match entry.sensors.as_deref().map(str::trim) {
        None => None,
        Some("") => {
            problems.stage(
                id,
                Some("sensors"),
                "must name a sensor set (six, lower-body, full-suit) or a set file; leave it out for the graph's",
            );
            None
        }
        Some(name) => Some(name.to_owned()),
    };
    Some(Declared {
        id,
        runner,
        role,
        spec,
        outputs,
        inputs,
        feedback,
        params: entry.params.clone(),
        on_failure,
        stall_timeout_s,
        restart,
        nice,
        sensors,
    })
}

type ParsedInputs = (BTreeMap<String, (String, String)>, BTreeSet<String>);

fn parse_inputs(id: &str, table: &toml::Table, problems: &mut Problems) -> ParsedInputs {
    let mut inputs = BTreeMap::new();
    let mut feedback = BTreeSet::new();
    for (name, value) in table {
        let key = format!("inputs.{name}");
        if name == FEEDBACK_KEY {
            match value.as_array() {
                Some(items) => {
                    for item in items {
                        match item.as_str() {
                            Some(s) => {
                                feedback.insert(s.to_owned());
                            }
                            None => problems.stage(
                                id,
                                Some(&key),
                                format!("must list input names as strings (got {item})"),
                            ),
                        }
                    }
                }
                None => problems.stage(
                    id,
                    Some(&key),
                    format!("must be an array of input names (got {value})"),
                ),
            }
            continue;
        }
        if let Err(why) = check_identifier(name) {
            problems.stage(id, Some(&key), format!("invalid input name: {why}"));
            continue;
        }
        let Some(text) = value.as_str() else {
            problems.stage(
                id,
                Some(&key),
                format!("must be \"stage.port\" (got {value})"),
            );
            continue;
        };
        match text.split_once('.') {
            Some((stage, port)) if !stage.is_empty() && !port.is_empty() && !port.contains('.') => {
                inputs.insert(name.clone(), (stage.to_owned(), port.to_owned()));
            }
            _ => problems.stage(
                id,
                Some(&key),
                format!("must be \"stage.port\" (got \"{text}\")"),
            ),
        }
    }
    (inputs, feedback)
}

fn check_inputs_against_spec(
    id: &str,
    spec: &StageSpec,
    inputs: &BTreeMap<String, (String, String)>,
    problems: &mut Problems,
) {
    match spec.inputs {
        InputsSpec::Any => {
            if spec.role == Role::Source && !inputs.is_empty() {
                problems.stage(
                    id,
                    Some("inputs"),
                    format!("kind '{}' is a source and takes no inputs", spec.kind),
                );
            }
        }
        InputsSpec::Fixed(ports) => {
            for name in inputs.keys() {
                if !ports.iter().any(|p| p.name == name) {
                    let known = list_or_none(ports.iter().map(|p| p.name));
                    problems.stage(
                        id,
                        Some(&format!("inputs.{name}")),
                        format!(
                            "kind '{}' has no input '{name}' (inputs: {known})",
                            spec.kind
                        ),
                    );
                }
            }
            for port in ports.iter().filter(|p| p.required) {
                if !inputs.contains_key(port.name) {
                    problems.stage(
                        id,
                        Some(&format!("inputs.{}", port.name)),
                        format!(
                            "required input '{}' ({}) is not connected",
                            port.name, port.frame
                        ),
                    );
                }
            }
        }
    }
}

fn check_params(id: &str, spec: &StageSpec, params: &toml::Table, problems: &mut Problems) {
    for (name, value) in params {
        let key = format!("params.{name}");
        match spec.param(name) {
            None => {
                let known = list_or_none(spec.params.iter().map(|p| p.name));
                problems.stage(
                    id,
                    Some(&key),
                    format!(
                        "unknown parameter for kind '{}' (parameters: {known})",
                        spec.kind
                    ),
                );
            }
            Some(p) => {
                if let Err(why) = p.ty.check(value) {
                    problems.stage(id, Some(&key), why);
                }
            }
        }
    }
    for p in spec.params.iter().filter(|p| p.required) {
        if !params.contains_key(p.name) {
            problems.stage(
                id,
                Some(&format!("params.{}", p.name)),
                format!(
                    "required parameter is missing ({}: {})",
                    p.ty.expected(),
                    p.doc
                ),
            );
        }
    }
}

/// A cycle of stages connected by non-feedback edges, as stage ids with the first repeated at the
/// end, if there is one.
fn find_cycle(stages: &BTreeMap<String, StageNode>) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Active,
        Done,
    }
    fn visit(
        id: &str,
        stages: &BTreeMap<String, StageNode>,
        marks: &mut BTreeMap<String, Mark>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        marks.insert(id.to_owned(), Mark::Active);
        path.push(id.to_owned());
        if let Some(node) = stages.get(id) {
            for edge in node.inputs.values().filter(|e| !e.feedback) {
                match marks.get(&edge.from_stage).copied().unwrap_or(Mark::Done) {
                    Mark::Active => {
                        let start = path.iter().position(|p| *p == edge.from_stage).unwrap_or(0);
                        // Report in flow direction (upstream first), from the smallest id.
                        let mut cycle: Vec<String> = path[start..].iter().rev().cloned().collect();
                        let first = (0..cycle.len()).min_by_key(|&i| &cycle[i]).unwrap_or(0);
                        cycle.rotate_left(first);
                        cycle.push(cycle[0].clone());
                        return Some(cycle);
                    }
                    Mark::New => {
                        if let Some(c) = visit(&edge.from_stage, stages, marks, path) {
                            return Some(c);
                        }
                    }
                    Mark::Done => {}
                }
            }
        }
        path.pop();
        marks.insert(id.to_owned(), Mark::Done);
        None
    }
    let mut marks: BTreeMap<String, Mark> = stages.keys().map(|k| (k.clone(), Mark::New)).collect();
    for id in stages.keys() {
        if marks.get(id) == Some(&Mark::New)
            && let Some(c) = visit(id, stages, &mut marks, &mut Vec::new())
        {
            return Some(c);
        }
    }
    None
}

/// Whether `exec` is a bare program name (`python3`), which is looked up on PATH as a shell does.
fn is_bare_name(exec: &Path) -> bool {
    !exec.as_os_str().is_empty() && !exec.as_os_str().to_string_lossy().contains('/')
}

/// The program an `exec` stage runs: a bare name (`exec = "python3"`) is found on PATH, so what
/// runs is what was checked; anything with a `/` is a path, relative to the working directory.
fn resolve_exec(exec: &str) -> PathBuf {
    let path = PathBuf::from(exec);
    if !is_bare_name(&path) {
        return path;
    }
    std::env::var_os("PATH")
        .iter()
        .flat_map(std::env::split_paths)
        .map(|dir| dir.join(exec))
        .find(|candidate| is_executable(candidate))
        .unwrap_or(path)
}

fn is_executable(path: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    path.metadata()
        .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
}
