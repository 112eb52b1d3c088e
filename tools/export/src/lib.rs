//! `imuflow export`: one MotionFrame channel of a recording (the estimate `opt.motion`, the truth
//! `source.truth`, a comparison's `pip-opt.motion`, ...) written for other tools:
//!
//! - **BVH** (`--format bvh`): the body model's skeleton at the subject's stature, joints named as
//!   SMPL names them, root translation, intrinsic XYZ Euler channels, Y up, metres or centimetres,
//!   at the recording's rate. Blender, MotionBuilder and most animation tools import it.
//! - **glTF binary** (`--format glb`): the same skeleton as a node per joint with the root's
//!   translation and every joint's local rotation animated, and a box per bone so any glTF viewer
//!   shows a moving figure; Y up, metres, the model frame as it is ([`glb`]).
//! - **npz** (`--format npz`): AMASS style (`poses` N × 72 SMPL axis-angle with the root, `trans`
//!   N × 3, `mocap_framerate`; no `betas` or `gender`), in the conventions
//!   `imuflow_motion::npz` reads, so exporting and reading back is the identity.
//!
//! A motion estimated from a sensor set other than the six (the recorder names the set's sites in
//! the channel's metadata, `sites`) is written with the joints that set observes
//! ([`imuflow_body::SiteMask::observed_joints`]): BVH and glb leave the others out (a joint whose
//! children are left out ends at its first child, so a lower body's shanks reach the ankles), npz
//! keeps SMPL's 24 (its layout has no place to leave one out) and adds `joint_estimated`. The
//! six's exports, a truth and recordings without `sites` keep every joint; `all_joints` keeps
//! them for any set (the unobserved ones at rest).
//!
//! Frames flagged CALIBRATING, PRELUDE or INVALID are left out unless `keep_all`; the result says
//! which recorded frame the export starts at. Nothing is written unless the whole export succeeds:
//! the file is written beside its destination and renamed into place.

pub mod glb;

use std::path::{Path, PathBuf};

use imuflow_body::skeleton::ALL_JOINTS;
use imuflow_body::{BodyModel, BodyParams, Imu, Pose, SiteMask};
use imuflow_graph::frames::{MotionFrame, flags};
use imuflow_motion::npz::{AmassOptions, write_amass_npz};
use imuflow_motion::retarget::{LengthUnit, MotionClip, bvh_of_joints};
use imuflow_recording::{carries, decode, for_each_record, schema_name};

/// The file formats `imuflow export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Bvh,
    Glb,
    Npz,
}

