//! Typed ports over iceoryx2: one publish-subscribe service per output (fan-out to every reader),
//! and one event service per reading stage so a publisher can wake its readers (iceoryx2's
//! publish-subscribe has no wake-up of its own).
//!
//! Offline graphs never drop: a full reader buffer makes the publisher wait (back-pressure). Live
//! graphs let a full buffer overwrite its oldest frame; readers count the gaps in `seq` as drops.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use iceoryx2::port::BackpressureAction;
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::prelude::*;

use crate::frames::{
    BodyImuFrame, ContactFrame, Frame, FrameHeader, FrameType, ImuFrame, KinematicsFrame,
    MotionFrame, RawImuFrame, ValidationFrame, flags,
};
use crate::graph::Mode;

/// Environment variable naming the base of imuflow's shared-memory file names (default
/// [`DEFAULT_SHM_PREFIX`]). Tests set it to isolate their runs and to find leftovers.
pub const ENV_SHM_PREFIX: &str = "IMUFLOW_SHM_PREFIX";
/// Environment variable the launcher sets for its stages: the run's own prefix.
pub const ENV_RUN_SHM_PREFIX: &str = "IMUFLOW_RUN_SHM_PREFIX";
/// Base of every shared-memory and iceoryx2 file name imuflow creates.
pub const DEFAULT_SHM_PREFIX: &str = "imuflow_";

/// The base prefix in effect for this process.
pub fn base_shm_prefix() -> String {
    std::env::var(ENV_SHM_PREFIX).unwrap_or_else(|_| DEFAULT_SHM_PREFIX.to_owned())
}

/// The prefix of one run's files: `<base><launcher pid>_<run id>_`. Each run is its own iceoryx2
/// domain, so the launcher can remove every file of its run once its stages are gone (iceoryx2
/// keeps a per-domain node counter alive otherwise), and a later run can tell from the pid
/// whether a run's files are stale.
pub fn run_shm_prefix(base: &str, launcher_pid: u32, run_id: &str) -> String {
    format!("{base}{launcher_pid}_{run_id}_")
}

/// The iceoryx2 configuration of the domain `prefix`: iceoryx2's defaults with imuflow's file
/// prefix, so imuflow finds its own files and nobody else's.
pub fn iceoryx_config_for(prefix: &str) -> Config {
    let mut config = Config::default();
    if let Ok(prefix) = FileName::new(prefix.as_bytes()) {
        config.global.prefix = prefix;
    }
    config
}

/// The iceoryx2 configuration of this process: its run's domain when started by the launcher.
pub fn iceoryx_config() -> Config {
    let prefix = std::env::var(ENV_RUN_SHM_PREFIX).unwrap_or_else(|_| base_shm_prefix());
    iceoryx_config_for(&prefix)
}

/// Reader buffer per edge in offline graphs: deep enough that stages with uneven per-frame cost
/// keep each other busy.
const OFFLINE_BUFFER: usize = 16;
/// Reader buffer per edge in live graphs: deep enough for the frames of a 100 ms stall's backlog
/// published at once (up to 160 frames a second), so a burst is queued, not overwritten; a stage
/// more than this many frames behind drops the oldest rather than adding more latency.
const LIVE_BUFFER: usize = 16;
/// Reader buffer of raw-sample edges in live graphs: a source publishes samples as they arrive,
/// up to one frame per sample (six trackers at 100 Hz whose ticks do not coincide: 600 frames a
/// second), so a 100 ms backlog is up to 60 frames.
const LIVE_RAW_BUFFER: usize = 64;
/// How long a writer sleeps before trying a full reader's buffer again (offline).
const BACKPRESSURE_SLEEP: Duration = Duration::from_micros(200);
/// Samples a reader may hold at once: the current frame of each input plus the latest feedback.
const MAX_BORROWED: usize = 4;
/// Spare subscriber slots per output beyond the graph's readers (tools that tap an edge).
const SPARE_SUBSCRIBERS: usize = 2;
/// Notifiers per wake service: one per output of every upstream stage, generously.
const MAX_NOTIFIERS: usize = 64;
/// Listeners per wake service: the stage's own, and one spare (a restarted process's while the
/// dead one's is cleaned up).
const MAX_LISTENERS: usize = 2;
/// Publishers per output service: the stage's own, and one spare (likewise).
const MAX_PUBLISHERS: usize = 2;

