//! AMASS-style `.npz` motion import and export.
//!
//! An AMASS file is a zip of `.npy` arrays. The ones read here:
//! - `poses`: N × 156 (SMPL-H) or N × 72 (SMPL) axis-angle rotation vectors (rad), SMPL joint order.
//!   The first 72 values are the 24 body joints (as PNP/GlobalPose preprocessing, reference §3: for
//!   SMPL-H, slots 22 and 23 then hold left-hand finger rotations; they are ignored joints anyway).
//!   Joint 0 is the global root orientation (`world_from_pelvis`), the others are local
//!   `parent_from_joint` rotations, as [`Pose::parent_from_joint`].
//! - `trans`: N × 3, SMPL `trans` (m), in AMASS's Z-up world.
//! - `mocap_framerate` (AMASS) or `mocap_frame_rate` (AMASS SMPL-X releases): scalar (Hz).
//!
//! float64 and float32 arrays are accepted; other arrays (`betas`, `gender`, `dmpls`, …) are ignored.
//! Export writes `poses` (N × 72, float64), `trans` (N × 3, float64) and `mocap_framerate` (a 0-d
//! float64 array), deflate-compressed like `numpy.savez_compressed`.
//!
//! ## Frames and the root convention
//!
//! SMPL's body frame is imuflow's model frame (x left, y up, z forward; the zero pose is the T-pose
//! facing +z), so the local joint rotations carry over unchanged. AMASS's *world* is Z-up; it is turned
//! into imuflow's Y-up world M with the TransPose/PIP alignment (reference §3)
//!
//! ```text
//!             [1  0  0]
//! M_from_A =  [0  0  1]      (x, y, z)_A  ↦  (x, z, −y)_M : −90° about x; A's up (+z) becomes +y
//!             [0 −1  0]
//! ```
//!
//! which left-multiplies the root orientation (`world_from_pelvis = M_from_A · R(poses[0:3])`) and the
//! translation.
//!
//! SMPL's `trans` is not the root joint's position: SMPL rotates the body about its rest root joint `J0(β)`
//! and then adds `trans`, so the root joint sits at `J0(β) + trans` (reference §0; articulate's
//! `ParametricModel` instead treats `tran` as the root position). [`Pose::root_in_world_m`] is the root
//! joint's position, so import computes
//!
//! ```text
//! root_in_world_m = M_from_A · (trans + J0)          export: trans = M_from_Aᵀ · root_in_world_m − J0
//! ```
//!
//! with `J0` = [`AmassOptions::smpl_root_joint_m`] (default: SMPL's mean-shape root joint,
//! [`SMPL_MEAN_ROOT_JOINT_M`]; set it to zero for articulate's convention). `J0` is a point of the rest
//! body expressed in the AMASS world axes (SMPL adds it without rotating it). Heights are kept: the
//! AMASS floor is z = 0, which becomes y = 0, but imuflow's body model is not SMPL's, so the feet may sit
//! slightly above or below the floor (re-align with [`crate::retarget::median_lowest_foot_height`]).

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Seek, Write};
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector3};
use npyz::{NpyFile, Order, WriterBuilder};

use crate::retarget::MotionClip;
use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::{axis_angle_from_rotation, rotation_from_axis_angle};
use imuflow_body::skeleton::NUM_JOINTS;

/// Row-major `M_from_A`: AMASS's Z-up world to imuflow's Y-up model frame (see the module docs).
pub const MODEL_FROM_AMASS: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];

/// SMPL's rest root joint `J0` for the mean shape (m, SMPL body axes; J_regressor applied to the
/// template mesh) [approximate: the published neutral/male models differ by a few millimetres].
pub const SMPL_MEAN_ROOT_JOINT_M: [f64; 3] = [-0.001_795, -0.223_333, 0.028_219];

/// Number of pose values per frame read and written (24 joints × 3).
pub const SMPL_POSE_VALUES: usize = NUM_JOINTS * 3;

