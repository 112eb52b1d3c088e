//! The `validation` stage: motion in, validation scores and the simulated body out.
//!
//! - Frames flagged CALIBRATING end the simulation; it restarts from the estimate at the next
//!   usable frame.
//! - A frame flagged INVALID, or one whose pose cannot be decoded, is not tracked: the simulated
//!   body holds the last usable estimate and the outputs are flagged INVALID.
//! - A fall resets the simulation to the estimate and is counted; the stage never stops on one.
//! - With a `contacts` input, the summary says how often the estimate's foot contacts agree with
//!   the simulated feet.

use anyhow::Context;
use imuflow_body::kinematics::Pose;
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::JointId;
use imuflow_contact::subject::{MASS_PARAM, STATURE_PARAM, subject_body};
use imuflow_graph::frames::{ContactFrame, MotionFrame, NUM_DOFS, ValidationFrame, flags};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, StageContext};

use crate::model::{FOOT_PITCH_PARAM, SimModel};
use crate::sim::{Joints, Mode, SimConfig};
use crate::validator::{FallRule, Outcome, Validator};

imuflow_graph::stage_params! {
    /// The validation stage's parameters, and so [`SimConfig::default`] and [`FallRule::default`].
    pub struct ValidationParams {
        /// torques: root unactuated, the body must balance on its contacts; residual: a weak root
        /// PD helps and its force is reported
        mode: Mode = "torques", choice(&Mode::NAMES);
        stature_m: f64 = use STATURE_PARAM;
        mass_kg: f64 = use MASS_PARAM;
        // 900: ω = 30 rad/s (about 4.8 Hz); 60: critically damped at that ω.
        /// joint stiffness per unit driven inertia (1/s²)
        kp: f64 = 900, float(0.0, 1e5);
        /// joint damping per unit driven inertia (1/s)
        kd: f64 = 60, float(0.1, 1e4);
        // A strong adult's hip or knee: about 3-4 N·m/kg.
        /// joint torque limit per kg of body mass (N·m/kg)
        max_torque_nm_per_kg: f64 = 4, float(0.0, 100.0);
        /// extra swing-knee bend per shank length the simulated swing foot hangs below the
        /// estimate's (rad/rad)
        clearance_gain: f64 = 4, float(0.0, 20.0);
        /// pelvis-orientation feedback through the stance hips, per unit root inertia (1/s²)
        balance_kp: f64 = 400, float(0.0, 1e5);
        /// its damping (1/s)
        balance_kd: f64 = 40, float(0.0, 1e4);
        /// foot placement: swing foot shift per metre the simulated centre of mass is ahead of the
        /// estimate's (relative to the stance foot)
        placement_kp: f64 = 1, float(0.0, 10.0);
        /// foot placement: swing foot shift per m/s the simulated centre of mass is faster (s)
        placement_kv: f64 = 0.3, float(0.0, 10.0);
        foot_pitch_deg: f64 = use FOOT_PITCH_PARAM;
        /// residual mode: root PD stiffness per unit mass / root inertia (1/s²)
        residual_kp: f64 = 100, float(0.0, 1e5);
        /// residual mode: root PD damping (1/s)
        residual_kd: f64 = 20, float(0.0, 1e4);
        /// friction coefficient body-floor
        friction: f64 = 0.8, float(0.0, 5.0);
        /// physics steps per frame
        substeps: usize = 4, int(1, 64);
        /// how the simulated links are joined: a rigid body each, held by impulse joints (the
        /// default: about 2.5x faster), or one rapier multibody in reduced coordinates (joints
        /// exact, dense mass matrix)
        joints: Joints = "impulse", choice(&Joints::NAMES);
        /// rapier solver iterations per physics step (with a multibody each recomputes its mass
        /// matrix)
        solver_iterations: Option<usize> = computed("4 (impulse), 1 (multibody)"), int(1, 16);
        /// Gauss-Seidel sweeps per solver iteration
        solver_sweeps: Option<usize> = computed("12 (impulse), 4 (multibody)"), int(1, 64);
        /// fallen when the simulated pelvis is below this fraction of the estimate's pelvis height
        fall_height_fraction: f64 = 0.6, float(0.0, 1.0);
        /// fallen when the simulated trunk tilts this far from the estimate's (degrees)
        fall_tilt_deg: f64 = 45, float(0.0, 180.0);
        /// re-anchor to the estimate (a resync, not a fall) past this horizontal root drift (m)
        max_drift_m: f64 = 0.5, float(0.0, 100.0);
    }
}

