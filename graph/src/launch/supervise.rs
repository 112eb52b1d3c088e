//! The supervision loop: every stage through the handshake (ready, connect, go), then the stream
//! to its end, reaping exits, forwarding logs and progress, and stopping on Ctrl-C.

use std::collections::BTreeMap;
use std::process::ExitStatus;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use crate::graph::Graph;
use crate::spec::Role;
use crate::stage::ControlMessage;

use super::failure::Failure;
use super::report::FailedBranch;
use super::spawn::{Event, Running, Spawner};
use super::{LaunchOptions, RunError};

/// After a stop request, how long stages get to drain before SIGTERM.
const DRAIN_GRACE: Duration = Duration::from_secs(5);
/// After SIGTERM, how long stages get to finalize before SIGKILL.
const TERM_GRACE: Duration = Duration::from_secs(3);
/// How often the supervisor polls its children.
const POLL: Duration = Duration::from_millis(5);

/// What the supervision loop needs besides the stages: the graph (for branches), the run's
/// shared-memory domain (for dead-node cleanup) and what failed so far.
pub(super) struct Supervisor<'a> {
    pub(super) graph: &'a Graph,
    pub(super) shm_prefix: &'a str,
    /// Starts restarted stages.
    pub(super) spawner: &'a Spawner<'a>,
    pub(super) failed_branches: Vec<FailedBranch>,
    /// Per restarted stage: why, each time.
    pub(super) restarts: BTreeMap<String, Vec<String>>,
    /// The user asked the run to stop (Ctrl-C): stages ending with errors are part of stopping.
    pub(super) stopping: bool,
}

