//! What a finished run reports, and the summary table `imuflow run` prints from it.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::Duration;

use crate::stats::{InputLatency, StageSummary};

use super::tail_text;

/// What a finished run reports.
#[derive(Debug, Clone)]
pub struct RunReport {
    pub run_id: String,
    /// The graph's name (`name` in the graph file).
    pub graph_name: String,
    /// Stage ids in the graph's topological order: the summary lists the stages in it.
    pub stage_order: Vec<String>,
    /// The sink stages: the summary's end-to-end latency table lists their inputs.
    pub sinks: BTreeSet<String>,
    /// Per stage: its kind label and summary.
    pub stages: BTreeMap<String, (String, StageSummary)>,
    /// From the go (every stage ready and connected) to the last stage's exit: the stream.
    pub wall: Duration,
    /// From the first spawn to the go: processes started, weights loaded, ports connected.
    pub startup: Duration,
    /// The user stopped the run (Ctrl-C); outputs were finalized.
    pub interrupted: bool,
    /// Isolated branches that failed and were stopped while the rest of the graph ran on.
    pub failed_branches: Vec<FailedBranch>,
    /// Stages that failed and were started again (`restart` policy): how often, and why.
    pub restarts: BTreeMap<String, Vec<String>>,
}

/// A branch stopped because one of its stages failed (`on_failure = "stop-branch"`).
#[derive(Debug, Clone)]
pub struct FailedBranch {
    /// The `stop-branch` stage that heads the branch.
    pub root: String,
    /// The stage that failed.
    pub stage: String,
    /// How it ended ("exited with code 3", "killed by signal 9").
    pub status: String,
    pub stderr_tail: Vec<String>,
    /// Every stage of the branch, in id order.
    pub stopped: Vec<String>,
}

impl std::fmt::Display for FailedBranch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "stage '{}' failed: {}; its branch ({}) was stopped, the rest of the graph ran to the end{}",
            self.stage,
            self.status,
            self.stopped.join(", "),
            tail_text(&self.stderr_tail)
        )
    }
}

/// The summary `imuflow run` prints: a title, a row per stage in topological order, live graphs'
/// end-to-end latency per sink input, each stage's own result line, restarts and failed branches.
/// Lines are separated, not ended, by newlines: `println!("{report}")` prints it.
impl fmt::Display for RunReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "graph '{}' finished in {:.2} s after a start-up of {:.2} s (run {})",
            self.graph_name,
            self.wall.as_secs_f64(),
            self.startup.as_secs_f64(),
            self.run_id
        )?;
        // Columns as wide as the longest id and kind (exec stages: `exec:smooth.py`).
        let id_width = self
            .rows()
            .map(|(id, _, _)| id.len())
            .max()
            .unwrap_or(0)
            .max(14);
        let kind_width = self
            .rows()
            .map(|(_, k, _)| k.len())
            .max()
            .unwrap_or(0)
            .max(14);
        write!(
            f,
            "\n{:<id_width$} {:<kind_width$} {:>9} {:>9} {:>8} {:>10} {:>10} {:>7} {:>12} {:>12}",
            "stage",
            "kind",
            "frames in",
            "out",
            "dropped",
            "mean µs",
            "p99 µs",
            "busy %",
            "in-lat p50",
            "in-lat p99"
        )?;
        for (id, kind, s) in self.rows() {
            write!(
                f,
                "\n{:<id_width$} {:<kind_width$} {:>9} {:>9} {:>8} {:>10.1} {:>10.1} {:>7.1} {:>12.1} {:>12.1}",
                id,
                kind,
                s.frames_in,
                s.frames_out,
                s.dropped,
                s.mean_us,
                s.p99_us,
                100.0 * s.busy_fraction,
                s.latency_p50_us,
                s.latency_p99_us
            )?;
        }
        self.fmt_from_capture(f)?;
        for (id, _, s) in self.rows().filter(|(_, _, s)| !s.detail.is_empty()) {
            write!(f, "\n{id}: {}", s.detail)?;
        }
        for (stage, why) in &self.restarts {
            write!(
                f,
                "\nrestarted '{stage}' {} time(s): {}",
                why.len(),
                why.join("; ")
            )?;
        }
        for branch in &self.failed_branches {
            write!(
                f,
                "\nbranch of '{}' stopped ({} failed): {}",
                branch.root,
                branch.stage,
                branch.stopped.join(", ")
            )?;
        }
        Ok(())
    }
}

impl RunReport {
    /// The stages in topological order: id, kind label, summary.
    fn rows(&self) -> impl Iterator<Item = (&String, &String, &StageSummary)> {
        self.stage_order
            .iter()
            .filter_map(|id| self.stages.get(id).map(|(kind, s)| (id, kind, s)))
    }

    /// Live runs: each sink input's end-to-end latency, from the source's capture to arrival.
    /// Offline runs have none, and print no table.
    fn fmt_from_capture(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let rows: Vec<(String, &InputLatency)> = self
            .rows()
            .filter(|(id, _, _)| self.sinks.contains(*id))
            .flat_map(|(id, _, s)| {
                s.from_capture
                    .iter()
                    .map(move |l| (format!("{id}.{}", l.input), l))
            })
            .collect();
        if rows.is_empty() {
            return Ok(());
        }
        write!(
            f,
            "\n{:<28} {:>9} {:>10} {:>10} {:>10}",
            "end to end (capture→sink)", "frames", "p50 ms", "p99 ms", "max ms"
        )?;
        for (input, l) in rows {
            write!(
                f,
                "\n{:<28} {:>9} {:>10.2} {:>10.2} {:>10.2}",
                input,
                l.frames,
                l.p50_us * 1e-3,
                l.p99_us * 1e-3,
                l.max_us * 1e-3
            )?;
        }
        Ok(())
    }
}

