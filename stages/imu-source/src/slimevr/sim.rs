//! Simulated SlimeVR trackers: each one does what the firmware's network code does (handshake
//! broadcast every second until a server answers, sensor info until acknowledged, feature-flags
//! requests, heartbeat answers, ping echoes, bundles when the server supports them, back to
//! searching after 3 s without a word from the server) and streams a rotation and an
//! acceleration packet per sensor and tick from a known motion ([`motion`]), so a receiver can be
//! checked against it. Used by `tools/slimevr-sim` and the tests.

use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};

use super::mapping::site_names;
use super::packets::{
    self, Acceleration, DATA_TYPE_NORMAL, Handshake, Mac, Packet, Rotation, SensorInfo,
    ServerPacket, server_feature,
};

/// One simulated tracker board: its MAC and how many IMUs (sensor ids 0..sensors) it carries.
#[derive(Debug, Clone, PartialEq)]
pub struct SimTracker {
    pub mac: Mac,
    pub sensors: u8,
}

/// Faults injected into the data datagrams (each `*_every` = 0: never), after the firmware has
/// numbered them, the way a wireless network loses, repeats and reorders datagrams.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimFaults {
    /// Every N-th data datagram is not sent (its packet number is used up).
    pub drop_every: u64,
    /// Every N-th data datagram is sent twice.
    pub duplicate_every: u64,
    /// Every N-th data datagram is held back and sent after the next one.
    pub swap_every: u64,
    /// Stalls, as a Wi-Fi link stalls: nothing is sent for a while, then the backlog goes out
    /// back to back.
    pub stall: Option<Stall>,
}

/// Every `every_ticks` ticks, the last `ticks` of them are held back and sent, each with its own
/// packet number and data, back to back just before the next tick's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stall {
    pub every_ticks: u64,
    pub ticks: u64,
}

impl Stall {
    /// Whether tick `tick` is held back.
    pub fn holds(&self, tick: u64) -> bool {
        self.every_ticks > 0
            && tick % self.every_ticks >= self.every_ticks.saturating_sub(self.ticks)
    }
}

/// What to simulate.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Where the server listens.
    pub server: String,
    pub trackers: Vec<SimTracker>,
    /// Ticks per second; each tick sends every sensor's rotation and acceleration.
    pub rate_hz: f64,
    /// Ticks to send.
    pub ticks: u64,
    /// Bundle each tick's packets when the server announces bundle support (the firmware's
    /// default build, `PACKET_BUNDLING`); false: always one packet per datagram.
    pub bundle: bool,
    /// Give up when no server answered the handshake within this long.
    pub handshake_timeout: Duration,
    pub faults: SimFaults,
}

/// What one simulated tracker did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimReport {
    pub mac: Option<Mac>,
    /// Ticks streamed (while connected).
    pub ticks_sent: u64,
    /// Datagrams sent, all kinds, faults included.
    pub datagrams: u64,
    /// Data datagrams sent as bundles.
    pub bundles: u64,
    /// Handshakes the server answered (1 without reconnections).
    pub connections: u64,
    /// Heartbeats the server sent.
    pub heartbeats: u64,
    /// Data datagrams the faults dropped, sent twice, held back behind the next one.
    pub dropped: u64,
    pub duplicated: u64,
    pub swapped: u64,
    /// Ticks held back by stalls (all sent with the backlog).
    pub stalled: u64,
}

/// Board, MCU and firmware the simulated trackers announce (`BoardType.SLIMEVR`,
/// `MCUType.ESP8266` in the server's FirmwareConstants.kt).
const BOARD: u32 = 9;
const MCU: u32 = 1;
const FIRMWARE: &str = "imuflow-slimevr-sim";
/// The current firmware's `PROTOCOL_VERSION` field position; any number above 8 makes the
/// server wait for sensor info packets, as with real trackers.
const FIRMWARE_BUILD: u32 = 21;
/// How often the firmware repeats a handshake, sensor info and feature-flags request
/// (`searchForServer`: 1 s, `SensorStateSendIntervalMillis`: 1 s,
/// `FeatureFlagsRequestIntervalMillis`: 500 ms, at most 15 times).
const HANDSHAKE_EVERY: Duration = Duration::from_secs(1);
const SENSOR_INFO_EVERY: Duration = Duration::from_secs(1);
const FEATURE_FLAGS_EVERY: Duration = Duration::from_millis(500);
const FEATURE_FLAGS_ATTEMPTS: u32 = 15;
/// The firmware's `ServerResponseTimeoutMillis`.
const SERVER_TIMEOUT: Duration = Duration::from_secs(3);