impl Supervisor<'_> {
    pub(super) fn supervise(
        &mut self,
        options: &LaunchOptions,
        stages: &mut [Running],
        rx: &Receiver<Event>,
        interrupted: &AtomicBool,
    ) -> Result<(Duration, bool), RunError> {
        let graph = self.graph;
        let bar = if options.progress {
            let bar = indicatif::ProgressBar::new(0);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} {elapsed_precise} [{bar:40}] {pos}/{len} frames ({per_sec}, eta {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            bar
        } else {
            indicatif::ProgressBar::hidden()
        };
        let log = |stages: &[Running], index: usize, line: &str| {
            if options.forward_logs {
                let id = stages.get(index).map_or("?", |s| s.id.as_str());
                bar.suspend(|| eprintln!("[{id}] {line}"));
            }
        };

        // Phase 1: every stage creates its ports (ready), then connects its readers (connected).
        // Only then may frames flow: a reader that is not yet connected would miss them.
        let ready_deadline = Instant::now() + Duration::from_secs_f64(graph.ready_timeout_s);
        let mut connect_sent = false;
        let waiting = |s: &Running| !s.connected && s.branch_stopped_at.is_none();
        while stages.iter().any(waiting) {
            handle_events(stages, rx, &bar, &log)?;
            self.reap(stages)?;
            if interrupted.load(Ordering::Relaxed) {
                stop_all(stages);
                return Ok((Duration::ZERO, true));
            }
            // A stage with a restart policy that died before the graph started is started again
            // and joins the start-up handshake (it used to wait for the ready timeout instead).
            self.restart_due_stages(stages)?;
            self.join_start(stages, connect_sent);
            if !connect_sent
                && stages
                    .iter()
                    .all(|s| s.ready || s.branch_stopped_at.is_some())
            {
                for s in stages.iter_mut() {
                    s.send("connect");
                }
                connect_sent = true;
            }
            if Instant::now() > ready_deadline
                && let Some(s) = stages.iter_mut().find(|s| waiting(s))
            {
                return Err(RunError::NotReady {
                    stage: s.id.clone(),
                    timeout_s: graph.ready_timeout_s,
                    stderr_tail: s
                        .stderr_tail
                        .lock()
                        .map(|t| t.iter().cloned().collect())
                        .unwrap_or_default(),
                });
            }
        }

        // Phase 2: go, then wait for every stage to finish its stream.
        let start = Instant::now();
        for s in stages.iter_mut() {
            s.send("go");
            s.moved_at = start;
            s.heard_at = start;
        }
        let mut stop_requested_at: Option<Instant> = None;
        let mut terminated_at: Option<Instant> = None;
        while stages
            .iter()
            .any(|s| s.exit.is_none() || s.restart_due.is_some())
        {
            handle_events(stages, rx, &bar, &log)?;
            self.reap(stages)?;
            if stop_requested_at.is_none() {
                self.catch_early_exits(stages, rx, &bar, &log)?;
                self.watch_for_stalls(stages)?;
                self.restart_due_stages(stages)?;
                self.rejoin(stages);
            } else {
                // Stopping: nothing is started again.
                for s in stages.iter_mut() {
                    s.restart_due = None;
                }
            }
            for s in stages.iter() {
                if s.branch_stopped_at
                    .is_some_and(|t| t.elapsed() > TERM_GRACE)
                {
                    s.signal(libc::SIGKILL);
                }
            }
            if interrupted.load(Ordering::Relaxed) && stop_requested_at.is_none() {
                bar.suspend(|| {
                    eprintln!("stopping: ending the stream at the sources (Ctrl-C again to force)")
                });
                for s in stages.iter_mut().filter(|s| s.role == Role::Source) {
                    s.send("stop");
                }
                stop_requested_at = Some(Instant::now());
                self.stopping = true;
                interrupted.store(false, Ordering::Relaxed);
            }
            if let Some(t) = stop_requested_at
                && terminated_at.is_none()
                && (t.elapsed() > DRAIN_GRACE || interrupted.load(Ordering::Relaxed))
            {
                for s in stages.iter() {
                    s.signal(libc::SIGTERM);
                }
                terminated_at = Some(Instant::now());
            }
            if let Some(t) = terminated_at
                && t.elapsed() > TERM_GRACE
            {
                for s in stages.iter() {
                    s.signal(libc::SIGKILL);
                }
            }
        }
        // Drain the remaining control lines (summaries printed just before exit).
        for s in stages.iter_mut() {
            for handle in s.readers.drain(..) {
                let _ = handle.join();
            }
        }
        handle_events(stages, rx, &bar, &log)?;
        bar.finish_and_clear();
        // (A stage that exited 0 without ending its stream was caught in the loop, by
        // `catch_early_exits`, right after it was reaped.)
        Ok((start.elapsed(), stop_requested_at.is_some()))
    }

    /// Records exited stages. A failure stops its isolated branch, or else the run.
    fn reap(&mut self, stages: &mut [Running]) -> Result<(), RunError> {
        for i in 0..stages.len() {
            if stages[i].exit.is_some() {
                continue;
            }
            let status = match stages[i].child.try_wait() {
                Ok(Some(status)) => status,
                Ok(None) => continue,
                Err(e) => {
                    return Err(RunError::StageFailed {
                        stage: stages[i].id.clone(),
                        status: format!("cannot wait for the process: {e}"),
                        stderr_tail: Vec::new(),
                    });
                }
            };
            stages[i].exit = Some(status);
            stages[i].stdin = None;
            if stages[i].restart_due.is_some() {
                continue; // killed for its restart (it had stalled)
            }
            if stages[i].branch_stopped_at.is_some() {
                // Stopped with its branch: a reader it left behind must not hold back its writers.
                self.disconnect_dead_readers();
                continue;
            }
            if status.success() {
                continue;
            }
            if self.stopping {
                // The user stopped the run: a stage that was waiting for room when SIGTERM came
                // ends with the stop as its error. That is the stop, not a failure of the run.
                tracing::info!(
                    "stage '{}' ended with {} while the run was stopping",
                    stages[i].id,
                    describe_status(status)
                );
                continue;
            }
            let stderr_tail = stages[i].tail();
            let failure = Failure::Ended(describe_status(status));
            self.fail_or_restart(stages, i, failure, stderr_tail)?;
        }
        Ok(())
    }

    /// A stage that exited 0 without ending its stream (no END_OF_STREAM, no summary) leaves its
    /// readers waiting forever: it failed, now, not when the rest of the graph ends. Its summary
    /// may still be in the pipe when its exit is seen, so its output is read to the end first.
    fn catch_early_exits(
        &mut self,
        stages: &mut [Running],
        rx: &Receiver<Event>,
        bar: &indicatif::ProgressBar,
        log: &impl Fn(&[Running], usize, &str),
    ) -> Result<(), RunError> {
        let quit = |s: &Running| {
            s.exit.is_some_and(|e| e.success())
                && s.summary.is_none()
                && s.branch_stopped_at.is_none()
                && s.restart_due.is_none()
        };
        while let Some(i) = stages.iter().position(quit) {
            // Its readers end at the pipes' end: then every line it wrote is in the channel.
            for handle in stages[i].readers.drain(..) {
                let _ = handle.join();
            }
            handle_events(stages, rx, bar, log)?;
            if stages[i].summary.is_some() {
                continue;
            }
            let stderr_tail = stages[i].tail();
            let failure = Failure::Ended(EXITED_EARLY.to_owned());
            self.fail_or_restart(stages, i, failure, stderr_tail)?;
        }
        Ok(())
    }
}

