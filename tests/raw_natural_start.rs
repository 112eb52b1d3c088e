//! What a natural start calibrates through raw sensors (issue: recordings as they come): the
//! bundled sample's walk behind a stand at ease of each length, raw samples at 200 Hz with the
//! BMI160's noise and biases and no magnetometer (as Noraxon's exports come), fused by the fusion
//! stage's library with its defaults, calibrated by the calibration's with its defaults; bone
//! errors of the six sensor bones against the truth over the walk after the calibration. A
//! measurement, not a check: run with `cargo test --release --test raw_natural_start -- --ignored
//! --nocapture`; it prints a table.

use imuflow_body::Imu;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::rotation::{angle_between, rotation_from_quat_wxyz};
use imuflow_calibration::{Calibrator, CalibratorConfig, Event, InertialFrame, Method};
use imuflow_fusion::assembler::Assembler;
use imuflow_graph::Mode;
use imuflow_graph::frames::{BodyImuFrame, ImuFrame};
use imuflow_synth::prelude::{PreludeKind, PreludeOptions};
use imuflow_synth::raw::{Magnetometer, RawOptions, RawSession};
use imuflow_synth::{Motion, Options, SensorSetup};

/// Bone errors (deg) after calibrating, or why it did not.
fn session(stand_s: f64, seed: u64) -> Result<Vec<f64>, String> {
    let options = Options {
        prelude: PreludeOptions {
            kind: PreludeKind::Stand,
            stand_s,
            elbow_deg: PreludeOptions::default_elbow_deg(PreludeKind::Stand),
            ..PreludeOptions::default()
        },
        sensors: SensorSetup {
            random_mounting: true,
            frame: InertialFrame::ZUp,
            frame_heading_deg: 30.0,
            heading_offset_deg: 0.0,
        },
        seed,
        ..Options::default()
    };
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/sample/walk.mcap");
    let motion = Motion::load(&path, &options, 60.0).map_err(|e| e.to_string())?;
    let body = imuflow_synth::body_model(&options).map_err(|e| e.to_string())?;
    let raw = RawSession::synthesize(
        &motion,
        &body,
        &RawOptions {
            seed,
            heading_deg: 30.0,
            noise_scale: 1.0,
            magnetometer: Magnetometer::None,
            ..RawOptions::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let settings = imuflow_fusion::stage::FusionParams::default()
        .settings(60.0, Mode::Offline)
        .map_err(|e| e.to_string())?;
    let mut fusion = Assembler::new(settings);
    let mut fused: Vec<ImuFrame> = Vec::new();
    for frame in &raw.frames {
        fusion.push(frame, &mut fused).map_err(|e| e.to_string())?;
    }
    fusion.finish(&mut fused).map_err(|e| e.to_string())?;
    let mut calibrator = Calibrator::new(CalibratorConfig {
        method: Method::Walking,
        frame: InertialFrame::ZUp,
        ..CalibratorConfig::default()
    });
    let mut out = BodyImuFrame::default();
    let mut errors = Vec::new();
    let mut calibrated = false;
    let mut fk = FkData::new();
    for frame in &fused {
        if let Some(Event::Calibrated { .. }) = calibrator.push(frame, &mut out) {
            calibrated = true;
        }
        let Some(pose) = motion.clip.poses.get(frame.header.seq as usize) else {
            continue;
        };
        if !calibrated {
            continue;
        }
        forward_kinematics(&body.skeleton, pose, &mut fk);
        for imu in Imu::SIX {
            let q = out.bone_orientation_wxyz[imu.index()].map(f64::from);
            if let Some(r) = rotation_from_quat_wxyz(&q) {
                errors.push(angle_between(&r, fk.world_from(imu.joint())).to_degrees());
            }
        }
    }
    if !calibrated {
        return Err(calibrator
            .finish()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default());
    }
    Ok(errors)
}

/// `q`-quantile of `v` (sorted here).
fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

#[test]
#[ignore = "a measurement (a few minutes in debug): prints the raw natural-start table"]
fn raw_natural_start_sweep() {
    eprintln!(
        "| stand (s) | bones median / p95 / max (deg), seeds 3-6 | per sensor median / max (IMU order) |"
    );
    eprintln!("|---|---|---|");
    for stand_s in [0.3, 0.5, 1.0] {
        let mut all = Vec::new();
        let mut per_sensor = vec![Vec::new(); Imu::SIX.len()];
        let mut refused = Vec::new();
        for seed in 3..7 {
            match session(stand_s, seed) {
                Ok(errors) => {
                    for (i, e) in errors.iter().enumerate() {
                        per_sensor[i % Imu::SIX.len()].push(*e);
                    }
                    all.extend(errors);
                }
                Err(why) => refused.push(format!(
                    "seed {seed} refused: {}",
                    why.lines().next().unwrap_or("")
                )),
            }
        }
        if all.is_empty() {
            eprintln!("| {stand_s} | {} | |", refused.join("; "));
            continue;
        }
        let sensors: Vec<String> = per_sensor
            .iter_mut()
            .map(|v| format!("{:.1} / {:.1}", quantile(v, 0.5), quantile(v, 1.0)))
            .collect();
        eprintln!(
            "| {stand_s} | {:.1} / {:.1} / {:.1} {} | {} |",
            quantile(&mut all, 0.5),
            quantile(&mut all, 0.95),
            quantile(&mut all, 1.0),
            refused.join("; "),
            sensors.join(", ")
        );
    }
}
