//! The rapier3d simulation: the body's links joined by spherical joints, built from a
//! [`SimModel`], standing on a half-space floor at y = 0, driven by joint motors that track an
//! estimated pose. The links are either rigid bodies held together by impulse joints (the default)
//! or one multibody in reduced coordinates ([`Joints`]); everything else is the same for both.
//!
//! Conventions that make the tracking exact to state: every link's frame is its joint's frame
//! (`local_frame2` = identity), and the joint anchor in the parent is the skeleton's bone offset
//! with no rotation (`local_frame1` = translation only). rapier then composes
//! `child_in_parent = offset · joint_rot`, so a spherical joint's `joint_rot` *is* the skeleton's
//! local rotation `parent_from_joint`, and its three generalized velocities (a multibody's) or its
//! motors' velocities (an impulse joint's) are the child's angular velocity relative to the
//! parent, expressed in the parent's frame.

use imuflow_body::kinematics::{FkData, Pose, forward_kinematics};
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::{JointId, NUM_JOINTS};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector3};
use rapier3d::glamx::{Quat, Vec3};
use rapier3d::prelude::*;

use crate::model::{Shape, SimModel};
use crate::stage::ValidationParams;

/// Standard gravity along M's -y, m/s².
const GRAVITY_MPS2: f64 = 9.81;
/// The root's (pelvis) stance feedback starts only when the feet carry this share of the weight:
/// a foot that barely touches cannot hold the pelvis up. [inferred]
const STANCE_LOAD_FRACTION: f64 = 0.2;
/// A foot is the stance foot (and the other one swings) when it carries this share of the feet's
/// load. [inferred]
const SINGLE_STANCE_SHARE: f64 = 0.8;
/// The estimate swings a foot when its ball is this much higher than the other's, m. [inferred]
const SWING_CLEARANCE_M: f64 = 0.02;
/// Largest foot-placement shift, m. [inferred]
const MAX_PLACEMENT_SHIFT_M: f64 = 0.3;
/// A swing knee is bent further for clearance only when the estimate bends it at least this
/// much (its bend gives the direction). [inferred]
const MIN_SWING_KNEE_BEND_RAD: f64 = 0.1;
/// Largest extra swing-knee bend for clearance, rad. [inferred]
const MAX_CLEARANCE_BEND_RAD: f64 = 0.5;
/// The feet's balls, [left, right].
const FEET: [JointId; 2] = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT];

/// How the root is driven.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Root unactuated: only joint torques and ground contact move the body (the honest test).
    Torques,
    /// A weak PD force and torque on the root keep it near the estimate; its size is reported.
    Residual,
}

impl Mode {
    pub const NAMES: [&'static str; 2] = ["torques", "residual"];

    pub fn parse(name: &str) -> Option<Mode> {
        match name {
            "torques" => Some(Mode::Torques),
            "residual" => Some(Mode::Residual),
            _ => None,
        }
    }
}

/// How the links are joined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Joints {
    /// One rapier multibody in reduced coordinates: the joints cannot come apart, at the cost of
    /// a dense mass matrix recomputed every physics step.
    Multibody,
    /// A rigid body per link held together by rapier impulse joints (maximal coordinates): each
    /// joint is a constraint the solver meets only approximately, at a cost linear in the links.
    Impulse,
}

impl Joints {
    pub const NAMES: [&'static str; 2] = ["multibody", "impulse"];

    pub fn parse(name: &str) -> Option<Joints> {
        match name {
            "multibody" => Some(Joints::Multibody),
            "impulse" => Some(Joints::Impulse),
            _ => None,
        }
    }

    /// The solver settings that suit these joints, (iterations, sweeps) per physics step
    /// (measured on the test split's walks and runs; stages/validation/README.md, "Joints"):
    /// - multibody: one solver iteration of four sweeps per physics step. Every iteration
    ///   recomputes the multibody's dense mass matrix (most of the time), and with one sweep the
    ///   stiff motors, coupled through that matrix, let a held T-pose fold at the knees within
    ///   1.5 s; with four it stands to 5 mm.
    /// - impulse: four iterations of twelve sweeps. Each joint is its own constraint, met
    ///   only as far as the sweeps carry a correction along the chain: with one iteration of four
    ///   sweeps the chain sagged (pose error on the sample's walk 10.7 against 5.0 cm) and fell four
    ///   times as often. Sweeps are cheap here, there is no mass matrix to rebuild.
    pub fn solver_settings(self) -> (usize, usize) {
        match self {
            Joints::Multibody => (1, 4),
            Joints::Impulse => (4, 12),
        }
    }
}

/// Gains and settings of the simulation. Joint gains are per unit of the inertia a joint drives
/// ([`crate::model::Link::driven_inertia_kgm2`]), so every joint tracks with the same natural
/// frequency: `kp = ω²`, `kd = 2ζω`.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    pub mode: Mode,
    /// Joint stiffness per unit driven inertia, 1/s² (900: ω = 30 rad/s, about 4.8 Hz).
    pub kp: f64,
    /// Joint damping per unit driven inertia, 1/s (60: critically damped at ω = 30 rad/s).
    pub kd: f64,
    /// Largest joint torque per kg of body mass, N·m/kg (a strong adult's hip or knee: about 3-4).
    pub max_torque_nm_per_kg: f64,
    /// Pelvis-orientation feedback through the stance hips, per unit root inertia, 1/s² and 1/s.
    pub balance_kp: f64,
    pub balance_kd: f64,
    /// Foot placement: the swing foot is put this far further per metre the simulated centre of
    /// mass is ahead of the estimate's (relative to the stance foot), and per m/s it is faster.
    pub placement_kp: f64,
    pub placement_kv: f64,
    /// Residual mode: root PD per unit mass (force) and root inertia (torque), 1/s² and 1/s.
    pub residual_kp: f64,
    pub residual_kd: f64,
    /// Swing clearance: extra swing-knee bend per shank length the simulated swing foot hangs
    /// lower than the estimate's (see `Simulation::swing_clearance`).
    pub clearance_gain: f64,
    /// Friction coefficient between body and floor.
    pub friction: f64,
    /// Physics steps per input frame.
    pub substeps: usize,
    /// rapier solver iterations (its internal substeps) per physics step.
    pub solver_iterations: usize,
    /// Gauss-Seidel sweeps per solver iteration (rapier's `num_internal_pgs_iterations`).
    pub solver_sweeps: usize,
    /// How the links are joined.
    pub joints: Joints,
}

impl Default for SimConfig {
    /// The validation stage's defaults ([`ValidationParams`]).
    fn default() -> SimConfig {
        ValidationParams::default().sim_config()
    }
}

