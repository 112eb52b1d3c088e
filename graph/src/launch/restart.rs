//! Restarts (the `restart` policy): once a failed stage's backoff has passed, a new process takes
//! its place and walks through the handshake on its own while the rest of the graph runs.

use std::collections::BTreeSet;
use std::time::Instant;

use super::RunError;
use super::spawn::Running;
use super::supervise::Supervisor;

/// Where a restarted stage is in its handshake.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Rejoin {
    Starting,
    ConnectSent,
}

impl Supervisor<'_> {
    /// Starts every stage whose restart is due: the dead process's ports are cleaned up first (so
    /// its writers and readers move on), then a new process joins the running graph.
    pub(super) fn restart_due_stages(&mut self, stages: &mut [Running]) -> Result<(), RunError> {
        let now = Instant::now();
        for (i, stage) in stages.iter_mut().enumerate() {
            if stage.restart_due.is_none_or(|due| due > now) {
                continue;
            }
            if stage.exit.is_none() {
                // A stalled process killed for this restart: gone before its ports are cleaned.
                stage.exit = stage.child.wait().ok();
            }
            self.disconnect_dead_readers();
            let Some(node) = self.graph.stages.get(&stage.id) else {
                continue;
            };
            let count = stage.restarted_at.len() as u32;
            for handle in stage.readers.drain(..) {
                let _ = handle.join();
            }
            let fresh = self.spawner.spawn(node, i, count)?;
            *stage = Running {
                restarted_at: std::mem::take(&mut stage.restarted_at),
                rejoining: Some(Rejoin::Starting),
                ..fresh
            };
        }
        Ok(())
    }

    /// Walks stages restarted during start-up (before the first `go`) through the start-up
    /// handshake: before the `connect` went out to all, a restarted stage is one more to wait for;
    /// after, it is told to connect once it is ready. Its `go` comes with everyone's.
    pub(super) fn join_start(&self, stages: &mut [Running], connect_sent: bool) {
        for s in stages.iter_mut() {
            if s.rejoining != Some(Rejoin::Starting) {
                continue;
            }
            if !connect_sent {
                s.rejoining = None;
            } else if s.ready {
                s.send("connect");
                s.rejoining = None;
            }
        }
    }

    /// Walks restarted stages through their handshake on their own: once ready they connect, once
    /// connected they go (the rest of the graph is running already), told which of their
    /// producers have finished meanwhile (their END_OF_STREAM went out before the new process
    /// was there to read it).
    pub(super) fn rejoin(&self, stages: &mut [Running]) {
        if stages.iter().all(|s| s.rejoining.is_none()) {
            return; // the usual case, checked every poll
        }
        let finished: BTreeSet<String> = stages
            .iter()
            .filter(|s| s.summary.is_some() || s.branch_stopped_at.is_some())
            .map(|s| s.id.clone())
            .collect();
        for s in stages.iter_mut() {
            match s.rejoining {
                Some(Rejoin::Starting) if s.ready => {
                    s.send("connect");
                    s.rejoining = Some(Rejoin::ConnectSent);
                }
                Some(Rejoin::ConnectSent) if s.connected => {
                    s.send("go");
                    let producers: BTreeSet<String> = self
                        .graph
                        .stages
                        .get(&s.id)
                        .map(|n| n.inputs.values().map(|e| e.from_stage.clone()).collect())
                        .unwrap_or_default();
                    for from in producers.intersection(&finished) {
                        s.send(&format!("ended {from}"));
                    }
                    s.rejoining = None;
                    s.moved_at = Instant::now();
                    s.heard_at = Instant::now();
                }
                _ => {}
            }
        }
    }
}
