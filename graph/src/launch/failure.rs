//! A failed stage (exited with an error, killed, ended its stream early, or stalled): its
//! `restart` policy starts it again, or its `on_failure` policy stops its branch or the run.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use crate::transport;

use super::RunError;
use super::report::FailedBranch;
use super::spawn::Running;
use super::supervise::{Supervisor, stop_all};

/// How a stage failed.
pub(super) enum Failure {
    /// It exited with an error or was killed (the status, described).
    Ended(String),
    /// The stall watchdog found it sitting on its input (what it waited on).
    Stalled(String),
}

impl Supervisor<'_> {
    /// A failed stage with a `restart` policy that allows one more is started again after its
    /// backoff (a stalled one is killed first); otherwise (or once the policy is spent) its
    /// failure policy applies.
    pub(super) fn fail_or_restart(
        &mut self,
        stages: &mut [Running],
        i: usize,
        failure: Failure,
        stderr_tail: Vec<String>,
    ) -> Result<(), RunError> {
        let stage = stages[i].id.clone();
        let why = match &failure {
            Failure::Ended(status) => status.clone(),
            Failure::Stalled(detail) => format!("stalled: {detail}"),
        };
        let policy = self.graph.stages.get(&stage).and_then(|n| n.restart);
        if let Some(policy) = policy
            && !self.stopping
        {
            let now = Instant::now();
            let window = Duration::from_secs_f64(policy.within_s);
            let s = &mut stages[i];
            s.restarted_at.retain(|t| now.duration_since(*t) < window);
            if (s.restarted_at.len() as u32) < policy.max {
                s.restarted_at.push(now);
                s.restart_due = Some(now + Duration::from_millis(policy.backoff_ms));
                if s.exit.is_none() {
                    // Stalled: the process still exists (hung, or stopped). It goes now; its
                    // ports are cleaned up when the restart is due.
                    s.signal(libc::SIGCONT);
                    s.signal(libc::SIGKILL);
                }
                let n = s.restarted_at.len();
                tracing::warn!(
                    "stage '{stage}' {why}; restarting it ({n} of {} within {} s)",
                    policy.max,
                    policy.within_s
                );
                self.restarts.entry(stage).or_default().push(why);
                return Ok(());
            }
            let failure = Failure::Ended(format!(
                "{why}, after {} restart(s) within {} s (restart.max = {})",
                s.restarted_at.len(),
                policy.within_s,
                policy.max
            ));
            return self.handle_failure(stages, stage, failure, stderr_tail);
        }
        self.handle_failure(stages, stage, failure, stderr_tail)
    }

    /// Applies a failed stage's policy: its isolated branch stops (and is reported at the end), or
    /// the whole run stops with the failure as its error.
    fn handle_failure(
        &mut self,
        stages: &mut [Running],
        stage: String,
        failure: Failure,
        stderr_tail: Vec<String>,
    ) -> Result<(), RunError> {
        match self.graph.isolated_branch_of(&stage) {
            Some((root, branch)) => {
                self.stop_branch(stages, &branch);
                let status = match failure {
                    Failure::Ended(status) => status,
                    Failure::Stalled(detail) => format!("stalled: {detail}"),
                };
                self.failed_branches.push(FailedBranch {
                    root,
                    stage,
                    status,
                    stderr_tail,
                    stopped: branch.into_iter().collect(),
                });
                Ok(())
            }
            None => {
                stop_all(stages);
                Err(match failure {
                    Failure::Ended(status) => RunError::StageFailed {
                        stage,
                        status,
                        stderr_tail,
                    },
                    Failure::Stalled(detail) => RunError::Stalled {
                        stage,
                        detail,
                        stderr_tail,
                    },
                })
            }
        }
    }

    /// Stops every stage of `branch` (SIGTERM: they finalize; SIGKILL after a grace period) and tells
    /// each stage outside it which of its inputs will never see END_OF_STREAM.
    fn stop_branch(&self, stages: &mut [Running], branch: &BTreeSet<String>) {
        let now = Instant::now();
        for s in stages.iter_mut().filter(|s| branch.contains(&s.id)) {
            // A stopped (SIGSTOP) process handles SIGTERM only once it runs again.
            s.signal(libc::SIGCONT);
            s.signal(libc::SIGTERM);
            s.branch_stopped_at.get_or_insert(now);
        }
        for s in stages.iter_mut().filter(|s| !branch.contains(&s.id)) {
            let Some(node) = self.graph.stages.get(&s.id) else {
                continue;
            };
            let gone: BTreeSet<&String> = node
                .inputs
                .values()
                .map(|e| &e.from_stage)
                .filter(|from| branch.contains(*from))
                .collect();
            for from in gone {
                s.send(&format!("ended {from}"));
            }
        }
        self.disconnect_dead_readers();
    }

    /// iceoryx2's dead-node cleanup: the ports of a killed stage are removed, so an offline writer
    /// retrying into its full buffer sees the reader gone and moves on.
    pub(super) fn disconnect_dead_readers(&self) {
        if let Err(e) = transport::cleanup_dead_nodes(self.shm_prefix) {
            tracing::warn!("cannot clean up the ports of a stopped branch: {e}");
        }
    }
}