impl SimConfig {
    /// The defaults with `joints` and the solver settings that suit them
    /// ([`Joints::solver_settings`]).
    pub fn for_joints(joints: Joints) -> SimConfig {
        ValidationParams {
            joints,
            ..ValidationParams::default()
        }
        .sim_config()
    }
}

/// What the simulation should track this frame: the estimate's pose and its velocities.
#[derive(Debug, Clone)]
pub struct Target {
    pub pose: Pose,
    /// Per joint: angular velocity relative to the parent in the parent's frame (root: world), rad/s.
    pub angular_velocity: [Vector3<f64>; NUM_JOINTS],
    /// Root joint linear velocity, world, m/s.
    pub root_velocity: Vector3<f64>,
}

impl Target {
    /// The target with each rigid joint's rotation folded into its children's, parents first:
    /// `R_c ← R_r·R_c` and `ω_c ← ω_r + R_r·ω_c` (relative angular velocities compose so, in the
    /// rigid joint's parent frame), then `R_r = I`, `ω_r = 0`. Every simulated joint keeps its
    /// world orientation and angular velocity ([`crate::model::RIGID_JOINTS`]).
    pub fn folded(mut self) -> Target {
        for rigid in crate::model::RIGID_JOINTS {
            let j = rigid.index();
            let (r, w) = (self.pose.parent_from_joint[j], self.angular_velocity[j]);
            for child in rigid.children() {
                let c = child.index();
                self.angular_velocity[c] = w + r * self.angular_velocity[c];
                self.pose.parent_from_joint[c] = r * self.pose.parent_from_joint[c];
            }
            self.pose.parent_from_joint[j] = Rotation3::identity();
            self.angular_velocity[j] = Vector3::zeros();
        }
        self
    }

    /// The target at `pose`, with velocities by finite difference from the previous frame's pose
    /// `dt` seconds earlier (zero without one).
    pub fn from_poses(previous: Option<&Pose>, pose: &Pose, dt: f64) -> Target {
        let mut angular_velocity = [Vector3::zeros(); NUM_JOINTS];
        let mut root_velocity = Vector3::zeros();
        if let Some(prev) = previous.filter(|_| dt > 0.0) {
            for (w, (now, before)) in angular_velocity.iter_mut().zip(
                pose.parent_from_joint
                    .iter()
                    .zip(prev.parent_from_joint.iter()),
            ) {
                // R(t) = exp([ω]dt) R(t-dt): ω in the parent's frame.
                *w = axis_angle_from_rotation(&(now * before.inverse())) / dt;
            }
            root_velocity = (pose.root_in_world_m - prev.root_in_world_m) / dt;
        }
        Target {
            pose: pose.clone(),
            angular_velocity,
            root_velocity,
        }
    }
}

/// What one frame of simulation measured.
#[derive(Debug, Clone, Default)]
pub struct FrameForces {
    /// Contact force of the floor on each joint (a foot box counts for its foot joint, a hand
    /// for its hand joint, other links for their own joint), world, N, averaged over the substeps.
    pub contact_force_n: [Vector3<f64>; NUM_JOINTS],
    /// Deepest penetration into the floor over the substeps, m.
    pub penetration_m: f64,
    /// Per foot [left, right]: horizontal speed of the foot at its contact points (weighted by
    /// their normal forces), averaged over the substeps it touched the floor; `None` without contact.
    pub foot_slip_mps: [Option<f64>; 2],
    /// Residual root force and torque applied (residual mode), world, N and N·m, averaged.
    pub residual_force_n: Vector3<f64>,
    pub residual_torque_nm: Vector3<f64>,
}

/// The simulated body's state.
#[derive(Debug, Clone)]
pub struct SimState {
    /// Local rotations (rigid leaves: identity) and root position, like an estimate's pose.
    pub pose: Pose,
    /// World position of every joint, m.
    pub joint_position_m: [Vector3<f64>; NUM_JOINTS],
    /// World linear velocity of every joint centre, m/s.
    pub joint_velocity_mps: [Vector3<f64>; NUM_JOINTS],
    /// World orientation of every joint's frame.
    pub world_from_joint: [Rotation3<f64>; NUM_JOINTS],
}

/// The rapier world holding one simulated body.
pub struct Simulation {
    model: SimModel,
    config: SimConfig,
    world: PhysicsWorld,
    /// Per model link: its rigid body.
    link_body: Vec<RigidBodyHandle>,
    /// Per model link: the link its joint hangs from (the root: itself).
    parent_link: Vec<usize>,
    /// What holds the links together.
    articulation: Articulation,
    /// Which joint each body collider's contact force is reported on.
    collider_joint: Vec<(ColliderHandle, JointId)>,
    ground: ColliderHandle,
    /// Vertical floor force on each foot during the last substep, N (for the stance feedback).
    foot_load_n: [f64; 2],
    /// The estimate's centre of mass at the previous frame, m (for its velocity).
    previous_target_com_m: Option<Vector3<f64>>,
    /// This frame's foot-placement reference (see `placement_reference`).
    placement: Option<Placement>,
    target_fk: FkData,
}

/// The rapier objects that join the links (see [`Joints`]).
enum Articulation {
    /// The multibody, and each model link's id in it.
    Multibody {
        index: MultibodyIndex,
        link_id: Vec<usize>,
    },
    /// Per model link: the impulse joint to its parent link (the root: none).
    Impulse {
        joint: Vec<Option<ImpulseJointHandle>>,
    },
}

/// What the foot placement compares the simulated body with, from the estimate of this frame.
#[derive(Debug, Clone)]
struct Placement {
    /// The estimate's centre of mass and its velocity, world, m and m/s.
    com_m: Vector3<f64>,
    com_velocity_mps: Vector3<f64>,
    /// The estimate's feet (balls), world, m, [left, right].
    feet_m: [Vector3<f64>; 2],
    /// The estimate's world rotation of each thigh (the hip joint frames), [left, right].
    thigh: [Rotation3<f64>; 2],
}

fn vec3(v: &Vector3<f64>) -> Vec3 {
    Vec3::new(v.x as f32, v.y as f32, v.z as f32)
}

fn vector(v: Vec3) -> Vector3<f64> {
    Vector3::new(v.x as f64, v.y as f64, v.z as f64)
}

fn quat(r: &Rotation3<f64>) -> Quat {
    let q = UnitQuaternion::from_rotation_matrix(r);
    Quat::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32).normalize()
}

fn rotation(q: Quat) -> Rotation3<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(
        q.w as f64, q.x as f64, q.y as f64, q.z as f64,
    ))
    .to_rotation_matrix()
}

