//! The controller-free score: could the floor carry the estimated motion at all?
//!
//! Whole-body inverse dynamics of the estimate (the body model's RNEA, the root's six rows) gives
//! the force and moment the floor must exert for the motion to happen. With foot contacts only,
//! that wrench is possible only when it pushes (vertical force up) and its centre of pressure lies
//! inside the support polygon of the soles touching the floor. Unlike the simulation's falls, this
//! judges the estimate without any controller in between: a motion the simulated body fails to
//! walk because its controller is too simple still scores here as well as it deserves, and a
//! floating or leaning estimate scores badly however the controller copes.
//!
//! Velocities and accelerations are central finite differences over [`SUPPORT_FRAMES`] frames each
//! way, so the score of a frame is known that many frames later: the stage reports each frame's
//! score [`SUPPORT_FRAMES`] frames late (the `ValidationFrame` field docs say so).
//!
//! On the retargeted true walks of the test split (the `track` example's `SIM_COP=1`), the needed
//! centre of pressure lies more than 3 cm outside the feet in 58 % of the frames with a foot down:
//! the truth is the reference to compare estimates with, not zero.

use std::collections::VecDeque;

use imuflow_body::dynamics::{DofVector, DynamicsData, RigidBodyModel, joint_dof};
use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::JointId;
use nalgebra::{Vector2, Vector3};

use crate::model::{Shape, SimModel};

/// Frames each way of the finite differences: 2 at 60 Hz (±33 ms), which spans one frame of
/// 30 Hz motion data resampled to 60 Hz (second differences over single frames of such data are
/// mostly the resampling's corners). [inferred]
pub const SUPPORT_FRAMES: usize = 2;
/// A sole corner within this height of the floor touches it, m: estimates place their feet a
/// centimetre or two off the floor, and the retargeted truth's soles stand up to 2 cm high.
/// [inferred]
pub const CONTACT_HEIGHT_M: f64 = 0.04;
/// A centre of pressure further than this outside the feet counts as unsupported in the summary,
/// m: about the sole's half width, beyond what a shoe or a rolling foot could add. [inferred]
pub const OUTSIDE_TOLERANCE_M: f64 = 0.03;
/// Vertical floor force below this fraction of body weight is no question of support: a flight,
/// or the noise of the differences around one. [inferred]
const LIGHT_LOAD_FRACTION: f64 = 0.25;

/// What the floor would have to do for one frame of the estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u32)]
pub enum SupportState {
    /// Not judged: too few consecutive frames yet (the start, after a gap or a recalibration).
    #[default]
    Unjudged = 0,
    /// Feet on the floor push the body: `gap_m` says how far outside them the centre of pressure is.
    Feet = 1,
    /// The motion needs little or no floor force (a flight, or nearly): nothing to carry.
    Light = 2,
    /// The floor would have to push a body with no foot on it, or pull one down: no contact can.
    Unsupported = 3,
}

impl SupportState {
    /// The state a `ValidationFrame`'s `support` field holds (`state as u32`); unknown values read
    /// as not judged.
    pub fn from_wire(value: u32) -> SupportState {
        match value {
            1 => SupportState::Feet,
            2 => SupportState::Light,
            3 => SupportState::Unsupported,
            _ => SupportState::Unjudged,
        }
    }
}

/// The support score of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Support {
    pub state: SupportState,
    /// How far the needed centre of pressure lies outside the support polygon, m (0 inside, and
    /// in every state but [`SupportState::Feet`]).
    pub gap_m: f64,
    /// The needed centre of pressure on the floor (x, z of model frame M), m, when the floor pushes.
    pub centre_of_pressure_m: Option<Vector2<f64>>,
    /// The vertical floor force the motion needs, as a fraction of body weight.
    pub load_fraction: f64,
}

impl Support {
    /// Whether the frame counts against the estimate: unsupported, or its centre of pressure more
    /// than [`OUTSIDE_TOLERANCE_M`] outside the feet.
    pub fn violated(&self) -> bool {
        self.state == SupportState::Unsupported || self.gap_m > OUTSIDE_TOLERANCE_M
    }
}

