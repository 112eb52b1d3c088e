//! Body dimensions, segment inertial parameters and IMU placement, loaded from `models/body.toml` and
//! scaled to a subject's stature and mass.
//!
//! The file holds de Leva's (1996) adjustments of Zatsiorsky–Seluyanov's segment parameters plus a few
//! proportions from Winter (2009); the file itself cites each number. This module turns them into a
//! T-pose skeleton in the model frame M (x left, y up, z forward) with the feet on the floor.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};
use serde::Deserialize;

use crate::skeleton::{Imu, JointId, MAX_SITES, NUM_JOINTS, Skeleton};

/// The body model shipped in the repository (`models/body.toml`), embedded at compile time.
pub const BUILTIN_BODY_TOML: &str = include_str!("../../../models/body.toml");

/// Gravity in the model frame M (m/s²), as in PIP's RBDL model (reference §0).
pub const GRAVITY_IN_MODEL_MPS2: Vector3<f64> = Vector3::new(0.0, -9.81, 0.0);

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct BodyFile {
    reference: ReferenceSubject,
    proportions: Proportions,
    segments: SegmentTable,
    imus: ImuTable,
}

/// The subject the tabulated values describe.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReferenceSubject {
    stature_m: f64,
    mass_kg: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct Proportions {
    ankle_height: f64,
    hip_joint_separation: f64,
    shoulder_joint_separation: f64,
    collar_lateral_fraction: f64,
    collar_below_neck_fraction: f64,
    foot_joint_forward_fraction: f64,
}

