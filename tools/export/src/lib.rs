//! `imuflow export`: one MotionFrame channel of a recording (the estimate `opt.motion`, the truth
//! `source.truth`, a comparison's `pip-opt.motion`, ...) written for other tools:
//!
//! - **BVH** (`--format bvh`): the body model's skeleton at the subject's stature, joints named as
//!   SMPL names them, root translation, intrinsic XYZ Euler channels, Y up, metres or centimetres,
//!   at the recording's rate. Blender, MotionBuilder and most animation tools import it.
//! - **npz** (`--format npz`): AMASS style (`poses` N × 72 SMPL axis-angle with the root, `trans`
//!   N × 3, `mocap_framerate`, `betas` zeros, `gender` "neutral"), in the conventions
//!   `imuflow_motion::npz` reads, so exporting and reading back is the identity.
//!
//! Frames flagged CALIBRATING, PRELUDE or INVALID are left out unless `keep_all`; the result says
//! which recorded frame the export starts at. Nothing is written unless the whole export succeeds:
//! the file is written beside its destination and renamed into place.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use imuflow_body::rotation::rotation_from_quat_wxyz;
use imuflow_body::{BodyModel, BodyParams, NUM_JOINTS, Pose};
use imuflow_graph::frames::{Frame, MotionFrame, flags, frame_from_bytes};
use imuflow_motion::npz::{AmassOptions, amass_to_writer};
use imuflow_motion::retarget::{LengthUnit, MotionClip, bvh_from_clip};
use imuflow_recording::for_each_record;
use nalgebra::{Rotation3, Vector3};

/// The file formats `imuflow export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Bvh,
    Npz,
}

impl Format {
    pub const NAMES: [&'static str; 2] = ["bvh", "npz"];

    pub fn parse(name: &str) -> Option<Format> {
        match name {
            "bvh" => Some(Format::Bvh),
            "npz" => Some(Format::Npz),
            _ => None,
        }
    }
}

/// What to export, and how.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// The recording (an imuflow mcap file).
    pub input: PathBuf,
    /// The MotionFrame channel, e.g. `opt.motion`.
    pub channel: String,
    pub format: Format,
    /// The file to write.
    pub out: PathBuf,
    /// BVH only: the unit of offsets and root positions.
    pub unit: LengthUnit,
    /// Keep frames flagged CALIBRATING, PRELUDE or INVALID.
    pub keep_all: bool,
    /// The subject's stature (m): scales the BVH skeleton's offsets.
    pub stature_m: f64,
}

/// What an export wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct Exported {
    /// Frames written.
    pub frames: usize,
    /// Recorded frames of the channel left out (calibration, prelude, invalid).
    pub left_out: usize,
    /// `seq` of the first frame written, and its time after the channel's first recorded frame (s).
    pub first_seq: u64,
    pub first_time_s: f64,
    /// The rate written (Hz): the recording's graph rate.
    pub rate_hz: f64,
}

/// Why nothing was exported; every variant names the file, and the channel where it matters.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: not a readable imuflow recording: {message}")]
    NotARecording { file: String, message: String },
    #[error("{file}: no channel '{channel}' (MotionFrame channels: {available})")]
    NoChannel {
        file: String,
        channel: String,
        available: String,
    },
    #[error(
        "{file}: channel '{channel}' carries {schema}, not MotionFrame (MotionFrame channels: {available})"
    )]
    NotMotion {
        file: String,
        channel: String,
        schema: String,
        available: String,
    },
    #[error("{file}: channel '{channel}' has no frame to export{why}")]
    Empty {
        file: String,
        channel: String,
        why: String,
    },
    #[error("{file}: channel '{channel}', message {index}: {message}")]
    BadFrame {
        file: String,
        channel: String,
        index: usize,
        message: String,
    },
    #[error("{file}: cannot write: {message}")]
    Write { file: String, message: String },
}

