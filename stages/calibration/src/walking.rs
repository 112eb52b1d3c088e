//! Walking calibration (GlobalPose §3.4, Eq. 17–24; reference §4 `walking_6dof`).
//!
//! The subject stands (N-pose), takes one step forward and stands again in the same pose. Every
//! point of the body then moved by the same horizontal vector. Each sensor integrates its own free
//! acceleration in its own inertial frame I_k during the step (Eq. 17–18), removes the velocity
//! drift with the zero-velocity update (Eq. 19–20) and the vertical component (Eq. 21). The sensors'
//! inertial frames share the up axis but not the heading, so their displacement vectors differ by
//! a rotation about up: aligning each to the pelvis's gives the relative heading errors (Eq. 22).
//! The pelvis's displacement is "forward", which fixes `R_MI` (Eq. 23), and the known standing
//! pose gives `R_SB` (Eq. 24), averaged over the stands before and after the step (reference §4).
//!
//! The checks follow the paper ("verify whether R_IS^(2) is close to R_IS^(1)") and the reference
//! (|vertical| < 0.1 m per sensor, R_SB disagreement < 20°), plus two of imuflow's own: the step
//! length must be plausible and every sensor must have moved as far as the pelvis (a rigid
//! translation moves all points equally; a different length means the pose changed or the
//! integration failed).

use imuflow_body::limb_joints::nearest_rotation_about;
use nalgebra::{Rotation3, Unit, Vector3};

use crate::calibration::{Calibration, Method, SensorCalibration};
use crate::convention::{InertialFrame, ReferencePose};
use crate::error::Rejection;
use crate::math::{horizontal, mean_rotation, signed_angle_about};
use crate::sample::Sample;
use crate::tpose::check_gravity;
use crate::{PELVIS, sensor_name};
use imuflow_body::{MAX_SITES, SiteMask};

/// What a walking calibration needs to know and accept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkingConfig {
    /// Only the up axis of the convention is used: the step gives the heading.
    pub frame: InertialFrame,
    /// The standing pose (GlobalPose: N-pose).
    pub pose: ReferencePose,
    pub accel_offset: bool,
    /// Largest angle between measured gravity and the convention's down axis (deg).
    pub max_gravity_deg: f64,
    /// Largest change of any sensor's orientation between the two stands (deg).
    pub max_pose_change_deg: f64,
    /// Largest vertical displacement of any sensor (m).
    pub max_vertical_m: f64,
    /// Plausible pelvis step length (m).
    pub min_step_m: f64,
    pub max_step_m: f64,
    /// Largest difference between a sensor's step length and the pelvis's (m).
    pub max_step_mismatch_m: f64,
}

/// The samples of one stand–step–stand.
#[derive(Clone, Copy, Debug)]
pub struct StepWindows<'a> {
    /// Still samples at the end of the stand before the step (averaged).
    pub before: &'a [Sample],
    /// The samples integrated: from the stand before (still) to the stand after (still).
    pub motion: &'a [Sample],
    /// Still samples of the stand after the step (averaged).
    pub after: &'a [Sample],
}

/// What the step measured, per sensor in its own inertial frame (by wire slot; identities and
/// zeros outside `sites`).
#[derive(Clone, Debug, PartialEq)]
pub struct StepGeometry {
    /// The sites measured (the samples' set).
    pub sites: SiteMask,
    /// R̄_IS averaged over the stand before (R_IS^(1)) and after (R_IS^(2)).
    pub stand_before: [Rotation3<f64>; MAX_SITES],
    pub stand_after: [Rotation3<f64>; MAX_SITES],
    /// Horizontal displacement p̄ (Eq. 21), m.
    pub displacement_m: [Vector3<f64>; MAX_SITES],
    /// Vertical displacement removed by Eq. 21, m.
    pub vertical_m: [f64; MAX_SITES],
    /// Mean free acceleration in I over both stands (the accelerometer offset), m/s².
    pub offset_in_inertial_mps2: [Vector3<f64>; MAX_SITES],
    /// Relative heading to the pelvis ψ_k, Eq. 22, rad (pelvis: 0).
    pub heading_to_pelvis_rad: [f64; MAX_SITES],
}

impl StepGeometry {
    /// Nothing measured yet of `sites`: identities and zeros.
    fn unmeasured(sites: SiteMask) -> StepGeometry {
        StepGeometry {
            sites,
            stand_before: [Rotation3::identity(); MAX_SITES],
            stand_after: [Rotation3::identity(); MAX_SITES],
            displacement_m: [Vector3::zeros(); MAX_SITES],
            vertical_m: [0.0; MAX_SITES],
            offset_in_inertial_mps2: [Vector3::zeros(); MAX_SITES],
            heading_to_pelvis_rad: [0.0; MAX_SITES],
        }
    }
}

