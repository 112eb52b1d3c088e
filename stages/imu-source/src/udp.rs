//! Mode `udp`: live sensors sending one datagram per sample of all the sensor set's IMUs.
//!
//! # Packet format (version 1), little-endian, 24 + N × 44 bytes
//!
//! N is the number of sensors of the stage's sensor set (the six-site set: 6, 288 bytes; the
//! lower body: 5, 244 bytes; the full suit: 17, 772 bytes).
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `b"IMUF"` |
//! | 4 | 2 | version, u16 = 1 |
//! | 6 | 2 | number of sensors, u16 = N |
//! | 8 | 8 | seq, u64: the sender's sample counter (increasing by 1 per sample) |
//! | 16 | 8 | timestamp_ns, u64: capture time, ns since the Unix epoch (0: use the arrival time) |
//! | 24 | N × 44 | per sensor, in the set's wire slot order (the six: left forearm, right forearm, left lower leg, right lower leg, head, pelvis; docs/sensor-sets.md lists every site's slot): |
//! | +0 | 16 | orientation R_IS as quaternion [w, x, y, z], 4 × f32 |
//! | +16 | 12 | specific force in the sensor frame, m/s², 3 × f32 |
//! | +28 | 12 | angular rate in the sensor frame, rad/s, 3 × f32 |
//! | +40 | 4 | valid, u32: 1 when the sensor delivered this sample, 0 when it did not |
//!
//! A sensor whose valid word is 0 or whose values are not all finite gets its `valid_mask` bit
//! cleared and the frame is flagged INVALID. Frames are numbered from the first packet received:
//! `seq` = packet seq − first packet seq, so lost packets show as gaps (counted as drops
//! downstream); packets older than the last one are discarded. Malformed packets (wrong size,
//! magic, version, or a sensor count other than the set's, which the warning names) are counted
//! and skipped. The stream ends after `timeout_ms`
//! without a packet, after `frames` packets (when > 0), or on stop.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_body::{NUM_IMUS, SiteMask};
use imuflow_graph::StageContext;
use imuflow_graph::frames::{FrameHeader, ImuFrame};
use imuflow_graph::transport::now_ns;

use crate::publisher::Publisher;
use imuflow_synth::mark_invalid_sites;

/// First four bytes of every packet.
pub const MAGIC: [u8; 4] = *b"IMUF";
/// Packet format version.
pub const VERSION: u16 = 1;
/// Bytes before the sensors.
pub const HEADER_SIZE: usize = 24;
/// Bytes per sensor.
pub const SENSOR_SIZE: usize = 44;
/// Bytes per packet of `sensors` sensors.
pub const fn packet_size(sensors: usize) -> usize {
    HEADER_SIZE + sensors * SENSOR_SIZE
}
/// Bytes per packet of the six-site set.
pub const PACKET_SIZE: usize = packet_size(NUM_IMUS);

/// One sensor's sample in a packet.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorSample {
    pub orientation_wxyz: [f32; 4],
    pub specific_force_mps2: [f32; 3],
    pub angular_rate_radps: [f32; 3],
    pub valid: bool,
}

/// One decoded packet: its sensors in the set's slot order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Packet {
    pub seq: u64,
    pub timestamp_ns: u64,
    pub sensors: Vec<SensorSample>,
}

/// Why a datagram is not a packet.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    #[error("{found} bytes, expected {expected}")]
    Size { found: usize, expected: usize },
    #[error("bad magic (expected \"IMUF\")")]
    Magic,
    #[error("version {0}, expected {VERSION}")]
    Version(u16),
    #[error("{found} sensors, expected {expected} (the stage's sensor set's)")]
    Sensors { found: u16, expected: usize },
}

impl Packet {
    /// The packet's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut b = vec![0u8; packet_size(self.sensors.len())];
        b[0..4].copy_from_slice(&MAGIC);
        b[4..6].copy_from_slice(&VERSION.to_le_bytes());
        b[6..8].copy_from_slice(&(self.sensors.len() as u16).to_le_bytes());
        b[8..16].copy_from_slice(&self.seq.to_le_bytes());
        b[16..24].copy_from_slice(&self.timestamp_ns.to_le_bytes());
        for (i, s) in self.sensors.iter().enumerate() {
            let at = HEADER_SIZE + i * SENSOR_SIZE;
            let values = s
                .orientation_wxyz
                .iter()
                .chain(&s.specific_force_mps2)
                .chain(&s.angular_rate_radps);
            for (k, v) in values.enumerate() {
                b[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
            }
            b[at + 40..at + 44].copy_from_slice(&u32::from(s.valid).to_le_bytes());
        }
        b
    }

