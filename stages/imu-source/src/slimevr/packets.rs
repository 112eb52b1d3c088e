//! The SlimeVR tracker protocol over UDP: what a tracker sends, what the server answers, byte for
//! byte. Shared by the `slimevr` receiver and the simulated tracker (`tools/slimevr-sim`).
//!
//! Sources (public repositories; the layouts below are read from them):
//! - firmware SlimeVR/SlimeVR-Tracker-ESP: `src/network/connection.cpp` and `src/network/packets.h`
//!   (the writers up to 2025), `src/network/wifi/WiFiPackets.cpp`, `WiFiPacketDatatypes.h` and
//!   `WiFiCommunication.cpp` (the current writers, same bytes), `src/network/featureflags.h`;
//! - server SlimeVR/SlimeVR-Server: `server/core/src/main/java/dev/slimevr/tracking/trackers/udp/`
//!   `UDPProtocolParser.kt` (framing, bundles, replies), `UDPPacket.kt` (packet bodies),
//!   `TrackersUDPServer.kt` (what the server answers and when), `UDPDevice.kt` (packet numbers),
//!   `FeatureFlags.kt`.
//!
//! # Framing (big-endian throughout)
//!
//! A tracker datagram is `type: u32` (the firmware writes three zero bytes and the type byte),
//! `packet number: u64` (one counter per tracker over every packet it sends, from 0; the handshake
//! always carries 0), then the body. A bundle (type 100) carries, after its own type and number,
//! any number of `length: u16` + inner packet, each inner packet being `type: u32` + body without a
//! packet number. A compact bundle (type 101) uses `length: u8` + `type: u8` + body.
//!
//! | type | packet | body |
//! |---|---|---|
//! | 0 | heartbeat (answer to the server's) | none |
//! | 3 | handshake | board i32, IMU type i32, MCU i32, 3 × i32 (0), firmware build / protocol version i32, firmware version (u8 length + ASCII), MAC 6 bytes; current firmware appends tracker type u8 and five short strings (vendor) |
//! | 4 | acceleration | x, y, z f32 (m/s², gravity removed, tracker frame), sensor id u8 |
//! | 15 | sensor info | sensor id u8, status u8, IMU type u8, then (newer firmware) config and debug fields |
//! | 17 | rotation data | sensor id u8, data type u8 (1 normal, 2 correction), x, y, z, w f32, accuracy u8 |
//! | 22 | feature flags | flag bytes |
//! | 23 | rotation and acceleration | sensor id u8, qx qy qz qw i16 (Q15), ax ay az i16 (1/128 m/s²) |
//! | 1, 16 | legacy rotation (sensor 0, 1) | x, y, z, w f32 |
//! | 10 | ping echo | ping id u32 |
//!
//! The server answers a handshake with 64 bytes: `3`, ASCII `Hey OVR =D 5`, zeros; a sensor info
//! with `type 15` + sensor id + status (no packet number); a feature-flags request with its own
//! flags; and sends a heartbeat (`type 1`, packet number 0) every 500 ms, which the tracker needs:
//! a tracker that hears nothing from the server for 3 s goes back to searching for one.

use std::fmt;
use std::str::FromStr;

/// The UDP port the SlimeVR server listens on and the firmware sends to.
pub const SERVER_PORT: u16 = 6969;

