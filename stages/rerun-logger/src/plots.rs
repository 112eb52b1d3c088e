//! The time series: every small field of every frame ([`Plots`], [`log_small_fields`]), the
//! INVALID flag as text events, and each estimate's errors against the truth (or, in a comparison
//! without one, against the first variant) and its latency from the source ([`ErrorSeries`]).

use std::collections::{BTreeMap, HashMap, HashSet};

use imuflow_body::JointId;
use imuflow_body::NUM_JOINTS;
use imuflow_body::rotation::angle_between;
use imuflow_body::skeleton::SIP_JOINTS;
use imuflow_graph::frames::{FrameHeader, FrameLayout, ScalarType, flags};
use imuflow_graph::transport::HeldFrame;

use crate::columns::{FrameTime, Log};

/// Fields with at most this many scalars are logged as time series.
const MAX_SERIES_SCALARS: usize = 6;
/// Truth frames kept for the error series (motion arrives a pipeline's latency after its truth).
pub(crate) const TRUTH_FRAMES_KEPT: usize = 1200;

/// The time series of a run, logged only once they say something: a series whose values never
/// change (a probability stuck at 0, an unused force, the truth's empty torques) would be a flat
/// plot taking screen space. Each series' first values are held back until a different value
/// arrives; then the held values are logged at their own time and the series is logged from then
/// on. The INVALID flag becomes text events at its changes instead of a 0/1 plot.
#[derive(Default)]
pub(crate) struct Plots {
    pub now: FrameTime,
    /// Series not yet logged: their first values and when they came.
    held: HashMap<String, (FrameTime, Vec<f64>)>,
    logged: HashSet<String>,
    /// Inputs whose last frame was flagged INVALID.
    invalid: HashSet<String>,
}

impl Plots {
    pub fn series(&mut self, rec: &mut Log, path: String, values: Vec<f64>) -> anyhow::Result<()> {
        if self.logged.contains(&path) {
            rec.log(path, &rerun::Scalars::new(values))?;
            return Ok(());
        }
        match self.held.get(&path) {
            None => {
                self.held.insert(path, (self.now, values));
            }
            Some((_, first)) if *first == values => {}
            Some(_) => {
                let (then, first) = self.held.remove(&path).expect("held");
                rec.set_time(then)?;
                rec.log(path.clone(), &rerun::Scalars::new(first))?;
                rec.set_time(self.now)?;
                rec.log(path.clone(), &rerun::Scalars::new(values))?;
                self.logged.insert(path);
            }
        }
        Ok(())
    }

    /// A text event where an input's INVALID flag turns on or off.
    pub fn flag_transition(
        &mut self,
        rec: &mut Log,
        input: &str,
        seq: u64,
        invalid: bool,
    ) -> anyhow::Result<()> {
        let was = self.invalid.contains(input);
        if invalid == was {
            return Ok(());
        }
        let (text, level) = if invalid {
            self.invalid.insert(input.to_owned());
            (
                format!(
                    "frame {seq}: {input} flagged INVALID (calibrating, a sensor missing, or unusable input)"
                ),
                rerun::TextLogLevel::WARN,
            )
        } else {
            self.invalid.remove(input);
            (
                format!("frame {seq}: {input} valid again"),
                rerun::TextLogLevel::INFO,
            )
        };
        rec.log(
            format!("{input}/events"),
            &rerun::TextLog::new(text).with_level(level),
        )?;
        Ok(())
    }
}

/// Logs every field with few scalars (probabilities, velocities, counters) as a time series, once
/// it has changed (see [`Plots`]).
pub(crate) fn log_small_fields(
    rec: &mut Log,
    plots: &mut Plots,
    input: &str,
    layout: &FrameLayout,
    held: &dyn HeldFrame,
) -> anyhow::Result<()> {
    let bytes = held.bytes();
    for field in layout.fields.iter().filter(|f| {
        !f.name.starts_with("header.")
            && f.len() <= MAX_SERIES_SCALARS
            && !f.name.starts_with("reserved")
    }) {
        let size = field.scalar.size();
        let values: Vec<f64> = (0..field.len())
            .filter_map(|i| bytes.get(field.offset + i * size..field.offset + (i + 1) * size))
            .map(|b| match field.scalar {
                ScalarType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ScalarType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                ScalarType::U64 => {
                    u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64
                }
            })
            .collect();
        if values.iter().all(|v| v.is_finite()) {
            plots.series(rec, format!("plots/{input}/{}", field.name), values)?;
        }
    }
    Ok(())
}