impl ValidationParams {
    /// The simulation's settings; the solver's, where not set, those that suit the joints
    /// ([`Joints::solver_settings`]).
    pub fn sim_config(&self) -> SimConfig {
        let (iterations, sweeps) = self.joints.solver_settings();
        SimConfig {
            mode: self.mode,
            kp: self.kp,
            kd: self.kd,
            max_torque_nm_per_kg: self.max_torque_nm_per_kg,
            balance_kp: self.balance_kp,
            balance_kd: self.balance_kd,
            placement_kp: self.placement_kp,
            placement_kv: self.placement_kv,
            residual_kp: self.residual_kp,
            residual_kd: self.residual_kd,
            clearance_gain: self.clearance_gain,
            friction: self.friction,
            substeps: self.substeps,
            solver_iterations: self.solver_iterations.unwrap_or(iterations),
            solver_sweeps: self.solver_sweeps.unwrap_or(sweeps),
            joints: self.joints,
        }
    }

    /// When the simulated body counts as fallen.
    pub fn fall_rule(&self) -> FallRule {
        FallRule {
            pelvis_height_fraction: self.fall_height_fraction,
            trunk_tilt_deg: self.fall_tilt_deg,
            max_drift_m: self.max_drift_m,
        }
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "validation",
    role: Role::Transform,
    summary: "independent rapier3d simulation: joint motors track the estimate on a floor with friction; scores plausibility",
    inputs: InputsSpec::Fixed(&[
        PortSpec {
            name: "motion",
            frame: FrameType::Motion,
            required: true,
            doc: "the motion to check (an optimizer's estimate, or an imu-source's truth)",
        },
        PortSpec {
            name: "contacts",
            frame: FrameType::Contact,
            required: false,
            doc: "the estimate's contacts, compared with the simulated feet in the summary",
        },
    ]),
    outputs: &[
        PortSpec {
            name: "validation",
            frame: FrameType::Validation,
            required: false,
            doc: "per-frame scores: tracking error, foot skate, penetration, falls, residual force, contact forces",
        },
        PortSpec {
            name: "sim",
            frame: FrameType::Motion,
            required: false,
            doc: "the simulated body's pose (q, qdot; floor forces as ground_reaction_force_n)",
        },
    ],
    params: ValidationParams::SPECS,
};

/// The validator a stage's parameters ask for.
pub fn build(stage: &str, params: &ValidationParams) -> anyhow::Result<Validator> {
    let body = subject_body(params.stature_m, params.mass_kg)
        .with_context(|| format!("stage '{stage}': body model"))?;
    let model = SimModel::with_foot_pitch(&body, params.foot_pitch_deg);
    Ok(Validator::new(
        model,
        params.sim_config(),
        params.fall_rule(),
    ))
}

/// Seconds between two frames from their capture times, or the graph's nominal period when the
/// times say nothing usable (first frame, repeated or out-of-order stamps, gaps over half a second).
fn frame_dt(previous_ns: Option<u64>, capture_ns: u64, nominal_s: f64) -> f64 {
    match previous_ns {
        Some(prev) if capture_ns > prev && capture_ns - prev < 500_000_000 => {
            (capture_ns - prev) as f64 * 1e-9
        }
        _ => nominal_s,
    }
}

/// Runs the validation stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let mut validator = build(&stage, &ValidationParams::from_params(ctx.params()))?;
    let residual = validator.config().mode == Mode::Residual;
    let nominal_s = 1.0 / ctx.graph().rate_hz;
    let motion = ctx.input::<MotionFrame>("motion")?;
    let contacts_in = if ctx.input_names().iter().any(|n| n == "contacts") {
        Some(ctx.input::<ContactFrame>("contacts")?)
    } else {
        None
    };
    let mut validation_out = ctx.output::<ValidationFrame>("validation")?;
    let mut sim_out = ctx.output::<MotionFrame>("sim")?;
    if !ctx.ready()? {
        return Ok(());
    }
    let mut previous_ns = None;
    let mut unusable = 0u64;
    let mut agreement = ContactAgreement::default();
    while let Some(step) = ctx.next()? {
        let mut header = step.header();
        let frame = ctx.get(&motion);
        if step.flags & flags::CALIBRATING != 0 {
            validator.clear();
        }
        let pose = if step.flags & (flags::INVALID | flags::CALIBRATING) != 0 {
            None
        } else {
            match Pose::from_wire(&frame.local_pose_wxyz, &frame.root_position_m) {
                Ok(p) => Some(p),
                Err(why) => {
                    unusable += 1;
                    tracing::warn!(stage, seq = step.seq, "motion frame unusable: {why}");
                    None
                }
            }
        };
        if pose.is_none() {
            header.flags |= flags::INVALID;
        }
        let dt = frame_dt(previous_ns, step.capture_ns, nominal_s);
        previous_ns = Some(step.capture_ns);
        let outcome = if step.flags & flags::CALIBRATING != 0 {
            None
        } else {
            validator.frame(pose.as_ref(), dt)
        };
        let Some(outcome) = outcome else {
            // Nothing to simulate yet: empty outputs, flagged INVALID.
            header.flags |= flags::INVALID;
            validation_out.publish(header, |_| {})?;
            sim_out.publish(header, |_| {})?;
            continue;
        };
        if outcome.fell {
            tracing::warn!(
                stage,
                seq = step.seq,
                "balance lost: the simulated body fell and was reset to the estimate"
            );
        }
        if let Some(input) = &contacts_in {
            agreement.add(ctx.get(input), outcome.contact_mask);
        }
        let falls = validator.stats.falls as u32;
        let resyncs = validator.stats.resyncs as u32;
        validation_out.publish(header, |out| {
            write_validation(&outcome, falls, resyncs, out)
        })?;
        sim_out.publish(header, |out| write_sim(&outcome, out))?;
    }
    let mut line = validator.stats.summary_line(residual);
    if let Some(share) = agreement.share() {
        line += &format!(
            ", foot contacts agree with the estimate's on {:.1} %",
            100.0 * share
        );
    }
    if unusable > 0 {
        line += &format!(", {unusable} unusable motion frames");
    }
    let line = format!("validation ({}): {line}", Mode::NAMES[residual as usize]);
    eprintln!("{stage}: {line}");
    // The same line under `imuflow run`'s summary table.
    ctx.set_summary_detail(line);
    ctx.finish(&mut [&mut validation_out, &mut sim_out])?;
    Ok(())
}

