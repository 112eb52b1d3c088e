//! The server side of the SlimeVR protocol: answers trackers the way SlimeVR-Server does, keeps
//! them streaming, pairs each sensor's rotation with its acceleration into one sample and counts
//! what the network did to the packets.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use imuflow_graph::transport::now_ns;

use super::clock::PacketClock;
use super::mapping::Mapping;
use super::packets::{
    self, Acceleration, DATA_TYPE_NORMAL, Datagram, Mac, Packet, RECEIVER_FEATURES, Rotation, reply,
};

/// How often the server sends each tracker a heartbeat (`TrackersUDPServer.kt`: every 500 ms); a
/// tracker that hears nothing for 3 s stops streaming and searches for a server again (firmware
/// `ServerResponseTimeoutMillis` in `src/network/wifi/WiFiCommunication.h`, `TIMEOUT` in
/// `src/network/connection.cpp`).
pub const KEEPALIVE: Duration = Duration::from_millis(500);

/// How long a rotation waits for the acceleration the firmware sends right after it
/// (`Sensor::sendData` in `src/sensors/sensor.cpp`: rotation, then acceleration of the same
/// fusion update) before it is published alone.
pub const PAIR_WAIT: Duration = Duration::from_millis(5);

/// Rotations in a row without an acceleration after which a sensor is taken to send none
/// (firmware built with `SEND_ACCELERATION false`): its rotations are then published at once.
const ROTATIONS_WITHOUT_ACCEL: u32 = 3;

/// Most datagrams handled in one poll: a flood cannot keep the stage from publishing.
pub const MAX_DRAIN: usize = 256;

/// Packet numbers remembered per tracker to tell duplicates from late packets.
const NUMBER_WINDOW: u64 = 4096;

/// Standard gravity the firmware removes from the acceleration (`CONST_EARTH_GRAVITY`,
/// src/consts.h), m/s².
pub const FIRMWARE_GRAVITY_MPS2: f64 = 9.80665;

/// One sample of one site: a rotation, an acceleration, or both from the same fusion update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub site: usize,
    /// When the sample's first packet arrived, ns since the Unix epoch.
    pub received_ns: u64,
    /// When the tracker sent it, from its packet number ([`PacketClock`]), on the same clock.
    pub sent_ns: u64,
    /// The rotation of this sample (x, y, z, w as received), when it brought one.
    pub rotation_xyzw: Option<[f32; 4]>,
    /// The linear acceleration as received (m/s², tracker frame, gravity removed) and the
    /// rotation (x, y, z, w) that gives its gravity direction: this sample's own, or the last one
    /// received when the tracker sent the acceleration alone.
    pub acceleration: Option<([f32; 3], [f32; 4])>,
}

/// What the network and the trackers did, per tracker (MAC).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TrackerStats {
    /// Datagrams received after the handshake.
    pub packets: u64,
    /// Samples published.
    pub samples: u64,
    /// Packet numbers never received.
    pub lost: u64,
    /// Datagrams whose packet number was already received (dropped).
    pub duplicated: u64,
    /// Datagrams older than one already received (dropped, as the server does).
    pub out_of_order: u64,
    /// Packets of a type this protocol version does not define.
    pub unknown_types: u64,
    /// Datagrams or bundle entries too short for their type.
    pub malformed: u64,
    /// Accelerations dropped because no rotation of their sensor had arrived yet.
    pub unpaired: u64,
    /// Handshakes received (the first, and one per reconnection).
    pub handshakes: u64,
}

/// Counts that belong to no known tracker.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct OtherStats {
    /// Datagrams from addresses that have not shaken hands (trackers still connected to a
    /// previous server, unmapped trackers) or too short to have a header.
    pub ignored: u64,
}

/// When a datagram arrived, and when its tracker sent it.
#[derive(Debug, Clone, Copy)]
struct Stamp {
    received_ns: u64,
    sent_ns: u64,
}

