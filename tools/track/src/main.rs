//! Tracks the true motion of clips with the validation simulation and prints the scores, the time
//! per frame and what preceded the falls: the quickest way to try the controller's gains.
//!
//! ```text
//! cargo run --release -p imuflow-track -- CLIP [FIRST [COUNT]]
//! cargo run --release -p imuflow-track -- @LIST    # one clip path a line
//! ```
//!
//! CLIP is a recording with a truth channel (`models/sample/walk.mcap`) or a Bandai Namco BVH.
//! With @LIST, torques mode only, the totals over the clips. Variables override the defaults:
//! `SIM_KP`, `SIM_KD`, `SIM_BKP`, `SIM_BKD`, `SIM_PKP`, `SIM_PKV`, `SIM_RKP`, `SIM_RKD`,
//! `SIM_CLEAR`, `SIM_FRICTION`, `SIM_MAXTAU`, `SIM_SUBSTEPS`, `SIM_ITERS`, `SIM_SWEEPS`, `SIM_JOINTS`, `SIM_FOOT_PITCH` (the SimConfig
//! fields and the stage parameters of the same meaning); `SIM_MODES=torques,residual` picks the
//! modes of a single clip; `SIM_TRACE=1` prints every frame (root offset from the estimate, pelvis
//! and trunk tilt, the feet's loads and the estimate's ball heights; the pelvis's heading
//! difference and both root velocities); `SIM_FEET=1` prints the
//! estimate's stance-foot pitch instead of simulating (see `model::DEFAULT_FOOT_PITCH_DEG`);
//! `SIM_COP=1` (a clip or @LIST) does not simulate either: it asks whether the estimate could be
//! carried by its feet at all (the centre of pressure its motion needs, against the support
//! polygon of the feet within `SIM_COP_HEIGHT` m of the floor, default 0.02; finite differences
//! over `SIM_COP_FRAMES` frames each way, default 2).

use std::path::Path;

use anyhow::Context;
use imuflow_body::body_model::{BodyModel, BodyParams};
use imuflow_body::kinematics::{FkData, Pose, forward_kinematics};
use imuflow_body::skeleton::JointId;
use imuflow_recording::{Recorded, Recording};
use imuflow_synth::{Motion, Options};
use imuflow_validation::model::DEFAULT_FOOT_PITCH_DEG;
use imuflow_validation::sim::Joints;
use imuflow_validation::{FallRule, Mode, SimConfig, SimModel, Validator};
use nalgebra::Vector3;

const DT: f64 = 1.0 / 60.0;
const FEET: [JointId; 2] = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT];
/// How far back a fall looks for what preceded it, frames (0.5 s).
const LOOKBACK: usize = 30;

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
    let clip = args.first().map_or("models/sample/walk.mcap", |s| s);
    if std::env::var("SIM_COP").is_ok() {
        return support(&body, clip);
    }
    if let Some(list) = clip.strip_prefix('@') {
        return batch(&body, Path::new(list));
    }
    let first: usize = args.get(1).map_or(Ok(0), |s| s.parse())?;
    let count: usize = args.get(2).map_or(Ok(usize::MAX), |s| s.parse())?;
    let poses: Vec<Pose> = load(Path::new(clip))?
        .into_iter()
        .skip(first)
        .take(count)
        .collect();
    if std::env::var("SIM_FEET").is_ok() {
        stance_pitch(&body, &poses);
        return Ok(());
    }
    let modes = std::env::var("SIM_MODES").unwrap_or_else(|_| "torques,residual".into());
    for mode in modes.split(',').filter_map(Mode::parse) {
        let run = track(&body, mode, &poses, first);
        println!(
            "{mode:?}: {}",
            run.validator.stats.summary_line(mode == Mode::Residual)
        );
        println!("  falls at frames {:?}", run.falls);
    }
    Ok(())
}