    /// Decodes a datagram of a sender of `sensors` sensors.
    pub fn decode(b: &[u8], sensors: usize) -> Result<Packet, PacketError> {
        if b.len() < HEADER_SIZE {
            return Err(PacketError::Size {
                found: b.len(),
                expected: packet_size(sensors),
            });
        }
        let u16_at = |at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
        let u32_at = |at: usize| u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
        let u64_at = |at: usize| u64::from(u32_at(at)) | (u64::from(u32_at(at + 4)) << 32);
        let f32_at = |at: usize| f32::from_bits(u32_at(at));
        if b[0..4] != MAGIC {
            return Err(PacketError::Magic);
        }
        if u16_at(4) != VERSION {
            return Err(PacketError::Version(u16_at(4)));
        }
        if usize::from(u16_at(6)) != sensors {
            return Err(PacketError::Sensors {
                found: u16_at(6),
                expected: sensors,
            });
        }
        if b.len() != packet_size(sensors) {
            return Err(PacketError::Size {
                found: b.len(),
                expected: packet_size(sensors),
            });
        }
        let mut p = Packet {
            seq: u64_at(8),
            timestamp_ns: u64_at(16),
            sensors: vec![SensorSample::default(); sensors],
        };
        for (i, s) in p.sensors.iter_mut().enumerate() {
            let at = HEADER_SIZE + i * SENSOR_SIZE;
            s.orientation_wxyz = std::array::from_fn(|k| f32_at(at + 4 * k));
            s.specific_force_mps2 = std::array::from_fn(|k| f32_at(at + 16 + 4 * k));
            s.angular_rate_radps = std::array::from_fn(|k| f32_at(at + 28 + 4 * k));
            s.valid = u32_at(at + 40) != 0;
        }
        Ok(p)
    }

    /// The frame's payload and valid mask, the packet's sensors in the slots of `sites` (in
    /// order; as many as the packet has), INVALID flagged in its header when one is not valid;
    /// the header's seq and capture time are left to the caller.
    pub fn to_frame(&self, sites: SiteMask) -> ImuFrame {
        let mut f = ImuFrame::default();
        for (s, site) in self.sensors.iter().zip(sites.sites()) {
            let i = site.index();
            f.orientation_wxyz[i] = s.orientation_wxyz;
            f.specific_force_mps2[i] = s.specific_force_mps2;
            f.angular_rate_radps[i] = s.angular_rate_radps;
            if s.valid {
                f.valid_mask |= 1 << i;
            }
        }
        mark_invalid_sites(&mut f, sites);
        f
    }
}

/// Settings of the udp mode.
#[derive(Debug, Clone)]
pub struct Options {
    pub bind: String,
    /// The sensor set's sites: what each packet carries, in slot order.
    pub sites: SiteMask,
    pub timeout: Duration,
    /// End after this many packets (0: no limit).
    pub frames: u64,
}

/// How often a blocked receive re-checks the stop flag.
const POLL: Duration = Duration::from_millis(20);

