//! Rigid-body dynamics of the floating-base character: mass matrix, bias forces, inverse and forward
//! dynamics, point Jacobians, energies, and integration.
//!
//! # Coordinates (singularity-free, GlobalPose; reference §5.4)
//!
//! PIP's RBDL model uses Euler angles (three revolute joints per SMPL joint, reference §5.1), which lose a
//! degree of freedom at gimbal lock. We use GlobalPose's singularity-free form instead: every joint is a
//! spherical joint and the root a free joint.
//!
//! - **Configuration** = [`Pose`]: world position of the root joint and the 24 local rotations
//!   `parent_from_joint` (the root's is `world_from_pelvis`).
//! - **Generalized velocity** `v ∈ R⁷⁵` ([`DofVector`], [`NUM_DOFS`] = 3 + 3·24):
//!   - `v[0..3]`: root linear velocity, world frame M (m/s);
//!   - `v[3+3j .. 6+3j]` for joint j = 0..23: angular velocity of joint j relative to its parent,
//!     expressed in joint j's own frame (rad/s), i.e. `(R_jᵀ·Ṙ_j)^∨` with `R_j = parent_from_joint[j]`.
//!     Joint 0's entry is the root angular velocity in the root (pelvis) frame.
//! - **Generalized force** `τ`, same coordinates, power `τᵀv`: root force in the world (N), then per joint the
//!   torque its parent applies to it, in its own frame (N·m; the root's is a "virtual" torque in the pelvis
//!   frame). This is the wire convention of `MotionFrame.q/qdot/tau` (graph `frames.rs`); [`pose_to_q`] and
//!   [`pose_from_q`] convert to and from its `q` (root position, then per joint the local rotation vector).
//! - **Integration** (GlobalPose's update, [`integrate`]): `δ = v·dt + ½·a·dt²`, `R_j ← R_j·exp(δ_j)`
//!   (right perturbation), root position `+= δ[0..3]`, `v += a·dt`. [`integrate_semi_implicit_euler`] is
//!   the plain variant (PIP §5.2: `v += a·dt`, then `δ = v·dt`). Along `q ⊕ t·v` (see [`displace`]) the
//!   velocity coordinates are constant, which is why `J̇v` below is the point acceleration at `v̇ = 0`.
//!
//! Equations of motion: `M(q)·v̇ + h(q, v) = τ (+ Σ Jᵀ·f_ext)`, with `h` = Coriolis/centrifugal + gravity.
//!
//! # Model
//!
//! [`RigidBodyModel`] is built from a [`BodyModel`]: bone offsets from its skeleton; per joint one rigid
//! link holding all segments attached to that joint (masses, centres of mass in the joint frame, inertias
//! about the centre of mass, merged by the parallel-axis theorem). Joints without a segment (spine2, neck,
//! collars, feet, hands) are massless. Gravity defaults to [`GRAVITY_IN_MODEL_MPS2`].
//!
//! **Armature.** A massless leaf joint (feet, hands) moves nothing, so its three rows of `M` are zero and
//! `M` is singular (massless inner joints such as spine2, neck and collars are fine: they move their
//! children). Like a rotor inertia in robot models (Pinocchio's `model.armature`), we add
//! `armature_kgm2[j]` (default [`DEFAULT_ARMATURE_KGM2`] = 1e-3 kg·m²) to the diagonal of `M` for each of
//! joint j's three rotational DoFs, and the matching `armature·v̇` to inverse dynamics and energy
//! (`½·armature·|ω_j|²`). For a 73 kg subject in the T-pose it is < 1 % of the diagonal of `M` for the
//! trunk, hips, knee flexion, shoulders and collars (0.05–15 kg·m²) but comparable to the small
//! twist inertias: forearm 1.9e-3, hand 0.6e-3 (wrist flexion 3e-3), ankle 2–8e-3 kg·m². Lower it if
//! those matter (1e-4 still keeps `M` well conditioned). It is a public field; set it to zero for the
//! pure rigid-body terms (then use only [`DynamicsData::mass_matrix`] and
//! [`DynamicsData::inverse_dynamics`]: forward dynamics needs `M` positive definite).
//!
//! # Algorithms (Featherstone, *Rigid Body Dynamics Algorithms*, 2008)
//!
//! Link quantities are spatial vectors in link (joint) coordinates, angular part first. `M` by the
//! composite-rigid-body algorithm (RBDA §6.2), `h` and `τ` by recursive Newton–Euler (§5.3), forward
//! dynamics by `M` and `h` and an `LᵀDL` factorisation in 3×3 blocks that exploits the tree (§6.5: no
//! fill-in, so its cost is Σ depth² block products instead of a dense 75³/3). Point Jacobians as in GlobalPose (§5.4): identity for the root
//! translation and `−R_Wi·[p_i]×` for each ancestor i, with `p_i` the point in frame i.
//!
//! # Use (Model/Data split, allocation-free per call)
//!
//! ```
//! use imuflow_body::dynamics::{DofVector, DynamicsData, RigidBodyModel};
//! use imuflow_body::{BodyModel, BodyParams, JointId, Pose};
//! use nalgebra::Vector3;
//!
//! let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
//! let model = RigidBodyModel::new(&body);
//! let mut data = DynamicsData::new(); // allocate once, reuse every frame
//! let pose = Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m, 0.0));
//! let v = DofVector::zeros();
//! data.set_state(&model, &pose, &v); // kinematics and velocities; call first
//! let m = data.mass_matrix(&model)[(0, 0)]; // total mass (no armature on translation)
//! let h = data.bias_forces(&model); // at rest: gravity only, world y force = m·9.81
//! assert!((h[1] - m * 9.81).abs() < 1e-9);
//! let mut jac = imuflow_body::dynamics::PointJacobian::zeros();
//! data.point_jacobian(JointId::LEFT_FOOT, &Vector3::zeros(), &mut jac);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use nalgebra::{Matrix3, Rotation3, SMatrix, SVector, UnitQuaternion, Vector3};

use crate::body_model::{BodyModel, GRAVITY_IN_MODEL_MPS2};
use crate::kinematics::{FkData, Pose};
use crate::rotation::axis_angle_from_rotation;
use crate::skeleton::{JointId, NUM_JOINTS, Skeleton};

/// Number of generalized velocities: root translation (3) + 3 rotational DoFs per joint (24 × 3).
pub const NUM_DOFS: usize = 3 + 3 * NUM_JOINTS;

/// A generalized velocity, acceleration or force (see the module docs for the coordinates).
pub type DofVector = SVector<f64, NUM_DOFS>;

/// The joint-space mass matrix `M(q)` (75 × 75, symmetric).
pub type MassMatrix = SMatrix<f64, NUM_DOFS, NUM_DOFS>;

/// Jacobian of a point's world linear velocity with respect to `v` (3 × 75).
pub type PointJacobian = SMatrix<f64, 3, NUM_DOFS>;

/// Jacobian of a joint's world angular velocity with respect to `v` (3 × 75).
pub type AngularJacobian = SMatrix<f64, 3, NUM_DOFS>;

/// Default armature (rotor inertia, kg·m²) on every rotational DoF; see the module docs.
pub const DEFAULT_ARMATURE_KGM2: f64 = 1e-3;

