//! The validator: feeds estimated poses to the simulation frame by frame, scores each frame, resets
//! the simulation on a fall, and keeps the run's statistics. The stage, the benchmark, the tests and
//! the evaluation all go through this one type.

use std::time::Instant;

use imuflow_body::kinematics::{FkData, Pose, forward_kinematics};
use imuflow_body::skeleton::{JointId, NUM_JOINTS};
use nalgebra::Vector3;

use crate::model::SimModel;
use crate::sim::{FrameForces, SimConfig, SimState, Simulation, Target};
use crate::stage::ValidationParams;
use crate::support::{Support, SupportJudge, SupportState};

/// A foot touches the floor when it carries at least this force, N. [inferred]
const CONTACT_FORCE_N: f64 = 5.0;
/// Largest lift applied to an estimate whose body would start inside the floor, m: motion data and
/// estimates place the feet a centimetre or two lower than the simulated foot boxes reach. [inferred]
const MAX_FLOOR_LIFT_M: f64 = 0.05;

/// When the simulated body counts as fallen, relative to the estimate it tracks.
#[derive(Debug, Clone, PartialEq)]
pub struct FallRule {
    /// Fallen when the simulated pelvis is below this fraction of the estimate's pelvis height.
    pub pelvis_height_fraction: f64,
    /// Fallen when the simulated trunk's up axis is tilted this far from the estimate's, degrees.
    pub trunk_tilt_deg: f64,
    /// Re-anchor (a resync, not a fall) when the simulated root drifts this far horizontally from
    /// the estimate's without falling, m.
    pub max_drift_m: f64,
}

impl Default for FallRule {
    /// The validation stage's defaults ([`ValidationParams`]).
    fn default() -> FallRule {
        ValidationParams::default().fall_rule()
    }
}

/// The scores of one simulated frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameScore {
    pub tracking_error_m: f64,
    pub pose_error_m: f64,
    pub root_error_m: f64,
    /// Mean horizontal speed of the feet in contact (`None` when no foot touches).
    pub foot_skate_mps: Option<f64>,
    pub penetration_m: f64,
    /// Residual root force as a fraction of body weight (0 in torques mode).
    pub residual_force_fraction: f64,
}

/// What one frame produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub score: FrameScore,
    pub forces: FrameForces,
    /// The simulated body at the end of the frame (after a reset: the estimate's pose).
    pub state: SimState,
    /// The body lost its balance this frame (and was reset to the estimate).
    pub fell: bool,
    /// The body drifted away and was re-anchored to the estimate.
    pub resynced: bool,
    /// Bit j set when joint j touches the floor.
    pub contact_mask: u32,
    /// Whether the floor could carry the estimate [`crate::support::SUPPORT_FRAMES`] frames ago
    /// (the controller-free score, independent of the simulation).
    pub support: Support,
}

/// Run statistics, for the end-of-run summary and the evaluation.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    pub frames: u64,
    pub simulated_s: f64,
    pub falls: u64,
    pub resyncs: u64,
    pub tracking_errors_m: Vec<f64>,
    pub pose_error_sum_m: f64,
    pub root_error_sum_m: f64,
    pub residual_fraction_sum: f64,
    pub skate_sum_mps: f64,
    pub skate_frames: u64,
    pub penetration_sum_m: f64,
    pub penetration_max_m: f64,
    /// The largest gap a joint of the simulated body opened, m (see
    /// [`Simulation::largest_joint_gap_m`]).
    pub joint_gap_max_m: f64,
    pub step_us: Vec<f64>,
    /// Frames whose support was judged (see [`crate::support`]).
    pub support_judged: u64,
    /// Of those, frames whose needed centre of pressure lies outside the feet by more than
    /// [`crate::support::OUTSIDE_TOLERANCE_M`].
    pub support_outside: u64,
    /// Of those, frames the floor could not carry at all (no foot down, or it would have to pull).
    pub support_unsupported: u64,
}

fn mean(sum: f64, n: u64) -> f64 {
    if n == 0 { 0.0 } else { sum / n as f64 }
}

fn percentile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[rank.min(sorted.len() - 1)]
}