impl Format {
    pub const NAMES: [&'static str; 3] = ["bvh", "glb", "npz"];

    pub fn parse(name: &str) -> Option<Format> {
        match name {
            "bvh" => Some(Format::Bvh),
            "glb" => Some(Format::Glb),
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
    /// The subject's stature (m): scales the BVH and glTF skeleton's offsets.
    pub stature_m: f64,
    /// Write every joint also for a motion estimated from a set that does not observe them all.
    pub all_joints: bool,
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
    /// The sensor sites the channel's motion was estimated from, when the recording names them
    /// (sets other than the six), comma-separated.
    pub sites: Option<String>,
    /// The joints written (BVH, glb) or flagged estimated (npz), as a mask over joint indices.
    pub joints: u32,
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

/// A channel's exportable motion: its poses at the recording's rate, and where they start.
#[derive(Clone, Debug)]
pub struct ChannelMotion {
    /// The poses kept, at the recording's rate.
    pub clip: MotionClip,
    /// What the export of this motion reports.
    pub exported: Exported,
}

/// Exports `options.channel` of `options.input` to `options.out`.
pub fn export(options: &ExportOptions) -> Result<Exported, ExportError> {
    let mut motion = read_motion(&options.input, &options.channel, options.keep_all)?;
    if options.all_joints {
        motion.exported.joints = ALL_JOINTS;
    }
    let joints = motion.exported.joints;
    let clip = &motion.clip;
    write_atomically(&options.out, |path| match options.format {
        Format::Bvh => write_bvh(path, clip, options, joints),
        Format::Glb => write_glb(path, clip, options, joints),
        Format::Npz => {
            let amass = AmassOptions {
                estimated_joints: (joints != ALL_JOINTS).then_some(joints),
                ..AmassOptions::default()
            };
            write_amass_npz(path, clip, &amass).map_err(|e| e.to_string())
        }
    })?;
    Ok(motion.exported)
}

/// The poses of MotionFrame channel `channel` of the recording `input` that an export writes
/// (frame `k` of the clip is frame `k` of every exported file): the frames flagged CALIBRATING,
/// PRELUDE or INVALID are left out unless `keep_all`.
pub fn read_motion(
    input: &Path,
    channel: &str,
    keep_all: bool,
) -> Result<ChannelMotion, ExportError> {
    let file = input.display().to_string();
    let recorded = read_channel(input, channel)?;
    let total = recorded.frames.len();
    let kept: Vec<&MotionFrame> = recorded
        .frames
        .iter()
        .filter(|f| keep_all || !is_left_out(f))
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
            channel: channel.to_owned(),
            why,
        });
    };
    let start_ns = recorded.frames[0].header.capture_ns;
    let first_time_s = first.header.capture_ns.saturating_sub(start_ns) as f64 * 1e-9;
    let first_seq = first.header.seq;
    let mut poses = Vec::with_capacity(kept.len());
    for (index, frame) in kept.iter().enumerate() {
        let pose = Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m);
        poses.push(pose.map_err(|e| ExportError::BadFrame {
            file: file.clone(),
            channel: channel.to_owned(),
            index,
            message: e.to_string(),
        })?);
    }
    Ok(ChannelMotion {
        clip: MotionClip {
            frame_time_s: 1.0 / recorded.rate_hz,
            poses,
        },
        exported: Exported {
            frames: kept.len(),
            left_out: total - kept.len(),
            first_seq,
            first_time_s,
            rate_hz: recorded.rate_hz,
            joints: recorded.sites.map_or(ALL_JOINTS, |s| s.observed_joints()),
            sites: recorded.sites.map(|s| s.names()),
        },
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
    /// The sensor sites its motion was estimated from (channel metadata `sites`), when named.
    sites: Option<SiteMask>,
}

/// The recorder's rate when its metadata has none (imuflow's nominal rate).
const DEFAULT_RATE_HZ: f64 = 60.0;

fn read_channel(path: &Path, channel: &str) -> Result<RecordedChannel, ExportError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ExportError::Read {
        file: file.clone(),
        source,
    })?;
    let not_a_recording = |e: anyhow::Error| ExportError::NotARecording {
        file: file.clone(),
        message: format!("{e:#}"),
    };
    let channels = imuflow_recording::channels(&bytes).map_err(not_a_recording)?;
    let available = {
        let motion: Vec<&str> = channels
            .values()
            .filter(|c| carries::<MotionFrame>(c))
            .map(|c| c.topic.as_str())
            .collect();
        if motion.is_empty() {
            "none".to_owned()
        } else {
            motion.join(", ")
        }
    };
    let wanted = match channels.values().find(|c| c.topic == channel) {
        None => {
            return Err(ExportError::NoChannel {
                file,
                channel: channel.to_owned(),
                available,
            });
        }
        Some(c) if !carries::<MotionFrame>(c) => {
            let schema = schema_name(c);
            return Err(ExportError::NotMotion {
                file,
                channel: channel.to_owned(),
                schema: if schema.is_empty() {
                    "no schema".into()
                } else {
                    schema.to_owned()
                },
                available,
            });
        }
        Some(c) => c.id,
    };
    let sites = match channels[&wanted].metadata.get("sites") {
        None => None,
        Some(names) => Some(
            site_mask(names).map_err(|message| ExportError::NotARecording {
                file: file.clone(),
                message: format!("channel '{channel}': metadata `sites`: {message}"),
            })?,
        ),
    };
    let mut frames = Vec::new();
    let mut rate_hz = DEFAULT_RATE_HZ;
    for_each_record(&bytes, |_, record| {
        match record {
            mcap::records::Record::Message { header, data } if header.channel_id == wanted => {
                frames.push(decode::<MotionFrame>(&data, channel, frames.len() as u64)?);
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
    .map_err(not_a_recording)?;
    Ok(RecordedChannel {
        frames,
        rate_hz,
        sites,
    })
}

/// The sites of a channel's `sites` metadata (site names, comma-separated).
fn site_mask(names: &str) -> Result<SiteMask, String> {
    names
        .split(',')
        .map(|name| {
            Imu::from_name(name.trim()).ok_or_else(|| {
                format!(
                    "'{}' is not a site of the body model ({})",
                    name.trim(),
                    Imu::NAMES.join(", ")
                )
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map(SiteMask::of)
}

/// The subject's body model at `stature_m` (its mass does not enter an export: BVH and glTF hold
/// none, so imuflow's default subject mass).
fn body_model(stature_m: f64) -> Result<BodyModel, String> {
    let params = BodyParams::builtin().map_err(|e| e.to_string())?;
    BodyModel::new(&params, stature_m, 70.0).map_err(|e| e.to_string())
}

fn write_bvh(
    path: &Path,
    clip: &MotionClip,
    options: &ExportOptions,
    joints: u32,
) -> Result<(), String> {
    let body = body_model(options.stature_m)?;
    let name = options.out.display().to_string();
    let bvh = bvh_of_joints(&body, clip, options.unit, &name, joints)
        .ok_or_else(|| "the motion has no frame".to_owned())?;
    std::fs::write(path, bvh.to_bvh_string()).map_err(|e| e.to_string())
}

fn write_glb(
    path: &Path,
    clip: &MotionClip,
    options: &ExportOptions,
    joints: u32,
) -> Result<(), String> {
    let body = body_model(options.stature_m)?;
    let bytes = glb::glb_of_joints(&body, clip, &options.channel, joints)?;
    std::fs::write(path, bytes).map_err(|e| e.to_string())
}

/// Writes through `write` into a temporary file beside `out` and renames it into place, so a failed
/// export leaves nothing behind (the temporary file is removed when dropped) and an existing file
/// untouched.
fn write_atomically(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), ExportError> {
    let fail = |message: String| ExportError::Write {
        file: out.display().to_string(),
        message,
    };
    let dir = match out.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(|e| fail(e.to_string()))?;
            dir
        }
        None => Path::new("."),
    };
    let partial = partial_file(dir).map_err(|e| fail(e.to_string()))?;
    write(partial.path()).map_err(fail)?;
    partial
        .persist(out)
        .map_err(|e| fail(e.error.to_string()))?;
    Ok(())
}

/// A temporary file in `dir` with the permissions any new file gets (0o666 less the umask), not
/// the owner-only 0o600 of a temporary file: it is renamed into place as the export.
fn partial_file(dir: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    let mut builder = tempfile::Builder::new();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    builder.tempfile_in(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_channels_sites_metadata_reads_as_its_sites_or_names_the_one_that_is_not() {
        let legs =
            site_mask("left_lower_leg,right_lower_leg,pelvis,left_upper_leg,right_upper_leg")
                .expect("the lower body's sites");
        assert_eq!(legs, SiteMask(1 << 2 | 1 << 3 | 1 << 5 | 1 << 6 | 1 << 7));
        let err = site_mask("pelvis,tail").unwrap_err();
        assert!(
            err.starts_with("'tail' is not a site of the body model (left_forearm, "),
            "{err}"
        );
    }
}
