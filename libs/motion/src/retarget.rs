//! Retargeting BVH motion onto the 24-joint body, resampling, and BVH export of 24-joint motion.
//!
//! Retargeting transfers GLOBAL bone orientations relative to each skeleton's rest pose. The source's
//! rest (OFFSET) pose need not be a T-pose: for every mapped joint i with source joint s, the rest
//! alignment Q_i is a rotation taking the target bone direction (towards its next mapped descendant in
//! the T-pose) to the source bone direction (same descendant, in the source's rest pose, expressed in
//! M). The target's global rotation is then `world_from_joint[i] = A·G_s·Aᵀ · Q_i`, where
//! G_s is the source joint's global rotation and A turns the source axes into M. A source bone in its
//! rest direction thus gives the T-pose direction (identity = T-pose as in SMPL). Bones without a
//! direction (leaves) inherit the alignment of their nearest mapped ancestor. Target joints the source
//! lacks get an identity local rotation. The root translation is scaled by the ratio of leg lengths.
//!
//! Bone directions leave the roll (twist) about each bone open: Q_i = F_i·Rot(d_i, twist_i) with F_i the
//! shortest arc and twist_i from the mapping's `[twist_deg]` table (0 by default). Skeletons whose joint
//! frames are rolled or mirrored relative to the T-pose (Bandai Namco's are) need those twists; positions
//! do not depend on them, local rotations and IMU orientations do. [`estimate_twists_deg`] measures them
//! from a clip of ordinary motion, once per source skeleton.
//!
//! Bone directions are a poor guide where the source's bones do not run where the body model's do (an
//! iClone spine's short joints zigzag, so each spine bone copied by direction bends ours): the mapping's
//! `[rest_deg]` table turns such a joint's rest alignment further, Q_i = F_i·Rot(d_i, twist_i)·C_i, by the
//! rotation that makes the source's T-pose the body model's identity there.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Rotation3, Unit, Vector3};
use serde::Deserialize;

use crate::bvh::{Bvh, BvhJoint, Channel};
use imuflow_body::body_model::BodyModel;
use imuflow_body::kinematics::{FkData, Pose, forward_kinematics, global_to_local_rotations};
use imuflow_body::rotation::{euler_xyz_from_rotation, from_to, rotation_from_axis_angle, slerp};
use imuflow_body::skeleton::{ALL_JOINTS, JointId, NUM_JOINTS, cut_bone_end, joint_tree};

/// Length unit of a source file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
pub enum LengthUnit {
    /// Centimetres (Bandai Namco, CMU).
    #[serde(rename = "cm")]
    Centimetre,
    /// Metres.
    #[serde(rename = "m")]
    Metre,
}

impl LengthUnit {
    /// Metres per file unit.
    pub fn metres_per_unit(self) -> f64 {
        match self {
            LengthUnit::Centimetre => 0.01,
            LengthUnit::Metre => 1.0,
        }
    }
}

/// Up axis of a source file. Both assume the subject faces +z at rest in Y-up files; Z-up files are
/// turned into M with the AMASS alignment `A = [[1,0,0],[0,0,1],[0,−1,0]]` (reference §3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
pub enum UpAxis {
    #[serde(rename = "y")]
    Y,
    #[serde(rename = "z")]
    Z,
}

impl UpAxis {
    /// Rotation `model_from_source` taking source axes into the model frame M.
    pub fn model_from_source(self) -> Rotation3<f64> {
        match self {
            UpAxis::Y => Rotation3::identity(),
            UpAxis::Z => Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0,
            )),
        }
    }
}

/// How a source skeleton maps onto the 24 joints: units, axes and joint names.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceSkeleton {
    /// Where the mapping came from (file name or "built-in ..."), for error messages.
    pub origin: String,
    /// Length unit of the BVH files.
    pub unit: LengthUnit,
    /// Up axis of the BVH files.
    pub up: UpAxis,
    /// Source joint name for each mapped target joint, with the mapping file line (0 if built in).
    pub joints: BTreeMap<JointId, (String, usize)>,
    /// Source joints deliberately left unmapped (their rotations still move their children).
    pub ignore: Vec<String>,
    /// Extra rotation (degrees) about each target bone applied to the rest alignment, resolving the twist
    /// that bone directions alone leave open (see [`estimate_twists_deg`]). Missing joints: 0.
    pub twist_deg: BTreeMap<JointId, f64>,
    /// Extra rotation of a target joint's rest alignment after its bone direction and twist, as a
    /// rotation vector in degrees (body model axes at the T-pose), for rigs whose bones do not run where
    /// the body model's do: a spine whose short joints zigzag would otherwise be copied bone by bone
    /// into a bent spine. Turning a joint by its measured rest rotation makes the rig's T-pose the
    /// body model's identity there. Joints not listed: no turn.
    pub rest_deg: BTreeMap<JointId, Vector3<f64>>,
    /// Frames dropped from the start of every clip before retargeting: a pose a converter prepended
    /// (a T-pose) is not motion, and the jump from it to the first real frame would be synthesized
    /// into impossible accelerations.
    pub skip_frames: usize,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingFile {
    unit: LengthUnit,
    up: UpAxis,
    #[serde(default)]
    ignore: Vec<String>,
    joints: BTreeMap<toml::Spanned<String>, String>,
    #[serde(default)]
    twist_deg: BTreeMap<toml::Spanned<String>, f64>,
    #[serde(default)]
    rest_deg: BTreeMap<toml::Spanned<String>, [f64; 3]>,
    #[serde(default)]
    skip_frames: usize,
}

