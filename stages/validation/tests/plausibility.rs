//! The validator on true motion (the bundled sample's truth: a calibration prelude, then 13 s of a
//! test-split walk) and on motions built to be implausible: a floating root, sliding feet, a body
//! leaning past its balance. Each asserts what the simulation must measure.

use std::path::Path;

use imuflow_body::body_model::{BodyModel, BodyParams};
use imuflow_body::kinematics::Pose;
use imuflow_body::skeleton::JointId;
use imuflow_recording::{Recorded, Recording};
use imuflow_validation::sim::Joints;
use imuflow_validation::{FallRule, Mode, SimConfig, SimModel, Stats, Validator};
use nalgebra::{Rotation3, Vector3};

const DT: f64 = 1.0 / 60.0;
/// models/sample/README.md: 12.2 s of calibration prelude (T-pose hold, stand, one step, stand).
const PRELUDE_FRAMES: usize = 732;

fn body() -> BodyModel {
    // The sample was synthesized on the default subject (1.75 m, 70 kg).
    BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
}

fn validator(mode: Mode) -> Validator {
    validator_joined(mode, SimConfig::default().joints)
}

/// Both ways of joining the links: every property below that does not depend on them is checked
/// for both (the default first).
const JOININGS: [Joints; 2] = [Joints::Impulse, Joints::Multibody];

fn validator_joined(mode: Mode, joints: Joints) -> Validator {
    let config = SimConfig {
        mode,
        ..SimConfig::for_joints(joints)
    };
    Validator::new(SimModel::new(&body()), config, FallRule::default())
}

fn sample_truth() -> Vec<Pose> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sample/walk.mcap");
    let recording = Recording::load(&path, None, None).unwrap();
    recording
        .frames
        .iter()
        .filter_map(|f| match f {
            Recorded::Truth(m) => {
                Some(Pose::from_wire(&m.local_pose_wxyz, &m.root_position_m).unwrap())
            }
            Recorded::Imu(_) => None,
        })
        .collect()
}

/// Runs `poses` through a validator; returns it and each frame's (residual fraction, skate, root error).
fn run(mode: Mode, poses: &[Pose]) -> (Validator, Vec<(f64, Option<f64>, f64)>) {
    run_joined(mode, SimConfig::default().joints, poses)
}

fn run_joined(
    mode: Mode,
    joints: Joints,
    poses: &[Pose],
) -> (Validator, Vec<(f64, Option<f64>, f64)>) {
    let mut v = validator_joined(mode, joints);
    let mut per_frame = Vec::new();
    for pose in poses {
        let o = v.frame(Some(pose), DT).unwrap();
        per_frame.push((
            o.score.residual_force_fraction,
            o.score.foot_skate_mps,
            o.score.root_error_m,
        ));
    }
    (v, per_frame)
}

fn report(name: &str, stats: &Stats) {
    eprintln!("{name}: {}", stats.summary_line(true));
}

/// A standing pose of the prelude (the N-pose stand after the T-pose hold, 5 s in).
fn standing(truth: &[Pose]) -> Pose {
    truth[300].clone()
}

#[test]
fn standing_still_carries_the_body_weight_on_the_feet_without_falling() {
    let pose = standing(&sample_truth());
    for joints in JOININGS {
        stands_still(&pose, joints);
    }
}

fn stands_still(pose: &Pose, joints: Joints) {
    let mut v = validator_joined(Mode::Torques, joints);
    let mut vertical = Vec::new();
    for _ in 0..180 {
        let o = v.frame(Some(pose), DT).unwrap();
        let total: f64 = o.forces.contact_force_n.iter().map(|f| f.y).sum();
        vertical.push(total);
        // Only the feet touch the floor.
        let feet = (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index());
        assert_eq!(o.contact_mask & !feet, 0, "mask {:#x}", o.contact_mask);
    }
    report(&format!("standing, {joints:?}"), &v.stats);
    assert_eq!(v.stats.falls, 0);
    // After the first second: the floor carries m·g (within 3 %), the joints hold the pose.
    let weight = v.model().total_mass_kg * 9.81;
    let settled = &vertical[60..];
    let mean = settled.iter().sum::<f64>() / settled.len() as f64;
    assert!(
        (mean / weight - 1.0).abs() < 0.03,
        "floor force {mean:.1} N, weight {weight:.1} N"
    );
    assert!(
        v.stats.pose_error_mean_m() < 0.02,
        "{}",
        v.stats.pose_error_mean_m()
    );
    assert!(
        v.stats.foot_skate_mean_mps() < 0.02,
        "{}",
        v.stats.foot_skate_mean_mps()
    );
    assert!(v.stats.penetration_max_m < 0.02);
    // The controller-free score agrees: every judged frame is carried inside the feet.
    assert_eq!(v.stats.support_judged, 180 - 4);
    assert_eq!(v.stats.support_violated_fraction(), 0.0);
}