fn write_validation(outcome: &Outcome, falls: u32, resyncs: u32, out: &mut ValidationFrame) {
    let s = &outcome.score;
    out.tracking_error_m = s.tracking_error_m as f32;
    out.pose_error_m = s.pose_error_m as f32;
    out.root_error_m = s.root_error_m as f32;
    out.foot_skate_mps = s.foot_skate_mps.unwrap_or(0.0) as f32;
    out.penetration_m = s.penetration_m as f32;
    out.balance_lost = u32::from(outcome.fell);
    out.falls = falls;
    out.resyncs = resyncs;
    out.sim_contact_mask = outcome.contact_mask;
    out.support_gap_m = outcome.support.gap_m as f32;
    out.support = outcome.support.state as u32;
    let f = &outcome.forces;
    out.residual_root_force_n = f.residual_force_n.cast::<f32>().into();
    out.residual_root_torque_nm = f.residual_torque_nm.cast::<f32>().into();
    out.sim_root_position_m = outcome.state.pose.root_in_world_m.cast::<f32>().into();
    for (o, force) in out.sim_contact_force_n.iter_mut().zip(&f.contact_force_n) {
        *o = force.cast::<f32>().into();
    }
}

/// The simulated body as a MotionFrame: pose, q (root position, per-joint rotation vectors),
/// the root's linear velocity in qdot, floor forces as ground-reaction forces. Joint torques are
/// not reported (rapier does not expose its motor impulses), so `tau` stays zero.
fn write_sim(outcome: &Outcome, out: &mut MotionFrame) {
    let state = &outcome.state;
    for (o, r) in out
        .local_pose_wxyz
        .iter_mut()
        .zip(&state.pose.parent_from_joint)
    {
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(r);
        *o = [q.w as f32, q.i as f32, q.j as f32, q.k as f32];
    }
    out.root_position_m = state.pose.root_in_world_m.cast::<f32>().into();
    let mut q = [0.0f32; NUM_DOFS];
    q[..3].copy_from_slice(&out.root_position_m);
    for (j, r) in state.pose.parent_from_joint.iter().enumerate() {
        let v = axis_angle_from_rotation(r);
        q[3 + 3 * j..6 + 3 * j].copy_from_slice(&[v.x as f32, v.y as f32, v.z as f32]);
    }
    out.q = q;
    let root_velocity = state.joint_velocity_mps[JointId::ROOT.index()];
    out.qdot[..3].copy_from_slice(&[
        root_velocity.x as f32,
        root_velocity.y as f32,
        root_velocity.z as f32,
    ]);
    for (o, force) in out
        .ground_reaction_force_n
        .iter_mut()
        .zip(&outcome.forces.contact_force_n)
    {
        *o = force.cast::<f32>().into();
    }
    out.contact_mask = outcome.contact_mask;
    out.residual_root_force_n = outcome.forces.residual_force_n.cast::<f32>().into();
}