/// Receives packets and publishes them until timeout, `frames` packets or stop.
pub fn run(ctx: StageContext, options: &Options) -> anyhow::Result<()> {
    let socket = UdpSocket::bind(&options.bind)
        .with_context(|| format!("cannot bind UDP socket to '{}'", options.bind))?;
    socket.set_read_timeout(Some(POLL))?;
    let total = options.frames;
    let Some(mut out) = Publisher::start(ctx, total)? else {
        return Ok(());
    };
    let mut buf = [0u8; 2048];
    let mut last_packet = Instant::now();
    let mut first_seq: Option<u64> = None;
    let mut last_seq: Option<u64> = None;
    let (mut received, mut malformed, mut stale) = (0u64, 0u64, 0u64);
    while !out.ctx.should_stop() && (total == 0 || received < total) {
        let len = match socket.recv(&mut buf) {
            Ok(len) => len,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                if last_packet.elapsed() >= options.timeout {
                    tracing::info!("no packet for {:?}: end of stream", options.timeout);
                    break;
                }
                continue;
            }
            Err(e) => return Err(e).context("receiving a UDP packet"),
        };
        let t0 = Instant::now();
        last_packet = t0;
        let packet = match Packet::decode(buf.get(..len).unwrap_or(&[]), options.sites.len()) {
            Ok(p) => p,
            Err(e) => {
                malformed += 1;
                if malformed.is_power_of_two() {
                    tracing::warn!("skipping malformed packet ({e}); {malformed} so far");
                }
                continue;
            }
        };
        if last_seq.is_some_and(|l| packet.seq <= l) {
            stale += 1;
            if stale.is_power_of_two() {
                tracing::warn!(
                    "skipping packet {} (not newer than the last); {stale} so far",
                    packet.seq
                );
            }
            continue;
        }
        let first = *first_seq.get_or_insert(packet.seq);
        last_seq = Some(packet.seq);
        received += 1;
        let mut frame = packet.to_frame(options.sites);
        frame.header = FrameHeader {
            seq: packet.seq - first,
            capture_ns: if packet.timestamp_ns == 0 {
                now_ns()
            } else {
                packet.timestamp_ns
            },
            flags: frame.header.flags,
            ..Default::default()
        };
        out.publish_imu(&frame, t0)?;
    }
    if malformed + stale > 0 {
        tracing::warn!("skipped {malformed} malformed and {stale} out-of-order packet(s)");
    }
    out.finish()
}

/// The faults a sender injects (each `*_every` = 0: never), the way wireless sensor networks fail:
/// for `tools/udp-send` and the live-degradation test.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Faults {
    /// Put a NaN into sensor 0 of every N-th packet.
    pub nan_every: u64,
    /// Mark sensor 1 not valid in every N-th packet.
    pub missing_every: u64,
    /// Drop every N-th packet (step `seq % N == N / 2`).
    pub loss_every: u64,
    /// Every N steps, send a pair swapped: `seq + 1` first, then `seq` (stale by then).
    pub reorder_every: u64,
    /// Send every N-th packet twice.
    pub duplicate_every: u64,
    /// Every N-th step, also send the packet of half a second before (late).
    pub late_every: u64,
    /// `(sensor, packets)`: that sensor is marked not valid for those packets.
    pub dead: Option<(usize, std::ops::Range<u64>)>,
    /// `(sensor, packets)`: that sensor reports a NaN angular rate for those packets.
    pub nan_burst: Option<(usize, std::ops::Range<u64>)>,
    /// Packets during which the body holds still (no rotation), e.g. for a T-pose calibration.
    pub still: std::ops::Range<u64>,
}

impl Faults {
    /// The packets (their seqs) to send at step `seq` of a stream at `rate_hz`, in order.
    pub fn plan(&self, seq: u64, rate_hz: f64) -> Vec<u64> {
        let every = |n: u64, at: u64| n > 0 && seq % n == at % n;
        if every(self.loss_every, self.loss_every / 2) {
            return Vec::new();
        }
        if every(self.reorder_every, 8) {
            return vec![seq + 1, seq];
        }
        if every(self.reorder_every, 9) {
            return Vec::new();
        }
        let mut out = vec![seq];
        if every(self.duplicate_every, 0) {
            out.push(seq);
        }
        let half_second = (0.5 * rate_hz).round() as u64;
        if every(self.late_every, 0) && seq >= half_second {
            out.push(seq - half_second);
        }
        out
    }

