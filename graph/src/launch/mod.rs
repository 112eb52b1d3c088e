//! The launcher/supervisor behind `imuflow run`: one OS process per stage, a ready handshake,
//! END_OF_STREAM-driven completion, crash handling and clean stops.
//!
//! Stages run in their own process groups, so a terminal's Ctrl-C reaches only the launcher, which
//! then stops the sources; their END_OF_STREAM drains the graph and every recorder finalizes its
//! file. If a stage crashes, the others get SIGTERM (they finalize and exit), and the launcher
//! reports the failed stage with the last lines of its stderr. If the stage belongs to an isolated
//! branch (`on_failure = "stop-branch"`), only that branch is stopped: its stages get SIGTERM, the
//! stages that also read from elsewhere are told (`ended <stage>`) that those inputs end, iceoryx2's
//! dead-node cleanup disconnects a killed reader so back-pressure cannot block its writers, and
//! the run goes on; the report lists the failed branch.
//!
//! This file is the run from start to end; the parts it calls, one file each:
//!
//! - `spawn.rs`: starting a stage process (its environment, pipes, scheduling) and the handle the
//!   supervisor keeps on it.
//! - `supervise.rs`: the handshake and the stream (ready, connect, go, the end), reaping exits,
//!   Ctrl-C, stopping every stage.
//! - `failure.rs`: what a failed stage's policy does (restart it, stop its branch, or the run).
//! - `restart.rs`: a restarted stage's new process, joining the running graph.
//! - `watchdog.rs`: the stall watchdog.
//! - `report.rs`: what a finished run reports, and its summary table.
//! - `shm.rs`: the runs' shared-memory files, found and removed.

mod failure;
mod report;
mod restart;
mod shm;
mod spawn;
mod supervise;
mod watchdog;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::sync::mpsc;
use std::time::Instant;

use crate::graph::Graph;
use crate::spec::Role;
use crate::stage::GRAPH_JSON;
use crate::transport;

pub use report::{FailedBranch, RunReport};
pub use shm::{remove_stale_runs, shared_memory_files};
pub use spawn::RAYON_THREADS_ENV;

use report::empty_summary;
use shm::remove_run_files;
use spawn::{Spawner, spawn_all};
use supervise::{Supervisor, stop_all};

/// How `run` should behave.
#[derive(Debug, Clone)]
pub struct LaunchOptions {
    /// The `imuflow` executable that runs built-in stages (`imuflow stage <kind>`).
    pub imuflow_exe: PathBuf,
    /// Show a progress bar (when stderr is a terminal).
    pub progress: bool,
    /// Forward stages' log lines to stderr.
    pub forward_logs: bool,
}

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("cannot prepare the run directory {path}: {source}")]
    RunDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start stage '{stage}' ({program}): {source}")]
    Spawn {
        stage: String,
        program: String,
        #[source]
        source: std::io::Error,
    },
    /// A stage exited with an error, was killed, or ended without finishing its stream.
    #[error("stage '{stage}' failed: {status}{}", tail_text(stderr_tail))]
    StageFailed {
        stage: String,
        status: String,
        stderr_tail: Vec<String>,
    },
    #[error(
        "stage '{stage}' did not report ready within {timeout_s} s (ready_timeout_s in the graph){}",
        tail_text(stderr_tail)
    )]
    NotReady {
        stage: String,
        timeout_s: f64,
        stderr_tail: Vec<String>,
    },
    /// The stall watchdog: inputs waiting, nothing taken for the stage's stall timeout.
    #[error("stage '{stage}' stalled: {detail}{}", tail_text(stderr_tail))]
    Stalled {
        stage: String,
        detail: String,
        stderr_tail: Vec<String>,
    },
    #[error(transparent)]
    Transport(#[from] transport::TransportError),
}

fn tail_text(lines: &[String]) -> String {
    if lines.is_empty() {
        "\n  (no stderr output)".to_owned()
    } else {
        format!(
            "\n  last stderr lines:\n{}",
            lines
                .iter()
                .map(|l| format!("    | {l}"))
                .collect::<Vec<_>>()
                .join("\n")
        )
    }
}

