//! The `contact` stage: PIP's contact rule between the kinematics networks and the optimizer.
//!
//! Inputs: `kin` (the networks' foot-contact probabilities of this frame) and `state`, a feedback input
//! carrying the optimizer's previous output, i.e. the physics state the optimizer starts this frame
//! from (PIP evaluates its rule on the current simulated body, reference §5.2).
//!
//! - Before the optimizer has published (`state` flagged FEEDBACK_INITIAL), while calibrating (the step
//!   flagged CALIBRATING), or when the state cannot be decoded: an empty contact set, flagged INVALID.
//! - A state flagged INVALID or DEGRADED (the optimizer's estimate where its input was unusable or
//!   its physics could not be solved) is still the state the optimizer continues from, so the rule
//!   is applied to it.
//!
//! `MotionFrame` is decoded here (local rotations + root position → forward kinematics) because the
//! stages import no other stage.

use anyhow::Context;
use imuflow_body::kinematics::FkData;
use imuflow_body::{BodyModel, NUM_JOINTS, Pose, forward_kinematics};
use imuflow_graph::frames::{ContactFrame, Frame, KinematicsFrame, MotionFrame, flags};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::{FrameType, StageContext};
use nalgebra::Vector3;

use imuflow_contact::pip::{
    FOOT_MARGIN_PARAM, FOOT_THRESHOLD_PARAM, PipContactConfig, pip_contacts,
};
use imuflow_contact::subject::{MASS_PARAM, STATURE_PARAM, subject_body};
use imuflow_contact::{ContactGeometry, ContactSet};

imuflow_graph::stage_params! {
    /// The contact stage's parameters.
    pub struct ContactParams {
        /// pip (CVPR 2022 §3.2.3: height + foot-contact probability)
        method: String = "pip", choice(&["pip"]);
        stature_m: f64 = use STATURE_PARAM;
        mass_kg: f64 = use MASS_PARAM;
        foot_threshold: f64 = use FOOT_THRESHOLD_PARAM;
        foot_margin_m: f64 = use FOOT_MARGIN_PARAM;
    }
}

impl ContactParams {
    /// PIP's rule with these parameters.
    pub fn pip_config(&self) -> PipContactConfig {
        PipContactConfig {
            foot_probability_threshold: self.foot_threshold,
            foot_margin_m: self.foot_margin_m,
            ..PipContactConfig::default()
        }
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "contact",
    role: Role::Transform,
    summary: "PIP's contact rule: joint heights of the physics state plus the networks' foot-contact probabilities",
    inputs: InputsSpec::Fixed(&[
        PortSpec {
            name: "kin",
            frame: FrameType::Kinematics,
            required: true,
            doc: "the kinematics networks' estimate (foot-contact probabilities)",
        },
        PortSpec {
            name: "state",
            frame: FrameType::Motion,
            required: true,
            doc: "the optimizer's motion, wired as a feedback input (the previous frame's physics state)",
        },
    ]),
    outputs: &[PortSpec {
        name: "contacts",
        frame: FrameType::Contact,
        required: false,
        doc: "contact joints, 4 points each (no forces)",
    }],
    params: ContactParams::SPECS,
};

/// The stage's per-frame work, free of the graph: decode the fed-back state, apply PIP's rule.
pub struct ContactEstimator {
    body: BodyModel,
    geometry: ContactGeometry,
    config: PipContactConfig,
    fk: FkData,
    pose: Pose,
}

impl ContactEstimator {
    pub fn new(body: BodyModel, config: PipContactConfig) -> ContactEstimator {
        ContactEstimator {
            geometry: ContactGeometry::new(&body),
            body,
            config,
            fk: FkData::new(),
            pose: Pose::default(),
        }
    }