/// Options of [`read_amass_npz`] / [`write_amass_npz`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AmassOptions {
    /// `J0`: the rest root joint added to `trans` (m, see the module docs).
    pub smpl_root_joint_m: Vector3<f64>,
    /// Writing: which of the 24 joints the motion estimates (a mask over joint indices, such as
    /// the joints a sensor set observes), written as the array `joint_estimated` (24 values, 1
    /// estimated, 0 at rest) beside `poses`, whose SMPL layout holds every joint. `None`: every
    /// joint, no such array.
    pub estimated_joints: Option<u32>,
}

impl Default for AmassOptions {
    fn default() -> AmassOptions {
        AmassOptions {
            smpl_root_joint_m: Vector3::from(SMPL_MEAN_ROOT_JOINT_M),
            estimated_joints: None,
        }
    }
}

/// Failure to read or write an AMASS-style `.npz`; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum NpzError {
    /// Opening, reading or writing the file failed.
    #[error("{file}: {source}")]
    Io {
        file: String,
        #[source]
        source: io::Error,
    },
    /// The file is not a zip archive (or a damaged one).
    #[error("{file}: not an npz (zip) archive: {message}")]
    NotZip { file: String, message: String },
    /// A required array is absent.
    #[error("{file}: array `{array}` is missing")]
    MissingArray { file: String, array: String },
    /// An array could not be decoded (damaged .npy, unsupported dtype, pickled objects).
    #[error("{file}: array `{array}`: {message}")]
    BadArray {
        file: String,
        array: String,
        message: String,
    },
    /// An array has the wrong shape.
    #[error("{file}: array `{array}` has shape {shape:?}, expected {expected}")]
    WrongShape {
        file: String,
        array: String,
        shape: Vec<u64>,
        expected: String,
    },
    /// An array holds a NaN or an infinity.
    #[error("{file}: array `{array}` holds a non-finite value at flat index {index}")]
    NonFinite {
        file: String,
        array: String,
        index: usize,
    },
    /// `poses` and `trans` disagree on the number of frames.
    #[error("{file}: array `poses` has {poses} frames but array `trans` has {trans}")]
    FrameCountMismatch {
        file: String,
        poses: usize,
        trans: usize,
    },
    /// The frame rate is not positive (or the clip to export has an invalid frame time).
    #[error("{file}: array `{array}`: frame rate {rate_hz} Hz must be positive and finite")]
    InvalidRate {
        file: String,
        array: String,
        rate_hz: f64,
    },
}

fn model_from_amass() -> Rotation3<f64> {
    let m = MODEL_FROM_AMASS;
    Rotation3::from_matrix_unchecked(Matrix3::new(
        m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2],
    ))
}

/// Read an AMASS-style `.npz` into a clip at the file's frame rate (see the module docs).
pub fn read_amass_npz(path: &Path, options: &AmassOptions) -> Result<MotionClip, NpzError> {
    let file = path.display().to_string();
    let f = File::open(path).map_err(|source| NpzError::Io {
        file: file.clone(),
        source,
    })?;
    amass_from_reader(BufReader::new(f), &file, options)
}