/// A walking calibration with what it measured.
#[derive(Clone, Debug, PartialEq)]
pub struct WalkingEstimate {
    pub calibration: Calibration,
    pub geometry: StepGeometry,
    /// A natural start: which way the walk went relative to facing (a step: always forward).
    pub walk_direction: Option<WalkDirection>,
}

/// Which way a natural start's walk went relative to where the body faced, right-handed about up
/// (rad: 0 forward, π/2 to the left, ±π backwards, −π/2 to the right).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkDirection {
    /// What the legs say, to the nearest of the four (`None`: the shanks hardly leaned, so they
    /// cannot tell).
    pub from_legs_rad: Option<f64>,
    /// The legs' angle before rounding.
    pub legs_rad: f64,
    /// The shanks' mean lean over the walk (sine of the angle from vertical).
    pub lean: f64,
    /// The angle from where the shanks' flexion axes say the body faces to the direction of
    /// travel, not rounded (`None`: the shanks did not turn about one axis, or it disagrees with
    /// their lean by more than [`WalkDirection::MAX_FLEXION_LEAN_RAD`]).
    pub flexion_rad: Option<f64>,
    /// What the configuration said (`walk_direction_deg`), if it said anything.
    pub given_rad: Option<f64>,
    /// What was used: the given direction, else the flexion axes', else the legs' (rounded),
    /// else forward.
    pub used_rad: f64,
    /// The pelvis's travel over the walk with each step turned back by the pelvis's turn about up
    /// since the stand (m, horizontal, the pelvis's inertial frame): where the walk went
    /// relative to the body as it stood, which a turn while walking leaves as it was. The
    /// angles above are taken to it.
    pub travel_m: Vector3<f64>,
}

impl WalkDirection {
    /// The given direction and the legs' disagree by more than this (rad): worth a warning.
    pub const CONTRADICTION_RAD: f64 = std::f64::consts::FRAC_PI_4;
    /// The shanks' mean lean below which the legs cannot tell (sine: about 1.7°).
    pub const MIN_LEAN: f64 = 0.03;
    /// The most the facing from the flexion axes may differ from the lean's (rad): the lean
    /// points within a few degrees of facing (both legs, synthetic walks: 3–9°); a flexion axis
    /// that is not the knees' (a side step's hips) lies a quarter turn away.
    pub const MAX_FLEXION_LEAN_RAD: f64 = 0.5;
    /// How much more a shank must turn about its main axis than about the next one for that axis
    /// to count as its flexion axis (ratio of the angular rate's second moments). Bandai's walks
    /// with the reference noise: one shank at 2.1–3 in several styles, where 3 left them to the
    /// travel direction (bones max 19–23° against 10° with 2).
    pub const MIN_FLEXION_DOMINANCE: f64 = 2.0;

    /// The given direction, when the legs confidently say another.
    pub fn contradiction(&self) -> Option<(f64, f64)> {
        let (given, legs) = (self.given_rad?, self.from_legs_rad?);
        let gap = (given - legs).sin().atan2((given - legs).cos()).abs();
        (gap > Self::CONTRADICTION_RAD).then_some((given, legs))
    }

    /// The direction's name, for the log.
    pub fn name(rad: f64) -> &'static str {
        match ((rad.to_degrees() / 90.0).round() as i64).rem_euclid(4) {
            0 => "forward",
            1 => "to the left",
            2 => "backwards",
            _ => "to the right",
        }
    }
}

/// Calibrates from one stand–step–stand, or says why it must be redone.
pub fn calibrate_walking(
    windows: &StepWindows<'_>,
    config: &WalkingConfig,
) -> Result<WalkingEstimate, Rejection> {
    let geometry = measure_step(windows, config)?;
    let up = config.frame.up_in_inertial();
    let model_from_inertial = model_from_inertial(&up, &geometry.displacement_m[PELVIS]);
    estimate_from(geometry, model_from_inertial, config, None)
}

/// The calibration a measured geometry gives with `R_MI`: per sensor the heading correction, `R_SB`
/// (Eq. 24 for each stand, then their rotation average, reference §4 step 5; a single stand is
/// both) and the accelerometer offset in M.
fn estimate_from(
    geometry: StepGeometry,
    model_from_inertial: Rotation3<f64>,
    config: &WalkingConfig,
    walk_direction: Option<WalkDirection>,
) -> Result<WalkingEstimate, Rejection> {
    let reference = config.pose.bone_orientations();
    let mut sensors = [SensorCalibration::IDENTITY; MAX_SITES];
    for k in geometry.sites.sites().map(|s| s.index()) {
        let cal = &mut sensors[k];
        cal.heading_correction_rad = geometry.heading_to_pelvis_rad[k];
        let sensor_model_from_inertial = imuflow_body::rotation::Axis::Y
            .rotation(cal.heading_correction_rad)
            * model_from_inertial;
        let estimate = |stand: &Rotation3<f64>| {
            (sensor_model_from_inertial * stand).transpose() * reference[k]
        };
        let before = estimate(&geometry.stand_before[k]);
        let after = estimate(&geometry.stand_after[k]);
        cal.sensor_from_bone =
            mean_rotation([&before, &after]).ok_or(Rejection::NoSamples { phase: "stand" })?;
        if config.accel_offset {
            cal.accel_offset_in_model_mps2 =
                sensor_model_from_inertial * geometry.offset_in_inertial_mps2[k];
        }
    }
    Ok(WalkingEstimate {
        calibration: Calibration {
            method: Method::Walking,
            model_from_inertial,
            sites: geometry.sites,
            sensors,
        },
        geometry,
        walk_direction,
    })
}

