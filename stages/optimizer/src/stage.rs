//! The `optimizer` stage: kinematics (and, for PIP, contacts) in, motion out.
//!
//! - Frames flagged CALIBRATING, and frames before the first usable kinematics frame, go out as the
//!   reference pose standing on the floor, flagged INVALID; the method starts at the first frame
//!   that is neither.
//! - A kinematics frame that cannot be decoded (non-finite values) repeats the previous estimate,
//!   flagged INVALID, and is counted.
//! - Solver fallbacks are counted, logged, and flag their frames INVALID; the totals are printed
//!   when the stream ends.

use anyhow::{Context, bail};
use imuflow_contact::ContactSet;
use imuflow_contact::subject::{MASS_PARAM, STATURE_PARAM, subject_body};
use imuflow_graph::frames::{ContactFrame, KinematicsFrame, MotionFrame, flags};
use imuflow_graph::spec::{InputsSpec, ParamSpec, ParamType, PortSpec, Role, StageSpec};
use imuflow_graph::stage::Params;
use imuflow_graph::{FrameType, StageContext};

use crate::estimate::{FEET, place_on_floor};
use crate::globalpose::{GlobalPose, GlobalPoseConfig};
use crate::integrate::Integrate;
use crate::pip::{Pip, PipConfig};
use crate::{Method, MotionEstimate, PhysicsBody, Reference, Terrain};

/// The methods, as the `method` parameter names them.
pub const METHODS: [&str; 3] = ["integrate", "pip", "globalpose"];

pub const SPEC: StageSpec = StageSpec {
    kind: "optimizer",
    role: Role::Transform,
    summary: "physics: PIP dual-PD QP, GlobalPose pre-/re-tracking, or no-physics root integration",
    inputs: InputsSpec::Fixed(&[
        PortSpec {
            name: "kin",
            frame: FrameType::Kinematics,
            required: true,
            doc: "the kinematics networks' estimate",
        },
        PortSpec {
            name: "contacts",
            frame: FrameType::Contact,
            required: false,
            doc: "contacts for this frame (method pip: the contact stage's PIP rule; without it pip applies the rule itself)",
        },
    ]),
    outputs: &[
        PortSpec {
            name: "motion",
            frame: FrameType::Motion,
            required: false,
            doc: "pose with global translation, q/qdot/tau, ground-reaction forces, contacts",
        },
        PortSpec {
            name: "contacts",
            frame: FrameType::Contact,
            required: false,
            doc: "the contacts the method used, with per-point forces (globalpose: its own estimate)",
        },
    ],
    params: &[
        ParamSpec {
            name: "method",
            ty: ParamType::Choice(&METHODS),
            required: false,
            default: "integrate",
            doc: "integrate (no physics), pip (CVPR 2022 QP) or globalpose (SIGGRAPH 2025 double tracking)",
        },
        STATURE_PARAM,
        MASS_PARAM,
        ParamSpec::float(
            "kp_rotation",
            0.0,
            1e6,
            "pip 2400, globalpose 3600",
            "joint-rotation PD stiffness (1/s²)",
        ),
        ParamSpec::float(
            "kd_rotation",
            0.0,
            1e4,
            "60",
            "joint-rotation PD damping (1/s)",
        ),
        ParamSpec::float(
            "kp_position",
            0.0,
            1e6,
            "3600",
            "joint-position PD stiffness (1/s²)",
        ),
        ParamSpec::float(
            "kd_position",
            0.0,
            1e4,
            "60",
            "joint-position PD damping (1/s)",
        ),
        ParamSpec::float(
            "friction",
            0.0,
            5.0,
            "pip 0.6, globalpose 0.7",
            "friction coefficient μ of the contact cones",
        ),
        ParamSpec::float(
            "sensor_bone_weight",
            0.0,
            1e3,
            "1",
            "pip: weight of the world-orientation PD on the six instrumented bones (0: PIP's own cost)",
        ),
        ParamSpec::float(
            "limb_bone_weight",
            0.0,
            1e3,
            "1",
            "pip: weight of the same PD on the upper legs and upper arms, which the kinematics stage sets from the sensors below them (0: PIP's own cost)",
        ),
        ParamSpec {
            name: "terrain",
            ty: ParamType::Choice(&Terrain::NAMES),
            required: false,
            default: "flat",
            doc: "integrate and globalpose: flat (stationary feet pulled to the floor from any height: no vertical drift) or proxy (GlobalPose's proxy surfaces: steps and seats, but a biased network can ratchet the root up)",
        },
    ],
};