/// Packet types a tracker sends (firmware `SendPacketType`, server `UDPProtocolParser` constants).
pub mod kind {
    pub const HEARTBEAT: u32 = 0;
    /// Legacy rotation of sensor 0 (quaternion only).
    pub const ROTATION: u32 = 1;
    pub const HANDSHAKE: u32 = 3;
    pub const ACCEL: u32 = 4;
    pub const RAW_CALIBRATION_DATA: u32 = 6;
    pub const CALIBRATION_FINISHED: u32 = 7;
    pub const PING_PONG: u32 = 10;
    pub const SERIAL: u32 = 11;
    pub const BATTERY_LEVEL: u32 = 12;
    pub const TAP: u32 = 13;
    pub const ERROR: u32 = 14;
    pub const SENSOR_INFO: u32 = 15;
    /// Legacy rotation of sensor 1 (quaternion only).
    pub const ROTATION_2: u32 = 16;
    pub const ROTATION_DATA: u32 = 17;
    pub const MAGNETOMETER_ACCURACY: u32 = 18;
    pub const SIGNAL_STRENGTH: u32 = 19;
    pub const TEMPERATURE: u32 = 20;
    pub const USER_ACTION: u32 = 21;
    pub const FEATURE_FLAGS: u32 = 22;
    pub const ROTATION_AND_ACCELERATION: u32 = 23;
    pub const ACK_CONFIG_CHANGE: u32 = 24;
    /// Flex sensor data in the current firmware, log messages in the server.
    pub const FLEX_DATA_OR_LOG: u32 = 26;
    pub const BUNDLE: u32 = 100;
    pub const BUNDLE_COMPACT: u32 = 101;
    pub const INSPECTION: u32 = 105;
    pub const PROTOCOL_CHANGE: u32 = 200;

    /// Types a tracker sends that carry nothing the receiver uses (battery, signal strength,
    /// temperature, taps, errors, ...): not counted as unknown.
    pub const IGNORED: [u32; 14] = [
        RAW_CALIBRATION_DATA,
        CALIBRATION_FINISHED,
        SERIAL,
        BATTERY_LEVEL,
        TAP,
        ERROR,
        MAGNETOMETER_ACCURACY,
        SIGNAL_STRENGTH,
        TEMPERATURE,
        USER_ACTION,
        ACK_CONFIG_CHANGE,
        FLEX_DATA_OR_LOG,
        INSPECTION,
        PROTOCOL_CHANGE,
    ];
}

/// Packet types the server sends (firmware `ReceivePacketType`).
pub mod server_kind {
    pub const HEARTBEAT: u32 = 1;
    pub const VIBRATE: u32 = 2;
    pub const HANDSHAKE: u32 = 3;
    pub const COMMAND: u32 = 4;
    pub const CONFIG: u32 = 8;
    pub const PING_PONG: u32 = 10;
    pub const SENSOR_INFO: u32 = 15;
    pub const FEATURE_FLAGS: u32 = 22;
    pub const SET_CONFIG_FLAG: u32 = 25;
}

/// Rotation data type of the fused orientation (`DATA_TYPE_NORMAL`); 2 is a magnetometer
/// correction the server does not use either.
pub const DATA_TYPE_NORMAL: u8 = 1;

/// What the server's handshake answer starts with after its first byte (`HANDSHAKE_BUFFER` in
/// `UDPProtocolParser.kt`); the firmware compares these 12 bytes.
pub const HANDSHAKE_GREETING: &[u8; 12] = b"Hey OVR =D 5";

/// Length of the server's handshake answer.
pub const HANDSHAKE_REPLY_LEN: usize = 64;

/// Server feature flag bits (`ServerFeatureFlags` in `FeatureFlags.kt`; bit i of byte i / 8).
pub mod server_feature {
    /// The server parses bundles (type 100); the firmware then bundles each loop's packets.
    pub const BUNDLE: u8 = 1 << 0;
    /// The server parses compact bundles (type 101) and rotation-and-acceleration packets (23).
    pub const BUNDLE_COMPACT: u8 = 1 << 1;
}

/// Feature flags this receiver announces: it parses both bundle forms (not log messages).
pub const RECEIVER_FEATURES: [u8; 1] = [server_feature::BUNDLE | server_feature::BUNDLE_COMPACT];

/// Bytes of the `type + packet number` header of a standalone packet.
pub const HEADER_LEN: usize = 12;

/// A tracker's MAC address, as the handshake carries it (6 bytes) and the mapping file writes it
/// (`aa:bb:cc:dd:ee:ff`, any case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Mac(pub [u8; 6]);

impl fmt::Display for Mac {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let b = self.0;
        write!(
            f,
            "{:02x}:{:02x}:{:02x}:{:02x}:{:02x}:{:02x}",
            b[0], b[1], b[2], b[3], b[4], b[5]
        )
    }
}

impl FromStr for Mac {
    type Err = String;