/// Eq. 23: forward (M's z) is the pelvis's step direction, up is against gravity; `R_MI`'s rows are
/// M's axes written in I.
pub fn model_from_inertial(up: &Unit<Vector3<f64>>, pelvis_step: &Vector3<f64>) -> Rotation3<f64> {
    let forward = horizontal(pelvis_step, up).normalize();
    let left = up.cross(&forward);
    Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_rows(&[
        left.transpose(),
        up.transpose(),
        forward.transpose(),
    ]))
}

/// Everything of the step that does not depend on an existing calibration, with the checks.
pub fn measure_step(
    windows: &StepWindows<'_>,
    config: &WalkingConfig,
) -> Result<StepGeometry, Rejection> {
    let before = valid(windows.before, "stand before the step")?;
    let after = valid(windows.after, "stand after the step")?;
    let motion = valid(windows.motion, "step")?;
    check_gravity(before, config.frame, config.max_gravity_deg)?;
    check_gravity(after, config.frame, config.max_gravity_deg)?;
    let up = config.frame.up_in_inertial();
    let gravity = -up.into_inner() * imuflow_body::GRAVITY_IN_MODEL_MPS2.norm();

    let mut g = StepGeometry::unmeasured(before[0].sites);
    let slots: Vec<usize> = before[0].slots().collect();
    for &k in &slots {
        g.stand_before[k] = stand_orientation(before, k)?;
        g.stand_after[k] = stand_orientation(after, k)?;
        let angle_deg =
            imuflow_body::rotation::angle_between(&g.stand_before[k], &g.stand_after[k])
                .to_degrees();
        if angle_deg > config.max_pose_change_deg {
            return Err(Rejection::PoseChanged {
                sensor: sensor_name(k),
                angle_deg,
                max_deg: config.max_pose_change_deg,
            });
        }
    }
    for &k in &slots {
        let offset = if config.accel_offset {
            mean_free_acceleration(before.iter().chain(after), k, &gravity)
        } else {
            Vector3::zeros()
        };
        g.offset_in_inertial_mps2[k] = offset;
        let p = integrate_with_zupt(motion, k, &(gravity - offset));
        // Eq. 21 removes the component along g; the paper prints `g·a` in the denominator, a typo
        // for `g·g` (only that makes p̄ orthogonal to g).
        g.vertical_m[k] = p.dot(&up);
        g.displacement_m[k] = horizontal(&p, &up);
        if g.vertical_m[k].abs() > config.max_vertical_m {
            return Err(Rejection::NotLevel {
                sensor: sensor_name(k),
                vertical_m: g.vertical_m[k],
                max_m: config.max_vertical_m,
                param: "max_vertical_m",
            });
        }
    }
    check_lengths(&g.displacement_m, g.sites, config)?;
    let pelvis = g.displacement_m[PELVIS];
    for &k in &slots {
        g.heading_to_pelvis_rad[k] = signed_angle_about(&up, &g.displacement_m[k], &pelvis);
    }
    Ok(g)
}

fn valid<'a>(samples: &'a [Sample], phase: &'static str) -> Result<&'a [Sample], Rejection> {
    Sample::check_usable(samples, phase)?;
    Ok(samples)
}

fn stand_orientation(window: &[Sample], k: usize) -> Result<Rotation3<f64>, Rejection> {
    mean_rotation(window.iter().map(|s| &s.sensors[k].inertial_from_sensor))
        .ok_or(Rejection::NoSamples { phase: "stand" })
}

fn mean_free_acceleration<'a>(
    samples: impl Iterator<Item = &'a Sample>,
    k: usize,
    gravity: &Vector3<f64>,
) -> Vector3<f64> {
    let (sum, n) = samples.fold((Vector3::zeros(), 0usize), |(sum, n), s| {
        (
            sum + s.sensors[k].free_acceleration_in_inertial(gravity),
            n + 1,
        )
    });
    if n == 0 { sum } else { sum / n as f64 }
}

