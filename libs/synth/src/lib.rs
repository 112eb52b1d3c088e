//! Synthetic IMU sessions: a motion (a BVH file, or a clip already on the body model) with an
//! optional calibration prelude, sensors worn on the body in a chosen inertial frame, and the
//! frames they would report.
//! A library with no process: the imu-source stage's `synthesize` mode publishes these frames, and
//! tests and tools use them as inputs with a known truth.
//!
//! - [`prelude`]: the T-pose / stand-step-stand prelude put in front of a clip.
//! - [`Motion`]: a clip synthesized into IMU frames and truth frames.
//! - [`raw`]: the raw accelerometer, gyroscope and magnetometer samples of a [`Motion`] on the
//!   sensors' own clocks, with noise, clock offsets and drift, delivery jitter and loss, as
//!   `RawImuFrame`s.

pub mod prelude;
pub mod raw;

use std::path::{Path, PathBuf};

use anyhow::Context;
use imuflow_body::rotation::{Axis, quat_wxyz_from_rotation};
use imuflow_body::{BodyModel, BodyParams, Pose};
use imuflow_body::{Imu, MAX_SITES, NUM_IMUS, SiteMask};
use imuflow_graph::frames::{FrameHeader, ImuFrame, MotionFrame, NUM_JOINTS, flags};
use imuflow_motion::bvh::Bvh;
use imuflow_motion::imu_synthesis::{
    AccelStencil, Augmentation, AugmentationConfig, ImuSample, SynthesisOptions, synthesize_imus,
};
use imuflow_motion::retarget::{
    MotionClip, RetargetOptions, SourceSkeleton, resample, retarget_bvh,
};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::prelude::{PreludeOptions, WithPrelude, with_prelude};

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
    /// Calibration prelude put in front of the clip (default: none).
    pub prelude: PreludeOptions,
    /// How the sensors are worn and which inertial frame they report in (default: sensor = bone,
    /// I = M, as without calibration).
    pub sensors: SensorSetup,
    /// The sites worn (a sensor set's, [`imuflow_body::SensorSet::mask`]); `None`: the six-site
    /// set.
    pub sites: Option<SiteMask>,
}

impl Options {
    /// The sites worn.
    pub fn sites(&self) -> SiteMask {
        self.sites.unwrap_or(SiteMask::of(Imu::SIX))
    }
}

/// Every sensor of the six-site set valid.
pub const ALL_VALID: u32 = (1 << NUM_IMUS) - 1;

/// Marks non-finite sensors of `frame` invalid: clears their `valid_mask` bits (starting from
/// `valid_mask` as given) and sets the INVALID flag when any sensor of the six-site set is invalid.
pub fn mark_invalid_sensors(frame: &mut ImuFrame) {
    mark_invalid_sites(frame, SiteMask(ALL_VALID));
}

/// Marks non-finite sensors of `frame` invalid: clears their `valid_mask` bits (starting from
/// `valid_mask` as given) and sets the INVALID flag when any of `sites` is invalid.
pub fn mark_invalid_sites(frame: &mut ImuFrame, sites: SiteMask) {
    for i in 0..MAX_SITES {
        let finite = frame.orientation_wxyz[i].iter().all(|v| v.is_finite())
            && frame.specific_force_mps2[i].iter().all(|v| v.is_finite())
            && frame.angular_rate_radps[i].iter().all(|v| v.is_finite());
        if !finite {
            frame.valid_mask &= !(1 << i);
        }
    }
    if frame.valid_mask & sites.0 != sites.0 {
        frame.header.flags |= flags::INVALID;
    }
}

pub use imuflow_body::inertial::InertialFrame;

/// How the simulated sensors are worn and what they report their orientation in.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SensorSetup {
    /// Each sensor mounted in a uniformly random orientation on its bone (seeded).
    pub random_mounting: bool,
    /// The inertial-frame convention.
    pub frame: InertialFrame,
    /// Heading of the inertial frames (deg): the subject, facing +z in M, faces this direction in I
    /// (right-handed about up from the convention's forward axis).
    pub frame_heading_deg: f64,
    /// Each sensor's inertial frame is turned further by a heading offset uniform in ±this (deg,
    /// seeded): what a walking calibration's heading correction undoes.
    pub heading_offset_deg: f64,
}