    fn from_str(s: &str) -> Result<Mac, String> {
        let bad =
            || format!("'{s}' is not a MAC address (expected six hex bytes: aa:bb:cc:dd:ee:ff)");
        let parts: Vec<&str> = s.trim().split([':', '-']).collect();
        if parts.len() != 6 {
            return Err(bad());
        }
        let mut mac = [0u8; 6];
        for (byte, part) in mac.iter_mut().zip(&parts) {
            if part.len() != 2 {
                return Err(bad());
            }
            *byte = u8::from_str_radix(part, 16).map_err(|_| bad())?;
        }
        Ok(Mac(mac))
    }
}

/// The handshake a tracker broadcasts until a server answers.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Handshake {
    pub board: u32,
    /// IMU type of the first sensor (kept for old servers; sensor info packets carry each one's).
    pub imu: u32,
    pub mcu: u32,
    /// `FIRMWARE_BUILD_NUMBER` (older firmware) or `PROTOCOL_VERSION` (current firmware).
    pub firmware_build: u32,
    pub firmware: String,
    /// None when the handshake carries none, or all zeros (the server treats both alike).
    pub mac: Option<Mac>,
    /// What current firmware sends after the MAC (tracker type and vendor strings); kept as
    /// bytes, the receiver does not use it.
    pub tail: Vec<u8>,
}

impl Handshake {
    /// The tail current firmware writes after the MAC (`sendTrackerDiscovery` in
    /// `WiFiCommunication.cpp`): tracker type, then vendor name, vendor URL, product name, update
    /// address and update name as short strings (u8 length + bytes, at most 255).
    pub fn firmware_tail(tracker_type: u8, strings: [&str; 5]) -> Vec<u8> {
        let mut tail = vec![tracker_type];
        for s in strings {
            short_string(&mut tail, s);
        }
        tail
    }
}

/// A rotation packet (type 17): the orientation the tracker fused on board.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rotation {
    pub sensor_id: u8,
    pub data_type: u8,
    /// Quaternion in the firmware's order x, y, z, w.
    pub xyzw: [f32; 4],
    pub accuracy: u8,
}

/// An acceleration packet (type 4): linear acceleration (gravity removed), m/s², tracker frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acceleration {
    pub sensor_id: u8,
    pub xyz: [f32; 3],
}

/// A sensor info packet (type 15): a sensor's status (0 offline, 1 ok, 2 error) and IMU type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorInfo {
    pub sensor_id: u8,
    pub status: u8,
    pub imu_type: Option<u8>,
}

/// One decoded tracker packet.
#[derive(Debug, Clone, PartialEq)]
pub enum Packet {
    Heartbeat,
    Handshake(Handshake),
    Rotation(Rotation),
    Acceleration(Acceleration),
    /// Type 23: both in one packet, quantized.
    RotationAndAcceleration(Rotation, Acceleration),
    SensorInfo(SensorInfo),
    FeatureFlags(Vec<u8>),
    /// The tracker's echo of the server's ping.
    PingPong(u32),
    /// A known type the receiver has no use for.
    Ignored(u32),
    /// A type this protocol version does not define.
    Unknown(u32),
}

/// Why bytes are not a packet.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    #[error("{what}: {got} bytes, needs {need}")]
    Short {
        what: &'static str,
        need: usize,
        got: usize,
    },
    #[error("bundle entry of {len} bytes runs past the datagram's end ({left} bytes left)")]
    BundleOverrun { len: usize, left: usize },
}

/// One datagram: its type and packet number, and the packets it carries (one, or a bundle's
/// entries, each decoded on its own so one bad entry does not lose the others).
#[derive(Debug, Clone, PartialEq)]
pub struct Datagram {
    pub kind: u32,
    pub number: u64,
    pub packets: Vec<Result<Packet, PacketError>>,
}

