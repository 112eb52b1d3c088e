//! `--without STAGE`: a graph file with stages taken out, and every input that read them.
//!
//! For a run or a benchmark without a branch (the rapier judge, the viewer) without editing the
//! file. The result is validated like any graph: a stage left without a required input is named
//! there. Hand-written over the `toml` tables rather than a `--set`: an override can add or change
//! a key but not remove one.

use std::path::Path;

use imuflow_graph::{Graph, GraphLoadError, Registry};

/// [`Graph::load`] of `file` without the stages `removed` (none: the file as it is).
pub fn load(
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

#[cfg(test)]
mod tests {
    use super::*;

    const GRAPH: &str = r#"
name = "g"
[stages.source]
kind = "test-source"
[stages.opt]
kind = "x"
inputs = { kin = "source.imu", state = "val.sim", feedback = ["state"] }
[stages.val]
kind = "validation"
inputs = { motion = "opt.motion" }
[stages.viz]
kind = "rerun-logger"
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
}