const ANGULAR_AXES: [JointAxis; 3] = [JointAxis::AngX, JointAxis::AngY, JointAxis::AngZ];

impl Simulation {
    /// A world with the body in the target's pose and moving with its velocities.
    pub fn new(model: &SimModel, config: &SimConfig, start: &Target) -> Simulation {
        let mut world = PhysicsWorld::new();
        world.gravity = Vec3::new(0.0, -GRAVITY_MPS2 as f32, 0.0);
        world.integration_parameters.dt = (1.0 / 60.0 / config.substeps.max(1) as f64) as f32;
        // More Gauss-Seidel sweeps than rapier's default of one (see `SimConfig::for_joints`).
        world.integration_parameters.num_internal_pgs_iterations = config.solver_sweeps.max(1);
        world.integration_parameters.num_solver_iterations = config.solver_iterations.max(1);

        let ground_body = world.bodies.insert(RigidBodyBuilder::fixed());
        let floor = ColliderBuilder::halfspace(rapier3d::na::Unit::new_unchecked(Vec3::Y))
            .friction(config.friction as f32)
            .collision_groups(InteractionGroups::new(
                Group::GROUP_2,
                Group::GROUP_1,
                InteractionTestMode::And,
            ));
        let ground = world
            .colliders
            .insert_with_parent(floor, ground_body, &mut world.bodies);

        let root_pose = rapier3d::math::Pose::from_parts(
            vec3(&start.pose.root_in_world_m),
            quat(&start.pose.parent_from_joint[0]),
        );
        let mut link_body = Vec::with_capacity(model.links.len());
        let mut parent_link = Vec::with_capacity(model.links.len());
        let mut impulse_joint = Vec::with_capacity(model.links.len());
        let mut collider_joint = Vec::new();
        let link_of = model.link_of_joint();
        for link in &model.links {
            let mass = MassProperties::new(
                vec3(&link.com_m),
                link.mass_kg as f32,
                vec3(&link.inertia_kgm2),
            );
            let body = RigidBodyBuilder::dynamic()
                .pose(root_pose)
                .additional_mass_properties(mass)
                .can_sleep(false);
            let handle = world.bodies.insert(body);
            for (carried, shape) in &link.shapes {
                let collider = collider(shape)
                    .density(0.0)
                    .friction(config.friction as f32)
                    .collision_groups(InteractionGroups::new(
                        Group::GROUP_1,
                        Group::GROUP_2,
                        InteractionTestMode::And,
                    ));
                let c = world
                    .colliders
                    .insert_with_parent(collider, handle, &mut world.bodies);
                collider_joint.push((c, contact_joint(*carried)));
            }
            // rapier adds the additional mass properties at the next step; the centre of mass
            // has to be right before it, for the velocities `set_state` gives and `state` reads.
            world.bodies[handle].recompute_mass_properties_from_colliders(&world.colliders);
            if let Some(parent) = link.joint.parent() {
                // The parent link may carry rigid joints between it and this one (a collar
                // before a shoulder): the anchor is this joint's rest position in that link.
                let carrier = crate::model::carrier(parent);
                let parent_index = link_of[carrier.index()].expect("carriers are links");
                let parent_body = link_body[parent_index];
                parent_link.push(parent_index);
                let offset = crate::model::offset_in_carrier(&model.body, link.joint);
                let mut joint = SphericalJointBuilder::new()
                    .local_anchor1(vec3(&offset))
                    .local_anchor2(Vec3::ZERO)
                    .build();
                let max_torque = (config.max_torque_nm_per_kg * model.body.mass_kg) as f32;
                for axis in ANGULAR_AXES {
                    joint
                        .set_motor_model(axis, MotorModel::ForceBased)
                        .set_motor_velocity(axis, 0.0, 0.0)
                        .set_motor_max_force(axis, max_torque);
                }
                match config.joints {
                    Joints::Multibody => {
                        world
                            .multibody_joints
                            .insert(parent_body, handle, joint, true)
                            .expect("a tree of new bodies is a valid multibody");
                        impulse_joint.push(None);
                    }
                    Joints::Impulse => impulse_joint.push(Some(world.impulse_joints.insert(
                        parent_body,
                        handle,
                        joint,
                        true,
                    ))),
                }
            } else {
                parent_link.push(0);
                impulse_joint.push(None);
            }
            link_body.push(handle);
        }
        let articulation = match config.joints {
            Joints::Multibody => {
                let root_link = *world
                    .multibody_joints
                    .rigid_body_link(link_body[0])
                    .expect("the root is a multibody link");
                let link_id = link_body
                    .iter()
                    .map(|h| {
                        world
                            .multibody_joints
                            .rigid_body_link(*h)
                            .expect("every body is a link")
                            .id
                    })
                    .collect();
                Articulation::Multibody {
                    index: root_link.multibody,
                    link_id,
                }
            }
            Joints::Impulse => Articulation::Impulse {
                joint: impulse_joint,
            },
        };
        let mut sim = Simulation {
            model: model.clone(),
            config: config.clone(),
            world,
            link_body,
            parent_link,
            articulation,
            collider_joint,
            ground,
            foot_load_n: [0.0; 2],
            previous_target_com_m: None,
            placement: None,
            target_fk: FkData::new(),
        };
        sim.set_state(start);
        sim
    }

    /// Puts the body in the target's pose (the root where the target has it, every joint rotated
    /// from identity to its target) with the target's velocities.
    fn set_state(&mut self, target: &Target) {
        match &self.articulation {
            Articulation::Multibody { index, link_id } => {
                set_multibody_state(&mut self.world, *index, link_id, &self.model.links, target);
                // The multibody moves its links' bodies at its first step; until then they would
                // read as standing still (the centre of mass's velocity, the joints').
                self.set_body_states(target, false);
            }
            Articulation::Impulse { .. } => self.set_body_states(target, true),
        }
    }