/// Simulated trackers with MACs `02:53:4c:00:00:01`, ... (locally administered), one sensor each.
pub fn default_trackers(count: usize) -> Vec<SimTracker> {
    (1..=count)
        .map(|i| SimTracker {
            mac: Mac([0x02, 0x53, 0x4c, 0x00, (i >> 8) as u8, i as u8]),
            sensors: 1,
        })
        .collect()
}

/// A trackers file for `trackers`: their sensors in order on the sites in IMU order (at most
/// six sensors are mapped).
pub fn trackers_toml(trackers: &[SimTracker]) -> String {
    let sensors = trackers
        .iter()
        .flat_map(|t| (0..t.sensors).map(move |s| (t.mac, s)));
    let mut text =
        String::from("# Simulated SlimeVR trackers (tools/slimevr-sim) on the six sites.\n");
    for ((mac, sensor), site) in sensors.zip(site_names()) {
        text.push_str(&format!(
            "\n[[tracker]]\nmac = \"{mac}\"\nsensor = {sensor}\nsite = \"{site}\"\n"
        ));
    }
    text
}

/// Runs every simulated tracker (a thread each, its own socket as each board has its own
/// address) until its ticks are sent or `stop` is set; their reports in order.
pub fn run(options: &SimOptions, stop: Arc<AtomicBool>) -> anyhow::Result<Vec<SimReport>> {
    if !(options.rate_hz.is_finite() && options.rate_hz > 0.0) {
        bail!(
            "rate must be a positive number of Hz (got {})",
            options.rate_hz
        );
    }
    let server = options
        .server
        .to_socket_addrs()
        .with_context(|| format!("cannot resolve server address '{}'", options.server))?
        .next()
        .with_context(|| format!("server address '{}' resolves to nothing", options.server))?;
    let start = Instant::now();
    let mut first_sensor = 0usize;
    let handles: Vec<_> = options
        .trackers
        .iter()
        .map(|t| {
            let tracker = SimulatedTracker::new(t.clone(), first_sensor, server, options)?;
            first_sensor += usize::from(t.sensors);
            let stop = stop.clone();
            Ok(std::thread::spawn(move || tracker.run(start, &stop)))
        })
        .collect::<anyhow::Result<_>>()?;
    handles
        .into_iter()
        .map(|h| {
            h.join()
                .map_err(|_| anyhow::anyhow!("a simulated tracker panicked"))?
        })
        .collect()
}

/// The known motion of simulated sensor `index` (counted over all trackers' sensors in order):
/// orientation `R_IT(t)` in the firmware's z-up inertial frame, and linear acceleration.
pub mod motion {
    /// Rotation rate about the sensor's own axis, rad/s.
    pub fn rate_radps(index: usize) -> f64 {
        0.4 + 0.15 * index as f64
    }

    /// The sensor's rotation axis (unit), different for every sensor and never vertical.
    pub fn axis(index: usize) -> [f64; 3] {
        let k = index as f64;
        let v = [k.cos(), k.sin(), 0.6];
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.map(|x| x / n)
    }

    /// The sensor's heading at t = 0 about the vertical (each tracker fuses its own), rad.
    pub fn heading_rad(index: usize) -> f64 {
        0.5 * index as f64
    }

    /// `R_IT(t) = R_z(heading) · R(axis, rate · t)` as a quaternion x, y, z, w.
    pub fn orientation_xyzw(index: usize, t: f64) -> [f64; 4] {
        let (hz, hw) = (0.5 * heading_rad(index)).sin_cos();
        let (s, c) = (0.5 * rate_radps(index) * t).sin_cos();
        let a = axis(index).map(|v| v * s);
        // (0, 0, hz, hw) ⊗ (a, c)
        [
            hw * a[0] - hz * a[1],
            hw * a[1] + hz * a[0],
            hw * a[2] + hz * c,
            hw * c - hz * a[2],
        ]
    }