/// Exports `options.channel` of `options.input` to `options.out`.
pub fn export(options: &ExportOptions) -> Result<Exported, ExportError> {
    let file = options.input.display().to_string();
    let recorded = read_channel(&options.input, &options.channel)?;
    let total = recorded.frames.len();
    let kept: Vec<&MotionFrame> = recorded
        .frames
        .iter()
        .filter(|f| options.keep_all || !is_left_out(f))
        .collect();
    let Some(first) = kept.first() else {
        let why = if total == 0 {
            String::new()
        } else {
            format!(
                " ({total} recorded, all flagged CALIBRATING, PRELUDE or INVALID; --keep-all keeps them)"
            )
        };
        return Err(ExportError::Empty {
            file,
            channel: options.channel.clone(),
            why,
        });
    };
    let start_ns = recorded.frames[0].header.capture_ns;
    let first_time_s = first.header.capture_ns.saturating_sub(start_ns) as f64 * 1e-9;
    let first_seq = first.header.seq;
    let mut poses = Vec::with_capacity(kept.len());
    for (index, frame) in kept.iter().enumerate() {
        poses.push(pose_of(frame).map_err(|message| ExportError::BadFrame {
            file: file.clone(),
            channel: options.channel.clone(),
            index,
            message,
        })?);
    }
    let clip = MotionClip {
        frame_time_s: 1.0 / recorded.rate_hz,
        poses,
    };
    write_atomically(&options.out, |path| match options.format {
        Format::Bvh => write_bvh(path, &clip, options),
        Format::Npz => {
            let f = std::fs::File::create(path).map_err(|e| e.to_string())?;
            let name = options.out.display().to_string();
            amass_to_writer(
                std::io::BufWriter::new(f),
                &clip,
                &AmassOptions::default(),
                &name,
            )
            .and_then(|mut w| {
                std::io::Write::flush(&mut w)
                    .map_err(|source| imuflow_motion::npz::NpzError::Io { file: name, source })
            })
            .map_err(|e| e.to_string())
        }
    })?;
    Ok(Exported {
        frames: kept.len(),
        left_out: total - kept.len(),
        first_seq,
        first_time_s,
        rate_hz: recorded.rate_hz,
    })
}

/// Calibration and prelude frames are not the capture; INVALID ones carry no usable pose.
fn is_left_out(frame: &MotionFrame) -> bool {
    frame.header.flags & (flags::CALIBRATING | flags::PRELUDE | flags::INVALID) != 0
}

/// A channel's frames in file order and the recording's rate.
struct RecordedChannel {
    frames: Vec<MotionFrame>,
    rate_hz: f64,
}

/// The recorder's rate when its metadata has none (imuflow's nominal rate).
const DEFAULT_RATE_HZ: f64 = 60.0;

