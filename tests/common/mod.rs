//! Helpers for tests that run real multi-process graphs through the `imuflow` binary.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

pub const IMUFLOW: &str = env!("CARGO_BIN_EXE_imuflow");

/// A scratch directory and a shared-memory prefix of its own, so parallel tests never see each
/// other's files and each can check that its runs left nothing behind.
pub struct Sandbox {
    pub dir: PathBuf,
    pub shm_prefix: String,
}

impl Sandbox {
    pub fn new(name: &str) -> Self {
        static COUNTER: AtomicU32 = AtomicU32::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tag = format!("{}_{}_{n}", std::process::id(), name);
        let dir = std::env::temp_dir().join(format!("imuflow-test-{tag}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create sandbox dir");
        Sandbox {
            dir,
            shm_prefix: format!("imft{}_{n}_", std::process::id()),
        }
    }

    pub fn path(&self, file: &str) -> PathBuf {
        self.dir.join(file)
    }

    /// Writes a graph file into the sandbox; `{dir}` in the text becomes the sandbox path.
    pub fn graph(&self, file: &str, text: &str) -> PathBuf {
        let path = self.path(file);
        std::fs::write(
            &path,
            text.replace("{dir}", &self.dir.display().to_string()),
        )
        .expect("write graph");
        path
    }

    pub fn command(&self, args: &[&str]) -> Command {
        let mut c = Command::new(IMUFLOW);
        c.args(args)
            .env("IMUFLOW_SHM_PREFIX", &self.shm_prefix)
            .env("IMUFLOW_LOG", "warn");
        c
    }

    /// Starts imuflow with its stdout and stderr piped, for tests that act on the run while it
    /// goes (kill a stage, send packets) and read its output at the end.
    pub fn spawn(&self, args: &[&str]) -> std::process::Child {
        self.command(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("start imuflow")
    }

    /// Runs imuflow to completion; a run that takes over a minute is killed and fails the test
    /// (a hang is a bug, never an answer).
    pub fn run(&self, args: &[&str]) -> Output {
        self.run_within(args, 60)
    }

    /// [`Sandbox::run`] with a limit of `seconds` (whole graphs in a debug build under load).
    pub fn run_within(&self, args: &[&str], seconds: u64) -> Output {
        let child = self
            .command(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("start imuflow");
        let id = child.id();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(child.wait_with_output());
        });
        match rx.recv_timeout(std::time::Duration::from_secs(seconds)) {
            Ok(output) => output.expect("wait for imuflow"),
            Err(_) => {
                // SAFETY: kill(2) on the launcher we started; its stages stop when its pipes close.
                #[allow(unsafe_code)]
                unsafe {
                    libc::kill(id as i32, libc::SIGKILL);
                }
                panic!("imuflow {args:?} did not finish within {seconds} s");
            }
        }
    }

    /// Shared-memory / iceoryx2 files this sandbox's runs left behind.
    pub fn leftovers(&self) -> Vec<PathBuf> {
        imuflow_graph::launch::shared_memory_files(&self.shm_prefix)
    }

    /// Processes still running with this sandbox's prefix in their environment.
    pub fn stray_processes(&self) -> Vec<String> {
        let needle = format!("IMUFLOW_SHM_PREFIX={}", self.shm_prefix);
        let mut found = Vec::new();
        let me = std::process::id().to_string();
        for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
            let pid = entry.file_name().to_string_lossy().to_string();
            if !pid.chars().all(|c| c.is_ascii_digit()) || pid == me {
                continue;
            }
            if let Ok(env) = std::fs::read(entry.path().join("environ"))
                && env.split(|&b| b == 0).any(|v| v == needle.as_bytes())
            {
                let cmd = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
                found.push(format!(
                    "{pid}: {}",
                    String::from_utf8_lossy(&cmd).replace('\0', " ")
                ));
            }
        }
        found
    }
}

