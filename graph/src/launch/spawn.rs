//! Starting a stage process: its command, environment, pipes and scheduling, and the handle the
//! supervisor keeps on it ([`Running`]).

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use crate::graph::{Graph, Mode, Nice, Runner};
use crate::spec::Role;
use crate::stage::{ControlMessage, ENV_RESTART, ENV_RUN_DIR, ENV_RUN_ID, ENV_STAGE_ID};
use crate::stats::StageSummary;
use crate::transport;

use super::restart::Rejoin;
use super::{LaunchOptions, RunError};

/// Size of rayon's thread pool in each stage process (1 unless the user's environment sets it).
pub const RAYON_THREADS_ENV: &str = "RAYON_NUM_THREADS";

/// Lines of a stage's stderr kept for the failure report.
const STDERR_TAIL: usize = 12;

/// Starts every stage of `graph`, producers before their readers; a stage's place in `stages` is
/// the index its events carry.
pub(super) fn spawn_all(
    graph: &Graph,
    spawner: &Spawner,
    stages: &mut Vec<Running>,
) -> Result<(), RunError> {
    for node in graph.topological_order() {
        let index = stages.len();
        stages.push(spawner.spawn(node, index, 0)?);
    }
    Ok(())
}

/// What starting a stage process needs: the run's identity and where its events go.
pub(super) struct Spawner<'a> {
    pub(super) options: &'a LaunchOptions,
    /// Live or offline: how `nice = "idle"` schedules a stage.
    pub(super) mode: Mode,
    pub(super) run_id: &'a str,
    pub(super) run_dir: &'a Path,
    pub(super) shm_prefix: &'a str,
    pub(super) tx: Sender<Event>,
}

impl Spawner<'_> {
    /// Starts `node`'s process as stage number `index` (`restart`: how many times it was started
    /// before in this run).
    pub(super) fn spawn(
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

/// A line from a stage: its stdout carries control messages (or stray output, treated as a log
/// line), its stderr log lines; the number is the stage's index among the running stages.
pub(super) enum Event {
    Control(usize, ControlMessage),
    Log(usize, String),
}

/// A started stage process as the supervisor sees it: its pipes, where it is in the handshake and
/// the stream, and its restarts.
pub(super) struct Running {
    pub(super) id: String,
    pub(super) kind: String,
    pub(super) role: Role,
    pub(super) child: Child,
    pub(super) stdin: Option<ChildStdin>,
    pub(super) stderr_tail: Arc<Mutex<VecDeque<String>>>,
    pub(super) readers: Vec<std::thread::JoinHandle<()>>,
    pub(super) ready: bool,
    pub(super) connected: bool,
    pub(super) summary: Option<StageSummary>,
    pub(super) exit: Option<ExitStatus>,
    /// When the stage was stopped with its failed branch (SIGTERM sent); its exit no longer
    /// matters and it owes no summary.
    pub(super) branch_stopped_at: Option<Instant>,
    /// The stall watchdog's view: the seq after the newest frame the stage took (its heartbeat),
    /// when that last changed, and when the stage was last heard from.
    pub(super) position: u64,
    pub(super) moved_at: Instant,
    pub(super) heard_at: Instant,
    /// Restart policy: when each restart happened, when the next start is due (after the
    /// backoff), and whether a restarted process is still in its handshake (ready → connect →
    /// go, on its own while the rest of the graph runs).
    pub(super) restarted_at: Vec<Instant>,
    pub(super) restart_due: Option<Instant>,
    pub(super) rejoining: Option<Rejoin>,
}

impl Running {
    pub(super) fn send(&mut self, line: &str) {
        if let Some(stdin) = &mut self.stdin {
            // A stage that already exited has closed its stdin; nothing to tell it then.
            let _ = writeln!(stdin, "{line}").and_then(|_| stdin.flush());
        }
    }

    pub(super) fn signal(&self, signal: i32) {
        if self.exit.is_none() {
            // SAFETY: kill(2) with a pid we spawned and have not reaped; no memory is touched.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(self.child.id() as i32, signal);
            }
        }
    }

    /// The last stderr lines so far, without waiting for the process to end (it may be hung).
    pub(super) fn tail_now(&self) -> Vec<String> {
        self.stderr_tail
            .lock()
            .map(|t| t.iter().cloned().collect())
            .unwrap_or_default()
    }

    pub(super) fn tail(&mut self) -> Vec<String> {
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
