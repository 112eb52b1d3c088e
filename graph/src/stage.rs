//! The Stage API: what a stage process (built-in or external) uses to read its inputs, write its
//! outputs and talk to the launcher.
//!
//! ```text
//! let mut ctx = StageContext::from_env()?;            // wiring from the launcher
//! let imu = ctx.input::<ImuFrame>("imu")?;            // typed handle, checked against the graph
//! let mut out = ctx.output::<BodyImuFrame>("body")?;
//! ctx.ready()?;                                       // handshake: wait until every stage is up
//! while let Some(step) = ctx.next()? {                // one aligned set of input frames
//!     let frame = ctx.get(&imu);
//!     out.publish(step.header(), |o| { /* fill o from frame */ })?;
//! }
//! ctx.finish(&mut [&mut out])?;                       // END_OF_STREAM downstream, summary up
//! ```
//!
//! Inputs are aligned by `seq`: `next` returns when every non-feedback input holds the frame with
//! the same `seq`. A feedback input yields the newest frame its producer published, which in an
//! offline graph is exactly the previous `seq` (the stage waits for it); before the producer's
//! first frame it yields an all-zero frame flagged FEEDBACK_INITIAL | INVALID.
//!
//! The launcher talks to a stage over its stdin/stdout with lines starting `@imuflow`; a stage
//! must log to stderr (tracing does), never print to stdout.

use std::io::{BufRead, Write};
use std::marker::PhantomData;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::frames::{Frame, FrameHeader, flags};
use crate::graph::{Graph, Mode, StageNode};
use crate::stats::{StageStats, StageSummary};
use crate::transport::{
    self, ErasedSubscriber, HeldFrame, Output, TransportError, WakeListener, frame_ref,
};
use crate::wait::ArrivalWaiter;

/// Environment variable: the run directory (holds `graph.json`).
pub const ENV_RUN_DIR: &str = "IMUFLOW_RUN_DIR";
/// Environment variable: the run id (part of every service name).
pub const ENV_RUN_ID: &str = "IMUFLOW_RUN_ID";
/// Environment variable: this process's stage id.
pub const ENV_STAGE_ID: &str = "IMUFLOW_STAGE_ID";
/// Set by the launcher when it starts a stage again after a failure (its `restart` policy): how
/// many times it was started before. The stage's first output frames carry `RESTARTED`.
pub const ENV_RESTART: &str = "IMUFLOW_RESTART";
/// File in the run directory holding the validated graph as JSON.
pub const GRAPH_JSON: &str = "graph.json";

/// Prefix of every control line on a stage's stdout.
pub const CONTROL_PREFIX: &str = "@imuflow ";

/// How often a blocked stage re-checks the stop flag.
const POLL: Duration = Duration::from_millis(20);
/// How long a sink told to stop keeps taking the frames its inputs already hold (well inside the
/// launcher's grace before SIGKILL, so the recording is still finalized).
const SINK_DRAIN: Duration = Duration::from_millis(1000);

/// Why a stage could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// The process was not started by `imuflow run` (or an environment variable is missing).
    #[error("{0} is not set: stages are started by `imuflow run GRAPH`, not by hand")]
    MissingEnv(&'static str),
    #[error("cannot read the run's graph {path}: {message}")]
    Graph { path: PathBuf, message: String },
    #[error("stage '{0}' is not in the run's graph")]
    UnknownStage(String),
    /// The stage asked for a port the graph does not give it.
    #[error(
        "stage '{stage}': the graph has no {direction} '{port}' for this stage (it has: {known})"
    )]
    NoSuchPort {
        stage: String,
        direction: &'static str,
        port: String,
        known: String,
    },
    /// The stage's code and the graph disagree about a port's frame type.
    #[error(
        "stage '{stage}': {direction} '{port}' carries {graph} in the graph but the stage uses {code}"
    )]
    PortType {
        stage: String,
        direction: &'static str,
        port: String,
        graph: &'static str,
        code: &'static str,
    },
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("cannot talk to the launcher: {0}")]
    Control(#[from] std::io::Error),
}

/// A typed handle to an input, from [`StageContext::input`].
pub struct InputId<T: Frame> {
    index: usize,
    _type: PhantomData<T>,
}

