//! Mode `synthesize`: synthetic IMUs (and the true pose) from a BVH motion.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_body::bvh::Bvh;
use imuflow_body::imu_synthesis::{
    AccelStencil, Augmentation, AugmentationConfig, ImuSample, SynthesisOptions, synthesize_imus,
};
use imuflow_body::retarget::{MotionClip, RetargetOptions, SourceSkeleton, resample, retarget_bvh};
use imuflow_body::rotation::quat_wxyz_from_rotation;
use imuflow_body::{BodyModel, BodyParams, Pose};
use imuflow_graph::StageContext;
use imuflow_graph::frames::{FrameHeader, ImuFrame, MotionFrame, NUM_IMUS, NUM_JOINTS};

use crate::{ALL_VALID, Publisher, mark_invalid_sensors};

/// How to turn a BVH into IMU signals.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Joint-mapping TOML; `None`: the built-in Bandai Namco mapping.
    pub mapping: Option<PathBuf>,
    /// Subject stature (m); `None`: the body model's reference subject.
    pub stature_m: Option<f64>,
    /// Subject mass (kg); `None`: the body model's reference subject.
    pub mass_kg: Option<f64>,
    /// Add the reference sensor errors, seeded by `seed`.
    pub augment: bool,
    pub seed: u64,
    /// Central-difference acceleration instead of the TransPose/PIP smoothed stencil.
    pub central_stencil: bool,
}

/// A motion resampled to the graph's rate with its synthetic IMUs, ready to publish.
#[derive(Debug)]
pub struct Motion {
    /// The resampled clip (the true poses).
    pub clip: MotionClip,
    /// One entry per clip frame, IMU order.
    pub imus: Vec<[ImuSample; NUM_IMUS]>,
    /// The graph's rate (Hz).
    pub rate_hz: f64,
}