/// Decodes a datagram a tracker sent; an error when it is shorter than the 12-byte header.
pub fn decode(bytes: &[u8]) -> Result<Datagram, PacketError> {
    let mut r = Reader::new(bytes, "packet header");
    let kind = r.u32()?;
    let number = r.u64()?;
    let body = r.rest();
    let packets = match kind {
        kind::BUNDLE => bundle_entries(body, 2, 4),
        kind::BUNDLE_COMPACT => bundle_entries(body, 1, 1),
        _ => vec![decode_body(kind, body)],
    };
    Ok(Datagram {
        kind,
        number,
        packets,
    })
}

/// A bundle's entries: `len_bytes` of length, then an entry starting with `type_bytes` of type.
fn bundle_entries(
    mut body: &[u8],
    len_bytes: usize,
    type_bytes: usize,
) -> Vec<Result<Packet, PacketError>> {
    let mut out = Vec::new();
    while !body.is_empty() {
        let Some((len, rest)) = split_uint(body, len_bytes) else {
            out.push(Err(PacketError::Short {
                what: "bundle entry length",
                need: len_bytes,
                got: body.len(),
            }));
            break;
        };
        let len = len as usize;
        if len > rest.len() {
            out.push(Err(PacketError::BundleOverrun {
                len,
                left: rest.len(),
            }));
            break;
        }
        let (entry, next) = rest.split_at(len);
        body = next;
        // The server skips empty entries.
        if len == 0 {
            continue;
        }
        out.push(match split_uint(entry, type_bytes) {
            Some((kind, entry_body)) => decode_body(kind as u32, entry_body),
            None => Err(PacketError::Short {
                what: "bundle entry type",
                need: type_bytes,
                got: entry.len(),
            }),
        });
    }
    out
}

/// A big-endian unsigned integer of `n` bytes (1, 2 or 4) and what follows it.
fn split_uint(b: &[u8], n: usize) -> Option<(u64, &[u8])> {
    if b.len() < n {
        return None;
    }
    let (head, rest) = b.split_at(n);
    Some((
        head.iter().fold(0u64, |v, &x| (v << 8) | u64::from(x)),
        rest,
    ))
}

/// A packet's body by its type; bytes after the fields a type defines are ignored, as the server
/// does (newer firmware appends fields).
fn decode_body(kind: u32, body: &[u8]) -> Result<Packet, PacketError> {
    let legacy_rotation = |sensor_id: u8| -> Result<Packet, PacketError> {
        let mut r = Reader::new(body, "legacy rotation");
        Ok(Packet::Rotation(Rotation {
            sensor_id,
            data_type: DATA_TYPE_NORMAL,
            xyzw: [r.f32()?, r.f32()?, r.f32()?, r.f32()?],
            accuracy: 0,
        }))
    };
    match kind {
        kind::HEARTBEAT => Ok(Packet::Heartbeat),
        kind::HANDSHAKE => Ok(Packet::Handshake(decode_handshake(body))),
        kind::ROTATION_DATA => decode_rotation(body),
        kind::ACCEL => decode_acceleration(body),
        kind::ROTATION_AND_ACCELERATION => decode_rotation_and_acceleration(body),
        kind::SENSOR_INFO => decode_sensor_info(body),
        kind::FEATURE_FLAGS => Ok(Packet::FeatureFlags(body.to_vec())),
        kind::PING_PONG => Ok(Packet::PingPong(Reader::new(body, "ping").u32()?)),
        kind::ROTATION => legacy_rotation(0),
        kind::ROTATION_2 => legacy_rotation(1),
        k if kind::IGNORED.contains(&k) => Ok(Packet::Ignored(k)),
        k => Ok(Packet::Unknown(k)),
    }
}

