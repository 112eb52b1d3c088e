//! The command line's files as variants: a graph file is one variant (no overrides), an ablation
//! file (configs/ab/) its `[[variant]]`s.

use std::path::{Path, PathBuf};

use imuflow_graph::Graph;
use imuflow_graph::spec::Registry;

use crate::combine::{self, AblationVariant, Variant};

/// The variants named by `files`, and the single ablation file's name if that is all there is.
pub fn variant_sources(
    files: &[PathBuf],
) -> anyhow::Result<(Vec<AblationVariant>, Option<String>)> {
    let mut sources = Vec::new();
    let mut ablation_names = Vec::new();
    for path in files {
        match combine::read_ablation(path)? {
            Some(ablation) => {
                ablation_names.push(ablation.name);
                sources.extend(ablation.variants);
            }
            None => sources.push(AblationVariant {
                name: variant_name(path),
                graph: path.clone(),
                set: Vec::new(),
            }),
        }
    }
    if sources.len() < 2 {
        anyhow::bail!(
            "compare needs two or more variants: graph files, or an ablation file (configs/ab/) that lists them"
        );
    }
    let name = (files.len() == 1).then(|| ablation_names.pop()).flatten();
    Ok((sources, name))
}

/// Each source's graph loaded and validated (with its overrides), named uniquely.
pub fn load(
    sources: &[AblationVariant],
    registry: &Registry,
) -> Result<Vec<Variant>, imuflow_graph::GraphLoadError> {
    let mut variants = Vec::new();
    for source in sources {
        let graph = Graph::load(&source.graph, &source.set, registry)?;
        let name = unique_name(&source.name, &variants);
        variants.push(Variant { name, graph });
    }
    Ok(variants)
}

/// A variant's name from its file: the stem, reduced to the characters stage ids allow.
fn variant_name(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '-'
            }
        })
        .collect();
    if name.is_empty() {
        "variant".into()
    } else {
        name
    }
}

/// `name`, or `name-2`, `name-3`, ... when an earlier variant has it (the same file twice).
fn unique_name(name: &str, earlier: &[Variant]) -> String {
    let taken = |n: &str| earlier.iter().any(|v| v.name == n);
    if !taken(name) {
        return name.to_owned();
    }
    (2..)
        .map(|i| format!("{name}-{i}"))
        .find(|n| !taken(n))
        .expect("some suffix is free")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_come_from_file_stems_and_repeat_with_a_suffix() {
        assert_eq!(variant_name(Path::new("configs/pip.toml")), "pip");
        assert_eq!(variant_name(Path::new("my graph.v2.toml")), "my-graph-v2");
        assert_eq!(variant_name(Path::new(".toml")), "-toml");
        assert_eq!(unique_name("pip", &[]), "pip");
    }
}