struct InputSlot {
    name: String,
    /// The stage it reads.
    from_stage: String,
    feedback: bool,
    subscriber: Box<dyn ErasedSubscriber>,
    /// Forward inputs: the frame waiting to be aligned or being processed.
    /// Feedback inputs: the newest frame (or the initial value).
    current: Option<Box<dyn HeldFrame>>,
    last_seq: Option<u64>,
    ended: bool,
    /// The launcher said the producer's branch was stopped: no END_OF_STREAM will come, the input
    /// ends once what was already delivered is taken.
    source_gone: bool,
}

/// What `next` delivers: the shared header of one aligned set of input frames.
#[derive(Debug, Clone, Copy)]
pub struct Step {
    pub seq: u64,
    pub capture_ns: u64,
    /// Union of the input frames' INVALID and CALIBRATING flags.
    pub flags: u32,
}

impl Step {
    /// A header for this step's outputs, carrying `seq`, `capture_ns` and the propagated flags.
    pub fn header(&self) -> FrameHeader {
        FrameHeader {
            seq: self.seq,
            capture_ns: self.capture_ns,
            flags: self.flags,
            ..Default::default()
        }
    }
}

/// Anything `finish` can close with END_OF_STREAM.
pub trait EndOutput {
    fn end(&mut self, seq: u64, capture_ns: u64) -> Result<(), TransportError>;
    fn frames_sent(&self) -> u64;
}

impl<T: Frame> EndOutput for Output<T> {
    fn end(&mut self, seq: u64, capture_ns: u64) -> Result<(), TransportError> {
        self.publish_end(seq, capture_ns)
    }
    fn frames_sent(&self) -> u64 {
        self.sent()
    }
}

/// A stage's connection to its graph and its launcher.
pub struct StageContext {
    node: Node<ipc::Service>,
    graph: Graph,
    stage: StageNode,
    run_id: String,
    stop: Arc<AtomicBool>,
    commands: Arc<AtomicU8>,
    ended_sources: Arc<EndedSources>,
    listener: Option<WakeListener>,
    inputs: Vec<InputSlot>,
    stats: StageStats,
    step_started: Option<Instant>,
    /// Time the outputs spent in `send` since it was last read (back-pressure), ns.
    publish_wait_ns: Arc<AtomicU64>,
    last_step: Option<Step>,
    started: Instant,
    any_cursor: usize,
    /// [`StageContext::next_any`] after a stop request: until when it still hands out the frames
    /// already delivered (a sink told to stop while behind would otherwise lose them).
    drain_deadline: Option<Instant>,
    waiter: ArrivalWaiter,
    /// The frames taken so far, as the seq after the newest one (0: none). The heartbeat thread
    /// reports it to the launcher's stall watchdog.
    position: Arc<AtomicU64>,
    /// How many times the launcher started this stage before ([`ENV_RESTART`]; 0: first start).
    restarts: u32,
    /// Restarted and no step taken yet: the first step's outputs carry `RESTARTED` (the process
    /// starts with fresh state, rebuilt from that frame).
    restart_flag_pending: bool,
}

impl StageContext {
    /// Connects to the run that started this process (see the `ENV_*` constants).
    pub fn from_env() -> Result<Self, StageError> {
        let run_dir = env(ENV_RUN_DIR)?;
        let run_id = env(ENV_RUN_ID)?;
        let stage_id = env(ENV_STAGE_ID)?;
        let path = PathBuf::from(run_dir).join(GRAPH_JSON);
        let text = std::fs::read_to_string(&path).map_err(|e| StageError::Graph {
            path: path.clone(),
            message: e.to_string(),
        })?;
        let graph: Graph = serde_json::from_str(&text).map_err(|e| StageError::Graph {
            path: path.clone(),
            message: e.to_string(),
        })?;
        Self::new(graph, &run_id, &stage_id)
    }