impl Motion {
    /// Reads, retargets, resamples to `rate_hz` and synthesizes. Errors name the file (and line,
    /// for a malformed BVH or mapping).
    pub fn load(path: &Path, options: &Options, rate_hz: f64) -> anyhow::Result<Motion> {
        let source = match &options.mapping {
            Some(m) => SourceSkeleton::load(m).map_err(flat)?,
            None => SourceSkeleton::bandai_namco().map_err(flat)?,
        };
        let params = BodyParams::builtin().map_err(flat)?;
        let body = BodyModel::new(
            &params,
            options
                .stature_m
                .unwrap_or_else(|| params.reference_stature_m()),
            options
                .mass_kg
                .unwrap_or_else(|| params.reference_mass_kg()),
        )
        .map_err(flat)?;
        let bvh = Bvh::read(path).map_err(flat)?;
        let clip = retarget_bvh(&bvh, &source, &body, &RetargetOptions::default()).map_err(flat)?;
        let clip = resample(&clip, rate_hz).with_context(|| path.display().to_string())?;
        let synthesis = SynthesisOptions {
            stencil: if options.central_stencil {
                AccelStencil::Central
            } else {
                AccelStencil::SmoothedTransPose
            },
            augmentation: options.augment.then_some(Augmentation {
                config: AugmentationConfig::REFERENCE,
                seed: options.seed,
            }),
        };
        let imus = synthesize_imus(&clip, &body, &synthesis)
            .with_context(|| format!("{} (resampled to {rate_hz} Hz)", path.display()))?;
        Ok(Motion {
            clip,
            imus: imus.frames,
            rate_hz,
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.imus.len().min(self.clip.poses.len())
    }

    /// Whether there are no frames.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Capture time of frame `seq` (ns from the start of the motion).
    pub fn capture_ns(&self, seq: u64) -> u64 {
        (seq as f64 * 1e9 / self.rate_hz) as u64
    }

    /// The IMU frame `seq` (header: seq, capture time, INVALID when a sample is not finite).
    pub fn imu_frame(&self, seq: usize) -> Option<ImuFrame> {
        let samples = self.imus.get(seq)?;
        let mut f = ImuFrame {
            header: FrameHeader {
                seq: seq as u64,
                capture_ns: self.capture_ns(seq as u64),
                ..Default::default()
            },
            valid_mask: ALL_VALID,
            ..Default::default()
        };
        fill_imu(&mut f, samples);
        mark_invalid_sensors(&mut f);
        Some(f)
    }

    /// The true pose of frame `seq` as a MotionFrame (physics fields zero).
    pub fn truth_frame(&self, seq: usize) -> Option<MotionFrame> {
        let pose = self.clip.poses.get(seq)?;
        let mut m = MotionFrame {
            header: FrameHeader {
                seq: seq as u64,
                capture_ns: self.capture_ns(seq as u64),
                ..Default::default()
            },
            ..Default::default()
        };
        fill_truth(&mut m, pose);
        Some(m)
    }
}

/// The body crate's errors already write their cause into their message (file, line and OS
/// error); keep only that message so the cause is not printed twice.
fn flat(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("{e}")
}

/// Writes the six samples into `frame` (orientation `R_MS`, specific force and angular rate in S).
pub fn fill_imu(frame: &mut ImuFrame, samples: &[ImuSample; NUM_IMUS]) {
    for (i, s) in samples.iter().enumerate() {
        frame.orientation_wxyz[i] = quat_wxyz_from_rotation(&s.model_from_sensor).map(|v| v as f32);
        let f = &s.specific_force_in_sensor_mps2;
        frame.specific_force_mps2[i] = [f.x as f32, f.y as f32, f.z as f32];
        let w = &s.angular_velocity_in_sensor_radps;
        frame.angular_rate_radps[i] = [w.x as f32, w.y as f32, w.z as f32];
    }
}

/// Writes the pose into `frame`: local rotations and the root position.
pub fn fill_truth(frame: &mut MotionFrame, pose: &Pose) {
    for (out, r) in frame
        .local_pose_wxyz
        .iter_mut()
        .zip(pose.parent_from_joint.iter())
        .take(NUM_JOINTS)
    {
        *out = quat_wxyz_from_rotation(r).map(|v| v as f32);
    }
    let p = &pose.root_in_world_m;
    frame.root_position_m = [p.x as f32, p.y as f32, p.z as f32];
}

/// Publishes every frame of `motion` (paced at its rate when `realtime`).
pub fn run(ctx: StageContext, motion: &Motion, realtime: bool) -> anyhow::Result<()> {
    let total = motion.len();
    let Some(mut out) = Publisher::start(ctx, total as u64)? else {
        return Ok(());
    };
    let period = Duration::from_secs_f64(1.0 / motion.rate_hz);
    for seq in 0..total {
        if out.ctx.should_stop() {
            break;
        }
        if realtime {
            out.pace(period.mul_f64(seq as f64));
        }
        let t0 = Instant::now();
        let (Some(imu), Some(truth)) = (motion.imu_frame(seq), motion.truth_frame(seq)) else {
            break;
        };
        out.publish_truth(&truth)?;
        out.publish_imu(&imu, t0)?;
    }
    out.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../body/tests/fixtures/bandai-walk-normal-trimmed.bvh")
    }

    #[test]
    fn fixture_synthesizes_at_60_hz_with_unit_quaternions() {
        let motion = Motion::load(&fixture(), &Options::default(), 60.0).expect("fixture loads");
        // 48 frames at 1/30 s: 47 intervals = 1.567 s -> 95 frames at 60 Hz.
        assert_eq!(motion.len(), 95);
        for seq in 0..motion.len() {
            let f = motion.imu_frame(seq).expect("frame");
            assert_eq!(f.valid_mask, ALL_VALID);
            assert_eq!(f.header.flags, 0);
            for q in f.orientation_wxyz {
                let n: f32 = q.iter().map(|v| v * v).sum();
                assert!((n - 1.0).abs() < 1e-4);
            }
            let t = motion.truth_frame(seq).expect("truth");
            assert_eq!(t.header.seq, seq as u64);
            assert_eq!(t.header.capture_ns, f.header.capture_ns);
        }
    }

    #[test]
    fn augmentation_is_seeded() {
        let opts = |seed| Options {
            augment: true,
            seed,
            ..Options::default()
        };
        let a = Motion::load(&fixture(), &opts(1), 60.0).expect("loads");
        let b = Motion::load(&fixture(), &opts(1), 60.0).expect("loads");
        let c = Motion::load(&fixture(), &opts(2), 60.0).expect("loads");
        assert_eq!(a.imu_frame(10), b.imu_frame(10));
        assert_ne!(a.imu_frame(10), c.imu_frame(10));
    }

    #[test]
    fn missing_and_malformed_files_are_errors_naming_the_file() {
        let err = Motion::load(Path::new("/nonexistent/x.bvh"), &Options::default(), 60.0)
            .expect_err("missing file fails");
        assert!(format!("{err:#}").contains("/nonexistent/x.bvh"), "{err:#}");

        let dir = std::env::temp_dir().join(format!("imu-source-synth-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("tmp dir");
        let bad = dir.join("bad.bvh");
        let text = std::fs::read_to_string(fixture()).expect("fixture");
        std::fs::write(&bad, &text[..text.len() / 2]).expect("write");
        let err = Motion::load(&bad, &Options::default(), 60.0).expect_err("truncated file fails");
        let msg = format!("{err:#}");
        assert!(msg.contains("bad.bvh"), "{msg}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn nan_sample_marks_the_sensor_invalid() {
        let mut motion = Motion::load(&fixture(), &Options::default(), 60.0).expect("loads");
        motion.imus[5][2].specific_force_in_sensor_mps2.x = f64::NAN;
        let f = motion.imu_frame(5).expect("frame");
        assert_eq!(f.valid_mask, ALL_VALID & !(1 << 2));
        assert!(f.header.has(imuflow_graph::frames::flags::INVALID));
        assert_eq!(
            motion.imu_frame(6).expect("frame").valid_mask,
            ALL_VALID,
            "only the bad frame"
        );
    }
}
