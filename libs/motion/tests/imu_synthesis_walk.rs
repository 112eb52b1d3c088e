//! IMU synthesis of the committed Bandai walking fixture (retargeted, resampled to 60 Hz).

use std::path::Path;

use imuflow_body::{BodyModel, BodyParams, Imu, NUM_IMUS};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::imu_synthesis::{
    AccelStencil, Augmentation, AugmentationConfig, SynthesisOptions, synthesize_imus,
};
use imuflow_motion::retarget::{
    MotionClip, RetargetOptions, SourceSkeleton, resample, retarget_bvh,
};

fn walk_60hz(body: &BodyModel) -> MotionClip {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/bandai-walk-normal-trimmed.bvh");
    let bvh = Bvh::read(&path).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    let clip = retarget_bvh(&bvh, &map, body, &RetargetOptions::default()).unwrap();
    resample(&clip, 60.0).unwrap()
}

#[test]
fn walking_fixture_gives_finite_plausible_signals() {
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
    let clip = walk_60hz(&body);
    assert!(clip.poses.len() > 90, "{} frames", clip.poses.len());
    let cases = [
        (AccelStencil::SmoothedTransPose, None),
        (AccelStencil::Central, None),
        (
            AccelStencil::SmoothedTransPose,
            Some(Augmentation {
                config: AugmentationConfig::REFERENCE,
                seed: 1,
            }),
        ),
    ];
    for (stencil, augmentation) in cases {
        let out = synthesize_imus(
            &clip,
            &body,
            &SynthesisOptions {
                stencil,
                augmentation,
                ..SynthesisOptions::default()
            },
        )
        .unwrap();
        assert_eq!(out.frames.len(), clip.poses.len());
        for (t, frame) in out.frames.iter().enumerate() {
            for s in frame.iter().take(NUM_IMUS) {
                let finite = s.model_from_sensor.matrix().iter().all(|v| v.is_finite())
                    && [
                        s.position_in_model_m,
                        s.free_accel_in_model_mps2,
                        s.specific_force_in_sensor_mps2,
                        s.angular_velocity_in_model_radps,
                        s.angular_velocity_in_sensor_radps,
                    ]
                    .iter()
                    .all(|v| v.iter().all(|x| x.is_finite()));
                assert!(finite, "{stencil:?} frame {t}");
            }
        }
        let pelvis: Vec<f64> = out.frames[4..out.frames.len() - 4]
            .iter()
            .map(|f| f[Imu::Pelvis.index()].free_accel_in_model_mps2.norm())
            .collect();
        let rms = (pelvis.iter().map(|a| a * a).sum::<f64>() / pelvis.len() as f64).sqrt();
        let max = pelvis.iter().cloned().fold(0.0, f64::max);
        let wrist: Vec<f64> = out.frames[4..out.frames.len() - 4]
            .iter()
            .map(|f| {
                f[Imu::LeftForearm.index()]
                    .angular_velocity_in_model_radps
                    .norm()
            })
            .collect();
        let wmax = wrist.iter().cloned().fold(0.0, f64::max);
        // Pelvis (sacrum) accelerations in normal walking peak at about 0.3-0.6 g vertically and 0.2-0.4 g
        // fore-aft (gait-analysis literature), so |a| of a few m/s² with peaks below ~1 g. The smoothed
        // stencil (the one the networks are trained with) measures rms 4.0 / max 6.9 m/s² here. The central
        // stencil on a 30 Hz clip linearly resampled to 60 Hz alternates 0 and twice the 30 Hz second
        // difference at the original frames, so its rms and peak are larger (measured 6.9 / 17 m/s²).
        let (rms_range, max_limit) = match stencil {
            AccelStencil::SmoothedTransPose => (1.0..6.0, 10.0),
            AccelStencil::Central => (1.0..10.0, 25.0),
        };
        assert!(
            rms_range.contains(&rms),
            "{stencil:?}: pelvis rms {rms} m/s²"
        );
        assert!(
            max > 2.0 && max < max_limit,
            "{stencil:?}: pelvis max {max} m/s²"
        );
        // Forearm swing in walking: a few rad/s (measured 5.3).
        assert!(wmax > 1.0 && wmax < 12.0, "forearm max rate {wmax} rad/s");
    }
}
