//! imuflow's side of `scripts/bench/authors_stack.py`: PIP's networks and PIP's QP on the frames
//! of one recording, timed per frame, and the per-frame data the script needs to run the same
//! computation through the authors' stack (onnxruntime and quadprog).
//!
//! ```sh
//! cargo build --release -p imuflow-eval --example authors_stack_frames
//! target/release/examples/authors_stack_frames DIR models/pip.safetensors
//! ```
//!
//! `DIR` holds three files of frames as they travelled (each frame's bytes, one after another,
//! no END_OF_STREAM frame), which the script cuts out of a recording of `configs/pip.toml`:
//! `body_imu.bin` (`calib.body_imu`), `kinematics.bin` (`kin.kinematics`) and `contacts.bin`
//! (`contact.contacts`). Written into `DIR`:
//!
//! - `meta.json`: sizes, the start pose, rnn1's learned-initialization input, PIP's QP constants
//!   (`PipConfig::default()`, what the `optimizer` stage runs), imuflow's per-frame times;
//! - `net_input.f32`: per networks' frame the 72 PIP inputs as the kinematics stage computes them;
//! - `net_output.f64`: per networks' frame what the kinematics stage's `Streamer` outputs with
//!   `sensor_bones = "network"`, `limb_joints = "free"` (the papers' pose): joint positions (24×3,
//!   M), joint velocities (24×3, M), foot-contact probabilities (2), local pose (24 row-major 3×3);
//! - `qp.f64`: per frame the optimizer solved a QP for, its ingredients at the state the
//!   optimizer stood at (dynamics `M`, `h`, Jacobians, velocities, `J̇·v`, the PD errors, contact
//!   points, foot bounds) and imuflow's solution (`v̇`, contact forces, `τ`); the record layout is
//!   [`write_qp_record`]'s.
//!
//! With a third argument `--timing-only` only the times are measured and `meta.json` written (the
//! script times imuflow before and after the authors' stack).
//!
//! The times: the kinematics stage's own `Streamer` with the stage's defaults (measured bones,
//! anatomical limbs), per frame the whole step and the networks' part of it; the optimizer's `Pip`
//! per frame, the whole step (contacts, dynamics, QP set-up and solve, integration) and the QP's
//! solve alone (`SolveStats::solve_time_s`). Each after a warm-up of 100 frames, in this process,
//! one frame after the other.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail, ensure};
use imuflow_body::dynamics::{DofVector, DynamicsData, NUM_DOFS, PointJacobian};
use imuflow_body::kinematics::{FkData, forward_kinematics, local_to_global_rotations};
use imuflow_body::rotation::axis_angle_from_rotation;
use imuflow_body::skeleton::LEAF_JOINTS;
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS};
use imuflow_contact::ContactSet;
use imuflow_contact::pip::FEET;
use imuflow_contact::subject::{MASS_PARAM, STATURE_PARAM, subject_body};
use imuflow_graph::frames::{
    BodyImuFrame, ContactFrame, Frame, KinematicsFrame, flags, frame_from_bytes,
};
use imuflow_kinematics::features::{HeldSamples, ImuInput, PIP_INPUT, pip_input};
use imuflow_kinematics::infer::{LimbJoints, SensorBones, StartPose, Streamer};
use imuflow_kinematics::weights::Weights;
use imuflow_optimizer::Method as _;
use imuflow_optimizer::pip::{
    POSITION_PD_JOINTS, Pip, PipConfig, orientation_rows, orientation_target,
};
use imuflow_optimizer::{MotionEstimate, PhysicsBody, Reference};
use nalgebra::{Rotation3, Vector3};