    /// Linear acceleration in the inertial frame, m/s².
    pub fn acceleration_inertial(index: usize, t: f64) -> [f64; 3] {
        let p = 2.0 * std::f64::consts::PI * 0.7 * t + index as f64;
        [
            1.5 * p.sin(),
            p.cos(),
            0.5 * (2.0 * std::f64::consts::PI * 1.3 * t).sin(),
        ]
    }

    /// What the firmware sends: the linear acceleration in the tracker frame, `R_ITᵀ · a_I`.
    pub fn acceleration_tracker(index: usize, t: f64) -> [f64; 3] {
        let [x, y, z, w] = orientation_xyzw(index, t);
        let v = acceleration_inertial(index, t);
        // Rotation by the conjugate quaternion (u, w), u = −(x, y, z):
        // v' = v + 2w·(u × v) + 2·u × (u × v).
        let u = [-x, -y, -z];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let uv = cross(u, v);
        let uuv = cross(u, uv);
        std::array::from_fn(|i| v[i] + 2.0 * (w * uv[i] + uuv[i]))
    }

    /// The packets' values of sensor `index` at tick `tick` of a stream at `rate_hz`, as the
    /// firmware sends them (f32): rotation x, y, z, w and linear acceleration.
    pub fn sample(index: usize, tick: u64, rate_hz: f64) -> ([f32; 4], [f32; 3]) {
        let t = tick as f64 / rate_hz;
        (
            orientation_xyzw(index, t).map(|v| v as f32),
            acceleration_tracker(index, t).map(|v| v as f32),
        )
    }
}

/// One simulated tracker's connection state (the firmware's `WiFiCommunication`).
struct SimulatedTracker {
    tracker: SimTracker,
    first_sensor: usize,
    socket: UdpSocket,
    server: SocketAddr,
    rate_hz: f64,
    ticks: u64,
    bundle: bool,
    handshake_timeout: Duration,
    faults: SimFaults,
    packet_number: u64,
    server_bundles: bool,
    sensor_info_acked: Vec<bool>,
    last_sensor_info: Option<Instant>,
    feature_requests: u32,
    last_feature_request: Option<Instant>,
    last_heard: Instant,
    data_datagrams: u64,
    held: Option<Vec<u8>>,
    /// Data datagrams held back by a stall.
    backlog: Vec<Vec<u8>>,
    stalling: bool,
    report: SimReport,
}

impl SimulatedTracker {
    fn new(
        tracker: SimTracker,
        first_sensor: usize,
        server: SocketAddr,
        options: &SimOptions,
    ) -> anyhow::Result<Self> {
        let local = if server.ip().is_loopback() {
            "127.0.0.1:0"
        } else {
            "0.0.0.0:0"
        };
        let socket = UdpSocket::bind(local).context("cannot open a UDP socket")?;
        socket.set_read_timeout(Some(Duration::from_millis(1)))?;
        let sensors = usize::from(tracker.sensors);
        Ok(SimulatedTracker {
            report: SimReport {
                mac: Some(tracker.mac),
                ..SimReport::default()
            },
            tracker,
            first_sensor,
            socket,
            server,
            rate_hz: options.rate_hz,
            ticks: options.ticks,
            bundle: options.bundle,
            handshake_timeout: options.handshake_timeout,
            faults: options.faults.clone(),
            packet_number: 0,
            server_bundles: false,
            sensor_info_acked: vec![false; sensors],
            last_sensor_info: None,
            feature_requests: 0,
            last_feature_request: None,
            last_heard: Instant::now(),
            data_datagrams: 0,
            held: None,
            backlog: Vec::new(),
            stalling: false,
        })
    }