/// The handshake, read as leniently as the server reads it (`UDPPacket3Handshake.readData`):
/// every field is optional, a missing one stays at its default.
fn decode_handshake(body: &[u8]) -> Handshake {
    let mut r = Reader::new(body, "handshake");
    let (board, imu, mcu) = (
        r.u32().unwrap_or(0),
        r.u32().unwrap_or(0),
        r.u32().unwrap_or(0),
    );
    // Three unused IMU-info ints, read only when all are there (as the server does).
    if r.left() > 11 {
        let _ = (r.u32(), r.u32(), r.u32());
    }
    let firmware_build = r.u32().unwrap_or(0);
    let len = usize::from(r.u8().unwrap_or(0));
    let version = r.bytes(len.min(r.left())).unwrap_or_default();
    // The server stops at a NUL as well.
    let end = version
        .iter()
        .position(|&c| c == 0)
        .unwrap_or(version.len());
    let firmware = version[..end].iter().map(|&c| char::from(c)).collect();
    let (mac, tail) = match r.array::<6>() {
        Ok(mac) => ((mac != [0; 6]).then_some(Mac(mac)), r.rest().to_vec()),
        Err(_) => (None, Vec::new()),
    };
    Handshake {
        board,
        imu,
        mcu,
        firmware_build,
        firmware,
        mac,
        tail,
    }
}

fn decode_rotation(body: &[u8]) -> Result<Packet, PacketError> {
    let mut r = Reader::new(body, "rotation data");
    let sensor_id = r.u8()?;
    let data_type = r.u8()?;
    let xyzw = [r.f32()?, r.f32()?, r.f32()?, r.f32()?];
    let accuracy = r.u8()?;
    Ok(Packet::Rotation(Rotation {
        sensor_id,
        data_type,
        xyzw,
        accuracy,
    }))
}

fn decode_acceleration(body: &[u8]) -> Result<Packet, PacketError> {
    let mut r = Reader::new(body, "acceleration");
    let xyz = [r.f32()?, r.f32()?, r.f32()?];
    // Without a sensor id (owoTrack) the server takes sensor 0.
    let sensor_id = r.u8().unwrap_or(0);
    Ok(Packet::Acceleration(Acceleration { sensor_id, xyz }))
}

/// Type 23 (`UDPPacket23RotationAndAcceleration`): Q15 quaternion, normalized by the server, and
/// acceleration in units of 1/128 m/s².
fn decode_rotation_and_acceleration(body: &[u8]) -> Result<Packet, PacketError> {
    let mut r = Reader::new(body, "rotation and acceleration");
    let sensor_id = r.u8()?;
    let mut q = [0f32; 4];
    for v in &mut q {
        *v = f32::from(r.i16()?) / 32768.0;
    }
    let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    if norm > 0.0 {
        q.iter_mut().for_each(|v| *v /= norm);
    }
    let mut a = [0f32; 3];
    for v in &mut a {
        *v = f32::from(r.i16()?) / 128.0;
    }
    Ok(Packet::RotationAndAcceleration(
        Rotation {
            sensor_id,
            data_type: DATA_TYPE_NORMAL,
            xyzw: q,
            accuracy: 0,
        },
        Acceleration { sensor_id, xyz: a },
    ))
}

fn decode_sensor_info(body: &[u8]) -> Result<Packet, PacketError> {
    let mut r = Reader::new(body, "sensor info");
    let sensor_id = r.u8()?;
    let status = r.u8()?;
    let imu_type = r.u8().ok();
    Ok(Packet::SensorInfo(SensorInfo {
        sensor_id,
        status,
        imu_type,
    }))
}

impl Packet {
    /// The packet's type on the wire.
    pub fn kind(&self) -> u32 {
        match self {
            Packet::Heartbeat => kind::HEARTBEAT,
            Packet::Handshake(_) => kind::HANDSHAKE,
            Packet::Rotation(_) => kind::ROTATION_DATA,
            Packet::Acceleration(_) => kind::ACCEL,
            Packet::RotationAndAcceleration(..) => kind::ROTATION_AND_ACCELERATION,
            Packet::SensorInfo(_) => kind::SENSOR_INFO,
            Packet::FeatureFlags(_) => kind::FEATURE_FLAGS,
            Packet::PingPong(_) => kind::PING_PONG,
            Packet::Ignored(k) | Packet::Unknown(k) => *k,
        }
    }

