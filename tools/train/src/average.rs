//! `imuflow average-weights`: the element-wise mean of weight files that share one method and one
//! architecture, fine-tuned from the same start. Averaging fine-tuned weights ("model soups",
//! Wortsman et al., ICML 2022), and the start with its fine-tunes (WiSE-FT, Wortsman et al.,
//! CVPR 2022), keeps what the start knew while adding what the fine-tunes learned: models/README.md
//! says which shipped file is such an average and how it was measured.
//!
//! Averaging only makes sense for weights in one basin (one start, fine-tuned): the command cannot
//! check that, so the provenance names every ingredient with its own provenance and hash.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use candle_core::{Device, Tensor};
use sha2::{Digest, Sha256};

use imuflow_kinematics::method::Method;
use imuflow_kinematics::weights::{self, Weights, WeightsMetadata};

/// One ingredient: its metadata and its tensors (name → shape, values).
struct Ingredient {
    path: PathBuf,
    metadata: WeightsMetadata,
    tensors: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    sha256: String,
}

/// Average `inputs` (at least two) into `out`. Every input must be an imuflow weight file of one
/// method with the same tensors (names and shapes), normalization and licence; the first input
/// fixes what the others must match, and a mismatch names the file and the tensor or field.
pub fn average_weights(inputs: &[PathBuf], out: &Path, command: &str) -> anyhow::Result<()> {
    if inputs.len() < 2 {
        bail!(
            "averaging needs at least two weight files, got {}",
            inputs.len()
        );
    }
    let ingredients: Vec<Ingredient> = inputs
        .iter()
        .map(|p| read_ingredient(p))
        .collect::<anyhow::Result<_>>()?;
    let first = &ingredients[0];
    for other in &ingredients[1..] {
        check_same_layout(first, other)?;
    }

    // Mean in f64, one tensor at a time, in the first file's order of names.
    let n = ingredients.len() as f64;
    let mut tensors = Vec::with_capacity(first.tensors.len());
    for (name, (shape, values)) in &first.tensors {
        let mut sum: Vec<f64> = values.iter().map(|&v| f64::from(v)).collect();
        for other in &ingredients[1..] {
            for (s, &v) in sum.iter_mut().zip(&other.tensors[name].1) {
                *s += f64::from(v);
            }
        }
        // Finite inputs (checked on reading) have a finite mean within f32's range.
        let mean: Vec<f32> = sum.iter().map(|s| (s / n) as f32).collect();
        tensors.push((
            name.clone(),
            Tensor::from_vec(mean, shape.as_slice(), &Device::Cpu)?,
        ));
    }

    let metadata = WeightsMetadata {
        format: weights::FORMAT.to_owned(),
        method: first.metadata.method,
        nets: first.metadata.nets.clone(),
        normalization: first.metadata.normalization.clone(),
        provenance: serde_json::json!({
            "averaged": "element-wise mean with equal weights of the ingredients' tensors (model soups, Wortsman et al. 2022)",
            "command": command,
            "ingredients": ingredients.iter().map(|i| serde_json::json!({
                "file": i.path.display().to_string(),
                "sha256": i.sha256,
                "provenance": i.metadata.provenance,
            })).collect::<Vec<_>>(),
        }),
        licence: first.metadata.licence.clone(),
        sensors: first.metadata.sensors.clone(),
    };
    weights::save(out, &tensors, &metadata)
        .with_context(|| format!("writing {}", out.display()))?;
    // What a user runs must load: the stage's own reader checks every net.
    Weights::load(out, first.metadata.method)
        .with_context(|| format!("reading back {}", out.display()))?;
    Ok(())
}

fn read_ingredient(path: &Path) -> anyhow::Result<Ingredient> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    // The stage's reader checks what a user would load: the metadata, every net of the method
    // present with the right shapes, nothing foreign.
    let metadata = weights::read_metadata(&bytes)
        .map_err(|message| anyhow::anyhow!("{}: {message}", path.display()))?
        .with_context(|| {
            format!(
                "{}: no imuflow metadata (not a weight file of `imuflow train` or `import-checkpoint`)",
                path.display()
            )
        })?;
    Weights::from_bytes(&bytes, path, metadata.method)
        .with_context(|| format!("reading {}", path.display()))?;
    let st = safetensors::SafeTensors::deserialize(&bytes)
        .with_context(|| format!("{}: not a safetensors file", path.display()))?;
    let mut tensors = BTreeMap::new();
    for (name, view) in st.tensors() {
        let values = crate::data::f32_values(&name, &view)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            bail!(
                "{}: tensor {name} is not finite at element {i} ({})",
                path.display(),
                values[i]
            );
        }
        tensors.insert(name, (view.shape().to_vec(), values));
    }
    Ok(Ingredient {
        path: path.to_owned(),
        metadata,
        tensors,
        sha256: format!("{:x}", Sha256::digest(&bytes)),
    })
}

/// `other` has `first`'s method, tensors (names and shapes), normalization and licence.
fn check_same_layout(first: &Ingredient, other: &Ingredient) -> anyhow::Result<()> {
    let (a, b) = (first.path.display(), other.path.display());
    let method = |m: Method| m.name();
    if first.metadata.method != other.metadata.method {
        bail!(
            "{b} holds {} networks, {a} {}: only one method's weights average",
            method(other.metadata.method),
            method(first.metadata.method)
        );
    }
    for (name, (shape, _)) in &first.tensors {
        match other.tensors.get(name) {
            None => bail!("{b} has no tensor {name} ({a} has)"),
            Some((s, _)) if s != shape => {
                bail!("tensor {name}: {b} has shape {s:?}, {a} {shape:?}")
            }
            Some(_) => {}
        }
    }
    if let Some(extra) = other
        .tensors
        .keys()
        .find(|k| !first.tensors.contains_key(*k))
    {
        bail!("{b} has a tensor {extra} that {a} lacks");
    }
    if first.metadata.sensors != other.metadata.sensors {
        bail!(
            "{b} was trained for the sensors {:?}, {a} for {:?}: only one set's weights average",
            other.metadata.sensors,
            first.metadata.sensors
        );
    }
    if first.metadata.normalization != other.metadata.normalization {
        bail!("{b} normalizes its inputs differently from {a} (metadata 'normalization')");
    }
    if first.metadata.licence != other.metadata.licence {
        bail!(
            "{b} is licensed '{}', {a} '{}': an average carries one licence",
            other.metadata.licence,
            first.metadata.licence
        );
    }
    Ok(())
}