/// The settings every port of a service must agree on, for stages in other languages
/// ([`crate::wire`]): a service opened with other values is a different service.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct TransportSettings {
    pub offline_buffer: usize,
    pub live_buffer: usize,
    pub live_raw_buffer: usize,
    pub max_borrowed: usize,
    pub spare_subscribers: usize,
    pub max_publishers: usize,
    pub max_notifiers: usize,
    pub max_listeners: usize,
}

/// This build's [`TransportSettings`].
pub fn settings() -> TransportSettings {
    TransportSettings {
        offline_buffer: OFFLINE_BUFFER,
        live_buffer: LIVE_BUFFER,
        live_raw_buffer: LIVE_RAW_BUFFER,
        max_borrowed: MAX_BORROWED,
        spare_subscribers: SPARE_SUBSCRIBERS,
        max_publishers: MAX_PUBLISHERS,
        max_notifiers: MAX_NOTIFIERS,
        max_listeners: MAX_LISTENERS,
    }
}

/// Why a port could not be opened or used.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// iceoryx2 could not create the process's node (shared memory unavailable or full).
    #[error("cannot create the shared-memory node for stage '{stage}': {message}")]
    Node { stage: String, message: String },
    /// A service could not be opened or created; usually a frame type that differs between
    /// stages built from different versions.
    #[error("cannot open service '{service}': {message}")]
    Service { service: String, message: String },
    /// A port on an open service could not be created (too many readers or writers).
    #[error("cannot create {what} on '{service}': {message}")]
    Port {
        what: &'static str,
        service: String,
        message: String,
    },
    #[error("sending on '{service}' failed: {message}")]
    Send { service: String, message: String },
    #[error("receiving on '{service}' failed: {message}")]
    Receive { service: String, message: String },
    /// The stage was told to stop while a reader was not consuming (offline back-pressure).
    #[error("stopped while waiting for a reader of '{service}' to make room")]
    Stopped { service: String },
}

/// Creates this process's iceoryx2 node. Signal handling is left to imuflow (see `stage`).
pub fn create_node(stage: &str) -> Result<Node<ipc::Service>, TransportError> {
    let err = |message: String| TransportError::Node {
        stage: stage.to_owned(),
        message,
    };
    let name = NodeName::new(stage).map_err(|e| err(format!("{e:?}")))?;
    NodeBuilder::new()
        .name(&name)
        .config(&iceoryx_config())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| err(format!("{e:?}")))
}

/// Removes the shared-memory resources of dead processes of the domain `prefix` through
/// iceoryx2 (which also deregisters them from the services). Returns (cleaned, failed).
pub fn cleanup_dead_nodes(prefix: &str) -> Result<(u64, u64), TransportError> {
    let err = |message: String| TransportError::Node {
        stage: "imuflow-cleaner".into(),
        message,
    };
    let name = NodeName::new("imuflow-cleaner").map_err(|e| err(format!("{e:?}")))?;
    let node = NodeBuilder::new()
        .name(&name)
        .config(&iceoryx_config_for(prefix))
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| err(format!("{e:?}")))?;
    let state = node.blocking_cleanup_dead_nodes(Duration::from_millis(500));
    Ok((state.cleanups, state.failed_cleanups))
}

/// The service name of an output port. The only place service names are built.
pub fn output_service_name(run_id: &str, stage: &str, port: &str) -> String {
    format!("imuflow/{run_id}/{stage}/out/{port}")
}

/// The service name of a stage's wake-up events.
pub fn wake_service_name(run_id: &str, stage: &str) -> String {
    format!("imuflow/{run_id}/{stage}/wake")
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(|e| TransportError::Service {
        service: name.to_owned(),
        message: format!("{e:?}"),
    })
}

type PubSub<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;

fn open_pubsub<T: Frame>(
    node: &Node<ipc::Service>,
    name: &str,
    mode: Mode,
    readers: usize,
) -> Result<PubSub<T>, TransportError> {
    let (buffer, overflow) = match mode {
        Mode::Offline => (OFFLINE_BUFFER, false),
        Mode::Live if T::TYPE == FrameType::RawImu => (LIVE_RAW_BUFFER, true),
        Mode::Live => (LIVE_BUFFER, true),
    };
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .subscriber_max_buffer_size(buffer)
        .subscriber_max_borrowed_samples(MAX_BORROWED)
        .enable_safe_overflow(overflow)
        .history_size(0)
        .max_publishers(MAX_PUBLISHERS)
        .max_subscribers(readers + SPARE_SUBSCRIBERS)
        .open_or_create()
        .map_err(|e| TransportError::Service {
            service: name.to_owned(),
            message: format!("{e:?}"),
        })
}

