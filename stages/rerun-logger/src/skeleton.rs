//! What the 3D views show: bodies as skeletons ([`SkeletonDrawer`]: MotionFrames through the body
//! model's forward kinematics, KinematicsFrames at the estimate's root, the truth beside the
//! estimate), their ground-reaction forces, contact points and forces ([`log_contacts`]), the IMU
//! sensors' orientations ([`log_sensors`]), and the fixed colours that tell the skeletons apart.

use imuflow_body::Imu;
use imuflow_body::skeleton::SIP_JOINTS;
use imuflow_body::{BodyModel, JointId, NUM_JOINTS, Pose, forward_kinematics};
use imuflow_graph::frames::{ContactFrame, FrameType, MAX_SITES, MotionFrame};

use crate::columns::{FrameTime, Log};
use crate::plots::{ErrorSeries, Plots, Posed, TRUTH_FRAMES_KEPT, group_of};
use imuflow_body::skeleton::{ALL_JOINTS, cut_bone_end, joint_tree};

/// Spacing of the sensors' display positions along x, m.
const SENSOR_SPACING_M: f32 = 0.3;
/// Length of the drawn axes, m.
const AXIS_LENGTH_M: f32 = 0.1;
/// Drawn length of a force arrow per newton (1 m per 1000 N: body weight is about 0.7 m).
const FORCE_ARROW_M_PER_N: f32 = 1e-3;
/// Joint point radius: base, and extra per N·m of joint torque.
const JOINT_RADIUS_M: f32 = 0.015;
const JOINT_RADIUS_M_PER_NM: f32 = 2e-4;
/// Radius of drawn bones, m.
const BONE_RADIUS_M: f32 = 0.008;
/// Fixed colours of a single run's skeletons, by input name (the legend names them): `motion` (the
/// estimate: physics, or the integrated networks), `kinematics` (the networks' pose), `truth`,
/// `validation` (the simulated body). Other skeletons get rerun's automatic colours, or their
/// group's. Okabe & Ito's colour-blind-safe palette (2008), green kept for the truth.
pub(crate) const MOTION_RGB: [u8; 3] = [0, 114, 178];
pub(crate) const NETWORK_RGB: [u8; 3] = [204, 121, 167];
pub(crate) const VALIDATION_RGB: [u8; 3] = [240, 150, 30];
pub(crate) const TRUTH_RGB: [u8; 3] = [120, 200, 120];
/// Group colours, in the order the groups first appear among the inputs (a colour-blind-safe
/// qualitative palette: Okabe & Ito, 2008; green left out for the truth).
const GROUP_PALETTE: [[u8; 3]; 6] = [
    [0, 114, 178],
    [213, 94, 0],
    [204, 121, 167],
    [230, 159, 0],
    [86, 180, 233],
    [240, 228, 66],
];
/// The input whose pelvis the follow view moves with (a single run's estimate), and the entity
/// that carries its position.
pub(crate) const FOLLOWED: &str = "motion";
pub(crate) const FOLLOW_ENTITY: &str = "follow";
/// With `truth = "beside"`: the truth's pose is drawn this far along +x from the estimate's root,
/// a body width and a half apart, so the two skeletons never overlap.
pub(crate) const TRUTH_BESIDE_M: f32 = 0.8;

/// Draws skeletons: forward kinematics of the body model for MotionFrames.
pub(crate) struct SkeletonDrawer {
    body: BodyModel,
    fk: imuflow_body::FkData,
    groups: Vec<String>,
    /// The errors are measured on the joints drawn here: the drawer hands each motion frame's
    /// pose on, and takes the truth's back to draw it beside the estimate.
    errors: ErrorSeries,
    /// Whether the run has a followed estimate ([`FOLLOWED`]) to draw kinematics frames at.
    pub follows_estimate: bool,
    /// The followed estimate's root positions by seq (its valid frames).
    estimate_roots: std::collections::BTreeMap<u64, [f32; 3]>,
    /// Kinematics frames waiting for the estimate of their seq.
    waiting_kinematics: WaitingKinematics,
    /// `truth = "beside"`: the truth is drawn with the followed estimate of its seq, moved beside it.
    pub truth_beside: bool,
    /// Whether a truth pose came (an input named `truth` can stay empty: a file of real sensors).
    pub truth_seen: bool,
    /// Motion inputs (by entity) estimated from a set that leaves joints at rest: the joints
    /// observed, and those drawn and measured ([`drawn_joints`]); the others are drawn whole.
    pub drawn: std::collections::BTreeMap<String, Estimated>,
}