/// Double integration of sensor `k`'s free acceleration from rest (Eq. 17–18), then the zero-velocity
/// update (Eq. 19–20): the final velocity should be 0, and the position error correlates with the
/// velocity error through σ_pv/σ_vv (for a constant acceleration bias this removes its effect
/// exactly: σ_pv/σ_vv = T/2). `gravity` is g_I minus the accelerometer offset. Time steps come from
/// the samples' own timestamps.
pub fn integrate_with_zupt(samples: &[Sample], k: usize, gravity: &Vector3<f64>) -> Vector3<f64> {
    let (mut p, mut v) = (Vector3::zeros(), Vector3::zeros());
    let (mut sigma_pv, mut sigma_vv) = (0.0, 0.0);
    for pair in samples.windows(2) {
        let dt = pair[1].time_s - pair[0].time_s;
        let a = pair[0].sensors[k].free_acceleration_in_inertial(gravity);
        p += v * dt + a * (0.5 * dt * dt);
        v += a * dt;
        sigma_pv += sigma_vv * dt;
        sigma_vv += 1.0;
    }
    if sigma_vv > 0.0 {
        p -= v * (sigma_pv / sigma_vv);
    }
    p
}

fn check_lengths(
    displacement: &[Vector3<f64>; MAX_SITES],
    sites: SiteMask,
    config: &WalkingConfig,
) -> Result<(), Rejection> {
    let pelvis_m = displacement[PELVIS].norm();
    if !(config.min_step_m..=config.max_step_m).contains(&pelvis_m) {
        return Err(Rejection::StepLength {
            length_m: pelvis_m,
            min_m: config.min_step_m,
            max_m: config.max_step_m,
        });
    }
    for (k, d) in displacement
        .iter()
        .enumerate()
        .filter(|(k, _)| sites.contains_slot(*k))
    {
        let length_m = d.norm();
        if (length_m - pelvis_m).abs() > config.max_step_mismatch_m {
            return Err(Rejection::StepMismatch {
                sensor: sensor_name(k),
                length_m,
                pelvis_m,
                max_m: config.max_step_mismatch_m,
            });
        }
    }
    Ok(())
}

/// What a calibration from a natural start needs beyond [`WalkingConfig`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkStartConfig {
    /// The stand's pose, frame convention, offset and gravity check.
    pub walking: WalkingConfig,
    /// Direction of the walk relative to the way the subject faces, right-handed about up (rad):
    /// 0 forward, π/2 to the left, π backwards; `None`: found from the legs ([`WalkDirection`]).
    pub walk_direction_rad: Option<f64>,
    /// Length of the walk integrated after the stand (s; the caller cuts the window, this names it
    /// in refusals).
    pub walk_s: f64,
    /// Shortest pelvis displacement over the integrated walk (m).
    pub min_walk_m: f64,
    /// Largest RMS distance between a sensor's path, turned by its heading correction, and the
    /// pelvis's (m).
    pub max_walk_mismatch_m: f64,
    /// Largest vertical displacement of any sensor at the end of the walk (m).
    pub max_walk_vertical_m: f64,
    /// Largest change of the pelvis's walking direction over the walk (deg).
    pub max_walk_turn_deg: f64,
}

/// The samples of a natural start: standing still, then walking, with no stand after.
#[derive(Clone, Copy, Debug)]
pub struct WalkStartWindows<'a> {
    /// Still samples at the end of the stand (averaged).
    pub stand: &'a [Sample],
    /// Still samples for the accelerometer offset: the stand's end up to just before the motion
    /// began (more of them than `stand`: on short stands the noise of a shorter average costs
    /// more heading accuracy than a slow start's first accelerations, measured).
    pub offset_stand: &'a [Sample],
    /// The samples integrated: from inside the stand (at rest) into the walk.
    pub walk: &'a [Sample],
}