fn open_event(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, TransportError> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_notifiers(MAX_NOTIFIERS)
        .max_listeners(MAX_LISTENERS)
        .open_or_create()
        .map_err(|e| TransportError::Service {
            service: name.to_owned(),
            message: format!("{e:?}"),
        })
}

/// Wakes this stage when any upstream publishes.
pub struct WakeListener {
    listener: iceoryx2::port::listener::Listener<ipc::Service>,
    _service: iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
}

impl WakeListener {
    pub fn open(
        node: &Node<ipc::Service>,
        run_id: &str,
        stage: &str,
    ) -> Result<Self, TransportError> {
        let name = wake_service_name(run_id, stage);
        let service = open_event(node, &name)?;
        let listener = service
            .listener_builder()
            .create()
            .map_err(|e| TransportError::Port {
                what: "listener",
                service: name,
                message: format!("{e:?}"),
            })?;
        Ok(Self {
            listener,
            _service: service,
        })
    }

    /// Blocks until woken or `timeout` passes; consumes every pending wake-up.
    pub fn wait(&self, timeout: Duration) {
        // Errors here only mean "no event"; the caller re-checks its inputs either way.
        let _ = self.listener.timed_wait(|_| {}, timeout);
    }

    /// Consumes pending wake-ups without blocking.
    pub fn drain(&self) {
        let _ = self.listener.try_wait(|_| {});
    }
}

/// A typed output port: publishes frames to every reader of `stage.port` and wakes them.
pub struct Output<T: Frame> {
    service_label: String,
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>,
    notifiers: Vec<iceoryx2::port::notifier::Notifier<ipc::Service>>,
    _services: (
        PubSub<T>,
        Vec<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>>,
    ),
    sent: u64,
    /// The highest `seq` published (END_OF_STREAM aside).
    last_seq: Option<u64>,
    /// Nanoseconds spent in `send` (offline: waiting for a full reader, back-pressure), shared
    /// with the stage's context so its processing time leaves them out.
    waited_ns: Arc<AtomicU64>,
    /// Every frame's `header.restarts`.
    restarts: u32,
}

/// What an output shares with its stage: the stop flag it gives up waiting on, the counter of
/// time spent waiting for full readers, and how many times the stage was restarted before.
#[derive(Clone, Debug, Default)]
pub struct OutputShared {
    pub stop: Arc<AtomicBool>,
    pub waited_ns: Arc<AtomicU64>,
    /// Written into every frame's header ([`FrameHeader::restarts`]).
    pub restarts: u32,
}

impl<T: Frame> Output<T> {
    /// Opens output `port` of `stage`, read by the stages in `reader_stages`.
    pub fn open(
        node: &Node<ipc::Service>,
        run_id: &str,
        stage: &str,
        port: &str,
        mode: Mode,
        reader_stages: &[String],
        shared: OutputShared,
    ) -> Result<Self, TransportError> {
        let OutputShared {
            stop,
            waited_ns,
            restarts,
        } = shared;
        let name = output_service_name(run_id, stage, port);
        let service = open_pubsub::<T>(node, &name, mode, reader_stages.len())?;
        let strategy = match mode {
            Mode::Offline => BackpressureStrategy::RetryUntilDelivered,
            Mode::Live => BackpressureStrategy::DiscardData,
        };
        let publisher = service
            .publisher_builder()
            .backpressure_strategy(strategy)
            .set_backpressure_handler(move |_: &iceoryx2::port::BackpressureInfo| {
                // A reader's buffer is full (offline: the stream runs as fast as its slowest
                // reader). Sleep, without spinning first: the buffer holds OFFLINE_BUFFER frames,
                // so the reader has work for longer than the sleep, and on two cores a spinning
                // (or yielding) writer takes the time of the very reader it waits for. Measured
                // offline on the sample, alternating binaries, four runs each: globalpose graph
                // median 1,340 frames/s with 200 spins before each sleep, 1,455 without (pip 787,
                // 844). Give up when told to stop.
                if stop.load(Ordering::Relaxed) {
                    return BackpressureAction::DiscardDataAndFail;
                }
                std::thread::sleep(BACKPRESSURE_SLEEP);
                BackpressureAction::Retry
            })
            .create()
            .map_err(|e| TransportError::Port {
                what: "publisher",
                service: name.clone(),
                message: format!("{e:?}"),
            })?;
        let mut wake_services = Vec::new();
        let mut notifiers = Vec::new();
        let mut distinct: Vec<&String> = reader_stages.iter().collect();
        distinct.sort();
        distinct.dedup();
        for reader in distinct {
            let wake = wake_service_name(run_id, reader);
            let event = open_event(node, &wake)?;
            notifiers.push(event.notifier_builder().create().map_err(|e| {
                TransportError::Port {
                    what: "notifier",
                    service: wake.clone(),
                    message: format!("{e:?}"),
                }
            })?);
            wake_services.push(event);
        }
        Ok(Self {
            service_label: format!("{stage}.{port}"),
            publisher,
            notifiers,
            _services: (service, wake_services),
            sent: 0,
            last_seq: None,
            waited_ns,
            restarts,
        })
    }