/// What an estimate of a sensor set holds: the joints its sensors observe, and those drawn and
/// measured ([`drawn_joints`]), as masks over joint indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Estimated {
    pub observed: u32,
    pub drawn: u32,
}

impl Estimated {
    /// Every joint: a truth, or an estimate of the six.
    pub const ALL: Estimated = Estimated {
        observed: ALL_JOINTS,
        drawn: ALL_JOINTS,
    };

    pub fn of(observed: u32) -> Estimated {
        Estimated {
            observed,
            drawn: drawn_joints(observed),
        }
    }
}

/// The joints drawn of an estimate whose sensors observe `observed` (a mask over joint
/// indices): those joints, and for an observed joint whose children are all unobserved its first
/// child (the end of the bone it turns: a knee's shank reaches the ankle), as `imuflow export`
/// writes them. Every other joint sits at rest in the estimate: drawn, it would look estimated.
pub(crate) fn drawn_joints(observed: u32) -> u32 {
    let tree = joint_tree(observed);
    JointId::all()
        .filter(|j| tree & (1 << j.index()) != 0)
        .filter_map(|j| cut_bone_end(j, tree))
        .fold(tree, |drawn, end| drawn | 1 << end.index())
}

impl SkeletonDrawer {
    pub fn new(body: BodyModel, groups: Vec<String>, has_truth: bool) -> SkeletonDrawer {
        SkeletonDrawer {
            body,
            fk: imuflow_body::FkData::new(),
            errors: ErrorSeries::new(&groups, has_truth),
            groups,
            follows_estimate: false,
            estimate_roots: Default::default(),
            waiting_kinematics: Default::default(),
            truth_beside: false,
            truth_seen: false,
            drawn: Default::default(),
        }
    }

    /// Skeleton at its global position, ground-reaction force arrows, torque magnitudes.
    pub fn log_motion(
        &mut self,
        rec: &mut Log,
        input: &str,
        f: &MotionFrame,
    ) -> anyhow::Result<()> {
        let Ok(pose) = Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m) else {
            return Ok(()); // not a pose (e.g. an all-zero invalid frame): draw nothing
        };
        self.truth_seen |= input == "truth";
        forward_kinematics(&self.body.skeleton, &pose, &mut self.fk);
        let joints: [[f32; 3]; NUM_JOINTS] =
            self.fk.joint_in_world_m.map(|p| p.cast::<f32>().into());
        // Torque per joint: the norm of its three generalized-force entries (the root's: virtual torque).
        let torque: Vec<f32> = (0..NUM_JOINTS)
            .map(|j| {
                let t = &f.tau[3 + 3 * j..6 + 3 * j];
                (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt()
            })
            .collect();
        // Beside: the truth waits for the estimate of its seq (drawn below, next to it).
        if !(self.truth_beside && input == "truth") {
            self.log_joints(rec, input, &joints, Some(&torque))?;
        }
        let posed = Posed {
            joints,
            sip: SIP_JOINTS.map(|j| *self.fk.world_from(j)),
            holds: self.drawn.get(input).copied().unwrap_or(Estimated::ALL),
        };
        self.errors.track(rec, input, &f.header, &posed)?;
        if torque.iter().any(|t| *t != 0.0) {
            // Physics estimates only: the truth and the networks carry no torques.
            rec.log(
                format!("plots/{input}/torque_norm_nm"),
                &rerun::BarChart::new(torque),
            )?;
        }
        if input == FOLLOWED {
            let root = joints[JointId::ROOT.index()];
            rec.log(
                FOLLOW_ENTITY,
                &rerun::Transform3D::from_translation(follow_translation(root)),
            )?;
            if self.truth_beside {
                self.log_truth_beside(rec, f.header.seq, root)?;
            }
            self.estimate_roots.insert(f.header.seq, root);
            while self.estimate_roots.len() > TRUTH_FRAMES_KEPT {
                self.estimate_roots.pop_first();
            }
            self.place_waiting_kinematics(rec, f.header.seq, root)?;
        }
        let (origins, vectors): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (0..NUM_JOINTS)
            .filter(|&j| f.ground_reaction_force_n[j].iter().any(|v| *v != 0.0))
            .map(|j| {
                (
                    joints[j],
                    f.ground_reaction_force_n[j].map(|v| v * FORCE_ARROW_M_PER_N),
                )
            })
            .unzip();
        rec.log(
            format!("{input}/ground_reaction_force"),
            &rerun::Arrows3D::from_vectors(vectors)
                .with_origins(origins)
                .with_colors([rerun::Color::from_rgb(230, 80, 40)]),
        )?;
        Ok(())
    }

