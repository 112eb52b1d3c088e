//! Accumulating sequences into safetensors shards of one split.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::DatasetError;
use crate::split::Split;

/// Tensor names, per-frame element counts and shapes after the frame axis, in file order, for the
/// six-site set (a set of n sites has n where these have 6: [`frame_tensors`]). All are f32
/// little-endian, row-major; see `tools/dataset/README.md` for units and frames.
pub const FRAME_TENSORS: [(&str, &[usize]); 6] = [
    ("imu_orientation", &[6, 3, 3]),
    ("imu_free_accel", &[6, 3]),
    ("imu_angular_velocity", &[6, 3]),
    ("pose_local", &[24, 3, 3]),
    ("root_position", &[3]),
    ("joint_position", &[24, 3]),
];

/// The per-sequence offsets tensor: i64 [S+1], sequence s is frames `offsets[s]..offsets[s+1]`.
pub const OFFSETS_TENSOR: &str = "clip_offsets";

/// The header metadata key holding [`ShardMetadata`] as JSON.
pub const METADATA_KEY: &str = "imuflow";

/// Bytes per frame over all [`FRAME_TENSORS`] (f32), six sites.
pub const BYTES_PER_FRAME: usize = 4 * (54 + 18 + 18 + 216 + 3 + 72);

/// [`FRAME_TENSORS`] for a set of `sites` sensors: the IMU tensors' sensor axis is the set's
/// sites in wire slot order.
pub fn frame_tensors(sites: usize) -> [(&'static str, Vec<usize>); 6] {
    FRAME_TENSORS.map(|(name, dims)| {
        let mut dims = dims.to_vec();
        if name.starts_with("imu_") {
            dims[0] = sites;
        }
        (name, dims)
    })
}

/// One sequence (a clip's ideal synthesis or one augmented copy) in a shard.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SequenceInfo {
    /// The clip's path relative to the input directory (`/` separators): the split key.
    pub clip: String,
    /// 0: ideal (noise-free) IMUs; k ≥ 1: the k-th augmented copy.
    pub copy: u32,
    /// Whether the IMU signals are augmented (copy ≥ 1).
    pub augmented: bool,
    /// Augmentation seed (`None` for the ideal copy).
    pub seed: Option<u64>,
    /// Frames at 60 Hz.
    pub frames: usize,
    /// The motion augmentation this sequence carries: "" for the recorded motion, "mirrored",
    /// "speed 0.7", … (training clips only).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub motion: String,
    /// The stature of the body this sequence was synthesized on, m, when it is not the shard's
    /// `body_model` (`--vary-stature`: augmented training copies on other body sizes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stature_m: Option<f64>,
}

/// Everything in a shard's `imuflow` metadata entry (JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardMetadata {
    /// Format name and version.
    pub format: String,
    /// The split.
    pub split: String,
    /// Frame rate of every tensor (Hz).
    pub fps: f64,
    /// Licence of the data.
    pub licence: String,
    /// Body model the motion was retargeted onto.
    pub body_model: BodyModelInfo,
    /// IMU synthesis settings.
    pub synthesis: SynthesisInfo,
    /// The sensor sites synthesized, in wire slot order (the IMU tensors' sensor axis; shards
    /// written before sensor sets have none: the six-site set's).
    #[serde(default = "imuflow_body::sensor_set::six_site_names")]
    pub sensors: Vec<String>,
    /// One entry per sequence, in `clip_offsets` order.
    pub sequences: Vec<SequenceInfo>,
}

/// The body model of the shards.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BodyModelInfo {
    /// Stature (m).
    pub stature_m: f64,
    /// Mass (kg).
    pub mass_kg: f64,
}

/// IMU synthesis settings of the shards.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SynthesisInfo {
    /// Acceleration stencil (`Debug` name of `imuflow_motion::imu_synthesis::AccelStencil`).
    pub accel_stencil: String,
    /// Augmentation magnitudes of augmented copies.
    pub augmentation: String,
    /// The `--seed` the per-copy seeds derive from.
    pub base_seed: u64,
}

/// Frame data of one sequence, as little-endian f32 bytes per tensor (in [`FRAME_TENSORS`] order).
pub(crate) struct SequenceData {
    pub info: SequenceInfo,
    pub tensors: [Vec<u8>; 6],
}

