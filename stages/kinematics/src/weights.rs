//! Weight files: safetensors with the nets' tensors under the authors' key names and a JSON metadata
//! header (`imuflow` key) describing architecture, normalization, training data and licence.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};

use crate::error::WeightsError;
use crate::features::InputOrder;
use crate::method::Method;
use crate::net::{Rnn, RnnSpec};
use imuflow_body::SiteMask;

/// Format tag in the metadata.
pub const FORMAT: &str = "imuflow-kinematics/1";

/// The metadata header of a weight file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WeightsMetadata {
    pub format: String,
    pub method: Method,
    /// Every net's architecture.
    pub nets: Vec<RnnSpec>,
    /// How the inputs are normalized (human-readable; the code in `features` is the definition).
    pub normalization: String,
    /// Where the weights come from (training run summary, or "imported from ...").
    pub provenance: serde_json::Value,
    pub licence: String,
    /// The sites the nets were trained for, in wire slot order (a sensor set's sites; files
    /// written before sensor sets have none: the six-site set's).
    #[serde(default = "imuflow_body::sensor_set::six_site_names")]
    pub sensors: Vec<String>,
}

impl WeightsMetadata {
    /// The sites the nets were trained for.
    pub fn sites(&self) -> Result<imuflow_body::SiteMask, WeightsError> {
        let sites = self.sensors.iter().map(|name| {
            imuflow_body::Imu::from_name(name)
                .ok_or_else(|| WeightsError::UnknownSite { site: name.clone() })
        });
        Ok(imuflow_body::SiteMask::of(
            sites.collect::<Result<Vec<_>, _>>()?,
        ))
    }

    /// Refuses a graph whose sensor set is not the one the nets were trained for, naming both.
    pub fn check_sensors(&self, graph: &imuflow_body::SensorSet) -> Result<(), WeightsError> {
        let sites = self.sites()?;
        if sites == graph.mask() {
            return Ok(());
        }
        Err(WeightsError::WrongSensors {
            weights: format!("({})", sites.names()),
            graph: graph.to_string(),
        })
    }
}

/// The networks' sensor order for a set's `sites`, or why `method`'s networks cannot take them
/// (no pelvis, the networks' root; GlobalPose's for the six-site set only).
pub fn input_order(method: Method, sites: SiteMask) -> Result<InputOrder, WeightsError> {
    let unsupported = |why: &str| WeightsError::UnsupportedSet {
        method: method.name().to_owned(),
        sensors: sites.names(),
        why: why.to_owned(),
    };
    let order = InputOrder::of(sites)
        .ok_or_else(|| unsupported("the pelvis, their root, is not among them"))?;
    if !method.takes(&order) {
        return Err(unsupported(
            "GlobalPose's networks take the six-site set only (its inputs hold the six's \
             sensors in fixed blocks); PIP's can be trained for any set with the pelvis",
        ));
    }
    Ok(order)
}

/// A method's nets, ready to run.
pub struct Weights {
    pub metadata: WeightsMetadata,
    pub nets: Vec<Rnn>,
}