/// The sensor frames a [`SensorSetup`] drew.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorFrames {
    /// `R_S'S` per sensor: from the mounted sensor frame S to the synthesized sensor frame S' (the
    /// bone frame, with the augmentation's small mounting error when augmenting). The true
    /// `R_SB` is `R_S'Sᵀ·R_S'B`.
    pub ideal_from_sensor: [Rotation3<f64>; MAX_SITES],
    /// `R_IM` per sensor: model frame to the sensor's inertial frame.
    pub inertial_from_model: [Rotation3<f64>; MAX_SITES],
    /// The total heading of each sensor's inertial frame (rad): `frame_heading_deg` plus its offset.
    /// A walking calibration's heading correction of sensor k is `heading[pelvis] − heading[k]`.
    pub heading_rad: [f64; MAX_SITES],
}

impl SensorSetup {
    /// Draws the mountings and offsets of `sites` from `seed` (independent of the augmentation's
    /// draws; site by site in slot order, so a site's draws depend only on the sites before it).
    pub fn draw(&self, seed: u64, sites: SiteMask) -> SensorFrames {
        // A distinct stream: "calibrat" in ASCII.
        let mut rng = StdRng::seed_from_u64(seed ^ 0x6361_6c69_6272_6174);
        let mut frames = SensorFrames {
            ideal_from_sensor: [Rotation3::identity(); MAX_SITES],
            inertial_from_model: [Rotation3::identity(); MAX_SITES],
            heading_rad: [0.0; MAX_SITES],
        };
        for k in sites.sites().map(Imu::index) {
            // Uniform on SO(3): a normalized 4-D Gaussian quaternion. Drawn even when unused so the
            // offsets do not depend on `random_mounting`.
            let q: [f64; 4] = std::array::from_fn(|_| rng.sample(StandardNormal));
            let offset = (rng.random::<f64>() * 2.0 - 1.0) * self.heading_offset_deg;
            if self.random_mounting {
                frames.ideal_from_sensor[k] =
                    UnitQuaternion::new_normalize(Quaternion::new(q[0], q[1], q[2], q[3]))
                        .to_rotation_matrix();
            }
            let heading = (self.frame_heading_deg + offset).to_radians();
            frames.heading_rad[k] = heading;
            // R_MI,k = R_y(−heading)·R_MI(0), so R_IM,k = R_MI(0)ᵀ·R_y(heading).
            frames.inertial_from_model[k] =
                self.frame.model_from_inertial_at_zero_heading().transpose()
                    * Axis::Y.rotation(heading);
        }
        frames
    }
}

/// A motion resampled to the graph's rate with its synthetic IMUs, ready to publish.
#[derive(Debug)]
pub struct Motion {
    /// The resampled clip (the true poses).
    pub clip: MotionClip,
    /// One entry per clip frame, by wire slot ([`Motion::sites`] filled).
    pub imus: Vec<[ImuSample; MAX_SITES]>,
    /// The sites worn.
    pub sites: SiteMask,
    /// The graph's rate (Hz).
    pub rate_hz: f64,
    /// How the sensors are worn and what they report in.
    pub sensors: SensorFrames,
    /// Frames of the calibration prelude before the clip's first (flagged PRELUDE).
    pub prelude_frames: usize,
}

impl Motion {
    /// Reads a motion, resamples it to `rate_hz` and synthesizes. The motion is, by extension: a
    /// `.bvh` (retargeted with the options' joint mapping), an AMASS-style `.npz` (SMPL poses, as
    /// `imuflow export --format npz` writes) or an imuflow recording `.mcap` (its first
    /// `MotionFrame` channel, the true pose, without the frames flagged PRELUDE). Errors name the
    /// file (and line, for a malformed BVH or mapping).
    pub fn load(path: &Path, options: &Options, rate_hz: f64) -> anyhow::Result<Motion> {
        let body = body_model(options)?;
        let extension = path
            .extension()
            .map(|e| e.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        let clip = match extension.as_str() {
            "npz" => imuflow_motion::npz::read_amass_npz(
                path,
                &imuflow_motion::npz::AmassOptions::default(),
            )
            .map_err(flat)?,
            "mcap" => recorded_truth(path)?,
            _ => {
                let source = match &options.mapping {
                    Some(m) => SourceSkeleton::load(m).map_err(flat)?,
                    None => SourceSkeleton::bandai_namco().map_err(flat)?,
                };
                let bvh = Bvh::read(path).map_err(flat)?;
                retarget_bvh(&bvh, &source, &body, &RetargetOptions::default()).map_err(flat)?
            }
        };
        let clip = resample(&clip, rate_hz).with_context(|| path.display().to_string())?;
        let mut motion = Motion::from_clip(clip, &body, options)
            .with_context(|| format!("{} (resampled to {rate_hz} Hz)", path.display()))?;
        // The graph's rate exactly, for the capture times (not 1 / frame time).
        motion.rate_hz = rate_hz;
        Ok(motion)
    }

    /// Synthesizes the IMUs of `clip` (already at the graph's rate) on `body`, with the options'
    /// prelude, augmentation and sensor setup.
    pub fn from_clip(
        clip: MotionClip,
        body: &BodyModel,
        options: &Options,
    ) -> anyhow::Result<Motion> {
        let WithPrelude {
            clip,
            prelude_frames,
        } = with_prelude(&clip, body, &options.prelude);
        let rate_hz = clip.rate_hz();
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
            sites: options.sites(),
        };
        let imus = synthesize_imus(&clip, body, &synthesis)?;
        Ok(Motion {
            clip,
            imus: imus.frames,
            sites: options.sites(),
            rate_hz,
            sensors: options.sensors.draw(options.seed, options.sites()),
            prelude_frames,
        })
    }
}