/// One row of de Leva's Table 4.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentParams {
    length_m: f64,
    mass_fraction: f64,
    com_fraction: f64,
    /// [sagittal, transverse, longitudinal], fractions of length.
    radius_of_gyration: [f64; 3],
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentTable {
    head: SegmentParams,
    head_neck: SegmentParams,
    upper_trunk: SegmentParams,
    mid_trunk: SegmentParams,
    lower_trunk: SegmentParams,
    upper_arm: SegmentParams,
    forearm: SegmentParams,
    hand: SegmentParams,
    thigh: SegmentParams,
    shank: SegmentParams,
    foot: SegmentParams,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImuParams {
    offset_m: [f64; 3],
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImuTable {
    left_forearm: ImuParams,
    right_forearm: ImuParams,
    left_lower_leg: ImuParams,
    right_lower_leg: ImuParams,
    head: ImuParams,
    pelvis: ImuParams,
    left_upper_leg: ImuParams,
    right_upper_leg: ImuParams,
    left_foot: ImuParams,
    right_foot: ImuParams,
    sternum: ImuParams,
    left_shoulder: ImuParams,
    right_shoulder: ImuParams,
    left_upper_arm: ImuParams,
    right_upper_arm: ImuParams,
    left_hand: ImuParams,
    right_hand: ImuParams,
}

/// Parsed and validated `body.toml`: the reference subject's tables, not yet scaled to a subject.
#[derive(Debug, Clone)]
pub struct BodyParams {
    file: BodyFile,
}

/// Failure to load or validate a body model file.
#[derive(Debug, thiserror::Error)]
pub enum BodyLoadError {
    /// The file could not be read. Fix: check the path (usually `models/body.toml`).
    #[error("cannot read body model '{file}': {source}")]
    Io {
        file: PathBuf,
        source: std::io::Error,
    },
    /// The file is not valid TOML or a key is missing, unknown or of the wrong type; `detail` (from the
    /// TOML parser) names the line and the key.
    #[error("body model '{file}': {detail}")]
    Parse { file: String, detail: String },
    /// A value is out of its allowed range.
    #[error("body model '{file}': key `{key}` must be {expected} (got {value})")]
    Invalid {
        file: String,
        key: String,
        expected: &'static str,
        value: f64,
    },
}

/// Invalid subject dimensions passed to [`BodyModel::new`].
#[derive(Debug, thiserror::Error)]
pub enum BodyModelError {
    /// `stature_m` or `mass_kg` is not a positive finite number.
    #[error("subject {field} must be a positive finite number (got {value})")]
    InvalidSubject { field: &'static str, value: f64 },
}

impl BodyParams {
    /// Parse `text` (the contents of a body.toml); `file` names it in errors.
    pub fn from_toml_str(text: &str, file: &str) -> Result<BodyParams, BodyLoadError> {
        let parsed: BodyFile = toml::from_str(text).map_err(|e| BodyLoadError::Parse {
            file: file.to_owned(),
            detail: e.to_string(),
        })?;
        validate(&parsed, file)?;
        Ok(BodyParams { file: parsed })
    }

    /// Read and parse a body.toml file.
    pub fn load(path: &Path) -> Result<BodyParams, BodyLoadError> {
        let text = std::fs::read_to_string(path).map_err(|source| BodyLoadError::Io {
            file: path.to_owned(),
            source,
        })?;
        BodyParams::from_toml_str(&text, &path.display().to_string())
    }

    /// The repository's `models/body.toml`, embedded in the binary.
    pub fn builtin() -> Result<BodyParams, BodyLoadError> {
        BodyParams::from_toml_str(BUILTIN_BODY_TOML, "models/body.toml (built in)")
    }

    /// Stature of the tables' reference subject (m).
    pub fn reference_stature_m(&self) -> f64 {
        self.file.reference.stature_m
    }

    /// Mass of the tables' reference subject (kg).
    pub fn reference_mass_kg(&self) -> f64 {
        self.file.reference.mass_kg
    }
}

fn validate(f: &BodyFile, file: &str) -> Result<(), BodyLoadError> {
    let bad = |key: &str, expected: &'static str, value: f64| BodyLoadError::Invalid {
        file: file.to_owned(),
        key: key.to_owned(),
        expected,
        value,
    };
    let positive = |key: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(bad(key, "a positive finite number", v))
        }
    };
    let unit = |key: &str, v: f64| {
        if v.is_finite() && (0.0..=1.0).contains(&v) {
            Ok(())
        } else {
            Err(bad(key, "a finite number in [0, 1]", v))
        }
    };
    positive("reference.stature_m", f.reference.stature_m)?;
    positive("reference.mass_kg", f.reference.mass_kg)?;
    let p = &f.proportions;
    unit("proportions.ankle_height", p.ankle_height)?;
    unit("proportions.hip_joint_separation", p.hip_joint_separation)?;
    unit(
        "proportions.shoulder_joint_separation",
        p.shoulder_joint_separation,
    )?;
    unit(
        "proportions.collar_lateral_fraction",
        p.collar_lateral_fraction,
    )?;
    unit(
        "proportions.collar_below_neck_fraction",
        p.collar_below_neck_fraction,
    )?;
    unit(
        "proportions.foot_joint_forward_fraction",
        p.foot_joint_forward_fraction,
    )?;
    let s = &f.segments;
    for (name, seg) in [
        ("head", &s.head),
        ("head_neck", &s.head_neck),
        ("upper_trunk", &s.upper_trunk),
        ("mid_trunk", &s.mid_trunk),
        ("lower_trunk", &s.lower_trunk),
        ("upper_arm", &s.upper_arm),
        ("forearm", &s.forearm),
        ("hand", &s.hand),
        ("thigh", &s.thigh),
        ("shank", &s.shank),
        ("foot", &s.foot),
    ] {
        positive(&format!("segments.{name}.length_m"), seg.length_m)?;
        unit(&format!("segments.{name}.mass_fraction"), seg.mass_fraction)?;
        unit(&format!("segments.{name}.com_fraction"), seg.com_fraction)?;
        for (i, r) in seg.radius_of_gyration.iter().enumerate() {
            positive(&format!("segments.{name}.radius_of_gyration[{i}]"), *r)?;
        }
    }
    // The segments carrying mass (all but head_neck, an alternative head definition) must share out the
    // whole body: de Leva's male fractions sum to 1.0000.
    let mass_sum = s.head.mass_fraction
        + s.upper_trunk.mass_fraction
        + s.mid_trunk.mass_fraction
        + s.lower_trunk.mass_fraction
        + 2.0
            * (s.upper_arm.mass_fraction
                + s.forearm.mass_fraction
                + s.hand.mass_fraction
                + s.thigh.mass_fraction
                + s.shank.mass_fraction
                + s.foot.mass_fraction);
    if (mass_sum - 1.0).abs() > 0.01 {
        return Err(bad(
            "segments.*.mass_fraction",
            "fractions summing to 1 (±0.01) over head, trunk parts and both sides' limbs",
            mass_sum,
        ));
    }
    if s.head_neck.length_m < s.head.length_m {
        return Err(bad(
            "segments.head_neck.length_m",
            "at least segments.head.length_m",
            s.head_neck.length_m,
        ));
    }
    let i = &f.imus;
    for imu in Imu::CATALOGUE {
        let o = imu_params(i, imu).offset_m;
        for (k, v) in o.iter().enumerate() {
            if !v.is_finite() {
                return Err(bad(
                    &format!("imus.{}.offset_m[{k}]", imu.name()),
                    "a finite number",
                    *v,
                ));
            }
        }
    }
    Ok(())
}