/// Judges the support of a stream of estimated poses, frame by frame.
pub struct SupportJudge {
    model: RigidBodyModel,
    data: DynamicsData,
    /// The sole corners of the feet, four per foot: the carrying joint and the corner in its
    /// frame, m.
    sole_corners: Vec<(JointId, Vector3<f64>)>,
    weight_n: f64,
    /// The last `2·SUPPORT_FRAMES + 1` consecutive usable poses with their frame durations.
    history: VecDeque<(Pose, f64)>,
}

impl SupportJudge {
    /// A judge for `model`'s body, its soles those of the simulated foot boxes.
    pub fn new(model: &SimModel) -> SupportJudge {
        let sole_corners = model
            .links
            .iter()
            .flat_map(|link| {
                link.shapes
                    .iter()
                    .filter_map(move |(_, shape)| match shape {
                        Shape::Cuboid {
                            centre,
                            half_extents: h,
                            rotation,
                        } => Some(
                            [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)]
                                .map(|(x, z)| {
                                    (
                                        link.joint,
                                        centre + rotation * Vector3::new(x * h.x, -h.y, z * h.z),
                                    )
                                })
                                .to_vec(),
                        ),
                        _ => None,
                    })
            })
            .flatten()
            .collect();
        let rigid = RigidBodyModel::new(&model.body);
        let weight_n = rigid.total_mass_kg() * 9.81;
        SupportJudge {
            model: rigid,
            data: DynamicsData::new(),
            sole_corners,
            weight_n,
            history: VecDeque::with_capacity(2 * SUPPORT_FRAMES + 1),
        }
    }

    /// Forgets the poses seen so far (a gap in the stream, a recalibration).
    pub fn clear(&mut self) {
        self.history.clear();
    }

    /// Takes the next frame's estimate (`None`: unusable, which breaks the sequence) lasting `dt`
    /// seconds, and returns the support of the frame [`SUPPORT_FRAMES`] frames before it.
    pub fn push(&mut self, estimate: Option<&Pose>, dt: f64) -> Support {
        let Some(pose) = estimate else {
            self.clear();
            return Support::default();
        };
        if self.history.len() == 2 * SUPPORT_FRAMES + 1 {
            self.history.pop_front();
        }
        self.history.push_back((pose.clone(), dt));
        if self.history.len() < 2 * SUPPORT_FRAMES + 1 {
            return Support::default();
        }
        let k = SUPPORT_FRAMES;
        let (before, now, after) = (&self.history[0], &self.history[k], &self.history[2 * k]);
        let span_before: f64 = self.history.range(1..=k).map(|(_, dt)| dt).sum();
        let span_after: f64 = self.history.range(k + 1..).map(|(_, dt)| dt).sum();
        let v0 = velocity(&before.0, &now.0, span_before);
        let v1 = velocity(&now.0, &after.0, span_after);
        let v = (v0 + v1) / 2.0;
        let vdot = (v1 - v0) / (0.5 * (span_before + span_after));
        let now = now.0.clone();
        self.needed_support(&now, &v, &vdot)
    }

    /// The support that pose `pose` moving with velocity `v` and acceleration `vdot` needs.
    pub fn needed_support(&mut self, pose: &Pose, v: &DofVector, vdot: &DofVector) -> Support {
        self.data.set_state(&self.model, pose, v);
        let mut tau = DofVector::zeros();
        self.data.inverse_dynamics(&self.model, vdot, &mut tau);
        let (force, centre_of_pressure) = floor_force(&self.data, &tau);
        let load_fraction = force.y / self.weight_n;
        // A foot touches when any of its sole corners is near the floor, and then supports with
        // its whole sole: the papers' networks do not estimate the ankles (they stay at the rest
        // pose), so an estimated foot tilts with its shank and would otherwise stand on an edge
        // that a real ankle would have laid flat.
        let mut corners: Vec<Vector2<f64>> = Vec::with_capacity(self.sole_corners.len());
        for foot in self.sole_corners.chunks(4) {
            let points = foot
                .iter()
                .map(|(joint, corner)| self.data.point_position(*joint, corner));
            if points.clone().any(|p| p.y < CONTACT_HEIGHT_M) {
                corners.extend(points.map(|p| Vector2::new(p.x, p.z)));
            }
        }
        let (state, gap_m) = match centre_of_pressure {
            _ if load_fraction < -LIGHT_LOAD_FRACTION => (SupportState::Unsupported, 0.0),
            Some(cop) if load_fraction >= LIGHT_LOAD_FRACTION => {
                if corners.is_empty() {
                    (SupportState::Unsupported, 0.0)
                } else {
                    (SupportState::Feet, distance_outside_hull(&cop, &corners))
                }
            }
            _ => (SupportState::Light, 0.0),
        };
        Support {
            state,
            gap_m,
            // Only a floor that pushes hard enough to matter has a centre of pressure to report.
            centre_of_pressure_m: centre_of_pressure
                .filter(|_| load_fraction >= LIGHT_LOAD_FRACTION),
            load_fraction,
        }
    }
}