    /// Every link's rigid body moving (and with `place`, placed) as the multibody's forward
    /// kinematics would have it (parents first: a link's origin is its joint, `offset_in_carrier`
    /// from its parent's, turned by the target's local rotation).
    fn set_body_states(&mut self, target: &Target, place: bool) {
        let mut frames: Vec<(Vector3<f64>, Rotation3<f64>)> =
            Vec::with_capacity(self.link_body.len());
        // Per link: the linear velocity of its origin and its angular velocity, world.
        let mut velocities: Vec<(Vector3<f64>, Vector3<f64>)> =
            Vec::with_capacity(self.link_body.len());
        for (l, link) in self.model.links.iter().enumerate() {
            let j = link.joint.index();
            let (origin, orientation, linear, angular) = if l == 0 {
                (
                    target.pose.root_in_world_m,
                    target.pose.parent_from_joint[0],
                    target.root_velocity,
                    target.angular_velocity[0],
                )
            } else {
                let (parent_origin, parent_orientation) = frames[self.parent_link[l]];
                let (parent_linear, parent_angular) = velocities[self.parent_link[l]];
                let offset = parent_orientation
                    * crate::model::offset_in_carrier(&self.model.body, link.joint);
                (
                    parent_origin + offset,
                    parent_orientation * target.pose.parent_from_joint[j],
                    parent_linear + parent_angular.cross(&offset),
                    parent_angular + parent_orientation * target.angular_velocity[j],
                )
            };
            frames.push((origin, orientation));
            velocities.push((linear, angular));
            let rb = &mut self.world.bodies[self.link_body[l]];
            if place {
                rb.set_position(
                    rapier3d::math::Pose::from_parts(vec3(&origin), quat(&orientation)),
                    true,
                );
            }
            // rapier's linear velocity is the centre of mass's.
            let com = orientation * link.com_m;
            rb.set_linvel(vec3(&(linear + angular.cross(&com))), true);
            rb.set_angvel(vec3(&angular), true);
        }
    }

    /// World pose of a link's frame (its joint centre and orientation).
    fn link_frame(&self, l: usize) -> (Vector3<f64>, Rotation3<f64>) {
        match &self.articulation {
            Articulation::Multibody { index, link_id } => {
                let to_world = self
                    .world
                    .multibody_joints
                    .get_multibody(*index)
                    .expect("the body's multibody exists")
                    .link(link_id[l])
                    .expect("link ids are valid")
                    .local_to_world();
                (vector(to_world.translation), rotation(to_world.rotation))
            }
            Articulation::Impulse { .. } => {
                let rb = &self.world.bodies[self.link_body[l]];
                (vector(rb.translation()), rotation(*rb.rotation()))
            }
        }
    }

    /// The largest distance between a joint's anchor on its parent link and its own link's
    /// origin, m: how far the impulse joints have come apart (the multibody's cannot; 0 there up to
    /// float rounding).
    pub fn largest_joint_gap_m(&self) -> f64 {
        (1..self.link_body.len())
            .map(|l| {
                let (parent_origin, parent_orientation) = self.link_frame(self.parent_link[l]);
                let (origin, _) = self.link_frame(l);
                let offset =
                    crate::model::offset_in_carrier(&self.model.body, self.model.links[l].joint);
                (parent_origin + parent_orientation * offset - origin).norm()
            })
            .fold(0.0, f64::max)
    }

    /// A link's rotation relative to its parent link: its joint's local rotation.
    fn joint_rotation(&self, l: usize) -> Rotation3<f64> {
        match &self.articulation {
            Articulation::Multibody { index, link_id } => rotation(
                self.world
                    .multibody_joints
                    .get_multibody(*index)
                    .expect("the body's multibody exists")
                    .link(link_id[l])
                    .expect("link ids are valid")
                    .joint
                    .joint_rot(),
            ),
            Articulation::Impulse { .. } => {
                let (_, parent) = self.link_frame(self.parent_link[l]);
                let (_, child) = self.link_frame(l);
                parent.inverse() * child
            }
        }
    }

    /// Sets a link's joint motors to the relative angular velocity `velocity` (parent's frame)
    /// with damping `damping`.
    fn set_joint_motors(&mut self, l: usize, velocity: &Vector3<f64>, damping: f64) {
        let data = match &self.articulation {
            Articulation::Multibody { index, link_id } => {
                &mut self
                    .world
                    .multibody_joints
                    .get_multibody_mut(*index)
                    .expect("the body's multibody exists")
                    .link_mut(link_id[l])
                    .expect("link ids are valid")
                    .joint
                    .data
            }
            Articulation::Impulse { joint } => {
                &mut self
                    .world
                    .impulse_joints
                    .get_mut(
                        joint[l].expect("every link but the root has a joint"),
                        false,
                    )
                    .expect("the body's joints exist")
                    .data
            }
        };
        for (k, axis) in ANGULAR_AXES.into_iter().enumerate() {
            data.set_motor_velocity(axis, velocity[k] as f32, damping as f32);
        }
    }

    /// Advances one input frame of `dt` seconds (in `substeps` physics steps) towards `target`.
    pub fn step(&mut self, target: &Target, dt: f64) -> FrameForces {
        let substeps = self.config.substeps.max(1);
        let h = dt / substeps as f64;
        self.placement = Some(self.placement_reference(target, dt));
        self.world.integration_parameters.dt = h as f32;
        let mut out = FrameForces::default();
        let mut slip = [(0.0, 0u32); 2];
        for _ in 0..substeps {
            self.drive_joints(target);
            let (force, torque) = self.drive_root(target);
            self.world.step();
            out.residual_force_n += force / substeps as f64;
            out.residual_torque_nm += torque / substeps as f64;
            out.penetration_m = out.penetration_m.max(self.add_contact_forces(
                &mut out.contact_force_n,
                h,
                1.0 / substeps as f64,
            ));
            for (foot, (sum, n)) in self.foot_slip().into_iter().zip(slip.iter_mut()) {
                if let Some(speed) = foot {
                    *sum += speed;
                    *n += 1;
                }
            }
        }
        out.foot_slip_mps = slip.map(|(sum, n)| (n > 0).then(|| sum / f64::from(n)));
        out
    }

    /// Per foot: the horizontal speed at its floor contact points, weighted by their normal
    /// impulses (the velocity of the foot where it touches, not of the ankle, which rolls over
    /// the toes in every step); `None` for a foot off the floor.
    fn foot_slip(&self) -> [Option<f64>; 2] {
        let mut out = [None; 2];
        for pair in self.world.narrow_phase.contact_pairs_with(self.ground) {
            let (other, body_is_first) = if pair.collider1 == self.ground {
                (pair.collider2, false)
            } else {
                (pair.collider1, true)
            };
            let side = match self.collider_joint.iter().find(|(c, _)| *c == other) {
                Some((_, JointId::LEFT_FOOT)) => 0,
                Some((_, JointId::RIGHT_FOOT)) => 1,
                _ => continue,
            };
            let collider = &self.world.colliders[other];
            let Some(rb) = collider.parent().map(|h| &self.world.bodies[h]) else {
                continue;
            };
            let (mut weighted, mut total) = (Vector3::zeros(), 0.0);
            for manifold in pair.manifolds() {
                for point in &manifold.points {
                    let local = if body_is_first {
                        point.local_p1
                    } else {
                        point.local_p2
                    };
                    let at = collider.position().transform_point(local);
                    let w = f64::from(point.data.impulse.abs());
                    weighted += w * vector(rb.velocity_at_point(at));
                    total += w;
                }
            }
            if total > 0.0 {
                out[side] = Some((weighted / total).xz().norm());
            }
        }
        out
    }