/// Untimed frames before each timed pass.
const WARMUP_FRAMES: usize = 100;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let (Some(dir), Some(weights)) = (args.next(), args.next()) else {
        bail!("usage: authors_stack_frames DIR WEIGHTS [--timing-only] (see the file's docs)");
    };
    let dump = match args.next().as_deref() {
        None => true,
        Some("--timing-only") => false,
        Some(other) => bail!("unknown argument '{other}' (--timing-only)"),
    };
    let dir = PathBuf::from(dir);
    let weights = PathBuf::from(weights);

    let body_imu: Vec<BodyImuFrame> = read_frames(&dir.join("body_imu.bin"))?;
    let kinematics: Vec<KinematicsFrame> = read_frames(&dir.join("kinematics.bin"))?;
    let contacts: Vec<ContactFrame> = read_frames(&dir.join("contacts.bin"))?;

    let nets = networks(&dir, &weights, &body_imu, dump)?;
    let physics = physics(&dir, &kinematics, &contacts, dump)?;

    let meta = format!(
        "{{\n\"format\": \"imuflow-authors-stack-frames/1\",\n\"frames\": {},\n\"networks\": {nets},\n\"physics\": {physics}\n}}\n",
        body_imu.len()
    );
    std::fs::write(dir.join("meta.json"), meta)?;
    Ok(())
}

/// A JSON list of numbers (this example writes its small JSON by hand).
fn list<T: std::fmt::Display>(values: impl IntoIterator<Item = T>) -> String {
    let items: Vec<String> = values.into_iter().map(|v| v.to_string()).collect();
    format!("[{}]", items.join(", "))
}

/// Every frame of a file of frames of type `T` laid end to end.
fn read_frames<T: Frame>(path: &Path) -> anyhow::Result<Vec<T>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let size = std::mem::size_of::<T>();
    ensure!(
        bytes.len() % size == 0,
        "{}: {} bytes is not a whole number of {} ({size} bytes)",
        path.display(),
        bytes.len(),
        T::layout().type_name
    );
    Ok(bytes
        .chunks_exact(size)
        .map(|chunk| frame_from_bytes::<T>(chunk).expect("sized chunk"))
        .collect())
}

/// Writes each value's little-endian bytes, one after another (numpy's `fromfile` reads them).
fn write_le<const N: usize>(
    path: &Path,
    values: impl IntoIterator<Item = [u8; N]>,
) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    for bytes in values {
        f.write_all(&bytes)?;
    }
    f.flush()?;
    Ok(())
}

fn row_major(r: &Rotation3<f64>) -> [f64; 9] {
    std::array::from_fn(|k| r[(k / 3, k % 3)])
}