    fn run(mut self, start: Instant, stop: &AtomicBool) -> anyhow::Result<SimReport> {
        self.connect(stop)?;
        let period = Duration::from_secs_f64(1.0 / self.rate_hz);
        // Ticks from the connection on, on the common phase: a board does not send the ticks
        // it spent searching for a server (that would be a backlog at start).
        let behind = Instant::now().saturating_duration_since(start);
        let start = start + period.mul_f64((behind.as_secs_f64() * self.rate_hz).ceil());
        for tick in 0..self.ticks {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            imuflow_graph::wait::sleep_until(start + period.mul_f64(tick as f64));
            self.listen();
            if self.last_heard.elapsed() >= SERVER_TIMEOUT {
                // The firmware gives the server up and searches again; the ticks meanwhile are
                // not sent.
                self.connect(stop)?;
                continue;
            }
            self.upkeep();
            self.send_tick(tick);
        }
        for bytes in std::mem::take(&mut self.backlog) {
            self.transmit(&bytes);
        }
        if let Some(held) = self.held.take() {
            self.send_raw(&held);
        }
        Ok(self.report)
    }

    /// Broadcasts the handshake every second until the server answers.
    fn connect(&mut self, stop: &AtomicBool) -> anyhow::Result<()> {
        let since = Instant::now();
        let mut last_sent: Option<Instant> = None;
        self.server_bundles = false;
        self.feature_requests = 0;
        self.sensor_info_acked.iter_mut().for_each(|a| *a = false);
        loop {
            if stop.load(Ordering::Relaxed) {
                return Ok(());
            }
            if since.elapsed() >= self.handshake_timeout {
                bail!(
                    "tracker {}: no server answered at {} within {:?}",
                    self.tracker.mac,
                    self.server,
                    self.handshake_timeout
                );
            }
            if last_sent.is_none_or(|t| t.elapsed() >= HANDSHAKE_EVERY) {
                last_sent = Some(Instant::now());
                self.send_raw(&self.handshake().standalone(0));
            }
            if let Some((ServerPacket::Handshake, from)) = self.receive() {
                // The firmware takes whoever answered as its server (`acceptHandshake`).
                self.server = from;
                self.last_heard = Instant::now();
                self.report.connections += 1;
                return Ok(());
            }
        }
    }

    fn handshake(&self) -> Packet {
        Packet::Handshake(Handshake {
            board: BOARD,
            imu: 0,
            mcu: MCU,
            firmware_build: FIRMWARE_BUILD,
            firmware: FIRMWARE.to_owned(),
            mac: Some(self.tracker.mac),
            tail: Handshake::firmware_tail(0, ["imuflow", "", "simulated tracker", "", ""]),
        })
    }

    /// One datagram and its sender, if one is there within 1 ms (the firmware reads 128 bytes).
    fn receive(&mut self) -> Option<(ServerPacket, SocketAddr)> {
        let mut buf = [0u8; 128];
        let (len, from) = self.socket.recv_from(&mut buf).ok()?;
        let packet = packets::decode_server(&buf[..len.min(buf.len())])?;
        if packet == ServerPacket::PingPong {
            // The firmware echoes the ping as it came (`returnLastPacket`).
            self.send_raw(&buf[..len]);
        }
        Some((packet, from))
    }

    /// Everything the server sent since the last tick (the firmware's `tick`).
    fn listen(&mut self) {
        while let Some((p, _)) = self.receive() {
            if p == ServerPacket::Handshake {
                // "Handshake received again, ignoring": does not count as hearing the server.
                continue;
            }
            self.last_heard = Instant::now();
            match p {
                ServerPacket::Heartbeat => {
                    self.report.heartbeats += 1;
                    let number = self.next_number();
                    self.send_raw(&Packet::Heartbeat.standalone(number));
                }
                ServerPacket::SensorInfo { sensor_id, .. } => {
                    if let Some(a) = self.sensor_info_acked.get_mut(usize::from(sensor_id)) {
                        *a = true;
                    }
                }
                ServerPacket::FeatureFlags(flags) => {
                    self.server_bundles = flags
                        .first()
                        .is_some_and(|f| f & server_feature::BUNDLE != 0);
                    self.feature_requests = FEATURE_FLAGS_ATTEMPTS;
                }
                _ => {}
            }
        }
    }