impl Weights {
    /// Load and check a weight file for `method`: every tensor present with the right shape, no foreign
    /// tensors, the metadata's method matching.
    pub fn load(path: &Path, method: Method) -> Result<Weights, WeightsError> {
        let bytes = std::fs::read(path).map_err(|e| WeightsError::File {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Weights::from_bytes(&bytes, path, method)
    }

    /// [`Weights::load`] on a file's bytes already read (`path` names it in errors).
    pub fn from_bytes(bytes: &[u8], path: &Path, method: Method) -> Result<Weights, WeightsError> {
        let file_err = |message: String| WeightsError::File {
            path: path.display().to_string(),
            message,
        };
        let metadata = read_metadata(bytes).map_err(file_err)?;
        if let Some(meta) = &metadata
            && meta.method != method
        {
            return Err(WeightsError::WrongMethod {
                expected: method.name().to_owned(),
                found: meta.method.name().to_owned(),
            });
        }
        let tensors = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)
            .map_err(|e| file_err(format!("reading tensors: {e}")))?;
        let order = match &metadata {
            Some(meta) => input_order(method, meta.sites()?)?,
            None => InputOrder::six(),
        };
        let nets = nets_from_tensors(method, &tensors, &order)?;
        let metadata = metadata.unwrap_or_else(|| WeightsMetadata {
            format: FORMAT.to_owned(),
            method,
            nets: nets.iter().map(|n| n.spec.clone()).collect(),
            normalization: normalization(method).to_owned(),
            provenance: serde_json::json!("no metadata in the file"),
            licence: "unknown".to_owned(),
            sensors: imuflow_body::sensor_set::six_site_names(),
        });
        Ok(Weights { metadata, nets })
    }
}

/// A weight file's `imuflow` metadata, `None` when it has none (an error message when the bytes are
/// not safetensors or the metadata is not valid).
pub fn read_metadata(bytes: &[u8]) -> Result<Option<WeightsMetadata>, String> {
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| format!("not a safetensors file: {e}"))?;
    header
        .metadata()
        .as_ref()
        .and_then(|m| m.get("imuflow"))
        .map(|s| serde_json::from_str(s))
        .transpose()
        .map_err(|e| format!("metadata 'imuflow' is not valid: {e}"))
}

/// Build `method`'s nets from named tensors, with sizes read from the tensors and checked against
/// what the method's data flow needs for the sensors of `order` ([`InputOrder::six`]: the six-site
/// set).
pub fn nets_from_tensors(
    method: Method,
    tensors: &HashMap<String, Tensor>,
    order: &InputOrder,
) -> Result<Vec<Rnn>, WeightsError> {
    let names = method.net_names();
    if let Some(stray) = tensors
        .keys()
        .find(|k| !names.iter().any(|n| k.starts_with(&format!("{n}."))))
    {
        return Err(WeightsError::UnexpectedTensor {
            name: stray.clone(),
            method: method.name().to_owned(),
        });
    }
    names
        .iter()
        .map(|&name| {
            let spec = RnnSpec::infer(name, tensors)?;
            let (input, output, init, input_linear) =
                method.net_io(name, order).unwrap_or((0, 0, None, false));
            let check = |what: &str, found: usize, want: usize| {
                if found == want {
                    Ok(())
                } else {
                    Err(WeightsError::Shape {
                        name: format!("{name}.{what}"),
                        expected: format!(
                            "{want} {}",
                            if what.contains("linear2") {
                                "outputs"
                            } else {
                                "inputs"
                            }
                        ),
                        found: vec![found],
                    })
                }
            };
            let first = if input_linear {
                "linear1.weight"
            } else {
                "rnn.weight_ih_l0"
            };
            if spec.input_linear != input_linear {
                return Err(WeightsError::Shape {
                    name: format!("{name}.linear1.weight"),
                    expected: if input_linear {
                        "present".into()
                    } else {
                        "absent".into()
                    },
                    found: vec![],
                });
            }
            check(first, spec.input, input)?;
            check("linear2.weight", spec.output, output)?;
            if let Some(want) = init {
                check("init_net.0.weight", spec.init_input.unwrap_or(0), want)?;
            }
            Rnn::from_tensors(&spec, tensors)
        })
        .collect()
}

/// The input normalization of PIP's networks for a set other than the six, as written in the
/// metadata ([`normalization`] is the six-site set's).
pub const PIP_SET_NORMALIZATION: &str = "PIP (reference §2.2) sized by the sensor set: x = [R_rootᵀ(a_i − a_root) for the non-root sensors, R_rootᵀa_root, R_rootᵀR_i for the non-root sensors, R_root], the sensors in the set's wire slot order with the pelvis (root) last; rnn1 predicts one leaf joint per non-root sensor (its bone's far end); accelerations in m/s² unscaled, matrices row-major; joint velocities predicted in the root frame divided by 3";