/// A written shard.
#[derive(Clone, Debug, PartialEq)]
pub struct ShardFile {
    /// Path.
    pub path: PathBuf,
    /// Size (bytes).
    pub bytes: u64,
    /// Frames.
    pub frames: usize,
}

/// Accumulates the sequences of one split and writes `SPLIT-NNNN.safetensors` when full.
pub(crate) struct ShardAccumulator {
    split: Split,
    next_index: usize,
    max_frames: usize,
    frames: usize,
    offsets: Vec<i64>,
    sequences: Vec<SequenceInfo>,
    buffers: [Vec<u8>; 6],
}

impl ShardAccumulator {
    pub fn new(split: Split, max_frames: usize) -> ShardAccumulator {
        ShardAccumulator {
            split,
            next_index: 0,
            max_frames: max_frames.max(1),
            frames: 0,
            offsets: vec![0],
            sequences: Vec::new(),
            buffers: Default::default(),
        }
    }

    /// Add the sequences of one clip (its ideal and augmented copies, kept together in one shard);
    /// writes the current shard first if they would overflow it. Sequences are never cut: a clip longer
    /// than the limit gets a shard of its own.
    pub fn push_clip(
        &mut self,
        sequences: Vec<SequenceData>,
        out_dir: &Path,
        meta: &ShardMetadata,
    ) -> Result<Option<ShardFile>, DatasetError> {
        let frames: usize = sequences.iter().map(|s| s.info.frames).sum();
        let written = if self.frames > 0 && self.frames + frames > self.max_frames {
            self.flush(out_dir, meta)?
        } else {
            None
        };
        for seq in sequences {
            self.frames += seq.info.frames;
            self.offsets.push(self.frames as i64);
            for (buf, data) in self.buffers.iter_mut().zip(seq.tensors) {
                buf.extend_from_slice(&data);
            }
            self.sequences.push(seq.info);
        }
        Ok(written)
    }

    /// Write what has been accumulated (nothing when empty).
    pub fn flush(
        &mut self,
        out_dir: &Path,
        meta: &ShardMetadata,
    ) -> Result<Option<ShardFile>, DatasetError> {
        if self.sequences.is_empty() {
            return Ok(None);
        }
        let path = out_dir.join(format!(
            "{}-{:04}.safetensors",
            self.split.name(),
            self.next_index
        ));
        let st_err = |e: safetensors::SafeTensorError| DatasetError::Shard {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let offsets: Vec<u8> = self.offsets.iter().flat_map(|o| o.to_le_bytes()).collect();
        let mut views = Vec::with_capacity(FRAME_TENSORS.len() + 1);
        for ((name, dims), buf) in frame_tensors(meta.sensors.len()).iter().zip(&self.buffers) {
            let mut shape = vec![self.frames];
            shape.extend_from_slice(dims);
            let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape, buf)
                .map_err(st_err)?;
            views.push((name.to_string(), view));
        }
        let view = safetensors::tensor::TensorView::new(
            safetensors::Dtype::I64,
            vec![self.offsets.len()],
            &offsets,
        )
        .map_err(st_err)?;
        views.push((OFFSETS_TENSOR.to_string(), view));

        let mut meta = meta.clone();
        meta.split = self.split.name().to_string();
        meta.sequences = std::mem::take(&mut self.sequences);
        let json = serde_json::to_string(&meta).map_err(|e| DatasetError::Shard {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        // One key only: safetensors writes the metadata map in hash order, so a second key would make
        // the header bytes differ between runs.
        let header = HashMap::from([(METADATA_KEY.to_string(), json)]);
        // Serialized in memory and written with the usual permissions (safetensors' own
        // `serialize_to_file` goes through a 0600 temporary file), under a temporary name then renamed,
        // so a killed run leaves no truncated shard.
        let bytes = safetensors::tensor::serialize(views, Some(header)).map_err(st_err)?;
        let partial = path.with_extension("safetensors.partial");
        let io_err = |source| DatasetError::Io {
            path: partial.display().to_string(),
            source,
        };
        std::fs::write(&partial, &bytes).map_err(io_err)?;
        std::fs::rename(&partial, &path).map_err(io_err)?;
        let bytes = bytes.len() as u64;
        let shard = ShardFile {
            path,
            bytes,
            frames: self.frames,
        };
        self.next_index += 1;
        self.frames = 0;
        self.offsets = vec![0];
        for b in &mut self.buffers {
            b.clear();
        }
        Ok(Some(shard))
    }
}