    /// Sensor info until acknowledged, feature flags until answered.
    fn upkeep(&mut self) {
        if self
            .last_sensor_info
            .is_none_or(|t| t.elapsed() >= SENSOR_INFO_EVERY)
        {
            self.last_sensor_info = Some(Instant::now());
            for sensor_id in 0..self.tracker.sensors {
                if !self.sensor_info_acked[usize::from(sensor_id)] {
                    let info = Packet::SensorInfo(SensorInfo {
                        sensor_id,
                        status: 1,
                        imu_type: Some(0),
                    });
                    let number = self.next_number();
                    self.send_raw(&info.standalone(number));
                }
            }
        }
        if self.feature_requests < FEATURE_FLAGS_ATTEMPTS
            && self
                .last_feature_request
                .is_none_or(|t| t.elapsed() >= FEATURE_FLAGS_EVERY)
        {
            self.last_feature_request = Some(Instant::now());
            self.feature_requests += 1;
            let number = self.next_number();
            // The firmware announces no feature of its own (one zero byte).
            self.send_raw(&Packet::FeatureFlags(vec![0]).standalone(number));
        }
    }

    /// Every sensor's rotation, then its acceleration (`Sensor::sendData`), bundled when the
    /// server supports it.
    fn send_tick(&mut self, tick: u64) {
        self.stalling = self.faults.stall.is_some_and(|s| s.holds(tick));
        if self.stalling {
            self.report.stalled += 1;
        }
        let packets: Vec<Packet> = (0..self.tracker.sensors)
            .flat_map(|sensor_id| {
                let index = self.first_sensor + usize::from(sensor_id);
                let (xyzw, acc) = motion::sample(index, tick, self.rate_hz);
                [
                    Packet::Rotation(Rotation {
                        sensor_id,
                        data_type: DATA_TYPE_NORMAL,
                        xyzw,
                        accuracy: 0,
                    }),
                    Packet::Acceleration(Acceleration {
                        sensor_id,
                        xyz: acc,
                    }),
                ]
            })
            .collect();
        if self.bundle && self.server_bundles {
            let number = self.next_number();
            self.report.bundles += 1;
            self.send_data(packets::bundle(number, &packets));
        } else {
            for p in &packets {
                let number = self.next_number();
                self.send_data(p.standalone(number));
            }
        }
        self.report.ticks_sent += 1;
    }

    /// A data datagram through the fault injector.
    fn send_data(&mut self, bytes: Vec<u8>) {
        if self.stalling {
            self.backlog.push(bytes);
            return;
        }
        for held in std::mem::take(&mut self.backlog) {
            self.transmit(&held);
        }
        self.send_faulty(bytes);
    }

    fn send_faulty(&mut self, bytes: Vec<u8>) {
        self.data_datagrams += 1;
        let n = self.data_datagrams;
        let every = |k: u64| k > 0 && n.is_multiple_of(k);
        if every(self.faults.drop_every) {
            self.report.dropped += 1;
            return;
        }
        if every(self.faults.swap_every) && self.held.is_none() {
            self.report.swapped += 1;
            self.held = Some(bytes);
            return;
        }
        self.send_raw(&bytes);
        if every(self.faults.duplicate_every) {
            self.report.duplicated += 1;
            self.send_raw(&bytes);
        }
        if let Some(held) = self.held.take() {
            self.send_raw(&held);
        }
    }

    fn next_number(&mut self) -> u64 {
        let n = self.packet_number;
        self.packet_number += 1;
        n
    }

    /// Sends a datagram, or holds it back behind the others while a stall lasts (a stalled link
    /// holds every datagram, in order).
    fn send_raw(&mut self, bytes: &[u8]) {
        if self.stalling {
            self.backlog.push(bytes.to_vec());
            return;
        }
        self.transmit(bytes);
    }

    fn transmit(&mut self, bytes: &[u8]) {
        self.report.datagrams += 1;
        // A server that is not listening (yet) makes loopback sends fail; keep going, as the
        // firmware does.
        if let Err(e) = self.socket.send_to(bytes, self.server) {
            tracing::debug!("send to {}: {e}", self.server);
        }
    }
}