/// The floor's force on the body (model frame M, N) that the root's rows of inverse dynamics
/// `tau`, at the state in `data`, ask for, and its centre of pressure on the floor y = 0 (x, z of
/// M, m) when that force pushes (its vertical part is positive).
pub fn floor_force(data: &DynamicsData, tau: &DofVector) -> (Vector3<f64>, Option<Vector2<f64>>) {
    // The root's rows: the force in M; the torque in the pelvis frame, about the pelvis origin.
    let force = Vector3::new(tau[0], tau[1], tau[2]);
    let origin = data.fk().joint_in_world_m[0];
    let moment = data.fk().world_from_joint[0] * Vector3::new(tau[3], tau[4], tau[5]);
    // Centre of pressure p on y = 0: moment = (p − origin) × force + a free moment about y.
    let centre_of_pressure = (force.y > 0.0).then(|| {
        Vector2::new(
            origin.x + (moment.z - origin.y * force.x) / force.y,
            origin.z + (-moment.x - origin.y * force.z) / force.y,
        )
    });
    (force, centre_of_pressure)
}

/// The generalized velocity that takes pose `a` to pose `b` in `dt` seconds (the coordinates of
/// [`imuflow_body::dynamics`]: root translation in M, each joint's rotation vector in its own frame).
pub fn velocity(a: &Pose, b: &Pose, dt: f64) -> DofVector {
    let mut v = DofVector::zeros();
    v.fixed_rows_mut::<3>(0)
        .copy_from(&((b.root_in_world_m - a.root_in_world_m) / dt));
    for j in JointId::all() {
        let i = j.index();
        let w =
            axis_angle_from_rotation(&(a.parent_from_joint[i].inverse() * b.parent_from_joint[i]))
                / dt;
        v.fixed_rows_mut::<3>(joint_dof(j)).copy_from(&w);
    }
    v
}