/// How a stage that exits 0 mid-stream is reported.
const EXITED_EARLY: &str =
    "exited without ending its stream (exit status 0, no END_OF_STREAM/summary)";

fn handle_events(
    stages: &mut [Running],
    rx: &Receiver<Event>,
    bar: &indicatif::ProgressBar,
    log: &impl Fn(&[Running], usize, &str),
) -> Result<(), RunError> {
    let mut timeout = POLL;
    loop {
        match rx.recv_timeout(timeout) {
            Ok(Event::Control(i, msg)) => match msg {
                ControlMessage::Ready => {
                    if let Some(s) = stages.get_mut(i) {
                        s.ready = true;
                    }
                }
                ControlMessage::Connected => {
                    if let Some(s) = stages.get_mut(i) {
                        s.connected = true;
                    }
                }
                ControlMessage::Progress { done, total } => {
                    if total > 0 {
                        bar.set_length(total);
                    }
                    bar.set_position(done);
                }
                ControlMessage::Summary(summary) => {
                    if let Some(s) = stages.get_mut(i) {
                        s.summary = Some(summary);
                    }
                }
                ControlMessage::Alive { position } => {
                    if let Some(s) = stages.get_mut(i) {
                        let now = Instant::now();
                        s.heard_at = now;
                        if position != s.position {
                            s.position = position;
                            s.moved_at = now;
                        }
                    }
                }
            },
            Ok(Event::Log(i, line)) => log(stages, i, &line),
            Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => return Ok(()),
        }
        timeout = Duration::ZERO;
    }
}

fn describe_status(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exited with code {code}"),
        (None, Some(sig)) => format!("killed by signal {sig}"),
        _ => "ended abnormally".into(),
    }
}

/// SIGTERM to every running stage (they finalize their outputs), SIGKILL after a grace period.
pub(super) fn stop_all(stages: &mut [Running]) {
    for s in stages.iter() {
        // A stopped (SIGSTOP) process handles SIGTERM only once it runs again.
        s.signal(libc::SIGCONT);
        s.signal(libc::SIGTERM);
    }
    let deadline = Instant::now() + TERM_GRACE;
    loop {
        let mut running = false;
        for s in stages.iter_mut().filter(|s| s.exit.is_none()) {
            match s.child.try_wait() {
                Ok(Some(status)) => s.exit = Some(status),
                _ => running = true,
            }
        }
        if !running {
            return;
        }
        if Instant::now() > deadline {
            for s in stages.iter_mut().filter(|s| s.exit.is_none()) {
                let _ = s.child.kill();
                s.exit = s.child.wait().ok();
            }
            return;
        }
        std::thread::sleep(POLL);
    }
}
