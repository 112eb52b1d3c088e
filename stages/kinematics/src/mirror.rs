//! Test-time mirroring: the networks also run on the stream reflected left–right, and the two
//! estimates, the second seen back in the mirror, are averaged.
//!
//! Why: on motion they never saw, the networks' errors are lopsided (the holdout's right upper
//! arm is several degrees worse than the left, docs/results); the weights were trained on
//! mirrored clips too (`dataset build --mirror`), so the mirrored stream is as familiar to them as
//! the recorded one, and where their error does not mirror with the motion the average cancels
//! part of it. It costs a second set of network steps per frame.
//!
//! The reflection is S = diag(−1, 1, 1) in the model frame M (x → −x; y stays up, so gravity and
//! the floor are unchanged): positions, velocities and accelerations map to S·v, orientations to
//! S·R·S, angular velocities (pseudovectors) to −S·ω, and every left sensor or joint trades
//! places with its right one. That is the IMU stream the mirrored motion would have produced,
//! which is how `dataset build --mirror` makes it (tested against it).

use imuflow_body::kinematics::{mirror_rotation, mirror_vector};
use imuflow_body::{JointId, NUM_JOINTS};
use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use crate::features::{ImuInput, Mat3};
use crate::infer::{Estimate, global_rotations};

/// `S·R·S` of a row-major f32 matrix: the entries that mix x with y or z change sign.
fn mirror_matrix(m: &Mat3) -> Mat3 {
    let mut out = *m;
    for k in [1, 2, 3, 6] {
        out[k] = -out[k];
    }
    out
}

/// The IMU frame of the motion reflected across the x = 0 plane of M: each sensor takes its
/// mirror sensor's reading, orientation `S·R·S`, free acceleration `S·a`, angular velocity `−S·ω`.
/// A sensor whose mirror site the set lacks ([`crate::features::InputOrder::is_symmetric`]; the
/// stage refuses mirroring for such a set) keeps its own reading, reflected.
pub fn mirrored_input(imu: &ImuInput) -> ImuInput {
    let order = imu.order;
    let mut out = ImuInput::of(order);
    for (i, sensor) in order.sites().enumerate() {
        let from = order.index_of(sensor.mirror()).unwrap_or(i);
        out.orientation[i] = mirror_matrix(&imu.orientation[from]);
        let [x, y, z] = imu.acceleration[from];
        out.acceleration[i] = [-x, y, z];
        let [x, y, z] = imu.angular_velocity[from];
        out.angular_velocity[i] = [x, -y, -z];
    }
    out
}

/// An estimate of the mirrored stream seen back in the mirror: every field of each joint from its
/// mirror joint, reflected; the left and right feet's and hands' probabilities trade places.
pub fn mirrored_estimate(e: &Estimate) -> Estimate {
    let [pelvis, left_foot, right_foot, left_hand, right_hand] = e.stationary;
    let mut seen = Estimate {
        pose: e.pose,
        joint_position: e.joint_position,
        joint_velocity: e.joint_velocity,
        foot_contact: [e.foot_contact[1], e.foot_contact[0]],
        stationary: [pelvis, right_foot, left_foot, right_hand, left_hand],
        root_velocity: mirror_vector(&e.root_velocity),
        // gR = Rᵀ·g mirrors to (S·R·S)ᵀ·S·g = S·(Rᵀ·g).
        gravity_in_root: mirror_vector(&e.gravity_in_root),
    };
    for j in JointId::all() {
        let (to, from) = (j.index(), j.mirror().index());
        seen.pose[to] = mirror_rotation(&e.pose[from]);
        seen.joint_position[to] = mirror_vector(&e.joint_position[from]);
        seen.joint_velocity[to] = mirror_vector(&e.joint_velocity[from]);
    }
    seen
}