/// The networks: inputs, the papers'-pose outputs for the check, imuflow's times.
fn networks(
    dir: &Path,
    weights_path: &Path,
    frames: &[BodyImuFrame],
    dump: bool,
) -> anyhow::Result<String> {
    // The frames the kinematics stage feeds to the networks (calibrated, every sensor seen).
    let mut inputs: Vec<(usize, ImuInput)> = Vec::new();
    let mut held = HeldSamples::default();
    for (i, frame) in frames.iter().enumerate() {
        let complete = held.update(frame);
        if frame.header.flags & flags::CALIBRATING == 0 && complete {
            inputs.push((i, held.input));
        }
    }
    ensure!(
        !inputs.is_empty(),
        "no calibrated frame to run the networks on"
    );
    // The stage's `start_pose = "auto"`: the pose the first calibrated frame shows.
    let start = StartPose::shown_by(&inputs[0].1);

    if dump {
        let mut x: Vec<f32> = Vec::with_capacity(inputs.len() * PIP_INPUT);
        for (_, input) in &inputs {
            let mut v = [0.0; PIP_INPUT];
            pip_input(input, &mut v);
            x.extend_from_slice(&v);
        }
        write_le(
            &dir.join("net_input.f32"),
            x.iter().map(|v| v.to_le_bytes()),
        )?;
    }

    // rnn1's learned initialization input (the Streamer's): the start pose's leaf joints relative
    // to the root, the root at identity, on the body the weights were trained on.
    let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
    let mut pose = start.pose();
    pose.parent_from_joint[0] = Rotation3::identity();
    pose.root_in_world_m = Vector3::zeros();
    let mut fk = FkData::new();
    forward_kinematics(&body.skeleton, &pose, &mut fk);
    let leaf_init: Vec<f64> = LEAF_JOINTS
        .iter()
        .flat_map(|&j| {
            let p = fk.position(j) - fk.position(JointId::ROOT);
            [p.x as f32 as f64, p.y as f32 as f64, p.z as f32 as f64]
        })
        .collect();

    let load = || Weights::load(weights_path, imuflow_kinematics::Method::Pip);

    // The papers' pose (no sensor bones, free limbs): what the networks alone give.
    if dump {
        let mut check = Streamer::new(load()?, start.pose())?;
        check.set_sensor_bones(SensorBones::Network);
        check.set_limb_joints(LimbJoints::Free);
        let mut out: Vec<f64> = Vec::with_capacity(inputs.len() * (72 + 72 + 2 + 216));
        for (_, input) in &inputs {
            let e = check.step(input)?;
            out.extend(e.joint_position.iter().flat_map(|v| [v.x, v.y, v.z]));
            out.extend(e.joint_velocity.iter().flat_map(|v| [v.x, v.y, v.z]));
            out.extend(e.foot_contact);
            out.extend(e.pose.iter().flat_map(row_major));
        }
        write_le(
            &dir.join("net_output.f64"),
            out.iter().map(|v| v.to_le_bytes()),
        )?;
    }

    // The stage's own configuration, timed.
    let mut streamer = Streamer::new(load()?, start.pose())?;
    for (_, input) in inputs.iter().take(WARMUP_FRAMES) {
        std::hint::black_box(streamer.step(input)?);
    }
    streamer.set_start(start.pose());
    streamer.reset();
    let (mut step_us, mut nets_us) = (Vec::new(), Vec::new());
    for (_, input) in &inputs {
        let nets0 = streamer.nets_time();
        let t0 = Instant::now();
        std::hint::black_box(streamer.step(input)?);
        step_us.push(t0.elapsed().as_secs_f64() * 1e6);
        nets_us.push((streamer.nets_time() - nets0).as_secs_f64() * 1e6);
    }

    Ok(format!(
        "{{\"frames\": {}, \"frame_index\": {}, \"start_pose\": \"{start:?}\", \
         \"rnn1_init_input\": {}, \"rnn4_init_input\": {}, \
         \"imuflow_step_us\": {}, \"imuflow_nets_us\": {}}}",
        inputs.len(),
        list(inputs.iter().map(|(i, _)| *i)),
        list(&leaf_init),
        list([0.0; 72]),
        list(&step_us),
        list(&nets_us),
    ))
}

/// Sizes of one QP record (see [`write_qp_record`]).
const JAC: usize = 3 * NUM_DOFS;