fn imu_params(t: &ImuTable, imu: Imu) -> ImuParams {
    match imu {
        Imu::LeftForearm => t.left_forearm,
        Imu::RightForearm => t.right_forearm,
        Imu::LeftLowerLeg => t.left_lower_leg,
        Imu::RightLowerLeg => t.right_lower_leg,
        Imu::Head => t.head,
        Imu::Pelvis => t.pelvis,
        Imu::LeftUpperLeg => t.left_upper_leg,
        Imu::RightUpperLeg => t.right_upper_leg,
        Imu::LeftFoot => t.left_foot,
        Imu::RightFoot => t.right_foot,
        Imu::Sternum => t.sternum,
        Imu::LeftShoulder => t.left_shoulder,
        Imu::RightShoulder => t.right_shoulder,
        Imu::LeftUpperArm => t.left_upper_arm,
        Imu::RightUpperArm => t.right_upper_arm,
        Imu::LeftHand => t.left_hand,
        Imu::RightHand => t.right_hand,
    }
}

/// A rigid body segment attached to (moving with) one joint.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// de Leva segment name, with `left_`/`right_` for limbs (e.g. `"left_thigh"`).
    pub name: String,
    /// Joint whose frame the segment moves with.
    pub joint: JointId,
    /// Segment mass (kg).
    pub mass_kg: f64,
    /// Centre of mass (m) in the joint's frame (equal to M axes at rest).
    pub com_in_joint_m: Vector3<f64>,
    /// Inertia tensor about the centre of mass (kg·m²), axes of the joint's frame.
    pub inertia_about_com_kgm2: Matrix3<f64>,
}

/// A subject's body: skeleton, segments and IMU placement, scaled from [`BodyParams`]. Immutable model data.
#[derive(Clone, Debug)]
pub struct BodyModel {
    /// Subject stature (m): floor to vertex in the T-pose.
    pub stature_m: f64,
    /// Subject mass (kg).
    pub mass_kg: f64,
    /// Rest (T-pose) geometry.
    pub skeleton: Skeleton,
    /// Massive segments (massless joints such as spine2, neck and collars carry none).
    pub segments: Vec<Segment>,
    /// IMU position (m) in its carrying joint's frame ([`Imu::joint`]), per site of the
    /// catalogue in wire slot order.
    pub imu_offsets_in_joint_m: [Vector3<f64>; MAX_SITES],
    /// Height of the root joint above the floor in the T-pose (m); the floor is y = 0 when the root is
    /// placed at (0, this, 0).
    pub rest_root_height_m: f64,
    /// Distance from the head joint up to the vertex (m), along +y of the head frame.
    pub head_top_above_head_joint_m: f64,
}