impl Stamp {
    /// The sample of `site` that the datagram stamped so brought.
    fn sample(
        self,
        site: usize,
        rotation_xyzw: Option<[f32; 4]>,
        acceleration: Option<([f32; 3], [f32; 4])>,
    ) -> Sample {
        Sample {
            site,
            received_ns: self.received_ns,
            sent_ns: self.sent_ns,
            rotation_xyzw,
            acceleration,
        }
    }
}

/// A rotation waiting for its acceleration.
#[derive(Debug, Clone, Copy)]
struct Pending {
    rotation: [f32; 4],
    at: Stamp,
    deadline: Instant,
}

/// What the receiver knows of one sensor of a tracker.
#[derive(Debug, Default)]
struct SensorState {
    pending: Option<Pending>,
    last_rotation: Option<[f32; 4]>,
    rotations_without_accel: u32,
    logged_status: Option<u8>,
}

/// A tracker that shook hands, by MAC.
#[derive(Debug)]
struct Tracker {
    addr: SocketAddr,
    numbers: Numbering,
    clock: PacketClock,
    /// Datagrams without sample data received since the handshake (their numbers are not on
    /// the clock).
    other_numbers: u64,
    stats: TrackerStats,
    sensors: BTreeMap<u8, SensorState>,
    /// Sensor ids not in the mapping, logged once.
    unmapped: BTreeSet<u8>,
    /// Unknown packet types, logged once.
    unknown_logged: BTreeSet<u32>,
}

/// Receives from the trackers on one UDP socket.
pub struct Receiver {
    socket: UdpSocket,
    mapping: Mapping,
    trackers: BTreeMap<Mac, Tracker>,
    by_addr: HashMap<SocketAddr, Mac>,
    other: OtherStats,
    /// Addresses and MACs already logged as not mapped or not connected.
    logged_addrs: BTreeSet<SocketAddr>,
    logged_macs: BTreeSet<Mac>,
    last_keepalive: Instant,
    buf: Vec<u8>,
}

impl Receiver {
    /// Binds the socket trackers send to.
    pub fn bind(bind: &str, mapping: Mapping) -> std::io::Result<Receiver> {
        let socket = UdpSocket::bind(bind)?;
        Ok(Receiver {
            socket,
            mapping,
            trackers: BTreeMap::new(),
            by_addr: HashMap::new(),
            other: OtherStats::default(),
            logged_addrs: BTreeSet::new(),
            logged_macs: BTreeSet::new(),
            last_keepalive: Instant::now(),
            // The server's buffer (TrackersUDPServer.kt): the largest datagram without IP fragments.
            buf: vec![0; 1472],
        })
    }

    /// The address the socket is bound to.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Waits up to `wait` for a datagram, then handles it and every other datagram the socket
    /// already holds (at most [`MAX_DRAIN`]); appends finished samples to `out`. Returns whether
    /// a mapped tracker was heard (the stream's silence timeout counts from it).
    pub fn poll(&mut self, wait: Duration, out: &mut Vec<Sample>) -> std::io::Result<bool> {
        self.keep_alive();
        let wait = self.until_next_deadline().map_or(wait, |d| d.min(wait));
        // A zero read timeout is an error on some platforms: wait at least 1 ms.
        self.socket
            .set_read_timeout(Some(wait.max(Duration::from_millis(1))))?;
        let heard = match self.receive_one(out)? {
            Some(first) => self.drain_queued(out)? | first,
            None => false,
        };
        self.flush_expired(Instant::now(), out);
        Ok(heard)
    }

    /// Handles the datagrams the socket already holds, without waiting (at most
    /// [`MAX_DRAIN`] − 1); whether one came from a mapped tracker.
    fn drain_queued(&mut self, out: &mut Vec<Sample>) -> std::io::Result<bool> {
        self.socket.set_nonblocking(true)?;
        let mut heard = Ok(false);
        for _ in 1..MAX_DRAIN {
            match self.receive_one(out) {
                Ok(Some(h)) => heard = heard.map(|a| a | h),
                Ok(None) => break,
                Err(e) => {
                    heard = Err(e);
                    break;
                }
            }
        }
        self.socket.set_nonblocking(false)?;
        heard
    }