/// Index of the first of joint `j`'s three rotational DoFs in `v` (the root translation is `0..3`).
pub const fn joint_dof(j: JointId) -> usize {
    3 + 3 * j.index()
}

/// Blocks of three DoFs for the factorisation: the root translation, then one per joint.
const NUM_BLOCKS: usize = 1 + NUM_JOINTS;

/// "No parent" marker in the block-level parent array.
const NO_BLOCK: usize = usize::MAX;

/// Failure of forward dynamics.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum DynamicsError {
    /// The mass matrix is not positive definite: after eliminating the descendants, the 3×3 diagonal
    /// block of DoFs `dof..dof + 3` is not (`determinant` is that block's). With a positive armature this
    /// only happens for non-finite states. Fix: keep `armature_kgm2` > 0 and the state finite.
    #[error("mass matrix not positive definite at DoFs {dof}..{} (block determinant {determinant})", dof + 3)]
    NotPositiveDefinite { dof: usize, determinant: f64 },
}

/// Mass, centre of mass and inertia of the rigid link moving with one joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkInertia {
    /// Mass (kg); 0 for a massless joint.
    pub mass_kg: f64,
    /// Centre of mass in the joint frame (m); zero when massless.
    pub com_in_joint_m: Vector3<f64>,
    /// Inertia about the centre of mass, joint-frame axes (kg·m²).
    pub inertia_about_com_kgm2: Matrix3<f64>,
}

impl LinkInertia {
    const ZERO: LinkInertia = LinkInertia {
        mass_kg: 0.0,
        com_in_joint_m: Vector3::new(0.0, 0.0, 0.0),
        inertia_about_com_kgm2: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };
}

/// Spatial inertia in a link frame (Featherstone's `(m, h = m·c, Ī = I_c + m·[c]×[c]×ᵀ)` about the frame
/// origin).
#[derive(Clone, Copy, Debug, PartialEq)]
struct SpatialInertia {
    m: f64,
    h: Vector3<f64>,
    ibar: Matrix3<f64>,
}

impl SpatialInertia {
    const ZERO: SpatialInertia = SpatialInertia {
        m: 0.0,
        h: Vector3::new(0.0, 0.0, 0.0),
        ibar: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    fn from_link(l: &LinkInertia) -> SpatialInertia {
        let c = l.com_in_joint_m;
        let cx = c.cross_matrix();
        SpatialInertia {
            m: l.mass_kg,
            h: c * l.mass_kg,
            ibar: l.inertia_about_com_kgm2 - cx * cx * l.mass_kg,
        }
    }

    /// `I·(ω, v)` → force `(n, f)`.
    fn apply(&self, w: &Vector3<f64>, v: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        (
            self.ibar * w + self.h.cross(v),
            v * self.m - self.h.cross(w),
        )
    }

    /// This inertia (in a child frame) expressed in its parent's frame, the child's origin being at
    /// `r` with orientation `rot = parent_from_child` (RBDA eq. 2.66: `Xᵀ·I·X`).
    fn expressed_in_parent(&self, rot: &Matrix3<f64>, r: &Vector3<f64>) -> SpatialInertia {
        let h = rot * self.h;
        let ibar = rot * self.ibar * rot.transpose();
        let rx = r.cross_matrix();
        let h_new = h + r * self.m;
        SpatialInertia {
            m: self.m,
            h: h_new,
            ibar: ibar - rx * h.cross_matrix() - h_new.cross_matrix() * rx,
        }
    }

    fn add(&mut self, o: &SpatialInertia) {
        self.m += o.m;
        self.h += o.h;
        self.ibar += o.ibar;
    }
}

/// Immutable dynamic model of the body: bone offsets, link inertias, armature, gravity.
#[derive(Clone, Debug)]
pub struct RigidBodyModel {
    /// Gravity in the world (m/s²); default [`GRAVITY_IN_MODEL_MPS2`]. Set to zero for gravity-free tests.
    pub gravity_mps2: Vector3<f64>,
    /// Armature (kg·m²) added to each of joint j's three rotational DoFs, root included; see the module docs.
    pub armature_kgm2: [f64; NUM_JOINTS],
    skeleton: Skeleton,
    links: [LinkInertia; NUM_JOINTS],
    spatial: [SpatialInertia; NUM_JOINTS],
    /// Parent of each 3-DoF block (block 0 = root translation, block 1 + j = joint j).
    block_parent: [usize; NUM_BLOCKS],
}

impl RigidBodyModel {
    /// Build from a body model: one link per joint holding all its segments (parallel-axis merge).
    pub fn new(body: &BodyModel) -> RigidBodyModel {
        let mut links = [LinkInertia::ZERO; NUM_JOINTS];
        for j in JointId::all() {
            let segs = || body.segments.iter().filter(move |s| s.joint == j);
            let mass: f64 = segs().map(|s| s.mass_kg).sum();
            if mass <= 0.0 {
                continue;
            }
            let com = segs().fold(Vector3::zeros(), |acc, s| {
                acc + s.com_in_joint_m * s.mass_kg
            }) / mass;
            // Parallel axis: I_com = Σ I_i + m_i·([d_i]×[d_i]×ᵀ), d_i = c_i − com.
            let inertia = segs().fold(Matrix3::zeros(), |acc, s| {
                let dx = (s.com_in_joint_m - com).cross_matrix();
                acc + s.inertia_about_com_kgm2 - dx * dx * s.mass_kg
            });
            links[j.index()] = LinkInertia {
                mass_kg: mass,
                com_in_joint_m: com,
                inertia_about_com_kgm2: inertia,
            };
        }
        // The root rotation hangs below the root translation, each joint below its parent joint.
        let mut block_parent = [NO_BLOCK; NUM_BLOCKS];
        for j in JointId::all() {
            block_parent[1 + j.index()] = j.parent().map_or(0, |p| 1 + p.index());
        }
        RigidBodyModel {
            gravity_mps2: GRAVITY_IN_MODEL_MPS2,
            armature_kgm2: [DEFAULT_ARMATURE_KGM2; NUM_JOINTS],
            skeleton: body.skeleton.clone(),
            spatial: links.map(|l| SpatialInertia::from_link(&l)),
            links,
            block_parent,
        }
    }

    /// The rigid link moving with `joint` (all its segments merged).
    pub fn link(&self, joint: JointId) -> &LinkInertia {
        &self.links[joint.index()]
    }

    /// The skeleton (bone offsets) used for kinematics.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Total mass (kg): the sum of all link masses, equal to the body model's mass.
    pub fn total_mass_kg(&self) -> f64 {
        self.links.iter().map(|l| l.mass_kg).sum()
    }
}

/// A spatial motion or force vector in link coordinates, angular part first.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Spatial {
    ang: Vector3<f64>,
    lin: Vector3<f64>,
}

impl Spatial {
    const ZERO: Spatial = Spatial {
        ang: Vector3::new(0.0, 0.0, 0.0),
        lin: Vector3::new(0.0, 0.0, 0.0),
    };
}