fn read_channel(path: &Path, channel: &str) -> Result<RecordedChannel, ExportError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ExportError::Read {
        file: file.clone(),
        source,
    })?;
    let motion_type = MotionFrame::layout().type_name;
    // channel id -> (topic, schema name)
    let mut channels: BTreeMap<u16, (String, String)> = BTreeMap::new();
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let mut messages: Vec<Vec<u8>> = Vec::new();
    let mut rate_hz = DEFAULT_RATE_HZ;
    let mut wanted: Option<u16> = None;
    let mut records = 0usize;
    for_each_record(&bytes, |_, record| {
        records += 1;
        match record {
            mcap::records::Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            mcap::records::Record::Channel(c) => {
                let schema = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                if c.topic == channel && schema == motion_type {
                    wanted = Some(c.id);
                }
                channels.insert(c.id, (c.topic.clone(), schema));
            }
            mcap::records::Record::Message { header, data }
                if Some(header.channel_id) == wanted =>
            {
                messages.push(data.into_owned());
            }
            mcap::records::Record::Metadata(m) => {
                if let Some(rate) = m
                    .metadata
                    .get("rate_hz")
                    .and_then(|r| r.parse::<f64>().ok())
                    && rate.is_finite()
                    && rate > 0.0
                {
                    rate_hz = rate;
                }
            }
            _ => {}
        }
        Ok(())
    })
    .map_err(|e| ExportError::NotARecording {
        file: file.clone(),
        message: format!("{e:#}"),
    })?;
    if records == 0 {
        return Err(ExportError::NotARecording {
            file,
            message: "no mcap record in it".into(),
        });
    }
    let available = {
        let motion: Vec<&str> = channels
            .values()
            .filter(|(_, schema)| *schema == motion_type)
            .map(|(topic, _)| topic.as_str())
            .collect();
        if motion.is_empty() {
            "none".to_owned()
        } else {
            motion.join(", ")
        }
    };
    if wanted.is_none() {
        return Err(
            match channels.values().find(|(topic, _)| topic == channel) {
                Some((_, schema)) => ExportError::NotMotion {
                    file,
                    channel: channel.to_owned(),
                    schema: if schema.is_empty() {
                        "no schema".into()
                    } else {
                        schema.clone()
                    },
                    available,
                },
                None => ExportError::NoChannel {
                    file,
                    channel: channel.to_owned(),
                    available,
                },
            },
        );
    }
    let mut frames = Vec::with_capacity(messages.len());
    for (index, data) in messages.iter().enumerate() {
        frames.push(frame_from_bytes::<MotionFrame>(data).ok_or_else(|| {
            ExportError::BadFrame {
                file: file.clone(),
                channel: channel.to_owned(),
                index,
                message: format!(
                    "{} bytes, a MotionFrame has {}",
                    data.len(),
                    std::mem::size_of::<MotionFrame>()
                ),
            }
        })?);
    }
    Ok(RecordedChannel { frames, rate_hz })
}

/// A MotionFrame's pose: local rotations (unit quaternions) and the root position.
fn pose_of(frame: &MotionFrame) -> Result<Pose, String> {
    let mut parent_from_joint = [Rotation3::identity(); NUM_JOINTS];
    for (j, q) in frame.local_pose_wxyz.iter().enumerate().take(NUM_JOINTS) {
        let q = q.map(f64::from);
        parent_from_joint[j] = rotation_from_quat_wxyz(&q)
            .ok_or_else(|| format!("joint {j}: not a rotation quaternion {q:?}"))?;
    }
    let p = frame.root_position_m.map(f64::from);
    if !p.iter().all(|v| v.is_finite()) {
        return Err(format!("root position {p:?} is not finite"));
    }
    Ok(Pose {
        parent_from_joint,
        root_in_world_m: Vector3::new(p[0], p[1], p[2]),
    })
}

fn write_bvh(path: &Path, clip: &MotionClip, options: &ExportOptions) -> Result<(), String> {
    let params = BodyParams::builtin().map_err(|e| e.to_string())?;
    // imuflow's default subject mass; a BVH holds no masses.
    let body = BodyModel::new(&params, options.stature_m, 70.0).map_err(|e| e.to_string())?;
    let name = options.out.display().to_string();
    let bvh = bvh_from_clip(&body, clip, options.unit, &name)
        .ok_or_else(|| "the motion has no frame".to_owned())?;
    std::fs::write(path, bvh.to_bvh_string()).map_err(|e| e.to_string())
}

/// Writes through `write` into a file beside `out` and renames it into place, so a failed export
/// leaves nothing behind (and an existing file untouched).
fn write_atomically(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), ExportError> {
    let file = out.display().to_string();
    let fail = |message: String| ExportError::Write {
        file: file.clone(),
        message,
    };
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| fail(e.to_string()))?;
    }
    let name = out
        .file_name()
        .ok_or_else(|| fail("not a file name".into()))?
        .to_string_lossy();
    let partial = out.with_file_name(format!(".{name}.partial"));
    let result =
        write(&partial).and_then(|()| std::fs::rename(&partial, out).map_err(|e| e.to_string()));
    if let Err(message) = result {
        let _ = std::fs::remove_file(&partial);
        return Err(fail(message));
    }
    Ok(())
}