    /// Receives and handles one datagram: `None` when none came (timeout, or none queued);
    /// otherwise whether it came from a mapped tracker.
    fn receive_one(&mut self, out: &mut Vec<Sample>) -> std::io::Result<Option<bool>> {
        match self.socket.recv_from(&mut self.buf) {
            Ok((len, from)) => {
                let buf = std::mem::take(&mut self.buf);
                let heard = self.handle(&buf[..len], from, out);
                self.buf = buf;
                Ok(Some(heard))
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(None),
            // A previous send to a tracker that is gone can surface here (ICMP unreachable).
            Err(e) if e.kind() == ErrorKind::ConnectionRefused => Ok(Some(false)),
            Err(e) => Err(e),
        }
    }

    /// Publishes every rotation still waiting for its acceleration (at the end of the stream).
    pub fn flush_all(&mut self, out: &mut Vec<Sample>) {
        self.flush_where(out, |_| true);
    }

    /// Per tracker: its MAC and counts.
    pub fn tracker_stats(&self) -> impl Iterator<Item = (Mac, TrackerStats)> + '_ {
        self.trackers.iter().map(|(mac, t)| {
            let mut stats = t.stats.clone();
            stats.lost += t.numbers.lost();
            (*mac, stats)
        })
    }

    /// Counts that belong to no tracker.
    pub fn other_stats(&self) -> &OtherStats {
        &self.other
    }

    /// Handles one datagram; whether it came from a mapped tracker.
    fn handle(&mut self, bytes: &[u8], from: SocketAddr, out: &mut Vec<Sample>) -> bool {
        let received_ns = now_ns();
        let datagram = match packets::decode(bytes) {
            Ok(d) => d,
            Err(e) => {
                match self
                    .by_addr
                    .get(&from)
                    .and_then(|m| self.trackers.get_mut(m))
                {
                    Some(t) => {
                        t.stats.packets += 1;
                        t.stats.malformed += 1;
                    }
                    None => self.other.ignored += 1,
                }
                tracing::debug!("malformed datagram from {from}: {e}");
                return self.by_addr.contains_key(&from);
            }
        };
        if datagram.kind == packets::kind::HANDSHAKE {
            return self.handshake(&datagram, from);
        }
        let Some(&mac) = self.by_addr.get(&from) else {
            self.other.ignored += 1;
            if self.logged_addrs.insert(from) {
                tracing::info!(
                    "ignoring packets from {from}: no handshake from it yet (a tracker still \
                     connected to an earlier server searches again after 3 s)"
                );
            }
            return false;
        };
        self.tracker_datagram(mac, &datagram, received_ns, out);
        true
    }

    /// A handshake: answered when its MAC is mapped (the tracker then streams to this socket),
    /// ignored otherwise, as the server ignores devices it does not know.
    fn handshake(&mut self, datagram: &Datagram, from: SocketAddr) -> bool {
        let Some(Ok(Packet::Handshake(h))) = datagram.packets.first() else {
            self.other.ignored += 1;
            return false;
        };
        let Some(mac) = h.mac.filter(|m| self.mapping.knows(*m)) else {
            self.other.ignored += 1;
            let first = match h.mac {
                Some(m) => self.logged_macs.insert(m),
                None => self.logged_addrs.insert(from),
            };
            if first {
                let who = h.mac.map_or("no MAC".to_owned(), |m| format!("MAC {m}"));
                tracing::warn!(
                    "ignoring tracker at {from} ({who}, firmware '{}'): not in the trackers file",
                    h.firmware
                );
            }
            return false;
        };
        let tracker = self.trackers.entry(mac).or_insert_with(|| Tracker {
            addr: from,
            numbers: Numbering::default(),
            clock: PacketClock::default(),
            other_numbers: 0,
            stats: TrackerStats::default(),
            sensors: BTreeMap::new(),
            unmapped: BTreeSet::new(),
            unknown_logged: BTreeSet::new(),
        });
        if tracker.stats.handshakes == 0 || tracker.addr != from {
            tracing::info!(
                "tracker {mac} at {from}: board {}, MCU {}, firmware '{}' (build {})",
                h.board,
                h.mcu,
                h.firmware,
                h.firmware_build
            );
        }
        self.by_addr.remove(&tracker.addr);
        self.by_addr.insert(from, mac);
        tracker.addr = from;
        tracker.stats.handshakes += 1;
        // The tracker's packet numbers go on across reconnections; the server starts anew too.
        tracker.numbers.restart();
        tracker.clock = PacketClock::default();
        tracker.other_numbers = 0;
        self.send(from, &reply::handshake());
        true
    }