    /// Connects to the run `run_id` of `graph` as `stage_id` (tests and embedding).
    pub fn new(graph: Graph, run_id: &str, stage_id: &str) -> Result<Self, StageError> {
        let stage = graph
            .stages
            .get(stage_id)
            .cloned()
            .ok_or_else(|| StageError::UnknownStage(stage_id.to_owned()))?;
        let restarts = std::env::var(ENV_RESTART)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0);
        let stop = Arc::new(AtomicBool::new(false));
        let commands = Arc::new(AtomicU8::new(0));
        for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
            signal_hook::flag::register(signal, stop.clone())?;
        }
        let ended_sources = Arc::new(EndedSources::default());
        spawn_control_reader(stop.clone(), commands.clone(), ended_sources.clone());

        let node = transport::create_node(stage_id)?;
        let listener = if stage.inputs.is_empty() {
            None
        } else {
            Some(WakeListener::open(&node, run_id, stage_id)?)
        };
        let mut inputs = Vec::new();
        for (name, edge) in &stage.inputs {
            let readers = graph
                .stages
                .get(&edge.from_stage)
                .and_then(|s| s.readers.get(&edge.from_port))
                .map_or(1, Vec::len);
            let subscriber = transport::open_subscriber(
                &node,
                run_id,
                &edge.from_stage,
                &edge.from_port,
                edge.frame,
                graph.mode,
                readers,
            )?;
            inputs.push(InputSlot {
                name: name.clone(),
                from_stage: edge.from_stage.clone(),
                feedback: edge.feedback,
                subscriber,
                current: edge
                    .feedback
                    .then(|| transport::initial_feedback_frame(edge.frame)),
                last_seq: None,
                ended: false,
                source_gone: false,
            });
        }
        Ok(Self {
            node,
            graph,
            stage,
            run_id: run_id.to_owned(),
            stop,
            commands,
            ended_sources,
            listener,
            inputs,
            stats: StageStats::default(),
            step_started: None,
            publish_wait_ns: Arc::new(AtomicU64::new(0)),
            last_step: None,
            started: Instant::now(),
            any_cursor: 0,
            drain_deadline: None,
            waiter: ArrivalWaiter::default(),
            position: Arc::new(AtomicU64::new(0)),
            restarts,
            restart_flag_pending: restarts > 0,
        })
    }

    /// How many times the launcher started this stage before in this run (its `restart`
    /// policy); 0 for the first start.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }

    /// A file of this stage in the run's own folder (removed when the run ends): where a stage
    /// keeps what a restart of it should find (the calibration stage: its calibration).
    pub fn run_file(&self, name: &str) -> Option<PathBuf> {
        std::env::var_os(ENV_RUN_DIR)
            .map(|dir| PathBuf::from(dir).join(format!("{}.{name}", self.stage.id)))
    }

    /// This stage's id.
    pub fn id(&self) -> &str {
        &self.stage.id
    }

    /// This stage's parameters as written in the graph (already validated for built-in kinds).
    pub fn params(&self) -> &toml::Table {
        &self.stage.params
    }

    /// The whole graph.
    pub fn graph(&self) -> &Graph {
        &self.graph
    }

    /// The sensor set this stage works with (a shipped set's name or a set file's path): the
    /// stage's own `sensors` in the graph file, else the graph's.
    pub fn sensors(&self) -> &str {
        self.stage.sensors.as_deref().unwrap_or(&self.graph.sensors)
    }

    /// This stage's node in the graph.
    pub fn node(&self) -> &StageNode {
        &self.stage
    }

    /// The graph's mode.
    pub fn mode(&self) -> Mode {
        self.graph.mode
    }

    /// Set when the stage should stop (SIGTERM/SIGINT, the launcher's `stop`, or the launcher gone).
    pub fn should_stop(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// The stop flag, for loops that run outside `next` (sources).
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// A typed handle to input `name`; fails if the graph has no such input or its frame type
    /// differs from `T`.
    pub fn input<T: Frame>(&self, name: &str) -> Result<InputId<T>, StageError> {
        let index = self
            .inputs
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| StageError::NoSuchPort {
                stage: self.stage.id.clone(),
                direction: "input",
                port: name.to_owned(),
                known: self
                    .inputs
                    .iter()
                    .map(|s| s.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        let frame = self.inputs[index].subscriber.frame_type();
        if frame != T::TYPE {
            return Err(StageError::PortType {
                stage: self.stage.id.clone(),
                direction: "input",
                port: name.to_owned(),
                graph: frame.name(),
                code: T::TYPE.name(),
            });
        }
        Ok(InputId {
            index,
            _type: PhantomData,
        })
    }

    /// Names of all inputs, in the order `held` indexes them.
    pub fn input_names(&self) -> Vec<String> {
        self.inputs.iter().map(|s| s.name.clone()).collect()
    }

    /// Opens output `port` as frame type `T`.
    pub fn output<T: Frame>(&self, port: &str) -> Result<Output<T>, StageError> {
        let frame = *self
            .stage
            .outputs
            .get(port)
            .ok_or_else(|| StageError::NoSuchPort {
                stage: self.stage.id.clone(),
                direction: "output",
                port: port.to_owned(),
                known: self
                    .stage
                    .outputs
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        if frame != T::TYPE {
            return Err(StageError::PortType {
                stage: self.stage.id.clone(),
                direction: "output",
                port: port.to_owned(),
                graph: frame.name(),
                code: T::TYPE.name(),
            });
        }
        let readers: Vec<String> = self
            .stage
            .readers
            .get(port)
            .map(|rs| rs.iter().map(|r| r.stage.clone()).collect())
            .unwrap_or_default();
        Ok(Output::open(
            &self.node,
            &self.run_id,
            &self.stage.id,
            port,
            self.graph.mode,
            &readers,
            crate::transport::OutputShared {
                stop: self.stop.clone(),
                waited_ns: self.publish_wait_ns.clone(),
                restarts: self.restarts,
            },
        )?)
    }

    /// The start handshake. Tells the launcher this stage's ports exist (`ready`); once every
    /// stage's do (`connect`), connects its readers to their publishers and says so
    /// (`connected`); then waits until every stage is connected (`go`). Frames published before
    /// a reader is connected would be lost, so no frame flows before `go`. Returns `false` if
    /// the stage was told to stop instead.
    pub fn ready(&mut self) -> Result<bool, StageError> {
        control_line("ready")?;
        if !self.wait_for_command(Command::Connect) {
            return Ok(false);
        }
        for slot in &self.inputs {
            slot.subscriber.connect()?;
        }
        control_line("connected")?;
        if !self.wait_for_command(Command::Go) {
            return Ok(false);
        }
        self.started = Instant::now();
        spawn_heartbeat(self.position.clone());
        Ok(true)
    }

    /// Records that the frames up to `seq` were taken (never moves back).
    fn advance(&self, seq: u64) {
        self.position.fetch_max(seq + 1, Ordering::Relaxed);
    }

    /// Waits until the launcher sent `command` (or a later one); `false` on stop.
    fn wait_for_command(&self, command: Command) -> bool {
        while self.commands.load(Ordering::Acquire) < command as u8 {
            if self.should_stop() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        true
    }

    /// Reports a source's progress (`total` = 0 when unknown) to the launcher's progress bar.
    pub fn progress(&self, done: u64, total: u64) -> Result<(), StageError> {
        control_line(&format!("progress {done} {total}"))?;
        Ok(())
    }

    /// Waits for the next aligned set of input frames. `None` when every input reached
    /// END_OF_STREAM or the stage was told to stop.
    // Not an Iterator: it is fallible and lends frames out of the context.
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> Result<Option<Step>, StageError> {
        self.next_step(&mut |_| {})
    }

    /// [`StageContext::next`] that calls `warm` shortly before the next frame is expected
    /// (live streams with a steady rhythm): the stage brings its working set (network weights)
    /// back into cache while it would otherwise idle. `warm` should stop when its argument
    /// returns true (the frame is there). Offline graphs never warm: their cores are busy with
    /// the stream, and a frame's work follows the previous one closely enough to find the
    /// working set in cache.
    pub fn next_warming(
        &mut self,
        warm: &mut dyn FnMut(&mut dyn FnMut() -> bool),
    ) -> Result<Option<Step>, StageError> {
        if self.graph.mode != Mode::Live {
            return self.next_step(&mut |_| {});
        }
        self.next_step(warm)
    }

    fn next_step(
        &mut self,
        warm: &mut dyn FnMut(&mut dyn FnMut() -> bool),
    ) -> Result<Option<Step>, StageError> {
        if let Some(t) = self.step_started.take() {
            self.record_work(t.elapsed());
        }
        // Release the frames of the previous step so their shared memory goes back.
        for slot in self.inputs.iter_mut().filter(|s| !s.feedback) {
            slot.current = None;
        }
        loop {
            if self.should_stop() {
                return Ok(None);
            }
            self.take_ended_sources();
            self.fill_inputs()?;
            if self
                .inputs
                .iter()
                .any(|s| !s.feedback && s.source_gone && s.current.is_none())
            {
                // A stopped branch fed this input and everything it delivered is used: no
                // aligned step can ever be complete again, so the stream ends here.
                return Ok(None);
            }
            if let Some(step) = self.aligned_step() {
                if step.flags & flags::END_OF_STREAM != 0 {
                    return Ok(None);
                }
                self.stats.frames_in += 1;
                let published = self
                    .inputs
                    .iter()
                    .filter(|s| !s.feedback)
                    .filter_map(|s| s.current.as_ref().map(|f| f.header().publish_ns))
                    .max()
                    .unwrap_or(0);
                let now = transport::now_ns();
                self.stats.record_latency(published, now);
                if self.graph.mode == Mode::Live {
                    // Live sources stamp capture on the Unix epoch: end-to-end per input.
                    for slot in self.inputs.iter().filter(|s| !s.feedback) {
                        self.stats
                            .record_from_capture(&slot.name, step.capture_ns, now);
                    }
                }
                self.waiter.arrived(Instant::now());
                self.last_step = Some(step);
                self.advance(step.seq);
                self.step_started = Some(Instant::now());
                let restarted = if std::mem::take(&mut self.restart_flag_pending) {
                    flags::RESTARTED
                } else {
                    0
                };
                return Ok(Some(Step {
                    flags: step.flags & (flags::INVALID | flags::CALIBRATING) | restarted,
                    ..step
                }));
            }
            let Some(listener) = &self.listener else {
                return Ok(None);
            };
            let inputs = &self.inputs;
            // Only a frame that can complete the step ends the wait: one for a forward input that
            // holds none, or a feedback frame. A forward input that already holds this step's
            // frame may have the next ones queued behind it (offline, a stage waiting for its
            // feedback has its upstream running ahead); waking on those would spin this stage
            // through its inputs until the feedback comes, a core's worth of polling (measured:
            // PIP's contact stage at 43 % of a core for 18 µs of work a frame).
            self.waiter.wait_warming(
                listener,
                POLL,
                || {
                    inputs
                        .iter()
                        .any(|s| (s.feedback || s.current.is_none()) && s.subscriber.has_frames())
                },
                warm,
            );
        }
    }

    /// For sinks that take every frame as it arrives (recorders, loggers): the index of an input
    /// holding a new frame (read it with `held`). No alignment, no waiting on feedback. `None`
    /// when every input reached END_OF_STREAM or the stage was told to stop.
    pub fn next_any(&mut self) -> Result<Option<usize>, StageError> {
        if let Some(t) = self.step_started.take() {
            self.record_work(t.elapsed());
        }
        let n = self.inputs.len();
        loop {
            // Told to stop (a crashed stage's neighbours get SIGTERM), a sink still takes what
            // its inputs already hold, for a bounded time, then ends: the frames a writer
            // published before it died belong in the recording.
            let stopping = self.should_stop();
            if stopping {
                let deadline = *self
                    .drain_deadline
                    .get_or_insert_with(|| Instant::now() + SINK_DRAIN);
                if Instant::now() > deadline {
                    return Ok(None);
                }
            }
            if n == 0 {
                return Ok(None);
            }
            self.take_ended_sources();
            for k in 0..n {
                let i = (self.any_cursor + k) % n;
                let slot = &mut self.inputs[i];
                if slot.ended {
                    continue;
                }
                let Some(frame) = slot.subscriber.receive()? else {
                    slot.ended |= slot.source_gone;
                    continue;
                };
                let header = *frame.header();
                self.stats.dropped += missed_before(slot.last_seq, &header);
                if header.is_end() {
                    slot.ended = true;
                    continue;
                }
                slot.last_seq = Some(header.seq);
                slot.current = Some(frame);
                let now = transport::now_ns();
                self.stats.record_latency(header.publish_ns, now);
                if self.graph.mode == Mode::Live {
                    let name = &self.inputs[i].name;
                    self.stats.record_from_capture(name, header.capture_ns, now);
                }
                self.any_cursor = i + 1;
                self.stats.frames_in += 1;
                self.advance(header.seq);
                self.step_started = Some(Instant::now());
                if self.last_step.is_none_or(|s| s.seq <= header.seq) {
                    self.last_step = Some(Step {
                        seq: header.seq,
                        capture_ns: header.capture_ns,
                        flags: 0,
                    });
                }
                return Ok(Some(i));
            }
            if self.inputs.iter().all(|s| s.ended) || stopping {
                return Ok(None);
            }
            let Some(listener) = &self.listener else {
                return Ok(None);
            };
            let inputs = &self.inputs;
            self.waiter.wait(listener, POLL, || {
                inputs.iter().any(|s| !s.ended && s.subscriber.has_frames())
            });
        }
    }

    /// Marks the inputs fed by stages the launcher reported stopped (`ended <stage>`).
    fn take_ended_sources(&mut self) {
        if !self.ended_sources.news.swap(false, Ordering::AcqRel) {
            return;
        }
        let Ok(stages) = self.ended_sources.stages.lock() else {
            return;
        };
        for slot in &mut self.inputs {
            if !slot.source_gone && stages.contains(&slot.from_stage) {
                tracing::warn!(
                    input = %slot.name,
                    "stage '{}' was stopped (its branch failed); this input ends here",
                    slot.from_stage
                );
                slot.source_gone = true;
            }
        }
    }

    /// Takes frames from the subscribers: one pending per forward input, the newest for feedback.
    fn fill_inputs(&mut self) -> Result<(), StageError> {
        let mode = self.graph.mode;
        for slot in &mut self.inputs {
            if slot.feedback {
                while let Some(frame) = slot.subscriber.receive()? {
                    slot.last_seq = Some(frame.header().seq);
                    slot.ended |= frame.header().is_end();
                    if !frame.header().is_end() {
                        slot.current = Some(frame);
                    }
                }
                // Its producer was stopped: keep the last value, stop waiting for newer ones.
                slot.ended |= slot.source_gone;
                continue;
            }
            if slot.current.is_some() {
                continue;
            }
            if let Some(frame) = slot.subscriber.receive()? {
                let seq = frame.header().seq;
                let missed = missed_before(slot.last_seq, frame.header());
                if missed > 0 {
                    // Live graphs overwrite the oldest frame when a reader lags: count the gap.
                    self.stats.dropped += missed;
                    if mode == Mode::Offline {
                        tracing::warn!(input = %slot.name, "{missed} frame(s) before {seq} never arrived");
                    }
                }
                slot.last_seq = Some(seq);
                slot.current = Some(frame);
            }
        }
        Ok(())
    }

    /// If every forward input holds a frame of one `seq` (and feedback is current enough), the
    /// step; frames older than the newest are discarded as unmatched.
    fn aligned_step(&mut self) -> Option<Step> {
        let mut target = 0;
        for slot in self.inputs.iter().filter(|s| !s.feedback) {
            target = target.max(slot.current.as_ref()?.header().seq);
        }
        let mut unmatched = 0;
        for slot in self.inputs.iter_mut().filter(|s| !s.feedback) {
            if slot
                .current
                .as_ref()
                .is_some_and(|f| f.header().seq < target)
            {
                slot.current = None;
                unmatched += 1;
            }
        }
        if unmatched > 0 {
            self.stats.unmatched += unmatched;
            return None;
        }
        let mut step = Step {
            seq: target,
            capture_ns: 0,
            flags: 0,
        };
        for slot in self.inputs.iter().filter(|s| !s.feedback) {
            if let Some(f) = &slot.current {
                let h = f.header();
                step.capture_ns = step.capture_ns.max(h.capture_ns);
                step.flags |= h.flags;
            }
        }
        // Offline: a feedback input must hold the previous frame (its producer cannot be ahead).
        if self.graph.mode == Mode::Offline && target > 0 && step.flags & flags::END_OF_STREAM == 0
        {
            let behind =
                self.inputs.iter().filter(|s| s.feedback).any(|s| {
                    !s.ended && s.last_seq.is_none_or(|seq| seq.saturating_add(1) < target)
                });
            if behind {
                return None;
            }
        }
        Some(step)
    }

    /// The current frame of a typed input (the newest for a feedback input).
    pub fn get<T: Frame>(&self, input: &InputId<T>) -> &T {
        self.inputs
            .get(input.index)
            .and_then(|s| s.current.as_deref())
            .and_then(frame_ref::<T>)
            .unwrap_or_else(|| {
                // The handle was checked against the frame type and `next` fills every slot
                // before returning, so this is a bug in the caller (called before `next`).
                unreachable!("StageContext::get called without a current frame")
            })
    }

    /// The current frame of input `index` (see `input_names`), type-erased.
    pub fn held(&self, index: usize) -> Option<&dyn HeldFrame> {
        self.inputs.get(index).and_then(|s| s.current.as_deref())
    }

    /// Counts a frame written to an output (for outputs not written through `Output`).
    pub fn count_out(&mut self, n: u64) {
        self.stats.frames_out += n;
    }

    /// Ends the stage: END_OF_STREAM on every output, the summary to the launcher.
    pub fn finish(
        mut self,
        outputs: &mut [&mut dyn EndOutput],
    ) -> Result<StageSummary, StageError> {
        if let Some(t) = self.step_started.take() {
            self.record_work(t.elapsed());
        }
        let (seq, capture_ns) = self.last_step.map_or((0, 0), |s| (s.seq + 1, s.capture_ns));
        let mut end_error = None;
        for out in outputs.iter_mut() {
            if let Err(e) = out.end(seq, capture_ns) {
                end_error.get_or_insert(e);
            }
            self.stats.frames_out += out.frames_sent().saturating_sub(1);
        }
        let summary = self.stats.summary(self.started.elapsed());
        let json = serde_json::to_string(&summary).unwrap_or_default();
        control_line(&format!("summary {json}"))?;
        match end_error {
            // After a stop request a reader may be gone; that is the expected end.
            Some(TransportError::Stopped { .. }) | None => Ok(summary),
            Some(e) => Err(e.into()),
        }
    }

    /// Records a step's processing time, less the time its outputs waited for full readers
    /// (offline back-pressure): the summary's processing time and busy share are the stage's own
    /// work, so the stage nearest 100 % busy is the bottleneck.
    fn record_work(&mut self, elapsed: Duration) {
        let waited = Duration::from_nanos(self.publish_wait_ns.swap(0, Ordering::Relaxed));
        self.stats.record_processing(elapsed.saturating_sub(waited));
    }

    /// One line of this stage's own end-of-run result (scores, counts) for the run summary.
    pub fn set_summary_detail(&mut self, line: impl Into<String>) {
        self.stats.detail = line.into();
    }

    /// For sources: records `n` frames as produced and `elapsed` as the time producing them took.
    pub fn record_source_step(&mut self, step: Step, elapsed: Duration) {
        self.stats.frames_in += 1;
        self.record_work(elapsed);
        self.last_step = Some(step);
        self.advance(step.seq);
    }
}

/// How often a running stage tells the launcher how far it got (`alive <position>`).
pub const HEARTBEAT: Duration = Duration::from_millis(250);

/// Reports the stage's position to the launcher every [`HEARTBEAT`] from a thread of its own, so
/// a stage stuck in its own code still reports (its position stands still), and a process that
/// is not running at all (stopped, frozen) goes quiet. Ends when the launcher is gone.
fn spawn_heartbeat(position: Arc<AtomicU64>) {
    let spawned = std::thread::Builder::new()
        .name("imuflow-heartbeat".into())
        .spawn(move || {
            loop {
                let at = position.load(Ordering::Relaxed);
                if control_line(&format!("alive {at}")).is_err() {
                    break;
                }
                std::thread::sleep(HEARTBEAT);
            }
        });
    if spawned.is_err() {
        tracing::warn!(
            "cannot start the heartbeat thread; the stall watchdog cannot see this stage"
        );
    }
}

/// Frames of an input that never arrived before `header`, given the last `seq` received (counting
/// from frame 0 when none was). END_OF_STREAM carries the `seq` after the last frame its output
/// published, so frames lost just before the end count too. An input that ends before it delivered anything
/// (an output its producer never wrote, such as the truth of a source without one) lost nothing:
/// its END_OF_STREAM's `seq` is then the producer's frame count.
fn missed_before(last_seq: Option<u64>, header: &FrameHeader) -> u64 {
    match last_seq {
        Some(last) => header.seq.saturating_sub(last + 1),
        None if header.is_end() => 0,
        None => header.seq,
    }
}

fn env(name: &'static str) -> Result<String, StageError> {
    std::env::var(name).map_err(|_| StageError::MissingEnv(name))
}

/// Writes one control line to the launcher.
fn control_line(text: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{CONTROL_PREFIX}{text}")?;
    out.flush()
}

/// The launcher's start commands, in the order it sends them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
enum Command {
    Connect = 1,
    Go = 2,
}

/// Stages whose branch the launcher stopped, as told by `ended <stage>` lines.
#[derive(Default)]
struct EndedSources {
    stages: Mutex<Vec<String>>,
    /// Set when `stages` grew; the stage loop takes it.
    news: AtomicBool,
}

/// Reads the launcher's commands from stdin: `connect`, then `go` start the stage; `stop` (or
/// stdin closing, which means the launcher is gone) stops it; `ended <stage>` says a stage this
/// one may read from was stopped with its branch.
fn spawn_control_reader(
    stop: Arc<AtomicBool>,
    commands: Arc<AtomicU8>,
    ended_sources: Arc<EndedSources>,
) {
    let spawned = std::thread::Builder::new()
        .name("imuflow-control".into())
        .spawn(move || {
            for line in std::io::stdin().lock().lines() {
                match line.as_deref().map(str::trim) {
                    Ok("connect") => {
                        commands.fetch_max(Command::Connect as u8, Ordering::AcqRel);
                    }
                    Ok("go") => {
                        commands.fetch_max(Command::Go as u8, Ordering::AcqRel);
                    }
                    Ok("stop") => stop.store(true, Ordering::Release),
                    Ok(line) if line.starts_with("ended ") => {
                        let stage = line["ended ".len()..].trim().to_owned();
                        if let Ok(mut stages) = ended_sources.stages.lock() {
                            stages.push(stage);
                            ended_sources.news.store(true, Ordering::Release);
                        }
                    }
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
            stop.store(true, Ordering::Release);
        });
    if spawned.is_err() {
        tracing::warn!("cannot start the control thread; the stage will only stop on signals");
    }
}

/// Parsed control lines from a stage's stdout (used by the launcher).
#[derive(Debug, Clone, PartialEq)]
pub enum ControlMessage {
    /// The stage's ports exist.
    Ready,
    /// The stage's readers are connected to their publishers.
    Connected,
    Progress {
        done: u64,
        total: u64,
    },
    Summary(StageSummary),
    /// Heartbeat: the seq after the newest frame the stage took (0: none yet).
    Alive {
        position: u64,
    },
}

impl ControlMessage {
    /// Parses a stdout line; `None` if it is not a control line.
    pub fn parse(line: &str) -> Option<ControlMessage> {
        let rest = line.strip_prefix(CONTROL_PREFIX)?;
        let (word, args) = rest.split_once(' ').unwrap_or((rest, ""));
        match word {
            "ready" => Some(ControlMessage::Ready),
            "alive" => args
                .trim()
                .parse()
                .ok()
                .map(|position| ControlMessage::Alive { position }),
            "connected" => Some(ControlMessage::Connected),
            "progress" => {
                let mut it = args.split_whitespace().map(str::parse::<u64>);
                match (it.next(), it.next()) {
                    (Some(Ok(done)), Some(Ok(total))) => {
                        Some(ControlMessage::Progress { done, total })
                    }
                    _ => None,
                }
            }
            "summary" => serde_json::from_str(args).ok().map(ControlMessage::Summary),
            _ => None,
        }
    }
}

/// Parameters of a stage, read key by key with a default given at each read. A stage that declares
/// its parameters with [`crate::stage_params!`] reads them typed, with the declared defaults.
pub struct Params<'a>(pub &'a toml::Table);

impl Params<'_> {
    pub fn str(&self, key: &str) -> Option<&str> {
        self.0.get(key).and_then(toml::Value::as_str)
    }
    pub fn bool(&self, key: &str, default: bool) -> bool {
        self.0
            .get(key)
            .and_then(toml::Value::as_bool)
            .unwrap_or(default)
    }
    pub fn int(&self, key: &str, default: i64) -> i64 {
        self.0
            .get(key)
            .and_then(toml::Value::as_integer)
            .unwrap_or(default)
    }
    pub fn float(&self, key: &str, default: f64) -> f64 {
        match self.0.get(key) {
            Some(toml::Value::Float(x)) => *x,
            Some(toml::Value::Integer(i)) => *i as f64,
            _ => default,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(seq: u64, flags: u32) -> FrameHeader {
        FrameHeader {
            seq,
            flags,
            ..Default::default()
        }
    }

    #[test]
    fn missed_frames_are_the_gaps_in_seq_including_before_the_end() {
        assert_eq!(missed_before(Some(4), &header(5, 0)), 0);
        assert_eq!(missed_before(Some(4), &header(7, 0)), 2); // 5 and 6
        assert_eq!(missed_before(None, &header(3, 0)), 3); // 0, 1, 2 before the first received
        assert_eq!(missed_before(None, &header(0, 0)), 0);
        // END_OF_STREAM's seq is one past the producer's last frame.
        assert_eq!(missed_before(Some(9), &header(10, flags::END_OF_STREAM)), 0);
        assert_eq!(missed_before(Some(9), &header(12, flags::END_OF_STREAM)), 2); // 10 and 11
        // An input whose producer never wrote it (a source without truth) ends without a gap.
        assert_eq!(missed_before(None, &header(1513, flags::END_OF_STREAM)), 0);
    }
}
