//! The `optimizer` stage: kinematics (and, for PIP, contacts) in, motion out.
//!
//! - Frames flagged CALIBRATING, and frames before the first usable kinematics frame, go out as the
//!   reference pose standing on the floor, flagged INVALID; the method starts at the first frame
//!   that is neither.
//! - A kinematics frame that cannot be decoded (non-finite values) repeats the previous estimate,
//!   flagged INVALID, and is counted. A kinematics frame flagged INVALID keeps the flag.
//! - A frame the method cannot solve is its degraded estimate ([`crate::degraded`]), flagged
//!   DEGRADED, not INVALID: the user's output for that frame. Such frames are counted, the first
//!   and last of each run logged, and the totals reported when the stream ends (the stage's log
//!   and the run summary).
//!
//! [`Optimizer`] is that per-frame logic without the transport; [`run`] feeds it the aligned inputs.

use anyhow::{Context, bail};
use imuflow_body::kinematics::FkData;
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

/// The stage's work on one frame without the transport: which estimate goes out, with which flags,
/// and what is counted (the module docs).
pub struct Optimizer {
    stage: String,
    method_name: String,
    method: Box<dyn Method>,
    physics: PhysicsBody,
    fk: FkData,
    estimate: MotionEstimate,
    /// The method has started (a calibrated, decodable frame came since the last calibrating one).
    running: bool,
    /// Degraded frames in a row up to the last frame.
    degraded_run: u64,
    counts: Counts,
}

/// What the optimizer stage counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Frames taken.
    pub frames: u64,
    /// Frames the method could not solve, published as its degraded estimate (flagged DEGRADED).
    pub degraded: u64,
    /// Kinematics frames that could not be decoded (the previous estimate, flagged INVALID).
    pub undecodable: u64,
}

impl Optimizer {
    /// The method `params` ask for, for stage `stage` (the id in messages).
    pub fn new(stage: &str, params: &OptimizerParams) -> anyhow::Result<Optimizer> {
        let (method_name, method, physics) = build(stage, params)?;
        Ok(Optimizer::with_method(stage, &method_name, method, physics))
    }

    /// A method built elsewhere (tests, other configurations), named `method_name` in messages;
    /// `physics` is the subject's body (the calibrating frames stand its reference pose on it).
    pub fn with_method(
        stage: &str,
        method_name: &str,
        method: Box<dyn Method>,
        physics: PhysicsBody,
    ) -> Optimizer {
        Optimizer {
            stage: stage.to_owned(),
            method_name: method_name.to_owned(),
            method,
            physics,
            fk: FkData::new(),
            estimate: MotionEstimate::default(),
            running: false,
            degraded_run: 0,
            counts: Counts::default(),
        }
    }

    /// The method's name (`pip`, ...).
    pub fn method_name(&self) -> &str {
        &self.method_name
    }

    /// The estimate of the last frame.
    pub fn estimate(&self) -> &MotionEstimate {
        &self.estimate
    }

    /// The contacts the method used in the last frame.
    pub fn contacts(&self) -> &ContactSet {
        self.method.contacts()
    }

