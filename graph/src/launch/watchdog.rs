//! The stall watchdog: a stage that went quiet, or sits on input it does not take, fails.

use super::RunError;
use super::failure::Failure;
use super::spawn::Running;
use super::supervise::Supervisor;

impl Supervisor<'_> {
    /// The stall watchdog. A stage that sent no heartbeat for its `stall_timeout_s` is not running
    /// (stopped, frozen); a stage whose every forward input holds frames it has not taken (its
    /// least advanced producer is ahead of it) and whose position has not moved for that long is
    /// hung. Either is handled like a failed stage (its branch stops, or the run). Positions come
    /// from the stages' heartbeats, not from their logs; a stage waiting on a slow producer is not
    /// behind it, and a source blocked by back-pressure still sends heartbeats.
    pub(super) fn watch_for_stalls(&mut self, stages: &mut [Running]) -> Result<(), RunError> {
        for i in 0..stages.len() {
            let s = &stages[i];
            if s.exit.is_some()
                || s.branch_stopped_at.is_some()
                || s.summary.is_some()
                || s.restart_due.is_some()
            {
                continue;
            }
            let Some(node) = self.graph.stages.get(&s.id) else {
                continue;
            };
            let timeout_s = node.stall_timeout_s(self.graph);
            // Any stage, sources included: a process that sends no heartbeat is not running.
            // (A source has no input to sit on; frozen, it would hold its readers forever.)
            let quiet = s.heard_at.elapsed();
            if quiet.as_secs_f64() >= timeout_s {
                let detail = format!(
                    "no heartbeat for {:.0} s (stall_timeout_s = {timeout_s}): the process is not running (stopped or frozen)",
                    quiet.as_secs_f64()
                );
                let stage = s.id.clone();
                let stderr_tail = s.tail_now();
                tracing::warn!("stage '{stage}' stalled: {detail}");
                self.fail_or_restart(stages, i, Failure::Stalled(detail), stderr_tail)?;
                continue;
            }
            let still = s.moved_at.elapsed();
            if still.as_secs_f64() < timeout_s {
                continue;
            }
            let least_ahead = node
                .inputs
                .values()
                .filter(|e| !e.feedback)
                .filter_map(|e| stages.iter().find(|r| r.id == e.from_stage))
                .map(|r| (r.id.clone(), r.position))
                .min_by_key(|(_, position)| *position);
            let Some((from, waiting)) = least_ahead else {
                continue;
            };
            if waiting <= s.position {
                continue;
            }
            // A stage busy in its own code keeps sending heartbeats while it stands still; a
            // stopped or frozen process went quiet when it stopped moving.
            let quiet = s.heard_at.elapsed();
            let process = if quiet + crate::stage::HEARTBEAT * 2 >= still {
                format!(
                    "no heartbeat for {:.0} s: the process is not running (stopped or frozen)",
                    quiet.as_secs_f64()
                )
            } else {
                "the process is alive: stuck in its own code or waiting on something outside the graph"
                    .to_owned()
            };
            let taken = match s.position {
                0 => "no frame yet".to_owned(),
                p => format!("frames up to {}", p - 1),
            };
            let detail = format!(
                "took no frame for {:.0} s (stall_timeout_s = {timeout_s}) while its inputs held frames up to {} (from '{from}'); it took {taken}; {process}",
                still.as_secs_f64(),
                waiting - 1
            );
            let stage = s.id.clone();
            let stderr_tail = s.tail_now();
            tracing::warn!("stage '{stage}' stalled: {detail}");
            self.fail_or_restart(stages, i, Failure::Stalled(detail), stderr_tail)?;
        }
        Ok(())
    }
}