    /// A kinematics frame's root-relative joints, drawn at the root of the followed estimate
    /// ([`FOLLOWED`]) of the first valid frame at or after its seq (usually its own), else at
    /// the origin. Frames whose estimate has not come yet wait for it: where a frame is drawn
    /// must not depend on which input the logger happened to read first (the recording would
    /// differ between two runs of the same input).
    pub fn log_kinematics(
        &mut self,
        rec: &mut Log,
        input: &str,
        time: FrameTime,
        joints: &RelativeJoints,
    ) -> anyhow::Result<()> {
        if !self.follows_estimate {
            return self.log_joints(rec, input, &at_root(joints, [0.0; 3]), None);
        }
        if let Some((_, root)) = self.estimate_roots.range(time.seq..).next() {
            return self.log_joints(rec, input, &at_root(joints, *root), None);
        }
        self.waiting_kinematics.entry(time.seq).or_default().push((
            input.to_owned(),
            time,
            *joints,
        ));
        while self.waiting_kinematics.len() > TRUTH_FRAMES_KEPT {
            self.waiting_kinematics.pop_first();
        }
        Ok(())
    }

    /// Draws the kinematics frames up to `seq` that waited for an estimate, at `root` (the
    /// estimate of `seq`).
    fn place_waiting_kinematics(
        &mut self,
        rec: &mut Log,
        seq: u64,
        root: [f32; 3],
    ) -> anyhow::Result<()> {
        // Called for every estimate frame: nothing to do unless a frame up to `seq` waits.
        if self
            .waiting_kinematics
            .first_key_value()
            .is_none_or(|(first, _)| *first > seq)
        {
            return Ok(());
        }
        let later = self.waiting_kinematics.split_off(&(seq + 1));
        let due = std::mem::replace(&mut self.waiting_kinematics, later);
        self.draw_kinematics(rec, due, root)
    }

    /// At the end of the stream: the kinematics frames no estimate came for, at the last
    /// estimate's root (or the origin).
    pub fn place_remaining_kinematics(&mut self, rec: &mut Log) -> anyhow::Result<()> {
        let root = self
            .estimate_roots
            .values()
            .last()
            .copied()
            .unwrap_or([0.0; 3]);
        let due = std::mem::take(&mut self.waiting_kinematics);
        self.draw_kinematics(rec, due, root)
    }

    /// Kinematics frames that waited, drawn at `root`, each at its own time; the time is then
    /// set back to the frame being logged.
    fn draw_kinematics(
        &self,
        rec: &mut Log,
        due: WaitingKinematics,
        root: [f32; 3],
    ) -> anyhow::Result<()> {
        let now = rec.now();
        for (input, time, joints) in due.into_values().flatten() {
            rec.set_time(time)?;
            self.log_joints(rec, &input, &at_root(&joints, root), None)?;
        }
        rec.set_time(now)
    }

