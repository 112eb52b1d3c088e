//! Training data: the dataset shards (`imuflow dataset build`, tools/dataset/README.md) turned into the
//! per-frame arrays each method's nets read and predict.
//!
//! Every array is `[F, dim]` row-major f32 over all frames of all sequences of a split. Root-relative
//! quantities use the **true** root orientation (the pose's joint 0) for targets, and the IMU's root
//! orientation for network inputs, as at inference.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use imuflow_body::kinematics::{FkData, forward_kinematics, imu_positions_in_world};
use imuflow_body::skeleton::{CONTACT_JOINTS, FULL_JOINTS, REDUCED_JOINTS};
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS, Pose};
use nalgebra::{Rotation3, Vector3};
use safetensors::SafeTensors;
use safetensors::tensor::TensorView;

pub use imuflow_kinematics::features::{FPS, PIP_VELOCITY_SCALE};
use imuflow_kinematics::features::{
    GLOBALPOSE_INPUT, ImuInput, InputOrder, Mat3, ROOT_IMU, globalpose_input, mul, pip_input,
    pip_input_len, rt_mul, rt_mul_vec,
};
use imuflow_kinematics::method::Method;

/// A foot (or stationary joint) moving less than this between frames is in contact (TransPose paper
/// §4.3: u = 0.008 m per 60 Hz frame).
pub const CONTACT_THRESHOLD_M: f32 = 0.008;

/// One derived quantity for every frame.
#[derive(Clone, Debug, Default)]
pub struct Array {
    pub dim: usize,
    pub data: Vec<f32>,
}

impl Array {
    fn new(dim: usize) -> Array {
        Array {
            dim,
            data: Vec::new(),
        }
    }

    pub fn row(&self, frame: usize) -> &[f32] {
        &self.data[frame * self.dim..(frame + 1) * self.dim]
    }
}

/// A split's frames for one method.
#[derive(Debug, Default)]
pub struct TrainSet {
    pub frames: usize,
    /// `(first frame, length)` of each sequence.
    pub sequences: Vec<(usize, usize)>,
    pub arrays: BTreeMap<&'static str, Array>,
    /// The shards' metadata (`imuflow` key), for the weights' provenance.
    pub shard_metadata: Vec<serde_json::Value>,
    /// The shards' sensor set, in the networks' order (every shard of a split has the same).
    pub order: InputOrder,
}

impl TrainSet {
    pub fn array(&self, name: &str) -> anyhow::Result<&Array> {
        self.arrays
            .get(name)
            .with_context(|| format!("training data has no array '{name}'"))
    }
}

/// The shard files of `split` in `dir`, in order.
pub fn shard_files(dir: &Path, split: &str) -> anyhow::Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("reading dataset folder {}", dir.display()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(&format!("{split}-")) && n.ends_with(".safetensors"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "no {split}-NNNN.safetensors shards in {} (build them with `imuflow dataset build`)",
            dir.display()
        );
    }
    Ok(files)
}