/// What the error series compare of one frame: the world positions of the 24 joints (m) and the
/// global rotations of the SIP joints (hips, shoulders).
#[derive(Clone, Copy)]
pub(crate) struct Posed {
    pub joints: [[f32; 3]; NUM_JOINTS],
    pub sip: [nalgebra::Rotation3<f64>; SIP_JOINTS.len()],
    /// The joints the pose holds (every joint; a sensor set's estimate: those it observes and
    /// places): the errors are measured on those.
    pub holds: crate::skeleton::Estimated,
}

/// The error and latency series of the estimates.
pub(crate) struct ErrorSeries {
    /// What estimates are measured against, by seq: the truth's joints when there is a truth
    /// input, else (in a comparison) the first group's estimate.
    reference: Option<Reference>,
    /// The source's publish time of each seq (the truth's frames), for the latency series.
    source_publish_ns: BTreeMap<u64, u64>,
}

/// The stream estimates are compared with, and its joints by seq.
struct Reference {
    /// `truth`, or the first group's `<group>/motion`.
    entity: String,
    /// Where the series go: `plots/error_vs_truth` or `plots/disagreement_vs_<group>`.
    plots: String,
    joints: BTreeMap<u64, Posed>,
    /// Estimates that arrived before the reference's frame of their seq (variants finish frames
    /// in any order), logged when it comes.
    pending: BTreeMap<u64, Vec<(String, Posed)>>,
}

impl ErrorSeries {
    pub fn new(groups: &[String], has_truth: bool) -> ErrorSeries {
        let reference = if has_truth {
            Some(Reference {
                entity: "truth".into(),
                plots: "plots/error_vs_truth".into(),
                joints: Default::default(),
                pending: Default::default(),
            })
        } else {
            // Without truth, a comparison shows how far each variant is from the first.
            groups
                .first()
                .filter(|_| groups.len() > 1)
                .map(|g| Reference {
                    entity: format!("{g}/motion"),
                    plots: format!("plots/disagreement_vs_{g}"),
                    joints: Default::default(),
                    pending: Default::default(),
                })
        };
        ErrorSeries {
            reference,
            source_publish_ns: Default::default(),
        }
    }

    /// Keeps the reference's joints, or logs this estimate's error against the reference's frame
    /// of the same seq (and, in a comparison, its latency from the source).
    pub fn track(
        &mut self,
        rec: &mut Log,
        entity: &str,
        header: &FrameHeader,
        posed: &Posed,
    ) -> anyhow::Result<()> {
        let seq = header.seq;
        if entity == "truth" {
            self.source_publish_ns.insert(seq, header.publish_ns);
            while self.source_publish_ns.len() > TRUTH_FRAMES_KEPT {
                self.source_publish_ns.pop_first();
            }
        }
        // Calibrating and invalid frames are not estimates of the motion: no error for them.
        let is_estimate = (entity == "motion" || entity.ends_with("/motion"))
            && header.flags & (flags::INVALID | flags::CALIBRATING) == 0;
        let group = group_of(entity).unwrap_or(entity);
        if is_estimate
            && let Some(published) = self.source_publish_ns.get(&seq)
            && header.publish_ns >= *published
        {
            // Source publish to this variant's motion publish: the variant's whole pipeline.
            let ms = (header.publish_ns - published) as f64 * 1e-6;
            rec.log(
                format!("plots/latency_ms/{group}"),
                &rerun::Scalars::single(ms),
            )?;
        }
        let Some(reference) = &mut self.reference else {
            return Ok(());
        };
        if entity == reference.entity {
            reference.joints.insert(seq, *posed);
            while reference.joints.len() > TRUTH_FRAMES_KEPT {
                reference.joints.pop_first();
            }
            for (waiting, estimate) in reference.pending.remove(&seq).unwrap_or_default() {
                log_difference(rec, &reference.plots, &waiting, &estimate, posed)?;
            }
            return Ok(());
        }
        if !is_estimate {
            return Ok(());
        }
        match reference.joints.get(&seq) {
            Some(truth) => log_difference(rec, &reference.plots, entity, posed, truth),
            None => {
                reference
                    .pending
                    .entry(seq)
                    .or_default()
                    .push((entity.to_owned(), *posed));
                while reference.pending.len() > TRUTH_FRAMES_KEPT {
                    reference.pending.pop_first();
                }
                Ok(())
            }
        }
    }