/// Calibrates from a stand followed by walking, or says why not.
///
/// Every sensor integrates its free acceleration in its own inertial frame from rest (Eq. 17–18);
/// without a stand after, there is no zero-velocity update, so the window is kept short (a few
/// seconds) and the accelerometer offset measured while standing is removed. Over a walk every
/// body point travels with the body: a sensor's horizontal path differs from the pelvis's by the
/// limb's swing (bounded) and a turn about up (its heading error). The heading correction ψ_k is
/// the rotation about up that best aligns the two paths over the whole window (least squares,
/// the 2-D Procrustes solution `atan2(Σ (p_k × p_pelvis)·up, Σ p_k·p_pelvis)`), the walk's
/// direction gives forward (Eq. 23, turned by `walk_direction_rad`), and the stand gives `R_SB`
/// (Eq. 24).
pub fn calibrate_walk_start(
    windows: &WalkStartWindows<'_>,
    config: &WalkStartConfig,
) -> Result<WalkingEstimate, Rejection> {
    let walking = &config.walking;
    let stand = valid(windows.stand, "stand before walking")?;
    let walk = valid(windows.walk, "walk")?;
    let still = valid(windows.offset_stand, "stand before walking")?;
    check_gravity(stand, walking.frame, walking.max_gravity_deg)?;
    let up = walking.frame.up_in_inertial();
    let gravity = -up.into_inner() * imuflow_body::GRAVITY_IN_MODEL_MPS2.norm();

    let mut g = StepGeometry::unmeasured(stand[0].sites);
    let slots: Vec<usize> = stand[0].slots().collect();
    // Each sensor's path from rest, and how a residual accelerometer bias would bend it (by
    // wire slot, empty outside the set).
    let mut raw_paths = vec![Vec::new(); MAX_SITES];
    let mut bias_bases = vec![Vec::new(); MAX_SITES];
    for &k in &slots {
        g.stand_before[k] = stand_orientation(stand, k)?;
        g.stand_after[k] = g.stand_before[k];
        if walking.accel_offset {
            g.offset_in_inertial_mps2[k] = mean_free_acceleration(still.iter(), k, &gravity);
        }
        raw_paths[k] = integrate_path(walk, k, &(gravity - g.offset_in_inertial_mps2[k]));
        bias_bases[k] = bias_paths(walk, k, &g.stand_before[k]);
    }
    // The pelvis first: its own bias only from its height staying level (it turns too little
    // for more); then every sensor against it.
    let pelvis_fit = fit_path(
        &up,
        &gravity,
        &raw_paths[PELVIS],
        &bias_bases[PELVIS],
        None,
        0.0,
    );
    let pelvis: Vec<Vector3<f64>> = pelvis_fit.path.iter().map(|p| horizontal(p, &up)).collect();
    check_walk(&pelvis, &up, config)?;
    for &k in &slots {
        let fit = if k == PELVIS {
            PathFit {
                heading_rad: 0.0,
                ..pelvis_fit.clone()
            }
        } else {
            let start = align_about(&up, &horizontal_path(&raw_paths[k], &up), &pelvis);
            fit_path(
                &up,
                &gravity,
                &raw_paths[k],
                &bias_bases[k],
                Some(&pelvis),
                start,
            )
        };
        let end = fit.path.last().copied().unwrap_or_else(Vector3::zeros);
        g.vertical_m[k] = end.dot(&up);
        if g.vertical_m[k].abs() > config.max_walk_vertical_m {
            return Err(Rejection::NotLevel {
                sensor: sensor_name(k),
                vertical_m: g.vertical_m[k],
                max_m: config.max_walk_vertical_m,
                param: "max_walk_vertical_m",
            });
        }
        g.displacement_m[k] = horizontal(&end, &up);
        let path = horizontal_path(&fit.path, &up);
        let rms_m = path_mismatch_m(&up, fit.heading_rad, &path, &pelvis);
        if rms_m > config.max_walk_mismatch_m {
            return Err(Rejection::WalkMismatch {
                sensor: sensor_name(k),
                rms_m,
                max_m: config.max_walk_mismatch_m,
            });
        }
        g.heading_to_pelvis_rad[k] = fit.heading_rad;
    }
    g.heading_to_pelvis_rad[PELVIS] = 0.0;

    // Forward is the walk's direction (relative to the body as it stood) turned back by the
    // walk's direction relative to facing: as given, else as the legs say.
    let direction = walk_direction(walk, &pelvis, &g, &up, config.walk_direction_rad);
    let walked = Rotation3::from_axis_angle(&up, -direction.used_rad) * direction.travel_m;
    let model_from_inertial = model_from_inertial(&up, &walked);
    // The stand after is the stand before (set above): Eq. 24 on the one stand.
    estimate_from(g, model_from_inertial, walking, Some(direction))
}