    /// Publishes one frame: `fill` writes the payload into shared memory (starting from zeros).
    /// `seq` and `capture_ns` come from `header`; the flags are `header`'s plus any `fill` set
    /// (e.g. INVALID for a bad sample); `publish_ns` is stamped now.
    pub fn publish(
        &mut self,
        header: FrameHeader,
        fill: impl FnOnce(&mut T),
    ) -> Result<(), TransportError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| TransportError::Send {
                service: self.service_label.clone(),
                message: format!("{e:?}"),
            })?;
        let mut sample = sample.write_payload(T::zeroed());
        let frame = sample.payload_mut();
        fill(frame);
        let flags_from_fill = frame.header().flags;
        *frame.header_mut() = FrameHeader {
            publish_ns: now_ns(),
            flags: header.flags | flags_from_fill,
            restarts: self.restarts,
            ..header
        };
        let sending = std::time::Instant::now();
        let sent = sample.send();
        self.waited_ns
            .fetch_add(sending.elapsed().as_nanos() as u64, Ordering::Relaxed);
        match sent {
            Ok(_) => {}
            Err(iceoryx2::port::SendError::UnableToDeliver) => {
                return Err(TransportError::Stopped {
                    service: self.service_label.clone(),
                });
            }
            Err(e) => {
                return Err(TransportError::Send {
                    service: self.service_label.clone(),
                    message: format!("{e:?}"),
                });
            }
        }
        self.sent += 1;
        if header.flags & flags::END_OF_STREAM == 0 {
            self.last_seq = Some(self.last_seq.map_or(header.seq, |s| s.max(header.seq)));
        }
        for n in &self.notifiers {
            // A reader that already exited has no listener; that is not an error here.
            let _ = n.notify();
        }
        Ok(())
    }

    /// Publishes the END_OF_STREAM marker after the last frame: its `seq` is one past the last
    /// frame this output published (a reader counts the frames between its last and that as never
    /// arrived), or `seq` when it published none. An output a stage writes for only some of its
    /// steps (a source's truth or ideal sensors beside its raw samples) thus ends after its own
    /// frames, not after the stage's.
    pub fn publish_end(&mut self, seq: u64, capture_ns: u64) -> Result<(), TransportError> {
        self.publish(
            FrameHeader {
                seq: self.last_seq.map_or(seq, |last| last + 1),
                capture_ns,
                flags: flags::END_OF_STREAM,
                ..Default::default()
            },
            |_| {},
        )
    }

    /// Frames published so far (END_OF_STREAM included).
    pub fn sent(&self) -> u64 {
        self.sent
    }
}

/// A frame held in shared memory (or, for a feedback input's initial value, in local memory).
pub trait HeldFrame {
    fn frame_type(&self) -> FrameType;
    fn header(&self) -> &FrameHeader;
    /// The whole frame, `#[repr(C)]` bytes, aligned for its type.
    fn bytes(&self) -> &[u8];
}

struct SharedSample<T: Frame>(iceoryx2::sample::Sample<ipc::Service, T, ()>);

impl<T: Frame> HeldFrame for SharedSample<T> {
    fn frame_type(&self) -> FrameType {
        T::TYPE
    }
    fn header(&self) -> &FrameHeader {
        self.0.payload().header()
    }
    fn bytes(&self) -> &[u8] {
        bytemuck::bytes_of(self.0.payload())
    }
}

struct LocalFrame<T: Frame>(T);

impl<T: Frame> HeldFrame for LocalFrame<T> {
    fn frame_type(&self) -> FrameType {
        T::TYPE
    }
    fn header(&self) -> &FrameHeader {
        self.0.header()
    }
    fn bytes(&self) -> &[u8] {
        bytemuck::bytes_of(&self.0)
    }
}

/// Borrows a held frame as its concrete type; `None` if the type differs.
pub fn frame_ref<T: Frame>(held: &dyn HeldFrame) -> Option<&T> {
    if held.frame_type() != T::TYPE {
        return None;
    }
    bytemuck::try_from_bytes(held.bytes()).ok()
}