/// With the root helped (residual mode, rapier's default of one solver iteration per step) the
/// true walk is tracked without a fall and every score stays finite: the residual PD once pushed
/// the pelvis link alone, which diverged to NaN at 240 Hz once rapier stopped sub-stepping it four
/// times; it now accelerates the whole body as one piece.
#[test]
fn the_true_walk_is_tracked_in_residual_mode_without_falls() {
    let truth = sample_truth();
    let walk = &truth[PRELUDE_FRAMES..];
    for joints in JOININGS {
        let (r, frames) = run_joined(Mode::Residual, joints, walk);
        report(&format!("true walk, residual, {joints:?}"), &r.stats);
        assert_eq!(r.stats.falls, 0, "{}", r.stats.summary_line(true));
        assert!(frames.iter().all(|f| f.0.is_finite() && f.2.is_finite()));
        // Measured on this walk: tracking 3.5 cm mean with the multibody, 2.0 cm with impulse
        // joints, about 0.25 mg of help on average.
        assert!(
            r.stats.tracking_error_mean_m() < 0.08,
            "{}",
            r.stats.summary_line(true)
        );
        assert!(r.stats.residual_force_mean_fraction() < 0.7);
        // Impulse joints give a little under load, never enough to show.
        assert!(
            r.stats.joint_gap_max_m < 0.01,
            "{}",
            r.stats.summary_line(true)
        );
    }
}

#[test]
fn swing_clearance_takes_falls_off_the_true_walk() {
    // The swing foot scuffing the floor preceded most falls on true walks; bending the swing knee
    // while the simulated foot hangs below the estimate's should trip the body less. Measured on
    // the sample: 8 falls without, 4 with (on the test split's 87 walks 23.6 -> 16.6 a minute).
    let walk = &sample_truth()[PRELUDE_FRAMES..];
    let falls = |clearance_gain: f64| {
        let config = SimConfig {
            clearance_gain,
            ..SimConfig::default()
        };
        let mut v = Validator::new(SimModel::new(&body()), config, FallRule::default());
        for pose in walk {
            v.frame(Some(pose), DT);
        }
        v.stats.falls
    };
    let (without, with) = (falls(0.0), falls(SimConfig::default().clearance_gain));
    assert!(
        with < without,
        "falls with swing clearance {with}, without {without}"
    );
}

/// Issue 10's target, not met yet: with the root unactuated the true walk still falls about 10
/// times a minute (foot placement, the stance-hip feedback and the swing clearance help; hard
/// landings that bounce the body, and a body that loses speed over its stance leg and drifts
/// behind the estimate, precede most falls and resyncs). Run with
/// `cargo test -p imuflow-validation -- --ignored` to see the numbers.
#[test]
#[ignore = "the tracking controller cannot walk the true motion yet (issue 10 note)"]
fn the_true_walk_is_tracked_without_falls_in_torques_mode() {
    let truth = sample_truth();
    let walk = &truth[PRELUDE_FRAMES..];
    let (v, _) = run(Mode::Torques, walk);
    report("true walk, torques", &v.stats);
    assert_eq!(v.stats.falls, 0, "{}", v.stats.summary_line(false));
}

#[test]
fn a_floating_root_needs_the_body_weight_as_residual_force() {
    let truth = sample_truth();
    let stand = standing(&truth);
    // 1 s standing, 2 s with the whole body lifted 0.3 m, 1 s standing again.
    let mut poses = vec![stand.clone(); 240];
    for p in &mut poses[60..180] {
        p.root_in_world_m.y += 0.3;
    }
    let (v, frames) = run(Mode::Residual, &poses);
    report("floating, residual", &v.stats);
    let lifted: f64 = frames[90..180].iter().map(|f| f.0).sum::<f64>() / 90.0;
    let grounded: f64 = frames[30..60].iter().map(|f| f.0).sum::<f64>() / 30.0;
    assert!(lifted > 0.7, "residual force while floating {lifted:.2} mg");
    assert!(
        grounded < 0.1,
        "residual force while standing {grounded:.2} mg"
    );
    // Without the residual help the body cannot follow: it stays on the floor, 0.3 m below.
    let (t, frames) = run(Mode::Torques, &poses);
    report("floating, torques", &t.stats);
    let root_error: f64 = frames[90..180].iter().map(|f| f.2).sum::<f64>() / 90.0;
    assert!(
        root_error > 0.2,
        "root error while floating {root_error:.2} m"
    );
    // Without any simulation: the floating frames need the floor to hold up a body with no foot
    // on it (120 frames, less the few around the jumps up and down whose differences span them).
    assert!(
        t.stats.support_unsupported >= 110,
        "{}",
        t.stats.summary_line(false)
    );
    assert!(
        t.stats.support_outside <= 10,
        "{}",
        t.stats.summary_line(false)
    );
}

#[test]
fn feet_sliding_while_standing_show_as_foot_skate() {
    let stand = standing(&sample_truth());
    // Standing still, then the whole standing body glides forward at 0.5 m/s for 2 s.
    let mut poses = vec![stand.clone(); 180];
    for (i, p) in poses.iter_mut().enumerate().skip(60) {
        p.root_in_world_m.z += 0.5 * (i - 60) as f64 * DT;
    }
    let (v, frames) = run(Mode::Residual, &poses);
    report("sliding, residual", &v.stats);
    let skate = |range: std::ops::Range<usize>| {
        let values: Vec<f64> = frames[range].iter().filter_map(|f| f.1).collect();
        values.iter().sum::<f64>() / values.len().max(1) as f64
    };
    let still = skate(20..60);
    let sliding = skate(90..180);
    assert!(still < 0.02, "skate while standing {still:.3} m/s");
    assert!(sliding > 0.3, "skate while gliding {sliding:.3} m/s");
}