/// The rotation halfway between `a` and `b` (on the shorter arc).
fn halfway(a: &Rotation3<f64>, b: &Rotation3<f64>) -> Rotation3<f64> {
    let qa = UnitQuaternion::from_rotation_matrix(a);
    let qb = UnitQuaternion::from_rotation_matrix(b);
    // q and −q are the same rotation: add the pair that lies on the same side.
    let sum = if qa.coords.dot(&qb.coords) < 0.0 {
        qa.coords - qb.coords
    } else {
        qa.coords + qb.coords
    };
    // Two rotations 180° apart have no unique midpoint (the sum vanishes); keep `a`.
    match UnitQuaternion::try_new(nalgebra::Quaternion::from(sum), 1e-12) {
        Some(q) => q.to_rotation_matrix(),
        None => *a,
    }
}

/// The average of two estimates of the same frame: each bone's global orientation halfway
/// between the two (so bones both put on their sensor stay there), every vector and probability
/// the mean. The caller re-imposes its joint limits: the mean of two anatomical poses need not be
/// one.
pub fn average(a: &Estimate, b: &Estimate) -> Estimate {
    let (ga, gb) = (global_rotations(&a.pose), global_rotations(&b.pose));
    let global: [Rotation3<f64>; NUM_JOINTS] = std::array::from_fn(|j| halfway(&ga[j], &gb[j]));
    let mut pose = global;
    for j in JointId::all() {
        if let Some(parent) = j.parent() {
            pose[j.index()] = global[parent.index()].transpose() * global[j.index()];
        }
    }
    let mean = |u: &Vector3<f64>, v: &Vector3<f64>| 0.5 * (u + v);
    Estimate {
        pose,
        joint_position: std::array::from_fn(|j| mean(&a.joint_position[j], &b.joint_position[j])),
        joint_velocity: std::array::from_fn(|j| mean(&a.joint_velocity[j], &b.joint_velocity[j])),
        foot_contact: std::array::from_fn(|k| 0.5 * (a.foot_contact[k] + b.foot_contact[k])),
        stationary: std::array::from_fn(|k| 0.5 * (a.stationary[k] + b.stationary[k])),
        root_velocity: mean(&a.root_velocity, &b.root_velocity),
        gravity_in_root: global[0].transpose()
            * (0.5 * (a.gravity_in_root.norm() + b.gravity_in_root.norm()) * -Vector3::y()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infer::Streamer;
    use crate::infer::tests::{
        assert_on_sensors_with_hinged_knees, committed_weights, flat, largest_gap,
    };
    use crate::method::Method;
    use imuflow_body::{BodyModel, BodyParams, Pose};
    use imuflow_motion::augment::mirror;
    use imuflow_motion::imu_synthesis::{SynthesisOptions, synthesize_imus};
    use imuflow_motion::retarget::MotionClip;
    use nalgebra::Unit;

    /// Two seconds of an asymmetric motion: every joint turning at its own rate about its own
    /// axis, the root walking off diagonally.
    fn lopsided_clip() -> MotionClip {
        let poses = (0..120)
            .map(|k| {
                let t = k as f64 / 60.0;
                let mut pose = Pose::t_pose(Vector3::new(0.3 + 0.4 * t, 0.9, -0.2 * t));
                for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
                    let axis =
                        Unit::new_normalize(Vector3::new(1.0, j as f64 - 4.0, 0.5 * j as f64));
                    *r = Rotation3::from_axis_angle(
                        &axis,
                        0.1 + 0.3 * (t * (1.0 + 0.1 * j as f64)).sin(),
                    );
                }
                pose
            })
            .collect();
        MotionClip {
            frame_time_s: 1.0 / 60.0,
            poses,
        }
    }

    /// The ideal signals of `clip`, frame by frame, as the networks take them.
    fn inputs(clip: &MotionClip, body: &BodyModel) -> Vec<ImuInput> {
        let imus = synthesize_imus(clip, body, &SynthesisOptions::default()).unwrap();
        let f32s = |v: &Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        imus.frames
            .iter()
            .map(|frame| {
                let mut input = ImuInput::default();
                for (i, s) in frame.iter().take(imuflow_body::NUM_IMUS).enumerate() {
                    let m = s.model_from_sensor.matrix();
                    input.orientation[i] = std::array::from_fn(|k| m[(k / 3, k % 3)] as f32);
                    input.acceleration[i] = f32s(&s.free_accel_in_model_mps2);
                    input.angular_velocity[i] = f32s(&s.angular_velocity_in_model_radps);
                }
                input
            })
            .collect()
    }

    fn largest_difference(a: &ImuInput, b: &ImuInput) -> f32 {
        let flat = |x: &ImuInput| -> Vec<f32> {
            (0..6)
                .flat_map(|i| {
                    x.orientation[i]
                        .into_iter()
                        .chain(x.acceleration[i])
                        .chain(x.angular_velocity[i])
                })
                .collect()
        };
        flat(a)
            .iter()
            .zip(flat(b))
            .map(|(u, v)| (u - v).abs())
            .fold(0.0, f32::max)
    }

    /// The reflected input is what the synthesis makes of the mirrored motion (an independent
    /// path: positions differentiated twice, rotations differenced), frame by frame.
    #[test]
    fn the_mirrored_input_is_the_mirrored_motions_signals() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let clip = lopsided_clip();
        let (recorded, reflected) = (inputs(&clip, &body), inputs(&mirror(&clip), &body));
        let mut moved = 0.0f32;
        for (a, b) in recorded.iter().zip(&reflected) {
            let d = largest_difference(&mirrored_input(a), b);
            // f32 signals; accelerations of a few m/s² differenced from f64 positions.
            assert!(d < 1e-4, "{d}");
            assert_eq!(mirrored_input(&mirrored_input(a)), *a);
            moved = moved.max(largest_difference(a, b));
        }
        assert!(moved > 0.5, "the motion is its own mirror image ({moved})");
    }

    #[test]
    fn halfway_halves_the_angle_on_the_shorter_arc() {
        for k in 0..50 {
            let axis = |s: f64| Unit::new_normalize(Vector3::new(s.sin(), 1.0, (2.0 * s).cos()));
            let a = Rotation3::from_axis_angle(&axis(k as f64), 0.07 * k as f64);
            let b = Rotation3::from_axis_angle(&axis(k as f64 + 0.5), 3.0 - 0.05 * k as f64);
            let mid = halfway(&a, &b);
            let whole = a.angle_to(&b);
            assert!((a.angle_to(&mid) - whole / 2.0).abs() < 1e-9, "{k}");
            assert!((mid.angle_to(&b) - whole / 2.0).abs() < 1e-9, "{k}");
        }
    }

    /// The ensemble is symmetric by construction: fed the mirrored stream, it gives the mirror
    /// image of what it gives on the recorded one (every field, 1e-5; the two runs' networks see
    /// the same two streams in swapped roles). It differs from the networks alone, keeps the
    /// instrumented bones on their sensors, and keeps the knees hinges.
    fn the_ensemble_mirrors_with_its_input(method: Method, path: &str) {
        let streamer = |ensemble: bool| {
            let mut s = Streamer::new(
                committed_weights(method, path),
                Pose::t_pose(Vector3::zeros()),
            )
            .unwrap();
            s.set_mirror_ensemble(ensemble);
            s
        };
        let (mut recorded, mut reflected, mut alone) =
            (streamer(true), streamer(true), streamer(false));
        let (mut worst, mut averaged) = (0.0f64, 0.0f64);
        for f in 0..240 {
            let input = crate::bench::swaying_sensors(f);
            let a = recorded.step(&input).unwrap();
            let b = reflected.step(&mirrored_input(&input)).unwrap();
            let own = alone.step(&input).unwrap();
            worst = worst.max(largest_gap(&flat(&mirrored_estimate(&b)), &flat(&a)));
            averaged = averaged.max(largest_gap(&flat(&own), &flat(&a)));
            assert_on_sensors_with_hinged_knees(&a, &input, &format!("{method:?} frame {f}"));
        }
        assert!(worst < 1e-5, "{method:?}: not mirror-symmetric by {worst}");
        assert!(
            averaged > 1e-2,
            "{method:?}: the average changes nothing ({averaged})"
        );
    }

    #[test]
    fn the_ensemble_mirrors_with_its_input_pip() {
        the_ensemble_mirrors_with_its_input(Method::Pip, "models/pip.safetensors");
    }

    #[test]
    fn the_ensemble_mirrors_with_its_input_globalpose() {
        the_ensemble_mirrors_with_its_input(Method::GlobalPose, "models/globalpose.safetensors");
    }
}