    /// A datagram of a connected tracker: numbering, then each packet it carries.
    fn tracker_datagram(
        &mut self,
        mac: Mac,
        datagram: &Datagram,
        received_ns: u64,
        out: &mut Vec<Sample>,
    ) {
        let Some(tracker) = self.trackers.get_mut(&mac) else {
            return;
        };
        tracker.stats.packets += 1;
        match tracker.numbers.accept(datagram.number) {
            Verdict::New => {}
            Verdict::Duplicate => {
                tracker.stats.duplicated += 1;
                return;
            }
            Verdict::Late => {
                tracker.stats.out_of_order += 1;
                return;
            }
        }
        // The clock runs on the data datagrams' numbers: the others (heartbeat answers, battery,
        // sensor info) are sent between the samples, whenever the firmware has them, so they are
        // taken out of the count. Number 0 (a ping echo, a handshake) is not on the count.
        let carries_data = datagram.packets.iter().any(|p| {
            matches!(
                p,
                Ok(Packet::Rotation(_)
                    | Packet::Acceleration(_)
                    | Packet::RotationAndAcceleration(..))
            )
        });
        let sent_ns = match datagram.number {
            0 => received_ns,
            _ if !carries_data => {
                tracker.other_numbers += 1;
                received_ns
            }
            n => tracker
                .clock
                .date(n.saturating_sub(tracker.other_numbers), received_ns),
        };
        let at = Stamp {
            received_ns,
            sent_ns,
        };
        let mut replies = Vec::new();
        for packet in &datagram.packets {
            match packet {
                Ok(p) => {
                    if let Some(r) = self.packet(mac, p, at, out) {
                        replies.push(r);
                    }
                }
                Err(e) => {
                    if let Some(t) = self.trackers.get_mut(&mac) {
                        t.stats.malformed += 1;
                    }
                    tracing::debug!("malformed packet from tracker {mac}: {e}");
                }
            }
        }
        let addr = self.trackers[&mac].addr;
        for r in replies {
            self.send(addr, &r);
        }
    }