    /// The truth's pose of `seq`, its root moved horizontally to [`TRUTH_BESIDE_M`] along +x from the
    /// estimate's root (heights kept: both stand on the same floor).
    fn log_truth_beside(
        &self,
        rec: &mut Log,
        seq: u64,
        estimate_root: [f32; 3],
    ) -> anyhow::Result<()> {
        let Some(truth) = self.errors.truth(seq) else {
            return Ok(());
        };
        let joints = placed_beside(&truth.joints, estimate_root);
        self.log_joints(rec, "truth", &joints, None)
    }

    /// Joints as points (radius from `torque` when given) and bones as lines: every joint, or
    /// for an estimate of a set that leaves joints at rest, the joints it places ([`drawn_joints`]).
    fn log_joints(
        &self,
        rec: &mut Log,
        input: &str,
        joints: &[[f32; 3]; NUM_JOINTS],
        torque: Option<&[f32]>,
    ) -> anyhow::Result<()> {
        if !joints.iter().flatten().all(|v| v.is_finite()) {
            return Ok(());
        }
        let drawn = self.drawn.get(input).map_or(ALL_JOINTS, |e| e.drawn);
        let is_drawn = |j: JointId| drawn & (1 << j.index()) != 0;
        let radii: Vec<f32> = JointId::all()
            .filter(|&j| is_drawn(j))
            .map(|j| JOINT_RADIUS_M + torque.map_or(0.0, |t| t[j.index()] * JOINT_RADIUS_M_PER_NM))
            .collect();
        let mut points = rerun::Points3D::new(
            JointId::all()
                .filter(|&j| is_drawn(j))
                .map(|j| joints[j.index()]),
        )
        .with_radii(radii);
        let bones = JointId::all().filter(|&j| is_drawn(j)).filter_map(|j| {
            j.parent()
                .filter(|&p| is_drawn(p))
                .map(|p| [joints[p.index()], joints[j.index()]])
        });
        let mut lines = rerun::LineStrips3D::new(bones).with_radii([BONE_RADIUS_M]);
        if let Some(colour) = skeleton_colour(input, &self.groups) {
            points = points.with_colors([colour]);
            lines = lines.with_colors([colour]);
        }
        rec.log(format!("{input}/skeleton/joints"), &points)?;
        rec.log(format!("{input}/skeleton/bones"), &lines)?;
        Ok(())
    }
}

/// A kinematics frame's joints, relative to its root (m).
type RelativeJoints = [[f32; 3]; NUM_JOINTS];

/// Kinematics frames by seq: input, time and root-relative joints.
type WaitingKinematics = std::collections::BTreeMap<u64, Vec<(String, FrameTime, RelativeJoints)>>;

/// Root-relative `joints` placed at `root`.
fn at_root(joints: &RelativeJoints, root: [f32; 3]) -> [[f32; 3]; NUM_JOINTS] {
    joints.map(|p| [p[0] + root[0], p[1] + root[1], p[2] + root[2]])
}

/// The follow view's origin for an estimate whose root is at `root`: the point on the floor below
/// it (y = 0, the floor the views draw), so that the view's eye, fixed in this frame, moves with
/// the body along the floor and does not bob with the pelvis.
fn follow_translation(root: [f32; 3]) -> [f32; 3] {
    [root[0], 0.0, root[2]]
}

/// `joints` moved horizontally so that their root stands [`TRUTH_BESIDE_M`] along +x from
/// `estimate_root` (heights kept: both stand on the same floor).
fn placed_beside(
    joints: &[[f32; 3]; NUM_JOINTS],
    estimate_root: [f32; 3],
) -> [[f32; 3]; NUM_JOINTS] {
    let root = joints[JointId::ROOT.index()];
    let shift = [
        estimate_root[0] + TRUTH_BESIDE_M - root[0],
        0.0,
        estimate_root[2] - root[2],
    ];
    joints.map(|p| [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]])
}