/// The input normalization of each method for the six-site set, as written in the metadata.
pub fn normalization(method: Method) -> &'static str {
    match method {
        Method::Pip => {
            "PIP (reference §2.2): x = [R_rootᵀ(a_i − a_root) for 5 sensors, R_rootᵀa_root, R_rootᵀR_i for 5 sensors, R_root], accelerations in m/s² unscaled, matrices row-major; joint velocities predicted in the root frame divided by 3"
        }
        Method::GlobalPose => {
            "GlobalPose (reference §2.4): x = [R_rootᵀa_i (6), R_rootᵀω_i (6), R_rootᵀR_i (5, row-major), −row1(R_root)], m/s² and rad/s unscaled"
        }
    }
}

/// Write `tensors` (name → f32 tensor) with `metadata` as a safetensors file. The provenance
/// never names a machine's folders: every absolute path in it is written as its last component
/// (the data set's or the file's name; [`without_machine_paths`]).
pub fn save(
    path: &Path,
    tensors: &[(String, Tensor)],
    metadata: &WeightsMetadata,
) -> anyhow::Result<()> {
    let mut metadata = metadata.clone();
    without_machine_paths(&mut metadata.provenance);
    let meta = serde_json::to_string(&metadata)?;
    save_with_metadata(path, tensors, Some(("imuflow", meta)))
}

/// Rewrites every string in `value` that is an absolute path (`/…`, `\\…`, `C:\…` or `C:/…`) to its
/// last component, so weight files say which data set or file, not where it lay on the machine
/// that trained them. Relative paths (`models/pip.safetensors`) and other text stay.
pub fn without_machine_paths(value: &mut serde_json::Value) {
    match value {
        serde_json::Value::String(s) => *s = without_machine_path(s),
        serde_json::Value::Array(items) => items.iter_mut().for_each(without_machine_paths),
        serde_json::Value::Object(map) => map.values_mut().for_each(without_machine_paths),
        _ => {}
    }
}

/// `s` as [`without_machine_paths`] writes it: an absolute path as its last component, anything
/// else unchanged.
pub fn without_machine_path(s: &str) -> String {
    if !is_absolute_path(s) {
        return s.to_owned();
    }
    s.trim_end_matches(['/', '\\'])
        .rsplit(['/', '\\'])
        .next()
        .unwrap_or_default()
        .to_owned()
}

fn is_absolute_path(s: &str) -> bool {
    let b = s.as_bytes();
    s.starts_with('/')
        || s.starts_with("\\\\")
        || (b.len() > 2
            && b[0].is_ascii_alphabetic()
            && b[1] == b':'
            && (b[2] == b'\\' || b[2] == b'/'))
}

