//! Calibration files: a finished calibration as JSON, so a recording can be re-run with the same
//! calibration and a live session can skip it.
//!
//! ```json
//! {
//!   "format": "imuflow-calibration",
//!   "version": 1,
//!   "method": "walking",
//!   "model_from_inertial_wxyz": [w, x, y, z],
//!   "sensors": [
//!     { "name": "left_forearm", "heading_correction_rad": 0.12,
//!       "sensor_from_bone_wxyz": [w, x, y, z], "accel_offset_mps2": [x, y, z] },
//!     ... six entries, IMU order ...
//!   ]
//! }
//! ```
//!
//! Quaternions are [w, x, y, z] and must have unit norm (within 1e-3); `name` must match the IMU
//! order, so a file written for another sensor set or order is refused.

use std::path::Path;

use imuflow_body::rotation::{quat_wxyz_from_rotation, rotation_from_quat_wxyz};
use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibration::{Calibration, Method, SensorCalibration};
use crate::error::FileError;
use crate::sensor_name;
use imuflow_body::{Imu, MAX_SITES, SiteMask};

/// The `format` every calibration file carries.
pub const FORMAT: &str = "imuflow-calibration";
/// The file version this code reads and writes.
pub const VERSION: u32 = 1;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRepr {
    format: String,
    version: u32,
    method: Method,
    model_from_inertial_wxyz: [f64; 4],
    sensors: Vec<SensorRepr>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SensorRepr {
    name: String,
    heading_correction_rad: f64,
    sensor_from_bone_wxyz: [f64; 4],
    accel_offset_mps2: [f64; 3],
}

/// Writes `calibration` to `path` (creating parent directories).
pub fn save(calibration: &Calibration, path: &Path) -> Result<(), FileError> {
    let repr = FileRepr {
        format: FORMAT.to_owned(),
        version: VERSION,
        method: calibration.method,
        model_from_inertial_wxyz: quat_wxyz_from_rotation(&calibration.model_from_inertial),
        sensors: calibration
            .sites
            .sites()
            .map(|site| (site.index(), &calibration.sensors[site.index()]))
            .map(|(k, s)| SensorRepr {
                name: sensor_name(k).to_owned(),
                heading_correction_rad: s.heading_correction_rad,
                sensor_from_bone_wxyz: quat_wxyz_from_rotation(&s.sensor_from_bone),
                accel_offset_mps2: s.accel_offset_in_model_mps2.into(),
            })
            .collect(),
    };
    let io = |source| FileError::Io {
        path: path.to_owned(),
        source,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let text = serde_json::to_string_pretty(&repr).map_err(|e| FileError::Parse {
        path: path.to_owned(),
        message: e.to_string(),
    })?;
    std::fs::write(path, text + "\n").map_err(io)
}

/// Reads a calibration written by [`save`]. Errors name the file and the offending field.
pub fn load(path: &Path) -> Result<Calibration, FileError> {
    let text = std::fs::read_to_string(path).map_err(|source| FileError::Io {
        path: path.to_owned(),
        source,
    })?;
    let repr: FileRepr = serde_json::from_str(&text).map_err(|e| FileError::Parse {
        path: path.to_owned(),
        message: e.to_string(),
    })?;
    let field = |field: String, problem: String| FileError::Field {
        path: path.to_owned(),
        field,
        problem,
    };
    if repr.format != FORMAT {
        return Err(field(
            "format".into(),
            format!("is \"{}\", expected \"{FORMAT}\"", repr.format),
        ));
    }
    if repr.version != VERSION {
        return Err(field(
            "version".into(),
            format!("is {}, this build reads {VERSION}", repr.version),
        ));
    }
    if repr.sensors.is_empty() {
        return Err(field("sensors".into(), "is empty".into()));
    }
    let model_from_inertial = rotation(&repr.model_from_inertial_wxyz)
        .map_err(|p| field("model_from_inertial_wxyz".into(), p))?;
    let mut sensors = [SensorCalibration::IDENTITY; MAX_SITES];
    let mut sites = SiteMask::default();
    let mut last_slot = None;
    for (i, s) in repr.sensors.iter().enumerate() {
        let at = |name: &str| format!("sensors[{i}].{name}");
        // The sites in wire slot order, each once (as `save` writes them).
        let Some(site) = Imu::from_name(&s.name) else {
            return Err(field(
                at("name"),
                format!(
                    "is \"{}\", not a site of the body model ({})",
                    s.name,
                    Imu::NAMES.join(", ")
                ),
            ));
        };
        let k = site.index();
        if last_slot.is_some_and(|last| k <= last) {
            return Err(field(
                at("name"),
                format!(
                    "is \"{}\", out of order or twice: the sites come in wire slot order ({})",
                    s.name,
                    Imu::NAMES.join(", ")
                ),
            ));
        }
        last_slot = Some(k);
        sites = SiteMask(sites.0 | 1 << k);
        let out = &mut sensors[k];
        if !s.heading_correction_rad.is_finite() {
            return Err(field(
                at("heading_correction_rad"),
                "is not a finite number".into(),
            ));
        }
        if !s.accel_offset_mps2.iter().all(|v| v.is_finite()) {
            return Err(field(
                at("accel_offset_mps2"),
                "holds a non-finite number".into(),
            ));
        }
        *out = SensorCalibration {
            heading_correction_rad: s.heading_correction_rad,
            sensor_from_bone: rotation(&s.sensor_from_bone_wxyz)
                .map_err(|p| field(at("sensor_from_bone_wxyz"), p))?,
            accel_offset_in_model_mps2: Vector3::from(s.accel_offset_mps2),
        };
    }
    Ok(Calibration {
        method: repr.method,
        model_from_inertial,
        sites,
        sensors,
    })
}

fn rotation(q: &[f64; 4]) -> Result<Rotation3<f64>, String> {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    // A NaN norm fails the range test too.
    let unit = (1.0 - 1e-3..=1.0 + 1e-3).contains(&norm);
    match rotation_from_quat_wxyz(q) {
        Some(r) if unit => Ok(r),
        _ => Err(format!("is not a unit quaternion (norm {norm})")),
    }
}