/// The colour of the skeleton at `entity`, if it has a fixed one.
fn skeleton_colour(entity: &str, groups: &[String]) -> Option<rerun::Color> {
    let what = entity.rsplit('/').next().unwrap_or(entity);
    let [r, g, b] = match (group_of(entity), what) {
        (None, "validation") => VALIDATION_RGB,
        (None, "truth") => TRUTH_RGB,
        (None, "motion") => MOTION_RGB,
        (None, "kinematics") => NETWORK_RGB,
        (None, _) => return None,
        (Some(group), what) => {
            let index = groups.iter().position(|g| g == group)?;
            let base = GROUP_PALETTE[index % GROUP_PALETTE.len()];
            if what == "validation" {
                // The simulated body: the group's colour halfway to white.
                base.map(|c| c / 2 + 128)
            } else {
                base
            }
        }
    };
    Some(rerun::Color::from_rgb(r, g, b))
}

/// Contact points and their forces.
pub(crate) fn log_contacts(rec: &mut Log, input: &str, f: &ContactFrame) -> anyhow::Result<()> {
    let n = (f.num_points as usize).min(f.point_position_m.len());
    let points = &f.point_position_m[..n];
    if !points.iter().flatten().all(|v| v.is_finite()) {
        return Ok(());
    }
    rec.log(
        format!("{input}/points"),
        &rerun::Points3D::new(points.iter().copied())
            .with_radii([0.02])
            .with_colors([rerun::Color::from_rgb(40, 160, 230)]),
    )?;
    let forces = f.point_force_n[..n]
        .iter()
        .map(|v| v.map(|x| x * FORCE_ARROW_M_PER_N));
    rec.log(
        format!("{input}/forces"),
        &rerun::Arrows3D::from_vectors(forces).with_origins(points.iter().copied()),
    )?;
    Ok(())
}

/// Where each IMU input's sensors (the graph's set's `sites`) stand (side by side along x, so
/// their axes do not overlap), and their axes: static, logged once before the frames.
pub(crate) fn log_sensor_layout(
    rec: &rerun::RecordingStream,
    inputs: &[(String, FrameType)],
    sites: &[Imu],
) -> anyhow::Result<()> {
    for (name, frame) in inputs {
        if matches!(frame, FrameType::Imu | FrameType::BodyImu) {
            for (k, sensor) in sites.iter().map(|s| s.name()).enumerate() {
                let base = format!("{name}/{sensor}");
                rec.log_static(
                    base.clone(),
                    &rerun::Transform3D::from_translation([k as f32 * SENSOR_SPACING_M, 0.0, 0.0]),
                )?;
                rec.log_static(
                    format!("{base}/orientation"),
                    &rerun::TransformAxes3D::new(AXIS_LENGTH_M),
                )?;
            }
        }
    }
    Ok(())
}