/// Which way the walk went relative to facing, from the legs (imuflow's own; neither paper
/// needs it, their calibration asks for a step forward).
///
/// Knees flex only backwards, so over a walk in any direction a shank spends its largest tilts
/// with the knee ahead of the ankle (late stance, early swing: about 40–50° against 10–20° the
/// other way at heel strike), and its mean lean points where the body faces. Standing in the
/// N-pose the shank is vertical, so its long axis in the sensor frame is `R̄_ISᵀ·up` from the
/// stand; during the walk that axis in I is `R_IS(t)·R̄_ISᵀ·up`, and its horizontal part, turned
/// into the pelvis's inertial frame by the sensor's heading correction, is the lean toward where
/// the knee is. The angle from the mean lean of both shanks to the pelvis's direction of travel is
/// the walk's direction relative to facing, rounded to forward, left, backwards or right. Where
/// the body faced exactly comes from the shanks' flexion axes ([`facing_from_flexion`]): a walk
/// strays a few degrees from facing, and a diagonal one more. Lean, travel (`pelvis_path`, one
/// point per sample) and flexion axes are taken with each sample turned back by the pelvis's turn
/// about up since the stand, so that a walk that turns gives them relative to the body as it
/// stood.
fn walk_direction(
    walk: &[Sample],
    pelvis_path: &[Vector3<f64>],
    g: &StepGeometry,
    up: &Unit<Vector3<f64>>,
    given_rad: Option<f64>,
) -> WalkDirection {
    let shanks = [
        imuflow_body::Imu::LeftLowerLeg.index(),
        imuflow_body::Imu::RightLowerLeg.index(),
    ];
    // Each sample turned back by how far the pelvis has turned about up since the stand, so that
    // a walk that turns gives the directions relative to the body as it stood, which R_SB is
    // taken from.
    let back: Vec<Rotation3<f64>> = walk
        .iter()
        .map(|s| {
            let since = s.sensors[PELVIS].inertial_from_sensor * g.stand_before[PELVIS].transpose();
            nearest_rotation_about(&since, up).inverse()
        })
        .collect();
    let travel: Vector3<f64> = pelvis_path
        .windows(2)
        .zip(&back)
        .map(|(step, back)| back * horizontal(&(step[1] - step[0]), up))
        .sum();
    let mut sum = Vector3::zeros();
    let mut n = 0usize;
    for &k in &shanks {
        let axis_in_sensor = g.stand_before[k].transpose() * up.into_inner();
        let to_pelvis = Rotation3::from_axis_angle(up, g.heading_to_pelvis_rad[k]);
        for (s, back) in walk.iter().zip(&back) {
            let axis = s.sensors[k].inertial_from_sensor * axis_in_sensor;
            sum += back * to_pelvis * horizontal(&axis, up);
            n += 1;
        }
    }
    let lean_vector = sum / n.max(1) as f64;
    let legs_rad = signed_angle_about(up, &lean_vector, &travel);
    let lean = lean_vector.norm();
    let flexion_rad = (lean >= WalkDirection::MIN_LEAN)
        .then(|| facing_from_flexion(walk, &back, g, up, &shanks, &lean_vector))
        .flatten()
        .map(|facing| signed_angle_about(up, &facing, &travel));
    let quarter = std::f64::consts::FRAC_PI_2;
    let from_legs_rad = (lean >= WalkDirection::MIN_LEAN).then(|| {
        let snapped = (legs_rad / quarter).round() * quarter;
        // ±π both mean backwards: say π.
        if snapped <= -std::f64::consts::PI + 1e-9 {
            std::f64::consts::PI
        } else {
            snapped
        }
    });
    WalkDirection {
        from_legs_rad,
        legs_rad,
        lean,
        flexion_rad,
        given_rad,
        used_rad: given_rad.or(flexion_rad).or(from_legs_rad).unwrap_or(0.0),
        travel_m: travel,
    }
}

/// Where the body faced during the walk (horizontal, in the pelvis's inertial frame), from the
/// shanks' flexion axes: a knee flexes about the body's left–right axis, so each shank turns
/// mostly about it. Each shank's toe-out turns its own axis a few degrees, the left one way and
/// the right the other, and their mean is the body's (on the true motion of the bundled walk,
/// within 0.6° of the pelvis's facing over any 3 s, where the direction of travel strayed
/// 2.5–4°). Each sample is turned back (`back`) by the pelvis's turn about up since the stand
/// first, so a curved walk gives the facing of the stand. Facing is perpendicular to that axis, on
/// the side the shanks lean to. `None` when a shank does not turn mostly about one axis
/// ([`WalkDirection::MIN_FLEXION_DOMINANCE`]) or the result strays from the lean by more than
/// [`WalkDirection::MAX_FLEXION_LEAN_RAD`].
fn facing_from_flexion(
    walk: &[Sample],
    back: &[Rotation3<f64>],
    g: &StepGeometry,
    up: &Unit<Vector3<f64>>,
    shanks: &[usize; 2],
    lean: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let mut axes = [Vector3::zeros(); 2];
    for (axis, &k) in axes.iter_mut().zip(shanks) {
        let to_pelvis = Rotation3::from_axis_angle(up, g.heading_to_pelvis_rad[k]);
        let moment = walk
            .iter()
            .zip(back)
            .map(|(s, back)| {
                let w = back
                    * to_pelvis
                    * (s.sensors[k].inertial_from_sensor * s.sensors[k].angular_rate_radps);
                w * w.transpose()
            })
            .sum::<nalgebra::Matrix3<f64>>();
        let eigen = moment.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
        if eigen.eigenvalues[order[0]]
            < WalkDirection::MIN_FLEXION_DOMINANCE * eigen.eigenvalues[order[1]]
        {
            return None;
        }
        *axis = horizontal(&eigen.eigenvectors.column(order[0]).into_owned(), up);
        // An axis near vertical (a shank twisting about itself) says nothing about facing.
        if axis.norm() < 0.5 {
            return None;
        }
    }
    let [left, right] = axes;
    let right = if left.dot(&right) < 0.0 {
        -right
    } else {
        right
    };
    let across = left.normalize() + right.normalize();
    let facing = up.cross(&across);
    let facing = if facing.dot(lean) < 0.0 {
        -facing
    } else {
        facing
    };
    (signed_angle_about(up, &facing, lean).abs() <= WalkDirection::MAX_FLEXION_LEAN_RAD)
        .then_some(facing)
}

