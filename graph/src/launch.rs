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

use std::collections::{BTreeMap, VecDeque};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::graph::{Graph, Mode, Nice, Runner};
use crate::spec::Role;
use crate::stage::{
    ControlMessage, ENV_RESTART, ENV_RUN_DIR, ENV_RUN_ID, ENV_STAGE_ID, GRAPH_JSON,
};
use crate::stats::StageSummary;
use crate::transport;
use std::collections::BTreeSet;

/// Size of rayon's thread pool in each stage process (1 unless the user's environment sets it).
pub const RAYON_THREADS_ENV: &str = "RAYON_NUM_THREADS";

/// Lines of a stage's stderr kept for the failure report.
const STDERR_TAIL: usize = 12;
/// After a stop request, how long stages get to drain before SIGTERM.
const DRAIN_GRACE: Duration = Duration::from_secs(5);
/// After SIGTERM, how long stages get to finalize before SIGKILL.
const TERM_GRACE: Duration = Duration::from_secs(3);
/// How often the supervisor polls its children.
const POLL: Duration = Duration::from_millis(5);

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

/// What a finished run reports.
#[derive(Debug, Clone)]
pub struct RunReport {
    pub run_id: String,
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

enum Event {
    Control(usize, ControlMessage),
    Log(usize, String),
}

struct Running {
    id: String,
    kind: String,
    role: Role,
    child: Child,
    stdin: Option<ChildStdin>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    readers: Vec<std::thread::JoinHandle<()>>,
    ready: bool,
    connected: bool,
    summary: Option<StageSummary>,
    exit: Option<ExitStatus>,
    /// When the stage was stopped with its failed branch (SIGTERM sent); its exit no longer
    /// matters and it owes no summary.
    branch_stopped_at: Option<Instant>,
    /// The stall watchdog's view: the seq after the newest frame the stage took (its heartbeat),
    /// when that last changed, and when the stage was last heard from.
    position: u64,
    moved_at: Instant,
    heard_at: Instant,
    /// Restart policy: when each restart happened, when the next start is due (after the
    /// backoff), and whether a restarted process is still in its handshake (ready → connect →
    /// go, on its own while the rest of the graph runs).
    restarted_at: Vec<Instant>,
    restart_due: Option<Instant>,
    rejoining: Option<Rejoin>,
}

/// Where a restarted stage is in its handshake.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Rejoin {
    Starting,
    ConnectSent,
}

impl Running {
    fn send(&mut self, line: &str) {
        if let Some(stdin) = &mut self.stdin {
            // A stage that already exited has closed its stdin; nothing to tell it then.
            let _ = writeln!(stdin, "{line}").and_then(|_| stdin.flush());
        }
    }

    fn signal(&self, signal: i32) {
        if self.exit.is_none() {
            // SAFETY: kill(2) with a pid we spawned and have not reaped; no memory is touched.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(self.child.id() as i32, signal);
            }
        }
    }

    /// The last stderr lines so far, without waiting for the process to end (it may be hung).
    fn tail_now(&self) -> Vec<String> {
        self.stderr_tail
            .lock()
            .map(|t| t.iter().cloned().collect())
            .unwrap_or_default()
    }

    fn tail(&mut self) -> Vec<String> {
        // Let the stderr reader catch the last lines of an exited process.
        for handle in self.readers.drain(..) {
            let _ = handle.join();
        }
        self.stderr_tail
            .lock()
            .map(|t| t.iter().cloned().collect())
            .unwrap_or_default()
    }
}