/// Load `split` of the dataset in `dir` for `method`: every sequence, or, when the split holds more
/// than `max_frames` frames, a uniform sample of its sequences across all shards (a fixed hash of
/// shard and sequence index picks them, so a resumed run sees the same set) of about `max_frames`.
///
/// The sample is chosen from the shards' headers and clip offsets before any frame is read, and
/// every array is reserved at its exact final size: a split of millions of frames takes its size in
/// memory once, not a growing vector's up to twice that.
pub fn load_split(
    dir: &Path,
    split: &str,
    method: Method,
    max_frames: usize,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<TrainSet> {
    let files = shard_files(dir, split)?;
    let indexes = files
        .iter()
        .map(|f| ShardIndex::read(f).with_context(|| format!("shard {}", f.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let total: usize = indexes.iter().map(|i| i.usable_frames()).sum();
    let fraction = if total > max_frames {
        max_frames as f64 / total as f64
    } else {
        1.0
    };
    let chosen: Vec<Vec<bool>> = indexes
        .iter()
        .enumerate()
        .map(|(i, index)| {
            (0..index.sequences())
                .map(|s| index.length(s) >= 2 && sampled(i, s, fraction))
                .collect()
        })
        .collect();
    let frames: usize = indexes
        .iter()
        .zip(&chosen)
        .flat_map(|(index, keep)| {
            (0..keep.len())
                .filter(|&s| keep[s])
                .map(|s| index.length(s))
        })
        .sum();

    let mut set = TrainSet::default();
    let mut builder: Option<Builder> = None;
    for (i, file) in files.iter().enumerate() {
        progress(i, files.len());
        if !chosen[i].contains(&true) {
            continue;
        }
        let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
        let shard = Shard::parse(&bytes).with_context(|| format!("shard {}", file.display()))?;
        if shard.offsets != indexes[i].offsets {
            bail!("shard {} changed while loading", file.display());
        }
        let builder = match &mut builder {
            Some(b) if b.order != shard.order => bail!(
                "shard {} holds the sensors ({}), the split's earlier shards ({}): a split is one \
                 sensor set",
                file.display(),
                shard.order.mask().names(),
                b.order.mask().names()
            ),
            Some(b) => b,
            None => {
                let mut b = Builder::new(method, shard.order)
                    .with_context(|| format!("shard {}", file.display()))?;
                b.reserve(frames);
                builder.insert(b)
            }
        };
        if let Some(meta) = shard.metadata.clone() {
            set.shard_metadata.push(meta);
        }
        for s in (0..shard.offsets.len() - 1).filter(|&s| chosen[i][s]) {
            let (a, b) = (shard.offsets[s], shard.offsets[s + 1]);
            set.sequences.push((set.frames, b - a));
            // `imuflow dataset build --vary-stature` synthesizes some sequences on other bodies.
            let stature_m = shard
                .metadata
                .as_ref()
                .and_then(|m| m["sequences"][s]["stature_m"].as_f64());
            builder.push_sequence(&shard, a, b, stature_m)?;
            set.frames += b - a;
        }
    }
    progress(files.len(), files.len());
    let builder = match builder {
        Some(b) => b,
        // Nothing chosen (every sequence too short): empty arrays of the six-site sizes.
        None => Builder::new(method, InputOrder::six())?,
    };
    set.order = builder.order;
    set.arrays = builder.arrays;
    Ok(set)
}

/// Whether sequence `sequence` of shard `shard` is in a sample of `fraction` of all sequences: a
/// SplitMix64 hash of the pair, as a number in [0, 1), below the fraction.
fn sampled(shard: usize, sequence: usize, fraction: f64) -> bool {
    if fraction >= 1.0 {
        return true;
    }
    let mut z = ((shard as u64) << 32 | sequence as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    ((z >> 11) as f64 / (1u64 << 53) as f64) < fraction
}

/// A shard's sequence boundaries, read from its safetensors header and `clip_offsets` tensor alone
/// (a few kilobytes of a 150 MB file).
struct ShardIndex {
    offsets: Vec<usize>,
}

impl ShardIndex {
    fn read(path: &Path) -> anyhow::Result<ShardIndex> {
        use std::io::{Read, Seek, SeekFrom};
        let mut file = std::fs::File::open(path)?;
        let mut len = [0u8; 8];
        file.read_exact(&mut len)
            .context("safetensors header length")?;
        let len = u64::from_le_bytes(len);
        if len > 100_000_000 {
            bail!("safetensors header of {len} bytes");
        }
        let mut header = vec![0u8; len as usize];
        file.read_exact(&mut header).context("safetensors header")?;
        let header: serde_json::Value =
            serde_json::from_slice(&header).context("safetensors header JSON")?;
        let info = &header["clip_offsets"];
        if info["dtype"] != "I64" {
            bail!("tensor 'clip_offsets' missing or not I64");
        }
        let range = info["data_offsets"]
            .as_array()
            .and_then(|r| Some((r.first()?.as_u64()?, r.get(1)?.as_u64()?)))
            .context("tensor 'clip_offsets' has no data_offsets")?;
        let mut raw = vec![0u8; range.1.saturating_sub(range.0) as usize];
        file.seek(SeekFrom::Start(8 + len + range.0))?;
        file.read_exact(&mut raw).context("tensor 'clip_offsets'")?;
        let offsets = raw
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")).max(0) as usize)
            .collect::<Vec<_>>();
        if offsets.first() != Some(&0) || offsets.windows(2).any(|w| w[1] < w[0]) {
            bail!("clip_offsets are not increasing from 0");
        }
        Ok(ShardIndex { offsets })
    }

    fn sequences(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    fn length(&self, sequence: usize) -> usize {
        self.offsets[sequence + 1] - self.offsets[sequence]
    }

    /// Frames in sequences long enough to train on (two frames or more).
    fn usable_frames(&self) -> usize {
        (0..self.sequences())
            .map(|s| self.length(s))
            .filter(|&n| n >= 2)
            .sum()
    }
}

pub struct Shard<'a> {
    orientation: Vec<f32>,
    accel: Vec<f32>,
    gyro: Vec<f32>,
    /// The shard's sensors in the networks' order.
    pub order: InputOrder,
    /// Per input index, the sensor's index along the shard's sensor axis (wire slot order).
    column: [usize; imuflow_body::MAX_SITES],
    pose: Vec<f32>,
    root: Vec<f32>,
    joints: Vec<f32>,
    pub(crate) offsets: Vec<usize>,
    pub(crate) metadata: Option<serde_json::Value>,
    _bytes: std::marker::PhantomData<&'a [u8]>,
}

/// A safetensors tensor's values, which must be f32 (as every tensor imuflow writes is).
pub(crate) fn f32_values(name: &str, view: &TensorView) -> anyhow::Result<Vec<f32>> {
    if view.dtype() != safetensors::Dtype::F32 {
        bail!("tensor '{name}' is {:?}, expected F32", view.dtype());
    }
    Ok(view
        .data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

impl<'a> Shard<'a> {
    /// Parses one shard file's bytes (safetensors, as `imuflow dataset build` writes them).
    pub fn parse(bytes: &'a [u8]) -> anyhow::Result<Shard<'a>> {
        let (_, header) = SafeTensors::read_metadata(bytes).context("safetensors header")?;
        let metadata = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("imuflow"))
            .and_then(|s| serde_json::from_str(s).ok());
        // The sites the IMU tensors hold, in wire slot order (shards written before sensor sets
        // have no `sensors`: the six).
        let names: Vec<String> = match metadata
            .as_ref()
            .and_then(|m: &serde_json::Value| m.get("sensors"))
        {
            Some(sensors) => serde_json::from_value(sensors.clone())
                .with_context(|| format!("metadata `sensors` {sensors} is not a list of sites"))?,
            None => imuflow_body::sensor_set::six_site_names(),
        };
        let sites = names
            .iter()
            .map(|n| {
                imuflow_body::Imu::from_name(n)
                    .with_context(|| format!("metadata `sensors` names '{n}', not a site"))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let order = InputOrder::of(imuflow_body::SiteMask::of(sites.iter().copied()))
            .with_context(|| {
                format!(
                    "the shard's sensors ({}) lack the pelvis, the networks' root",
                    names.join(", ")
                )
            })?;
        // Where each of the networks' sensors is along the shard's sensor axis.
        let mut column = [0usize; imuflow_body::MAX_SITES];
        for (i, site) in order.sites().enumerate() {
            column[i] = sites.iter().position(|s| *s == site).unwrap_or(0);
        }
        let n = sites.len();
        let st = SafeTensors::deserialize(bytes).context("safetensors")?;
        let f32s = |name: &str, per_frame: usize| -> anyhow::Result<Vec<f32>> {
            let t = st
                .tensor(name)
                .with_context(|| format!("tensor '{name}' missing"))?;
            let values = f32_values(name, &t)?;
            let n: usize = t.shape()[1..].iter().product();
            if n != per_frame {
                bail!("tensor '{name}' has shape {:?}", t.shape());
            }
            Ok(values)
        };
        let offsets_t = st.tensor("clip_offsets").context("tensor 'clip_offsets'")?;
        let offsets: Vec<usize> = offsets_t
            .data()
            .chunks_exact(8)
            .map(|c| {
                i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]).max(0) as usize
            })
            .collect();
        let shard = Shard {
            orientation: f32s("imu_orientation", 9 * n)?,
            accel: f32s("imu_free_accel", 3 * n)?,
            gyro: f32s("imu_angular_velocity", 3 * n)?,
            order,
            column,
            pose: f32s("pose_local", 216)?,
            root: f32s("root_position", 3)?,
            joints: f32s("joint_position", 72)?,
            offsets,
            metadata,
            _bytes: std::marker::PhantomData,
        };
        let frames = shard.root.len() / 3;
        if shard.offsets.first() != Some(&0) || shard.offsets.last() != Some(&frames) {
            bail!("clip_offsets do not span the shard's {frames} frames");
        }
        Ok(shard)
    }

    /// Where each sequence starts, and the frame count last: sequence `s` is frames
    /// `offsets[s]..offsets[s + 1]` (checked on parsing to span the shard).
    pub fn offsets(&self) -> &[usize] {
        &self.offsets
    }

    /// The shard's `imuflow` metadata (clip names, augmentation per sequence), when present.
    pub fn metadata(&self) -> Option<&serde_json::Value> {
        self.metadata.as_ref()
    }

    /// Frame `f`'s sensors in the networks' order.
    pub fn imu(&self, f: usize) -> ImuInput {
        let n = self.order.len();
        let mut imu = ImuInput::of(self.order);
        for i in 0..n {
            let c = self.column[i];
            let o = f * 9 * n + c * 9;
            imu.orientation[i].copy_from_slice(&self.orientation[o..o + 9]);
            let v = f * 3 * n + c * 3;
            imu.acceleration[i].copy_from_slice(&self.accel[v..v + 3]);
            imu.angular_velocity[i].copy_from_slice(&self.gyro[v..v + 3]);
        }
        imu
    }

    fn local(&self, f: usize, j: usize) -> Mat3 {
        let o = f * 216 + j * 9;
        let mut m = [0.0; 9];
        m.copy_from_slice(&self.pose[o..o + 9]);
        m
    }

    fn joint(&self, f: usize, j: usize) -> [f32; 3] {
        let o = f * 72 + j * 3;
        [self.joints[o], self.joints[o + 1], self.joints[o + 2]]
    }

    /// Global joint rotations (true pose).
    fn globals(&self, f: usize) -> [Mat3; NUM_JOINTS] {
        let mut g = [[0.0; 9]; NUM_JOINTS];
        for joint in JointId::all() {
            let j = joint.index();
            g[j] = match joint.parent() {
                None => self.local(f, j),
                Some(p) => mul(&g[p.index()], &self.local(f, j)),
            };
        }
        g
    }
}

struct Builder {
    method: Method,
    /// The sensors of the inputs, in the networks' order.
    order: InputOrder,
    /// The body model's tables, for the sequences synthesized on other statures.
    params: BodyParams,
    body: BodyModel,
    /// The body of the sequence being pushed when it is not `body` (its stature, its model).
    resized: Option<(f64, BodyModel)>,
    arrays: BTreeMap<&'static str, Array>,
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// First two columns of a row-major rotation: [R00, R10, R20, R01, R11, R21] (reference §0).
pub fn r6d(m: &Mat3) -> [f32; 6] {
    [m[0], m[3], m[6], m[1], m[4], m[7]]
}

/// Rotation taking unit vector `a` onto unit vector `b` (row-major), the shortest arc.
pub fn from_to(a: [f32; 3], b: [f32; 3]) -> Mat3 {
    let ra = Vector3::new(a[0] as f64, a[1] as f64, a[2] as f64);
    let rb = Vector3::new(b[0] as f64, b[1] as f64, b[2] as f64);
    let r = Rotation3::rotation_between(&ra, &rb).unwrap_or_else(|| {
        // Opposite vectors: half a turn about any perpendicular axis.
        let axis = ra
            .cross(&Vector3::x())
            .try_normalize(1e-9)
            .unwrap_or(Vector3::z());
        Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), std::f64::consts::PI)
    });
    let m = r.matrix();
    let mut out = [0.0; 9];
    for rr in 0..3 {
        for c in 0..3 {
            out[rr * 3 + c] = m[(rr, c)] as f32;
        }
    }
    out
}

impl Builder {
    fn new(method: Method, order: InputOrder) -> anyhow::Result<Builder> {
        if !method.takes(&order) {
            bail!(
                "{}'s networks take the six-site set only; the shards hold ({}) (PIP's networks \
                 train for any set with the pelvis)",
                method.name(),
                order.mask().names()
            );
        }
        let params = BodyParams::builtin().context("built-in body model")?;
        // The dataset builder's subject (tools/dataset/README.md: 1.75 m, 70 kg).
        let body = BodyModel::new(&params, 1.75, 70.0).context("body model")?;
        let dims: &[(&'static str, usize)] = match method {
            Method::Pip => &[
                ("imu", pip_input_len(order.len())),
                ("leaf", 3 * (order.len() - 1)),
                ("full", 69),
                ("r6d", 90),
                ("vel", 72),
                ("contact", 2),
            ],
            Method::GlobalPose => &[
                ("gp_imu", GLOBALPOSE_INPUT),
                ("pl", 18),
                ("prb", 15),
                ("grav", 3),
                ("rrb_true", 45),
                ("ik1", 72),
                ("full", 69),
                ("r6d", 90),
                ("rrj", 135),
                ("arb_true", 18),
                ("wrb_true", 18),
                ("vr", 9),
            ],
        };
        let arrays = dims.iter().map(|&(n, d)| (n, Array::new(d))).collect();
        Ok(Builder {
            method,
            order,
            params,
            body,
            resized: None,
            arrays,
        })
    }

    /// Room for exactly `frames` more frames in every array.
    fn reserve(&mut self, frames: usize) {
        for a in self.arrays.values_mut() {
            a.data.reserve_exact(frames * a.dim);
        }
    }

    fn put(&mut self, name: &'static str, values: &[f32]) {
        let a = self
            .arrays
            .get_mut(name)
            .expect("array declared in Builder::new");
        debug_assert_eq!(values.len(), a.dim, "{name}");
        a.data.extend_from_slice(values);
    }

    /// The body a sequence was synthesized on: the dataset's subject, or one of `stature_m`
    /// (mass does not matter here).
    fn use_body(&mut self, stature_m: Option<f64>) -> anyhow::Result<()> {
        match stature_m {
            Some(s) if (s - self.body.stature_m).abs() > 1e-9 => {
                if self.resized.as_ref().is_none_or(|(r, _)| *r != s) {
                    let body = BodyModel::new(&self.params, s, self.body.mass_kg)
                        .with_context(|| format!("body model of stature {s} m"))?;
                    self.resized = Some((s, body));
                }
            }
            _ => self.resized = None,
        }
        Ok(())
    }

    fn push_sequence(
        &mut self,
        shard: &Shard,
        start: usize,
        end: usize,
        stature_m: Option<f64>,
    ) -> anyhow::Result<()> {
        self.use_body(stature_m)?;
        let mut fk = FkData::new();
        let mut imu_pos = [Vector3::zeros(); 6];
        let leaf_joints = self.order.leaf_joints();
        for f in start..end {
            let g = shard.globals(f);
            let root = g[0];
            let p_root = shard.joint(f, 0);
            let rel = |j: usize| rt_mul_vec(&root, &sub(shard.joint(f, j), p_root));
            // Finite differences within the sequence: frame `start` uses the first step forward.
            let (fa, fb) = if f == start { (f, f + 1) } else { (f - 1, f) };
            let world_vel = |j: usize| {
                let d = sub(shard.joint(fb, j), shard.joint(fa, j));
                [d[0] * FPS, d[1] * FPS, d[2] * FPS]
            };
            let still = |j: usize| {
                let d = sub(shard.joint(fb, j), shard.joint(fa, j));
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if n < CONTACT_THRESHOLD_M { 1.0 } else { 0.0 }
            };
            let imu = shard.imu(f);
            let full: Vec<f32> = FULL_JOINTS.iter().flat_map(|j| rel(j.index())).collect();
            let r6: Vec<f32> = REDUCED_JOINTS
                .iter()
                .flat_map(|j| r6d(&rt_mul(&root, &g[j.index()])))
                .collect();
            match self.method {
                Method::Pip => {
                    let mut x = vec![0.0; pip_input_len(imu.order.len())];
                    pip_input(&imu, &mut x);
                    self.put("imu", &x);
                    let leaf: Vec<f32> = leaf_joints.iter().flat_map(|j| rel(j.index())).collect();
                    self.put("leaf", &leaf);
                    self.put("full", &full);
                    self.put("r6d", &r6);
                    let vel: Vec<f32> = (0..NUM_JOINTS)
                        .flat_map(|j| {
                            rt_mul_vec(&root, &world_vel(j)).map(|v| v / PIP_VELOCITY_SCALE)
                        })
                        .collect();
                    self.put("vel", &vel);
                    self.put(
                        "contact",
                        &[
                            still(JointId::LEFT_FOOT.index()),
                            still(JointId::RIGHT_FOOT.index()),
                        ],
                    );
                }
                Method::GlobalPose => {
                    let mut x = [0.0; GLOBALPOSE_INPUT];
                    globalpose_input(&imu, &mut x);
                    self.put("gp_imu", &x);
                    // True down-vector in the true root frame: the gravity target (reference §2.4).
                    let g_true = [-root[3], -root[4], -root[5]];
                    // IMU positions from the true pose on the sequence's body model.
                    let pose = pose_of(shard, f);
                    let body = self.resized.as_ref().map_or(&self.body, |(_, b)| b);
                    forward_kinematics(&body.skeleton, &pose, &mut fk);
                    imu_positions_in_world(body, &fk, &mut imu_pos);
                    let p5 = imu_pos[ROOT_IMU];
                    let prb: Vec<f32> = (0..5)
                        .flat_map(|i| {
                            let d = imu_pos[i] - p5;
                            rt_mul_vec(&root, &[d.x as f32, d.y as f32, d.z as f32])
                        })
                        .collect();
                    self.put("prb", &prb);
                    let mut pl = prb.clone();
                    pl.extend_from_slice(&g_true);
                    self.put("pl", &pl);
                    self.put("grav", &g_true);
                    // IMU-relative orientations, tilt-corrected onto the true gravity as PL's refined
                    // gravity would do (reference §2.4: RRB ← FromTo(gR0 → gR1)·RRB).
                    let r_imu = imu.orientation[ROOT_IMU];
                    let g0 = [-r_imu[3], -r_imu[4], -r_imu[5]];
                    let tilt = from_to(g0, g_true);
                    let rrb: Vec<f32> = (0..5)
                        .flat_map(|i| mul(&tilt, &rt_mul(&r_imu, &imu.orientation[i])))
                        .collect();
                    self.put("rrb_true", &rrb);
                    let mut ik1 = full.clone();
                    ik1.extend_from_slice(&g_true);
                    self.put("ik1", &ik1);
                    self.put("full", &full);
                    self.put("r6d", &r6);
                    let rrj: Vec<f32> = REDUCED_JOINTS
                        .iter()
                        .flat_map(|j| rt_mul(&root, &g[j.index()]))
                        .collect();
                    self.put("rrj", &rrj);
                    let arb: Vec<f32> = (0..6)
                        .flat_map(|i| rt_mul_vec(&root, &imu.acceleration[i]))
                        .collect();
                    let wrb: Vec<f32> = (0..6)
                        .flat_map(|i| rt_mul_vec(&root, &imu.angular_velocity[i]))
                        .collect();
                    self.put("arb_true", &arb);
                    self.put("wrb_true", &wrb);
                    // OV target (reference §2.4): world vertical root speed, horizontal root velocity
                    // in the root frame, stationary labels of the contact joints.
                    let v = world_vel(0);
                    let vh = rt_mul_vec(&root, &[v[0], 0.0, v[2]]);
                    let mut vr = vec![v[1], vh[0], vh[1], vh[2]];
                    vr.extend(CONTACT_JOINTS.iter().map(|j| still(j.index())));
                    self.put("vr", &vr);
                }
            }
        }
        Ok(())
    }
}

pub fn pose_of(shard: &Shard, f: usize) -> Pose {
    let root = shard.root[f * 3..f * 3 + 3]
        .iter()
        .map(|&v| v as f64)
        .collect::<Vec<_>>();
    let mut pose = Pose::t_pose(Vector3::new(root[0], root[1], root[2]));
    for j in 0..NUM_JOINTS {
        let m = shard.local(f, j);
        let mat = nalgebra::Matrix3::from_row_slice(&m.map(|v| v as f64));
        pose.parent_from_joint[j] = Rotation3::from_matrix_unchecked(mat);
    }
    pose
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A shard's bytes with no tensors and `sensors` (JSON) in its metadata: what `Shard::parse`
    /// reads before any tensor.
    fn shard_naming(sensors: &str) -> Vec<u8> {
        let meta = std::collections::HashMap::from([(
            "imuflow".to_owned(),
            format!(r#"{{"sensors": {sensors}}}"#),
        )]);
        let none: Vec<(&str, safetensors::tensor::TensorView)> = Vec::new();
        safetensors::serialize(none, Some(meta)).expect("serializes")
    }

    fn refusal(sensors: &str) -> String {
        let bytes = shard_naming(sensors);
        match Shard::parse(&bytes) {
            Ok(_) => panic!("{sensors} parsed"),
            Err(e) => format!("{e:#}"),
        }
    }

    #[test]
    fn a_shard_naming_no_site_of_the_body_or_no_pelvis_is_refused_naming_it() {
        let err = refusal(r#"["pelvis", "left_upper_leg", "tail"]"#);
        assert!(err.contains("names 'tail', not a site"), "{err}");
        let err = refusal(r#"["left_upper_leg", "right_upper_leg"]"#);
        assert!(
            err.contains("(left_upper_leg, right_upper_leg) lack the pelvis"),
            "{err}"
        );
        let err = refusal(r#""pelvis""#);
        assert!(err.contains("is not a list of sites"), "{err}");
    }
}