/// The true pose of a recording (its first `MotionFrame` channel, the frames flagged PRELUDE left
/// out) as a clip at the recording's rate.
fn recorded_truth(path: &Path) -> anyhow::Result<MotionClip> {
    use imuflow_graph::frames::{MotionFrame, flags};
    use imuflow_recording::{carries, decode, for_each_record};
    let file = path.display();
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {file}"))?;
    let channels = imuflow_recording::channels(&bytes)
        .with_context(|| format!("{file}: not an imuflow recording"))?;
    let Some((&id, channel)) = channels.iter().find(|(_, c)| carries::<MotionFrame>(c)) else {
        anyhow::bail!("{file}: no MotionFrame channel (the true pose) to synthesize from");
    };
    let topic = channel.topic.clone();
    let mut frames: Vec<MotionFrame> = Vec::new();
    let mut index = 0u64;
    for_each_record(&bytes, |_, record| {
        if let mcap::records::Record::Message { header, data } = record
            && header.channel_id == id
        {
            let frame = decode::<MotionFrame>(&data, &topic, index)?;
            index += 1;
            if !frame.header.has(flags::PRELUDE) && !frame.header.is_end() {
                frames.push(frame);
            }
        }
        Ok(())
    })
    .with_context(|| format!("{file}: channel '{topic}'"))?;
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        anyhow::bail!("{file}: channel '{topic}' holds no pose outside the prelude");
    };
    let span_s = last
        .header
        .capture_ns
        .saturating_sub(first.header.capture_ns) as f64
        * 1e-9;
    if frames.len() < 2 || span_s <= 0.0 {
        anyhow::bail!("{file}: channel '{topic}' holds fewer than 2 poses in time order");
    }
    let poses = frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            imuflow_body::Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m)
                .with_context(|| format!("{file}: channel '{topic}', pose {i}"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(MotionClip {
        frame_time_s: span_s / (frames.len() - 1) as f64,
        poses,
    })
}

/// The body model of the options' subject.
pub fn body_model(options: &Options) -> anyhow::Result<BodyModel> {
    let params = BodyParams::builtin().map_err(flat)?;
    BodyModel::new(
        &params,
        options
            .stature_m
            .unwrap_or_else(|| params.reference_stature_m()),
        options
            .mass_kg
            .unwrap_or_else(|| params.reference_mass_kg()),
    )
    .map_err(flat)
}

impl Motion {
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

    /// The header of frame `seq`: its capture time, and PRELUDE before the clip's first frame.
    fn header(&self, seq: usize) -> FrameHeader {
        FrameHeader {
            seq: seq as u64,
            capture_ns: self.capture_ns(seq as u64),
            flags: if seq < self.prelude_frames {
                flags::PRELUDE
            } else {
                0
            },
            ..Default::default()
        }
    }

    /// The IMU frame `seq` (header: seq, capture time, PRELUDE in the prelude, INVALID when a
    /// sample is not finite).
    pub fn imu_frame(&self, seq: usize) -> Option<ImuFrame> {
        let samples = self.imus.get(seq)?;
        let mut f = ImuFrame {
            header: self.header(seq),
            valid_mask: self.sites.0,
            ..Default::default()
        };
        fill_imu(&mut f, samples, &self.sensors, self.sites);
        mark_invalid_sites(&mut f, self.sites);
        Some(f)
    }

    /// The true pose of frame `seq` as a MotionFrame (physics fields zero; PRELUDE in the
    /// prelude).
    pub fn truth_frame(&self, seq: usize) -> Option<MotionFrame> {
        let pose = self.clip.poses.get(seq)?;
        let mut m = MotionFrame {
            header: self.header(seq),
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

/// Writes the samples of `sites` into `frame` as the mounted sensors of `sensors` report them:
/// orientation `R_IS = R_IM·R_MS'·R_S'S`, specific force and angular rate in S (`R_S'Sᵀ` times the
/// synthesized ones). With the default setup (identities) this is the synthesized `R_MS` and S-frame
/// signals. The other slots are left as they are.
pub fn fill_imu(
    frame: &mut ImuFrame,
    samples: &[ImuSample; MAX_SITES],
    sensors: &SensorFrames,
    sites: SiteMask,
) {
    for i in sites.sites().map(Imu::index) {
        let s = &samples[i];
        let mount = &sensors.ideal_from_sensor[i];
        let orientation = sensors.inertial_from_model[i] * s.model_from_sensor * mount;
        frame.orientation_wxyz[i] = quat_wxyz_from_rotation(&orientation).map(|v| v as f32);
        let f = mount.transpose() * s.specific_force_in_sensor_mps2;
        frame.specific_force_mps2[i] = [f.x as f32, f.y as f32, f.z as f32];
        let w = mount.transpose() * s.angular_velocity_in_sensor_radps;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn fixture() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
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
            for q in &f.orientation_wxyz[..NUM_IMUS] {
                let n: f32 = q.iter().map(|v| v * v).sum();
                assert!((n - 1.0).abs() < 1e-4);
            }
            let t = motion.truth_frame(seq).expect("truth");
            assert_eq!(t.header.seq, seq as u64);
            assert_eq!(t.header.capture_ns, f.header.capture_ns);
        }
    }

    /// Largest angle (rad) between the local rotations, and distance (m) between the roots, of two
    /// clips' poses frame by frame.
    fn clip_difference(a: &MotionClip, b: &MotionClip) -> (f64, f64) {
        assert_eq!(a.poses.len(), b.poses.len());
        let (mut angle, mut root) = (0.0f64, 0.0f64);
        for (p, q) in a.poses.iter().zip(&b.poses) {
            for (r, s) in p.parent_from_joint.iter().zip(&q.parent_from_joint) {
                angle = angle.max(imuflow_body::rotation::angle_between(r, s));
            }
            root = root.max((p.root_in_world_m - q.root_in_world_m).norm());
        }
        (angle, root)
    }

    #[test]
    fn a_recording_s_truth_and_an_exported_npz_synthesize_the_same_motion() {
        let rate = 60.0;
        let bvh = Motion::load(&fixture(), &Options::default(), rate).expect("fixture loads");
        let dir = std::env::temp_dir().join(format!("imuflow-synth-load-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        // The npz round trip: what `imuflow export --format npz` writes, read back.
        let npz = dir.join("walk.npz");
        imuflow_motion::npz::write_amass_npz(
            &npz,
            &bvh.clip,
            &imuflow_motion::npz::AmassOptions::default(),
        )
        .expect("npz written");
        let from_npz = Motion::load(&npz, &Options::default(), rate).expect("npz loads");
        let (angle, root) = clip_difference(&bvh.clip, &from_npz.clip);
        assert!(angle < 1e-6 && root < 1e-6, "npz: {angle} rad, {root} m");
        // The bundled sample's truth, without its calibration prelude: 13.0 s of walking.
        let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sample/walk.mcap");
        let from_mcap = Motion::load(&sample, &Options::default(), rate).expect("sample loads");
        assert_eq!(from_mcap.len(), 1511 - 732, "frames outside the prelude");
        assert_eq!(from_mcap.prelude_frames, 0);
        // Not a recording, and a recording without a pose: errors that name the file.
        let text = dir.join("not.mcap");
        std::fs::write(&text, "hello").expect("write");
        let Err(e) = Motion::load(&text, &Options::default(), rate) else {
            panic!("a text file is not a recording");
        };
        let e = format!("{e:#}");
        assert!(
            e.contains("not.mcap") && e.contains("not an imuflow recording"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn prelude_frames_and_only_they_are_flagged_prelude() {
        use crate::prelude::PreludeKind;
        let plain = Motion::load(&fixture(), &Options::default(), 60.0).expect("fixture loads");
        let options = Options {
            prelude: PreludeOptions {
                kind: PreludeKind::Tpose,
                stand_s: 1.0,
                blend_s: 0.5,
                ..PreludeOptions::default()
            },
            ..Options::default()
        };
        let motion = Motion::load(&fixture(), &options, 60.0).expect("fixture loads");
        // T-pose hold (1 s) and blend (0.5 s) at 60 Hz; then the clip, every frame of it.
        assert_eq!(motion.prelude_frames, 60 + 30);
        assert_eq!(motion.len(), motion.prelude_frames + plain.len());
        for seq in 0..motion.len() {
            let in_prelude = seq < motion.prelude_frames;
            for header in [
                motion.imu_frame(seq).expect("imu").header,
                motion.truth_frame(seq).expect("truth").header,
            ] {
                assert_eq!(header.has(flags::PRELUDE), in_prelude, "frame {seq}");
            }
        }
        // The first unflagged frame is the clip's first: its joints as in the clip (only the root
        // is turned and moved).
        let start = motion.truth_frame(motion.prelude_frames).expect("truth");
        let first = plain.truth_frame(0).expect("truth");
        assert_eq!(start.local_pose_wxyz[1..], first.local_pose_wxyz[1..]);
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

    #[test]
    fn default_sensor_setup_reports_the_synthesized_signals_unchanged() {
        let motion = Motion::load(&fixture(), &Options::default(), 60.0).expect("loads");
        let f = motion.imu_frame(20).expect("frame");
        for (k, s) in motion.imus[20].iter().take(NUM_IMUS).enumerate() {
            let q = quat_wxyz_from_rotation(&s.model_from_sensor).map(|v| v as f32);
            assert_eq!(f.orientation_wxyz[k], q);
            let a = s.specific_force_in_sensor_mps2;
            assert_eq!(
                f.specific_force_mps2[k],
                [a.x as f32, a.y as f32, a.z as f32]
            );
        }
    }

    #[test]
    fn mounted_sensors_report_gravity_along_their_frame_convention() {
        use crate::prelude::{PreludeKind, PreludeOptions};
        use imuflow_body::rotation::rotation_from_quat_wxyz;
        use nalgebra::Vector3;
        let options = |seed| Options {
            prelude: PreludeOptions {
                kind: PreludeKind::Walk,
                ..PreludeOptions::default()
            },
            sensors: SensorSetup {
                random_mounting: true,
                frame: InertialFrame::ZDown,
                frame_heading_deg: 30.0,
                heading_offset_deg: 20.0,
            },
            seed,
            ..Options::default()
        };
        let motion = Motion::load(&fixture(), &options(3), 60.0).expect("loads");
        // 3 s stand + step + 3 s stand + blend + the clip's 94 further frames.
        assert_eq!(motion.len(), 1 + 180 + 72 + 180 + 60 + 94);
        assert_eq!(
            motion
                .truth_frame(motion.len() - 1)
                .expect("truth")
                .header
                .seq,
            motion.len() as u64 - 1
        );
        let frame = motion.imu_frame(60).expect("standing");
        for k in 0..NUM_IMUS {
            let q = frame.orientation_wxyz[k].map(f64::from);
            let r_is = rotation_from_quat_wxyz(&q).expect("unit");
            let f = Vector3::from(frame.specific_force_mps2[k].map(f64::from));
            // At rest the specific force points up: −z in a z-down frame.
            let up_in_i = r_is * f;
            assert!(
                (up_in_i - Vector3::new(0.0, 0.0, -9.81)).norm() < 1e-3,
                "sensor {k}: {up_in_i:?}"
            );
            let heading = motion.sensors.heading_rad[k].to_degrees();
            assert!(
                (10.0..=50.0).contains(&heading),
                "sensor {k}: heading {heading}"
            );
            assert!(
                imuflow_body::rotation::angle_between(
                    &motion.sensors.ideal_from_sensor[k],
                    &Rotation3::identity()
                ) > 1e-3
            );
        }
        let other = Motion::load(&fixture(), &options(4), 60.0).expect("loads");
        assert_ne!(other.sensors, motion.sensors, "seeded");
        assert_eq!(
            Motion::load(&fixture(), &options(3), 60.0)
                .expect("loads")
                .sensors,
            motion.sensors
        );
    }

    #[test]
    fn nan_sample_clears_its_bit_and_flags_the_frame() {
        let mut f = ImuFrame {
            valid_mask: ALL_VALID,
            ..Default::default()
        };
        for q in &mut f.orientation_wxyz {
            *q = [1.0, 0.0, 0.0, 0.0];
        }
        mark_invalid_sensors(&mut f);
        assert_eq!(f.valid_mask, ALL_VALID);
        assert_eq!(f.header.flags, 0);
        f.angular_rate_radps[3][1] = f32::NAN;
        mark_invalid_sensors(&mut f);
        assert_eq!(f.valid_mask, ALL_VALID & !(1 << 3));
        assert!(f.header.has(flags::INVALID));
    }
}
