//! imuflow's forward kinematics of the frames an export writes, as JSON: the expected values a
//! check of an exported file in another tool compares with (scripts/verify/blender_check.py).
//!
//! ```sh
//! cargo run -p imuflow-export --example fk_reference -- RECORDING CHANNEL [--stature-m M] FRAME...
//! ```
//!
//! FRAME is an index into the exported frames (frame k of the BVH, the glb's keyframe k), the
//! frames `imuflow export` leaves out (calibration, prelude, invalid) not counted. Prints
//! `{"recording", "channel", "stature_m", "rate_hz", "frames_exported", "joints": [names],
//! "frames": [{"index", "position_m": J × [x, y, z], "rotation_wxyz": J × [w, x, y, z]}]}`:
//! the world position (m) and world rotation in the model frame M (x left, y up, z forward) of
//! every joint the export writes (all 24, or those a sensor set's estimate observes).

use std::path::PathBuf;
use std::process::ExitCode;

use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::rotation::quat_wxyz_from_rotation;
use imuflow_body::{BodyModel, BodyParams, JointId};
use serde_json::json;

struct Args {
    recording: PathBuf,
    channel: String,
    stature_m: f64,
    frames: Vec<usize>,
}

fn parse(mut args: impl Iterator<Item = String>) -> Result<Args, String> {
    let usage = "usage: fk_reference RECORDING CHANNEL [--stature-m M] FRAME...";
    let recording = args.next().ok_or(usage)?.into();
    let channel = args.next().ok_or(usage)?;
    let mut stature_m = 1.75;
    let mut frames = Vec::new();
    while let Some(arg) = args.next() {
        if arg == "--stature-m" {
            let value = args.next().ok_or("--stature-m needs a value")?;
            stature_m = value
                .parse()
                .map_err(|_| format!("--stature-m: {value:?} is not a number"))?;
        } else {
            frames.push(
                arg.parse()
                    .map_err(|_| format!("{arg:?} is not a frame index\n{usage}"))?,
            );
        }
    }
    if frames.is_empty() {
        return Err(usage.into());
    }
    Ok(Args {
        recording,
        channel,
        stature_m,
        frames,
    })
}

fn run(args: Args) -> Result<serde_json::Value, String> {
    let motion = imuflow_export::read_motion(&args.recording, &args.channel, false)
        .map_err(|e| e.to_string())?;
    let params = BodyParams::builtin().map_err(|e| e.to_string())?;
    // The export's body: mass does not enter the kinematics.
    let body = BodyModel::new(&params, args.stature_m, 70.0).map_err(|e| e.to_string())?;
    let poses = &motion.clip.poses;
    let mask = motion.exported.joints;
    let written = || JointId::all().filter(move |j| mask & (1 << j.index()) != 0);
    let mut fk = FkData::new();
    let mut frames = Vec::new();
    for &k in &args.frames {
        let pose = poses.get(k).ok_or_else(|| {
            format!(
                "frame {k}: the export of '{}' has {} frames",
                args.channel,
                poses.len()
            )
        })?;
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let positions: Vec<[f64; 3]> = written()
            .map(|j| fk.position(j).as_slice().try_into().expect("3 values"))
            .collect();
        let rotations: Vec<[f64; 4]> = written()
            .map(|j| quat_wxyz_from_rotation(fk.world_from(j)))
            .collect();
        frames.push(json!({"index": k, "position_m": positions, "rotation_wxyz": rotations}));
    }
    Ok(json!({
        "recording": args.recording.display().to_string(),
        "channel": args.channel,
        "stature_m": args.stature_m,
        "rate_hz": motion.exported.rate_hz,
        "frames_exported": motion.exported.frames,
        "joints": written().map(JointId::name).collect::<Vec<_>>(),
        "frames": frames,
    }))
}

fn main() -> ExitCode {
    match parse(std::env::args().skip(1)).and_then(run) {
        Ok(out) => {
            println!("{out:#}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}