    /// Packet `seq` of the synthetic body ([`synthetic_packet`]) of `sensors` sensors with these
    /// faults.
    pub fn packet(&self, seq: u64, rate_hz: f64, sensors: usize) -> Packet {
        let mut p = synthetic_packet(seq, rate_hz, self.nan_every, self.missing_every, sensors);
        if self.still.contains(&seq) {
            // Held in the first still packet's orientations; the faults stay this packet's.
            let held = synthetic_packet(self.still.start, rate_hz, 0, 0, sensors);
            for (s, h) in p.sensors.iter_mut().zip(&held.sensors) {
                s.orientation_wxyz = h.orientation_wxyz;
                s.angular_rate_radps = [0.0; 3];
            }
        }
        if let Some((sensor, packets)) = &self.dead
            && packets.contains(&seq)
            && let Some(s) = p.sensors.get_mut(*sensor)
        {
            s.valid = false;
        }
        if let Some((sensor, packets)) = &self.nan_burst
            && packets.contains(&seq)
            && let Some(s) = p.sensors.get_mut(*sensor)
        {
            s.angular_rate_radps[1] = f32::NAN;
        }
        p
    }
}

/// Sends `frames` steps of a slowly turning body of `sensors` sensors ([`synthetic_packet`]) to
/// `to` at `rate_hz` (the sender of `tools/udp-send`), with `faults`. Returns the packets sent.
pub fn send_synthetic(
    to: &str,
    frames: u64,
    rate_hz: f64,
    faults: &Faults,
    sensors: usize,
) -> anyhow::Result<u64> {
    let socket = UdpSocket::bind("127.0.0.1:0")
        .or_else(|_| UdpSocket::bind("0.0.0.0:0"))
        .context("cannot open a UDP socket")?;
    socket
        .connect(to)
        .with_context(|| format!("cannot send to '{to}'"))?;
    let start = Instant::now();
    let period = Duration::from_secs_f64(1.0 / rate_hz.max(1e-3));
    let mut sent = 0;
    for step in 0..frames {
        imuflow_graph::wait::sleep_until(start + period.mul_f64(step as f64));
        for seq in faults.plan(step, rate_hz) {
            // A receiver that is not (yet) listening makes loopback sends fail; keep going.
            if let Err(e) = socket.send(&faults.packet(seq, rate_hz, sensors).encode()) {
                tracing::debug!("send {seq}: {e}");
            }
            sent += 1;
        }
    }
    Ok(sent)
}