/// Workspace of the dynamics algorithms for one state; allocate once ([`DynamicsData::new`]) and reuse.
///
/// Call [`DynamicsData::set_state`] first; every other method works on the state it stored. All methods
/// are allocation-free.
#[derive(Clone, Debug)]
pub struct DynamicsData {
    fk: FkData,
    /// `parent_from_joint` of the stored pose.
    local: [Matrix3<f64>; NUM_JOINTS],
    v: DofVector,
    /// Link spatial velocities, link coordinates.
    vel: [Spatial; NUM_JOINTS],
    /// Link spatial accelerations for `v̇ = 0`, without gravity (velocity-product terms).
    acc_v: [Spatial; NUM_JOINTS],
    /// Scratch: accelerations and forces of an RNEA pass, composite inertias of CRBA.
    acc: [Spatial; NUM_JOINTS],
    force: [Spatial; NUM_JOINTS],
    composite: [SpatialInertia; NUM_JOINTS],
    mass_matrix: Box<MassMatrix>,
    bias: DofVector,
    /// `LᵀDL` factor: block (k, i) for i an ancestor of k holds `L_ki`.
    factor: Box<[[Matrix3<f64>; NUM_BLOCKS]; NUM_BLOCKS]>,
    /// Inverses of the 3×3 diagonal blocks of D.
    d_inv: [Matrix3<f64>; NUM_BLOCKS],
    factor_valid: bool,
}

impl Default for DynamicsData {
    fn default() -> DynamicsData {
        DynamicsData::new()
    }
}

impl DynamicsData {
    /// A workspace holding the T-pose at rest at the origin (call [`DynamicsData::set_state`] before use).
    pub fn new() -> DynamicsData {
        DynamicsData {
            fk: FkData::new(),
            local: [Matrix3::identity(); NUM_JOINTS],
            v: DofVector::zeros(),
            vel: [Spatial::ZERO; NUM_JOINTS],
            acc_v: [Spatial::ZERO; NUM_JOINTS],
            acc: [Spatial::ZERO; NUM_JOINTS],
            force: [Spatial::ZERO; NUM_JOINTS],
            composite: [SpatialInertia::ZERO; NUM_JOINTS],
            mass_matrix: Box::new(MassMatrix::zeros()),
            bias: DofVector::zeros(),
            factor: Box::new([[Matrix3::zeros(); NUM_BLOCKS]; NUM_BLOCKS]),
            d_inv: [Matrix3::zeros(); NUM_BLOCKS],
            factor_valid: false,
        }
    }

    /// Store a state and compute its kinematics (joint positions and orientations, link velocities and
    /// velocity-product accelerations). Must precede every other call for this state.
    pub fn set_state(&mut self, model: &RigidBodyModel, pose: &Pose, v: &DofVector) {
        self.v = *v;
        self.factor_valid = false;
        for j in JointId::all() {
            let i = j.index();
            let r = *pose.parent_from_joint[i].matrix();
            self.local[i] = r;
            let w_rel = dof3(v, joint_dof(j));
            match j.parent() {
                None => {
                    self.fk.world_from_joint[i] = pose.parent_from_joint[i];
                    self.fk.joint_in_world_m[i] = pose.root_in_world_m;
                    let lin = r.transpose() * Vector3::new(v[0], v[1], v[2]);
                    self.vel[i] = Spatial { ang: w_rel, lin };
                    // d/dt(R₀ᵀ·v_world) at v̇ = 0 is −ω₀ × (R₀ᵀ·v_world).
                    self.acc_v[i] = Spatial {
                        ang: Vector3::zeros(),
                        lin: -w_rel.cross(&lin),
                    };
                }
                Some(p) => {
                    let pi = p.index();
                    let off = model.skeleton.offset_in_parent_m(j);
                    let world_from_parent = self.fk.world_from_joint[pi];
                    self.fk.world_from_joint[i] = world_from_parent * pose.parent_from_joint[i];
                    self.fk.joint_in_world_m[i] =
                        self.fk.joint_in_world_m[pi] + world_from_parent * off;
                    let vp = motion_to_child(&r, off, &self.vel[pi]);
                    let vel = Spatial {
                        ang: vp.ang + w_rel,
                        lin: vp.lin,
                    };
                    // Velocity-product term c = v_j × (S·ω_rel) (S is constant in link coordinates).
                    let ap = motion_to_child(&r, off, &self.acc_v[pi]);
                    self.acc_v[i] = Spatial {
                        ang: ap.ang + vel.ang.cross(&w_rel),
                        lin: ap.lin + vel.lin.cross(&w_rel),
                    };
                    self.vel[i] = vel;
                }
            }
        }
    }

    /// Joint positions and orientations of the stored state.
    pub fn fk(&self) -> &FkData {
        &self.fk
    }

    /// The stored generalized velocity.
    pub fn velocity(&self) -> &DofVector {
        &self.v
    }

    /// Mass matrix `M(q)` (composite-rigid-body algorithm), armature included. Symmetric, both triangles
    /// filled. Recomputed on every call.
    pub fn mass_matrix(&mut self, model: &RigidBodyModel) -> &MassMatrix {
        self.composite = model.spatial;
        for j in JointId::all().rev() {
            if let Some(p) = j.parent() {
                let (i, pi) = (j.index(), p.index());
                let c = self.composite[i]
                    .expressed_in_parent(&self.local[i], model.skeleton.offset_in_parent_m(j));
                self.composite[pi].add(&c);
            }
        }
        let m = &mut *self.mass_matrix;
        for j in JointId::all().skip(1) {
            let i = j.index();
            let d = joint_dof(j);
            let ic = &self.composite[i];
            // F = Ic·S with S = [I; 0]: angular block Ī, linear block −[h]×.
            let mut f_ang = ic.ibar;
            let mut f_lin = -ic.h.cross_matrix();
            let arm = model.armature_kgm2[i];
            set_block(m, d, d, &(f_ang + Matrix3::identity() * arm));
            let mut k = j;
            while let Some(p) = k.parent() {
                let rot = &self.local[k.index()];
                let off = model.skeleton.offset_in_parent_m(k);
                let lin = rot * f_lin;
                f_ang = rot * f_ang + off.cross_matrix() * lin;
                f_lin = lin;
                k = p;
                let dk = joint_dof(k);
                set_block(m, dk, d, &f_ang);
                set_block(m, d, dk, &f_ang.transpose());
                if k == JointId::ROOT {
                    // Root translation column of S is (0, R₀ᵀ): Sᵀ·F = R₀·F_lin.
                    let t = self.fk.world_from_joint[0].matrix() * f_lin;
                    set_block(m, 0, d, &t);
                    set_block(m, d, 0, &t.transpose());
                }
            }
        }
        let ic = &self.composite[0];
        let r0 = *self.fk.world_from_joint[0].matrix();
        set_block(m, 0, 0, &(Matrix3::identity() * ic.m));
        let t = r0 * -ic.h.cross_matrix();
        set_block(m, 0, 3, &t);
        set_block(m, 3, 0, &t.transpose());
        set_block(
            m,
            3,
            3,
            &(ic.ibar + Matrix3::identity() * model.armature_kgm2[0]),
        );
        &self.mass_matrix
    }

    /// Bias forces `h(q, v)` = Coriolis/centrifugal + gravity, i.e. inverse dynamics at `v̇ = 0` (RNEA).
    /// Recomputed on every call.
    pub fn bias_forces(&mut self, model: &RigidBodyModel) -> &DofVector {
        let mut h = DofVector::zeros();
        self.rnea(model, None, true, true, &mut h);
        self.bias = h;
        &self.bias
    }