    /// The body as the firmware writes it (`sendPacket` writes the packed structs of
    /// `WiFiPacketDatatypes.h`, `connection.cpp` writes field by field: the same bytes).
    pub fn body(&self) -> Vec<u8> {
        let mut b = Vec::new();
        match self {
            Packet::Heartbeat | Packet::Ignored(_) | Packet::Unknown(_) => {}
            Packet::Handshake(h) => {
                for v in [h.board, h.imu, h.mcu, 0, 0, 0, h.firmware_build] {
                    b.extend_from_slice(&v.to_be_bytes());
                }
                short_string(&mut b, &h.firmware);
                b.extend_from_slice(&h.mac.unwrap_or(Mac([0; 6])).0);
                b.extend_from_slice(&h.tail);
            }
            Packet::Rotation(r) => {
                b.extend_from_slice(&[r.sensor_id, r.data_type]);
                r.xyzw
                    .iter()
                    .for_each(|v| b.extend_from_slice(&v.to_be_bytes()));
                b.push(r.accuracy);
            }
            Packet::Acceleration(a) => {
                a.xyz
                    .iter()
                    .for_each(|v| b.extend_from_slice(&v.to_be_bytes()));
                b.push(a.sensor_id);
            }
            Packet::RotationAndAcceleration(r, a) => {
                b.push(r.sensor_id);
                let q15 = r
                    .xyzw
                    .map(|v| (v * 32768.0).round().clamp(-32768.0, 32767.0) as i16);
                let acc = a
                    .xyz
                    .map(|v| (v * 128.0).round().clamp(-32768.0, 32767.0) as i16);
                q15.iter()
                    .chain(&acc)
                    .for_each(|v| b.extend_from_slice(&v.to_be_bytes()));
            }
            Packet::SensorInfo(s) => {
                b.extend_from_slice(&[s.sensor_id, s.status]);
                b.extend(s.imu_type);
            }
            Packet::FeatureFlags(flags) => b.extend_from_slice(flags),
            Packet::PingPong(id) => b.extend_from_slice(&id.to_be_bytes()),
        }
        b
    }

    /// The packet as one datagram: type, packet `number` (0 for a handshake), body.
    pub fn standalone(&self, number: u64) -> Vec<u8> {
        let mut b = self.kind().to_be_bytes().to_vec();
        b.extend_from_slice(&number.to_be_bytes());
        b.extend(self.body());
        b
    }
}

/// Packets as one bundle datagram (`WiFiPackets::beginBundle` / `endPacket`): type 100, the
/// bundle's packet `number`, then per packet its length (u16) and type + body (no number).
pub fn bundle(number: u64, packets: &[Packet]) -> Vec<u8> {
    let mut b = kind::BUNDLE.to_be_bytes().to_vec();
    b.extend_from_slice(&number.to_be_bytes());
    for p in packets {
        let mut entry = p.kind().to_be_bytes().to_vec();
        entry.extend(p.body());
        b.extend_from_slice(&(entry.len() as u16).to_be_bytes());
        b.extend(entry);
    }
    b
}

/// A short string: u8 length, then the bytes (the firmware asserts ≤ 255; longer is cut).
fn short_string(b: &mut Vec<u8>, s: &str) {
    let bytes = &s.as_bytes()[..s.len().min(255)];
    b.push(bytes.len() as u8);
    b.extend_from_slice(bytes);
}

/// What the server sends, as `TrackersUDPServer.kt` writes it.
pub mod reply {
    use super::*;

    /// The handshake answer (`writeHandshakeResponse`): 64 bytes, `3`, the greeting, zeros.
    pub fn handshake() -> [u8; HANDSHAKE_REPLY_LEN] {
        let mut b = [0u8; HANDSHAKE_REPLY_LEN];
        b[0] = server_kind::HANDSHAKE as u8;
        b[1..13].copy_from_slice(HANDSHAKE_GREETING);
        b
    }

    /// The keep-alive heartbeat (`UDPPacket1Heartbeat` through `write`: type, packet number 0).
    pub fn heartbeat() -> [u8; HEADER_LEN] {
        header(server_kind::HEARTBEAT)
    }

    /// The acknowledgement of a sensor info (`writeSensorInfoResponse`: no packet number).
    pub fn sensor_info(sensor_id: u8, status: u8) -> [u8; 6] {
        let mut b = [0u8; 6];
        b[..4].copy_from_slice(&server_kind::SENSOR_INFO.to_be_bytes());
        b[4] = sensor_id;
        b[5] = status;
        b
    }

