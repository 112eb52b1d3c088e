//! Graph transforms a command line applies to a graph file, beside `--set` (overrides.rs):
//!
//! - `--without STAGE` ([`load_without`]): the file with stages taken out, and every input that read
//!   them. For a run or a benchmark without a branch (the rapier judge, the viewer) without editing
//!   the file. The result is validated like any graph: a stage left without a required input is
//!   named there. Written over the `toml` tables rather than as an override: an override can add or
//!   change a key but not remove one.
//! - `--connect URL` ([`connect_viewers`]): every stage that can stream to a viewer (its kind has a
//!   `connect` parameter) streams to URL instead of writing its file.

use std::path::Path;

use crate::graph::Runner;
use crate::{Graph, GraphLoadError, Registry};

/// The parameter by which a stage kind streams to a running viewer instead of a file (`path`).
pub const CONNECT_PARAM: &str = "connect";

/// [`Graph::load`] of `file` without the stages `removed` (none: the file as it is).
pub fn load_without(
    file: &Path,
    sets: &[String],
    removed: &[String],
    registry: &Registry,
) -> Result<Graph, GraphLoadError> {
    if removed.is_empty() {
        return Graph::load(file, sets, registry);
    }
    let text = std::fs::read_to_string(file).map_err(|source| GraphLoadError::Io {
        path: file.to_owned(),
        source,
    })?;
    let text = graph_text_without(&text, removed).map_err(|message| GraphLoadError::Parse {
        path: file.to_owned(),
        message,
    })?;
    Graph::from_str_with(file, &text, sets, registry)
}

/// A graph file's `text` without the stages `removed` and the inputs that read them.
fn graph_text_without(text: &str, removed: &[String]) -> Result<String, String> {
    let mut table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| e.to_string().trim_end().to_owned())?;
    let Some(toml::Value::Table(stages)) = table.get_mut("stages") else {
        return Err("no [stages] table".into());
    };
    for stage in removed {
        if stages.remove(stage).is_none() {
            let known: Vec<&str> = stages.keys().map(String::as_str).collect();
            return Err(format!(
                "--without {stage}: no such stage (stages: {})",
                known.join(", ")
            ));
        }
    }
    for (_, node) in stages.iter_mut() {
        let Some(toml::Value::Table(inputs)) = node.get_mut("inputs") else {
            continue;
        };
        let gone: Vec<String> = inputs
            .iter()
            .filter(|(_, from)| {
                from.as_str()
                    .and_then(|from| from.split_once('.'))
                    .is_some_and(|(stage, _)| removed.iter().any(|r| r == stage))
            })
            .map(|(name, _)| name.clone())
            .collect();
        for name in &gone {
            inputs.remove(name);
        }
        // A feedback input that read a removed stage is gone from the feedback list too.
        if let Some(toml::Value::Array(feedback)) = inputs.get_mut("feedback") {
            feedback.retain(|name| name.as_str().is_none_or(|n| !gone.iter().any(|g| g == n)));
        }
    }
    toml::to_string(&table).map_err(|e| e.to_string())
}

/// Points every stage whose kind has a [`CONNECT_PARAM`] at the viewer at `url` instead of its
/// file; returns how many.
pub fn connect_viewers(graph: &mut Graph, url: &str, registry: &Registry) -> usize {
    let mut count = 0;
    for node in graph.stages.values_mut() {
        let Runner::Builtin { kind } = &node.runner else {
            continue;
        };
        if registry
            .get(kind)
            .and_then(|spec| spec.param(CONNECT_PARAM))
            .is_none()
        {
            continue;
        }
        node.params.remove("path");
        node.params
            .insert(CONNECT_PARAM.into(), toml::Value::String(url.to_owned()));
        count += 1;
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    const GRAPH: &str = r#"
name = "g"
[stages.source]
kind = "src"
[stages.opt]
kind = "x"
inputs = { kin = "source.imu", state = "val.sim", feedback = ["state"] }
[stages.val]
kind = "judge"
inputs = { motion = "opt.motion" }
[stages.viz]
kind = "viewer"
inputs = { motion = "opt.motion", sim = "val.sim", scores = "val.validation" }
"#;

    #[test]
    fn removes_the_stage_and_every_input_that_read_it() {
        let text = graph_text_without(GRAPH, &["val".into()]).expect("ok");
        let table: toml::Table = text.parse().expect("valid toml");
        let stages = table["stages"].as_table().expect("stages");
        assert!(!stages.contains_key("val"));
        let viz = stages["viz"]["inputs"].as_table().expect("inputs");
        assert_eq!(viz.keys().collect::<Vec<_>>(), ["motion"]);
        let opt = stages["opt"]["inputs"].as_table().expect("inputs");
        assert_eq!(opt["kin"].as_str(), Some("source.imu"));
        assert!(!opt.contains_key("state"));
        assert_eq!(opt["feedback"].as_array().map(Vec::len), Some(0));
    }

    #[test]
    fn an_unknown_stage_is_named_with_the_stages_there_are() {
        let err = graph_text_without(GRAPH, &["judge".into()]).expect_err("no such stage");
        assert!(err.contains("--without judge: no such stage"), "{err}");
        assert!(err.contains("opt, source, val, viz"), "{err}");
    }

    /// A source, a sink kind that can stream to a viewer, and one that only writes files.
    fn registry() -> Registry {
        use crate::FrameType;
        use crate::spec::{InputsSpec, ParamSpec, ParamType, PortSpec, Role, StageSpec};
        const PATH: ParamSpec = ParamSpec {
            name: "path",
            ty: ParamType::Path,
            required: false,
            default: "",
            doc: "",
        };
        const CONNECT: ParamSpec = ParamSpec {
            name: CONNECT_PARAM,
            ty: ParamType::String,
            required: false,
            default: "",
            doc: "",
        };
        let sink = |kind, params| StageSpec {
            kind,
            role: Role::Sink,
            summary: "",
            inputs: InputsSpec::Any,
            outputs: &[],
            params,
        };
        Registry::new([
            StageSpec {
                kind: "src",
                role: Role::Source,
                summary: "",
                inputs: InputsSpec::Fixed(&[]),
                outputs: &[PortSpec {
                    name: "imu",
                    frame: FrameType::Imu,
                    required: false,
                    doc: "",
                }],
                params: &[],
            },
            sink("viewer", &[PATH, CONNECT]),
            sink("file", &[PATH]),
        ])
    }

    #[test]
    fn connect_points_only_the_kinds_that_can_stream_at_the_viewer() {
        let text = r#"
name = "g"
[stages.source]
kind = "src"
[stages.a]
kind = "viewer"
inputs = { imu = "source.imu" }
params = { path = "a.rrd" }
[stages.b]
kind = "viewer"
inputs = { imu = "source.imu" }
[stages.c]
kind = "file"
inputs = { imu = "source.imu" }
params = { path = "c.out" }
"#;
        let registry = registry();
        let mut graph =
            Graph::from_str_with(Path::new("g.toml"), text, &[], &registry).expect("valid graph");
        assert_eq!(
            connect_viewers(&mut graph, "rerun+http://h:1/proxy", &registry),
            2
        );
        for id in ["a", "b"] {
            let params = &graph.stages[id].params;
            assert!(!params.contains_key("path"), "{id}: {params:?}");
            assert_eq!(
                params[CONNECT_PARAM].as_str(),
                Some("rerun+http://h:1/proxy")
            );
        }
        let c = &graph.stages["c"].params;
        assert_eq!(c["path"].as_str(), Some("c.out"));
        assert!(!c.contains_key(CONNECT_PARAM));
    }
}