    /// One packet of a tracker; the reply it needs, if any.
    fn packet(
        &mut self,
        mac: Mac,
        packet: &Packet,
        at: Stamp,
        out: &mut Vec<Sample>,
    ) -> Option<Vec<u8>> {
        match packet {
            Packet::Rotation(r) if r.data_type == DATA_TYPE_NORMAL => {
                self.rotation(mac, r, at, out);
            }
            Packet::Acceleration(a) => self.acceleration(mac, a, at, out),
            Packet::RotationAndAcceleration(r, a) => {
                if let Some(site) = self.site(mac, r.sensor_id) {
                    let state = self.sensor(mac, r.sensor_id);
                    state.last_rotation = Some(r.xyzw);
                    self.emit(
                        mac,
                        out,
                        at.sample(site, Some(r.xyzw), Some((a.xyz, r.xyzw))),
                    );
                }
            }
            Packet::SensorInfo(s) => {
                let state = self.sensor(mac, s.sensor_id);
                if state.logged_status != Some(s.status) {
                    state.logged_status = Some(s.status);
                    tracing::info!(
                        "tracker {mac} sensor {}: status {} ({}), IMU type {}",
                        s.sensor_id,
                        s.status,
                        match s.status {
                            0 => "offline",
                            1 => "ok",
                            2 => "error",
                            _ => "unknown",
                        },
                        s.imu_type.map_or("?".to_owned(), |t| t.to_string())
                    );
                }
                return Some(reply::sensor_info(s.sensor_id, s.status).to_vec());
            }
            Packet::FeatureFlags(_) => return Some(reply::feature_flags(&RECEIVER_FEATURES)),
            Packet::Unknown(kind) => {
                let tracker = self.trackers.get_mut(&mac)?;
                tracker.stats.unknown_types += 1;
                if tracker.unknown_logged.insert(*kind) {
                    tracing::warn!("tracker {mac} sent packets of unknown type {kind}; ignored");
                }
            }
            // Heartbeats, ping echoes, magnetometer corrections, battery, signal strength, ...
            _ => {}
        }
        None
    }

    /// A rotation: published once its acceleration arrives (or at once when the sensor sends
    /// none); a rotation still waiting is published alone.
    fn rotation(&mut self, mac: Mac, r: &Rotation, at: Stamp, out: &mut Vec<Sample>) {
        let Some(site) = self.site(mac, r.sensor_id) else {
            return;
        };
        let state = self.sensor(mac, r.sensor_id);
        let previous = state.pending.take();
        state.last_rotation = Some(r.xyzw);
        let waits = state.rotations_without_accel < ROTATIONS_WITHOUT_ACCEL;
        if previous.is_some() {
            state.rotations_without_accel = state.rotations_without_accel.saturating_add(1);
        }
        if waits {
            state.pending = Some(Pending {
                rotation: r.xyzw,
                at,
                deadline: Instant::now() + PAIR_WAIT,
            });
        }
        if let Some(p) = previous {
            self.emit(mac, out, alone(site, p));
        }
        if !waits {
            self.emit(mac, out, at.sample(site, Some(r.xyzw), None));
        }
    }

    /// An acceleration: completes its sensor's waiting rotation, or stands alone with the last
    /// rotation's gravity direction (firmware that sends accelerations on their own, e.g. while
    /// the rotation did not change).
    fn acceleration(&mut self, mac: Mac, a: &Acceleration, at: Stamp, out: &mut Vec<Sample>) {
        let Some(site) = self.site(mac, a.sensor_id) else {
            return;
        };
        let state = self.sensor(mac, a.sensor_id);
        state.rotations_without_accel = 0;
        let sample = match (state.pending.take(), state.last_rotation) {
            (Some(p), _) => {
                p.at.sample(site, Some(p.rotation), Some((a.xyz, p.rotation)))
            }
            (None, Some(last)) => at.sample(site, None, Some((a.xyz, last))),
            (None, None) => {
                if let Some(t) = self.trackers.get_mut(&mac) {
                    t.stats.unpaired += 1;
                }
                return;
            }
        };
        self.emit(mac, out, sample);
    }

    fn emit(&mut self, mac: Mac, out: &mut Vec<Sample>, sample: Sample) {
        if let Some(t) = self.trackers.get_mut(&mac) {
            t.stats.samples += 1;
        }
        out.push(sample);
    }

    /// The site of a tracker's sensor; an unmapped sensor is logged once.
    fn site(&mut self, mac: Mac, sensor_id: u8) -> Option<usize> {
        let site = self.mapping.site(mac, sensor_id);
        if site.is_none()
            && let Some(t) = self.trackers.get_mut(&mac)
            && t.unmapped.insert(sensor_id)
        {
            tracing::warn!(
                "tracker {mac} sends sensor {sensor_id}, which the trackers file does not map; \
                 ignored"
            );
        }
        site
    }