/// One record of `qp.f64`, all f64:
/// `[frame, n_points, n_bodies, 0]`, `M` (75×75 row-major), `h` (75), `v` (75),
/// the rotation PD's tangent-space errors `log(R_curᵀ·R_ref)` per joint in joint order (72),
/// per position-PD joint (20, `POSITION_PD_JOINTS`): `J` (3×75 row-major), point velocity (3),
/// `J̇·v` (3), the networks' velocity (3);
/// per bone row (10: the six sensor bones, then the upper legs and arms): angular `J` (3×75),
/// its target acceleration (3), its weight (1);
/// per foot (2): `J` (3×75), velocity (3), ground-point height (1), contact probability (1);
/// per contact point (`n_points`): `J` (3×75), height above its surface (1);
/// per other contact body (`n_bodies`): `J` (3×75), velocity (3);
/// imuflow's solution: `v̇` (75), per point its force (3), `τ` (75), then the solve's interior-point
/// iterations, variables and constraint rows (3).
#[allow(clippy::too_many_arguments)]
fn write_qp_record(
    out: &mut Vec<f64>,
    frame: usize,
    physics: &PhysicsBody,
    config: &PipConfig,
    data: &mut DynamicsData,
    pose: &imuflow_body::Pose,
    reference: &Reference,
    contacts: &ContactSet,
) {
    let model = &physics.model;
    let points = contacts.points();
    let bodies: Vec<JointId> = JointId::all()
        .filter(|&j| contacts.contains(j) && !FEET.contains(&j))
        .collect();
    out.extend([frame as f64, points.len() as f64, bodies.len() as f64, 0.0]);
    let m = *data.mass_matrix(model);
    for r in 0..NUM_DOFS {
        out.extend(m.row(r).iter());
    }
    out.extend(data.bias_forces(model).iter());
    let v = *data.velocity();
    out.extend(v.iter());
    for j in JointId::all() {
        let rel = pose.parent_from_joint[j.index()].transpose() * reference.rotation(j.index());
        out.extend(axis_angle_from_rotation(&rel).iter());
    }
    let mut jac = PointJacobian::zeros();
    let push_jac = |out: &mut Vec<f64>, jac: &PointJacobian| {
        for r in 0..3 {
            out.extend(jac.row(r).iter());
        }
    };
    for &j in &POSITION_PD_JOINTS {
        data.point_jacobian(j, &Vector3::zeros(), &mut jac);
        push_jac(out, &jac);
        out.extend(data.point_velocity(j, &Vector3::zeros()).iter());
        out.extend(data.point_jdot_v(j, &Vector3::zeros()).iter());
        out.extend(reference.joint_velocity_mps[j.index()].iter());
    }
    // imuflow's bone rows (the optimizer's `coeff_sensor_bone`, `coeff_limb_bone`), their target
    // as stages/optimizer/src/pip/qp.rs forms it.
    let mut reference_world = [Rotation3::identity(); NUM_JOINTS];
    local_to_global_rotations(&reference.pose.parent_from_joint, &mut reference_world);
    for (j, weight) in orientation_rows(config) {
        let want = orientation_target(data, j, &reference_world[j.index()], config);
        data.angular_jacobian(j, &mut jac);
        push_jac(out, &jac);
        out.extend(want.iter());
        out.push(weight);
    }
    for (k, &foot) in FEET.iter().enumerate() {
        data.point_jacobian(foot, &Vector3::zeros(), &mut jac);
        push_jac(out, &jac);
        out.extend(data.point_velocity(foot, &Vector3::zeros()).iter());
        out.push(physics.geometry.height_above(
            foot,
            &data.fk().joint_in_world_m[foot.index()],
            config.contact.surface_height_m,
        ));
        out.push(reference.foot_contact_prob[k]);
    }
    for p in points {
        let i = p.joint.index();
        let fk = data.fk();
        let local = fk.world_from_joint[i].inverse() * (p.position - fk.joint_in_world_m[i]);
        data.point_jacobian(p.joint, &local, &mut jac);
        push_jac(out, &jac);
        out.push(p.position.y - contacts.surface_height_m[i]);
    }
    for &j in &bodies {
        data.point_jacobian(j, &Vector3::zeros(), &mut jac);
        push_jac(out, &jac);
        out.extend(data.point_velocity(j, &Vector3::zeros()).iter());
    }
}