/// A short id, unique enough among concurrent runs on one machine.
fn new_run_id() -> String {
    let nanos = transport::now_ns();
    format!("{:x}{:05x}", std::process::id(), nanos & 0xfffff)
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

/// Removes every file of the run domain `prefix`, first through iceoryx2 (dead-node cleanup),
/// then whatever remains. Only call it when no process of that run is alive.
fn remove_run_files(prefix: &str) -> usize {
    if let Err(e) = transport::cleanup_dead_nodes(prefix) {
        tracing::debug!("iceoryx2 cleanup of {prefix}: {e}");
    }
    let files = shared_memory_files(prefix);
    let mut removed = 0;
    for file in &files {
        if std::fs::remove_file(file).is_ok() {
            removed += 1;
        }
        // iceoryx2 keeps per-node files in a directory named after the node id.
        if let Some(dir) = file.parent()
            && dir.starts_with("/tmp/iceoryx2/nodes/")
        {
            let _ = std::fs::remove_dir(dir);
        }
    }
    removed
}

/// Removes the files of earlier runs whose launcher is no longer alive (it crashed or was
/// killed). Returns the number of files removed.
pub fn remove_stale_runs(base: &str) -> usize {
    let mut stale = std::collections::BTreeSet::new();
    for file in shared_memory_files(base) {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(rest) = name.strip_prefix(base) else {
            continue;
        };
        let mut parts = rest.splitn(3, '_');
        let (Some(pid), Some(run), Some(_)) = (parts.next(), parts.next(), parts.next()) else {
            continue;
        };
        let Ok(pid) = pid.parse::<i32>() else {
            continue;
        };
        if !process_alive(pid) {
            stale.insert(format!("{base}{pid}_{run}_"));
        }
    }
    stale.iter().map(|prefix| remove_run_files(prefix)).sum()
}

fn process_alive(pid: i32) -> bool {
    // SAFETY: kill(2) with signal 0 only checks that the process exists.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::kill(pid, 0) };
    rc == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

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

fn empty_summary() -> StageSummary {
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

fn spawn_all(graph: &Graph, spawner: &Spawner, stages: &mut Vec<Running>) -> Result<(), RunError> {
    for node in graph.topological_order() {
        let index = stages.len();
        stages.push(spawner.spawn(node, index, 0)?);
    }
    Ok(())
}

/// What starting a stage process needs: the run's identity and where its events go.
struct Spawner<'a> {
    options: &'a LaunchOptions,
    /// Live or offline: how `nice = "idle"` schedules a stage.
    mode: Mode,
    run_id: &'a str,
    run_dir: &'a Path,
    shm_prefix: &'a str,
    tx: Sender<Event>,
}

impl Spawner<'_> {
    /// Starts `node`'s process as stage number `index` (`restart`: how many times it was started
    /// before in this run).
    fn spawn(
        &self,
        node: &crate::graph::StageNode,
        index: usize,
        restart: u32,
    ) -> Result<Running, RunError> {
        let options = self.options;
        let mut command = match &node.runner {
            Runner::Builtin { kind } => {
                let mut c = Command::new(&options.imuflow_exe);
                c.arg("stage").arg(kind);
                c
            }
            Runner::Exec { path, args } => {
                let mut c = Command::new(path);
                c.args(args);
                c
            }
        };
        command
            .env(ENV_RUN_DIR, self.run_dir)
            .env(ENV_RUN_ID, self.run_id)
            .env(ENV_STAGE_ID, &node.id)
            .env(transport::ENV_RUN_SHM_PREFIX, self.shm_prefix)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if restart > 0 {
            command.env(ENV_RESTART, restart.to_string());
        }
        // Every stage is its own process, so thread pools inside stages (candle's rayon pool in the
        // kinematics stage) would oversubscribe the cores the other stages need: one thread each
        // unless the user chose otherwise (measured, release, configs/pip.toml on 2
        // cores: 2.5-2.7 s instead of 4.2-5.3 s).
        if std::env::var_os(RAYON_THREADS_ENV).is_none() {
            command.env(RAYON_THREADS_ENV, "1");
        }
        // Own process group: the terminal's Ctrl-C goes to the launcher alone, which stops the
        // graph in order instead of every stage dying at once.
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        set_nice(&mut command, node.nice, self.mode);
        let program = format!("{:?}", command.get_program());
        let mut child = command.spawn().map_err(|source| RunError::Spawn {
            stage: node.id.clone(),
            program,
            source,
        })?;
        let stderr_tail = Arc::new(Mutex::new(VecDeque::new()));
        let mut readers = Vec::new();
        if let Some(stdout) = child.stdout.take() {
            let tx = self.tx.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                    let event = match ControlMessage::parse(&line) {
                        Some(msg) => Event::Control(index, msg),
                        None => Event::Log(index, line),
                    };
                    if tx.send(event).is_err() {
                        break;
                    }
                }
            }));
        }
        if let Some(stderr) = child.stderr.take() {
            let tx = self.tx.clone();
            let tail = stderr_tail.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                    if let Ok(mut t) = tail.lock() {
                        if t.len() == STDERR_TAIL {
                            t.pop_front();
                        }
                        t.push_back(line.clone());
                    }
                    let _ = tx.send(Event::Log(index, line));
                }
            }));
        }
        Ok(Running {
            id: node.id.clone(),
            kind: node.kind_label(),
            role: node.role,
            stdin: child.stdin.take(),
            child,
            stderr_tail,
            readers,
            ready: false,
            connected: false,
            summary: None,
            exit: None,
            branch_stopped_at: None,
            position: 0,
            moved_at: Instant::now(),
            heard_at: Instant::now(),
            restarted_at: Vec::new(),
            restart_due: None,
            rejoining: None,
        })
    }
}