/// [`read_amass_npz`] from any reader; `file` names it in errors.
pub fn amass_from_reader<R: Read + Seek>(
    reader: R,
    file: &str,
    options: &AmassOptions,
) -> Result<MotionClip, NpzError> {
    let mut zip = zip::ZipArchive::new(reader).map_err(|e| NpzError::NotZip {
        file: file.to_string(),
        message: e.to_string(),
    })?;
    let (poses_shape, poses) = read_array(&mut zip, file, "poses")?;
    let n = match poses_shape.as_slice() {
        [n, 72 | 156] => *n as usize,
        _ => {
            return Err(NpzError::WrongShape {
                file: file.to_string(),
                array: "poses".into(),
                shape: poses_shape,
                expected: "N × 72 (SMPL) or N × 156 (SMPL-H)".into(),
            });
        }
    };
    let width = poses_shape[1] as usize;
    let (trans_shape, trans) = read_array(&mut zip, file, "trans")?;
    let n_trans = match trans_shape.as_slice() {
        [n, 3] => *n as usize,
        _ => {
            return Err(NpzError::WrongShape {
                file: file.to_string(),
                array: "trans".into(),
                shape: trans_shape,
                expected: "N × 3".into(),
            });
        }
    };
    if n_trans != n {
        return Err(NpzError::FrameCountMismatch {
            file: file.to_string(),
            poses: n,
            trans: n_trans,
        });
    }
    let rate_name = if has_array(&mut zip, "mocap_framerate") {
        "mocap_framerate"
    } else {
        "mocap_frame_rate"
    };
    let (rate_shape, rate) = read_array(&mut zip, file, rate_name)?;
    let rate_hz = match (rate_shape.iter().product::<u64>(), rate.first()) {
        (1, Some(&r)) => r,
        _ => {
            return Err(NpzError::WrongShape {
                file: file.to_string(),
                array: rate_name.into(),
                shape: rate_shape,
                expected: "a scalar".into(),
            });
        }
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(NpzError::InvalidRate {
            file: file.to_string(),
            array: rate_name.into(),
            rate_hz,
        });
    }

    let a = model_from_amass();
    let j0 = options.smpl_root_joint_m;
    let mut clip = MotionClip {
        frame_time_s: 1.0 / rate_hz,
        poses: Vec::with_capacity(n),
    };
    for (row, t) in poses.chunks_exact(width).zip(trans.chunks_exact(3)) {
        let mut pose = Pose::default();
        for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
            let v = Vector3::new(row[3 * j], row[3 * j + 1], row[3 * j + 2]);
            *r = rotation_from_axis_angle(&v);
        }
        pose.parent_from_joint[0] = a * pose.parent_from_joint[0];
        pose.root_in_world_m = a * (Vector3::new(t[0], t[1], t[2]) + j0);
        clip.poses.push(pose);
    }
    Ok(clip)
}

fn has_array<R: Read + Seek>(zip: &mut zip::ZipArchive<R>, name: &str) -> bool {
    zip.index_for_name(&npyz::npz::file_name_from_array_name(name))
        .is_some()
}

/// Read one float array (f8 or f4, C or Fortran order) as f64 in C order, checked finite.
fn read_array<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    file: &str,
    array: &str,
) -> Result<(Vec<u64>, Vec<f64>), NpzError> {
    let bad = |message: String| NpzError::BadArray {
        file: file.to_string(),
        array: array.to_string(),
        message,
    };
    let member = match zip.by_name(&npyz::npz::file_name_from_array_name(array)) {
        Ok(m) => m,
        Err(zip::result::ZipError::FileNotFound) => {
            return Err(NpzError::MissingArray {
                file: file.to_string(),
                array: array.to_string(),
            });
        }
        Err(e) => return Err(bad(e.to_string())),
    };
    let npy = NpyFile::new(member).map_err(|e| bad(format!("not a valid .npy member: {e}")))?;
    let shape = npy.shape().to_vec();
    let order = npy.order();
    let dtype = npy.dtype().descr();
    let values: Vec<f64> = match npy.try_data::<f64>() {
        Ok(reader) => reader
            .collect::<io::Result<Vec<f64>>>()
            .map_err(|e| bad(e.to_string()))?,
        Err(npy) => match npy.try_data::<f32>() {
            Ok(reader) => reader
                .map(|v| v.map(f64::from))
                .collect::<io::Result<Vec<f64>>>()
                .map_err(|e| bad(e.to_string()))?,
            Err(_) => return Err(bad(format!("dtype {dtype} is not float64 or float32"))),
        },
    };
    let expected_len: u64 = shape.iter().product();
    if values.len() as u64 != expected_len {
        return Err(bad(format!(
            "holds {} values, its shape {shape:?} needs {expected_len}",
            values.len()
        )));
    }
    if let Some(index) = values.iter().position(|v| !v.is_finite()) {
        return Err(NpzError::NonFinite {
            file: file.to_string(),
            array: array.to_string(),
            index,
        });
    }
    let values = match (order, shape.as_slice()) {
        (Order::Fortran, [rows, cols]) => {
            let (rows, cols) = (*rows as usize, *cols as usize);
            let mut c = vec![0.0; values.len()];
            for i in 0..rows {
                for j in 0..cols {
                    c[i * cols + j] = values[j * rows + i];
                }
            }
            c
        }
        _ => values,
    };
    Ok((shape, values))
}