/// Each valid sensor's orientation (turning its axes), with its signals as time series next to
/// it: the sensors of the graph's set (`sites`) are drawn and plotted in one pass, as the frame
/// carries them.
#[allow(clippy::too_many_arguments)]
pub(crate) fn log_sensors(
    rec: &mut Log,
    plots: &mut Plots,
    input: &str,
    sites: &[Imu],
    orientation_wxyz: &[[f32; 4]; MAX_SITES],
    accel: &[[f32; 3]; MAX_SITES],
    rate: &[[f32; 3]; MAX_SITES],
    valid_mask: u32,
    names: [&str; 2],
) -> anyhow::Result<()> {
    for (k, sensor) in sites.iter().map(|s| (s.index(), s.name())) {
        let valid = valid_mask & (1 << k) != 0;
        let [w, x, y, z] = orientation_wxyz[k];
        if valid && [w, x, y, z].iter().all(|v| v.is_finite()) {
            rec.log(
                format!("{input}/{sensor}/orientation"),
                &rerun::Transform3D::from_rotation(rerun::Quaternion::from_xyzw([x, y, z, w])),
            )?;
            rec.log(
                format!("plots/{input}/{sensor}/{}", names[0]),
                &rerun::Scalars::new(accel[k]),
            )?;
            rec.log(
                format!("plots/{input}/{sensor}/{}", names[1]),
                &rerun::Scalars::new(rate[k]),
            )?;
        }
        plots.series(
            rec,
            format!("plots/{input}/{sensor}/valid"),
            vec![if valid { 1.0 } else { 0.0 }],
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_lower_body_estimate_draws_its_legs_to_the_ankles_and_nothing_above_the_pelvis() {
        let legs = imuflow_body::SensorSet::builtin("lower-body").expect("shipped");
        let drawn = drawn_joints(legs.observed_joints());
        let names: Vec<&str> = JointId::all()
            .filter(|j| drawn & (1 << j.index()) != 0)
            .map(|j| j.name())
            .collect();
        assert_eq!(
            names,
            [
                "pelvis",
                "left_hip",
                "right_hip",
                "left_knee",
                "right_knee",
                "left_ankle",
                "right_ankle"
            ]
        );
        // The six: its wrists and ankles end the forearms and shanks; feet and hands not drawn.
        let six = drawn_joints(imuflow_body::SensorSet::six().observed_joints());
        assert_eq!(six.count_ones(), 24 - 2 - 2);
    }

    use super::*;
    use imuflow_graph::naming::entity_of;

    #[test]
    fn grouped_inputs_become_entity_paths_with_their_group_colour() {
        assert_eq!(entity_of("pip__motion"), "pip/motion");
        assert_eq!(entity_of("motion"), "motion");
        let groups = vec!["pip".to_owned(), "globalpose".to_owned()];
        let rgb = |e: &str| skeleton_colour(e, &groups).map(|c| c.to_array());
        assert_eq!(rgb("pip/motion"), Some([0, 114, 178, 255]));
        assert_eq!(rgb("globalpose/motion"), Some([213, 94, 0, 255]));
        // The simulated body: halfway to white.
        assert_eq!(rgb("pip/validation"), Some([128, 185, 217, 255]));
        assert_eq!(rgb("truth"), Some([120, 200, 120, 255]));
        assert_eq!(rgb("validation"), Some([240, 150, 30, 255]));
        assert_eq!(rgb("motion"), Some([0, 114, 178, 255]));
        assert_eq!(rgb("kinematics"), Some([204, 121, 167, 255]));
        assert_eq!(rgb("my_filter"), None);
        assert_eq!(rgb("other/motion"), None);
    }

    #[test]
    fn the_follow_origin_is_the_floor_point_below_the_root() {
        // Hand-derived: 12 m along z and 0.4 m to the left, the pelvis 0.93 m up.
        assert_eq!(follow_translation([0.4, 0.93, 12.0]), [0.4, 0.0, 12.0]);
    }

    #[test]
    fn the_truth_beside_keeps_its_pose_and_heights_next_to_the_estimate_root() {
        let truth: [[f32; 3]; NUM_JOINTS] = std::array::from_fn(|j| {
            [
                3.0 + 0.01 * j as f32,
                0.9 + 0.02 * j as f32,
                -2.0 + 0.03 * j as f32,
            ]
        });
        let estimate_root = [10.0, 0.95, 4.0];
        let beside = placed_beside(&truth, estimate_root);
        let root = beside[JointId::ROOT.index()];
        // Hand-derived: x = 10 + 0.8, the truth's own height, z = 4.
        assert!(
            (root[0] - 10.8).abs() < 1e-5 && (root[2] - 4.0).abs() < 1e-5,
            "{root:?}"
        );
        for j in 0..NUM_JOINTS {
            assert_eq!(beside[j][1], truth[j][1], "heights kept");
            for k in [0, 2] {
                let moved = beside[j][k] - root[k];
                let original = truth[j][k] - truth[JointId::ROOT.index()][k];
                assert!((moved - original).abs() < 1e-5, "the pose is kept");
            }
        }
    }
}