/// How a stage that exits 0 mid-stream is reported.
const EXITED_EARLY: &str =
    "exited without ending its stream (exit status 0, no END_OF_STREAM/summary)";

/// What the supervision loop needs besides the stages: the graph (for branches), the run's
/// shared-memory domain (for dead-node cleanup) and what failed so far.
/// How a stage failed.
enum Failure {
    /// It exited with an error or was killed (the status, described).
    Ended(String),
    /// The stall watchdog found it sitting on its input (what it waited on).
    Stalled(String),
}

struct Supervisor<'a> {
    graph: &'a Graph,
    shm_prefix: &'a str,
    /// Starts restarted stages.
    spawner: &'a Spawner<'a>,
    failed_branches: Vec<FailedBranch>,
    /// Per restarted stage: why, each time.
    restarts: BTreeMap<String, Vec<String>>,
    /// The user asked the run to stop (Ctrl-C): stages ending with errors are part of stopping.
    stopping: bool,
}

impl Supervisor<'_> {
    fn supervise(
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

    /// A failed stage with a `restart` policy that allows one more is started again after its
    /// backoff (a stalled one is killed first); otherwise (or once the policy is spent) its
    /// failure policy applies.
    fn fail_or_restart(
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

    /// Walks restarted stages through their handshake on their own: once ready they connect, once
    /// connected they go (the rest of the graph is running already), told which of their
    /// producers have finished meanwhile (their END_OF_STREAM went out before the new process
    /// was there to read it).
    fn rejoin(&self, stages: &mut [Running]) {
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

    /// Starts every stage whose restart is due: the dead process's ports are cleaned up first (so
    /// its writers and readers move on), then a new process joins the running graph.
    fn restart_due_stages(&mut self, stages: &mut [Running]) -> Result<(), RunError> {
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

    /// The stall watchdog. A stage that sent no heartbeat for its `stall_timeout_s` is not running
    /// (stopped, frozen); a stage whose every forward input holds frames it has not taken (its
    /// least advanced producer is ahead of it) and whose position has not moved for that long is
    /// hung. Either is handled like a failed stage (its branch stops, or the run). Positions come
    /// from the stages' heartbeats, not from their logs; a stage waiting on a slow producer is not
    /// behind it, and a source blocked by back-pressure still sends heartbeats.
    fn watch_for_stalls(&mut self, stages: &mut [Running]) -> Result<(), RunError> {
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
    fn disconnect_dead_readers(&self) {
        if let Err(e) = transport::cleanup_dead_nodes(self.shm_prefix) {
            tracing::warn!("cannot clean up the ports of a stopped branch: {e}");
        }
    }
}

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
fn stop_all(stages: &mut [Running]) {
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

/// imuflow's shared-memory and iceoryx2 files on this machine with `prefix`, for `imuflow clean`
/// and tests that prove a run left nothing behind.
pub fn shared_memory_files(prefix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let roots = [PathBuf::from("/dev/shm"), PathBuf::from("/tmp/iceoryx2")];
    let mut stack: Vec<PathBuf> = roots.to_vec();
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if entry.file_name().to_string_lossy().starts_with(prefix) {
                found.push(path);
            }
        }
    }
    found.sort();
    found
}

/// Starts the command's process with niceness `nice` (0: inherit), or live under `SCHED_IDLE`
/// ([`Nice::Idle`]). Set in the child between fork and exec, so every thread the stage starts
/// inherits it (Linux keeps niceness and policy per thread: setting them on the pid from outside
/// after the start would miss threads already running).
fn set_nice(command: &mut Command, nice: Nice, mode: Mode) {
    let (level, idle) = match nice {
        Nice::Level(n) => (libc::c_int::from(n), false),
        // Offline the judge is the slowest stage: an idle-class judge gets a core only when the
        // rest of the pipeline waits on it, which halved the offline frames per second
        // (measured, 2026-11-27, the pip and globalpose graphs).
        Nice::Idle => (0, mode == Mode::Live),
    };
    if level == 0 && !idle {
        return;
    }
    // SAFETY: the closure runs in the forked child before exec and calls only setpriority(2)
    // and sched_setscheduler(2), which are async-signal-safe, allocate nothing and touch no
    // lock. Raising one's own niceness or moving to SCHED_IDLE needs no privilege; a failure is
    // reported and the stage is not started.
    unsafe {
        std::os::unix::process::CommandExt::pre_exec(command, move || {
            if level > 0 && libc::setpriority(libc::PRIO_PROCESS, 0, level) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if idle {
                let param = libc::sched_param { sched_priority: 0 };
                if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The niceness and scheduling policy a command's process runs at, read from its own
    /// /proc/self/stat.
    fn scheduling_of(nice: Nice, mode: Mode) -> (i64, i64) {
        let mut command = Command::new("cat");
        command.arg("/proc/self/stat");
        set_nice(&mut command, nice, mode);
        let out = command.output().expect("cat runs");
        let stat = String::from_utf8(out.stdout).expect("utf8");
        // Fields after the command name's closing parenthesis start at field 3; nice is 19,
        // policy 41 (proc(5)).
        let fields: Vec<i64> = stat
            .rsplit_once(')')
            .expect("a stat line")
            .1
            .split_whitespace()
            .map(|f| f.parse().unwrap_or(-1))
            .collect();
        (fields[16], fields[38])
    }

    fn niceness_of(nice: u8) -> i64 {
        scheduling_of(Nice::Level(nice), Mode::Live).0
    }

    #[test]
    fn a_stage_process_starts_at_its_niceness() {
        let inherited = niceness_of(0);
        assert_eq!(niceness_of(7), 7);
        assert_eq!(niceness_of(19), 19);
        // 0 leaves the launcher's own niceness (a test run may itself be niced).
        let own = unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) };
        assert_eq!(inherited, i64::from(own));
    }

    #[test]
    fn an_idle_stage_runs_under_sched_idle_live_and_as_any_stage_offline() {
        let own_policy = unsafe { libc::sched_getscheduler(0) };
        let own_nice = unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) };
        assert_eq!(
            scheduling_of(Nice::Idle, Mode::Live).1,
            i64::from(libc::SCHED_IDLE)
        );
        assert_eq!(
            scheduling_of(Nice::Idle, Mode::Offline),
            (i64::from(own_nice), i64::from(own_policy))
        );
        assert_eq!(scheduling_of(Nice::Level(5), Mode::Offline).0, 5);
    }
}