    /// Joint motors: a velocity target `ω_ref + (kp/kd)·e` with damping `kd·I`, i.e. the PD torque
    /// `kd·I·(ω_ref − ω) + kp·I·e`, where `e` is the rotation from the current to the target local
    /// rotation (parent frame). rapier solves the damping implicitly, so stiff gains stay stable.
    ///
    /// Balance: the root is unactuated, so the pelvis's orientation is steered through the stance
    /// hips (SIMBICON, Yin et al. 2007, §4: the stance hip turns the pelvis, the floor under the
    /// stance foot takes the reaction). The pelvis should turn at `ω_c = (kp_b/kd_b)·e_root +
    /// (ω_ref,root − ω_root)` (world); with the thigh held by the stance leg that is a change of
    /// `−R_pelvisᵀ·ω_c` in the hip's relative velocity, added to the loaded hips' targets in
    /// proportion to their feet's load. Nothing acts on the root itself.
    fn drive_joints(&mut self, target: &Target) {
        let (kp, kd) = (self.config.kp, self.config.kd);
        let stance = self.stance_correction(target);
        let swing = self.swing_hip_target();
        let clearance = self.swing_clearance();
        let gains: Vec<(usize, JointId, f64)> = self
            .model
            .links
            .iter()
            .enumerate()
            .skip(1)
            .map(|(l, link)| (l, link.joint, kd * link.driven_inertia_kgm2))
            .collect();
        for (l, joint, damping) in gains {
            let j = joint.index();
            let current = self.joint_rotation(l);
            let mut wanted = match (joint, swing) {
                (JointId::LEFT_HIP, Some((0, hip))) | (JointId::RIGHT_HIP, Some((1, hip))) => hip,
                _ => target.pose.parent_from_joint[j],
            };
            let knee_lift = match joint {
                JointId::LEFT_KNEE => clearance[0],
                JointId::RIGHT_KNEE => clearance[1],
                _ => 0.0,
            };
            if knee_lift > 0.0 {
                let bend = axis_angle_from_rotation(&wanted);
                if bend.norm() > MIN_SWING_KNEE_BEND_RAD {
                    // Further along the knee's own bend: the knee flexes only one way.
                    wanted = Rotation3::new(bend.normalize() * (bend.norm() + knee_lift));
                }
            }
            let error = axis_angle_from_rotation(&(wanted * current.inverse()));
            let mut velocity = target.angular_velocity[j] + error * (kp / kd.max(1e-9));
            match joint {
                JointId::LEFT_HIP => velocity += stance[0],
                JointId::RIGHT_HIP => velocity += stance[1],
                _ => {}
            }
            self.set_joint_motors(l, &velocity, damping);
        }
    }

    /// Swing clearance: per side, extra knee flexion (rad) for a foot the estimate swings (its
    /// ball `SWING_CLEARANCE_M` above the other one's) while the simulated foot hangs lower than
    /// the estimate's. The data's swing feet clear the floor by 3-9 cm; a simulated body a few
    /// degrees off drags its toes (a scuff), which trips it. Torques mode only: in residual mode
    /// the root is held and a bent knee would only add tracking error.
    fn swing_clearance(&self) -> [f64; 2] {
        let Some(placement) = self
            .placement
            .as_ref()
            .filter(|_| self.config.mode == Mode::Torques)
        else {
            return [0.0; 2];
        };
        [0, 1].map(|side| {
            let other = 1 - side;
            if placement.feet_m[side].y - placement.feet_m[other].y < SWING_CLEARANCE_M {
                return 0.0;
            }
            let deficit = placement.feet_m[side].y - self.foot_position(FEET[side]).y;
            let shank = self
                .model
                .body
                .skeleton
                .offset_in_parent_m(FEET[side].parent().expect("feet have ankles"))
                .norm();
            (self.config.clearance_gain * deficit.max(0.0) / shank).min(MAX_CLEARANCE_BEND_RAD)
        })
    }

    /// The estimate's centre of mass (and its velocity from the previous frame's), feet and thighs.
    fn placement_reference(&mut self, target: &Target, dt: f64) -> Placement {
        forward_kinematics(&self.model.body.skeleton, &target.pose, &mut self.target_fk);
        let fk = &self.target_fk;
        let com_m = self
            .model
            .links
            .iter()
            .map(|l| {
                let j = l.joint.index();
                l.mass_kg * (fk.joint_in_world_m[j] + fk.world_from_joint[j] * l.com_m)
            })
            .sum::<Vector3<f64>>()
            / self.model.total_mass_kg;
        let com_velocity_mps = match self.previous_target_com_m {
            Some(previous) if dt > 0.0 => (com_m - previous) / dt,
            _ => self.sim_com().1,
        };
        self.previous_target_com_m = Some(com_m);
        Placement {
            com_m,
            com_velocity_mps,
            feet_m: FEET.map(|f| fk.joint_in_world_m[f.index()]),
            thigh: [JointId::LEFT_HIP, JointId::RIGHT_HIP].map(|h| fk.world_from_joint[h.index()]),
        }
    }

    /// The simulated centre of mass and its velocity, world, m and m/s.
    fn sim_com(&self) -> (Vector3<f64>, Vector3<f64>) {
        let (mut com, mut velocity) = (Vector3::zeros(), Vector3::zeros());
        for handle in &self.link_body {
            let rb = &self.world.bodies[*handle];
            let m = f64::from(rb.mass());
            com += m * vector(rb.center_of_mass());
            velocity += m * vector(rb.linvel());
        }
        (
            com / self.model.total_mass_kg,
            velocity / self.model.total_mass_kg,
        )
    }