/// Positions of sensor `k` from rest by double integration of its free acceleration (Eq. 17–18),
/// one per sample. `gravity` is g_I minus the accelerometer offset.
fn integrate_path(samples: &[Sample], k: usize, gravity: &Vector3<f64>) -> Vec<Vector3<f64>> {
    let (mut p, mut v) = (Vector3::zeros(), Vector3::zeros());
    let mut path = Vec::with_capacity(samples.len());
    path.push(p);
    for pair in samples.windows(2) {
        let dt = pair[1].time_s - pair[0].time_s;
        let a = pair[0].sensors[k].free_acceleration_in_inertial(gravity);
        p += v * dt + a * (0.5 * dt * dt);
        v += a * dt;
        path.push(p);
    }
    path
}

/// A sensor's path with its fitted residual bias removed, and its heading to the pelvis.
#[derive(Clone, Debug)]
struct PathFit {
    path: Vec<Vector3<f64>>,
    heading_rad: f64,
}

/// Rounds of alternating between the bias (linear least squares) and the heading (Procrustes).
const FIT_ROUNDS: usize = 4;
/// Ridge on the bias, relative to the data's own scale: keeps a sensor that barely turns (whose
/// bias paths are nearly the walk's own acceleration) from explaining its walk away as bias.
const BIAS_RIDGE: f64 = 0.05;

/// Fits a sensor's path to `target` (the pelvis's horizontal path): the turn about up (starting
/// from `heading_rad`), a constant offset c and the sensor's residual errors, by alternating the
/// linear least squares in them with the 2-D Procrustes in ψ. The vertical rows say the path
/// stays level; without a target (the pelvis itself) they are the only ones.
///
/// The residual errors are an accelerometer bias b_S and the tilt error δ_S the fusion keeps
/// because of it, both fixed in the sensor frame: they add `R_IS(t)·b + g × (R_IS(t)·δ)` to the
/// free acceleration, less what the stand's offset removed. Both are linear in the bias paths
/// `B_j` ([`bias_paths`]), so the path is `p(t) − Σ_j (b_j·B_j(t) + δ_j·g × B_j(t))`, and the fit
/// minimises `Σ_t |R_up(ψ)·(that) − target(t) − c|² + ridge·(|b|² + |g|²·|δ|²)`.
fn fit_path(
    up: &Unit<Vector3<f64>>,
    gravity: &Vector3<f64>,
    path: &[Vector3<f64>],
    basis: &[[Vector3<f64>; 3]],
    target: Option<&[Vector3<f64>]>,
    heading_rad: f64,
) -> PathFit {
    type Matrix9 = nalgebra::SMatrix<f64, 9, 9>;
    type Vector9 = nalgebra::SVector<f64, 9>;
    // Rows kept: all three, or only the vertical one.
    let keep = match target {
        Some(_) => nalgebra::Matrix3::identity(),
        None => up.into_inner() * up.transpose(),
    };
    let zero = Vector3::zeros();
    let columns = |b: &[Vector3<f64>; 3]| -> [Vector3<f64>; 6] {
        [
            b[0],
            b[1],
            b[2],
            gravity.cross(&b[0]),
            gravity.cross(&b[1]),
            gravity.cross(&b[2]),
        ]
    };
    let mut fit = PathFit {
        path: path.to_vec(),
        heading_rad,
    };
    let scale: f64 = basis
        .iter()
        .map(|b| b.iter().map(|v| v.norm_squared()).sum::<f64>())
        .sum::<f64>()
        / 3.0;
    let ridge = BIAS_RIDGE * scale + 1e-12;
    for round in 0..FIT_ROUNDS {
        let turn = Rotation3::from_axis_angle(up, fit.heading_rad);
        let mut normal = Matrix9::zeros();
        let mut rhs = Vector9::zeros();
        for (i, (p, b)) in path.iter().zip(basis).enumerate() {
            let t = target.map_or(&zero, |t| &t[i]);
            let mut a = nalgebra::SMatrix::<f64, 3, 9>::zeros();
            for (j, column) in columns(b).iter().enumerate() {
                a.set_column(j, &(keep * (turn * column)));
            }
            a.fixed_view_mut::<3, 3>(0, 6).copy_from(&keep);
            // r = (R·p − t) − A·x with x = (b, δ, c).
            let y = keep * (turn * p - t);
            normal += a.transpose() * a;
            rhs += a.transpose() * y;
        }
        for j in 0..9 {
            normal[(j, j)] += match j {
                0..3 => ridge,
                3..6 => ridge * gravity.norm_squared(),
                _ => 1e-9,
            };
        }
        let Some(x) = normal.cholesky().map(|c| c.solve(&rhs)) else {
            break;
        };
        fit.path = path
            .iter()
            .zip(basis)
            .map(|(p, b)| {
                let drift: Vector3<f64> =
                    columns(b).iter().zip(x.iter()).map(|(c, w)| c * *w).sum();
                p - drift
            })
            .collect();
        if let Some(target) = target
            && round + 1 < FIT_ROUNDS
        {
            fit.heading_rad = align_about(up, &horizontal_path(&fit.path, up), target);
        }
    }
    fit
}