impl Stats {
    pub fn falls_per_minute(&self) -> f64 {
        if self.simulated_s > 0.0 {
            self.falls as f64 / (self.simulated_s / 60.0)
        } else {
            0.0
        }
    }
    pub fn tracking_error_mean_m(&self) -> f64 {
        mean(self.tracking_errors_m.iter().sum(), self.frames)
    }
    pub fn tracking_error_p95_m(&self) -> f64 {
        percentile(&self.tracking_errors_m, 95.0)
    }
    pub fn pose_error_mean_m(&self) -> f64 {
        mean(self.pose_error_sum_m, self.frames)
    }
    pub fn root_error_mean_m(&self) -> f64 {
        mean(self.root_error_sum_m, self.frames)
    }
    pub fn residual_force_mean_fraction(&self) -> f64 {
        mean(self.residual_fraction_sum, self.frames)
    }
    pub fn foot_skate_mean_mps(&self) -> f64 {
        mean(self.skate_sum_mps, self.skate_frames)
    }
    pub fn penetration_mean_m(&self) -> f64 {
        mean(self.penetration_sum_m, self.frames)
    }
    pub fn step_mean_us(&self) -> f64 {
        mean(self.step_us.iter().sum(), self.step_us.len() as u64)
    }
    pub fn step_p99_us(&self) -> f64 {
        percentile(&self.step_us, 99.0)
    }
    /// Judged frames whose support is violated: outside the feet or unsupported.
    pub fn support_violated(&self) -> u64 {
        self.support_outside + self.support_unsupported
    }
    /// Their share of the judged frames.
    pub fn support_violated_fraction(&self) -> f64 {
        mean(self.support_violated() as f64, self.support_judged)
    }
    /// Counts one frame's support score.
    pub fn add_support(&mut self, support: &Support) {
        if support.state == SupportState::Unjudged {
            return;
        }
        self.support_judged += 1;
        if support.state == SupportState::Unsupported {
            self.support_unsupported += 1;
        } else if support.violated() {
            self.support_outside += 1;
        }
    }

    /// One line for logs and run summaries.
    pub fn summary_line(&self, residual_mode: bool) -> String {
        let mut line = format!(
            "{} frames ({:.1} s): falls {} ({:.2}/min), resyncs {}, tracking error mean {:.1} cm p95 {:.1} cm, pose error {:.1} cm, root error {:.1} cm, foot skate {:.3} m/s, penetration mean {:.2} cm max {:.2} cm",
            self.frames,
            self.simulated_s,
            self.falls,
            self.falls_per_minute(),
            self.resyncs,
            100.0 * self.tracking_error_mean_m(),
            100.0 * self.tracking_error_p95_m(),
            100.0 * self.pose_error_mean_m(),
            100.0 * self.root_error_mean_m(),
            self.foot_skate_mean_mps(),
            100.0 * self.penetration_mean_m(),
            100.0 * self.penetration_max_m,
        );
        if residual_mode {
            line += &format!(
                ", residual root force {:.3} mg",
                self.residual_force_mean_fraction()
            );
        }
        if self.support_judged > 0 {
            let share = |n: u64| 100.0 * n as f64 / self.support_judged as f64;
            line += &format!(
                ", support violated on {:.1} % of {} judged frames (centre of pressure > {:.0} cm outside the feet {:.1} %, unsupported {:.1} %)",
                100.0 * self.support_violated_fraction(),
                self.support_judged,
                100.0 * crate::support::OUTSIDE_TOLERANCE_M,
                share(self.support_outside),
                share(self.support_unsupported),
            );
        }
        line + &format!(
            ", joint gap max {:.2} cm, {:.0} µs/frame (p99 {:.0})",
            100.0 * self.joint_gap_max_m,
            self.step_mean_us(),
            self.step_p99_us()
        )
    }
}

/// Tracks an estimate through the simulation, frame by frame.
pub struct Validator {
    model: SimModel,
    config: SimConfig,
    fall: FallRule,
    sim: Option<Simulation>,
    /// The last usable estimate (the target while frames are unusable).
    previous: Option<Pose>,
    /// Lift applied to the estimate for this simulation (see [`MAX_FLOOR_LIFT_M`]), m.
    lift_m: f64,
    estimate_fk: FkData,
    support: SupportJudge,
    pub stats: Stats,
}

