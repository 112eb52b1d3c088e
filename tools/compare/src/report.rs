//! The report of `imuflow compare`: every variant scored from the run's recording, side by side.
//!
//! Reads the combined graph's mcap (each variant's motion and validation, and the truth when the
//! source has one), keeps the frames every stream can use (same seqs for every variant: the
//! calibrations end at different frames), scores them with [`imuflow_eval::score`] (its protocols: pose
//! errors GlobalPose "G", motion metrics on the recorded joints), and writes `report.md` (one
//! table, the best per row), `results.json` and PNG plots next to the recording.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::combine::Combined;
use anyhow::Context;
use imuflow_body::{BodyModel, BodyParams, NUM_JOINTS, Pose};
use imuflow_graph::frames::{BodyImuFrame, MotionFrame, ValidationFrame, frame_from_bytes};
use imuflow_graph::launch::RunReport;
use imuflow_recording::for_each_record;

use imuflow_eval::score::{
    MotionScores, SKIPPED_FLAGS, disagreement, score_against_truth, score_without_truth,
    sensor_bone_error_deg, summarize_validation,
};

/// One row of the table: a metric, its unit, whether lower is better, one value per variant.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Row {
    pub name: String,
    pub unit: String,
    pub lower_is_better: bool,
    /// Per variant, in the variants' order; `None` where the metric does not apply (a clip too
    /// short for 7 m of travel, a variant without validation).
    pub values: Vec<Option<f64>>,
}

/// A comparison run scored: the table's rows and the per-frame series behind the plots.
pub struct Scored {
    /// The variants, in order.
    pub names: Vec<String>,
    pub rows: Vec<Row>,
    pub series: Vec<Series>,
    /// The truth's root path (x, z), empty without truth.
    pub truth_trajectory: Vec<(f64, f64)>,
    /// Frames every variant was scored on.
    pub frames: usize,
    pub with_truth: bool,
}

/// A variant's decoded streams.
struct Streams {
    name: String,
    /// seq -> (pose, frame) of the estimate.
    motion: BTreeMap<u32, MotionFrame>,
    validation: Vec<ValidationFrame>,
    /// The calibrated IMU frames the estimate was made from, by seq (empty when not recorded).
    body_imu: BTreeMap<u64, BodyImuFrame>,
}

/// Per-frame series kept for the plots.
pub struct Series {
    pub name: String,
    /// (seq, joint position error cm).
    pub error_cm: Vec<(u32, f64)>,
    /// Per joint, cm; NaN where the variant's sensors do not place the joint (its parent not observed).
    pub per_joint_cm: [f64; NUM_JOINTS],
    /// Root positions (x, z), m.
    pub trajectory: Vec<(f64, f64)>,
    /// Capture-to-motion latency per frame, ms (from the frames' publish stamps).
    pub latency_ms: Vec<f64>,
}