/// The paths a unit residual accelerometer bias along each of the sensor's axes adds to its
/// integrated path: `B_j(t) = ∫∫ (R_IS(τ) − R̄_IS)·e_j` (the offset measured at the stand, `R̄_IS·b`,
/// is already removed, so only the part the walk's rotations move remains).
fn bias_paths(samples: &[Sample], k: usize, stand: &Rotation3<f64>) -> Vec<[Vector3<f64>; 3]> {
    let mut p = [Vector3::zeros(); 3];
    let mut v = [Vector3::zeros(); 3];
    let mut out = Vec::with_capacity(samples.len());
    out.push(p);
    for pair in samples.windows(2) {
        let dt = pair[1].time_s - pair[0].time_s;
        let delta = pair[0].sensors[k].inertial_from_sensor.matrix() - stand.matrix();
        for j in 0..3 {
            let a = delta.column(j).into_owned();
            p[j] += v[j] * dt + a * (0.5 * dt * dt);
            v[j] += a * dt;
        }
        out.push(p);
    }
    out
}

fn horizontal_path(path: &[Vector3<f64>], up: &Unit<Vector3<f64>>) -> Vec<Vector3<f64>> {
    path.iter().map(|p| horizontal(p, up)).collect()
}

/// The rotation about `up` (rad) that best turns `path` onto `target` in the least-squares sense,
/// allowing a constant offset between them (both paths centred first): a limb that holds itself
/// differently while walking than while standing (forearms forward, a wider stance) is shifted,
/// not turned.
fn align_about(up: &Unit<Vector3<f64>>, path: &[Vector3<f64>], target: &[Vector3<f64>]) -> f64 {
    let (path_mean, target_mean) = (mean(path), mean(target));
    let (sin, cos) = path.iter().zip(target).fold((0.0, 0.0), |(s, c), (p, t)| {
        let (p, t) = (p - path_mean, t - target_mean);
        (s + p.cross(&t).dot(up), c + p.dot(&t))
    });
    sin.atan2(cos)
}

/// RMS distance (m) between `path` turned by `psi` about `up` and `target`, both centred.
fn path_mismatch_m(
    up: &Unit<Vector3<f64>>,
    psi: f64,
    path: &[Vector3<f64>],
    target: &[Vector3<f64>],
) -> f64 {
    let turn = Rotation3::from_axis_angle(up, psi);
    let (path_mean, target_mean) = (mean(path), mean(target));
    let sum: f64 = path
        .iter()
        .zip(target)
        .map(|(p, t)| (turn * (p - path_mean) - (t - target_mean)).norm_squared())
        .sum();
    (sum / path.len().max(1) as f64).sqrt()
}

fn mean(points: &[Vector3<f64>]) -> Vector3<f64> {
    points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64
}

/// The pelvis walked far enough and straight enough for its path to define a direction.
fn check_walk(
    pelvis: &[Vector3<f64>],
    up: &Unit<Vector3<f64>>,
    config: &WalkStartConfig,
) -> Result<(), Rejection> {
    let end = pelvis.last().copied().unwrap_or_else(Vector3::zeros);
    let length_m = end.norm();
    if length_m < config.min_walk_m {
        return Err(Rejection::WalkTooShort {
            length_m,
            min_m: config.min_walk_m,
            walk_s: config.walk_s,
        });
    }
    // The second half of the walk should go the same way as the whole of it.
    let middle = pelvis[pelvis.len() / 2];
    let turn_deg = signed_angle_about(up, &end, &(end - middle))
        .abs()
        .to_degrees();
    if turn_deg > config.max_walk_turn_deg {
        return Err(Rejection::WalkTurned {
            turn_deg,
            max_deg: config.max_walk_turn_deg,
        });
    }
    Ok(())
}