/// Write `clip` as an AMASS-style `.npz` (`poses` N × 72, `trans` N × 3, `mocap_framerate`; see the
/// module docs for the frames).
pub fn write_amass_npz(
    path: &Path,
    clip: &MotionClip,
    options: &AmassOptions,
) -> Result<(), NpzError> {
    let file = path.display().to_string();
    let f = File::create(path).map_err(|source| NpzError::Io {
        file: file.clone(),
        source,
    })?;
    let mut w = amass_to_writer(BufWriter::new(f), clip, options, &file)?;
    w.flush().map_err(|source| NpzError::Io { file, source })
}

/// [`write_amass_npz`] into any writer (returned when done); `file` names it in errors.
pub fn amass_to_writer<W: Write + Seek>(
    writer: W,
    clip: &MotionClip,
    options: &AmassOptions,
    file: &str,
) -> Result<W, NpzError> {
    let rate_hz = clip.rate_hz();
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(NpzError::InvalidRate {
            file: file.to_string(),
            array: "mocap_framerate".into(),
            rate_hz,
        });
    }
    if let Some(frame) = clip.poses.iter().position(|p| !p.is_finite()) {
        return Err(NpzError::NonFinite {
            file: file.to_string(),
            array: "poses".into(),
            index: frame * SMPL_POSE_VALUES,
        });
    }
    let a_t = model_from_amass().transpose();
    let j0 = options.smpl_root_joint_m;
    let n = clip.poses.len();
    let mut poses = Vec::with_capacity(n * SMPL_POSE_VALUES);
    let mut trans = Vec::with_capacity(n * 3);
    for p in &clip.poses {
        for (j, r) in p.parent_from_joint.iter().enumerate() {
            let r = if j == 0 { a_t * r } else { *r };
            poses.extend(axis_angle_from_rotation(&r).iter());
        }
        trans.extend((a_t * p.root_in_world_m - j0).iter());
    }
    let mut zip = zip::ZipWriter::new(writer);
    let io_err = |e: io::Error| NpzError::Io {
        file: file.to_string(),
        source: e,
    };
    let zip_err = |e: zip::result::ZipError| NpzError::Io {
        file: file.to_string(),
        source: io::Error::other(e),
    };
    let estimated: Vec<f64> = options
        .estimated_joints
        .map(|mask| {
            (0..SMPL_POSE_VALUES / 3)
                .map(|j| f64::from(u8::from(mask & (1 << j) != 0)))
                .collect()
        })
        .unwrap_or_default();
    let rate = [rate_hz];
    let mut arrays: Vec<(&str, Vec<u64>, &[f64])> = vec![
        ("poses", vec![n as u64, SMPL_POSE_VALUES as u64], &poses),
        ("trans", vec![n as u64, 3], &trans),
        ("mocap_framerate", vec![], &rate),
    ];
    if !estimated.is_empty() {
        arrays.push(("joint_estimated", vec![estimated.len() as u64], &estimated));
    }
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, shape, data) in arrays {
        zip.start_file(npyz::npz::file_name_from_array_name(name), opts)
            .map_err(zip_err)?;
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape)
            .writer(&mut zip)
            .begin_nd()
            .map_err(io_err)?;
        w.extend(data.iter().copied()).map_err(io_err)?;
        w.finish().map_err(io_err)?;
    }
    zip.finish().map_err(zip_err)
}

#[cfg(test)]
mod tests {
    use std::io::Cursor;

    use super::*;
    use imuflow_body::rotation::Axis;

    fn npz_bytes(arrays: &[(&str, Vec<u64>, Vec<f64>)], f32_data: bool) -> Vec<u8> {
        let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
        for (name, shape, data) in arrays {
            zip.start_file(
                npyz::npz::file_name_from_array_name(name),
                zip::write::SimpleFileOptions::default(),
            )
            .unwrap();
            if f32_data {
                let mut w = npyz::WriteOptions::new()
                    .default_dtype()
                    .shape(shape)
                    .writer(&mut zip)
                    .begin_nd()
                    .unwrap();
                w.extend(data.iter().map(|&v| v as f32)).unwrap();
                w.finish().unwrap();
            } else {
                let mut w = npyz::WriteOptions::new()
                    .default_dtype()
                    .shape(shape)
                    .writer(&mut zip)
                    .begin_nd()
                    .unwrap();
                w.extend(data.iter().copied()).unwrap();
                w.finish().unwrap();
            }
        }
        zip.finish().unwrap().into_inner()
    }