    /// The answer to a feature-flags packet: type 22, packet number 0, the server's flags.
    pub fn feature_flags(flags: &[u8]) -> Vec<u8> {
        let mut b = header(server_kind::FEATURE_FLAGS).to_vec();
        b.extend_from_slice(flags);
        b
    }

    /// A ping (type 10, packet number 0, ping id); the tracker echoes it.
    pub fn ping(id: u32) -> [u8; 16] {
        let mut b = [0u8; 16];
        b[..HEADER_LEN].copy_from_slice(&header(server_kind::PING_PONG));
        b[HEADER_LEN..].copy_from_slice(&id.to_be_bytes());
        b
    }

    fn header(kind: u32) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[..4].copy_from_slice(&kind.to_be_bytes());
        b
    }
}

/// A packet from the server, as the firmware tells them apart (`WiFiCommunication::tick` and
/// `searchForServer`).
#[derive(Debug, Clone, PartialEq)]
pub enum ServerPacket {
    /// The handshake answer: byte 0 is 3 and bytes 1..13 the greeting.
    Handshake,
    Heartbeat,
    PingPong,
    SensorInfo {
        sensor_id: u8,
        status: u8,
    },
    FeatureFlags(Vec<u8>),
    /// Another type (vibrate, command, config, set config flag, ...), by its type byte.
    Other(u8),
}

/// Classifies a datagram from the server the way the firmware does: the handshake answer by its
/// first bytes, everything else by byte 3 (the low byte of the big-endian type). None when too
/// short to tell.
pub fn decode_server(b: &[u8]) -> Option<ServerPacket> {
    if b.len() >= 13 && u32::from(b[0]) == server_kind::HANDSHAKE && &b[1..13] == HANDSHAKE_GREETING
    {
        return Some(ServerPacket::Handshake);
    }
    let kind = u32::from(*b.get(3)?);
    Some(match kind {
        server_kind::HEARTBEAT => ServerPacket::Heartbeat,
        server_kind::PING_PONG => ServerPacket::PingPong,
        // The firmware needs at least 6 bytes here.
        server_kind::SENSOR_INFO if b.len() >= 6 => ServerPacket::SensorInfo {
            sensor_id: b[4],
            status: b[5],
        },
        // Type, packet number, at least one flag byte (firmware: `packetSize < 13` is invalid).
        server_kind::FEATURE_FLAGS if b.len() > HEADER_LEN => {
            ServerPacket::FeatureFlags(b[HEADER_LEN..].to_vec())
        }
        _ => ServerPacket::Other(kind as u8),
    })
}

/// A big-endian reader over a packet body whose errors name the packet.
struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    fn new(b: &'a [u8], what: &'static str) -> Self {
        Reader { b, at: 0, what }
    }

    fn left(&self) -> usize {
        self.b.len() - self.at
    }

    fn bytes(&mut self, n: usize) -> Result<&'a [u8], PacketError> {
        let Some(slice) = self.b.get(self.at..self.at + n) else {
            return Err(PacketError::Short {
                what: self.what,
                need: self.at + n,
                got: self.b.len(),
            });
        };
        self.at += n;
        Ok(slice)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], PacketError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.bytes(N)?);
        Ok(a)
    }

    fn rest(&mut self) -> &'a [u8] {
        let rest = &self.b[self.at..];
        self.at = self.b.len();
        rest
    }

    fn u8(&mut self) -> Result<u8, PacketError> {
        Ok(self.array::<1>()?[0])
    }

    fn i16(&mut self) -> Result<i16, PacketError> {
        Ok(i16::from_be_bytes(self.array()?))
    }

    fn u32(&mut self) -> Result<u32, PacketError> {
        Ok(u32::from_be_bytes(self.array()?))
    }

    fn u64(&mut self) -> Result<u64, PacketError> {
        Ok(u64::from_be_bytes(self.array()?))
    }

    fn f32(&mut self) -> Result<f32, PacketError> {
        Ok(f32::from_be_bytes(self.array()?))
    }
}