/// Torques mode over every clip of `list`: the totals, and what preceded the falls and resyncs.
fn batch(body: &BodyModel, list: &Path) -> anyhow::Result<()> {
    let (mut frames, mut falls, mut resyncs) = (0u64, 0u64, 0u64);
    let (mut tracking, mut pose) = (0.0, 0.0);
    let mut causes = Causes::default();
    let mut step_us = Vec::new();
    let (mut judged, mut violated) = (0u64, 0u64);
    for clip in clip_list(list)? {
        let run = track(body, Mode::Torques, &load(Path::new(&clip))?, 0);
        let s = &run.validator.stats;
        if std::env::var("SIM_VERBOSE").is_ok() {
            println!("{clip}: {}", s.summary_line(false));
        }
        frames += s.frames;
        falls += s.falls;
        resyncs += s.resyncs;
        tracking += s.tracking_error_mean_m() * s.frames as f64;
        pose += s.pose_error_mean_m() * s.frames as f64;
        step_us.extend_from_slice(&s.step_us[1..]);
        causes.add(&run.causes);
        judged += s.support_judged;
        violated += s.support_violated();
    }
    step_us.sort_by(f64::total_cmp);
    println!(
        "{frames} frames: falls {falls} ({:.1}/min), resyncs {resyncs} ({:.1}/min), tracking {:.1} cm, pose {:.1} cm, p50 {:.0} µs/frame, support violated on {:.1} % of {judged} judged frames",
        falls as f64 * 3600.0 / frames as f64,
        resyncs as f64 * 3600.0 / frames as f64,
        100.0 * tracking / frames as f64,
        100.0 * pose / frames as f64,
        step_us.get(step_us.len() / 2).copied().unwrap_or(0.0),
        100.0 * violated as f64 / judged.max(1) as f64,
    );
    println!(
        "of the {} falls and resyncs, {} followed a scuff (a simulated foot loaded while the estimate's sole, ball and heel, is 3 cm up) and {} a bounce (no simulated foot loaded while an estimate's foot is down) within 0.5 s",
        causes.failures, causes.after_scuff, causes.after_bounce
    );
    let [a, b, c, d] = causes.since_reset;
    println!(
        "after the start or the previous reset: {a} within 0.5 s, {b} in 0.5-1 s, {c} in 1-2 s, {d} later"
    );
    Ok(())
}

/// What preceded the failures of a run.
#[derive(Default)]
struct Causes {
    failures: u32,
    after_scuff: u32,
    after_bounce: u32,
    /// Failures within 0.5 s, 0.5-1 s, 1-2 s and later after the start or the previous reset.
    since_reset: [u32; 4],
}

impl Causes {
    fn add(&mut self, other: &Causes) {
        self.failures += other.failures;
        self.after_scuff += other.after_scuff;
        self.after_bounce += other.after_bounce;
        for (a, b) in self.since_reset.iter_mut().zip(other.since_reset) {
            *a += b;
        }
    }
}

struct Run {
    validator: Validator,
    falls: Vec<usize>,
    causes: Causes,
}

fn config(mode: Mode) -> SimConfig {
    let joints = std::env::var("SIM_JOINTS")
        .ok()
        .map(|name| Joints::parse(&name).expect("SIM_JOINTS: multibody or impulse"))
        .unwrap_or(SimConfig::default().joints);
    let d = SimConfig::for_joints(joints);
    SimConfig {
        mode,
        kp: env_f64("SIM_KP", d.kp),
        kd: env_f64("SIM_KD", d.kd),
        max_torque_nm_per_kg: env_f64("SIM_MAXTAU", d.max_torque_nm_per_kg),
        balance_kp: env_f64("SIM_BKP", d.balance_kp),
        balance_kd: env_f64("SIM_BKD", d.balance_kd),
        placement_kp: env_f64("SIM_PKP", d.placement_kp),
        placement_kv: env_f64("SIM_PKV", d.placement_kv),
        residual_kp: env_f64("SIM_RKP", d.residual_kp),
        residual_kd: env_f64("SIM_RKD", d.residual_kd),
        clearance_gain: env_f64("SIM_CLEAR", d.clearance_gain),
        friction: env_f64("SIM_FRICTION", d.friction),
        substeps: env_f64("SIM_SUBSTEPS", d.substeps as f64) as usize,
        solver_iterations: env_f64("SIM_ITERS", d.solver_iterations as f64) as usize,
        solver_sweeps: env_f64("SIM_SWEEPS", d.solver_sweeps as f64) as usize,
        joints,
    }
}