/// Failure to load a joint-mapping file.
#[derive(Debug, thiserror::Error)]
pub enum MappingError {
    /// The file could not be read.
    #[error("cannot read joint mapping '{file}': {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    /// Invalid TOML, or a missing/unknown key; `detail` names the line and key.
    #[error("joint mapping '{file}': {detail}")]
    Parse { file: String, detail: String },
    /// A key under `[joints]` that is not one of the 24 target joint names.
    #[error(
        "joint mapping '{file}':{line}: unknown target joint '{joint}' (expected one of pelvis, left_hip, ..., right_hand)"
    )]
    UnknownTargetJoint {
        file: String,
        line: usize,
        joint: String,
    },
    /// A `[twist_deg]` value that is not a finite number of degrees.
    #[error(
        "joint mapping '{file}':{line}: twist_deg.{joint} must be a finite number of degrees (got {value})"
    )]
    InvalidTwist {
        file: String,
        line: usize,
        joint: JointId,
        value: f64,
    },
    /// A `[rest_deg]` value with a component that is not a finite number of degrees.
    #[error(
        "joint mapping '{file}':{line}: rest_deg.{joint} must be three finite numbers of degrees (got {value:?})"
    )]
    InvalidRest {
        file: String,
        line: usize,
        joint: JointId,
        value: [f64; 3],
    },
}

/// Failure to retarget a BVH onto the body.
#[derive(Debug, thiserror::Error)]
pub enum RetargetError {
    /// The BVH has a joint that the mapping neither maps nor ignores. Fix: add it to `[joints]` or `ignore`.
    #[error(
        "{file}:{line}: joint '{joint}' is not in the joint mapping '{mapping}' (map it or list it under `ignore`)"
    )]
    UnmappedSourceJoint {
        file: String,
        line: usize,
        joint: String,
        mapping: String,
    },
    /// The mapping names a source joint the BVH does not have.
    #[error(
        "{mapping}:{line}: source joint '{joint}' (for target '{target}') does not exist in '{file}'"
    )]
    MissingSourceJoint {
        file: String,
        mapping: String,
        line: usize,
        joint: String,
        target: JointId,
    },
    /// A joint required for retargeting is not mapped.
    #[error("joint mapping '{mapping}': target joint '{target}' must be mapped ({why})")]
    RequiredJointUnmapped {
        mapping: String,
        target: JointId,
        why: &'static str,
    },
    /// Mapped joints whose source joints are not in the same ancestor order as the targets.
    #[error(
        "{file}:{line}: source joint '{joint}' (mapped to '{target}') is not a descendant of '{ancestor}' (mapped to '{target_ancestor}')"
    )]
    InconsistentHierarchy {
        file: String,
        line: usize,
        joint: String,
        target: JointId,
        ancestor: String,
        target_ancestor: JointId,
    },
    /// The source legs have zero length, so the translation scale is undefined.
    #[error("{file}: source leg length is zero; cannot scale the root translation")]
    DegenerateLegs { file: String },
    /// The BVH has no frames, or none left after the mapping's `skip_frames`.
    #[error("{file}: no frames to retarget ({frames} in the file, the mapping skips {skipped})")]
    NoFrames {
        file: String,
        frames: usize,
        skipped: usize,
    },
}

/// Built-in mapping of the Bandai Namco Research motion dataset skeleton (22 joints, ZXY rotations,
/// centimetres, Y up), from `libs/motion/mappings/bandai-namco.toml`, which documents the format.
/// `joint_Root` is a static parent of `Hips` and is ignored. SMPL's spine2 and the hand-end joints have
/// no counterpart and get identity local rotations.
pub const BANDAI_NAMCO_MAPPING_TOML: &str = include_str!("../mappings/bandai-namco.toml");

impl SourceSkeleton {
    /// Parse a mapping TOML (see [`BANDAI_NAMCO_MAPPING_TOML`] for the format); `file` names it in errors.
    pub fn from_toml_str(text: &str, file: &str) -> Result<SourceSkeleton, MappingError> {
        let raw: MappingFile = toml::from_str(text).map_err(|e| MappingError::Parse {
            file: file.to_owned(),
            detail: e.to_string(),
        })?;
        // A key of either table names one of our joints; errors point at its line.
        let target_joint = |key: toml::Spanned<String>| {
            let line = line_of(text, key.span().start);
            match JointId::from_name(key.get_ref()) {
                Some(target) => Ok((target, line)),
                None => Err(MappingError::UnknownTargetJoint {
                    file: file.to_owned(),
                    line,
                    joint: key.into_inner(),
                }),
            }
        };
        let mut joints = BTreeMap::new();
        for (key, source) in raw.joints {
            let (target, line) = target_joint(key)?;
            joints.insert(target, (source, line));
        }
        let mut twist_deg = BTreeMap::new();
        for (key, deg) in raw.twist_deg {
            let (target, line) = target_joint(key)?;
            if !deg.is_finite() {
                return Err(MappingError::InvalidTwist {
                    file: file.to_owned(),
                    line,
                    joint: target,
                    value: deg,
                });
            }
            twist_deg.insert(target, deg);
        }
        let mut rest_deg = BTreeMap::new();
        for (key, deg) in raw.rest_deg {
            let (target, line) = target_joint(key)?;
            if !deg.iter().all(|d| d.is_finite()) {
                return Err(MappingError::InvalidRest {
                    file: file.to_owned(),
                    line,
                    joint: target,
                    value: deg,
                });
            }
            rest_deg.insert(target, Vector3::from(deg));
        }
        Ok(SourceSkeleton {
            origin: file.to_owned(),
            unit: raw.unit,
            up: raw.up,
            joints,
            ignore: raw.ignore,
            twist_deg,
            rest_deg,
            skip_frames: raw.skip_frames,
        })
    }