    /// What was counted so far.
    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// One frame. `step_flags`: the step's (its inputs' INVALID and CALIBRATING); `kin`: the
    /// networks' frame; `contacts`: the contact stage's frame, where the graph wires one. Returns
    /// the output frames' flags; the estimate is then [`Optimizer::estimate`].
    pub fn step(
        &mut self,
        seq: u64,
        step_flags: u32,
        kin: &KinematicsFrame,
        contacts: Option<&ContactFrame>,
    ) -> anyhow::Result<u32> {
        let stage = self.stage.as_str();
        let mut out_flags = step_flags;
        self.counts.frames += 1;
        let reference = match Reference::read(kin) {
            Ok(r) => Some(r),
            Err(why) => {
                self.counts.undecodable += 1;
                tracing::warn!(stage, seq, "kinematics frame unusable: {why}");
                None
            }
        };
        let contacts = match contacts.map(ContactSet::read) {
            Some(Ok(c)) => Some(c),
            Some(Err(why)) => {
                tracing::warn!(stage, seq, "contact frame unusable: {why}");
                out_flags |= flags::INVALID;
                None
            }
            None => None,
        };
        match reference {
            Some(reference) if step_flags & flags::CALIBRATING == 0 => {
                if !self.running {
                    self.method.reset();
                    self.running = true;
                }
                let report = self
                    .method
                    .step(&reference, contacts.as_ref(), &mut self.estimate)
                    .with_context(|| format!("stage '{stage}': frame {seq}"))?;
                if report.fallback {
                    out_flags |= flags::DEGRADED;
                }
                self.count_degraded(seq, report.fallback);
            }
            Some(reference) => {
                // Still calibrating: show the reference pose standing on the floor.
                self.running = false;
                self.estimate = MotionEstimate {
                    pose: reference.pose,
                    ..MotionEstimate::default()
                };
                self.estimate.pose.root_in_world_m = nalgebra::Vector3::zeros();
                place_on_floor(&self.physics, &mut self.estimate.pose, &FEET, &mut self.fk);
                out_flags |= flags::INVALID;
            }
            None => out_flags |= flags::INVALID,
        }
        Ok(out_flags)
    }

    /// Counts a degraded frame; logs where a run of them starts and ends.
    fn count_degraded(&mut self, seq: u64, degraded: bool) {
        let (stage, method) = (self.stage.as_str(), self.method_name.as_str());
        if degraded {
            self.counts.degraded += 1;
            if self.degraded_run == 0 {
                tracing::warn!(
                    stage,
                    seq,
                    "{method}: solver failed, publishing the degraded estimate (DEGRADED)"
                );
            }
            self.degraded_run += 1;
        } else if self.degraded_run > 0 {
            tracing::info!(
                stage,
                seq,
                "{method}: physics solved again after {} degraded frames",
                self.degraded_run
            );
            self.degraded_run = 0;
        }
    }

    /// The counts as one line (the run summary's).
    pub fn summary_line(&self) -> String {
        let c = &self.counts;
        let mut line = format!(
            "{}: {} of {} frames degraded (solver fallback)",
            self.method_name, c.degraded, c.frames
        );
        if c.undecodable > 0 {
            line += &format!(", {} undecodable kinematics frames", c.undecodable);
        }
        line
    }
}

/// Runs the optimizer stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let mut optimizer = Optimizer::new(&stage, &OptimizerParams::from_params(ctx.params()))?;
    let kin = ctx.input::<KinematicsFrame>("kin")?;
    let has_contacts = ctx.input_names().iter().any(|n| n == "contacts");
    let contacts_in = if has_contacts {
        Some(ctx.input::<ContactFrame>("contacts")?)
    } else {
        None
    };
    if optimizer.method_name() == "pip" && contacts_in.is_none() {
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
    while let Some(step) = ctx.next()? {
        let mut header = step.header();
        let contacts = contacts_in.as_ref().map(|input| ctx.get(input));
        header.flags = optimizer.step(step.seq, step.flags, ctx.get(&kin), contacts)?;
        motion_out.publish(header, |out| optimizer.estimate().write(out))?;
        contacts_out.publish(header, |out| optimizer.contacts().write(out))?;
    }
    let counts = optimizer.counts();
    tracing::info!(
        stage,
        method = optimizer.method_name(),
        frames = counts.frames,
        degraded = counts.degraded,
        undecodable = counts.undecodable,
        "optimizer done"
    );
    let line = optimizer.summary_line();
    if counts.degraded > 0 {
        eprintln!("{stage}: {line}");
    }
    // The same line under `imuflow run`'s summary table.
    ctx.set_summary_detail(line);
    ctx.finish(&mut [&mut motion_out, &mut contacts_out])?;
    Ok(())
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
