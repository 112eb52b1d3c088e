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
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, StageContext};

use crate::estimate::{FEET, place_on_floor};
use crate::globalpose::{GlobalPose, GlobalPoseConfig};
use crate::integrate::Integrate;
use crate::pip::{LIMB_BONE_WEIGHT_PARAM, Pip, PipConfig, SENSOR_BONE_WEIGHT_PARAM};
use crate::{Method, MotionEstimate, PhysicsBody, Reference, Terrain};

/// The methods, as the `method` parameter names them.
pub const METHODS: [&str; 3] = ["integrate", "pip", "globalpose"];

imuflow_graph::stage_params! {
    /// The optimizer's parameters. Where the gains and the friction are not set, each method keeps
    /// its paper's ([`PipConfig::default`], [`GlobalPoseConfig::default`]); their texts say which.
    pub struct OptimizerParams {
        /// integrate (no physics), pip (CVPR 2022 QP) or globalpose (SIGGRAPH 2025 double
        /// tracking)
        method: String = "integrate", choice(&METHODS);
        stature_m: f64 = use STATURE_PARAM;
        mass_kg: f64 = use MASS_PARAM;
        /// joint-rotation PD stiffness (1/s²)
        kp_rotation: Option<f64> = computed("pip 2400, globalpose 3600"), float(0.0, 1e6);
        /// joint-rotation PD damping (1/s)
        kd_rotation: Option<f64> = computed("60"), float(0.0, 1e4);
        /// joint-position PD stiffness (1/s²)
        kp_position: Option<f64> = computed("3600"), float(0.0, 1e6);
        /// joint-position PD damping (1/s)
        kd_position: Option<f64> = computed("60"), float(0.0, 1e4);
        /// friction coefficient μ of the contact cones
        friction: Option<f64> = computed("pip 0.6, globalpose 0.7"), float(0.0, 5.0);
        sensor_bone_weight: f64 = use SENSOR_BONE_WEIGHT_PARAM;
        limb_bone_weight: f64 = use LIMB_BONE_WEIGHT_PARAM;
        /// integrate and globalpose: flat (stationary feet pulled to the floor from any height: no
        /// vertical drift) or proxy (GlobalPose's proxy surfaces: steps and seats, but a biased
        /// network can ratchet the root up)
        terrain: String = "flat", choice(&Terrain::NAMES);
    }
}

impl OptimizerParams {
    /// PIP's configuration: its own defaults where these parameters leave them.
    pub fn pip_config(&self) -> PipConfig {
        let d = PipConfig::default();
        PipConfig {
            kp_rotation: self.kp_rotation.unwrap_or(d.kp_rotation),
            kd_rotation: self.kd_rotation.unwrap_or(d.kd_rotation),
            kp_position: self.kp_position.unwrap_or(d.kp_position),
            kd_position: self.kd_position.unwrap_or(d.kd_position),
            friction: self.friction.unwrap_or(d.friction),
            coeff_sensor_bone: self.sensor_bone_weight,
            coeff_limb_bone: self.limb_bone_weight,
            ..d
        }
    }

    /// GlobalPose's configuration on `terrain`: its own defaults where these parameters leave
    /// them.
    pub fn globalpose_config(&self, terrain: Terrain) -> GlobalPoseConfig {
        let d = GlobalPoseConfig::default();
        GlobalPoseConfig {
            kp_rotation: self.kp_rotation.unwrap_or(d.kp_rotation),
            kd_rotation: self.kd_rotation.unwrap_or(d.kd_rotation),
            kp_position: self.kp_position.unwrap_or(d.kp_position),
            kd_position: self.kd_position.unwrap_or(d.kd_position),
            friction: self.friction.unwrap_or(d.friction),
            terrain,
            ..d
        }
    }
}

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
    params: OptimizerParams::SPECS,
};

/// Builds the method a stage's parameters ask for.
fn build(
    stage: &str,
    params: &OptimizerParams,
) -> anyhow::Result<(String, Box<dyn Method>, PhysicsBody)> {
    let name = params.method.clone();
    let physics = PhysicsBody::from_body(
        subject_body(params.stature_m, params.mass_kg)
            .with_context(|| format!("stage '{stage}': body model"))?,
    );
    let for_stage = physics.clone();
    let terrain_name = params.terrain.as_str();
    let Some(terrain) = Terrain::parse(terrain_name) else {
        bail!(
            "stage '{stage}': unknown terrain '{terrain_name}' ({})",
            Terrain::NAMES.join(", ")
        );
    };
    let method: Box<dyn Method> = match name.as_str() {
        "integrate" => Box::new(Integrate::with_terrain(physics, terrain)),
        "pip" => Box::new(Pip::new(physics, params.pip_config())?),
        "globalpose" => Box::new(GlobalPose::new(physics, params.globalpose_config(terrain))?),
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
    let (method_name, mut method, physics) =
        build(&stage, &OptimizerParams::from_params(ctx.params()))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<OptimizerParams>().unwrap();
        let p = OptimizerParams::default();
        assert_eq!(p.pip_config(), PipConfig::default());
        assert_eq!(
            p.globalpose_config(Terrain::parse(&p.terrain).unwrap()),
            GlobalPoseConfig::default()
        );
    }

    /// The texts of the defaults the methods keep: "pip A, globalpose B", or one value for both.
    #[test]
    fn the_method_defaults_texts_are_the_methods_defaults() {
        let (pip, globalpose) = (PipConfig::default(), GlobalPoseConfig::default());
        let read = |name: &str| {
            let text = SPEC.param(name).unwrap().default;
            let value = |s: &str| s.trim().parse::<f64>().unwrap();
            match text.split_once(", globalpose ") {
                Some((p, g)) => (value(p.strip_prefix("pip ").unwrap()), value(g)),
                None => (value(text), value(text)),
            }
        };
        let cases = [
            ("kp_rotation", pip.kp_rotation, globalpose.kp_rotation),
            ("kd_rotation", pip.kd_rotation, globalpose.kd_rotation),
            ("kp_position", pip.kp_position, globalpose.kp_position),
            ("kd_position", pip.kd_position, globalpose.kd_position),
            ("friction", pip.friction, globalpose.friction),
        ];
        for (name, p, g) in cases {
            assert_eq!(read(name), (p, g), "{name}");
        }
    }
}
