//! What a physics method publishes for a frame it cannot solve: the networks' pose with the root
//! integrated, as the no-physics method ([`Integrate`]) does, started from where the physics stood.
//!
//! Before, `pip` followed the reference kinematically at its last root position with zero velocity
//! and the stage flagged the frame INVALID; on athletic motion the stream went blank for seconds
//! (a back flip: 471 of 672 frames, runs up to 83). The degraded estimate is the user's output for
//! that frame (flagged DEGRADED, not INVALID) and the state the physics continues from:
//!
//! - **Pose**: the reference's local rotations.
//! - **Root**: the last published root position plus the refined root velocity of GlobalPose's
//!   Eq. 25 (the networks' root velocity averaged with "stationary joints stay where they are";
//!   [`crate::integrate`]) times dt, on the method's terrain. The root speed is limited to
//!   [`MAX_ROOT_SPEED_MPS`]: a network velocity no human reaches is not followed.
//! - **Floor**: the body is lifted until no joint's ground point is below the floor. A pose placed
//!   at a root height meant for another pose (upside down at a standing height, or the reverse)
//!   otherwise lies in the floor, and a physics state that starts in the floor does not get out
//!   of it (PIP's contact rows only stop penetrating bodies; see [`crate::pip`]).
//! - **Velocity**: the refined root velocity; the joints at rest. The rotation of the reference
//!   over one frame is where the networks' errors show most (jitter, a root orientation that
//!   flips over), and a physics that continued with it failed again. On the erring back flip of
//!   `tests/athletics.rs`, GlobalPose had 5 degraded frames in runs of up to 2 with the
//!   reference's joint velocities, 3 in runs of 1 with the joints at rest; PIP with its code's
//!   threshold (‖x‖ > 1e4) 10 in one run of 10, against 9 in runs of up to 5. On the erring roll:
//!   GlobalPose 4 against 2, PIP 5 against 2.
//! - Contacts: the integrator's (stationary joints), no forces, no torques.
//!
//! The methods call [`Degraded::follow`] after every frame with its reference (a copy, no
//! computation), so the estimate knows the previous frame's; the first frame's estimate, or one
//! after a state set from outside, takes the frame's own reference as the previous one (no joint
//! motion, Eq. 25 from the network's velocity alone).

use imuflow_body::dynamics::NUM_DOFS;
use imuflow_body::kinematics::FkData;
use imuflow_body::{JointId, NUM_JOINTS};
use nalgebra::Vector3;

use crate::estimate::lift_out_of_floor;
use crate::integrate::Integrate;
use crate::{DT_S, MAX_ROOT_SPEED_MPS, Method, MotionEstimate, PhysicsBody, Reference, Terrain};

/// The degraded estimate of one physics method (see the module docs).
pub struct Degraded {
    integrate: Integrate,
    /// The previous frame's reference.
    previous: Option<Reference>,
    physics: PhysicsBody,
    fk: FkData,
    /// Every joint: none may end below the floor.
    body: [JointId; NUM_JOINTS],
}

impl Degraded {
    /// For `physics` (the body's own contact geometry) on `terrain`.
    pub fn new(physics: PhysicsBody, terrain: Terrain) -> Degraded {
        Degraded {
            integrate: Integrate::with_terrain(physics.clone(), terrain),
            previous: None,
            physics,
            fk: FkData::new(),
            body: std::array::from_fn(|i| JointId::from_index(i).unwrap_or(JointId::PELVIS)),
        }
    }

    /// Start over with the method: no previous frame.
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// After every frame: `reference` was this frame's networks' estimate.
    pub fn follow(&mut self, reference: &Reference) {
        match &mut self.previous {
            Some(previous) => previous.clone_from(reference),
            None => self.previous = Some(reference.clone()),
        }
    }

