//! The rerun-logger stage: logs the frames it receives to a `.rrd` file or a live rerun viewer.
//!
//! Time axes: `seq` (the source's frame index) and `capture_time` (the frame's capture timestamp:
//! time since the start of the recording offline, wall-clock time live).
//!
//! What is logged per frame type (entity paths start with the input's name):
//! - ImuFrame / BodyImuFrame: each sensor's orientation as a transform with axes (sensors laid
//!   out side by side along x so they do not overlap), and its acceleration, angular rate and
//!   valid flag as time series under `plots/`.
//! - MotionFrame: the skeleton (bones as lines, joints as points whose radius grows with the joint's
//!   torque) at its global position, ground-reaction forces as arrows from the joints, and the torque
//!   magnitude per joint as a bar chart under `plots/<input>/torque_norm_nm`.
//! - KinematicsFrame: the networks' joint positions relative to the root (points and bones), drawn
//!   at the root of the estimate (`motion`) of the same frame, or at the origin without one.
//! - ContactFrame: contact points, and their forces as arrows.
//! - ValidationFrame: a warning text entry under `<input>/events` at every frame where the
//!   simulated body lost its balance (the scores are time series, as every small field). The
//!   validation stage's simulated body is a MotionFrame: wire it to an input named `validation`
//!   and it is drawn in its own colour with its floor forces as arrows.
//! - Errors against the truth: with an input named `truth` (a MotionFrame), every other motion
//!   input named `motion` (or `<group>__motion`) gets its SIP error (deg), root-aligned mean joint
//!   position error (cm) and its root distance (m) per frame under `plots/error_vs_truth/<entity>/`. Without a
//!   truth, a comparison's variants get the same against the first variant, under
//!   `plots/disagreement_vs_<first>/<group>/`. With a truth, each estimate's latency from the
//!   source publishing a frame to the estimate's publishing: `plots/latency_ms/<group or input>`.
//! - Every frame type: each small field (up to 6 scalars, e.g. stationary probabilities, root
//!   velocity) as a time series under `plots/<input>/<field>`, once it has changed (a constant
//!   series is never logged: `Plots` in `plots.rs`); the INVALID flag as text events under `<input>/events`
//!   where it turns on and off.
//!
//! Writing a file, the log calls are gathered and written as columns every `batch_frames` frames
//! (`columns.rs`); a live viewer gets them call by call.
//!
//! A single run's recording carries a blueprint (`blueprint.rs`): the scene and a
//! view that follows the estimate's pelvis (entity `follow`, with a camera fixed in its frame), a
//! legend (`legend`, markdown), and tabs of time series (the errors against the truth first, once
//! a truth pose came; the IMU sensors' axes in their input's tab). Fixed colours: `motion` blue,
//! `kinematics` pink (drawn at the estimate's root), `truth` green, `validation` orange.
//!
//! Groups (A/B comparisons, `imuflow compare`): an input named `<group>__<what>` is logged under
//! `<group>/<what>`, every group's skeletons get their own colour (its simulated body a lighter
//! tint), and the recording carries a blueprint: one 3D view per group with the truth, or all in
//! one view with `views = "overlaid"`, above the error and validation time series.
//!
//! The model frame M is x = left, y = up, z = forward (SMPL), logged as the world's view
//! coordinates so the viewer shows "up" correctly.
//!
//! Modules, one job each:
//! - `stage.rs`: the parameters, the spec and [`run`]: opens the file or viewer, reads the inputs
//!   and hands each frame to what draws or plots it.
//! - `skeleton.rs`: the 3D views' contents: skeletons, forces, contacts, sensors, their colours.
//! - `plots.rs`: the time series: small fields, INVALID events, errors against the truth, latency.
//! - `blueprint.rs`: the viewer's layout and the legend.
//! - `columns.rs`: where the log calls go (gathered into columns, or call by call).

mod blueprint;
mod columns;
mod plots;
mod skeleton;
mod stage;

pub use stage::{APPLICATION_ID, SPEC, run};