    /// Read a mapping TOML file.
    pub fn load(path: &Path) -> Result<SourceSkeleton, MappingError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| MappingError::Io {
            file: file.clone(),
            source,
        })?;
        SourceSkeleton::from_toml_str(&text, &file)
    }

    /// The Bandai Namco mapping ([`BANDAI_NAMCO_MAPPING_TOML`]).
    pub fn bandai_namco() -> Result<SourceSkeleton, MappingError> {
        SourceSkeleton::from_toml_str(BANDAI_NAMCO_MAPPING_TOML, "built-in Bandai Namco mapping")
    }

    /// imuflow's own skeleton as written by [`bvh_from_clip`]: every joint maps to its own name.
    pub fn imuflow(unit: LengthUnit) -> SourceSkeleton {
        SourceSkeleton {
            origin: "built-in imuflow mapping".to_owned(),
            unit,
            up: UpAxis::Y,
            joints: JointId::all()
                .map(|j| (j, (j.name().to_owned(), 0)))
                .collect(),
            ignore: Vec::new(),
            twist_deg: BTreeMap::new(),
            rest_deg: BTreeMap::new(),
            skip_frames: 0,
        }
    }
}

fn line_of(text: &str, byte: usize) -> usize {
    text.get(..byte).map_or(0, |t| t.matches('\n').count()) + 1
}

/// A sequence of 24-joint poses at a fixed rate.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionClip {
    /// Seconds between frames.
    pub frame_time_s: f64,
    /// One pose per frame.
    pub poses: Vec<Pose>,
}

impl MotionClip {
    /// Frame rate (Hz).
    pub fn rate_hz(&self) -> f64 {
        1.0 / self.frame_time_s
    }
}

/// Where to put the floor after retargeting.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FloorAlignment {
    /// Keep the source's heights (scaled): the source floor y = 0 stays at y = 0.
    Keep,
    /// Shift vertically so the median over frames of the lower foot joint's height is 0. Robust for
    /// clips that stand or walk on a flat floor (one foot is down in most frames).
    #[default]
    MedianLowestFoot,
}

/// Options of [`retarget_bvh`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RetargetOptions {
    /// Vertical placement of the result.
    pub floor: FloorAlignment,
}

/// Retarget every frame of `bvh` (but the mapping's first `skip_frames`) onto `body`'s skeleton through
/// `source`'s mapping. The clip keeps the BVH's frame rate (see [`resample`]).
pub fn retarget_bvh(
    bvh: &Bvh,
    source: &SourceSkeleton,
    body: &BodyModel,
    options: &RetargetOptions,
) -> Result<MotionClip, RetargetError> {
    let plan = Plan::new(bvh, source, body)?;
    let frames = motion_frames(bvh, source)?;
    let n = bvh.joints.len();
    let mut rot = vec![Rotation3::identity(); n];
    let mut pos = vec![Vector3::zeros(); n];
    let mut world = [Rotation3::identity(); NUM_JOINTS];
    let mut poses = Vec::with_capacity(frames.len());
    let a = plan.model_from_source;
    for f in frames {
        let Some(frame) = bvh.frame(f) else { break };
        bvh.global_transforms(frame, &mut rot, &mut pos);
        for j in JointId::all() {
            let i = j.index();
            world[i] = match (plan.source_of[i], j.parent()) {
                (Some(s), _) => a * rot[s] * a.transpose() * plan.rest_alignment[i],
                (None, Some(p)) => world[p.index()],
                (None, None) => Rotation3::identity(),
            };
        }
        let mut pose = Pose::default();
        global_to_local_rotations(&world, &mut pose.parent_from_joint);
        pose.root_in_world_m = a * pos[plan.root_source] * plan.translation_scale;
        poses.push(pose);
    }
    let mut clip = MotionClip {
        frame_time_s: bvh.frame_time_s,
        poses,
    };
    if options.floor == FloorAlignment::MedianLowestFoot {
        let lift = -median_lowest_foot_height(body, &clip);
        for p in &mut clip.poses {
            p.root_in_world_m.y += lift;
        }
    }
    Ok(clip)
}

/// The frames of `bvh` that hold motion: all but the mapping's first `skip_frames`, never none.
fn motion_frames(
    bvh: &Bvh,
    source: &SourceSkeleton,
) -> Result<std::ops::Range<usize>, RetargetError> {
    let frames = bvh.num_frames();
    if frames <= source.skip_frames {
        return Err(RetargetError::NoFrames {
            file: bvh.file.clone(),
            frames,
            skipped: source.skip_frames,
        });
    }
    Ok(source.skip_frames..frames)
}

/// Median over frames of min(left foot, right foot) joint height (m).
pub fn median_lowest_foot_height(body: &BodyModel, clip: &MotionClip) -> f64 {
    let mut fk = FkData::new();
    let mut lows: Vec<f64> = clip
        .poses
        .iter()
        .map(|p| {
            forward_kinematics(&body.skeleton, p, &mut fk);
            fk.position(JointId::LEFT_FOOT)
                .y
                .min(fk.position(JointId::RIGHT_FOOT).y)
        })
        .collect();
    if lows.is_empty() {
        return 0.0;
    }
    lows.sort_by(f64::total_cmp);
    lows[lows.len() / 2]
}

/// Shortest rotation F_i (target rest bone direction -> source's, in M) and the unit target bone axis.
type OwnAlignment = (Rotation3<f64>, Unit<Vector3<f64>>);

/// Precomputed, frame-independent part of a retargeting.
struct Plan {
    model_from_source: Rotation3<f64>,
    /// Source joint index for each target joint.
    source_of: [Option<usize>; NUM_JOINTS],
    /// For joints with their own bone direction: the shortest rotation F_i taking the target rest bone
    /// direction to the source's (in M), and the target bone axis.
    own_alignment: [Option<OwnAlignment>; NUM_JOINTS],
    /// The mapping's `[rest_deg]` rotations C_i (identity where it has none).
    rest_turn: [Rotation3<f64>; NUM_JOINTS],
    /// Q_i = F_i · twist_i · C_i (or the parent's Q · C_i for joints without a direction).
    rest_alignment: [Rotation3<f64>; NUM_JOINTS],
    root_source: usize,
    /// Source file units -> target metres, including the leg-length ratio.
    translation_scale: f64,
}

