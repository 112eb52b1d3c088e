//! Kinematics without networks, for sensor sets that sense the bones they estimate (`net =
//! "sensed"`): a lower-body set, a full suit. What gait-lab tools do with such sets (OpenSense's
//! inverse kinematics from orientations, a suit's segment model): the pose from the calibrated
//! bone orientations, the root's translation from the foot that stands.
//!
//! - **Pose.** A sensed bone's global orientation is its sensor's calibrated `R_MB`. A joint the
//!   set observes ([`SensorSet::observed_joints`]) without a sensor of its own lies on a single
//!   chain down to the nearest sensed bone (the spine below a sternum sensor, the neck below the
//!   head's): the turn between the sensed bones at the chain's ends is shared evenly by its
//!   joints. The joints the set does not observe stay at rest (identity: the body model's
//!   T-pose), not guessed.
//! - **Translation.** A foot touches with its lower point, the ankle or the ball of the foot (as
//!   it rolls over it); of the two feet the one that moved least in the world with the root's last
//!   velocity stands (unless the other is lower by [`STANCE_HEIGHT_M`]), and the root moves so that
//!   its point stays where it is ("stance foot pinning"); the other foot touches too when it is
//!   within [`CONTACT_HEIGHT_M`] of the standing one's height.
//!
//! A set the method cannot estimate is refused when the stage starts: it needs the pelvis, both
//! lower legs (the ankles stand), and a single chain below every unsensed observed joint (the
//! six-site set's trunk branches to the head and both arms without a sensor: the networks
//! estimate it).

use imuflow_body::kinematics::{FkData, Pose, forward_kinematics};
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::{BodyModel, Imu, JointId, NUM_JOINTS, SensorSet};
use imuflow_graph::frames::BodyImuFrame;
use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use crate::infer::Estimate;

/// A foot within this height of the standing one's (relative to the pelvis) touches too, m.
pub const CONTACT_HEIGHT_M: f64 = 0.02;
/// The ankle that moved least in the world stands, unless the other is lower by more than this,
/// m (a foot cannot stand in the air).
pub const STANCE_HEIGHT_M: f64 = 0.05;

/// Gravity in M, m/s².
const GRAVITY: Vector3<f64> = Vector3::new(0.0, -9.81, 0.0);

/// How one joint's global orientation is found.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Source {
    /// Its bone's sensor, by wire slot.
    Sensor(usize),
    /// A share of the turn from its parent's bone to the sensed bone at the end of its chain
    /// (that bone's sensor, by wire slot): `1 / steps` of it, `steps` the joints from this one
    /// to that bone's, both included.
    Between { slot: usize, steps: u32 },
    /// Not observed: at rest relative to its parent.
    Rest,
}

/// The sensed-kinematics estimator of one set.
pub struct SensedEstimator {
    body: BodyModel,
    sources: [Source; NUM_JOINTS],
    dt_s: f64,
    fk: FkData,
    /// Every joint relative to the root (M axes) in the last frame.
    last_positions: Option<[Vector3<f64>; NUM_JOINTS]>,
    /// The root's velocity in the last frame, M (m/s).
    last_root: Vector3<f64>,
}