    /// Gravity part of `h` only (`h(q, 0)`; `+∂U/∂q` along the exp-update directions).
    pub fn gravity_forces(&mut self, model: &RigidBodyModel, out: &mut DofVector) {
        self.rnea(model, None, false, true, out);
    }

    /// Inverse dynamics `τ = M·v̇ + h` by recursive Newton–Euler (armature included), written to `tau`.
    pub fn inverse_dynamics(
        &mut self,
        model: &RigidBodyModel,
        vdot: &DofVector,
        tau: &mut DofVector,
    ) {
        self.rnea(model, Some(vdot), true, true, tau);
    }

    /// RNEA on the stored state. `vdot = None` means zero; `with_velocity = false` drops the velocity terms
    /// (as if v = 0); `gravity` adds the uniform gravity field as a
    /// fictitious upward acceleration of every link (RBDA §5.3).
    fn rnea(
        &mut self,
        model: &RigidBodyModel,
        vdot: Option<&DofVector>,
        with_velocity: bool,
        gravity: bool,
        tau: &mut DofVector,
    ) {
        let g = if gravity {
            model.gravity_mps2
        } else {
            Vector3::zeros()
        };
        for j in JointId::all() {
            let i = j.index();
            // The v̇-driven acceleration (kept in acc[] for the children): S·v̇ plus the parent's.
            let a_vd = match vdot {
                None => Spatial::ZERO,
                Some(vd) => match j.parent() {
                    None => Spatial {
                        ang: dof3(vd, 3),
                        lin: self.local[i].tr_mul(&Vector3::new(vd[0], vd[1], vd[2])),
                    },
                    Some(p) => {
                        let ap = motion_to_child(
                            &self.local[i],
                            model.skeleton.offset_in_parent_m(j),
                            &self.acc[p.index()],
                        );
                        Spatial {
                            ang: ap.ang + dof3(vd, joint_dof(j)),
                            lin: ap.lin,
                        }
                    }
                },
            };
            self.acc[i] = a_vd;
            let (vel, a_v) = if with_velocity {
                (self.vel[i], self.acc_v[i])
            } else {
                (Spatial::ZERO, Spatial::ZERO)
            };
            // Gravity: a fictitious acceleration −g of every link, in link coordinates.
            let a = Spatial {
                ang: a_vd.ang + a_v.ang,
                lin: a_vd.lin + a_v.lin - self.fk.world_from_joint[i].matrix().tr_mul(&g),
            };
            let si = &model.spatial[i];
            let (n_a, f_a) = si.apply(&a.ang, &a.lin);
            let (n_v, f_v) = si.apply(&vel.ang, &vel.lin);
            // Force cross product v ×* (I·v) = (ω × n + v × f, ω × f).
            self.force[i] = Spatial {
                ang: n_a + vel.ang.cross(&n_v) + vel.lin.cross(&f_v),
                lin: f_a + vel.ang.cross(&f_v),
            };
        }
        for j in JointId::all().rev() {
            let i = j.index();
            let f = self.force[i];
            let d = joint_dof(j);
            let arm = model.armature_kgm2[i];
            let wd = vdot.map_or(Vector3::zeros(), |vd| dof3(vd, d));
            let t = f.ang + wd * arm;
            tau[d] = t.x;
            tau[d + 1] = t.y;
            tau[d + 2] = t.z;
            match j.parent() {
                Some(p) => {
                    let rot = &self.local[i];
                    let lin = rot * f.lin;
                    let ang = rot * f.ang + model.skeleton.offset_in_parent_m(j).cross(&lin);
                    let fp = &mut self.force[p.index()];
                    fp.ang += ang;
                    fp.lin += lin;
                }
                None => {
                    // Root translation: Sᵀ·f = R₀·f_lin, the force in the world frame.
                    let fw = self.local[i] * f.lin;
                    tau[0] = fw.x;
                    tau[1] = fw.y;
                    tau[2] = fw.z;
                }
            }
        }
    }

    /// Factorise the mass matrix of the stored state for [`DynamicsData::solve_mass_matrix`]: `M = LᵀDL`
    /// with 3×3 blocks (root translation, then one per joint), L block-unit-lower and D block-diagonal.
    /// Eliminating from the leaves up causes no fill-in on a tree (RBDA §6.5, here by blocks), so the cost
    /// is Σ depth² block products instead of a dense 75³/3. Computes `M` itself.
    pub fn factorize_mass_matrix(&mut self, model: &RigidBodyModel) -> Result<(), DynamicsError> {
        self.mass_matrix(model);
        self.factor_valid = false;
        let f = &mut *self.factor;
        let m = &*self.mass_matrix;
        let parent = &model.block_parent;
        for (k, row) in f.iter_mut().enumerate() {
            let mut i = k;
            while i != NO_BLOCK {
                row[i] = m.fixed_view::<3, 3>(3 * k, 3 * i).into_owned();
                i = parent[i];
            }
        }
        for k in (0..NUM_BLOCKS).rev() {
            let dk = f[k][k];
            let Some(chol) = nalgebra::Cholesky::new(dk) else {
                return Err(DynamicsError::NotPositiveDefinite {
                    dof: 3 * k,
                    determinant: dk.determinant(),
                });
            };
            let d_inv = chol.inverse();
            if !d_inv.iter().all(|x| x.is_finite()) {
                return Err(DynamicsError::NotPositiveDefinite {
                    dof: 3 * k,
                    determinant: dk.determinant(),
                });
            }
            self.d_inv[k] = d_inv;
            let mut i = parent[k];
            while i != NO_BLOCK {
                // L_ki = D_k⁻¹·H_ki; H_ij −= L_kiᵀ·H_kj for i and its ancestors j.
                let a = d_inv * f[k][i];
                let mut j = i;
                while j != NO_BLOCK {
                    let t = a.tr_mul(&f[k][j]);
                    f[i][j] -= t;
                    j = parent[j];
                }
                f[k][i] = a;
                i = parent[i];
            }
        }
        self.factor_valid = true;
        Ok(())
    }

    /// Solve `M·x = b` in place with the factorisation of [`DynamicsData::factorize_mass_matrix`]
    /// (computed on demand if missing for the stored state; it is kept until the next `set_state`, so
    /// refactorise after changing the model). Useful for `M⁻¹·Jᵀ` in contact solvers.
    pub fn solve_mass_matrix(
        &mut self,
        model: &RigidBodyModel,
        b: &mut DofVector,
    ) -> Result<(), DynamicsError> {
        if !self.factor_valid {
            self.factorize_mass_matrix(model)?;
        }
        let f = &*self.factor;
        let parent = &model.block_parent;
        // Lᵀ·y = b (descendants have larger indices), then D, then L·x = y.
        for i in (0..NUM_BLOCKS).rev() {
            let bi = dof3(b, 3 * i);
            let mut j = parent[i];
            while j != NO_BLOCK {
                let t = f[i][j].tr_mul(&bi);
                let mut bj = b.fixed_rows_mut::<3>(3 * j);
                bj -= t;
                j = parent[j];
            }
        }
        for i in 0..NUM_BLOCKS {
            let x = self.d_inv[i] * dof3(b, 3 * i);
            b.fixed_rows_mut::<3>(3 * i).copy_from(&x);
        }
        for i in 0..NUM_BLOCKS {
            let mut x = dof3(b, 3 * i);
            let mut j = parent[i];
            while j != NO_BLOCK {
                x -= f[i][j] * dof3(b, 3 * j);
                j = parent[j];
            }
            b.fixed_rows_mut::<3>(3 * i).copy_from(&x);
        }
        Ok(())
    }