impl BodyModel {
    /// Scale the reference tables to a subject. Lengths scale by `k = stature / chain`, where `chain` is
    /// the sum of de Leva's vertical segment lengths plus the ankle height (1.699 m for the reference
    /// subject of 1.741 m: de Leva's landmarks do not chain exactly to the stature), so the model's
    /// T-pose is exactly `stature_m` tall. Masses scale by `mass_kg / reference mass`.
    pub fn new(
        params: &BodyParams,
        stature_m: f64,
        mass_kg: f64,
    ) -> Result<BodyModel, BodyModelError> {
        if !(stature_m.is_finite() && stature_m > 0.0) {
            return Err(BodyModelError::InvalidSubject {
                field: "stature_m",
                value: stature_m,
            });
        }
        if !(mass_kg.is_finite() && mass_kg > 0.0) {
            return Err(BodyModelError::InvalidSubject {
                field: "mass_kg",
                value: mass_kg,
            });
        }
        let f = &params.file;
        let s = &f.segments;
        let p = &f.proportions;
        let h_ref = f.reference.stature_m;
        let ankle_h_ref = p.ankle_height * h_ref;
        let chain_ref = ankle_h_ref
            + s.shank.length_m
            + s.thigh.length_m
            + s.lower_trunk.length_m
            + s.mid_trunk.length_m
            + s.upper_trunk.length_m
            + s.head_neck.length_m;
        let k = stature_m / chain_ref;
        let len = |seg: &SegmentParams| seg.length_m * k;

        let ankle_h = ankle_h_ref * k;
        let hip_half = 0.5 * p.hip_joint_separation * h_ref * k;
        let shoulder_half = 0.5 * p.shoulder_joint_separation * h_ref * k;
        let (lower, mid, upper) = (len(&s.lower_trunk), len(&s.mid_trunk), len(&s.upper_trunk));
        let (thigh, shank, foot) = (len(&s.thigh), len(&s.shank), len(&s.foot));
        let (upper_arm, forearm, hand) = (len(&s.upper_arm), len(&s.forearm), len(&s.hand));
        let head_joint_above_neck = len(&s.head_neck) - len(&s.head);
        let collar_x = p.collar_lateral_fraction * shoulder_half;

        let mut o = [Vector3::zeros(); NUM_JOINTS];
        let mut set = |j: JointId, x: f64, y: f64, z: f64| o[j.index()] = Vector3::new(x, y, z);
        for side in [1.0, -1.0] {
            let (hip, knee, ankle, foot_j, collar, shoulder, elbow, wrist, hand_j) = if side > 0.0 {
                (
                    JointId::LEFT_HIP,
                    JointId::LEFT_KNEE,
                    JointId::LEFT_ANKLE,
                    JointId::LEFT_FOOT,
                    JointId::LEFT_COLLAR,
                    JointId::LEFT_SHOULDER,
                    JointId::LEFT_ELBOW,
                    JointId::LEFT_WRIST,
                    JointId::LEFT_HAND,
                )
            } else {
                (
                    JointId::RIGHT_HIP,
                    JointId::RIGHT_KNEE,
                    JointId::RIGHT_ANKLE,
                    JointId::RIGHT_FOOT,
                    JointId::RIGHT_COLLAR,
                    JointId::RIGHT_SHOULDER,
                    JointId::RIGHT_ELBOW,
                    JointId::RIGHT_WRIST,
                    JointId::RIGHT_HAND,
                )
            };
            set(hip, side * hip_half, 0.0, 0.0);
            set(knee, 0.0, -thigh, 0.0);
            set(ankle, 0.0, -shank, 0.0);
            set(foot_j, 0.0, -ankle_h, p.foot_joint_forward_fraction * foot);
            set(
                collar,
                side * collar_x,
                upper * (1.0 - p.collar_below_neck_fraction),
                0.0,
            );
            set(shoulder, side * (shoulder_half - collar_x), 0.0, 0.0);
            set(elbow, side * upper_arm, 0.0, 0.0);
            set(wrist, side * forearm, 0.0, 0.0);
            set(hand_j, side * hand, 0.0, 0.0);
        }
        set(JointId::SPINE1, 0.0, lower, 0.0);
        set(JointId::SPINE2, 0.0, 0.5 * mid, 0.0);
        set(JointId::SPINE3, 0.0, 0.5 * mid, 0.0);
        set(JointId::NECK, 0.0, upper, 0.0);
        set(JointId::HEAD, 0.0, head_joint_above_neck, 0.0);
        let skeleton = Skeleton::from_offsets(o);

        let mut segments = Vec::with_capacity(16);
        // Inertia about the centre: I = m (r L)², with r per axis; `axes` maps de Leva's
        // [sagittal, transverse, longitudinal] radii onto the joint frame's (x, y, z).
        let mut add = |name: String,
                       joint: JointId,
                       seg: &SegmentParams,
                       com: Vector3<f64>,
                       axes: [usize; 3]| {
            let m = seg.mass_fraction * mass_kg;
            let l = seg.length_m * k;
            let r = seg.radius_of_gyration;
            let i = |a: usize| m * (r[a] * l).powi(2);
            segments.push(Segment {
                name,
                joint,
                mass_kg: m,
                com_in_joint_m: com,
                inertia_about_com_kgm2: Matrix3::from_diagonal(&Vector3::new(
                    i(axes[0]),
                    i(axes[1]),
                    i(axes[2]),
                )),
            });
        };
        // Axes: vertical segments x = transverse, y = longitudinal, z = sagittal; arms (along x in the
        // T-pose) x = longitudinal, y = transverse, z = sagittal; the foot (along z) x = transverse,
        // y = sagittal, z = longitudinal. Indices into [sag, trans, long].
        const VERTICAL: [usize; 3] = [1, 2, 0];
        const ARM: [usize; 3] = [2, 1, 0];
        const FOOT: [usize; 3] = [1, 0, 2];
        // Centres of mass: de Leva measures com_fraction from the first landmark (trunk and head: the
        // upper one; limbs: the proximal one).
        let y = |v: f64| Vector3::new(0.0, v, 0.0);
        add(
            "head".into(),
            JointId::HEAD,
            &s.head,
            y(len(&s.head) * (1.0 - s.head.com_fraction)),
            VERTICAL,
        );
        add(
            "upper_trunk".into(),
            JointId::SPINE3,
            &s.upper_trunk,
            y(upper * (1.0 - s.upper_trunk.com_fraction)),
            VERTICAL,
        );
        add(
            "mid_trunk".into(),
            JointId::SPINE1,
            &s.mid_trunk,
            y(mid * (1.0 - s.mid_trunk.com_fraction)),
            VERTICAL,
        );
        add(
            "lower_trunk".into(),
            JointId::PELVIS,
            &s.lower_trunk,
            y(lower * (1.0 - s.lower_trunk.com_fraction)),
            VERTICAL,
        );
        for (side, prefix) in [(1.0, "left"), (-1.0, "right")] {
            let j = |l: JointId, r: JointId| if side > 0.0 { l } else { r };
            let x = |v: f64| Vector3::new(side * v, 0.0, 0.0);
            add(
                format!("{prefix}_upper_arm"),
                j(JointId::LEFT_SHOULDER, JointId::RIGHT_SHOULDER),
                &s.upper_arm,
                x(upper_arm * s.upper_arm.com_fraction),
                ARM,
            );
            add(
                format!("{prefix}_forearm"),
                j(JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW),
                &s.forearm,
                x(forearm * s.forearm.com_fraction),
                ARM,
            );
            add(
                format!("{prefix}_hand"),
                j(JointId::LEFT_WRIST, JointId::RIGHT_WRIST),
                &s.hand,
                x(hand * s.hand.com_fraction),
                ARM,
            );
            add(
                format!("{prefix}_thigh"),
                j(JointId::LEFT_HIP, JointId::RIGHT_HIP),
                &s.thigh,
                y(-thigh * s.thigh.com_fraction),
                VERTICAL,
            );
            add(
                format!("{prefix}_shank"),
                j(JointId::LEFT_KNEE, JointId::RIGHT_KNEE),
                &s.shank,
                y(-shank * s.shank.com_fraction),
                VERTICAL,
            );
            // [inferred] heel 0.25·L behind the ankle, centre of mass at half the ankle height.
            add(
                format!("{prefix}_foot"),
                j(JointId::LEFT_ANKLE, JointId::RIGHT_ANKLE),
                &s.foot,
                Vector3::new(0.0, -0.5 * ankle_h, (s.foot.com_fraction - 0.25) * foot),
                FOOT,
            );
        }

        let imu_offsets_in_joint_m = Imu::CATALOGUE
            .map(|imu| Vector3::from(imu_params(&f.imus, imu).offset_m) * (stature_m / h_ref));

        Ok(BodyModel {
            stature_m,
            mass_kg,
            skeleton,
            segments,
            imu_offsets_in_joint_m,
            rest_root_height_m: ankle_h + shank + thigh,
            head_top_above_head_joint_m: len(&s.head),
        })
    }