impl SensedEstimator {
    /// The estimator of `set` on `body` at `rate_hz`, or why the set cannot be estimated so.
    pub fn new(set: &SensorSet, body: BodyModel, rate_hz: f64) -> Result<SensedEstimator, String> {
        let needed = [Imu::Pelvis, Imu::LeftLowerLeg, Imu::RightLowerLeg];
        let missing: Vec<&str> = needed
            .iter()
            .filter(|s| !set.contains(**s))
            .map(|s| s.name())
            .collect();
        if !missing.is_empty() {
            return Err(format!(
                "net = \"sensed\" stands the body on its ankles and turns it by the pelvis: the sensor set {set} lacks {}",
                missing.join(", ")
            ));
        }
        let is_observed = |j: JointId| set.observes(j);
        let mut sources = [Source::Rest; NUM_JOINTS];
        for site in set.sites() {
            sources[site.joint().index()] = Source::Sensor(site.index());
        }
        for j in JointId::all() {
            if !is_observed(j) || sources[j.index()] != Source::Rest {
                continue;
            }
            // Down the single observed chain to the first sensed joint.
            let mut chain = vec![j];
            let slot = loop {
                let at = chain[chain.len() - 1];
                let below: Vec<JointId> = at.children().filter(|c| is_observed(*c)).collect();
                let [next] = below.as_slice() else {
                    return Err(format!(
                        "net = \"sensed\": the sensor set {set} observes {} without a sensor on its bone, and the chain below it branches at {} ({} observed branches); a set whose chains below an unsensed joint do not branch (a lower-body set, a full suit) is estimated so, the six-site set by its networks",
                        j.name(),
                        at.name(),
                        below.len()
                    ));
                };
                if let Source::Sensor(slot) = sources[next.index()] {
                    break slot;
                }
                chain.push(*next);
            };
            // Each joint of the chain turns by an equal share of what is left to the sensed bone.
            let joints = chain.len() as u32 + 1;
            for (i, k) in chain.iter().enumerate() {
                sources[k.index()] = Source::Between {
                    slot,
                    steps: joints - i as u32,
                };
            }
        }
        Ok(SensedEstimator {
            body,
            sources,
            dt_s: 1.0 / rate_hz,
            fk: FkData::new(),
            last_positions: None,
            last_root: Vector3::zeros(),
        })
    }

    /// Forgets the motion so far (the next frame starts standing where it is).
    pub fn reset(&mut self) {
        self.last_positions = None;
        self.last_root = Vector3::zeros();
    }