    /// The degraded estimate of this frame into `out`, from the method's last root position
    /// `root` (m, M; the module docs).
    pub fn estimate(
        &mut self,
        reference: &Reference,
        root: &Vector3<f64>,
        out: &mut MotionEstimate,
    ) -> anyhow::Result<()> {
        let previous = self.previous.as_ref().unwrap_or(reference);
        self.integrate.continue_from(previous, root);
        self.integrate.step(reference, None, out)?;
        limit_root_speed(out);
        lift_out_of_floor(&self.physics, &mut out.pose, &self.body, &mut self.fk);
        out.v.rows_mut(3, NUM_DOFS - 3).fill(0.0);
        Ok(())
    }
}

/// Scale the root velocity down to [`MAX_ROOT_SPEED_MPS`] and take back the distance it travelled
/// beyond that.
fn limit_root_speed(out: &mut MotionEstimate) {
    let v: Vector3<f64> = out.v.fixed_rows::<3>(0).into_owned();
    let speed = v.norm();
    if speed > MAX_ROOT_SPEED_MPS {
        let limited = v * (MAX_ROOT_SPEED_MPS / speed);
        out.pose.root_in_world_m -= (v - limited) * DT_S;
        out.v.fixed_rows_mut::<3>(0).copy_from(&limited);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn degraded() -> Degraded {
        Degraded::new(PhysicsBody::new(1.75, 70.0).unwrap(), Terrain::Flat)
    }

    #[test]
    fn the_degraded_root_continues_from_the_published_root_at_the_refined_velocity() {
        // No stationary joint: Eq. 25 is the network's velocity alone, 1.2 m/s forward.
        let mut d = degraded();
        let mut r = Reference {
            root_velocity_mps: Vector3::new(0.0, 0.0, 1.2),
            ..Reference::default()
        };
        let standing = d.physics.body.rest_root_height_m;
        let root = Vector3::new(0.5, standing + 0.3, -2.0);
        d.follow(&r);
        // The next reference bends the left knee by 0.6 rad over the frame.
        let knee = JointId::LEFT_KNEE;
        r.pose.parent_from_joint[knee.index()] = Rotation3::new(Vector3::new(0.6, 0.0, 0.0));
        let mut out = MotionEstimate::default();
        d.estimate(&r, &root, &mut out).unwrap();
        let want = root + Vector3::new(0.0, 0.0, 1.2 * DT_S);
        assert!((out.pose.root_in_world_m - want).norm() < 1e-12);
        assert_eq!(out.pose.parent_from_joint, r.pose.parent_from_joint);
        // Moving at the refined velocity, the joints at rest.
        assert!((out.v.fixed_rows::<3>(0) - Vector3::new(0.0, 0.0, 1.2)).norm() < 1e-12);
        assert!(out.v.rows(3, NUM_DOFS - 3).iter().all(|&w| w == 0.0));
        assert_eq!(out.tau, imuflow_body::dynamics::DofVector::zeros());
    }

    #[test]
    fn the_degraded_body_is_lifted_out_of_the_floor_and_its_root_kept_to_human_speed() {
        let mut d = degraded();
        // Upside down (π about x) with the root at 0.3 m: the head would be 0.3 m in the floor.
        let mut r = Reference {
            root_velocity_mps: Vector3::new(40.0, 0.0, 0.0),
            ..Reference::default()
        };
        r.pose.parent_from_joint[0] = Rotation3::new(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        d.follow(&r);
        let mut out = MotionEstimate::default();
        d.estimate(&r, &Vector3::new(0.0, 0.3, 0.0), &mut out)
            .unwrap();
        let mut fk = FkData::new();
        imuflow_body::forward_kinematics(&d.physics.body.skeleton, &out.pose, &mut fk);
        let lowest = JointId::all()
            .map(|j| {
                d.physics
                    .geometry
                    .height_above(j, &fk.joint_in_world_m[j.index()], 0.0)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(lowest.abs() < 1e-9, "lowest ground point at {lowest} m");
        // 40 m/s in x becomes 15 m/s, and the root moved 15 m/s · dt.
        assert!((out.v[0] - MAX_ROOT_SPEED_MPS).abs() < 1e-9, "{}", out.v[0]);
        assert!((out.pose.root_in_world_m.x - MAX_ROOT_SPEED_MPS * DT_S).abs() < 1e-12);
    }
}