    /// Rest position (m, model frame M) of every joint with the feet on the floor y = 0.
    pub fn rest_positions_on_floor_m(&self) -> [Vector3<f64>; NUM_JOINTS] {
        let lift = Vector3::new(0.0, self.rest_root_height_m, 0.0);
        self.skeleton.rest_positions_from_root_m().map(|p| p + lift)
    }

    /// Leg length (m): hip to knee to ankle, left side.
    pub fn leg_length_m(&self) -> f64 {
        self.skeleton.offset_in_parent_m(JointId::LEFT_KNEE).norm()
            + self.skeleton.offset_in_parent_m(JointId::LEFT_ANKLE).norm()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn reference_body() -> BodyModel {
        let params = BodyParams::builtin().unwrap();
        BodyModel::new(&params, 1.741, 73.0).unwrap()
    }

    #[test]
    fn t_pose_is_as_tall_as_the_stature_with_feet_on_the_floor() {
        let body = reference_body();
        let p = body.rest_positions_on_floor_m();
        let head_top = p[JointId::HEAD.index()].y + body.head_top_above_head_joint_m;
        assert_relative_eq!(head_top, 1.741, epsilon = 1e-12);
        assert_relative_eq!(p[JointId::LEFT_FOOT.index()].y, 0.0, epsilon = 1e-12);
        // Left is +x, arms horizontal, legs straight down.
        assert!(p[JointId::LEFT_WRIST.index()].x > 0.6);
        assert!(p[JointId::RIGHT_WRIST.index()].x < -0.6);
        assert_relative_eq!(
            p[JointId::LEFT_WRIST.index()].y,
            p[JointId::LEFT_SHOULDER.index()].y
        );
        assert_relative_eq!(
            p[JointId::LEFT_ANKLE.index()].x,
            p[JointId::LEFT_HIP.index()].x
        );
        // Arm span (hand joints) is close to the stature (Vitruvian ratio ≈ 1; finger tips add ~0.1 m).
        let span = p[JointId::LEFT_HAND.index()].x - p[JointId::RIGHT_HAND.index()].x;
        assert!((1.45..1.75).contains(&span), "span {span}");
    }

    #[test]
    fn masses_sum_to_body_mass_and_com_is_near_mid_height() {
        let body = reference_body();
        let total: f64 = body.segments.iter().map(|s| s.mass_kg).sum();
        assert_relative_eq!(total, 73.0, epsilon = 1e-9);
        let rest = body.rest_positions_on_floor_m();
        let com: Vector3<f64> = body
            .segments
            .iter()
            .map(|s| (rest[s.joint.index()] + s.com_in_joint_m) * s.mass_kg)
            .sum::<Vector3<f64>>()
            / total;
        // Standing adult male CoM height is about 55–58 % of stature with the arms down (Winter 2009,
        // §3.3); raising the arms (≈ 10 % of the mass) from ≈ 0.6 H to shoulder height ≈ 0.82 H adds ≈ 0.02 H.
        let frac = com.y / body.stature_m;
        assert!((0.57..0.60).contains(&frac), "CoM at {frac} of stature");
        assert!(com.x.abs() < 1e-9, "left/right symmetric");
        // Thigh inertia about its long axis from de Leva: m (0.149 L)².
        let thigh = body
            .segments
            .iter()
            .find(|s| s.name == "left_thigh")
            .unwrap();
        // chain = 0.039·1.741 + 0.434 + 0.4222 + 0.1457 + 0.2155 + 0.1707 + 0.2429 = 1.698899 m.
        let l: f64 = 0.4222 * 1.741 / 1.698899;
        assert_relative_eq!(
            thigh.inertia_about_com_kgm2[(1, 1)],
            0.1416 * 73.0 * (0.149_f64 * l).powi(2),
            epsilon = 1e-9
        );
    }

    #[test]
    fn scales_with_height_and_mass() {
        let params = BodyParams::builtin().unwrap();
        let a = BodyModel::new(&params, 1.6, 60.0).unwrap();
        let b = BodyModel::new(&params, 1.9, 90.0).unwrap();
        let r = 1.9 / 1.6;
        for j in JointId::all() {
            assert_relative_eq!(
                *b.skeleton.offset_in_parent_m(j),
                a.skeleton.offset_in_parent_m(j) * r,
                epsilon = 1e-12
            );
        }
        for (sa, sb) in a.segments.iter().zip(&b.segments) {
            assert_relative_eq!(sb.mass_kg, sa.mass_kg * 1.5, epsilon = 1e-12);
            assert_relative_eq!(
                sb.inertia_about_com_kgm2,
                sa.inertia_about_com_kgm2 * 1.5 * r * r,
                epsilon = 1e-12
            );
        }
        assert_relative_eq!(b.leg_length_m(), a.leg_length_m() * r, epsilon = 1e-12);
    }

    #[test]
    fn bad_subject_and_bad_files_are_reported_with_file_and_key() {
        let params = BodyParams::builtin().unwrap();
        assert!(matches!(
            BodyModel::new(&params, f64::NAN, 70.0),
            Err(BodyModelError::InvalidSubject {
                field: "stature_m",
                ..
            })
        ));
        assert!(BodyModel::new(&params, 1.7, -1.0).is_err());

        let broken = BUILTIN_BODY_TOML.replace("length_m = 0.4222", "length_m = -0.4222");
        let e = BodyParams::from_toml_str(&broken, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.toml") && e.contains("segments.thigh.length_m"),
            "{e}"
        );

        let missing = BUILTIN_BODY_TOML.replace("ankle_height = 0.039", "");
        let e = BodyParams::from_toml_str(&missing, "y.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("y.toml") && e.contains("ankle_height"), "{e}");

        let typo = BUILTIN_BODY_TOML.replace("com_fraction = 0.4095", "com_fractoin = 0.4095");
        let e = BodyParams::from_toml_str(&typo, "z.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("z.toml") && e.contains("com_fractoin") && e.contains("line"),
            "{e}"
        );

        let heavy = BUILTIN_BODY_TOML.replace("mass_fraction = 0.1416", "mass_fraction = 0.2416");
        let e = BodyParams::from_toml_str(&heavy, "w.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("w.toml") && e.contains("mass_fraction") && e.contains("1.2"),
            "{e}"
        );

        let e = BodyParams::load(Path::new("/nonexistent/body.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/body.toml"), "{e}");
    }
}