/// Write f32 tensors as safetensors, atomically (temporary file, then rename).
pub fn save_with_metadata(
    path: &Path,
    tensors: &[(String, Tensor)],
    metadata: Option<(&str, String)>,
) -> anyhow::Result<()> {
    use anyhow::Context;
    let mut buffers = Vec::with_capacity(tensors.len());
    for (name, t) in tensors {
        let values = t.flatten_all()?.to_vec1::<f32>()?;
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        buffers.push((name.clone(), t.dims().to_vec(), bytes));
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = buffers
        .iter()
        .map(|(n, shape, bytes)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape.clone(), bytes)
                .map(|v| (n.clone(), v))
        })
        .collect::<Result<_, _>>()?;
    let meta: Option<HashMap<String, String>> =
        metadata.map(|(k, v)| HashMap::from([(k.to_owned(), v)]));
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let tmp = path.with_extension("partial");
    safetensors::serialize_to_file(views, meta, &tmp)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod provenance_tests {
    use super::*;

    #[test]
    fn absolute_paths_become_names_and_everything_else_stays() {
        let mut p = serde_json::json!({
            "data": "/work/ds/perturb",
            "initialized_from": {"file": "/home/me/ckpt/gp-rc-e2.safetensors", "provenance": {
                "data": "C:\\data\\bandai\\", "unix_dir": "/tmp/out/", "share": "\\\\host\\d\\set"}},
            "relative": "models/pip.safetensors",
            "command": "imuflow dataset build --bvh-dir <Bandai> --out <dir>",
            "list": ["/a/b", 3, "x/y"],
        });
        without_machine_paths(&mut p);
        assert_eq!(p["data"], "perturb");
        assert_eq!(p["initialized_from"]["file"], "gp-rc-e2.safetensors");
        assert_eq!(p["initialized_from"]["provenance"]["data"], "bandai");
        assert_eq!(p["initialized_from"]["provenance"]["unix_dir"], "out");
        assert_eq!(p["initialized_from"]["provenance"]["share"], "set");
        assert_eq!(p["relative"], "models/pip.safetensors");
        assert_eq!(
            p["command"],
            "imuflow dataset build --bvh-dir <Bandai> --out <dir>"
        );
        assert_eq!(p["list"], serde_json::json!(["b", 3, "x/y"]));
    }

    #[test]
    fn the_shipped_weights_name_no_machine_path() {
        for file in [
            "pip",
            "globalpose",
            "protocol/pip",
            "protocol/globalpose",
            "ingredients/globalpose-every-seed9",
            "ingredients/globalpose-every-seed13",
        ] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join(format!("../../models/{file}.safetensors"));
            let bytes = std::fs::read(&path).expect("shipped weights");
            let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).expect("header");
            let text = &meta.metadata().as_ref().expect("metadata")["imuflow"];
            let mut value: serde_json::Value = serde_json::from_str(text).expect("JSON");
            let before = value.clone();
            without_machine_paths(&mut value);
            assert_eq!(value, before, "{file}: its provenance names a machine path");
        }
    }
}

#[cfg(test)]
mod sensor_tests {
    use super::*;
    use imuflow_body::SensorSet;

    #[test]
    fn shipped_weights_are_the_six_sites_and_refuse_another_set_naming_both() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/pip.safetensors");
        let bytes = std::fs::read(&path).expect("shipped weights");
        let meta = read_metadata(&bytes).unwrap().expect("metadata");
        // Written before sensor sets: no `sensors` key, so the six.
        assert_eq!(meta.sensors, imuflow_body::sensor_set::six_site_names());
        meta.check_sensors(&SensorSet::six()).unwrap();
        let legs = SensorSet::builtin("lower-body").unwrap();
        let err = meta.check_sensors(&legs).unwrap_err().to_string();
        assert!(
            err.contains("(left_forearm, right_forearm, left_lower_leg, right_lower_leg, head, pelvis)")
                && err.contains("lower-body (left_lower_leg, right_lower_leg, pelvis, left_upper_leg, right_upper_leg)"),
            "{err}"
        );
        let mut odd = meta.clone();
        odd.sensors.push("tail".to_owned());
        assert!(
            odd.check_sensors(&SensorSet::six())
                .unwrap_err()
                .to_string()
                .contains("'tail'")
        );
    }

    /// PIP's networks take any set with the pelvis; GlobalPose's the six-site set only, not
    /// another set of six sites.
    #[test]
    fn which_sets_each_methods_networks_take_is_named() {
        use imuflow_body::Imu;
        let six_others = SiteMask::of([
            Imu::Pelvis,
            Imu::LeftLowerLeg,
            Imu::RightLowerLeg,
            Imu::LeftUpperLeg,
            Imu::RightUpperLeg,
            Imu::Sternum,
        ]);
        assert_eq!(input_order(Method::Pip, six_others).unwrap().len(), 6);
        let err = input_order(Method::GlobalPose, six_others)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("six-site set only") && err.contains("sternum"),
            "{err}"
        );
        assert!(input_order(Method::GlobalPose, SiteMask::of(Imu::SIX)).is_ok());
        let err = input_order(Method::Pip, SiteMask::of([Imu::LeftLowerLeg]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("the pelvis, their root"), "{err}");
    }
}