    /// Foot placement (SIMBICON, Yin et al. 2007, §4.2: `θ_d = θ_d0 + c_d·d + c_v·v`): while one
    /// foot carries the body and the estimate has the other one in the air, the swing thigh
    /// follows the estimate's thigh in the world, not relative to the simulated pelvis, turned so
    /// that its foot lands `placement_kp·Δd + placement_kv·Δv` further, where Δd and Δv are how
    /// far the simulated centre of mass is ahead of the estimate's, relative to each one's stance
    /// foot, and how much faster it moves (horizontal). Stepping towards where the body is falling
    /// catches it.
    /// Returns the swing side (0 left, 1 right) and its hip's local target rotation.
    fn swing_hip_target(&self) -> Option<(usize, Rotation3<f64>)> {
        let placement = self.placement.as_ref()?;
        let weight = self.model.total_mass_kg * GRAVITY_MPS2;
        let load: f64 = self.foot_load_n.iter().sum();
        if load <= STANCE_LOAD_FRACTION * weight {
            return None;
        }
        let stance = if self.foot_load_n[0] >= SINGLE_STANCE_SHARE * load {
            0
        } else if self.foot_load_n[1] >= SINGLE_STANCE_SHARE * load {
            1
        } else {
            return None;
        };
        let swing = 1 - stance;
        // Only while the estimate swings that foot too: with both its feet down, an unloaded
        // simulated foot should come down, not be held off the floor by the shift.
        if placement.feet_m[swing].y - placement.feet_m[stance].y < SWING_CLEARANCE_M {
            return None;
        }
        let (com, com_velocity) = self.sim_com();
        let sim_foot = self.foot_position(FEET[stance]);
        let horizontal = |v: Vector3<f64>| Vector3::new(v.x, 0.0, v.z);
        let ahead = horizontal((com - sim_foot) - (placement.com_m - placement.feet_m[stance]));
        let faster = horizontal(com_velocity - placement.com_velocity_mps);
        let mut shift = self.config.placement_kp * ahead + self.config.placement_kv * faster;
        if shift.norm() > MAX_PLACEMENT_SHIFT_M {
            shift *= MAX_PLACEMENT_SHIFT_M / shift.norm();
        }
        // Turning the thigh by θ about `shift × up` moves a foot `leg` below the hip by θ·leg
        // along `shift`.
        let leg = self.model.leg_length_m;
        let turn = Rotation3::new(shift.cross(&Vector3::y()) / leg);
        let pelvis = rotation(*self.world.bodies[self.link_body[0]].rotation());
        Some((swing, pelvis.inverse() * turn * placement.thigh[swing]))
    }

    /// World position of a rigid joint (a foot's ball) of the simulated body, m.
    fn foot_position(&self, rigid: JointId) -> Vector3<f64> {
        let (origin, orientation) = self.link_frame(self.model.carrying_link(rigid));
        origin + orientation * crate::model::offset_in_carrier(&self.model.body, rigid)
    }

    /// The change of each hip's velocity target that steers the pelvis (see `drive_joints`); zero
    /// while the feet carry less than [`STANCE_LOAD_FRACTION`] of the weight.
    fn stance_correction(&self, target: &Target) -> [Vector3<f64>; 2] {
        let weight = self.model.total_mass_kg * GRAVITY_MPS2;
        let load: f64 = self.foot_load_n.iter().sum();
        if load <= STANCE_LOAD_FRACTION * weight || self.config.balance_kd <= 0.0 {
            return [Vector3::zeros(); 2];
        }
        let rb = &self.world.bodies[self.link_body[0]];
        let pelvis = rotation(*rb.rotation());
        let error =
            axis_angle_from_rotation(&(target.pose.parent_from_joint[0] * pelvis.inverse()));
        let turn = (self.config.balance_kp / self.config.balance_kd) * error
            + (target.angular_velocity[0] - vector(rb.angvel()));
        let in_pelvis = -(pelvis.inverse() * turn);
        [0, 1].map(|side| in_pelvis * (self.foot_load_n[side] / load))
    }

    /// Residual mode: a PD force and torque that keep the root near the estimate, applied as an
    /// acceleration field over the whole body (each link gets its mass times the same linear
    /// acceleration, and the same angular acceleration about the centre of mass), so the help
    /// moves the body as one piece, like a hand holding it by the pelvis through a rigid frame.
    /// Applied to the pelvis link alone, the damping term diverged at 240 Hz: in reduced
    /// coordinates the pelvis answers a root force with its own small articulated inertia. The
    /// total force and torque are `m·(kp·Δp + kd·Δv)` and `I·(kp·Δθ + kd·Δω)` with the root's
    /// errors, `I` the whole body's inertia about the pelvis. Returns them (world); zero in torques
    /// mode.
    fn drive_root(&mut self, target: &Target) -> (Vector3<f64>, Vector3<f64>) {
        for handle in &self.link_body {
            self.world.bodies[*handle].reset_forces(false);
        }
        if self.config.mode == Mode::Torques {
            return (Vector3::zeros(), Vector3::zeros());
        }
        let rb = &self.world.bodies[self.link_body[0]];
        let orientation = rotation(*rb.rotation());
        let origin = vector(rb.translation());
        let orientation_error =
            axis_angle_from_rotation(&(target.pose.parent_from_joint[0] * orientation.inverse()));
        let velocity = vector(rb.velocity_at_point(rb.translation()));
        let (kp, kd) = (self.config.residual_kp, self.config.residual_kd);
        let linear =
            kp * (target.pose.root_in_world_m - origin) + kd * (target.root_velocity - velocity);
        let angular =
            kp * orientation_error + kd * (target.angular_velocity[0] - vector(rb.angvel()));
        let (com, _) = self.sim_com();
        let mut total_torque = Vector3::zeros();
        for handle in &self.link_body {
            let rb = &mut self.world.bodies[*handle];
            let m = f64::from(rb.mass());
            let at = vector(rb.center_of_mass());
            let force = m * (linear + angular.cross(&(at - com)));
            // The link's inertia is diagonal in its frame (model.rs).
            let inertia = vector(rb.mass_properties().local_mprops.principal_inertia());
            let frame = rotation(*rb.rotation());
            let torque = frame * inertia.component_mul(&(frame.inverse() * angular));
            rb.add_force_at_point(vec3(&force), rb.center_of_mass(), false);
            rb.add_torque(vec3(&torque), false);
            total_torque += torque + (at - com).cross(&force);
        }
        (self.model.total_mass_kg * linear, total_torque)
    }