    /// Contacts for one frame into `out`. `step_flags` are the step's flags (CALIBRATING). Returns
    /// `Err(why)` (with `out` empty) when there is no usable state; the caller flags the frame INVALID.
    pub fn estimate(
        &mut self,
        kin: &KinematicsFrame,
        state: &MotionFrame,
        step_flags: u32,
        out: &mut ContactSet,
    ) -> Result<(), String> {
        out.clear();
        if step_flags & flags::CALIBRATING != 0 {
            return Err("calibrating".into());
        }
        if state.header().flags & flags::FEEDBACK_INITIAL != 0 {
            return Err("no physics state yet".into());
        }
        self.pose = Pose::from_wire(&state.local_pose_wxyz, &state.root_position_m)
            .map_err(|e| format!("state {e}"))?;
        let prob = kin.foot_contact_prob.map(f64::from);
        if !prob.iter().all(|p| (0.0..=1.0).contains(p)) {
            return Err(format!("foot_contact_prob {prob:?} is not a probability"));
        }
        forward_kinematics(&self.body.skeleton, &self.pose, &mut self.fk);
        let joints: &[Vector3<f64>; NUM_JOINTS] = &self.fk.joint_in_world_m;
        let dropped = pip_contacts(joints, prob, &self.geometry, &self.config, out);
        if dropped > 0 {
            tracing::debug!(dropped, "more contact bodies than a ContactFrame holds");
        }
        Ok(())
    }
}

/// Runs the contact stage as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = ContactParams::from_params(ctx.params());
    let method = params.method.as_str();
    if method != "pip" {
        anyhow::bail!("stage '{stage}': unknown method '{method}' (pip)");
    }
    let body = subject_body(params.stature_m, params.mass_kg)
        .with_context(|| format!("stage '{stage}': body model"))?;
    let mut estimator = ContactEstimator::new(body, params.pip_config());
    let kin = ctx.input::<KinematicsFrame>("kin")?;
    let state = ctx.input::<MotionFrame>("state")?;
    let mut output = ctx.output::<ContactFrame>("contacts")?;
    if !ctx.ready()? {
        return Ok(());
    }
    let mut set = ContactSet::new();
    let mut unusable = 0u64;
    while let Some(step) = ctx.next()? {
        let mut header = step.header();
        if let Err(why) = estimator.estimate(ctx.get(&kin), ctx.get(&state), step.flags, &mut set) {
            header.flags |= flags::INVALID;
            if !why.starts_with("calibrating") && !why.starts_with("no physics") {
                unusable += 1;
                tracing::warn!(stage, seq = step.seq, "no contacts: {why}");
            }
        }
        output.publish(header, |out| set.write(out))?;
    }
    ctx.finish(&mut [&mut output])?;
    tracing::info!(stage, unusable, "contact done");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;
    use imuflow_body::BodyParams;
    use imuflow_body::JointId;
    use imuflow_body::rotation::quat_wxyz_from_rotation;

    fn standing_state(body: &BodyModel, dy: f64) -> MotionFrame {
        let mut frame = MotionFrame::zeroed();
        let pose = Pose::t_pose(Vector3::new(0.0, body.rest_root_height_m + dy, 0.0));
        for j in 0..NUM_JOINTS {
            frame.local_pose_wxyz[j] =
                quat_wxyz_from_rotation(&pose.parent_from_joint[j]).map(|v| v as f32);
        }
        frame.root_position_m = pose.root_in_world_m.cast::<f32>().into();
        frame
    }

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<ContactParams>().unwrap();
        assert_eq!(
            ContactParams::default().pip_config(),
            PipContactConfig::default()
        );
    }

    #[test]
    fn the_fed_back_state_decides_and_initial_or_calibrating_frames_give_nothing() {
        let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.75, 70.0).unwrap();
        let mut est = ContactEstimator::new(body.clone(), PipContactConfig::default());
        let mut kin = KinematicsFrame::zeroed();
        kin.foot_contact_prob = [0.9, 0.1];
        let mut set = ContactSet::new();
        // Standing 1 cm above the floor: only the confident left foot is in contact.
        let state = standing_state(&body, 0.01);
        est.estimate(&kin, &state, 0, &mut set).unwrap();
        assert_eq!(set.mask, 1 << JointId::LEFT_FOOT.index());
        assert_eq!(set.points().len(), 4);
        // Before the optimizer's first frame.
        let mut initial = MotionFrame::zeroed();
        initial.header.flags = flags::FEEDBACK_INITIAL | flags::INVALID;
        assert!(est.estimate(&kin, &initial, 0, &mut set).is_err());
        assert_eq!(set.points().len(), 0);
        // Calibrating.
        assert!(
            est.estimate(&kin, &state, flags::CALIBRATING, &mut set)
                .is_err()
        );
        assert_eq!(set.mask, 0);
        // A fallback frame (INVALID only) is still a state.
        let mut fallback = state;
        fallback.header.flags = flags::INVALID;
        est.estimate(&kin, &fallback, 0, &mut set).unwrap();
        assert_eq!(set.points().len(), 4);
        // Garbage: a zero quaternion.
        let mut bad = state;
        bad.local_pose_wxyz[3] = [0.0; 4];
        let why = est.estimate(&kin, &bad, 0, &mut set).unwrap_err();
        assert!(why.contains("local_pose_wxyz[3]"), "{why}");
    }
}