impl Plan {
    fn new(bvh: &Bvh, source: &SourceSkeleton, body: &BodyModel) -> Result<Plan, RetargetError> {
        // Every source joint is mapped or ignored.
        for j in &bvh.joints {
            let mapped = source.joints.values().any(|(s, _)| *s == j.name);
            if !mapped && !source.ignore.contains(&j.name) {
                return Err(RetargetError::UnmappedSourceJoint {
                    file: bvh.file.clone(),
                    line: j.line,
                    joint: j.name.clone(),
                    mapping: source.origin.clone(),
                });
            }
        }
        let mut source_of = [None; NUM_JOINTS];
        for (target, (name, line)) in &source.joints {
            let idx = bvh
                .joint_index(name)
                .ok_or_else(|| RetargetError::MissingSourceJoint {
                    file: bvh.file.clone(),
                    mapping: source.origin.clone(),
                    line: *line,
                    joint: name.clone(),
                    target: *target,
                })?;
            source_of[target.index()] = Some(idx);
        }
        let required = |t: JointId, why: &'static str| {
            source_of[t.index()].ok_or_else(|| RetargetError::RequiredJointUnmapped {
                mapping: source.origin.clone(),
                target: t,
                why,
            })
        };
        let root_source = required(JointId::PELVIS, "it carries the root translation")?;
        let why_leg = "its leg length scales the translation";
        let (s_hip, s_knee, s_ankle) = (
            required(JointId::LEFT_HIP, why_leg)?,
            required(JointId::LEFT_KNEE, why_leg)?,
            required(JointId::LEFT_ANKLE, why_leg)?,
        );
        // Mapped targets must keep their ancestor order in the source.
        for j in JointId::all() {
            let Some(s) = source_of[j.index()] else {
                continue;
            };
            let mut a = j.parent();
            while let Some(t) = a {
                if let Some(sa) = source_of[t.index()] {
                    if !is_source_descendant(&bvh.joints, s, sa) {
                        return Err(RetargetError::InconsistentHierarchy {
                            file: bvh.file.clone(),
                            line: bvh.joints[s].line,
                            joint: bvh.joints[s].name.clone(),
                            target: j,
                            ancestor: bvh.joints[sa].name.clone(),
                            target_ancestor: t,
                        });
                    }
                    break;
                }
                a = t.parent();
            }
        }

        let a = source.up.model_from_source();
        let u = source.unit.metres_per_unit();
        let source_rest: Vec<Vector3<f64>> =
            bvh.rest_positions().iter().map(|p| a * p * u).collect();
        let target_rest = body.skeleton.rest_positions_from_root_m();

        let mut own_alignment = [None; NUM_JOINTS];
        for j in JointId::all() {
            let i = j.index();
            let Some(s) = source_of[i] else { continue };
            let mut c = chain_child(j);
            while let Some(k) = c {
                if source_of[k.index()].is_some() {
                    break;
                }
                c = chain_child(k);
            }
            own_alignment[i] = c.and_then(|c| {
                let sc = source_of[c.index()]?;
                let d_t = Unit::try_new(target_rest[c.index()] - target_rest[i], 1e-9)?;
                let d_s = Unit::try_new(source_rest[sc] - source_rest[s], 1e-9)?;
                Some((from_to(&d_t, &d_s), d_t))
            });
        }
        let twist_rad = |j: JointId| {
            source
                .twist_deg
                .get(&j)
                .copied()
                .unwrap_or(0.0)
                .to_radians()
        };
        let mut rest_turn = [Rotation3::identity(); NUM_JOINTS];
        for (j, deg) in &source.rest_deg {
            rest_turn[j.index()] = rotation_from_axis_angle(&deg.map(f64::to_radians));
        }
        let rest_alignment = alignments(&own_alignment, twist_rad, &rest_turn);

        let source_leg = (source_rest[s_knee] - source_rest[s_hip]).norm()
            + (source_rest[s_ankle] - source_rest[s_knee]).norm();
        if !(source_leg.is_finite() && source_leg > 1e-9) {
            return Err(RetargetError::DegenerateLegs {
                file: bvh.file.clone(),
            });
        }
        Ok(Plan {
            model_from_source: a,
            source_of,
            own_alignment,
            rest_turn,
            rest_alignment,
            root_source,
            translation_scale: u * body.leg_length_m() / source_leg,
        })
    }
}

/// Q_i = F_i · Rot(axis_i, twist_i) · C_i for joints with their own direction, else the parent's
/// Q · C_i.
fn alignments(
    own: &[Option<OwnAlignment>; NUM_JOINTS],
    twist_rad: impl Fn(JointId) -> f64,
    rest_turn: &[Rotation3<f64>; NUM_JOINTS],
) -> [Rotation3<f64>; NUM_JOINTS] {
    let mut q = [Rotation3::identity(); NUM_JOINTS];
    for j in JointId::all() {
        let i = j.index();
        let base = match &own[i] {
            Some((f, axis)) => f * Rotation3::from_axis_angle(axis, twist_rad(j)),
            None => j.parent().map_or(Rotation3::identity(), |p| q[p.index()]),
        };
        q[i] = base * rest_turn[i];
    }
    q
}