/// Writes the report of a finished comparison into `out`; returns the report's path.
pub fn write(
    name: &str,
    out: &Path,
    mcap: &Path,
    combined: &Combined,
    run: &RunReport,
    rate_hz: f64,
) -> anyhow::Result<PathBuf> {
    let scored = score_recording(mcap, combined, rate_hz)?;
    let plots = crate::plots::draw(out, &scored.series, &scored.truth_trajectory)?;
    let names: Vec<&str> = scored.names.iter().map(String::as_str).collect();
    let report = markdown(
        name,
        combined,
        run,
        &names,
        &scored.rows,
        &plots,
        scored.with_truth,
        scored.frames,
    );
    let path = out.join("report.md");
    std::fs::write(&path, report).with_context(|| format!("cannot write {}", path.display()))?;
    let json = results_json(combined, run, &names, &scored.rows);
    let json_path = out.join("results.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    Ok(path)
}

/// Scores every variant of a finished comparison from its recording, on the frames they share.
pub fn score_recording(mcap: &Path, combined: &Combined, rate_hz: f64) -> anyhow::Result<Scored> {
    let bytes = std::fs::read(mcap).with_context(|| format!("cannot read {}", mcap.display()))?;
    let topics = read_topics(&bytes).with_context(|| format!("{}", mcap.display()))?;
    let motion_of = |topic: &str| -> anyhow::Result<BTreeMap<u32, MotionFrame>> {
        topics
            .get(topic)
            .map(|messages| {
                messages
                    .iter()
                    .map(|data| {
                        let f: MotionFrame = frame_from_bytes(data)
                            .with_context(|| format!("{topic}: a message is not a MotionFrame"))?;
                        Ok((f.header.seq as u32, f))
                    })
                    .collect()
            })
            .unwrap_or_else(|| Ok(BTreeMap::new()))
    };
    let truth = match &combined.truth {
        Some(t) => Some(motion_of(t)?),
        None => None,
    };
    let mut variants = Vec::new();
    for v in &combined.variants {
        let validation = match &v.validation {
            Some(stage) => topics
                .get(&format!("{stage}.validation"))
                .map(|m| {
                    m.iter()
                        .filter_map(|d| frame_from_bytes::<ValidationFrame>(d))
                        .collect()
                })
                .unwrap_or_default(),
            None => Vec::new(),
        };
        let body_imu = v
            .body_imu
            .as_ref()
            .and_then(|topic| topics.get(topic))
            .map(|m| {
                m.iter()
                    .filter_map(|d| frame_from_bytes::<BodyImuFrame>(d))
                    .map(|f| (f.header.seq, f))
                    .collect()
            })
            .unwrap_or_default();
        variants.push(Streams {
            name: v.name.clone(),
            motion: motion_of(&v.motion)?,
            validation,
            body_imu,
        });
    }

    let body = BodyModel::new(&BodyParams::builtin()?, 1.75, 70.0)?;
    let source_publish: BTreeMap<u32, u64> = truth
        .as_ref()
        .map(|t| t.iter().map(|(s, f)| (*s, f.header.publish_ns)).collect())
        .unwrap_or_default();

    // Every variant is scored on the same frames: those usable in all of them (and in the truth).
    // Calibrations end at different frames (a T-pose hold ends before a walking calibration).
    let common: BTreeSet<u32> = variants[0]
        .motion
        .keys()
        .copied()
        .filter(|seq| {
            let usable = |m: &BTreeMap<u32, MotionFrame>| {
                m.get(seq).is_some_and(|f| {
                    f.header.flags & SKIPPED_FLAGS == 0
                        && Pose::from_wire(&f.local_pose_wxyz, &f.root_position_m).is_ok()
                })
            };
            variants.iter().all(|v| usable(&v.motion)) && truth.as_ref().is_none_or(usable)
        })
        .collect();
    let on_common = |m: &BTreeMap<u32, MotionFrame>| -> Vec<MotionFrame> {
        common
            .iter()
            .filter_map(|seq| m.get(seq).copied())
            .collect()
    };
    let truth_frames = truth.as_ref().map(on_common);

    // Each variant's sensor set: its scores are taken on the joints it observes.
    let sets = combined
        .variants
        .iter()
        .map(|v| imuflow_body::SensorSet::resolve(&v.sensors))
        .collect::<Result<Vec<_>, _>>()?;
    let mut table = Table::new(variants.len());
    let mut series = Vec::new();
    for (k, v) in variants.iter().enumerate() {
        let estimate = on_common(&v.motion);
        let scores = match &truth_frames {
            Some(t) => score_against_truth(&estimate, t, &body, rate_hz),
            None => score_without_truth(&estimate, &body, rate_hz),
        };
        add_motion_rows(&mut table, k, &scores, truth.is_some());
        let set = &sets[k];
        let unobserved = unobserved_scores(set);
        for row in &unobserved {
            table.blank(row, k);
        }
        let observed = set.observed_joints();
        if !v.body_imu.is_empty() {
            let error = sensor_bone_error_deg(&estimate, &v.body_imu, &body, set.mask());
            table.set("sensor-bone error", "deg", true, k, error);
        }
        if !v.validation.is_empty() {
            let frames: Vec<ValidationFrame> = v
                .validation
                .iter()
                .filter(|f| common.contains(&(f.header.seq as u32)))
                .copied()
                .collect();
            let val = summarize_validation(&frames, rate_hz, body.mass_kg);
            table.set(
                "validation falls",
                "/min",
                true,
                k,
                Some(val.falls_per_minute),
            );
            let tracking = Some(100.0 * val.tracking_error_mean_m);
            table.set("validation tracking error", "cm", true, k, tracking);
            let skate = Some(val.foot_skate_mean_mps);
            table.set("validation foot skate", "m/s", true, k, skate);
            let support = Some(100.0 * val.support_violated_fraction);
            table.set("validation support violated", "%", true, k, support);
        }
        let latency_ms = latency_ms(&v.motion, &source_publish);
        if !latency_ms.is_empty() {
            let p = |q: f64| Some(percentile(&latency_ms, q));
            table.set("source-to-motion latency p50", "ms", true, k, p(0.5));
            table.set("source-to-motion latency p99", "ms", true, k, p(0.99));
        }
        // A set that leaves joints at rest: no whole-body error over time, and per joint only
        // where the joint's position follows from observed rotations (its parent's chain).
        let whole_body = !unobserved.contains(&"joint position error");
        let mut per_joint_cm = scores
            .per_joint
            .as_ref()
            .map_or([0.0; NUM_JOINTS], |j| j.joint_position_error_cm);
        for j in imuflow_body::JointId::all() {
            let placed = j.parent().is_none_or(|p| observed & (1 << p.index()) != 0);
            if !placed {
                per_joint_cm[j.index()] = f64::NAN;
            }
        }
        series.push(Series {
            name: v.name.clone(),
            error_cm: scores
                .per_frame
                .seq
                .iter()
                .zip(&scores.per_frame.joint_position_error_cm)
                .filter(|_| whole_body)
                .map(|(seq, e)| (*seq as u32, *e))
                .collect(),
            per_joint_cm,
            trajectory: estimate
                .iter()
                .map(|f| {
                    let [x, _, z] = f.root_position_m;
                    (f64::from(x), f64::from(z))
                })
                .collect(),
            latency_ms,
        });
    }
    if truth.is_none() {
        // Without truth: how far each variant is from the first.
        let first = &variants[0];
        for (k, v) in variants.iter().enumerate().skip(1) {
            let d = disagreement(&on_common(&first.motion), &on_common(&v.motion), &body);
            let name = &first.name;
            // An angle over joints one of the two leaves at rest says nothing about either.
            let both_observe = [&sets[0], &sets[k]]
                .into_iter()
                .all(|set| !unobserved_scores(set).contains(&"angle error"));
            let angle = d.angle_deg.filter(|_| both_observe);
            table.set(&format!("angle vs {name}"), "deg", false, k, angle);
            let root = d.root_distance_m;
            table.set(&format!("root distance vs {name}"), "m", false, k, root);
        }
    }
    let rows = table.rows;

    let truth_trajectory: Vec<(f64, f64)> = truth
        .as_ref()
        .map(|t| {
            common
                .iter()
                .filter_map(|seq| t.get(seq))
                .map(|f| {
                    (
                        f64::from(f.root_position_m[0]),
                        f64::from(f.root_position_m[2]),
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    // Each estimate starts where its calibration put the origin: draw it from the truth's start.
    if let Some(&(tx, tz)) = truth_trajectory.first() {
        for s in &mut series {
            if let Some(&(x0, z0)) = s.trajectory.first() {
                for p in &mut s.trajectory {
                    *p = (p.0 - x0 + tx, p.1 - z0 + tz);
                }
            }
        }
    }
    Ok(Scored {
        names: variants.into_iter().map(|v| v.name).collect(),
        rows,
        series,
        truth_trajectory,
        frames: common.len(),
        with_truth: truth.is_some(),
    })
}

/// Messages per topic, in file order (through replay's validating reader: a damaged chunk is an
/// error, not a crash).
fn read_topics(bytes: &[u8]) -> anyhow::Result<BTreeMap<String, Vec<Vec<u8>>>> {
    let mut topic_of: BTreeMap<u16, String> = BTreeMap::new();
    let mut topics: BTreeMap<String, Vec<Vec<u8>>> = BTreeMap::new();
    for_each_record(bytes, |n, record| {
        match record {
            mcap::records::Record::Channel(c) => {
                topic_of.insert(c.id, c.topic);
            }
            mcap::records::Record::Message { header, data } => {
                let topic = topic_of.get(&header.channel_id).with_context(|| {
                    format!(
                        "mcap record {n}: a message of undeclared channel {}",
                        header.channel_id
                    )
                })?;
                topics
                    .entry(topic.clone())
                    .or_default()
                    .push(data.into_owned());
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(topics)
}

/// The report's table under construction: rows in first-set order.
struct Table {
    rows: Vec<Row>,
    variants: usize,
}

impl Table {
    fn new(variants: usize) -> Table {
        Table {
            rows: Vec::new(),
            variants,
        }
    }

    /// Sets variant `k`'s value of row `name` (created on first use).
    fn set(&mut self, name: &str, unit: &str, lower_is_better: bool, k: usize, value: Option<f64>) {
        let row = match self.rows.iter().position(|r| r.name == name) {
            Some(i) => &mut self.rows[i],
            None => {
                self.rows.push(Row {
                    name: name.to_owned(),
                    unit: unit.to_owned(),
                    lower_is_better,
                    values: vec![None; self.variants],
                });
                self.rows.last_mut().expect("just pushed")
            }
        };
        row.values[k] = value;
    }

    /// Clears variant `k`'s value of row `name`, if the row exists.
    fn blank(&mut self, name: &str, k: usize) {
        if let Some(row) = self.rows.iter_mut().find(|r| r.name == name) {
            row.values[k] = None;
        }
    }
}

/// The rows of the pose scores whose joints the sensor set `set` (a variant's `sensors`) does not
/// all observe ([`imuflow_body::SensorSet::observed_joints`]): an estimate leaves those joints at
/// rest, so a score over them measures the rest pose, not the estimate. The report shows them
/// as not applicable (–) for that variant. For the six and for sets that observe all they do:
/// none.
pub(crate) fn unobserved_scores(set: &imuflow_body::SensorSet) -> Vec<&'static str> {
    use imuflow_body::JointId;
    let observes_all = |joints: &[JointId]| joints.iter().all(|j| set.observes(*j));
    let mut rows = Vec::new();
    if !observes_all(&imuflow_body::skeleton::SIP_JOINTS) {
        rows.push("SIP error");
    }
    if !observes_all(&imuflow_eval::metrics::LEG_JOINTS) {
        rows.push("leg angle error (hips, knees)");
    }
    if !observes_all(&[JointId::LEFT_KNEE, JointId::RIGHT_KNEE]) {
        rows.push("knee flexion error");
    }
    if !observes_all(&[JointId::LEFT_ELBOW, JointId::RIGHT_ELBOW]) {
        rows.push("elbow flexion error");
    }
    // The whole-body scores cover what the six observe (protocol G's joints).
    let six = imuflow_body::SensorSet::six().observed_joints();
    if six & !set.observed_joints() != 0 {
        rows.extend(["angle error", "joint position error", "jitter"]);
    }
    rows
}

/// The report's line under the table when a variant's set leaves scores out; `variants`: each
/// variant's name and sensor set.
pub(crate) fn unobserved_note<'a>(
    variants: impl IntoIterator<Item = (&'a str, &'a str)>,
) -> Option<String> {
    let mut parts = Vec::new();
    for (name, sensors) in variants {
        let rows = unobserved_scores(&imuflow_body::SensorSet::resolve(sensors).ok()?);
        if !rows.is_empty() {
            parts.push(format!("{name} (sensors `{sensors}`): {}", rows.join(", ")));
        }
    }
    (!parts.is_empty()).then(|| {
        format!(
            "Not scored (–), because the variant's sensor set does not observe every joint of the score and its estimate leaves those at rest: {}.",
            parts.join("; ")
        )
    })
}

/// The rows of one variant's motion scores.
fn add_motion_rows(table: &mut Table, k: usize, s: &MotionScores, with_truth: bool) {
    if with_truth {
        table.set("SIP error", "deg", true, k, s.sip_error_deg);
        table.set(
            "leg angle error (hips, knees)",
            "deg",
            true,
            k,
            s.leg_angle_error_deg,
        );
        table.set("angle error", "deg", true, k, s.angle_error_deg);
        table.set(
            "joint position error",
            "cm",
            true,
            k,
            s.joint_position_error_cm,
        );
        table.set(
            "knee flexion error",
            "deg",
            true,
            k,
            s.knee_flexion_error_deg,
        );
        table.set(
            "elbow flexion error",
            "deg",
            true,
            k,
            s.elbow_flexion_error_deg,
        );
    }
    table.set("jitter", "km/s³", true, k, s.jitter_km_s3);
    table.set("root jitter", "km/s³", true, k, s.root_jitter_km_s3);
    if with_truth {
        table.set(
            "translation error at 2 m",
            "m",
            true,
            k,
            s.translation_error_2m_m,
        );
        table.set(
            "translation error at 7 m",
            "m",
            true,
            k,
            s.translation_error_7m_m,
        );
        table.set("drift at 7 m", "%", true, k, s.translation_drift_percent);
        // 100 is right: neither more nor less is better, so no best is marked.
        table.set(
            "distance walked",
            "% of truth",
            false,
            k,
            s.distance_walked_percent,
        );
    }
    table.set("foot skating", "m/s", true, k, s.foot_skating_mps);
    let penetration = s.ground_penetration_m.map(|m| 100.0 * m);
    table.set("ground penetration", "cm", true, k, penetration);
    if with_truth {
        let deviation = s.standing_grf_deviation;
        table.set(
            "standing GRF deviation from mg",
            "fraction",
            true,
            k,
            deviation,
        );
    }
    table.set("frames scored", "", false, k, Some(s.frames as f64));
}

/// Per frame: from the source publishing it to the variant publishing its motion, ms.
fn latency_ms(motion: &BTreeMap<u32, MotionFrame>, source: &BTreeMap<u32, u64>) -> Vec<f64> {
    let mut ms: Vec<f64> = motion
        .iter()
        .filter_map(|(seq, f)| {
            let published = *source.get(seq)?;
            (f.header.publish_ns > published)
                .then(|| (f.header.publish_ns - published) as f64 * 1e-6)
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    ms
}

/// Nearest-rank percentile of sorted values.
fn percentile(sorted: &[f64], q: f64) -> f64 {
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

pub(super) fn fmt_value(v: Option<f64>) -> String {
    match v {
        None => "–".into(),
        Some(x) if x.abs() >= 100.0 => format!("{x:.0}"),
        Some(x) if x.abs() >= 10.0 => format!("{x:.1}"),
        Some(x) => format!("{x:.3}"),
    }
}

/// The best variant of a row (ties: none).
fn winner(row: &Row) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    let mut tie = false;
    for (k, v) in row.values.iter().enumerate() {
        let Some(v) = v.filter(|v| v.is_finite()) else {
            continue;
        };
        match best {
            None => best = Some((k, v)),
            Some((_, b)) => {
                let better = if row.lower_is_better { v < b } else { v > b };
                if better {
                    best = Some((k, v));
                    tie = false;
                } else if v == b {
                    tie = true;
                }
            }
        }
    }
    best.filter(|_| !tie).map(|(k, _)| k)
}

#[allow(clippy::too_many_arguments)]
fn markdown(
    name: &str,
    combined: &Combined,
    run: &RunReport,
    names: &[&str],
    rows: &[Row],
    plots: &[(String, PathBuf)],
    with_truth: bool,
    frames: usize,
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# imuflow compare: {}\n", names.join(" vs "));
    let _ = writeln!(
        md,
        "One run, identical input: shared stages {}; each variant's own stages ran as an isolated branch. {} every variant is scored on the same {frames} frames, those that no stream flagged calibrating, invalid or prelude.\n",
        combined.shared.join(", "),
        if with_truth {
            "Scored against the source's truth;"
        } else {
            "No truth in the source: scores that need it are missing, and the variants are compared with each other;"
        }
    );
    let _ = write!(md, "| metric |");
    for n in names {
        let _ = write!(md, " {n} |");
    }
    let _ = writeln!(md, " best |");
    let _ = writeln!(md, "|---|{}---|", "---:|".repeat(names.len()));
    for row in rows {
        let unit = if row.unit.is_empty() {
            String::new()
        } else {
            format!(" ({})", row.unit)
        };
        let _ = write!(md, "| {}{unit} |", row.name);
        let best = winner(row).filter(|_| row.lower_is_better);
        for (k, v) in row.values.iter().enumerate() {
            if best == Some(k) {
                let _ = write!(md, " **{}** |", fmt_value(*v));
            } else {
                let _ = write!(md, " {} |", fmt_value(*v));
            }
        }
        let _ = writeln!(md, " {} |", best.map_or("", |k| names[k]));
    }
    let sets = combined
        .variants
        .iter()
        .map(|v| (v.name.as_str(), v.sensors.as_str()));
    if let Some(note) = unobserved_note(sets) {
        let _ = writeln!(md, "\n{note}");
    }
    let _ = writeln!(
        md,
        "\nThe latency rows measure, per frame, the time from the source publishing it to the variant publishing its motion. In an offline run (the default) the source runs ahead as far as back-pressure lets it, so this includes queueing; run the graphs with `mode = \"live\"` for the latency a live session sees."
    );
    let _ = writeln!(md, "\n## Stages\n");
    let _ = writeln!(
        md,
        "| stage | kind | frames in | out | dropped | mean µs | p99 µs | busy % | input latency p50 µs |\n|---|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (id, (kind, s)) in &run.stages {
        let _ = writeln!(
            md,
            "| {id} | {kind} | {} | {} | {} | {:.0} | {:.0} | {:.1} | {:.0} |",
            s.frames_in,
            s.frames_out,
            s.dropped,
            s.mean_us,
            s.p99_us,
            100.0 * s.busy_fraction,
            s.latency_p50_us
        );
    }
    for b in &run.failed_branches {
        let _ = writeln!(
            md,
            "\n**Branch stopped:** stage `{}` failed ({}); stopped: {}.",
            b.stage,
            b.status,
            b.stopped.join(", ")
        );
    }
    if !plots.is_empty() {
        let _ = writeln!(md, "\n## Plots\n");
        for (title, path) in plots {
            let file = path
                .file_name()
                .map_or_else(String::new, |f| f.to_string_lossy().into_owned());
            let _ = writeln!(md, "### {title}\n\n![{title}]({file})\n");
        }
    }
    let _ = writeln!(
        md,
        "\nMetrics: imuflow_eval::score (definitions in tools/eval/README.md): pose errors with GlobalPose's protocol G (ankles, feet, wrists and hands masked, global rotations, positions root-aligned); jitter, skating, penetration, translation error at 2 m and 7 m of travel and drift at 7 m (GlobalPose §6) on the recorded joints; standing forces on frames where the truth stands still. The combined graph is `{name}.toml` in this folder."
    );
    md
}

fn results_json(
    combined: &Combined,
    run: &RunReport,
    names: &[&str],
    rows: &[Row],
) -> serde_json::Value {
    let metrics: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            serde_json::json!({
                "metric": r.name,
                "unit": r.unit,
                "lower_is_better": r.lower_is_better,
                        "values": names
                    .iter()
                    .zip(&r.values)
                    .map(|(n, v)| (n.to_string(), serde_json::json!(v)))
                    .collect::<serde_json::Map<_, _>>(),
                "best": winner(r).filter(|_| r.lower_is_better).map(|k| names[k]),
            })
        })
        .collect();
    let stages: serde_json::Map<String, serde_json::Value> = run
        .stages
        .iter()
        .map(|(id, (kind, s))| {
            (
                id.clone(),
                serde_json::json!({
                    "kind": kind, "frames_in": s.frames_in, "frames_out": s.frames_out,
                    "dropped": s.dropped, "mean_us": s.mean_us, "p99_us": s.p99_us,
                    "latency_p50_us": s.latency_p50_us, "latency_p99_us": s.latency_p99_us,
                    "detail": s.detail,
                }),
            )
        })
        .collect();
    serde_json::json!({
        "variants": combined.variants,
        "shared": combined.shared,
        "truth": combined.truth,
        "metrics": metrics,
        "stages": stages,
        "failed_branches": run.failed_branches.iter().map(|b| serde_json::json!({
            "stage": b.stage, "status": b.status, "stopped": b.stopped,
        })).collect::<Vec<_>>(),
        "wall_s": run.wall.as_secs_f64(),
    })
}