/// A subscriber whose frame type is known only at run time (recorders, loggers, the stage runner).
pub trait ErasedSubscriber {
    fn frame_type(&self) -> FrameType;
    /// Takes the oldest pending frame, if any.
    fn receive(&self) -> Result<Option<Box<dyn HeldFrame>>, TransportError>;
    /// Whether a frame is pending (cheap; used while spinning).
    fn has_frames(&self) -> bool;
    /// Completes this reader's half of the connection to every publisher of the edge. Until
    /// then a publisher that fills the reader's buffer treats it as not connected and discards
    /// (iceoryx2 only blocks for connected readers), so this must happen before any frame flows.
    fn connect(&self) -> Result<(), TransportError>;
}

struct TypedSubscriber<T: Frame> {
    label: String,
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>,
    _service: PubSub<T>,
}

impl<T: Frame> ErasedSubscriber for TypedSubscriber<T> {
    fn frame_type(&self) -> FrameType {
        T::TYPE
    }
    fn receive(&self) -> Result<Option<Box<dyn HeldFrame>>, TransportError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(Box::new(SharedSample(sample)))),
            Ok(None) => Ok(None),
            Err(e) => Err(TransportError::Receive {
                service: self.label.clone(),
                message: format!("{e:?}"),
            }),
        }
    }
    fn has_frames(&self) -> bool {
        self.subscriber.has_samples().unwrap_or(true)
    }
    fn connect(&self) -> Result<(), TransportError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.subscriber
            .update_connections()
            .map_err(|e| TransportError::Receive {
                service: self.label.clone(),
                message: format!("cannot connect: {e:?}"),
            })
    }
}

fn open_typed<T: Frame>(
    node: &Node<ipc::Service>,
    run_id: &str,
    from_stage: &str,
    from_port: &str,
    mode: Mode,
    readers: usize,
) -> Result<Box<dyn ErasedSubscriber>, TransportError> {
    let name = output_service_name(run_id, from_stage, from_port);
    let service = open_pubsub::<T>(node, &name, mode, readers)?;
    let subscriber = service
        .subscriber_builder()
        .create()
        .map_err(|e| TransportError::Port {
            what: "subscriber",
            service: name.clone(),
            message: format!("{e:?}"),
        })?;
    Ok(Box::new(TypedSubscriber {
        label: format!("{from_stage}.{from_port}"),
        subscriber,
        _service: service,
    }))
}

/// Opens a subscriber on `from_stage.from_port` for a frame type known at run time. `readers` is
/// the number of readers the graph declares for that output (it sizes the service).
pub fn open_subscriber(
    node: &Node<ipc::Service>,
    run_id: &str,
    from_stage: &str,
    from_port: &str,
    frame: FrameType,
    mode: Mode,
    readers: usize,
) -> Result<Box<dyn ErasedSubscriber>, TransportError> {
    match frame {
        FrameType::RawImu => {
            open_typed::<RawImuFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::Imu => {
            open_typed::<ImuFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::BodyImu => {
            open_typed::<BodyImuFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::Kinematics => {
            open_typed::<KinematicsFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::Contact => {
            open_typed::<ContactFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::Motion => {
            open_typed::<MotionFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
        FrameType::Validation => {
            open_typed::<ValidationFrame>(node, run_id, from_stage, from_port, mode, readers)
        }
    }
}

/// The value a feedback input holds before its producer published anything: zeros, flagged
/// FEEDBACK_INITIAL and INVALID, with `seq` = `u64::MAX` ("before the first frame").
pub fn initial_feedback_frame(frame: FrameType) -> Box<dyn HeldFrame> {
    fn make<T: Frame>() -> Box<dyn HeldFrame> {
        let mut f = T::zeroed();
        *f.header_mut() = FrameHeader {
            seq: u64::MAX,
            flags: flags::FEEDBACK_INITIAL | flags::INVALID,
            ..Default::default()
        };
        Box::new(LocalFrame(f))
    }
    match frame {
        FrameType::RawImu => make::<RawImuFrame>(),
        FrameType::Imu => make::<ImuFrame>(),
        FrameType::BodyImu => make::<BodyImuFrame>(),
        FrameType::Kinematics => make::<KinematicsFrame>(),
        FrameType::Contact => make::<ContactFrame>(),
        FrameType::Motion => make::<MotionFrame>(),
        FrameType::Validation => make::<ValidationFrame>(),
    }
}

/// Nanoseconds since the Unix epoch.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