impl Validator {
    pub fn new(model: SimModel, config: SimConfig, fall: FallRule) -> Validator {
        let support = SupportJudge::new(&model);
        Validator {
            model,
            config,
            fall,
            sim: None,
            previous: None,
            lift_m: 0.0,
            estimate_fk: FkData::new(),
            support,
            stats: Stats::default(),
        }
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    pub fn model(&self) -> &SimModel {
        &self.model
    }

    /// Forgets the simulation (e.g. while the pipeline recalibrates); the next frame starts anew.
    pub fn clear(&mut self) {
        self.sim = None;
        self.previous = None;
        self.support.clear();
    }

    /// Whether a simulation is running.
    pub fn is_running(&self) -> bool {
        self.sim.is_some()
    }

    /// Simulates one frame of `dt` seconds towards `estimate` (or, with `None`, towards the last
    /// usable estimate, holding still). `None` when there is nothing to simulate yet.
    pub fn frame(&mut self, estimate: Option<&Pose>, dt: f64) -> Option<Outcome> {
        let started = Instant::now();
        let support = self.support.push(estimate, dt);
        let has_velocity = estimate.is_some() && self.previous.is_some();
        let mut target = match (estimate, &self.previous) {
            (Some(pose), previous) => Target::from_poses(previous.as_ref(), pose, dt),
            (None, Some(previous)) => Target::from_poses(None, previous, dt),
            (None, None) => return None,
        };
        if let Some(pose) = estimate {
            self.previous = Some(pose.clone());
        }
        if self.sim.is_none() {
            self.lift_m = self.floor_lift(&target.pose);
        }
        target.pose.root_in_world_m.y += self.lift_m;
        forward_kinematics(
            &self.model.body.skeleton,
            &target.pose,
            &mut self.estimate_fk,
        );
        let Some(sim) = &mut self.sim else {
            // A body dropped in without the estimate's velocities lags it from the first frame
            // (a walk at 1.3 m/s leaves it 0.2 m behind in 10 frames): start at the second frame.
            if !has_velocity {
                return Some(self.record(
                    started,
                    dt,
                    target_outcome(self.estimate_state(&target.pose), support),
                    false,
                    false,
                ));
            }
            let sim = Simulation::new(&self.model, &self.config, &target.clone().folded());
            let state = sim.state();
            self.sim = Some(sim);
            return Some(self.record(started, dt, target_outcome(state, support), false, false));
        };
        let forces = sim.step(&target.clone().folded(), dt);
        self.stats.joint_gap_max_m = self.stats.joint_gap_max_m.max(sim.largest_joint_gap_m());
        let state = sim.state();
        let score = self.score(&state, &forces);
        let contact_mask = contact_mask(&forces);
        let fell = self.has_fallen(&state);
        let drift = (state.pose.root_in_world_m - target.pose.root_in_world_m)
            .xz()
            .norm();
        let resynced = !fell && drift > self.fall.max_drift_m;
        let state = if fell || resynced {
            target.pose.root_in_world_m.y -= self.lift_m;
            self.lift_m = self.floor_lift(&target.pose);
            target.pose.root_in_world_m.y += self.lift_m;
            let sim = Simulation::new(&self.model, &self.config, &target.clone().folded());
            let state = sim.state();
            self.sim = Some(sim);
            state
        } else {
            state
        };
        let outcome = Outcome {
            score,
            forces,
            state,
            fell,
            resynced,
            contact_mask,
            support,
        };
        Some(self.record(started, dt, outcome, fell, resynced))
    }

    fn record(
        &mut self,
        started: Instant,
        dt: f64,
        outcome: Outcome,
        fell: bool,
        resynced: bool,
    ) -> Outcome {
        let s = &mut self.stats;
        let score = &outcome.score;
        s.frames += 1;
        s.simulated_s += dt;
        s.falls += u64::from(fell);
        s.resyncs += u64::from(resynced);
        s.tracking_errors_m.push(score.tracking_error_m);
        s.pose_error_sum_m += score.pose_error_m;
        s.root_error_sum_m += score.root_error_m;
        s.residual_fraction_sum += score.residual_force_fraction;
        if let Some(skate) = score.foot_skate_mps {
            s.skate_sum_mps += skate;
            s.skate_frames += 1;
        }
        s.penetration_sum_m += score.penetration_m;
        s.penetration_max_m = s.penetration_max_m.max(score.penetration_m);
        s.add_support(&outcome.support);
        s.step_us.push(started.elapsed().as_secs_f64() * 1e6);
        outcome
    }

    /// How far to lift an estimate that would start with the body inside the floor, m (never
    /// lowers one: a floating estimate must stay floating).
    fn floor_lift(&mut self, pose: &Pose) -> f64 {
        forward_kinematics(&self.model.body.skeleton, pose, &mut self.estimate_fk);
        (-self.model.lowest_point_m(&self.estimate_fk)).clamp(0.0, MAX_FLOOR_LIFT_M)
    }

    /// The estimate (its forward kinematics in `estimate_fk`) as a state at rest, for the frames
    /// before a simulation starts.
    fn estimate_state(&self, pose: &Pose) -> SimState {
        SimState {
            pose: pose.clone(),
            joint_position_m: self.estimate_fk.joint_in_world_m,
            joint_velocity_mps: [Vector3::zeros(); NUM_JOINTS],
            world_from_joint: self.estimate_fk.world_from_joint,
        }
    }

    fn score(&self, state: &SimState, forces: &FrameForces) -> FrameScore {
        let est = &self.estimate_fk.joint_in_world_m;
        let sim = &state.joint_position_m;
        let (est_root, sim_root) = (est[0], sim[0]);
        let mut tracking = 0.0;
        let mut pose = 0.0;
        for j in 0..NUM_JOINTS {
            tracking += (sim[j] - est[j]).norm();
            pose += ((sim[j] - sim_root) - (est[j] - est_root)).norm();
        }
        let skate: Vec<f64> = [JointId::LEFT_FOOT, JointId::RIGHT_FOOT]
            .iter()
            .zip(forces.foot_slip_mps)
            .filter(|(foot, _)| forces.contact_force_n[foot.index()].y > CONTACT_FORCE_N)
            .filter_map(|(_, slip)| slip)
            .collect();
        let weight = self.model.total_mass_kg * 9.81;
        FrameScore {
            tracking_error_m: tracking / NUM_JOINTS as f64,
            pose_error_m: pose / NUM_JOINTS as f64,
            root_error_m: (sim_root - est_root).norm(),
            foot_skate_mps: (!skate.is_empty())
                .then(|| skate.iter().sum::<f64>() / skate.len() as f64),
            penetration_m: forces.penetration_m,
            residual_force_fraction: forces.residual_force_n.norm() / weight,
        }
    }

    /// Balance lost: the pelvis sank well below the estimate's, or the trunk tipped away from it.
    fn has_fallen(&self, state: &SimState) -> bool {
        let est = &self.estimate_fk;
        let pelvis_low = state.joint_position_m[0].y
            < self.fall.pelvis_height_fraction * est.joint_in_world_m[0].y;
        let up = Vector3::y();
        let trunk = JointId::SPINE3.index();
        let tilt = (state.world_from_joint[trunk] * up)
            .angle(&(est.world_from_joint[trunk] * up))
            .to_degrees();
        pelvis_low || tilt > self.fall.trunk_tilt_deg
    }
}

/// A fresh simulation's first frame: it starts in the estimate's pose, so it scores zero.
fn target_outcome(state: SimState, support: Support) -> Outcome {
    Outcome {
        score: FrameScore::default(),
        forces: FrameForces::default(),
        state,
        fell: false,
        resynced: false,
        contact_mask: 0,
        support,
    }
}

fn contact_mask(forces: &FrameForces) -> u32 {
    forces
        .contact_force_n
        .iter()
        .enumerate()
        .filter(|(_, f)| f.y > CONTACT_FORCE_N)
        .fold(0, |mask, (j, _)| mask | (1 << j))
}