/// Estimate, for every non-root joint with a bone direction, the twist (degrees) about the target bone
/// that makes the retargeted local rotations of `bvh` closest to identity on average (maximizes
/// Σ_frames trace(R_local), closed form `θ = atan2(Σ tr(M·[d]×), Σ (tr M − dᵀMd))` for M the local rotation
/// without twist and d the bone axis; with the mapping's rest rotation C, M is C times it), joint by joint
/// from the root down. Ignores `source.twist_deg`; keeps `source.rest_deg`.
///
/// Meant for building a mapping file once per source skeleton from a clip of ordinary motion (walking),
/// not for per-clip use: skeletons with mirrored or rolled joint frames show twists near multiples of 90°.
pub fn estimate_twists_deg(
    bvh: &Bvh,
    source: &SourceSkeleton,
    body: &BodyModel,
) -> Result<BTreeMap<JointId, f64>, RetargetError> {
    let mut untwisted = source.clone();
    untwisted.twist_deg.clear();
    let plan = Plan::new(bvh, &untwisted, body)?;
    let a = plan.model_from_source;
    let n = bvh.joints.len();
    let mut rot = vec![Rotation3::identity(); n];
    let mut pos = vec![Vector3::zeros(); n];
    // Source global rotations in M for the mapped joints, per frame.
    let frames = motion_frames(bvh, source)?;
    let mut source_world: Vec<[Rotation3<f64>; NUM_JOINTS]> = Vec::with_capacity(frames.len());
    for f in frames {
        let Some(frame) = bvh.frame(f) else { break };
        bvh.global_transforms(frame, &mut rot, &mut pos);
        let mut g = [Rotation3::identity(); NUM_JOINTS];
        for (i, s) in plan.source_of.iter().enumerate() {
            if let Some(s) = s {
                g[i] = a * rot[*s] * a.transpose();
            }
        }
        source_world.push(g);
    }
    let mut twists = [0.0; NUM_JOINTS];
    let mut out = BTreeMap::new();
    let mut world = [Rotation3::identity(); NUM_JOINTS];
    for j in JointId::all() {
        let (Some((f, axis)), Some(parent)) = (&plan.own_alignment[j.index()], j.parent()) else {
            continue;
        };
        let q = alignments(&plan.own_alignment, |k| twists[k.index()], &plan.rest_turn);
        let (mut sum_sin, mut sum_cos) = (0.0, 0.0);
        let k = axis.into_inner().cross_matrix();
        for g in &source_world {
            for t in JointId::all() {
                let ti = t.index();
                world[ti] = match (plan.source_of[ti], t.parent()) {
                    (Some(_), _) => g[ti] * q[ti],
                    (None, Some(p)) => world[p.index()],
                    (None, None) => Rotation3::identity(),
                };
            }
            let m = plan.rest_turn[j.index()].matrix()
                * world[parent.index()].transpose().matrix()
                * g[j.index()].matrix()
                * f.matrix();
            sum_sin += (m * k).trace();
            sum_cos += m.trace() - axis.dot(&(m * axis.into_inner()));
        }
        let theta = sum_sin.atan2(sum_cos);
        twists[j.index()] = theta;
        out.insert(j, theta.to_degrees());
    }
    Ok(out)
}

/// The child that continues a joint's main chain (spine over legs/collars), `None` for leaves.
fn chain_child(j: JointId) -> Option<JointId> {
    match j {
        JointId::PELVIS => Some(JointId::SPINE1),
        JointId::SPINE3 => Some(JointId::NECK),
        _ => j.children().next(),
    }
}

fn is_source_descendant(joints: &[BvhJoint], mut j: usize, ancestor: usize) -> bool {
    for _ in 0..=joints.len() {
        if j == ancestor {
            return true;
        }
        match joints.get(j).and_then(|x| x.parent) {
            Some(p) => j = p,
            None => return false,
        }
    }
    false
}

/// Failure to resample a clip.
#[derive(Debug, thiserror::Error)]
pub enum ResampleError {
    /// The requested or the clip's rate is not a positive finite number.
    #[error(
        "resampling needs positive finite rates (clip frame time {frame_time_s} s, target {rate_hz} Hz)"
    )]
    InvalidRate { frame_time_s: f64, rate_hz: f64 },
}

/// Resample to `rate_hz` (imuflow's nominal rate is 60 Hz) over the clip's duration: slerp for rotations,
/// linear interpolation for the root position (as PNP/GlobalPose preprocessing, reference §3).
pub fn resample(clip: &MotionClip, rate_hz: f64) -> Result<MotionClip, ResampleError> {
    let dt_in = clip.frame_time_s;
    if !(rate_hz.is_finite() && rate_hz > 0.0 && dt_in.is_finite() && dt_in > 0.0) {
        return Err(ResampleError::InvalidRate {
            frame_time_s: dt_in,
            rate_hz,
        });
    }
    let dt_out = 1.0 / rate_hz;
    let n_in = clip.poses.len();
    if n_in == 0 {
        return Ok(MotionClip {
            frame_time_s: dt_out,
            poses: Vec::new(),
        });
    }
    let duration = (n_in - 1) as f64 * dt_in;
    // A last output frame within 1e-3 frames of the end is kept (clamped to the last input frame):
    // files store rounded frame times (Bandai: 0.0333333 s), which would otherwise drop it.
    let n_out = (duration / dt_out + 1e-3).floor() as usize + 1;
    let mut poses = Vec::with_capacity(n_out);
    for k in 0..n_out {
        let x = k as f64 * dt_out / dt_in;
        let i0 = (x.floor() as usize).min(n_in - 1);
        let i1 = (i0 + 1).min(n_in - 1);
        let t = (x - i0 as f64).clamp(0.0, 1.0);
        let (p0, p1) = (&clip.poses[i0], &clip.poses[i1]);
        let mut p = Pose::default();
        for j in 0..NUM_JOINTS {
            p.parent_from_joint[j] = slerp(&p0.parent_from_joint[j], &p1.parent_from_joint[j], t);
        }
        p.root_in_world_m = p0.root_in_world_m.lerp(&p1.root_in_world_m, t);
        poses.push(p);
    }
    Ok(MotionClip {
        frame_time_s: dt_out,
        poses,
    })
}