    /// The truth's frame of `seq`, while it is kept (none without a truth input).
    pub fn truth(&self, seq: u64) -> Option<&Posed> {
        self.reference
            .as_ref()
            .filter(|r| r.entity == "truth")
            .and_then(|r| r.joints.get(&seq))
    }
}

/// Logs an estimate's SIP error (deg: the mean angle between its and the reference's global
/// rotations of hips and shoulders, as `imuflow compare`), root-aligned mean joint distance (cm)
/// and root distance (m) from the reference under `<plots>/<group>/`.
fn log_difference(
    rec: &mut Log,
    plots: &str,
    entity: &str,
    estimate: &Posed,
    reference: &Posed,
) -> anyhow::Result<()> {
    // On the joints both hold (a sensor set's estimate leaves the others at rest).
    let measured = estimate.holds.drawn & reference.holds.drawn;
    let (joint_cm, root_m) = error_against_truth(&estimate.joints, &reference.joints, measured);
    let base = format!("{plots}/{}", group_of(entity).unwrap_or(entity));
    let observed = estimate.holds.observed & reference.holds.observed;
    if SIP_JOINTS.iter().all(|j| observed & (1 << j.index()) != 0) {
        let sip_deg = estimate
            .sip
            .iter()
            .zip(&reference.sip)
            .map(|(a, b)| angle_between(a, b).to_degrees())
            .sum::<f64>()
            / SIP_JOINTS.len() as f64;
        rec.log(format!("{base}/sip_deg"), &rerun::Scalars::single(sip_deg))?;
    }
    rec.log(
        format!("{base}/joint_position_cm"),
        &rerun::Scalars::single(joint_cm),
    )?;
    rec.log(
        format!("{base}/root_distance_m"),
        &rerun::Scalars::single(root_m),
    )?;
    Ok(())
}

/// Mean joint position error over the joints of `measured` (a mask over joint indices) after
/// aligning the roots (cm), and the roots' distance (m).
fn error_against_truth(
    joints: &[[f32; 3]; NUM_JOINTS],
    truth: &[[f32; 3]; NUM_JOINTS],
    measured: u32,
) -> (f64, f64) {
    let root = JointId::ROOT.index();
    let offset: [f64; 3] = std::array::from_fn(|k| f64::from(joints[root][k] - truth[root][k]));
    let (mut sum_m, mut n) = (0.0, 0usize);
    for (j, (p, t)) in joints.iter().zip(truth).enumerate() {
        if measured & (1 << j) == 0 {
            continue;
        }
        let d: f64 = (0..3)
            .map(|k| (f64::from(p[k] - t[k]) - offset[k]).powi(2))
            .sum();
        sum_m += d.sqrt();
        n += 1;
    }
    let root_m = offset.iter().map(|x| x * x).sum::<f64>().sqrt();
    (100.0 * sum_m / n.max(1) as f64, root_m)
}

/// The group of an entity path, if it has one. Here, below the other modules, because everything
/// the logger draws or plots goes by group: the error series' paths, the skeletons' colours, the
/// views.
pub(crate) fn group_of(entity: &str) -> Option<&str> {
    entity.split_once('/').map(|(group, _)| group)
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::skeleton::ALL_JOINTS;

    #[test]
    fn error_against_truth_aligns_roots_and_reports_their_distance() {
        let truth: [[f32; 3]; NUM_JOINTS] = std::array::from_fn(|j| [0.0, j as f32 * 0.1, 0.0]);
        // Shifted 0.3 m sideways, one joint 0.24 m off on top: 0.24 m / 24 joints = 1 cm.
        let mut estimate = truth.map(|[x, y, z]| [x + 0.3, y, z]);
        estimate[5][2] += 0.24;
        let (joint_cm, root_m) = error_against_truth(&estimate, &truth, ALL_JOINTS);
        assert!((joint_cm - 1.0).abs() < 1e-4, "{joint_cm}");
        assert!((root_m - 0.3).abs() < 1e-6, "{root_m}");
        // Over joints 4 to 7 only: 0.24 m / 4 joints = 6 cm.
        let (joint_cm, _) = error_against_truth(&estimate, &truth, 0b1111_0000);
        assert!((joint_cm - 6.0).abs() < 1e-4, "{joint_cm}");
    }
}