/// How often the estimate's foot contacts match the simulated feet.
#[derive(Default)]
struct ContactAgreement {
    frames: u64,
    agreeing: u64,
}

impl ContactAgreement {
    fn add(&mut self, estimate: &ContactFrame, sim_mask: u32) {
        let feet = (1 << JointId::LEFT_FOOT.index()) | (1 << JointId::RIGHT_FOOT.index());
        self.frames += 1;
        self.agreeing += u64::from(estimate.contact_mask & feet == sim_mask & feet);
    }

    fn share(&self) -> Option<f64> {
        (self.frames > 0).then(|| self.agreeing as f64 / self.frames as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<ValidationParams>().unwrap();
    }

    /// "4 (impulse), 1 (multibody)": what each joint kind's solver settings are.
    #[test]
    fn the_solver_defaults_texts_are_the_joints_settings() {
        let read = |name: &str, joints: Joints| -> usize {
            let text = SPEC.param(name).unwrap().default;
            let wanted = format!("({})", Joints::NAMES[joints as usize]);
            let part = text.split(", ").find(|p| p.ends_with(&wanted)).unwrap();
            part.split_whitespace().next().unwrap().parse().unwrap()
        };
        for joints in [Joints::Multibody, Joints::Impulse] {
            let (iterations, sweeps) = joints.solver_settings();
            assert_eq!(read("solver_iterations", joints), iterations, "{joints:?}");
            assert_eq!(read("solver_sweeps", joints), sweeps, "{joints:?}");
            let config = ValidationParams {
                joints,
                ..ValidationParams::default()
            }
            .sim_config();
            assert_eq!(config, SimConfig::for_joints(joints));
            assert_eq!(
                (config.solver_iterations, config.solver_sweeps),
                (iterations, sweeps)
            );
        }
        assert_eq!(SimConfig::default(), SimConfig::for_joints(Joints::Impulse));
    }

    #[test]
    fn frame_dt_uses_capture_times_when_they_make_sense() {
        let nominal = 1.0 / 60.0;
        assert_eq!(frame_dt(None, 5, nominal), nominal);
        assert!((frame_dt(Some(0), 20_000_000, nominal) - 0.02).abs() < 1e-12);
        // Repeated, backwards or far-apart stamps fall back to the nominal period.
        assert_eq!(frame_dt(Some(10), 10, nominal), nominal);
        assert_eq!(frame_dt(Some(10), 5, nominal), nominal);
        assert_eq!(frame_dt(Some(0), 2_000_000_000, nominal), nominal);
    }
}