fn track(body: &BodyModel, mode: Mode, poses: &[Pose], first: usize) -> Run {
    let model = SimModel::with_foot_pitch(body, env_f64("SIM_FOOT_PITCH", DEFAULT_FOOT_PITCH_DEG));
    let mut validator = Validator::new(model, config(mode), FallRule::default());
    let trace = std::env::var("SIM_TRACE").is_ok();
    let mut fk = FkData::new();
    let (mut falls, mut causes) = (Vec::new(), Causes::default());
    let mut recent: Vec<(bool, bool)> = Vec::new();
    let mut last_reset = 0;
    let mut previous_ball: Option<Vector3<f64>> = None;
    let ankle_rest_m = body.rest_positions_on_floor_m().map(|p| p.y);
    for (i, pose) in poses.iter().enumerate() {
        let Some(o) = validator.frame(Some(pose), DT) else {
            continue;
        };
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let load = |f: &JointId| o.forces.contact_force_n[f.index()].y;
        let height = |f: &JointId| fk.joint_in_world_m[f.index()].y;
        // The estimate's sole: the lower of its ball and its heel (the ankle's height above its
        // standing height); a landing heel with the toes up is not a scuff.
        let sole = |f: &JointId| {
            let ankle = f.parent().expect("feet have ankles").index();
            height(f).min(fk.joint_in_world_m[ankle].y - ankle_rest_m[ankle])
        };
        let scuff = FEET.iter().any(|f| load(f) > 50.0 && sole(f) > 0.03);
        let bounce = FEET.iter().all(|f| load(f) < 5.0) && FEET.iter().any(|f| height(f) < 0.01);
        recent.push((scuff, bounce));
        if o.fell || o.resynced {
            let window = &recent[recent.len().saturating_sub(LOOKBACK)..];
            causes.failures += 1;
            causes.after_scuff += u32::from(window.iter().any(|w| w.0));
            causes.after_bounce += u32::from(window.iter().any(|w| w.1));
            let since = (i - last_reset) as f64 * DT;
            causes.since_reset[[0.5, 1.0, 2.0].iter().filter(|&&t| since >= t).count()] += 1;
            last_reset = i;
        }
        if o.fell {
            falls.push(first + i);
        }
        if std::env::var("SIM_JOINTS")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            == Some(first + i)
        {
            for j in JointId::all() {
                let e = o.state.joint_position_m[j.index()] - fk.joint_in_world_m[j.index()];
                println!("{j:?}: {:.3} m", e.norm());
            }
        }
        if trace {
            let tilt = |j: usize| {
                (o.state.world_from_joint[j] * Vector3::y())
                    .angle(&(fk.world_from_joint[j] * Vector3::y()))
                    .to_degrees()
            };
            let d = o.state.joint_position_m[0] - fk.joint_in_world_m[0];
            let heading = |r: &nalgebra::Rotation3<f64>| {
                let f = r * Vector3::z();
                f.x.atan2(f.z).to_degrees()
            };
            let yaw = heading(&o.state.world_from_joint[0]) - heading(&fk.world_from_joint[0]);
            let estimate_velocity = i.checked_sub(1).map_or(Vector3::zeros(), |p| {
                (pose.root_in_world_m - poses[p].root_in_world_m) / DT
            });
            let sim_velocity = o.state.joint_velocity_mps[0];
            println!(
                "{:5} yaw {:+6.1}° v est {:+.2} {:+.2} sim {:+.2} {:+.2}",
                first + i,
                (yaw + 540.0) % 360.0 - 180.0,
                estimate_velocity.x,
                estimate_velocity.z,
                sim_velocity.x,
                sim_velocity.z
            );
            let ankle = JointId::LEFT_ANKLE.index();
            let knee = JointId::LEFT_KNEE.index();
            let bend = |r: &nalgebra::Rotation3<f64>| r.angle().to_degrees();
            let ball = fk.joint_in_world_m[FEET[0].index()];
            let ball_speed = previous_ball.map_or(0.0, |b| (ball - b).xz().norm() / DT);
            previous_ball = Some(ball);
            println!(
                "{:5} left: ball est {:.3} sim {:.3} (est moves {:.2} m/s), ankle est {:.3} sim {:.3} m, knee est {:5.1}° sim {:5.1}°",
                first + i,
                ball.y,
                o.state.joint_position_m[FEET[0].index()].y,
                ball_speed,
                fk.joint_in_world_m[ankle].y,
                o.state.joint_position_m[ankle].y,
                bend(&pose.parent_from_joint[knee]),
                bend(&o.state.pose.parent_from_joint[knee]),
            );
            println!(
                "{:5} track {:.3} root {:+.3} {:+.3} {:+.3} pelvis {:5.1}° trunk {:5.1}° load L {:5.0} R {:5.0} N, estimate's balls L {:.3} R {:.3} m{}",
                first + i,
                o.score.tracking_error_m,
                d.x,
                d.y,
                d.z,
                tilt(0),
                tilt(JointId::SPINE3.index()),
                load(&FEET[0]),
                load(&FEET[1]),
                height(&FEET[0]),
                height(&FEET[1]),
                if o.fell {
                    " FELL"
                } else if o.resynced {
                    " RESYNC"
                } else {
                    ""
                }
            );
        }
    }
    Run {
        validator,
        falls,
        causes,
    }
}