    fn read(bytes: Vec<u8>) -> Result<MotionClip, NpzError> {
        amass_from_reader(Cursor::new(bytes), "test.npz", &AmassOptions::default())
    }

    fn wavy_clip(n: usize) -> MotionClip {
        let mut poses = Vec::new();
        for f in 0..n {
            let mut p = Pose::default();
            for (j, r) in p.parent_from_joint.iter_mut().enumerate() {
                let t = f as f64 * 0.1 + j as f64;
                *r = rotation_from_axis_angle(&Vector3::new(
                    0.8 * t.sin(),
                    0.5 * (1.3 * t).cos(),
                    0.3 * (0.7 * t).sin(),
                ));
            }
            p.root_in_world_m = Vector3::new(0.1 * f as f64, 0.9, -0.05 * f as f64);
            poses.push(p);
        }
        MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses,
        }
    }

    #[test]
    fn npz_round_trip_equals_the_clip() {
        let clip = wavy_clip(20);
        for options in [
            AmassOptions::default(),
            AmassOptions {
                smpl_root_joint_m: Vector3::zeros(),
                estimated_joints: Some(0b111),
            },
        ] {
            let bytes = amass_to_writer(Cursor::new(Vec::new()), &clip, &options, "rt.npz")
                .unwrap()
                .into_inner();
            // The estimated joints, when given, travel beside `poses`: 1 for joints 0, 1, 2.
            let mut zip = zip::ZipArchive::new(Cursor::new(bytes.clone())).unwrap();
            match options.estimated_joints {
                None => assert!(read_array(&mut zip, "rt.npz", "joint_estimated").is_err()),
                Some(_) => {
                    let (shape, flags) = read_array(&mut zip, "rt.npz", "joint_estimated").unwrap();
                    assert_eq!(shape, [24]);
                    let mut expected = vec![0.0; 24];
                    expected[..3].fill(1.0);
                    assert_eq!(flags, expected);
                }
            }
            let back = amass_from_reader(Cursor::new(bytes), "rt.npz", &options).unwrap();
            assert!((back.frame_time_s - clip.frame_time_s).abs() < 1e-12);
            assert_eq!(back.poses.len(), clip.poses.len());
            for (a, b) in clip.poses.iter().zip(&back.poses) {
                assert!((a.root_in_world_m - b.root_in_world_m).norm() < 1e-12);
                for j in 0..NUM_JOINTS {
                    let d =
                        (a.parent_from_joint[j].matrix() - b.parent_from_joint[j].matrix()).norm();
                    assert!(d < 1e-9, "joint {j}: {d}");
                }
            }
        }
    }

    #[test]
    fn npz_file_round_trip() {
        let clip = wavy_clip(5);
        let path = std::env::temp_dir().join(format!("imuflow-npz-{}.npz", std::process::id()));
        write_amass_npz(&path, &clip, &AmassOptions::default()).unwrap();
        let back = read_amass_npz(&path, &AmassOptions::default()).unwrap();
        let _ = std::fs::remove_file(&path);
        assert_eq!(back.poses.len(), 5);
        assert!((back.poses[4].root_in_world_m - clip.poses[4].root_in_world_m).norm() < 1e-12);
    }

    /// An AMASS-like SMPL-H file: root orientation zero (the body stands in A's Y-up-body-in-Z-up-world
    /// default, i.e. lying along A's +y), left knee bent 90° about x, trans (1, 2, 3).
    fn amass_like(f32_data: bool, rate_name: &str) -> Vec<u8> {
        let n = 2;
        let mut poses = vec![0.0; n * 156];
        for f in 0..n {
            poses[f * 156 + 3 * 4] = std::f64::consts::FRAC_PI_2; // left_knee x
        }
        let trans = vec![1.0, 2.0, 3.0, 1.0, 2.0, 3.0];
        npz_bytes(
            &[
                ("poses", vec![n as u64, 156], poses),
                ("trans", vec![n as u64, 3], trans),
                (rate_name, vec![], vec![120.0]),
                ("betas", vec![16], vec![0.0; 16]),
            ],
            f32_data,
        )
    }

    #[test]
    fn hand_built_npz_gives_the_expected_pose() {
        for (f32_data, rate_name) in [(false, "mocap_framerate"), (true, "mocap_frame_rate")] {
            let clip = read(amass_like(f32_data, rate_name)).unwrap();
            assert_eq!(clip.poses.len(), 2);
            assert!((clip.rate_hz() - 120.0).abs() < 1e-9);
            let p = &clip.poses[1];
            // Root: world_from_pelvis = M_from_A, a −90° rotation about x.
            let expected_root = Axis::X.rotation(-std::f64::consts::FRAC_PI_2);
            assert!((p.parent_from_joint[0].matrix() - expected_root.matrix()).norm() < 1e-6);
            // The body's up (+y) points along A's +y, which is −z in M.
            let up = p.parent_from_joint[0] * Vector3::y();
            assert!((up - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-6);
            let knee = Axis::X.rotation(std::f64::consts::FRAC_PI_2);
            assert!((p.parent_from_joint[4].matrix() - knee.matrix()).norm() < 1e-6);
            assert!(p.parent_from_joint[5].angle() < 1e-9);
            // Root = M_from_A (trans + J0): (x, y, z) ↦ (x, z, −y).
            let j0 = Vector3::from(SMPL_MEAN_ROOT_JOINT_M);
            let expected = Vector3::new(1.0 + j0.x, 3.0 + j0.z, -(2.0 + j0.y));
            assert!((p.root_in_world_m - expected).norm() < 1e-6);
        }
    }

    fn err_text(bytes: Vec<u8>) -> String {
        read(bytes).unwrap_err().to_string()
    }

    #[test]
    fn malformed_npz_gives_named_errors() {
        let e = err_text(b"definitely not a zip".to_vec());
        assert!(e.contains("test.npz") && e.contains("not an npz"), "{e}");

        let poses = ("poses", vec![2, 72], vec![0.0; 144]);
        let trans = ("trans", vec![2, 3], vec![0.0; 6]);
        let rate = ("mocap_framerate", vec![], vec![60.0]);

        let e = err_text(npz_bytes(&[poses.clone(), rate.clone()], false));
        assert!(
            e.contains("test.npz") && e.contains("`trans` is missing"),
            "{e}"
        );

        let e = err_text(npz_bytes(&[poses.clone(), trans.clone()], false));
        assert!(e.contains("`mocap_frame_rate` is missing"), "{e}");

        let wrong = ("poses", vec![2, 70], vec![0.0; 140]);
        let e = err_text(npz_bytes(&[wrong, trans.clone(), rate.clone()], false));
        assert!(
            e.contains("test.npz") && e.contains("`poses` has shape [2, 70]"),
            "{e}"
        );

        let mut t = trans.2.clone();
        t[4] = f64::NAN;
        let nan = ("trans", vec![2, 3], t);
        let e = err_text(npz_bytes(&[poses.clone(), nan, rate.clone()], false));
        assert!(
            e.contains("`trans` holds a non-finite value at flat index 4"),
            "{e}"
        );

        let short = ("trans", vec![1, 3], vec![0.0; 3]);
        let e = err_text(npz_bytes(&[poses.clone(), short, rate.clone()], false));
        assert!(e.contains("2 frames") && e.contains("has 1"), "{e}");

        let zero_rate = ("mocap_framerate", vec![], vec![0.0]);
        let e = err_text(npz_bytes(&[poses.clone(), trans.clone(), zero_rate], false));
        assert!(e.contains("`mocap_framerate`") && e.contains("0 Hz"), "{e}");

        // A member that is not a valid .npy.
        let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
        zip.start_file("poses.npy", zip::write::SimpleFileOptions::default())
            .unwrap();
        zip.write_all(b"garbage").unwrap();
        let e = err_text(zip.finish().unwrap().into_inner());
        assert!(
            e.contains("test.npz: array `poses`: not a valid .npy"),
            "{e}"
        );

        let e = read_amass_npz(Path::new("/nonexistent/x.npz"), &AmassOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/x.npz"), "{e}");
    }
}