    /// Forward dynamics: `v̇ = M⁻¹·(τ − h)` for the stored state, written to `vdot`.
    pub fn forward_dynamics(
        &mut self,
        model: &RigidBodyModel,
        tau: &DofVector,
        vdot: &mut DofVector,
    ) -> Result<(), DynamicsError> {
        let h = *self.bias_forces(model);
        *vdot = tau - h;
        self.factorize_mass_matrix(model)?;
        self.solve_mass_matrix(model, vdot)
    }

    /// World position of a point fixed in `joint`'s frame (`point_in_joint`, m).
    pub fn point_position(&self, joint: JointId, point_in_joint: &Vector3<f64>) -> Vector3<f64> {
        let i = joint.index();
        self.fk.joint_in_world_m[i] + self.fk.world_from_joint[i] * point_in_joint
    }

    /// World linear velocity of a point fixed in `joint`'s frame (equals `J·v`).
    pub fn point_velocity(&self, joint: JointId, point_in_joint: &Vector3<f64>) -> Vector3<f64> {
        let i = joint.index();
        let vel = &self.vel[i];
        self.fk.world_from_joint[i] * (vel.lin + vel.ang.cross(point_in_joint))
    }

    /// Point Jacobian: `out` = ∂(world velocity of the point)/∂v (3 × 75), for a point fixed in `joint`'s
    /// frame. Identity on the root translation, `−[p − o_i]×·R_Wi` on each ancestor i (GlobalPose §5.4),
    /// zero elsewhere. Overwrites all of `out`.
    pub fn point_jacobian(
        &self,
        joint: JointId,
        point_in_joint: &Vector3<f64>,
        out: &mut PointJacobian,
    ) {
        out.as_mut_slice().fill(0.0);
        let p = self.point_position(joint, point_in_joint);
        out.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        let mut k = Some(joint);
        while let Some(j) = k {
            let i = j.index();
            let d = p - self.fk.joint_in_world_m[i];
            let block = -d.cross_matrix() * self.fk.world_from_joint[i].matrix();
            out.fixed_view_mut::<3, 3>(0, joint_dof(j))
                .copy_from(&block);
            k = j.parent();
        }
    }

    /// `J̇·v` for a point fixed in `joint`'s frame: its world acceleration at `v̇ = 0` (no gravity).
    pub fn point_jdot_v(&self, joint: JointId, point_in_joint: &Vector3<f64>) -> Vector3<f64> {
        let i = joint.index();
        let (vel, a) = (&self.vel[i], &self.acc_v[i]);
        // Classical acceleration of a body point from the spatial acceleration (RBDA eq. 2.40).
        let v_pt = vel.lin + vel.ang.cross(point_in_joint);
        let a_pt = a.lin + a.ang.cross(point_in_joint) + vel.ang.cross(&v_pt);
        self.fk.world_from_joint[i] * a_pt
    }

    /// World angular velocity Jacobian of `joint` (3 × 75): `R_Wi` on each ancestor i's block (root
    /// included), zero elsewhere. Overwrites all of `out`.
    pub fn angular_jacobian(&self, joint: JointId, out: &mut AngularJacobian) {
        out.as_mut_slice().fill(0.0);
        let mut k = Some(joint);
        while let Some(j) = k {
            out.fixed_view_mut::<3, 3>(0, joint_dof(j))
                .copy_from(self.fk.world_from_joint[j.index()].matrix());
            k = j.parent();
        }
    }

    /// World angular velocity of `joint`.
    pub fn angular_velocity(&self, joint: JointId) -> Vector3<f64> {
        let i = joint.index();
        self.fk.world_from_joint[i] * self.vel[i].ang
    }

    /// Kinetic energy (J): `Σ ½·V_jᵀ·I_j·V_j` over links plus `½·armature·|ω_j|²` (equals `½·vᵀ·M·v`).
    pub fn kinetic_energy(&self, model: &RigidBodyModel) -> f64 {
        let mut e = 0.0;
        for j in JointId::all() {
            let i = j.index();
            let vel = &self.vel[i];
            let (n, f) = model.spatial[i].apply(&vel.ang, &vel.lin);
            e += vel.ang.dot(&n) + vel.lin.dot(&f);
            e += model.armature_kgm2[i] * dof3(&self.v, joint_dof(j)).norm_squared();
        }
        0.5 * e
    }

    /// Gravitational potential energy (J): `−Σ m_j·g·c_j` (zero at the world origin's height).
    pub fn potential_energy(&self, model: &RigidBodyModel) -> f64 {
        let mut e = 0.0;
        for j in JointId::all() {
            let l = &model.links[j.index()];
            if l.mass_kg > 0.0 {
                e -= l.mass_kg
                    * model
                        .gravity_mps2
                        .dot(&self.point_position(j, &l.com_in_joint_m));
            }
        }
        e
    }

    /// Whole-body centre of mass in the world (m).
    pub fn center_of_mass(&self, model: &RigidBodyModel) -> Vector3<f64> {
        let mut c = Vector3::zeros();
        for j in JointId::all() {
            let l = &model.links[j.index()];
            c += self.point_position(j, &l.com_in_joint_m) * l.mass_kg;
        }
        c / model.total_mass_kg()
    }
}

/// Three consecutive entries of `v` from `d`.
fn dof3(v: &DofVector, d: usize) -> Vector3<f64> {
    Vector3::new(v[d], v[d + 1], v[d + 2])
}

fn set_block(m: &mut MassMatrix, r: usize, c: usize, b: &Matrix3<f64>) {
    m.fixed_view_mut::<3, 3>(r, c).copy_from(b);
}

/// Motion vector of a parent expressed at a child's origin in child coordinates; the child sits at `off`
/// in the parent with `rot = parent_from_child`: `(Rᵀω, Rᵀ(v + ω × off))`.
fn motion_to_child(rot: &Matrix3<f64>, off: &Vector3<f64>, m: &Spatial) -> Spatial {
    Spatial {
        ang: rot.tr_mul(&m.ang),
        lin: rot.tr_mul(&(m.lin + m.ang.cross(off))),
    }
}

/// `q ⊕ δ`: root position `+= δ[0..3]`, `R_j ← R_j·exp(δ_j)` (right perturbation, joint frame).
pub fn displace(pose: &mut Pose, delta: &DofVector) {
    pose.root_in_world_m += Vector3::new(delta[0], delta[1], delta[2]);
    for j in JointId::all() {
        let i = j.index();
        let r = pose.parent_from_joint[i] * Rotation3::new(dof3(delta, joint_dof(j)));
        // Keep the product of many small rotations orthonormal over long simulations. Through a
        // unit quaternion, not `Rotation3::renormalize`: that iterates until converged with no
        // bound and never returns on a non-finite matrix (a diverged step hung the optimizer).
        let q = *UnitQuaternion::from_rotation_matrix(&r).quaternion();
        pose.parent_from_joint[i] = UnitQuaternion::new_normalize(q).to_rotation_matrix();
    }
}