/// The true poses of a BVH (retargeted, 60 Hz) or of a recording's truth channel.
/// The clip paths of a list file, one a line (blank lines skipped).
fn clip_list(list: &Path) -> anyhow::Result<Vec<String>> {
    let text = std::fs::read_to_string(list).with_context(|| list.display().to_string())?;
    Ok(text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(str::to_owned)
        .collect())
}

fn load(path: &Path) -> anyhow::Result<Vec<Pose>> {
    if path.extension().is_some_and(|e| e == "bvh") {
        return Ok(Motion::load(path, &Options::default(), 60.0)?.clip.poses);
    }
    let recording = Recording::load(path, None, None)?;
    let poses: Vec<Pose> = recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) => Pose::from_wire(&m.local_pose_wxyz, &m.root_position_m).ok(),
            Recorded::Imu(_) => None,
        })
        .collect();
    anyhow::ensure!(!poses.is_empty(), "{}: no truth channel", path.display());
    Ok(poses)
}

/// Whether the estimate's motion could be carried by its feet at all: per frame, the floor's
/// force and moment the motion needs (inverse dynamics of the whole body, the root rows; finite
/// differences over two frames each way, as the data is 30 Hz resampled to 60), the centre of
/// pressure that force must act at on the floor, and how far it lies outside the support polygon
/// (the convex hull of the sole corners, heel and ball, of the feet within 2 cm of the floor).
/// A controller with joint torques and foot contacts cannot follow frames whose centre of
/// pressure is outside the feet, or which need the floor to pull.
fn support(body: &BodyModel, clip: &str) -> anyhow::Result<()> {
    use imuflow_body::dynamics::{DofVector, DynamicsData, RigidBodyModel};
    use imuflow_validation::support::{distance_outside_hull, floor_force, velocity};
    let clips = match clip.strip_prefix('@') {
        Some(list) => clip_list(Path::new(list))?,
        None => vec![clip.to_owned()],
    };
    let model = RigidBodyModel::new(body);
    let mut data = DynamicsData::new();
    let rest = body.rest_positions_on_floor_m();
    let half_width = 0.045 * body.stature_m / 1.75;
    let contact_height = env_f64("SIM_COP_HEIGHT", 0.02);
    let (mut frames, mut supported, mut pulling) = (0u64, 0u64, 0u64);
    let mut outside: Vec<f64> = Vec::new();
    // The same with the centre of mass alone (no change of angular momentum): a second opinion.
    let mut outside_com: Vec<f64> = Vec::new();
    let (mut along_cop, mut along_com) = (Vec::new(), Vec::new());
    let mut standing: Vec<f64> = Vec::new();
    let (mut lean, mut pelvis_ahead): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    // Frames each way of the finite differences (2: one frame of the 30 Hz data).
    let k = env_f64("SIM_COP_FRAMES", 2.0).max(1.0) as usize;
    let dt = k as f64 * DT;
    for path in &clips {
        let poses = load(Path::new(path))?;
        for t in k..poses.len().saturating_sub(k) {
            let (before, now, after) = (&poses[t - k], &poses[t], &poses[t + k]);
            let mut com = [Vector3::zeros(); 3];
            for (c, pose) in com.iter_mut().zip([before, now, after]) {
                data.set_state(&model, pose, &DofVector::zeros());
                *c = data.center_of_mass(&model);
            }
            let a_com = (com[2] - 2.0 * com[1] + com[0]) / (dt * dt);
            let zmp = nalgebra::Vector2::new(
                com[1].x - com[1].y * a_com.x / (a_com.y + 9.81),
                com[1].z - com[1].y * a_com.z / (a_com.y + 9.81),
            );
            let v0 = velocity(before, now, dt);
            let v1 = velocity(now, after, dt);
            let v = (v0 + v1) / 2.0;
            let vdot = (v1 - v0) / dt;
            data.set_state(&model, now, &v);
            let mut tau = DofVector::zeros();
            data.inverse_dynamics(&model, &vdot, &mut tau);
            frames += 1;
            // The pelvis, for which side of a stance foot is outward.
            let origin = data.fk().joint_in_world_m[0];
            let Some(cop) = floor_force(&data, &tau).1 else {
                pulling += 1;
                continue;
            };
            let mut corners = Vec::new();
            let mut feet_down = Vec::new();
            for foot in FEET {
                let ankle = foot.parent().expect("feet have ankles");
                let (a, b) = (ankle.index(), foot.index());
                let foot_length = (rest[b].z - rest[a].z) / 0.45;
                let heel_in_ankle = Vector3::new(0.0, -rest[a].y, -0.25 * foot_length);
                let ball_in_ankle = rest[b] - rest[a] - Vector3::new(0.0, rest[b].y, 0.0);
                for point in [heel_in_ankle, ball_in_ankle] {
                    for side in [-1.0, 1.0] {
                        let p = data.point_position(
                            ankle,
                            &(point + Vector3::new(side * half_width, 0.0, 0.0)),
                        );
                        if p.y < contact_height {
                            corners.push(nalgebra::Vector2::new(p.x, p.z));
                        }
                    }
                }
                let heel = data.point_position(ankle, &heel_in_ankle);
                let ball = data.point_position(ankle, &ball_in_ankle);
                if heel.y.min(ball.y) < contact_height {
                    feet_down.push((heel.xz(), ball.xz()));
                }
            }
            // Standing still on both feet: where the centre of mass is over the feet.
            if let [(h0, b0), (h1, b1)] = feet_down[..]
                && a_com.norm() < 0.3
            {
                let axis = ((b0 - h0) + (b1 - h1)).normalize();
                let heels = (h0 + h1) / 2.0;
                standing.push((com[1].xz() - heels).dot(&axis));
                // The trunk's lean (pelvis to neck, forward positive) and the pelvis over the heels.
                let fk = data.fk();
                let pelvis = fk.joint_in_world_m[0];
                let neck = fk.joint_in_world_m[JointId::NECK.index()];
                let up = neck - pelvis;
                lean.push(up.xz().dot(&axis).atan2(up.y).to_degrees());
                pelvis_ahead.push((pelvis.xz() - heels).dot(&axis));
            }
            // Where along the single stance foot the needed centre of pressure lies: forward from
            // the heel (m, the ball at the foot's length) and sideways from its midline.
            if let [(heel, ball)] = feet_down[..] {
                let axis = (ball - heel).normalize();
                // Sideways positive away from the pelvis (outward).
                let outward = axis.perp(&(heel - origin.xz())).signum();
                for (point, list) in [(cop, &mut along_cop), (zmp, &mut along_com)] {
                    let d = point - heel;
                    list.push((d.dot(&axis), outward * axis.perp(&d), (ball - heel).norm()));
                }
            }
            if corners.is_empty() {
                continue;
            }
            supported += 1;
            outside.push(distance_outside_hull(&cop, &corners));
            outside_com.push(distance_outside_hull(&zmp, &corners));
        }
    }
    outside.sort_by(f64::total_cmp);
    outside_com.sort_by(f64::total_cmp);
    let share_of = |values: &[f64], d: f64| {
        values.iter().filter(|x| **x > d).count() as f64 / values.len().max(1) as f64 * 100.0
    };
    let share = |d: f64| share_of(&outside, d);
    let share_com = |d: f64| share_of(&outside_com, d);
    println!(
        "{} clips, {frames} frames: {supported} with a foot down, {pulling} needing the floor to pull; centre of pressure outside the feet by > 1 cm in {:.1} %, > 3 cm in {:.1} %, > 10 cm in {:.1} % of the frames with a foot down (median {:.1} cm, p90 {:.1} cm)",
        clips.len(),
        share(0.01),
        share(0.03),
        share(0.10),
        outside.get(outside.len() / 2).copied().unwrap_or(0.0) * 100.0,
        outside.get(outside.len() * 9 / 10).copied().unwrap_or(0.0) * 100.0,
    );
    println!(
        "  from the centre of mass alone (its acceleration, no angular momentum): outside by > 3 cm in {:.1} %, > 10 cm in {:.1} % (median {:.1} cm)",
        share_com(0.03),
        share_com(0.10),
        outside_com
            .get(outside_com.len() / 2)
            .copied()
            .unwrap_or(0.0)
            * 100.0,
    );
    if !standing.is_empty() {
        let cm = |values: &mut Vec<f64>, q: f64| quantile(values, q) * 100.0;
        println!(
            "  standing still on both feet ({} frames): centre of mass forward of the heels p10/p50/p90 {:.1}/{:.1}/{:.1} cm",
            standing.len(),
            cm(&mut standing, 0.1),
            cm(&mut standing, 0.5),
            cm(&mut standing, 0.9)
        );
        println!(
            "    the trunk (pelvis to neck) leans forward by {:.1}° (median); the pelvis is {:.1} cm forward of the heels",
            quantile(&mut lean, 0.5),
            cm(&mut pelvis_ahead, 0.5)
        );
    }
    for (name, list) in [
        ("inverse dynamics", &along_cop),
        ("centre of mass", &along_com),
    ] {
        let cm = |values: &mut Vec<f64>, q: f64| quantile(values, q) * 100.0;
        let mut forward: Vec<f64> = list.iter().map(|x| x.0).collect();
        let mut side: Vec<f64> = list.iter().map(|x| x.1).collect();
        let length = list.first().map_or(0.0, |x| x.2) * 100.0;
        let behind = list.iter().filter(|x| x.0 < 0.0).count() as f64;
        let beyond = list.iter().filter(|x| x.0 > x.2).count() as f64;
        let n = list.len().max(1) as f64;
        println!(
            "  single stance ({} frames, {name}): forward from the heel p10/p50/p90 {:.1}/{:.1}/{:.1} cm (ball at {length:.1}); behind the heel {:.0} %, past the ball {:.0} %; outward p10/p50/p90 {:.1}/{:.1}/{:.1} cm",
            list.len(),
            cm(&mut forward, 0.1),
            cm(&mut forward, 0.5),
            cm(&mut forward, 0.9),
            100.0 * behind / n,
            100.0 * beyond / n,
            cm(&mut side, 0.1),
            cm(&mut side, 0.5),
            cm(&mut side, 0.9),
        );
    }
    Ok(())
}