/// BVH of a 24-joint clip on `body`'s skeleton (joint names as [`JointId::name`], intrinsic XYZ Euler
/// channels, offsets and root positions in `unit`), e.g. to inspect results in Blender. Read it back
/// with [`retarget_bvh`] and [`SourceSkeleton::imuflow`].
pub fn bvh_from_clip(
    body: &BodyModel,
    clip: &MotionClip,
    unit: LengthUnit,
    file: &str,
) -> Option<Bvh> {
    bvh_of_joints(body, clip, unit, file, ALL_JOINTS)
}

/// [`bvh_from_clip`] of the joints in `joints` (a mask over joint indices, such as the joints a
/// sensor set observes) and their ancestors' chain only: a joint is written when it and every
/// joint above it are in the mask, the root always. A written joint whose children are all left
/// out ends in an End Site at its first child (the bone it turns keeps its length: a knee's shank
/// reaches the ankle); the skeleton's own leaves end as in [`bvh_from_clip`].
pub fn bvh_of_joints(
    body: &BodyModel,
    clip: &MotionClip,
    unit: LengthUnit,
    file: &str,
    joints: u32,
) -> Option<Bvh> {
    let s = 1.0 / unit.metres_per_unit();
    let rot = [Channel::Xrotation, Channel::Yrotation, Channel::Zrotation];
    let tree = joint_tree(joints);
    let order: Vec<JointId> = depth_first_order()
        .into_iter()
        .filter(|j| tree & (1 << j.index()) != 0)
        .collect();
    let mut position_in_file = [0usize; NUM_JOINTS];
    for (k, j) in order.iter().enumerate() {
        position_in_file[j.index()] = k;
    }
    let bvh_joints: Vec<BvhJoint> = order
        .iter()
        .map(|&j| {
            let mut channels = Vec::new();
            if j.parent().is_none() {
                channels.extend([Channel::Xposition, Channel::Yposition, Channel::Zposition]);
            }
            channels.extend(rot);
            let off = body.skeleton.offset_in_parent_m(j);
            let end_sites = match cut_bone_end(j, tree) {
                // Its children left out: the bone it turns, to the first child's joint.
                Some(child) => vec![body.skeleton.offset_in_parent_m(child) * s],
                // Leaves: head top, or continue the bone by 0.1 m (hands, feet).
                None if j.children().next().is_none() => {
                    let e = if j == JointId::HEAD {
                        Vector3::new(0.0, body.head_top_above_head_joint_m, 0.0)
                    } else {
                        off.try_normalize(1e-12).unwrap_or_else(Vector3::zeros) * 0.1
                    };
                    vec![e * s]
                }
                None => Vec::new(),
            };
            BvhJoint {
                name: j.name().to_owned(),
                parent: j.parent().map(|p| position_in_file[p.index()]),
                offset: off * s,
                channels,
                end_sites,
                line: 0,
            }
        })
        .collect();
    let mut values = Vec::with_capacity(clip.poses.len() * (3 + 3 * order.len()));
    for p in &clip.poses {
        values.extend((p.root_in_world_m * s).iter());
        for j in &order {
            let r = &p.parent_from_joint[j.index()];
            values.extend(euler_xyz_from_rotation(r).map(f64::to_degrees));
        }
    }
    Bvh::from_parts(file, bvh_joints, clip.frame_time_s, values)
}