/// Builds the method a stage's parameters ask for.
fn build(stage: &str, params: &Params) -> anyhow::Result<(String, Box<dyn Method>, PhysicsBody)> {
    let name = params.str("method").unwrap_or("integrate").to_owned();
    let physics = PhysicsBody::from_body(
        subject_body(params).with_context(|| format!("stage '{stage}': body model"))?,
    );
    let for_stage = physics.clone();
    let terrain_name = params.str("terrain").unwrap_or("flat");
    let Some(terrain) = Terrain::parse(terrain_name) else {
        bail!(
            "stage '{stage}': unknown terrain '{terrain_name}' ({})",
            Terrain::NAMES.join(", ")
        );
    };
    let method: Box<dyn Method> = match name.as_str() {
        "integrate" => Box::new(Integrate::with_terrain(physics, terrain)),
        "pip" => {
            let d = PipConfig::default();
            let config = PipConfig {
                kp_rotation: params.float("kp_rotation", d.kp_rotation),
                kd_rotation: params.float("kd_rotation", d.kd_rotation),
                kp_position: params.float("kp_position", d.kp_position),
                kd_position: params.float("kd_position", d.kd_position),
                friction: params.float("friction", d.friction),
                coeff_sensor_bone: params.float("sensor_bone_weight", d.coeff_sensor_bone),
                coeff_limb_bone: params.float("limb_bone_weight", d.coeff_limb_bone),
                ..d
            };
            Box::new(Pip::new(physics, config)?)
        }
        "globalpose" => {
            let d = GlobalPoseConfig::default();
            let config = GlobalPoseConfig {
                kp_rotation: params.float("kp_rotation", d.kp_rotation),
                kd_rotation: params.float("kd_rotation", d.kd_rotation),
                kp_position: params.float("kp_position", d.kp_position),
                kd_position: params.float("kd_position", d.kd_position),
                friction: params.float("friction", d.friction),
                terrain,
                ..d
            };
            Box::new(GlobalPose::new(physics, config)?)
        }
        other => bail!(
            "stage '{stage}': unknown method '{other}' ({})",
            METHODS.join(", ")
        ),
    };
    Ok((name, method, for_stage))
}

/// Runs the optimizer stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let (method_name, mut method, physics) = build(&stage, &Params(ctx.params()))?;
    let kin = ctx.input::<KinematicsFrame>("kin")?;
    let has_contacts = ctx.input_names().iter().any(|n| n == "contacts");
    let contacts_in = if has_contacts {
        Some(ctx.input::<ContactFrame>("contacts")?)
    } else {
        None
    };
    if method_name == "pip" && contacts_in.is_none() {
        tracing::info!(
            stage,
            "no 'contacts' input: pip applies PIP's contact rule to its own state (as a contact \
             stage fed back this optimizer's motion would; configs/pip.toml wires one)"
        );
    }
    let mut motion_out = ctx.output::<MotionFrame>("motion")?;
    let mut contacts_out = ctx.output::<ContactFrame>("contacts")?;
    if !ctx.ready()? {
        return Ok(());
    }
    let mut fk = imuflow_body::kinematics::FkData::new();
    let mut estimate = MotionEstimate::default();
    let mut counts = Counts::default();
    let mut running = false;
    while let Some(step) = ctx.next()? {
        let frame = ctx.get(&kin);
        let mut header = step.header();
        counts.frames += 1;
        let reference = match Reference::read(frame) {
            Ok(r) => Some(r),
            Err(why) => {
                counts.undecodable += 1;
                tracing::warn!(stage, seq = step.seq, "kinematics frame unusable: {why}");
                None
            }
        };
        let contacts = match &contacts_in {
            Some(input) => match ContactSet::read(ctx.get(input)) {
                Ok(c) => Some(c),
                Err(why) => {
                    tracing::warn!(stage, seq = step.seq, "contact frame unusable: {why}");
                    header.flags |= flags::INVALID;
                    None
                }
            },
            None => None,
        };
        match reference {
            Some(reference) if step.flags & flags::CALIBRATING == 0 => {
                if !running {
                    method.reset();
                    running = true;
                }
                let report = method
                    .step(&reference, contacts.as_ref(), &mut estimate)
                    .with_context(|| format!("stage '{stage}': frame {}", step.seq))?;
                if report.fallback {
                    counts.fallbacks += 1;
                    header.flags |= flags::INVALID;
                    tracing::warn!(stage, seq = step.seq, "{method_name}: solver fallback used");
                }
            }
            Some(reference) => {
                // Still calibrating: show the reference pose standing on the floor.
                running = false;
                estimate = MotionEstimate {
                    pose: reference.pose,
                    ..MotionEstimate::default()
                };
                estimate.pose.root_in_world_m = nalgebra::Vector3::zeros();
                place_on_floor(&physics, &mut estimate.pose, &FEET, &mut fk);
                header.flags |= flags::INVALID;
            }
            None => header.flags |= flags::INVALID,
        }
        motion_out.publish(header, |out| estimate.write(out))?;
        let used = method.contacts();
        contacts_out.publish(header, |out| used.write(out))?;
    }
    ctx.finish(&mut [&mut motion_out, &mut contacts_out])?;
    tracing::info!(
        stage,
        method = method_name,
        frames = counts.frames,
        fallbacks = counts.fallbacks,
        undecodable = counts.undecodable,
        "optimizer done"
    );
    if counts.fallbacks > 0 {
        eprintln!(
            "{stage}: {method_name}: solver fallback in {} of {} frames",
            counts.fallbacks, counts.frames
        );
    }
    Ok(())
}

#[derive(Default)]
struct Counts {
    frames: u64,
    fallbacks: u64,
    undecodable: u64,
}
