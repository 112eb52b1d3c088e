//! Re-running IMU synthesis into a sized output must not allocate (counted with a wrapping global
//! allocator; this file holds a single test so no other test thread allocates while counting).

#[path = "../../body/tests/common/mod.rs"]
mod common;

use common::{Counting, allocations};

use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::Axis;
use imuflow_body::{BodyModel, BodyParams, JointId};
use imuflow_motion::imu_synthesis::{
    AccelStencil, Augmentation, AugmentationConfig, SynthesisOptions, SyntheticImus,
    synthesize_imus_into,
};
use imuflow_motion::retarget::MotionClip;
use nalgebra::Vector3;

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn synthesis_into_a_sized_output_does_not_allocate() {
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.8, 80.0).unwrap();
    let poses = (0..120)
        .map(|t| {
            let mut p = Pose::t_pose(Vector3::new(0.01 * t as f64, 1.0, 0.0));
            p.parent_from_joint[JointId::LEFT_ELBOW.index()] = Axis::Y.rotation(0.02 * t as f64);
            p
        })
        .collect();
    let clip = MotionClip {
        frame_time_s: 1.0 / 60.0,
        poses,
    };
    let mut out = SyntheticImus::default();
    for stencil in [AccelStencil::Central, AccelStencil::SmoothedTransPose] {
        for augmentation in [
            None,
            Some(Augmentation {
                config: AugmentationConfig::REFERENCE,
                seed: 5,
            }),
        ] {
            let options = SynthesisOptions {
                stencil,
                augmentation,
                ..SynthesisOptions::default()
            };
            synthesize_imus_into(&clip, &body, &options, &mut out).unwrap();
            let before = allocations();
            synthesize_imus_into(&clip, &body, &options, &mut out).unwrap();
            let after = allocations();
            assert_eq!(
                after - before,
                0,
                "{stencil:?}, augmented {}",
                augmentation.is_some()
            );
            assert_eq!(out.frames.len(), 120);
        }
    }
}
