//! `imuflow export`: the command line of tools/export (imuflow-export).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use imuflow_export::{ExportError, ExportOptions, Format};
use imuflow_motion::retarget::LengthUnit;

#[derive(Args)]
pub struct ExportArgs {
    /// The recording (an imuflow .mcap file).
    recording: PathBuf,
    /// The MotionFrame channel: the estimate (opt.motion), the truth (source.truth), the judge's
    /// body (val.sim), a comparison's variant (pip-opt.motion), ...
    #[arg(long, default_value = "opt.motion")]
    channel: String,
    /// bvh (animation tools: Blender, MotionBuilder, Unity via an importer), glb (glTF 2.0 binary:
    /// a jointed figure for any glTF viewer, Blender, Godot, three.js) or npz (AMASS style, SMPL
    /// axis-angle).
    #[arg(
        long,
        value_parser = PossibleValuesParser::new(Format::NAMES)
            .try_map(|name| Format::parse(&name).ok_or("not a format")),
    )]
    format: Format,
    /// The file to write.
    #[arg(long, short, value_name = "FILE")]
    out: PathBuf,
    /// BVH: the unit of offsets and root positions (m or cm).
    #[arg(long, default_value = "m", value_parser = ["m", "cm"])]
    unit: String,
    /// Keep frames flagged CALIBRATING, PRELUDE or INVALID (left out by default).
    #[arg(long)]
    keep_all: bool,
    /// BVH and glb: the subject's stature (m), which scales the skeleton's offsets.
    #[arg(long, default_value_t = 1.75)]
    stature_m: f64,
    /// Write every joint also for a motion estimated from a sensor set that does not observe
    /// them all (a lower body's upper body, at rest); by default such a motion's BVH and glb hold
    /// the joints its set observes, and its npz flags them (`joint_estimated`).
    #[arg(long)]
    all_joints: bool,
}

pub fn run(args: ExportArgs) -> ExitCode {
    let options = ExportOptions {
        input: args.recording,
        channel: args.channel,
        format: args.format,
        out: args.out,
        unit: if args.unit == "cm" {
            LengthUnit::Centimetre
        } else {
            LengthUnit::Metre
        },
        keep_all: args.keep_all,
        stature_m: args.stature_m,
        all_joints: args.all_joints,
    };
    match imuflow_export::export(&options) {
        Ok(done) => {
            println!(
                "wrote {}: {} frames of '{}' at {} Hz, from frame {} ({:.3} s after the channel's first recorded frame); {} left out",
                options.out.display(),
                done.frames,
                options.channel,
                done.rate_hz,
                done.first_seq,
                done.first_time_s,
                done.left_out
            );
            if let Some(sites) = &done.sites {
                let joints = done.joints.count_ones();
                let what = match options.format {
                    Format::Npz => "flagged estimated (joint_estimated)",
                    _ => "written",
                };
                if joints < imuflow_body::NUM_JOINTS as u32 {
                    println!(
                        "  estimated from the sensors {sites}: {joints} of {} joints {what}, the ones those sensors observe (--all-joints writes every joint, the others at rest)",
                        imuflow_body::NUM_JOINTS
                    );
                } else {
                    println!(
                        "  estimated from the sensors {sites}: every joint written (--all-joints), the ones they do not observe at rest"
                    );
                }
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            match e {
                // The user's input: the file, the channel.
                ExportError::Write { .. } => ExitCode::FAILURE,
                _ => ExitCode::from(2),
            }
        }
    }
}