/// How far `p` lies outside the convex hull of `points` (0 inside), m. `points` must not be empty.
pub fn distance_outside_hull(p: &Vector2<f64>, points: &[Vector2<f64>]) -> f64 {
    let hull = convex_hull(points);
    let segment_distance = |a: &Vector2<f64>, b: &Vector2<f64>| {
        let ab = b - a;
        let t = if ab.norm_squared() > 0.0 {
            ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (a + ab * t - p).norm()
    };
    match hull.len() {
        0 => f64::INFINITY,
        1 => (hull[0] - p).norm(),
        2 => segment_distance(&hull[0], &hull[1]),
        n => {
            let inside = (0..n).all(|i| cross(&hull[i], &hull[(i + 1) % n], p) >= -1e-12);
            if inside {
                0.0
            } else {
                (0..n)
                    .map(|i| segment_distance(&hull[i], &hull[(i + 1) % n]))
                    .fold(f64::INFINITY, f64::min)
            }
        }
    }
}

/// `(a − o) × (b − o)`: positive when `o → a → b` turns counter-clockwise.
fn cross(o: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    (a - o).perp(&(b - o))
}

/// The convex hull of `points`, counter-clockwise, without collinear points (Andrew's monotone
/// chain; at most eight sole corners here, so hand-written rather than a geometry crate).
fn convex_hull(points: &[Vector2<f64>]) -> Vec<Vector2<f64>> {
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    sorted.dedup();
    if sorted.len() < 3 {
        return sorted;
    }
    let mut hull: Vec<Vector2<f64>> = Vec::with_capacity(2 * sorted.len());
    for pass in [
        &sorted[..],
        &sorted.iter().rev().copied().collect::<Vec<_>>()[..],
    ] {
        let start = hull.len();
        for p in pass {
            while hull.len() >= start + 2
                && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(*p);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::body_model::{BodyModel, BodyParams};

    fn square() -> Vec<Vector2<f64>> {
        vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(1.0, 0.0),
            Vector2::new(1.0, 1.0),
            Vector2::new(0.0, 1.0),
            Vector2::new(0.5, 0.5),
        ]
    }

    #[test]
    fn distance_outside_a_square_is_the_distance_to_its_nearest_edge_or_corner() {
        let s = square();
        assert_eq!(distance_outside_hull(&Vector2::new(0.3, 0.7), &s), 0.0);
        assert_eq!(distance_outside_hull(&Vector2::new(1.0, 0.5), &s), 0.0);
        assert!((distance_outside_hull(&Vector2::new(1.25, 0.5), &s) - 0.25).abs() < 1e-12);
        assert!((distance_outside_hull(&Vector2::new(0.5, -0.1), &s) - 0.1).abs() < 1e-12);
        let corner = distance_outside_hull(&Vector2::new(-0.3, -0.4), &s);
        assert!((corner - 0.5).abs() < 1e-12, "{corner}");
        // Degenerate hulls: a segment and a point.
        let line = [
            Vector2::new(0.0, 0.0),
            Vector2::new(2.0, 0.0),
            Vector2::new(1.0, 0.0),
        ];
        assert!((distance_outside_hull(&Vector2::new(1.0, 0.3), &line) - 0.3).abs() < 1e-12);
        let point = [Vector2::new(1.0, 1.0), Vector2::new(1.0, 1.0)];
        assert!((distance_outside_hull(&Vector2::new(1.0, 3.0), &point) - 2.0).abs() < 1e-12);
    }

    /// A second algorithm: a point is inside the hull iff it lies in a triangle of three of the
    /// points (Carathéodory); outside, the nearest hull point is on an edge, and every segment
    /// between two points lies inside the hull, so the distance is the least over all pairs.
    fn brute_force_distance(p: &Vector2<f64>, points: &[Vector2<f64>]) -> f64 {
        let n = points.len();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let (a, b, c) = (&points[i], &points[j], &points[k]);
                    let area = cross(a, b, c);
                    if area.abs() < 1e-12 {
                        continue;
                    }
                    let s = area.signum();
                    if s * cross(a, b, p) >= 0.0
                        && s * cross(b, c, p) >= 0.0
                        && s * cross(c, a, p) >= 0.0
                    {
                        return 0.0;
                    }
                }
            }
        }
        let mut best = f64::INFINITY;
        for a in points {
            for b in points {
                let ab = b - a;
                let t = if ab.norm_squared() > 0.0 {
                    ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                best = best.min((a + ab * t - p).norm());
            }
        }
        best
    }

    #[test]
    fn the_hull_distance_matches_a_brute_force_computation_on_random_feet() {
        // A small linear congruential generator: deterministic, no dependency.
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for _ in 0..500 {
            let n = 3 + ((next() + 0.5) * 6.0) as usize;
            let points: Vec<Vector2<f64>> = (0..n).map(|_| Vector2::new(next(), next())).collect();
            for _ in 0..10 {
                let p = Vector2::new(2.0 * next(), 2.0 * next());
                let (fast, slow) = (
                    distance_outside_hull(&p, &points),
                    brute_force_distance(&p, &points),
                );
                assert!(
                    (fast - slow).abs() < 1e-9,
                    "{fast} vs {slow} for {p:?} in {points:?}"
                );
            }
        }
    }

    #[test]
    fn a_state_reads_back_from_the_wire_as_written() {
        use SupportState::*;
        for state in [Unjudged, Feet, Light, Unsupported] {
            assert_eq!(SupportState::from_wire(state as u32), state);
        }
        assert_eq!(SupportState::from_wire(7), Unjudged);
    }

    fn judge() -> (SupportJudge, BodyModel) {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        (SupportJudge::new(&SimModel::new(&body)), body)
    }

    /// The rest pose standing on the floor (its soles at y = 0).
    fn standing(body: &BodyModel) -> Pose {
        Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m, 0.0))
    }

    #[test]
    fn a_body_at_rest_needs_its_weight_at_the_centre_of_mass_projection() {
        // Statics: at rest the floor carries the weight under the centre of mass (an independent
        // computation: the body model's mass-weighted segment centres).
        let (mut judge, body) = judge();
        let pose = standing(&body);
        let zero = DofVector::zeros();
        let s = judge.needed_support(&pose, &zero, &zero);
        assert_eq!(s.state, SupportState::Feet);
        assert!((s.load_fraction - 1.0).abs() < 1e-9, "{}", s.load_fraction);
        let com = judge.data.center_of_mass(&judge.model);
        let cop = s.centre_of_pressure_m.unwrap();
        assert!((cop - com.xz()).norm() < 1e-9, "{cop} vs {com}");
        assert_eq!(s.gap_m, 0.0);
        assert!(!s.violated());
    }

    #[test]
    fn a_body_leaning_past_its_toes_needs_support_outside_its_feet() {
        // The whole body pitched forward: at rest the centre of pressure is the centre of mass's
        // projection, which now lies ahead of the toes (the front sole corners of the feet, both
        // touching) by a computable amount.
        let (mut judge, body) = judge();
        let mut pose = standing(&body);
        pose.parent_from_joint[0] = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), 0.3);
        let zero = DofVector::zeros();
        // Lower the body until its lowest sole corner touches the floor again.
        judge.data.set_state(&judge.model, &pose, &zero);
        let lowest = judge
            .sole_corners
            .iter()
            .map(|(j, c)| judge.data.point_position(*j, c).y)
            .fold(f64::INFINITY, f64::min);
        pose.root_in_world_m.y -= lowest;
        let s = judge.needed_support(&pose, &zero, &zero);
        judge.data.set_state(&judge.model, &pose, &zero);
        let com = judge.data.center_of_mass(&judge.model);
        let front = judge
            .sole_corners
            .iter()
            .map(|(j, c)| judge.data.point_position(*j, c).z)
            .fold(f64::NEG_INFINITY, f64::max);
        assert_eq!(s.state, SupportState::Feet);
        let expected = com.z - front;
        assert!(
            expected > 0.1,
            "the lean puts the centre of mass {expected} m past the feet"
        );
        assert!(
            (s.gap_m - expected).abs() < 1e-6,
            "{} vs {expected}",
            s.gap_m
        );
        assert!(s.violated());
    }

    #[test]
    fn a_floating_body_and_a_falling_faster_than_gravity_one_are_unsupported() {
        let (mut judge, body) = judge();
        let zero = DofVector::zeros();
        let mut floating = standing(&body);
        floating.root_in_world_m.y += 0.3;
        let s = judge.needed_support(&floating, &zero, &zero);
        assert_eq!(s.state, SupportState::Unsupported);
        assert!(s.violated());
        // Free fall needs no floor: light. Falling at twice gravity needs the floor to pull.
        let mut fall = DofVector::zeros();
        fall[1] = -9.81;
        assert_eq!(
            judge.needed_support(&floating, &zero, &fall).state,
            SupportState::Light
        );
        fall[1] = -2.0 * 9.81;
        let s = judge.needed_support(&standing(&body), &zero, &fall);
        assert_eq!(s.state, SupportState::Unsupported);
    }

    #[test]
    fn a_stream_is_judged_from_its_differences_frames_late() {
        // The standing body lifted at constant speed: no acceleration, so the same support as at
        // rest once enough frames are in; the first 2k frames and the frame after a gap are not
        // judged.
        let (mut judge, body) = judge();
        let dt = 1.0 / 60.0;
        let mut states = Vec::new();
        for t in 0..8 {
            let mut pose = standing(&body);
            pose.root_in_world_m.x += 0.5 * dt * t as f64;
            let estimate = (t != 5).then_some(&pose);
            states.push(judge.push(estimate, dt).state);
        }
        use SupportState::{Feet, Unjudged};
        let expected = [
            Unjudged, Unjudged, Unjudged, Unjudged, Feet, Unjudged, Unjudged, Unjudged,
        ];
        assert_eq!(states, expected);
    }
}