    fn sensor(&mut self, mac: Mac, sensor_id: u8) -> &mut SensorState {
        self.trackers
            .get_mut(&mac)
            .expect("a sensor of a connected tracker")
            .sensors
            .entry(sensor_id)
            .or_default()
    }

    /// Heartbeats to every tracker that shook hands, every [`KEEPALIVE`].
    fn keep_alive(&mut self) {
        if self.last_keepalive.elapsed() < KEEPALIVE {
            return;
        }
        self.last_keepalive = Instant::now();
        let addrs: Vec<SocketAddr> = self.trackers.values().map(|t| t.addr).collect();
        for addr in addrs {
            self.send(addr, &reply::heartbeat());
        }
    }

    /// Time until the next keep-alive or the earliest waiting rotation's deadline.
    fn until_next_deadline(&self) -> Option<Duration> {
        let now = Instant::now();
        let pending = self
            .trackers
            .values()
            .flat_map(|t| t.sensors.values())
            .filter_map(|s| s.pending.map(|p| p.deadline));
        let keepalive = std::iter::once(self.last_keepalive + KEEPALIVE);
        pending
            .chain(keepalive)
            .min()
            .map(|d| d.saturating_duration_since(now))
    }

    fn flush_expired(&mut self, now: Instant, out: &mut Vec<Sample>) {
        self.flush_where(out, |p| p.deadline <= now);
    }

    fn flush_where(&mut self, out: &mut Vec<Sample>, due: impl Fn(&Pending) -> bool) {
        let mut flushed = Vec::new();
        for (mac, tracker) in &mut self.trackers {
            for (&sensor_id, state) in &mut tracker.sensors {
                if let Some(p) = state.pending.filter(|p| due(p)) {
                    state.pending = None;
                    state.rotations_without_accel = state.rotations_without_accel.saturating_add(1);
                    flushed.push((*mac, sensor_id, p));
                }
            }
        }
        for (mac, sensor_id, p) in flushed {
            if let Some(site) = self.mapping.site(mac, sensor_id) {
                self.emit(mac, out, alone(site, p));
            }
        }
    }

    fn send(&self, to: SocketAddr, bytes: &[u8]) {
        // A tracker that went away makes sends fail; it shakes hands again when it comes back.
        if let Err(e) = self.socket.send_to(bytes, to) {
            tracing::debug!("send to {to}: {e}");
        }
    }
}

/// A rotation published without an acceleration.
fn alone(site: usize, p: Pending) -> Sample {
    p.at.sample(site, Some(p.rotation), None)
}

/// Specific force in the tracker frame from the firmware's linear acceleration:
/// `f_T = a_T + g·R_ITᵀ·e_z`, with I the tracker's z-up inertial frame, `R_IT` the rotation
/// `xyzw` and g the firmware's standard gravity. `R_ITᵀ·e_z` is the third row of `R_IT`, the
/// "gravity vector" the firmware subtracts (`SensorFusion::calcGravityVec`). None when the
/// rotation is not finite or zero.
pub fn specific_force(linear_mps2: [f32; 3], xyzw: [f32; 4]) -> Option<[f32; 3]> {
    let [x, y, z, w] = xyzw.map(f64::from);
    let n2 = x * x + y * y + z * z + w * w;
    if !n2.is_finite() || n2 < 1e-12 {
        return None;
    }
    // For a unit quaternion; dividing by the squared norm keeps the result a unit vector.
    let up = [
        2.0 * (x * z - w * y) / n2,
        2.0 * (y * z + w * x) / n2,
        (w * w - x * x - y * y + z * z) / n2,
    ];
    let f: [f32; 3] =
        std::array::from_fn(|i| (f64::from(linear_mps2[i]) + FIRMWARE_GRAVITY_MPS2 * up[i]) as f32);
    f.iter().all(|v| v.is_finite()).then_some(f)
}

/// Whether a datagram's packet number is new, a duplicate or late.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    New,
    Duplicate,
    Late,
}