/// The 24 joints in depth-first order (children in index order), the nesting order BVH files need.
fn depth_first_order() -> [JointId; NUM_JOINTS] {
    let mut out = [JointId::ROOT; NUM_JOINTS];
    let mut stack = vec![JointId::ROOT];
    let mut k = 0;
    while let Some(j) = stack.pop() {
        if let Some(slot) = out.get_mut(k) {
            *slot = j;
        }
        k += 1;
        // Push children in reverse so the lowest index is visited first.
        let children: Vec<JointId> = j.children().collect();
        stack.extend(children.into_iter().rev());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use imuflow_body::body_model::BodyParams;
    use imuflow_body::rotation::{Axis, angle_between};
    use std::f64::consts::FRAC_PI_2;

    /// Z-up, centimetres, rest pose NOT a T-pose: the left arm hangs down (−z). Frame 0 is the rest
    /// pose; frame 1 raises the arm to horizontal-left with Yrotation −90° and bends the knee.
    const A_POSE_Z_UP: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 0 40
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT LeftArm
    {
      OFFSET 18 0 5
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT LeftForeArm
      {
        OFFSET 0 0 -28
        CHANNELS 3 Zrotation Xrotation Yrotation
        End Site
        {
          OFFSET 0 0 -25
        }
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 9 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT LeftLeg
    {
      OFFSET 0 0 -45
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT LeftFoot
      {
        OFFSET 0 0 -45
        CHANNELS 3 Zrotation Xrotation Yrotation
        End Site
        {
          OFFSET 0 -10 -5
        }
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 0 100 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
0 0 100 0 0 0 0 0 0 0 0 -90 0 0 0 0 0 0 0 -30 0 0 0 0
";

    const A_POSE_MAP: &str = r#"
unit = "cm"
up = "z"
[joints]
pelvis = "Hips"
spine3 = "Chest"
left_shoulder = "LeftArm"
left_elbow = "LeftForeArm"
left_hip = "LeftUpLeg"
left_knee = "LeftLeg"
left_ankle = "LeftFoot"
"#;

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.8, 75.0).unwrap()
    }

    #[test]
    fn non_t_pose_rest_and_z_up_are_aligned_to_the_t_pose() {
        let bvh = Bvh::parse(A_POSE_Z_UP, "apose.bvh").unwrap();
        let map = SourceSkeleton::from_toml_str(A_POSE_MAP, "apose.toml").unwrap();
        let body = body();
        let opts = RetargetOptions {
            floor: FloorAlignment::Keep,
        };
        let clip = retarget_bvh(&bvh, &map, &body, &opts).unwrap();
        let id = Rotation3::identity();
        let local = |f: usize, j: JointId| clip.poses[f].parent_from_joint[j.index()];

        // Rest frame: the arm hangs down. In M that is the shortest arc +x -> −y, i.e. −90° about z.
        assert!(
            angle_between(
                &local(0, JointId::LEFT_SHOULDER),
                &Axis::Z.rotation(-FRAC_PI_2)
            ) < 1e-9
        );
        // Frame 1: raised to horizontal-left, which is exactly the T-pose.
        assert!(angle_between(&local(1, JointId::LEFT_SHOULDER), &id) < 1e-9);
        // The forearm follows the arm in both frames (its own rest direction matches the arm's).
        assert!(angle_between(&local(0, JointId::LEFT_ELBOW), &id) < 1e-9);
        assert!(angle_between(&local(1, JointId::LEFT_ELBOW), &id) < 1e-9);
        // Legs and spine stand straight; joints the source lacks are identity.
        for j in [
            JointId::PELVIS,
            JointId::LEFT_HIP,
            JointId::SPINE1,
            JointId::SPINE3,
            JointId::RIGHT_KNEE,
            JointId::HEAD,
        ] {
            assert!(angle_between(&local(0, j), &id) < 1e-9, "{j}");
        }
        // Source knee Xrotation −30° about source x = M x (A keeps x): flexion by −30° about x in M.
        assert!(
            angle_between(
                &local(1, JointId::LEFT_KNEE),
                &Axis::X.rotation(-30f64.to_radians())
            ) < 1e-9
        );
        // Root: source (0, 0, 100) cm, Z-up -> (0, 1 m, 0) in M, scaled by our leg / source leg (0.9 m).
        let scale = body.leg_length_m() / 0.9;
        assert_relative_eq!(
            clip.poses[0].root_in_world_m,
            Vector3::new(0.0, scale, 0.0),
            epsilon = 1e-12
        );
    }

    #[test]
    fn metres_and_centimetres_give_the_same_clip() {
        let cm = Bvh::parse(A_POSE_Z_UP, "cm.bvh").unwrap();
        let mut m = cm.clone();
        for j in &mut m.joints {
            j.offset /= 100.0;
            j.end_sites.iter_mut().for_each(|e| *e /= 100.0);
        }
        for (k, v) in m.values.iter_mut().enumerate() {
            if k % 24 < 3 {
                *v /= 100.0;
            }
        }
        let map_cm = SourceSkeleton::from_toml_str(A_POSE_MAP, "a.toml").unwrap();
        let mut map_m = map_cm.clone();
        map_m.unit = LengthUnit::Metre;
        let body = body();
        let opts = RetargetOptions::default();
        let a = retarget_bvh(&cm, &map_cm, &body, &opts).unwrap();
        let b = retarget_bvh(&m, &map_m, &body, &opts).unwrap();
        for (p, q) in a.poses.iter().zip(&b.poses) {
            assert_relative_eq!(p.root_in_world_m, q.root_in_world_m, epsilon = 1e-12);
        }
    }

    #[test]
    fn mapping_errors_name_file_line_and_key() {
        let bad = A_POSE_MAP.replace("left_knee =", "left_kneee =");
        let e = SourceSkeleton::from_toml_str(&bad, "m.toml").unwrap_err();
        assert!(
            matches!(&e, MappingError::UnknownTargetJoint { line: 10, joint, .. } if joint == "left_kneee"),
            "{e}"
        );
        assert!(
            e.to_string().starts_with("joint mapping 'm.toml':10:"),
            "{e}"
        );

        let e = SourceSkeleton::from_toml_str(&A_POSE_MAP.replace("\"cm\"", "\"inch\""), "u.toml")
            .unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("u.toml") && msg.contains("line 2") && msg.contains("inch"),
            "{msg}"
        );

        let e = SourceSkeleton::from_toml_str(
            &format!("{A_POSE_MAP}[twist_deg]\nleft_knee = nan\n"),
            "t.toml",
        )
        .unwrap_err();
        assert!(
            matches!(e, MappingError::InvalidTwist { line: 13, .. }),
            "{e}"
        );

        let e = SourceSkeleton::load(Path::new("/nonexistent/map.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/map.toml"));
    }

    #[test]
    fn rest_rotations_turn_their_joint_and_leave_the_other_bones_where_they_point() {
        let bvh = Bvh::parse(A_POSE_Z_UP, "apose.bvh").unwrap();
        let plain = SourceSkeleton::from_toml_str(A_POSE_MAP, "a.toml").unwrap();
        let turned = SourceSkeleton::from_toml_str(
            &format!("{A_POSE_MAP}[rest_deg]\npelvis = [0.0, 90.0, 0.0]\n"),
            "t.toml",
        )
        .unwrap();
        let body = body();
        let opts = RetargetOptions {
            floor: FloorAlignment::Keep,
        };
        let a = retarget_bvh(&bvh, &plain, &body, &opts).unwrap();
        let b = retarget_bvh(&bvh, &turned, &body, &opts).unwrap();
        let quarter = Axis::Y.rotation(FRAC_PI_2);
        for (p, q) in a.poses.iter().zip(&b.poses) {
            let mut wa = [Rotation3::identity(); NUM_JOINTS];
            let mut wb = [Rotation3::identity(); NUM_JOINTS];
            imuflow_body::kinematics::local_to_global_rotations(&p.parent_from_joint, &mut wa);
            imuflow_body::kinematics::local_to_global_rotations(&q.parent_from_joint, &mut wb);
            // The pelvis (the root: local = world) is turned by the rest rotation on its right ...
            assert!(angle_between(&wb[0], &(wa[0] * quarter)) < 1e-9);
            // ... and every joint with its own bone direction keeps its world rotation.
            for j in [
                JointId::LEFT_HIP,
                JointId::LEFT_KNEE,
                JointId::LEFT_SHOULDER,
            ] {
                assert!(angle_between(&wb[j.index()], &wa[j.index()]) < 1e-9, "{j}");
            }
            assert_eq!(p.root_in_world_m, q.root_in_world_m);
        }

        let e = SourceSkeleton::from_toml_str(
            &format!("{A_POSE_MAP}[rest_deg]\nneck = [0.0, inf, 0.0]\n"),
            "r.toml",
        )
        .unwrap_err();
        assert!(
            matches!(e, MappingError::InvalidRest { line: 13, .. }),
            "{e}"
        );
        assert!(
            e.to_string().starts_with("joint mapping 'r.toml':13:"),
            "{e}"
        );
        let e = SourceSkeleton::from_toml_str(
            &format!("{A_POSE_MAP}[rest_deg]\nneck = [0.0, 1.0]\n"),
            "r.toml",
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("r.toml") && e.to_string().contains("line 13"),
            "{e}"
        );
    }

    #[test]
    fn retarget_requires_the_root_and_a_leg() {
        let bvh = Bvh::parse(A_POSE_Z_UP, "apose.bvh").unwrap();
        let mut map = SourceSkeleton::from_toml_str(A_POSE_MAP, "a.toml").unwrap();
        map.joints.remove(&JointId::LEFT_KNEE);
        map.ignore.push("LeftLeg".into());
        let e = retarget_bvh(&bvh, &map, &body(), &RetargetOptions::default()).unwrap_err();
        assert!(
            matches!(
                e,
                RetargetError::RequiredJointUnmapped {
                    target: JointId::LEFT_KNEE,
                    ..
                }
            ),
            "{e}"
        );

        // Mapping the knee above the hip breaks the hierarchy.
        let swapped = A_POSE_MAP
            .replace("left_hip = \"LeftUpLeg\"", "left_hip = \"LeftLeg\"")
            .replace("left_knee = \"LeftLeg\"", "left_knee = \"LeftUpLeg\"");
        let map = SourceSkeleton::from_toml_str(&swapped, "s.toml").unwrap();
        let e = retarget_bvh(&bvh, &map, &body(), &RetargetOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("apose.bvh:"), "{e}");
        assert!(
            matches!(e, RetargetError::InconsistentHierarchy { .. }),
            "{e}"
        );
    }

    #[test]
    fn resample_checks_rates_and_keeps_constant_motion() {
        let clip = MotionClip {
            frame_time_s: 1.0 / 30.0,
            poses: vec![Pose::t_pose(Vector3::new(0.0, 1.0, 0.0)); 4],
        };
        assert!(resample(&clip, 0.0).is_err());
        assert!(resample(&clip, f64::NAN).is_err());
        // 3 intervals of 1/30 s at 120 Hz: 12 intervals, 13 frames.
        let up = resample(&clip, 120.0).unwrap();
        assert_eq!(up.poses.len(), 13);
        assert!(up.poses.iter().all(|p| *p == clip.poses[0]));
        // Down-sampling 30 -> 10 Hz keeps every third frame.
        assert_eq!(resample(&clip, 10.0).unwrap().poses.len(), 2);
    }

    #[test]
    fn depth_first_order_nests_children_under_parents() {
        let order = depth_first_order();
        let mut seen = [false; NUM_JOINTS];
        for j in order {
            assert!(j.parent().is_none_or(|p| seen[p.index()]), "{j}");
            seen[j.index()] = true;
        }
        assert!(seen.iter().all(|s| *s));
        assert_eq!(order[1], JointId::LEFT_HIP);
        assert_eq!(order[2], JointId::LEFT_KNEE);
    }

    #[test]
    fn a_bvh_of_some_joints_keeps_their_chain_and_ends_each_cut_bone_at_its_child() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut pose = Pose::default();
        pose.parent_from_joint[JointId::LEFT_KNEE.index()] = Axis::X.rotation(0.5);
        pose.parent_from_joint[JointId::LEFT_ANKLE.index()] = Axis::X.rotation(0.3);
        let clip = MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses: vec![pose],
        };
        // Pelvis, hips and knees (a lower body's); spine1 without its parent's chain is dropped
        // too: the left ankle is not in the mask, and a joint under it never is.
        let mask = [
            JointId::ROOT,
            JointId::LEFT_HIP,
            JointId::RIGHT_HIP,
            JointId::LEFT_KNEE,
            JointId::RIGHT_KNEE,
            JointId::LEFT_FOOT,
        ]
        .iter()
        .fold(0u32, |m, j| m | 1 << j.index());
        let bvh = bvh_of_joints(&body, &clip, LengthUnit::Metre, "legs.bvh", mask).unwrap();
        let names: Vec<&str> = bvh.joints.iter().map(|j| j.name.as_str()).collect();
        assert_eq!(
            names,
            ["pelvis", "left_hip", "left_knee", "right_hip", "right_knee"]
        );
        // The knee's End Site is the shank: the ankle's offset from the knee.
        let knee = &bvh.joints[2];
        let ankle = body.skeleton.offset_in_parent_m(JointId::LEFT_ANKLE);
        assert_eq!(knee.end_sites.len(), 1);
        assert!((knee.end_sites[0] - ankle).norm() < 1e-12);
        // One frame: the root's 3 positions and 3 rotations per written joint; the left knee's
        // 0.5 rad about x, the ankle's turn not written anywhere.
        let text = bvh.to_bvh_string();
        let frame: Vec<f64> = text
            .lines()
            .last()
            .unwrap()
            .split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(frame.len(), 3 + 3 * 5);
        assert!((frame[3 + 3 * 2] - 0.5f64.to_degrees()).abs() < 1e-9);
        assert_eq!(frame.iter().filter(|v| v.abs() > 1e-9).count(), 1);
    }
}