/// Runs `graph` to completion.
pub fn run(graph: &Graph, options: &LaunchOptions) -> Result<RunReport, RunError> {
    let run_id = new_run_id();
    let base = transport::base_shm_prefix();
    let removed = remove_stale_runs(&base);
    if removed > 0 {
        tracing::info!("removed {removed} shared-memory file(s) left by earlier runs that crashed");
    }
    let shm_prefix = transport::run_shm_prefix(&base, std::process::id(), &run_id);
    let run_dir = std::env::temp_dir().join("imuflow-runs").join(&run_id);
    let result = run_in(graph, options, &run_id, &run_dir, &shm_prefix);
    let _ = std::fs::remove_dir_all(&run_dir);
    // Every stage has exited: whatever they left (a crashed stage cannot clean up) goes now.
    remove_run_files(&shm_prefix);
    result
}

/// A short id, unique enough among concurrent runs on one machine.
fn new_run_id() -> String {
    let nanos = transport::now_ns();
    format!("{:x}{:05x}", std::process::id(), nanos & 0xfffff)
}

/// The run in its own directory: writes what every stage reads at its start (the graph, the wire
/// contract), turns Ctrl-C and SIGTERM into a stop request, starts every stage and supervises
/// them to the end.
fn run_in(
    graph: &Graph,
    options: &LaunchOptions,
    run_id: &str,
    run_dir: &Path,
    shm_prefix: &str,
) -> Result<RunReport, RunError> {
    let dir_err = |source| RunError::RunDir {
        path: run_dir.to_owned(),
        source,
    };
    std::fs::create_dir_all(run_dir).map_err(dir_err)?;
    let json = serde_json::to_string(graph).map_err(|e| dir_err(std::io::Error::other(e)))?;
    std::fs::write(run_dir.join(GRAPH_JSON), json).map_err(dir_err)?;
    // What stages in other languages build their ports from (python/imuflow/stage.py).
    let wire = serde_json::to_string(&crate::wire::contract())
        .map_err(|e| dir_err(std::io::Error::other(e)))?;
    std::fs::write(run_dir.join(crate::wire::WIRE_JSON), wire).map_err(dir_err)?;

    let interrupted = Arc::new(AtomicBool::new(false));
    let mut signal_ids = Vec::new();
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Ok(id) = signal_hook::flag::register(sig, interrupted.clone()) {
            signal_ids.push(id);
        }
    }
    let (tx, rx) = mpsc::channel();
    let spawner = Spawner {
        options,
        mode: graph.mode,
        run_id,
        run_dir,
        shm_prefix,
        tx,
    };
    let mut stages = Vec::new();
    let spawn_started = Instant::now();
    let spawned = spawn_all(graph, &spawner, &mut stages);
    let mut supervisor = Supervisor {
        graph,
        shm_prefix,
        spawner: &spawner,
        failed_branches: Vec::new(),
        restarts: BTreeMap::new(),
        stopping: false,
    };
    let result =
        spawned.and_then(|()| supervisor.supervise(options, &mut stages, &rx, &interrupted));
    if result.is_err() {
        stop_all(&mut stages);
    }
    for id in signal_ids {
        signal_hook::low_level::unregister(id);
    }
    result.map(|(wall, was_interrupted)| RunReport {
        startup: spawn_started.elapsed().saturating_sub(wall),
        run_id: run_id.to_owned(),
        graph_name: graph.name.clone(),
        stage_order: graph
            .topological_order()
            .into_iter()
            .map(|node| node.id.clone())
            .collect(),
        sinks: graph
            .stages
            .values()
            .filter(|node| node.role == Role::Sink)
            .map(|node| node.id.clone())
            .collect(),
        stages: stages
            .iter()
            .map(|s| {
                let summary = s.summary.clone().unwrap_or_else(empty_summary);
                (s.id.clone(), (s.kind.clone(), summary))
            })
            .collect(),
        wall,
        interrupted: was_interrupted,
        failed_branches: supervisor.failed_branches,
        restarts: supervisor.restarts,
    })
}