    /// The estimate of one calibrated frame whose set's sensors are all valid.
    pub fn step(&mut self, frame: &BodyImuFrame) -> Estimate {
        let sensor = |slot: usize| {
            let [w, x, y, z] = frame.bone_orientation_wxyz[slot].map(f64::from);
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
                .to_rotation_matrix()
        };
        let mut global = [Rotation3::identity(); NUM_JOINTS];
        let mut local = [Rotation3::identity(); NUM_JOINTS];
        for j in JointId::all() {
            let parent = j
                .parent()
                .map_or(Rotation3::identity(), |p| global[p.index()]);
            global[j.index()] = match self.sources[j.index()] {
                Source::Sensor(slot) => sensor(slot),
                Source::Rest => parent,
                Source::Between { slot, steps } => {
                    let turn = parent.transpose() * sensor(slot);
                    let share = axis_angle_from_rotation(&turn) / f64::from(steps);
                    parent * Rotation3::new(share)
                }
            };
            // The root's parent is M: its local rotation is its global one.
            local[j.index()] = parent.transpose() * global[j.index()];
        }
        forward_kinematics(
            &self.body.skeleton,
            &Pose {
                parent_from_joint: local,
                root_in_world_m: Vector3::zeros(),
            },
            &mut self.fk,
        );
        let positions = self.fk.joint_in_world_m;
        // Each foot touches with its lower point: the ankle, or the ball of the foot as it rolls.
        let point = |side: usize| {
            let (ankle, ball) = [
                (JointId::LEFT_ANKLE, JointId::LEFT_FOOT),
                (JointId::RIGHT_ANKLE, JointId::RIGHT_FOOT),
            ][side];
            if positions[ball.index()].y < positions[ankle.index()].y {
                ball
            } else {
                ankle
            }
        };
        let points = [point(0), point(1)];
        let feet = points.map(|j| positions[j.index()]);
        let lower = if feet[0].y <= feet[1].y { 0 } else { 1 };
        let (stance, root_velocity) = match &self.last_positions {
            Some(last_positions) => {
                let last = points.map(|j| last_positions[j.index()]);
                // The standing foot stays put in the world: of the two, the one that moved
                // least there with the root's last velocity, unless the other is clearly lower.
                let moved = |f: usize| ((feet[f] - last[f]) / self.dt_s + self.last_root).norm();
                let by_motion = if moved(0) <= moved(1) { 0 } else { 1 };
                let other = 1 - by_motion;
                let stance = if feet[other].y < feet[by_motion].y - STANCE_HEIGHT_M {
                    other
                } else {
                    by_motion
                };
                // The root moves against the standing foot's motion relative to the root.
                (stance, -(feet[stance] - last[stance]) / self.dt_s)
            }
            None => (lower, Vector3::zeros()),
        };
        self.last_root = root_velocity;
        let touches = |f: usize| f == stance || feet[f].y - feet[stance].y < CONTACT_HEIGHT_M;
        let foot_contact = [touches(0), touches(1)].map(|t| if t { 1.0 } else { 0.0 });
        let joint_velocity = match &self.last_positions {
            Some(last) => {
                std::array::from_fn(|j| (positions[j] - last[j]) / self.dt_s + root_velocity)
            }
            None => [Vector3::zeros(); NUM_JOINTS],
        };
        self.last_positions = Some(positions);
        Estimate {
            pose: local,
            joint_position: positions,
            joint_velocity,
            foot_contact,
            stationary: [0.0, foot_contact[0], foot_contact[1], 0.0, 0.0],
            root_velocity,
            gravity_in_root: global[0].transpose() * GRAVITY,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::BodyParams;
    use imuflow_body::rotation::{Axis, angle_between, quat_wxyz_from_rotation};

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap()
    }

    /// The frame the sensors of `set` give for the bones' global orientations `global`.
    fn frame_of(set: &SensorSet, global: &[Rotation3<f64>; NUM_JOINTS]) -> BodyImuFrame {
        let mut f = BodyImuFrame::default();
        for site in set.sites() {
            f.bone_orientation_wxyz[site.index()] =
                quat_wxyz_from_rotation(&global[site.joint().index()]).map(|v| v as f32);
            f.valid_mask |= 1 << site.index();
        }
        f
    }

    #[test]
    fn the_legs_turn_as_their_sensors_and_the_rest_stays_at_rest() {
        let legs = SensorSet::builtin("lower-body").unwrap();
        let mut est = SensedEstimator::new(&legs, body(), 60.0).unwrap();
        let mut pose = [Rotation3::identity(); NUM_JOINTS];
        pose[0] = Axis::Y.rotation(0.4);
        pose[JointId::LEFT_HIP.index()] = Axis::X.rotation(-0.5);
        pose[JointId::LEFT_KNEE.index()] = Axis::X.rotation(0.9);
        pose[JointId::RIGHT_HIP.index()] = Axis::X.rotation(0.2);
        pose[JointId::SPINE1.index()] = Axis::X.rotation(0.3); // not sensed: not seen
        let mut fk = FkData::new();
        let p = Pose {
            parent_from_joint: pose,
            root_in_world_m: Vector3::zeros(),
        };
        forward_kinematics(&body().skeleton, &p, &mut fk);
        let e = est.step(&frame_of(&legs, &fk.world_from_joint));
        for j in [0, 1, 2, 4, 5] {
            assert!(angle_between(&e.pose[j], &pose[j]) < 1e-6, "joint {j}");
        }
        assert!(angle_between(&e.pose[JointId::SPINE1.index()], &Rotation3::identity()) < 1e-12);
        // The right leg is the straighter, lower one: it stands; the left ankle is higher.
        assert_eq!(e.foot_contact, [0.0, 1.0]);
        assert_eq!(e.root_velocity, Vector3::zeros());
    }

    #[test]
    fn a_standing_foot_moving_back_under_the_body_moves_the_root_forward() {
        let legs = SensorSet::builtin("lower-body").unwrap();
        let mut est = SensedEstimator::new(&legs, body(), 60.0).unwrap();
        let mut fk = FkData::new();
        let mut points = Vec::new();
        let mut velocities = Vec::new();
        for (t, hip) in [-0.20f64, -0.18].into_iter().enumerate() {
            // The right leg straight and swung by `hip` about x (a negative angle: forward), the
            // left leg bent and lifted high.
            let mut pose = [Rotation3::identity(); NUM_JOINTS];
            pose[JointId::RIGHT_HIP.index()] = Axis::X.rotation(hip);
            pose[JointId::LEFT_HIP.index()] = Axis::X.rotation(-1.0);
            pose[JointId::LEFT_KNEE.index()] = Axis::X.rotation(1.8);
            let p = Pose {
                parent_from_joint: pose,
                root_in_world_m: Vector3::zeros(),
            };
            forward_kinematics(&body().skeleton, &p, &mut fk);
            // The right foot touches with its lower point: the ankle or the ball of the foot.
            let (ankle, ball) = (
                *fk.position(JointId::RIGHT_ANKLE),
                *fk.position(JointId::RIGHT_FOOT),
            );
            points.push(if ball.y < ankle.y {
                (ball, "ball")
            } else {
                (ankle, "ankle")
            });
            let e = est.step(&frame_of(&legs, &fk.world_from_joint));
            assert_eq!(e.foot_contact[1], 1.0, "frame {t}");
            velocities.push(e.root_velocity);
        }
        // A finite difference of that point, by hand: the root moves by its opposite (to the f32
        // quaternions' rounding). The foot went back under the body: the root went forward.
        assert_eq!(points[0].1, points[1].1);
        let expected = -(points[1].0 - points[0].0) * 60.0;
        assert!(
            (velocities[1] - expected).norm() < 1e-4,
            "{:?} against {expected:?}",
            velocities[1]
        );
        assert!(velocities[1].z > 1.0, "{:?}", velocities[1]);
    }

    #[test]
    fn the_full_suit_shares_the_spine_between_pelvis_and_sternum_and_the_six_are_refused() {
        let suit = SensorSet::builtin("full-suit").unwrap();
        let mut est = SensedEstimator::new(&suit, body(), 60.0).unwrap();
        let mut fk = FkData::new();
        let mut pose = [Rotation3::identity(); NUM_JOINTS];
        // 0.3 rad forward at each of spine1, spine2, spine3 (about x): the sternum 0.9 rad.
        for j in [JointId::SPINE1, JointId::SPINE2, JointId::SPINE3] {
            pose[j.index()] = Axis::X.rotation(0.3);
        }
        let p = Pose {
            parent_from_joint: pose,
            root_in_world_m: Vector3::zeros(),
        };
        forward_kinematics(&body().skeleton, &p, &mut fk);
        let e = est.step(&frame_of(&suit, &fk.world_from_joint));
        // The sternum sits on spine3: spine1 and spine2 share what is between with it.
        for j in [JointId::SPINE1, JointId::SPINE2, JointId::SPINE3] {
            assert!(angle_between(&e.pose[j.index()], &Axis::X.rotation(0.3)) < 1e-6);
        }
        let err = SensedEstimator::new(&SensorSet::six(), body(), 60.0)
            .err()
            .unwrap();
        assert!(
            err.contains("observes spine1") && err.contains("branches at spine3 (3 observed"),
            "{err}"
        );
        let hips = {
            let dir = std::env::temp_dir().join(format!("imuflow-sensed-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join("hips.toml");
            std::fs::write(
                &path,
                "[hips]\nsites = [\"pelvis\", \"left_upper_leg\", \"right_upper_leg\"]\nheading_reference = \"pelvis\"\n",
            )
            .unwrap();
            SensorSet::resolve(path.to_str().unwrap()).unwrap()
        };
        let err = SensedEstimator::new(&hips, body(), 60.0).err().unwrap();
        assert!(
            err.contains("lacks left_lower_leg, right_lower_leg"),
            "{err}"
        );
    }
}