/// Packet `seq` of [`send_synthetic`] with `sensors` sensors: sensor i turns about the vertical
/// at 0.5·(i+1) rad/s and feels gravity's reaction (+9.81 m/s² up).
pub fn synthetic_packet(
    seq: u64,
    rate_hz: f64,
    nan_every: u64,
    missing_every: u64,
    sensors: usize,
) -> Packet {
    let t = seq as f64 / rate_hz;
    let mut p = Packet {
        seq,
        timestamp_ns: now_ns(),
        sensors: vec![SensorSample::default(); sensors],
    };
    for (i, s) in p.sensors.iter_mut().enumerate() {
        let rate = 0.5 * (i + 1) as f64;
        let half = 0.5 * rate * t;
        *s = SensorSample {
            orientation_wxyz: [half.cos() as f32, 0.0, half.sin() as f32, 0.0],
            specific_force_mps2: [0.0, 9.81, 0.0],
            angular_rate_radps: [0.0, rate as f32, 0.0],
            valid: true,
        };
    }
    if nan_every > 0
        && seq % nan_every == nan_every - 1
        && let Some(s) = p.sensors.first_mut()
    {
        s.specific_force_mps2[0] = f32::NAN;
    }
    if missing_every > 0
        && seq % missing_every == missing_every - 1
        && let Some(s) = p.sensors.get_mut(1)
    {
        s.valid = false;
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use imuflow_body::SensorSet;
    use imuflow_graph::frames::flags;

    const SIX: usize = NUM_IMUS;

    fn six() -> SiteMask {
        SensorSet::six().mask()
    }

    #[test]
    fn packets_round_trip_and_bad_ones_are_rejected() {
        let p = synthetic_packet(41, 60.0, 0, 0, SIX);
        let bytes = p.encode();
        assert_eq!(bytes.len(), 288);
        assert_eq!(Packet::decode(&bytes, SIX), Ok(p.clone()));
        assert_eq!(
            Packet::decode(&bytes[..100], SIX),
            Err(PacketError::Size {
                found: 100,
                expected: 288
            })
        );
        let mut bad = bytes.clone();
        bad[0] = b'X';
        assert_eq!(Packet::decode(&bad, SIX), Err(PacketError::Magic));
        let mut bad = bytes.clone();
        bad[4] = 9;
        assert_eq!(Packet::decode(&bad, SIX), Err(PacketError::Version(9)));
        // A six-sensor sender and a five-sensor receiver: the counts named.
        assert_eq!(
            Packet::decode(&bytes, 5),
            Err(PacketError::Sensors {
                found: 6,
                expected: 5
            })
        );
        let f = p.to_frame(six());
        assert_eq!(f.valid_mask, 0b11_1111);
        assert_eq!(f.header.flags, 0);
    }

    #[test]
    fn a_lower_body_packet_carries_five_sensors_into_the_sets_slots() {
        // Pelvis, upper and lower legs: slots 2, 3, 5, 6, 7, in that order in the packet.
        let legs = SensorSet::builtin("lower-body").expect("shipped").mask();
        let mut p = synthetic_packet(7, 60.0, 0, 0, 5);
        p.sensors[4].valid = false; // the right upper leg
        let bytes = p.encode();
        assert_eq!(bytes.len(), 24 + 5 * 44);
        assert_eq!(u16::from_le_bytes([bytes[6], bytes[7]]), 5);
        let f = Packet::decode(&bytes, 5).expect("decodes").to_frame(legs);
        assert_eq!(f.valid_mask, 1 << 2 | 1 << 3 | 1 << 5 | 1 << 6);
        assert!(f.header.has(flags::INVALID));
        // The packet's third sensor (turning at 1.5 rad/s) is the pelvis, slot 5.
        assert_eq!(f.angular_rate_radps[5], [0.0, 1.5, 0.0]);
        assert_eq!(f.angular_rate_radps[4], [0.0; 3]);
    }

    #[test]
    fn faults_lose_swap_repeat_and_delay_packets_as_planned() {
        let f = Faults {
            loss_every: 11,
            reorder_every: 20,
            duplicate_every: 13,
            late_every: 17,
            dead: Some((2, 5..7)),
            nan_burst: Some((4, 6..8)),
            ..Faults::default()
        };
        assert_eq!(f.plan(5, 60.0), Vec::<u64>::new()); // lost: 5 % 11 == 11 / 2
        assert_eq!(f.plan(28, 60.0), vec![29, 28]); // swapped
        assert_eq!(f.plan(29, 60.0), Vec::<u64>::new()); // already sent
        assert_eq!(f.plan(26, 60.0), vec![26, 26]); // twice
        assert_eq!(f.plan(34, 60.0), vec![34, 4]); // and one of half a second (30) before
        assert_eq!(f.plan(1, 60.0), vec![1]);
        assert!(Faults::default().plan(5, 60.0) == vec![5]);
        let frame = |seq| {
            Packet::decode(&f.packet(seq, 60.0, SIX).encode(), SIX)
                .unwrap()
                .to_frame(six())
        };
        let all = 0b11_1111;
        assert_eq!(frame(4).valid_mask, all);
        assert_eq!(frame(5).valid_mask, all & !(1 << 2));
        assert_eq!(frame(6).valid_mask, all & !(1 << 2) & !(1 << 4));
        assert_eq!(frame(7).valid_mask, all & !(1 << 4));
        assert_eq!(f.packet(7, 60.0, SIX).seq, 7);
        // Held still, a packet keeps its seq's own faults and the first still orientation.
        let still = Faults {
            missing_every: 4,
            still: 0..10,
            ..Faults::default()
        };
        let (first, held) = (still.packet(0, 60.0, SIX), still.packet(7, 60.0, SIX));
        assert!(!held.sensors[1].valid && first.sensors[1].valid);
        assert_eq!(
            held.sensors[5].orientation_wxyz,
            first.sensors[5].orientation_wxyz
        );
        assert_eq!(held.sensors[5].angular_rate_radps, [0.0; 3]);
        assert!(still.packet(10, 60.0, SIX).sensors[5].angular_rate_radps[1] > 0.0);
    }

    #[test]
    fn missing_and_nan_samples_are_invalid() {
        let p = synthetic_packet(5, 60.0, 3, 2, SIX);
        let f = Packet::decode(&p.encode(), SIX)
            .expect("decodes")
            .to_frame(six());
        assert_eq!(f.valid_mask, 0b11_1111 & !0b11);
        assert!(f.header.has(flags::INVALID));
    }
}