/// One tracker's packet numbers since its last handshake: the highest, the ones seen recently,
/// how many distinct ones arrived. Number 0 is not counted: the firmware numbers from 0, the
/// handshake always carries 0 and a ping echo carries the server's 0 (`UDPDevice.isNextPacket`
/// lets 0 through for the same reason).
#[derive(Debug, Default)]
struct Numbering {
    first: Option<u64>,
    highest: u64,
    distinct: u64,
    recent: BTreeSet<u64>,
    /// Lost in earlier connections of the same tracker.
    lost_before: u64,
}

impl Numbering {
    fn accept(&mut self, n: u64) -> Verdict {
        if n == 0 {
            return Verdict::New;
        }
        let Some(first) = self.first else {
            self.first = Some(n);
            self.highest = n;
            self.distinct = 1;
            self.recent.insert(n);
            return Verdict::New;
        };
        if self.recent.contains(&n) {
            return Verdict::Duplicate;
        }
        if n < self.highest {
            // Older than the window (or than the connection): late or a duplicate, cannot tell;
            // dropped either way and not counted as arrived.
            if n > first && self.highest - n < NUMBER_WINDOW {
                self.recent.insert(n);
                self.distinct += 1;
            }
            return Verdict::Late;
        }
        self.highest = n;
        self.distinct += 1;
        self.recent.insert(n);
        let floor = n.saturating_sub(NUMBER_WINDOW);
        while self.recent.first().is_some_and(|&o| o < floor) {
            self.recent.pop_first();
        }
        Verdict::New
    }

    /// Numbers between the first and the highest that never arrived (over all connections).
    fn lost(&self) -> u64 {
        let span = self.first.map_or(0, |f| self.highest - f + 1);
        self.lost_before + span.saturating_sub(self.distinct)
    }

    /// A new connection: keep what was lost, count anew.
    fn restart(&mut self) {
        *self = Numbering {
            lost_before: self.lost(),
            ..Numbering::default()
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbering_counts_lost_duplicated_and_late_packets() {
        let mut n = Numbering::default();
        let verdicts: Vec<Verdict> = [0, 5, 6, 8, 8, 7, 11, 6, 12, 0]
            .iter()
            .map(|&k| n.accept(k))
            .collect();
        use Verdict::*;
        assert_eq!(
            verdicts,
            [
                New, New, New, New, Duplicate, Late, New, Duplicate, New, New
            ]
        );
        // 5..=12 is 8 numbers; 5, 6, 7, 8, 11, 12 arrived (7 late): 9 and 10 lost.
        assert_eq!(n.lost(), 2);
        n.restart();
        assert_eq!(n.accept(100), New);
        assert_eq!(n.accept(102), New);
        assert_eq!(n.lost(), 3);
    }

    #[test]
    fn specific_force_adds_gravity_along_the_trackers_up_axis() {
        // Identity: the tracker's z is up, at rest it feels +g along z.
        let f = specific_force([0.0; 3], [0.0, 0.0, 0.0, 1.0]).unwrap();
        assert_eq!(f, [0.0, 0.0, FIRMWARE_GRAVITY_MPS2 as f32]);
        // Turned 90° about x: the tracker's y axis points up (Rᵀ·e_z is the third row of
        // Rx(90°) = [[1, 0, 0], [0, 0, -1], [0, 1, 0]], i.e. (0, 1, 0)).
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let f = specific_force([1.0, 2.0, 3.0], [h, 0.0, 0.0, h]).unwrap();
        let g = FIRMWARE_GRAVITY_MPS2 as f32;
        assert!((f[0] - 1.0).abs() < 1e-5 && (f[1] - (2.0 + g)).abs() < 1e-5);
        assert!((f[2] - 3.0).abs() < 1e-5, "{f:?}");
        assert_eq!(specific_force([0.0; 3], [0.0; 4]), None);
        assert_eq!(specific_force([0.0; 3], [f32::NAN, 0.0, 0.0, 1.0]), None);
    }
}