    /// Adds `weight` × the floor's force on each joint during the last step of `h` seconds to
    /// `forces`; updates the feet's loads; returns the deepest penetration (m).
    fn add_contact_forces(
        &mut self,
        forces: &mut [Vector3<f64>; NUM_JOINTS],
        h: f64,
        weight: f64,
    ) -> f64 {
        let mut deepest = 0.0f64;
        let mut feet = [0.0; 2];
        for pair in self.world.narrow_phase.contact_pairs_with(self.ground) {
            let (other, sign) = if pair.collider1 == self.ground {
                (pair.collider2, 1.0)
            } else {
                (pair.collider1, -1.0)
            };
            let Some(joint) = self
                .collider_joint
                .iter()
                .find(|(c, _)| *c == other)
                .map(|(_, j)| *j)
            else {
                continue;
            };
            let mut impulse = Vector3::zeros();
            for manifold in pair.manifolds() {
                let normal = vector(manifold.data.normal);
                for point in &manifold.points {
                    impulse += normal * point.data.impulse as f64
                        + vector(point.data.warmstart_tangent_world);
                    deepest = deepest.max(-point.dist as f64);
                }
            }
            let force = sign * impulse / h;
            forces[joint.index()] += weight * force;
            match joint {
                JointId::LEFT_FOOT => feet[0] += force.y.max(0.0),
                JointId::RIGHT_FOOT => feet[1] += force.y.max(0.0),
                _ => {}
            }
        }
        self.foot_load_n = feet;
        deepest
    }

    /// The body's current state.
    pub fn state(&self) -> SimState {
        let mut pose = Pose::t_pose(Vector3::zeros());
        let mut world_from_joint = [Rotation3::identity(); NUM_JOINTS];
        let mut joint_position_m = [Vector3::zeros(); NUM_JOINTS];
        let mut joint_velocity_mps = [Vector3::zeros(); NUM_JOINTS];
        for (l, link) in self.model.links.iter().enumerate() {
            let (origin, orientation) = self.link_frame(l);
            let j = link.joint.index();
            world_from_joint[j] = orientation;
            joint_position_m[j] = origin;
            let rb = &self.world.bodies[self.link_body[l]];
            joint_velocity_mps[j] = vector(rb.velocity_at_point(vec3(&origin)));
            pose.parent_from_joint[j] = if l == 0 {
                world_from_joint[j]
            } else {
                self.joint_rotation(l)
            };
        }
        pose.root_in_world_m = joint_position_m[0];
        // The rigid joints ride on their carrying link, in their rest pose (parents first).
        for rigid in crate::model::RIGID_JOINTS {
            let parent = rigid.parent().expect("rigid joints have parents").index();
            let j = rigid.index();
            world_from_joint[j] = world_from_joint[parent];
            joint_position_m[j] = joint_position_m[parent]
                + world_from_joint[parent] * self.model.body.skeleton.offset_in_parent_m(rigid);
            let carrier = &self.world.bodies[self.link_body[self.model.carrying_link(rigid)]];
            joint_velocity_mps[j] = vector(carrier.velocity_at_point(vec3(&joint_position_m[j])));
        }
        SimState {
            pose,
            joint_position_m,
            joint_velocity_mps,
            world_from_joint,
        }
    }
}

/// [`Joints::Multibody`]: the multibody's coordinates and velocities set to the target's, its links'
/// bodies moved there.
fn set_multibody_state(
    world: &mut PhysicsWorld,
    index: MultibodyIndex,
    link_id: &[usize],
    links: &[crate::model::Link],
    target: &Target,
) {
    let mb = world
        .multibody_joints
        .get_multibody_mut(index)
        .expect("the body's multibody exists");
    let ndofs = mb.ndofs();
    let mut displacement = vec![0.0f32; ndofs];
    let mut velocity = vec![0.0f32; ndofs];
    // The free root: 3 linear then 3 angular world velocities.
    velocity[..3].copy_from_slice(&vec3(&target.root_velocity).to_array());
    velocity[3..6].copy_from_slice(&vec3(&target.angular_velocity[0]).to_array());
    for (link, id) in links.iter().zip(link_id).skip(1) {
        let first = mb.link(*id).expect("link ids are valid").assembly_id();
        let j = link.joint.index();
        displacement[first..first + 3].copy_from_slice(
            &vec3(&axis_angle_from_rotation(&target.pose.parent_from_joint[j])).to_array(),
        );
        velocity[first..first + 3].copy_from_slice(&vec3(&target.angular_velocity[j]).to_array());
    }
    mb.apply_displacements(&displacement);
    mb.generalized_velocity_mut().copy_from_slice(&velocity);
    mb.forward_kinematics(&world.bodies, true);
    mb.update_rigid_bodies(&mut world.bodies, true);
}

/// The joint a link's floor contact is reported on: feet and hands on the contact joints the
/// optimizer uses (`imuflow_body::skeleton::CONTACT_JOINTS`), other links on their own joint.
fn contact_joint(link: JointId) -> JointId {
    match link {
        JointId::LEFT_ANKLE => JointId::LEFT_FOOT,
        JointId::RIGHT_ANKLE => JointId::RIGHT_FOOT,
        JointId::LEFT_WRIST => JointId::LEFT_HAND,
        JointId::RIGHT_WRIST => JointId::RIGHT_HAND,
        other => other,
    }
}