/// PIP's QP: imuflow's times on the frames, and the per-frame data for quadprog.
fn physics(
    dir: &Path,
    kinematics: &[KinematicsFrame],
    contact_frames: &[ContactFrame],
    dump: bool,
) -> anyhow::Result<String> {
    ensure!(
        kinematics.len() == contact_frames.len(),
        "{} kinematics frames but {} contact frames",
        kinematics.len(),
        contact_frames.len()
    );
    let physics = PhysicsBody::from_body(subject_body(STATURE_PARAM.default, MASS_PARAM.default)?);
    let config = PipConfig::default();
    // The optimizer stage's inputs, as it decodes them (stages/optimizer/src/stage.rs).
    let mut steps: Vec<(usize, Reference, ContactSet)> = Vec::new();
    for (i, (kin, contact)) in kinematics.iter().zip(contact_frames).enumerate() {
        ensure!(
            kin.header.seq == contact.header.seq,
            "frame {i}: kinematics seq {} but contacts seq {}",
            kin.header.seq,
            contact.header.seq
        );
        if kin.header.flags & flags::CALIBRATING != 0 {
            ensure!(steps.is_empty(), "frame {i}: calibrating after the start");
            continue;
        }
        let reference =
            Reference::read(kin).map_err(|e| anyhow::anyhow!("kinematics frame {i}: {e}"))?;
        let contacts =
            ContactSet::read(contact).map_err(|e| anyhow::anyhow!("contact frame {i}: {e}"))?;
        steps.push((i, reference, contacts));
    }
    ensure!(
        steps.len() > 1,
        "fewer than two frames to step the physics on"
    );

    // Timed: the optimizer's Pip as the stage steps it.
    let mut pip = Pip::new(physics.clone(), config.clone())?;
    let mut estimate = MotionEstimate::default();
    for (_, reference, contacts) in steps.iter().take(WARMUP_FRAMES) {
        pip.step(reference, Some(contacts), &mut estimate)?;
    }
    pip.reset();
    let (mut step_us, mut solve_us, mut iterations) = (Vec::new(), Vec::new(), Vec::new());
    let mut fallbacks = 0;
    for (k, (_, reference, contacts)) in steps.iter().enumerate() {
        let t0 = Instant::now();
        let report = pip.step(reference, Some(contacts), &mut estimate)?;
        let us = t0.elapsed().as_secs_f64() * 1e6;
        fallbacks += usize::from(report.fallback);
        // The first frame places the reference on the floor: no QP.
        if k > 0 {
            step_us.push(us);
            if let Some(s) = pip.last_solve() {
                solve_us.push(s.solve_time_s * 1e6);
                iterations.push(s.iterations);
            }
        }
    }

    // Untimed: the same steps again, each QP's ingredients written before it is solved (none
    // with `--timing-only`).
    let to_dump: &[(usize, Reference, ContactSet)] = if dump { &steps } else { &[] };
    let mut pip = Pip::new(physics.clone(), config.clone())?;
    let mut data = DynamicsData::new();
    let mut records: Vec<f64> = Vec::new();
    let mut solved_frames = 0usize;
    for (k, (i, reference, contacts)) in to_dump.iter().enumerate() {
        if k == 0 {
            pip.step(reference, Some(contacts), &mut estimate)?;
            continue;
        }
        let (pose, v) = pip.state();
        let (pose, v) = (pose.clone(), *v);
        data.set_state(&physics.model, &pose, &v);
        let start = records.len();
        write_qp_record(
            &mut records,
            *i,
            &physics,
            &config,
            &mut data,
            &pose,
            reference,
            contacts,
        );
        let report = pip.step(reference, Some(contacts), &mut estimate)?;
        if report.fallback {
            // The degraded estimate: no QP solution to compare with.
            records.truncate(start);
            continue;
        }
        let (_, v_new) = pip.state();
        let vdot: DofVector = (v_new - v) / config.dt;
        records.extend(vdot.iter());
        for p in pip.contacts().points() {
            records.extend(p.force.iter());
        }
        records.extend(estimate.tau.iter());
        let stats = pip.last_solve().unwrap_or_default();
        records.extend([
            f64::from(stats.iterations),
            stats.variables as f64,
            stats.constraints as f64,
        ]);
        solved_frames += 1;
    }
    if dump {
        write_le(&dir.join("qp.f64"), records.iter().map(|v| v.to_le_bytes()))?;
    }

    let c = &config;
    let constants = [
        ("kp_rotation", c.kp_rotation),
        ("kd_rotation", c.kd_rotation),
        ("kp_position", c.kp_position),
        ("kd_position", c.kd_position),
        ("friction", c.friction),
        ("dt", c.dt),
        ("coeff_joint_velocity", c.coeff_joint_velocity),
        ("coeff_lambda", c.coeff_lambda),
        ("lambda_min_height_m", c.lambda_min_height_m),
        ("coeff_root_virtual", c.coeff_root_virtual),
        ("coeff_joint_torque", c.coeff_joint_torque),
        ("foot_lock_probability", c.foot_lock_probability),
        ("contact_body_slide_mps", c.contact_body_slide_mps),
        ("contact_body_rise_mps", c.contact_body_rise_mps),
        ("fallback_norm", c.fallback_norm),
    ]
    .map(|(name, value)| format!("\"{name}\": {value:e}"))
    .join(", ");
    Ok(format!(
        "{{\"steps\": {}, \"qp_frames\": {solved_frames}, \"fallbacks\": {fallbacks}, \
         \"dofs\": {NUM_DOFS}, \"jacobian_values\": {JAC}, \"position_pd_joints\": {}, \
         \"config\": {{{constants}}}, \"imuflow_step_us\": {}, \"imuflow_solve_us\": {}, \
         \"imuflow_iterations\": {}}}",
        steps.len(),
        list(POSITION_PD_JOINTS.iter().map(|j| j.index())),
        list(&step_us),
        list(&solve_us),
        list(&iterations),
    ))
}