pub(super) fn empty_summary() -> StageSummary {
    StageSummary {
        frames_in: 0,
        frames_out: 0,
        dropped: 0,
        unmatched: 0,
        mean_us: 0.0,
        p99_us: 0.0,
        max_us: 0.0,
        wall_s: 0.0,
        busy_fraction: 0.0,
        latency_p50_us: 0.0,
        latency_p99_us: 0.0,
        detail: String::new(),
        from_capture: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::InputLatency;

    fn summary(frames_in: u64, mean_us: f64, busy_fraction: f64) -> StageSummary {
        StageSummary {
            frames_in,
            frames_out: frames_in / 2,
            dropped: 3,
            mean_us,
            p99_us: mean_us * 2.0,
            busy_fraction,
            latency_p50_us: 41.25,
            latency_p99_us: 1234.5,
            ..empty_summary()
        }
    }

    /// A live run: stages listed in topological order (not id order), the id column widened to
    /// the longest id and the kind column to the longest kind, the end-to-end table for sink
    /// inputs only, then result lines, restarts and the failed branch.
    #[test]
    fn the_summary_lists_stages_in_topological_order_with_every_section() {
        let mut sink = summary(600, 12.34, 0.0125);
        sink.detail = "MPJPE 41.2 mm".to_owned();
        sink.from_capture = vec![InputLatency {
            input: "motion".to_owned(),
            frames: 598,
            p50_us: 8_123.0,
            p99_us: 15_678.9,
            max_us: 21_000.0,
        }];
        let mut relay = summary(597, 1.0, 0.5);
        // Not a sink: its capture latency is not the graph's end-to-end latency.
        relay.from_capture = sink.from_capture.clone();
        let report = RunReport {
            run_id: "1a2b3c".to_owned(),
            graph_name: "pip".to_owned(),
            stage_order: vec!["src".into(), "smoothing-relay-stage".into(), "eval".into()],
            sinks: ["eval".to_owned()].into(),
            stages: [
                ("eval", "scores-out", sink),
                ("smoothing-relay-stage", "exec:smooth_motion.py", relay),
                ("src", "any-source", summary(0, 0.0, 0.0)),
            ]
            .into_iter()
            .map(|(id, kind, s)| (id.to_owned(), (kind.to_owned(), s)))
            .collect(),
            wall: Duration::from_millis(10_125),
            startup: Duration::from_millis(1_504),
            interrupted: false,
            failed_branches: vec![FailedBranch {
                root: "view".to_owned(),
                stage: "view".to_owned(),
                status: "exited with code 3".to_owned(),
                stderr_tail: vec!["boom".to_owned()],
                stopped: vec!["view".to_owned()],
            }],
            restarts: [(
                "smoothing-relay-stage".to_owned(),
                vec![
                    "killed by signal 9".to_owned(),
                    "exited with code 1".to_owned(),
                ],
            )]
            .into(),
        };
        let expected = "\
graph 'pip' finished in 10.12 s after a start-up of 1.50 s (run 1a2b3c)
stage                 kind                  frames in       out  dropped    mean µs     p99 µs  busy %   in-lat p50   in-lat p99
src                   any-source                    0         0        3        0.0        0.0     0.0         41.2       1234.5
smoothing-relay-stage exec:smooth_motion.py       597       298        3        1.0        2.0    50.0         41.2       1234.5
eval                  scores-out                  600       300        3       12.3       24.7     1.2         41.2       1234.5
end to end (capture→sink)       frames     p50 ms     p99 ms     max ms
eval.motion                        598       8.12      15.68      21.00
eval: MPJPE 41.2 mm
restarted 'smoothing-relay-stage' 2 time(s): killed by signal 9; exited with code 1
branch of 'view' stopped (view failed): view";
        assert_eq!(report.to_string(), expected);
    }

    /// An offline run: no capture clock, no end-to-end table; short ids and kinds keep the
    /// columns 14 wide; nothing after the table.
    #[test]
    fn an_offline_summary_is_the_title_and_the_table() {
        let report = RunReport {
            run_id: "ff00".to_owned(),
            graph_name: "tiny".to_owned(),
            stage_order: vec!["src".into(), "rec".into()],
            sinks: ["rec".to_owned()].into(),
            stages: [
                (
                    "rec".to_owned(),
                    ("file-out".to_owned(), summary(10, 2.0, 0.25)),
                ),
                (
                    "src".to_owned(),
                    ("synth-frames".to_owned(), summary(0, 0.0, 0.0)),
                ),
            ]
            .into(),
            wall: Duration::from_millis(250),
            startup: Duration::from_millis(40),
            interrupted: false,
            failed_branches: Vec::new(),
            restarts: BTreeMap::new(),
        };
        let expected = "\
graph 'tiny' finished in 0.25 s after a start-up of 0.04 s (run ff00)
stage          kind           frames in       out  dropped    mean µs     p99 µs  busy %   in-lat p50   in-lat p99
src            synth-frames           0         0        3        0.0        0.0     0.0         41.2       1234.5
rec            file-out              10         5        3        2.0        4.0    25.0         41.2       1234.5";
        assert_eq!(report.to_string(), expected);
    }
}