/// The `q` quantile of `values` (sorted in place; the element at `(n − 1)·q`, 0 when empty).
fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => 0.0,
        n => values[((n - 1) as f64 * q) as usize],
    }
}

/// The stance feet's pitch in the estimate: over the frames where a ball of the foot is within
/// 1.5 cm of the floor and moves slower than 0.1 m/s, degrees toe-down from the rest pose.
fn stance_pitch(body: &BodyModel, poses: &[Pose]) {
    let ankles = [JointId::LEFT_ANKLE, JointId::RIGHT_ANKLE];
    let mut fk = FkData::new();
    let mut pitches = Vec::new();
    let mut previous: Option<[Vector3<f64>; 2]> = None;
    for pose in poses {
        forward_kinematics(&body.skeleton, pose, &mut fk);
        let balls = FEET.map(|f| fk.joint_in_world_m[f.index()]);
        if let Some(before) = previous {
            for side in 0..2 {
                let speed = (balls[side] - before[side]).xz().norm() / DT;
                if balls[side].y < 0.015 && speed < 0.1 {
                    let toe = fk.world_from_joint[ankles[side].index()] * Vector3::z();
                    pitches.push(-toe.y.asin().to_degrees());
                }
            }
        }
        previous = Some(balls);
    }
    if pitches.is_empty() {
        println!("no stance frames");
        return;
    }
    println!(
        "stance pitch over {} foot-frames: p10 {:.1}°, median {:.1}°, p90 {:.1}°",
        pitches.len(),
        quantile(&mut pitches, 0.1),
        quantile(&mut pitches, 0.5),
        quantile(&mut pitches, 0.9)
    );
}