fn collider(shape: &Shape) -> ColliderBuilder {
    match shape {
        Shape::Capsule { a, b, radius } => {
            ColliderBuilder::capsule_from_endpoints(vec3(a), vec3(b), *radius as f32)
        }
        Shape::Ball { centre, radius } => {
            ColliderBuilder::ball(*radius as f32).translation(vec3(centre))
        }
        Shape::Cuboid {
            centre,
            half_extents,
            rotation,
        } => ColliderBuilder::cuboid(
            half_extents.x as f32,
            half_extents.y as f32,
            half_extents.z as f32,
        )
        .position(rapier3d::math::Pose::from_parts(
            vec3(centre),
            quat(rotation),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default subject's body model.
    fn body() -> imuflow_body::body_model::BodyModel {
        imuflow_body::body_model::BodyModel::new(
            &imuflow_body::body_model::BodyParams::builtin().unwrap(),
            1.75,
            70.0,
        )
        .unwrap()
    }

    /// How far apart two rotations are, as the norm of their matrices' difference (`angle_to` is
    /// NaN a rounding away from identity).
    fn apart(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
        (a.matrix() - b.matrix()).norm()
    }

    /// A pose with every joint bent: rotations about varied axes, growing with `t`.
    fn bent(t: f64) -> Pose {
        let mut pose = Pose::t_pose(Vector3::new(0.1 * t, 0.9, 0.3 * t));
        for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
            let axis = Vector3::new((j as f64).sin(), 1.0, (2.0 * j as f64).cos());
            *r = Rotation3::new(axis.normalize() * (0.2 + 0.4 * t) * (1.0 + (j % 3) as f64) / 3.0);
        }
        pose
    }

    #[test]
    fn folding_the_rigid_joints_keeps_every_simulated_joint_turned_and_turning_as_before() {
        let body = body();
        let dt = 1e-4;
        let (before, now) = (bent(0.5), bent(0.5 + dt));
        let folded = Target::from_poses(Some(&before), &now, dt).folded();
        let (mut fk, mut fk_folded) = (FkData::new(), FkData::new());
        forward_kinematics(&body.skeleton, &now, &mut fk);
        forward_kinematics(&body.skeleton, &folded.pose, &mut fk_folded);
        // A second way to the folded velocities: finite differences of the folded poses.
        let fold_pose = |p: &Pose| Target::from_poses(None, p, dt).folded().pose;
        let differenced = Target::from_poses(Some(&fold_pose(&before)), &fold_pose(&now), dt);
        for joint in JointId::all() {
            let j = joint.index();
            if crate::model::is_simulated(joint) {
                let turned = (fk.world_from_joint[j].matrix()
                    - fk_folded.world_from_joint[j].matrix())
                .norm();
                assert!(turned < 1e-12, "{joint:?} turned by {turned}");
                let w = (folded.angular_velocity[j] - differenced.angular_velocity[j]).norm();
                assert!(w < 1e-3, "{joint:?}: {w} rad/s apart");
            } else {
                assert_eq!(folded.pose.parent_from_joint[j], Rotation3::identity());
            }
        }
    }

    #[test]
    fn both_joinings_start_in_the_targets_pose_moving_with_its_velocities() {
        // Expected independently of rapier: the skeleton's forward kinematics of the (folded)
        // target, and the joints' velocities as finite differences of it over the step the
        // target's velocities came from.
        let body = body();
        let model = SimModel::new(&body);
        let h = 1e-4;
        let fold = |p: &Pose| Target::from_poses(None, p, h).folded().pose;
        let (before, now) = (bent(0.6 - h), bent(0.6));
        let target = Target::from_poses(Some(&before), &now, h).folded();
        let (mut fk_before, mut fk_now) = (FkData::new(), FkData::new());
        forward_kinematics(&body.skeleton, &fold(&before), &mut fk_before);
        forward_kinematics(&body.skeleton, &fold(&now), &mut fk_now);
        for joints in [Joints::Impulse, Joints::Multibody] {
            let sim = Simulation::new(&model, &SimConfig::for_joints(joints), &target);
            let state = sim.state();
            for joint in JointId::all() {
                let j = joint.index();
                let misplaced = (state.joint_position_m[j] - fk_now.joint_in_world_m[j]).norm();
                assert!(
                    misplaced < 1e-5,
                    "{joints:?} {joint:?}: {misplaced} m from its place"
                );
                let turned = apart(&state.world_from_joint[j], &fk_now.world_from_joint[j]);
                assert!(turned < 1e-5, "{joints:?} {joint:?}: turned by {turned}");
                let differenced = (fk_now.joint_in_world_m[j] - fk_before.joint_in_world_m[j]) / h;
                let off = (state.joint_velocity_mps[j] - differenced).norm();
                assert!(off < 1e-3, "{joints:?} {joint:?}: velocity {off} m/s off");
            }
            for link in &model.links[1..] {
                let j = link.joint.index();
                let local = apart(
                    &state.pose.parent_from_joint[j],
                    &target.pose.parent_from_joint[j],
                );
                assert!(
                    local < 1e-5,
                    "{joints:?} {:?}: local rotation {local} off",
                    link.joint
                );
            }
            assert!(sim.largest_joint_gap_m() < 1e-5);
        }
    }

    #[test]
    fn impulse_joints_hold_together_and_track_like_the_multibody() {
        // The same slow bend tracked both ways, in the air (residual mode holds the root): the
        // impulse joints may give a little, but not more than a few millimetres, and both bodies
        // end up in the pose they were driven to.
        let body = body();
        let model = SimModel::new(&body);
        let dt = 1.0 / 60.0;
        let lifted = |t: f64| {
            let mut pose = bent(t);
            pose.root_in_world_m.y += 1.0;
            pose
        };
        let mut end = Vec::new();
        for joints in [Joints::Impulse, Joints::Multibody] {
            let config = SimConfig {
                mode: Mode::Residual,
                ..SimConfig::for_joints(joints)
            };
            let mut sim = Simulation::new(
                &model,
                &config,
                &Target::from_poses(None, &lifted(0.0), dt).folded(),
            );
            let mut gap = 0.0f64;
            for frame in 1..=120 {
                let t = 0.5 * (frame as f64 / 60.0).min(1.0);
                let previous = lifted(0.5 * ((frame - 1) as f64 / 60.0).min(1.0));
                sim.step(
                    &Target::from_poses(Some(&previous), &lifted(t), dt).folded(),
                    dt,
                );
                gap = gap.max(sim.largest_joint_gap_m());
            }
            assert!(gap < 0.005, "{joints:?}: joints {gap} m apart");
            let state = sim.state();
            let wanted = Target::from_poses(None, &lifted(0.5), dt).folded().pose;
            for link in &model.links[1..] {
                let j = link.joint.index();
                let off = apart(
                    &state.pose.parent_from_joint[j],
                    &wanted.parent_from_joint[j],
                );
                assert!(
                    off < 0.05,
                    "{joints:?} {:?}: {off} from its target",
                    link.joint
                );
            }
            end.push(state);
        }
        let (impulse, multibody) = (&end[0], &end[1]);
        for joint in JointId::all() {
            let j = joint.index();
            let distance = (impulse.joint_position_m[j] - multibody.joint_position_m[j]).norm();
            assert!(
                distance < 0.02,
                "{joint:?}: the two bodies {distance} m apart"
            );
        }
    }

    #[test]
    fn motor_errors_stay_finite_where_nalgebras_rotation_log_is_nan() {
        // The motors' error is target · current⁻¹ with `current` read back from rapier's f32
        // quaternion. For a target at (or within 1e-6 of) identity that product's trace can exceed
        // 3 by rounding; Rotation3::scaled_axis takes acos((trace-1)/2) and returns NaN, which
        // turned a whole simulated body NaN on pip's output of the bundled sample.
        let mut nalgebra_nan = 0;
        for i in 0..2000 {
            let t = i as f64 * 1e-3;
            let axis = Vector3::new(t.sin(), (1.7 * t).cos(), (0.3 * t).sin() + 0.1);
            let target = Rotation3::new(axis.normalize() * 1e-7 * (i % 13) as f64);
            let error = target * rotation(quat(&target)).inverse();
            if error.scaled_axis().x.is_nan() {
                nalgebra_nan += 1;
            }
            let v = axis_angle_from_rotation(&error);
            assert!(
                v.iter().all(|x| x.is_finite()) && v.norm() < 1e-6,
                "{i}: {v:?}"
            );
        }
        assert!(
            nalgebra_nan > 0,
            "the hazard this guards against did not occur"
        );
    }
}