/// GlobalPose's update (reference §5.4): `δ = v·dt + ½·a·dt²`, `q ← q ⊕ δ`, `v += a·dt`.
pub fn integrate(pose: &mut Pose, v: &mut DofVector, a: &DofVector, dt: f64) {
    let delta = *v * dt + a * (0.5 * dt * dt);
    displace(pose, &delta);
    *v += a * dt;
}

/// Semi-implicit Euler (PIP §5.2): `v += a·dt`, then `q ← q ⊕ v·dt`.
pub fn integrate_semi_implicit_euler(pose: &mut Pose, v: &mut DofVector, a: &DofVector, dt: f64) {
    *v += a * dt;
    displace(pose, &(*v * dt));
}

/// `MotionFrame.q` of a pose: root position (m), then per joint the local rotation vector (rad).
pub fn pose_to_q(pose: &Pose) -> DofVector {
    let mut q = DofVector::zeros();
    q.fixed_rows_mut::<3>(0).copy_from(&pose.root_in_world_m);
    for j in JointId::all() {
        let r = axis_angle_from_rotation(&pose.parent_from_joint[j.index()]);
        q.fixed_rows_mut::<3>(joint_dof(j)).copy_from(&r);
    }
    q
}

/// Inverse of [`pose_to_q`].
pub fn pose_from_q(q: &DofVector) -> Pose {
    let mut pose = Pose::t_pose(Vector3::new(q[0], q[1], q[2]));
    for j in JointId::all() {
        pose.parent_from_joint[j.index()] = Rotation3::new(dof3(q, joint_dof(j)));
    }
    pose
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body_model::BodyParams;
    use crate::kinematics::forward_kinematics;
    use crate::test_util::{XorShift, random_rotations};
    use nalgebra::DMatrix;

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.741, 73.0).unwrap()
    }

    fn random_vector(rng: &mut XorShift, scale: f64) -> DofVector {
        DofVector::from_fn(|_, _| rng.signed() * scale)
    }

    /// A random pose (arbitrary rotations, root anywhere near the origin) and velocity.
    fn random_state(seed: u64) -> (Pose, DofVector) {
        let mut rng = XorShift(seed);
        let rots = random_rotations(NUM_JOINTS, seed + 1000);
        let mut pose = Pose::t_pose(Vector3::new(rng.signed(), 1.0 + rng.signed(), rng.signed()));
        pose.parent_from_joint.copy_from_slice(&rots);
        (pose, random_vector(&mut rng, 2.0))
    }

    /// Unit vector along DoF k.
    fn e(k: usize) -> DofVector {
        let mut v = DofVector::zeros();
        v[k] = 1.0;
        v
    }

    #[test]
    fn displacing_keeps_rotations_orthonormal_and_returns_on_non_finite_steps() {
        // Many small steps: each joint's rotation stays a rotation and equals the product of the
        // steps' exact rotations (composed independently here).
        let (mut pose, _) = random_state(5);
        let mut exact = pose.parent_from_joint;
        let mut rng = XorShift(9);
        for _ in 0..2000 {
            let delta = random_vector(&mut rng, 0.05);
            displace(&mut pose, &delta);
            for j in JointId::all() {
                let i = j.index();
                exact[i] *= Rotation3::new(dof3(&delta, joint_dof(j)));
            }
        }
        for (r, want) in pose.parent_from_joint.iter().zip(&exact) {
            let m = r.matrix();
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
            assert!((m.determinant() - 1.0).abs() < 1e-12);
            let off = axis_angle_from_rotation(&(r.inverse() * want)).norm();
            assert!(off < 1e-6, "{off}");
        }
        // A diverged step (NaN) comes back as a non-finite pose the callers detect, instead of
        // never returning (nalgebra's iterative renormalization loops forever on NaN).
        let mut nan = DofVector::zeros();
        nan[joint_dof(JointId::LEFT_KNEE)] = f64::NAN;
        displace(&mut pose, &nan);
        assert!(!pose.is_finite());
    }

    fn displaced(pose: &Pose, delta: &DofVector) -> Pose {
        let mut p = pose.clone();
        displace(&mut p, delta);
        p
    }

    /// A point fixed in `joint`'s frame, computed by plain forward kinematics (independent of dynamics).
    fn fk_point(
        model: &RigidBodyModel,
        pose: &Pose,
        joint: JointId,
        p: &Vector3<f64>,
    ) -> Vector3<f64> {
        let mut fk = FkData::new();
        forward_kinematics(model.skeleton(), pose, &mut fk);
        fk.position(joint) + fk.world_from(joint) * p
    }

    /// Test points: a few joints, each with an offset off the bone.
    fn test_points() -> [(JointId, Vector3<f64>); 5] {
        [
            (JointId::ROOT, Vector3::new(0.05, -0.1, 0.02)),
            (JointId::LEFT_FOOT, Vector3::new(0.01, -0.03, 0.1)),
            (JointId::RIGHT_HAND, Vector3::new(-0.05, 0.01, 0.0)),
            (JointId::HEAD, Vector3::new(0.0, 0.1, 0.05)),
            (JointId::RIGHT_ANKLE, Vector3::zeros()),
        ]
    }

    #[test]
    fn total_mass_is_the_body_mass_and_massless_joints_are_the_documented_ones() {
        let body = body();
        let model = RigidBodyModel::new(&body);
        assert!((model.total_mass_kg() - 73.0).abs() < 1e-9 * 73.0);
        let seg_sum: f64 = body.segments.iter().map(|s| s.mass_kg).sum();
        assert!((model.total_mass_kg() - seg_sum).abs() < 1e-12);
        for j in [6, 10, 11, 12, 13, 14, 22, 23] {
            let j = JointId::from_index(j).unwrap();
            assert_eq!(model.link(j).mass_kg, 0.0, "{j}");
        }
        // Translational block of M is m·I; h at rest is the weight (world force, root torque about pelvis).
        let mut data = DynamicsData::new();
        let (pose, _) = random_state(3);
        data.set_state(&model, &pose, &DofVector::zeros());
        let m = *data.mass_matrix(&model);
        for r in 0..3 {
            for c in 0..3 {
                let want = if r == c { 73.0 } else { 0.0 };
                assert!((m[(r, c)] - want).abs() < 1e-9);
            }
        }
        let h = *data.bias_forces(&model);
        assert!(
            (Vector3::new(h[0], h[1], h[2]) - Vector3::new(0.0, 73.0 * 9.81, 0.0)).norm() < 1e-9
        );
        // Off-diagonal translation/rotation block encodes the COM: M[0..3, 3..6] = −m·[c − o]×·R₀.
        let c = data.center_of_mass(&model) - pose.root_in_world_m;
        let want = -(c * 73.0).cross_matrix() * pose.parent_from_joint[0].matrix();
        assert!((m.fixed_view::<3, 3>(0, 3) - want).norm() < 1e-9);
    }

    #[test]
    fn mass_matrix_is_symmetric_positive_definite() {
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        for seed in 1..20 {
            let (pose, v) = random_state(seed);
            data.set_state(&model, &pose, &v);
            let m = *data.mass_matrix(&model);
            assert!((m - m.transpose()).amax() < 1e-12);
            let dm = DMatrix::from_column_slice(NUM_DOFS, NUM_DOFS, m.as_slice());
            let eig = dm.symmetric_eigenvalues();
            let min = eig.min();
            // The armature (1e-3) bounds the smallest eigenvalue from below (hands and feet rows).
            assert!(
                min > 0.5 * DEFAULT_ARMATURE_KGM2,
                "seed {seed}: λ_min = {min}"
            );
            assert!(nalgebra::Cholesky::new(dm).is_some());
            // Without armature M is singular: the massless leaf joints move nothing.
            let mut bare = model.clone();
            bare.armature_kgm2 = [0.0; NUM_JOINTS];
            let m0 = *data.mass_matrix(&bare);
            let d = joint_dof(JointId::LEFT_HAND);
            assert!(m0.row(d).amax() < 1e-12 && m0.column(d + 2).amax() < 1e-12);
        }
    }

    #[test]
    fn mass_matrix_times_acceleration_plus_bias_equals_rnea() {
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        let mut rng = XorShift(77);
        for seed in 1..20 {
            let (pose, v) = random_state(seed);
            let vdot = random_vector(&mut rng, 5.0);
            data.set_state(&model, &pose, &v);
            let m = *data.mass_matrix(&model);
            let h = *data.bias_forces(&model);
            let mut tau = DofVector::zeros();
            data.inverse_dynamics(&model, &vdot, &mut tau);
            let err = (m * vdot + h - tau).amax();
            assert!(err < 1e-9 * tau.amax().max(1.0), "seed {seed}: {err}");
        }
    }

    #[test]
    fn mass_matrix_columns_match_rnea_and_kinetic_energy_matches_links() {
        // CRBA against RNEA at v = 0 (M·e_k = τ(e_k) − τ(0)), and ½vᵀMv against the per-link kinetic energy.
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        for seed in 1..6 {
            let (pose, v) = random_state(seed);
            data.set_state(&model, &pose, &DofVector::zeros());
            let m = *data.mass_matrix(&model);
            let mut g = DofVector::zeros();
            data.inverse_dynamics(&model, &DofVector::zeros(), &mut g);
            for k in 0..NUM_DOFS {
                let mut tau = DofVector::zeros();
                data.inverse_dynamics(&model, &e(k), &mut tau);
                assert!((tau - g - m.column(k)).amax() < 1e-10, "column {k}");
            }
            data.set_state(&model, &pose, &v);
            let ke = data.kinetic_energy(&model);
            assert!(
                (ke - 0.5 * v.dot(&(m * v))).abs() < 1e-10 * ke,
                "seed {seed}"
            );
        }
    }

    #[test]
    fn forward_dynamics_inverts_inverse_dynamics() {
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        let mut rng = XorShift(5);
        for seed in 1..10 {
            let (pose, v) = random_state(seed);
            let tau = random_vector(&mut rng, 20.0);
            data.set_state(&model, &pose, &v);
            let mut a = DofVector::zeros();
            data.forward_dynamics(&model, &tau, &mut a).unwrap();
            let mut back = DofVector::zeros();
            data.inverse_dynamics(&model, &a, &mut back);
            assert!(
                (back - tau).amax() < 1e-8,
                "seed {seed}: {}",
                (back - tau).amax()
            );
            // Same solution as a dense Cholesky of M.
            let m = *data.mass_matrix(&model);
            let h = *data.bias_forces(&model);
            let dense = nalgebra::Cholesky::new(m).unwrap().solve(&(tau - h));
            assert!((dense - a).amax() < 1e-8 * a.amax().max(1.0));
        }
        // Non-positive armature on a massless leaf joint is reported, not solved.
        let mut bad = model.clone();
        bad.armature_kgm2[JointId::LEFT_HAND.index()] = 0.0;
        let (pose, v) = random_state(1);
        data.set_state(&bad, &pose, &v);
        let mut a = DofVector::zeros();
        let err = data.forward_dynamics(&bad, &DofVector::zeros(), &mut a);
        assert!(matches!(
            err,
            Err(DynamicsError::NotPositiveDefinite { .. })
        ));
    }

    #[test]
    fn point_jacobian_matches_finite_differences_of_forward_kinematics() {
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        let mut jac = PointJacobian::zeros();
        let eps = 1e-6;
        for seed in 1..6 {
            let (pose, v) = random_state(seed);
            data.set_state(&model, &pose, &v);
            for (joint, p) in test_points() {
                data.point_jacobian(joint, &p, &mut jac);
                assert!(
                    (data.point_position(joint, &p) - fk_point(&model, &pose, joint, &p)).norm()
                        < 1e-12
                );
                for k in 0..NUM_DOFS {
                    let plus = fk_point(&model, &displaced(&pose, &(e(k) * eps)), joint, &p);
                    let minus = fk_point(&model, &displaced(&pose, &(e(k) * -eps)), joint, &p);
                    let fd = (plus - minus) / (2.0 * eps);
                    let err = (fd - jac.column(k)).norm();
                    assert!(err < 1e-8, "{joint} dof {k}: {err}");
                }
                assert!((jac * v - data.point_velocity(joint, &p)).norm() < 1e-12);
            }
            // Angular Jacobian: finite differences of the world rotation.
            let mut ang = AngularJacobian::zeros();
            data.angular_jacobian(JointId::LEFT_WRIST, &mut ang);
            let mut fk = FkData::new();
            for k in 0..NUM_DOFS {
                forward_kinematics(model.skeleton(), &displaced(&pose, &(e(k) * eps)), &mut fk);
                let rp = *fk.world_from(JointId::LEFT_WRIST);
                forward_kinematics(model.skeleton(), &displaced(&pose, &(e(k) * -eps)), &mut fk);
                let rm = *fk.world_from(JointId::LEFT_WRIST);
                // World angular velocity: (Ṙ·Rᵀ)^∨ ≈ log(R₊·R₋ᵀ)/(2ε).
                let fd = axis_angle_from_rotation(&(rp * rm.transpose())) / (2.0 * eps);
                assert!((fd - ang.column(k)).norm() < 1e-8, "angular dof {k}");
            }
            assert!((ang * v - data.angular_velocity(JointId::LEFT_WRIST)).norm() < 1e-12);
        }
    }

    #[test]
    fn jdot_v_matches_finite_differences_along_the_motion() {
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        let mut jac = PointJacobian::zeros();
        let eps = 1e-5;
        for seed in 1..6 {
            let (pose, v) = random_state(seed);
            let (plus, minus) = (displaced(&pose, &(v * eps)), displaced(&pose, &(v * -eps)));
            for (joint, p) in test_points() {
                data.set_state(&model, &pose, &v);
                let jdv = data.point_jdot_v(joint, &p);
                // d/dt (J·v) with v constant along q ⊕ t·v.
                data.set_state(&model, &plus, &v);
                data.point_jacobian(joint, &p, &mut jac);
                let jv_plus = jac * v;
                data.set_state(&model, &minus, &v);
                data.point_jacobian(joint, &p, &mut jac);
                let jv_minus = jac * v;
                let fd = (jv_plus - jv_minus) / (2.0 * eps);
                assert!(
                    (fd - jdv).norm() < 1e-6 * jdv.norm().max(1.0),
                    "{joint}: {fd} vs {jdv}"
                );
                // Second difference of the position along the same curve (FK only).
                let x0 = fk_point(&model, &pose, joint, &p);
                let h = 1e-4;
                let xp = fk_point(&model, &displaced(&pose, &(v * h)), joint, &p);
                let xm = fk_point(&model, &displaced(&pose, &(v * -h)), joint, &p);
                let fd2 = (xp - 2.0 * x0 + xm) / (h * h);
                assert!(
                    (fd2 - jdv).norm() < 1e-4 * jdv.norm().max(1.0),
                    "{joint}: {fd2} vs {jdv}"
                );
            }
        }
    }

    #[test]
    fn gravity_forces_are_the_gradient_of_the_potential_energy() {
        // h(q, 0) = +∂U/∂q along q ⊕ ε·e_k: the torque that holds the body still against gravity.
        let model = RigidBodyModel::new(&body());
        let mut data = DynamicsData::new();
        let eps = 1e-6;
        for seed in 1..6 {
            let (pose, v) = random_state(seed);
            data.set_state(&model, &pose, &v);
            let mut g = DofVector::zeros();
            data.gravity_forces(&model, &mut g);
            let mut tau = DofVector::zeros();
            data.set_state(&model, &pose, &DofVector::zeros());
            data.inverse_dynamics(&model, &DofVector::zeros(), &mut tau);
            assert!((tau - g).amax() < 1e-10);
            for k in 0..NUM_DOFS {
                data.set_state(&model, &displaced(&pose, &(e(k) * eps)), &v);
                let up = data.potential_energy(&model);
                data.set_state(&model, &displaced(&pose, &(e(k) * -eps)), &v);
                let um = data.potential_energy(&model);
                let fd = (up - um) / (2.0 * eps);
                assert!((fd - g[k]).abs() < 1e-6, "dof {k}: {fd} vs {}", g[k]);
            }
        }
    }

    /// Inverse of the right Jacobian of SO(3): `ξ̇ = J_r⁻¹(ξ)·ω` for `R = R₀·exp(ξ)`.
    fn right_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
        let t = phi.norm();
        let k = phi.cross_matrix();
        let c = if t < 1e-4 {
            1.0 / 12.0 + t * t / 720.0
        } else {
            1.0 / (t * t) - (1.0 + t.cos()) / (2.0 * t * t.sin())
        };
        Matrix3::identity() + k * 0.5 + k * k * c
    }

    /// One Runge–Kutta–Munthe-Kaas (RK4) step of the torque-free motion: RK4 on local coordinates ξ
    /// around the current pose, `q = q₀ ⊕ ξ`.
    fn rkmk4_step(
        model: &RigidBodyModel,
        data: &mut DynamicsData,
        pose: &mut Pose,
        v: &mut DofVector,
        dt: f64,
    ) {
        let mut f = |xi: &DofVector, vel: &DofVector| -> (DofVector, DofVector) {
            data.set_state(model, &displaced(pose, xi), vel);
            let mut a = DofVector::zeros();
            data.forward_dynamics(model, &DofVector::zeros(), &mut a)
                .unwrap();
            let mut xi_dot = *vel;
            for j in JointId::all() {
                let d = joint_dof(j);
                let w = right_jacobian_inverse(&dof3(xi, d)) * dof3(vel, d);
                xi_dot.fixed_rows_mut::<3>(d).copy_from(&w);
            }
            (xi_dot, a)
        };
        let xi0 = DofVector::zeros();
        let (k1x, k1v) = f(&xi0, v);
        let (k2x, k2v) = f(&(k1x * (dt / 2.0)), &(*v + k1v * (dt / 2.0)));
        let (k3x, k3v) = f(&(k2x * (dt / 2.0)), &(*v + k2v * (dt / 2.0)));
        let (k4x, k4v) = f(&(k3x * dt), &(*v + k3v * dt));
        let xi = (k1x + k2x * 2.0 + k3x * 2.0 + k4x) * (dt / 6.0);
        *v += (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (dt / 6.0);
        displace(pose, &xi);
    }

    #[test]
    fn energy_and_momentum_are_conserved_without_torque_and_gravity() {
        let mut model = RigidBodyModel::new(&body());
        model.gravity_mps2 = Vector3::zeros();
        let mut data = DynamicsData::new();
        let (mut pose, _) = random_state(11);
        let mut rng = XorShift(12);
        let mut v = random_vector(&mut rng, 1.5);
        data.set_state(&model, &pose, &v);
        let e0 = data.kinetic_energy(&model);
        let c0 = data.center_of_mass(&model);
        let m = model.total_mass_kg();
        let vc0 = JointId::all().fold(Vector3::zeros(), |acc, j| {
            let l = model.link(j);
            acc + data.point_velocity(j, &l.com_in_joint_m) * l.mass_kg
        }) / m;
        // 2 s at dt = 2.5 ms (RK4: error ~dt⁴; 1e-10 at dt = 1 ms).
        let (dt, steps) = (2.5e-3, 800);
        let mut max_drift: f64 = 0.0;
        for _ in 0..steps {
            rkmk4_step(&model, &mut data, &mut pose, &mut v, dt);
            data.set_state(&model, &pose, &v);
            max_drift = max_drift.max((data.kinetic_energy(&model) - e0).abs() / e0);
        }
        eprintln!("energy: E0 = {e0:.4} J, max relative drift {max_drift:e}");
        // Bound 1e-7 relative (measured 6e-9 at this step; the error shrinks as dt⁴).
        assert!(max_drift < 1e-7, "relative energy drift {max_drift:e}");
        // The centre of mass moves in a straight line at constant speed.
        let c = data.center_of_mass(&model);
        let want = c0 + vc0 * (dt * steps as f64);
        // Measured 1.5e-8 m after 2 s.
        assert!((c - want).norm() < 1e-6, "COM off by {}", (c - want).norm());
    }

    #[test]
    fn integrators_follow_their_formulas_and_q_round_trips() {
        let (pose, v) = random_state(8);
        let a = DofVector::from_fn(|r, _| (r as f64 * 0.37).sin());
        let dt = 1.0 / 60.0;
        let (mut p1, mut v1) = (pose.clone(), v);
        integrate(&mut p1, &mut v1, &a, dt);
        let delta = v * dt + a * (0.5 * dt * dt);
        assert!((v1 - (v + a * dt)).amax() < 1e-15);
        assert!(
            (p1.root_in_world_m - pose.root_in_world_m - delta.fixed_rows::<3>(0)).norm() < 1e-15
        );
        let j = JointId::LEFT_KNEE;
        let want = pose.parent_from_joint[j.index()] * Rotation3::new(dof3(&delta, joint_dof(j)));
        assert!(crate::rotation::angle_between(&p1.parent_from_joint[j.index()], &want) < 1e-12);
        let (mut p2, mut v2) = (pose.clone(), v);
        integrate_semi_implicit_euler(&mut p2, &mut v2, &a, dt);
        let want =
            pose.parent_from_joint[j.index()] * Rotation3::new(dof3(&(v2 * dt), joint_dof(j)));
        assert!(crate::rotation::angle_between(&p2.parent_from_joint[j.index()], &want) < 1e-12);

        let back = pose_from_q(&pose_to_q(&pose));
        assert!((back.root_in_world_m - pose.root_in_world_m).norm() < 1e-15);
        for j in JointId::all() {
            let i = j.index();
            assert!(
                crate::rotation::angle_between(
                    &back.parent_from_joint[i],
                    &pose.parent_from_joint[i]
                ) < 1e-12
            );
        }
    }
}