#[test]
fn leaning_past_the_feet_falls_and_the_simulation_carries_on() {
    let stand = standing(&sample_truth());
    // The whole standing body tipped 35° forward about the feet: the centre of mass is far ahead
    // of the toes, which no joint torque can hold. The estimate keeps asking for it for 3 s.
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), 35f64.to_radians());
    let mut lean = stand.clone();
    lean.parent_from_joint[0] = tilt * stand.parent_from_joint[0];
    let feet = Vector3::new(stand.root_in_world_m.x, 0.0, stand.root_in_world_m.z);
    lean.root_in_world_m = feet + tilt * (stand.root_in_world_m - feet);
    let poses = vec![lean; 180];
    let (v, _) = run(Mode::Torques, &poses);
    report("leaning", &v.stats);
    assert!(v.stats.falls >= 1, "{}", v.stats.summary_line(false));
    assert_eq!(v.stats.frames, 180, "every frame is scored, falls included");
    // And without the simulation: the centre of pressure this still lean needs is the centre of
    // mass's projection, far ahead of the toes, on every judged frame.
    assert_eq!(v.stats.support_judged, 180 - 4);
    assert_eq!(v.stats.support_outside, v.stats.support_judged);
}

#[test]
fn the_same_input_gives_the_same_output() {
    let truth = sample_truth();
    let clip = &truth[PRELUDE_FRAMES..PRELUDE_FRAMES + 120];
    for joints in JOININGS {
        let (a, fa) = run_joined(Mode::Residual, joints, clip);
        let (b, fb) = run_joined(Mode::Residual, joints, clip);
        assert_eq!(fa, fb);
        assert_eq!(a.stats.tracking_errors_m, b.stats.tracking_errors_m);
    }
}

#[test]
fn a_pose_with_near_identity_joints_simulates_without_nan() {
    // The first frame after calibration of pip on the bundled sample (the optimizer's output of
    // frame 125): several joints are identity to within 1e-6. The error rotation between such a
    // target and the simulation's f32 joint rotation has a trace a rounding above 3, where
    // nalgebra's Rotation3::scaled_axis (acos of (trace-1)/2) is NaN; that made every simulated
    // joint NaN until the next fall. Rotation vectors now go through a quaternion.
    let q: [[f32; 4]; 24] = [
        [0.9990634, 0.043199483, -0.0024766321, -0.0002661218],
        [0.98968196, -0.13199994, 0.03419672, 0.04400199],
        [0.9926705, -0.07738614, -0.08793647, -0.029729748],
        [0.9996478, 0.025945662, 0.0040039956, 0.0038887039],
        [0.98735523, 0.15578167, 0.01558073, -0.024878455],
        [0.99081874, 0.13507989, -0.00084841286, 0.005561932],
        [0.9997639, -0.014689543, 0.0039244485, 0.015520942],
        [0.9999627, 0.008638683, -2.0359612e-5, -1.177314e-5],
        [0.9999878, -0.0047359103, 0.0012274733, 0.0007177822],
        [0.99974215, -0.0002098, 0.018883338, -0.012611292],
        [1.0, 3.5315768e-9, -2.406544e-10, -3.771027e-10],
        [1.0, 4.60377e-9, 1.2052202e-10, 1.0522311e-10],
        [0.99414486, -0.10677478, 0.0015884415, -0.016509935],
        [0.99063736, 0.005316061, 0.11725205, 0.06972317],
        [0.9968965, 0.005086949, -0.07015991, -0.03534203],
        [0.99965733, -0.012290439, 0.008830062, -0.021357454],
        [0.9196147, -0.34071916, -0.08114714, -0.17786081],
        [0.93505204, -0.3296956, 0.0023844347, 0.1302796],
        [0.9881803, 0.13567996, -0.06252948, -0.034361355],
        [0.9977055, -0.05073629, 0.044541728, -0.0050551845],
        [1.0, -1.7233478e-9, 7.2229756e-7, -1.4034313e-6],
        [1.0, -9.760404e-10, -8.8722624e-7, 9.5056714e-7],
        [1.0, 0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
    ];
    let pose = Pose::from_wire(&q, &[0.028213738, 0.96156317, -0.05232744]).unwrap();
    let mut v = validator(Mode::Torques);
    for frame in 0..30 {
        let o = v.frame(Some(&pose), DT).unwrap();
        assert!(
            o.state
                .joint_position_m
                .iter()
                .all(|p| p.iter().all(|x| x.is_finite())),
            "frame {frame}: {:?}",
            o.score
        );
        // A held mid-stride pose is not balanced: the body may sag and slide a little.
        assert!(
            o.score.tracking_error_m < 0.15,
            "frame {frame}: {:?}",
            o.score
        );
    }
}
