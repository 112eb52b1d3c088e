//! `imuflow import-checkpoint`: the authors' PyTorch checkpoints (`torch.save(state_dict)`, zip +
//! pickle) to our weight files. The key names are already ours (reference §2: `rnn1.linear1.weight`,
//! `plnet.rnn.weight_ih_l0`, `iknet.net1...`), so the mapping is: read, drop a DataParallel `module.`
//! prefix, convert to f32, check every tensor against the method's nets, write with metadata.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Tensor};

use imuflow_kinematics::error::WeightsError;
use imuflow_kinematics::features::InputOrder;
use imuflow_kinematics::method::Method;
use imuflow_kinematics::weights::{self, WeightsMetadata, nets_from_tensors};

/// Read a PyTorch checkpoint's tensors, checked against `method`'s nets.
pub fn read_checkpoint(
    method: Method,
    path: &Path,
) -> Result<HashMap<String, Tensor>, WeightsError> {
    let file_err = |message: String| WeightsError::File {
        path: path.display().to_string(),
        message,
    };
    if !path.exists() {
        return Err(file_err("no such file".to_owned()));
    }
    let raw = candle_core::pickle::read_all(path)
        .map_err(|e| file_err(format!("not a PyTorch checkpoint (zip + pickle): {e}")))?;
    if raw.is_empty() {
        return Err(file_err("holds no tensors".to_owned()));
    }
    let mut tensors = HashMap::new();
    for (name, t) in raw {
        let name = name.strip_prefix("module.").unwrap_or(&name).to_owned();
        let t = t.to_dtype(DType::F32)?;
        tensors.insert(name, t);
    }
    // Builds every net: names each missing, misshapen or foreign tensor.
    nets_from_tensors(method, &tensors, &InputOrder::six())?;
    Ok(tensors)
}

/// Convert `input` (PyTorch) to `output` (our safetensors with metadata).
pub fn import_checkpoint(method: Method, input: &Path, output: &Path) -> anyhow::Result<()> {
    let tensors = read_checkpoint(method, input)?;
    let nets = nets_from_tensors(method, &tensors, &InputOrder::six())?;
    let mut named: Vec<(String, Tensor)> = tensors.into_iter().collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let metadata = WeightsMetadata {
        format: weights::FORMAT.to_owned(),
        method,
        nets: nets.iter().map(|n| n.spec.clone()).collect(),
        normalization: weights::normalization(method).to_owned(),
        provenance: serde_json::json!({
            "imported_from": input.display().to_string(),
            "converter": "imuflow import-checkpoint",
        }),
        licence: "that of the imported checkpoint (see its source)".to_owned(),
        sensors: imuflow_body::sensor_set::six_site_names(),
    };
    weights::save(output, &named, &metadata)
}