impl Drop for Sandbox {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Messages per topic of an mcap file, read with the mcap crate's reader (which checks the
/// footer, summary and CRCs), as (topic, sequence, data).
pub fn mcap_messages(path: &Path) -> Vec<(String, u32, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let summary = mcap::Summary::read(&bytes)
        .expect("mcap summary readable")
        .expect("mcap has a summary section (finalized)");
    assert!(summary.stats.is_some(), "finalized mcap has statistics");
    mcap::MessageStream::new(&bytes)
        .expect("mcap stream")
        .map(|m| {
            let m = m.expect("valid mcap message");
            (m.channel.topic.clone(), m.sequence, m.data.into_owned())
        })
        .collect()
}

/// The path of a built example (e.g. `external_counter`), next to the imuflow binary.
pub fn example_exe(name: &str) -> PathBuf {
    Path::new(IMUFLOW)
        .parent()
        .expect("target dir")
        .join("examples")
        .join(name)
}

/// Messages of `topic` in a recording read with [`mcap_messages`].
pub fn count(messages: &[(String, u32, Vec<u8>)], topic: &str) -> usize {
    messages.iter().filter(|m| m.0 == topic).count()
}

/// Nothing left behind: no shared-memory files, no stage processes of this sandbox.
pub fn assert_clean(sandbox: &Sandbox) {
    let left = sandbox.leftovers();
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    let stray = sandbox.stray_processes();
    assert!(stray.is_empty(), "stray stage processes: {stray:?}");
}

/// The pid of this sandbox's stage `id`, once it runs.
pub fn wait_for_stage(sb: &Sandbox, id: &str, timeout: Duration) -> Option<i32> {
    let needle = format!("IMUFLOW_STAGE_ID={id}");
    let start = Instant::now();
    while start.elapsed() < timeout {
        for line in sb.stray_processes() {
            let pid: i32 = line.split(':').next()?.parse().ok()?;
            let env = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
            if env.split(|&b| b == 0).any(|v| v == needle.as_bytes()) {
                return Some(pid);
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    None
}

/// Waits for the launcher `child`; past `timeout` it is killed and the test fails (a hang is a
/// bug, never an answer).
pub fn wait_with_timeout(child: std::process::Child, timeout: Duration) -> std::process::Output {
    let id = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(timeout) {
        Ok(output) => output.expect("wait for imuflow"),
        Err(_) => {
            // SAFETY: kill(2) on the launcher this test started.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(id as i32, libc::SIGKILL);
            }
            panic!(
                "imuflow did not finish within {timeout:?}: a failed stage must not hang the run"
            );
        }
    }
}

/// `imuflow run` arguments for a method graph (`configs/<graph>.toml`) on the bundled sample, its
/// recorder and rerun logger writing `mcap` and `rrd`, with `extra` `--set` overrides first.
pub fn sample_run_args(graph: &str, mcap: &Path, rrd: &Path, extra: &[&str]) -> Vec<String> {
    let root = env!("CARGO_MANIFEST_DIR");
    let mut args = vec![
        "run".to_owned(),
        format!("{root}/configs/{graph}.toml"),
        "--no-progress".to_owned(),
        "--quiet".to_owned(),
    ];
    let sets = extra.iter().map(|s| s.to_string()).chain([
        format!("stages.source.params.path={root}/models/sample/walk.mcap"),
        format!("stages.record.params.path={}", mcap.display()),
        format!("stages.viz.params.path={}", rrd.display()),
    ]);
    for set in sets {
        args.extend(["--set".to_owned(), set]);
    }
    args
}

/// A free loopback UDP port: bound, noted and released again, for a stage to bind.
pub fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("free port")
        .port()
}

/// Waits until the run `child` streams past `frame`, as a marker stage beside its graph
/// (examples/external_counter.rs `--mark-from FRAME MARKED`) says by creating `marked`: tests act
/// on a run at a point of its stream, not after a time a loaded machine's start-up may outlast. A
/// run that ends first fails the test with its stderr; so does one that gets no further in two
/// minutes. `label` starts the failure's message (e.g. the stage the test is about).
pub fn wait_for_mark(child: &mut std::process::Child, marked: &Path, frame: u64, label: &str) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while !marked.exists() {
        if let Ok(Some(status)) = child.try_wait() {
            let mut stderr = String::new();
            if let Some(mut pipe) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut pipe, &mut stderr);
            }
            panic!("{label}the run ended ({status}) before frame {frame}\n{stderr}");
        }
        assert!(
            Instant::now() < deadline,
            "{label}the stream never reached frame {frame}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}
