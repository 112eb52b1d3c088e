//! The protocol against byte arrays written from the firmware's layouts, the receiver against a
//! hand-driven tracker socket, and the whole mode against the simulated trackers.

use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::packets::*;
use super::receiver::{FIRMWARE_GRAVITY_MPS2, Receiver, Sample, TrackerStats};
use super::sim::{self, SimFaults, SimOptions, SimTracker};
use super::*;

const MAC1: Mac = Mac([0x02, 0x53, 0x4c, 0x00, 0x00, 0x01]);

// ---------------------------------------------------------------------------------------------
// Encoding: the bytes the firmware writes, field by field from `connection.cpp` /
// `WiFiPacketDatatypes.h` (big-endian; 1.0f = 3f800000, -2.0f = c0000000, 0.5f = 3f000000,
// 0.25f = 3e800000, 1.5f = 3fc00000, -0.25f = be800000).

fn rotation_bytes() -> Vec<u8> {
    vec![
        0, 0, 0, 17, // PACKET_ROTATION_DATA
        1, 2, 3, 4, 5, 6, 7, 8, // packet number 0x0102030405060708
        2, // sensor id
        1, // DATA_TYPE_NORMAL
        0x3f, 0x80, 0, 0, // x = 1.0
        0xc0, 0, 0, 0, // y = -2.0
        0x3f, 0, 0, 0, // z = 0.5
        0x3e, 0x80, 0, 0, // w = 0.25
        3, // accuracy
    ]
}

fn rotation() -> Packet {
    Packet::Rotation(Rotation {
        sensor_id: 2,
        data_type: 1,
        xyzw: [1.0, -2.0, 0.5, 0.25],
        accuracy: 3,
    })
}

fn acceleration_bytes() -> Vec<u8> {
    vec![
        0, 0, 0, 4, // PACKET_ACCEL
        0, 0, 0, 0, 0, 0, 0, 9, // packet number 9
        0x3f, 0xc0, 0, 0, // x = 1.5
        0xbe, 0x80, 0, 0, // y = -0.25
        0, 0, 0, 0, // z = 0
        1, // sensor id
    ]
}

fn acceleration() -> Packet {
    Packet::Acceleration(Acceleration {
        sensor_id: 1,
        xyz: [1.5, -0.25, 0.0],
    })
}

/// `Connection::sendTrackerDiscovery` (connection.cpp): board 9, IMU 10, MCU 2, three zeros,
/// build 17, "0.5.0", the MAC.
fn handshake_bytes() -> Vec<u8> {
    let mut b = vec![0, 0, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0];
    b.extend([0, 0, 0, 9, 0, 0, 0, 10, 0, 0, 0, 2]);
    b.extend([0; 12]);
    b.extend([0, 0, 0, 17, 5, b'0', b'.', b'5', b'.', b'0']);
    b.extend([0x02, 0x53, 0x4c, 0x00, 0x00, 0x01]);
    b
}

fn handshake() -> Handshake {
    Handshake {
        board: 9,
        imu: 10,
        mcu: 2,
        firmware_build: 17,
        firmware: "0.5.0".to_owned(),
        mac: Some(MAC1),
        tail: Vec::new(),
    }
}

#[test]
fn packets_encode_as_the_firmware_writes_them() {
    assert_eq!(rotation().standalone(0x0102030405060708), rotation_bytes());
    assert_eq!(acceleration().standalone(9), acceleration_bytes());
    assert_eq!(
        Packet::Handshake(handshake()).standalone(0),
        handshake_bytes()
    );
    assert_eq!(
        Packet::Heartbeat.standalone(5),
        [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 5]
    );
    let info = Packet::SensorInfo(SensorInfo {
        sensor_id: 1,
        status: 1,
        imu_type: Some(10),
    });
    assert_eq!(
        info.standalone(7),
        [0, 0, 0, 15, 0, 0, 0, 0, 0, 0, 0, 7, 1, 1, 10]
    );
    // Current firmware's handshake tail: tracker type, then five short strings.
    let tail = Handshake::firmware_tail(0, ["ab", "", "c", "", ""]);
    assert_eq!(tail, [0, 2, b'a', b'b', 0, 1, b'c', 0, 0]);
    // A bundle (WiFiPackets::endPacket): type 100, number, then u16 length + type + body.
    let mut bundle_bytes = vec![0, 0, 0, 100, 0, 0, 0, 0, 0, 0, 0, 42, 0, 23];
    bundle_bytes.extend(&rotation_bytes()[..4]);
    bundle_bytes.extend(&rotation_bytes()[12..]);
    bundle_bytes.extend([0, 17]);
    bundle_bytes.extend(&acceleration_bytes()[..4]);
    bundle_bytes.extend(&acceleration_bytes()[12..]);
    assert_eq!(bundle(42, &[rotation(), acceleration()]), bundle_bytes);
}

#[test]
fn server_replies_are_the_servers_bytes() {
    // UDPProtocolParser.HANDSHAKE_BUFFER: 64 bytes, 3, "Hey OVR =D 5", zeros.
    let mut hello = vec![3u8];
    hello.extend(b"Hey OVR =D 5");
    hello.resize(64, 0);
    assert_eq!(reply::handshake().to_vec(), hello);
    assert_eq!(reply::heartbeat(), [0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(reply::sensor_info(1, 2), [0, 0, 0, 15, 1, 2]);
    assert_eq!(
        reply::feature_flags(&RECEIVER_FEATURES),
        [0, 0, 0, 22, 0, 0, 0, 0, 0, 0, 0, 0, 0b11]
    );
    assert_eq!(reply::ping(0x01020304)[12..], [1, 2, 3, 4]);
    // The firmware tells them apart by byte 0 (handshake) or byte 3.
    assert_eq!(decode_server(&hello), Some(ServerPacket::Handshake));
    assert_eq!(
        decode_server(&reply::heartbeat()),
        Some(ServerPacket::Heartbeat)
    );
    assert_eq!(
        decode_server(&reply::sensor_info(1, 2)),
        Some(ServerPacket::SensorInfo {
            sensor_id: 1,
            status: 2
        })
    );
    assert_eq!(
        decode_server(&reply::feature_flags(&[1])),
        Some(ServerPacket::FeatureFlags(vec![1]))
    );
    let mut wrong = hello.clone();
    wrong[5] = b'x';
    // Not the greeting: the firmware then reads byte 3 as a type ('y').
    assert_eq!(decode_server(&wrong), Some(ServerPacket::Other(b'y')));
    assert_eq!(decode_server(&[0, 0, 1]), None);
}

#[test]
fn datagrams_decode_to_their_packets() {
    let d = decode(&rotation_bytes()).unwrap();
    assert_eq!((d.kind, d.number), (17, 0x0102030405060708));
    assert_eq!(d.packets, [Ok(rotation())]);
    assert_eq!(
        decode(&acceleration_bytes()).unwrap().packets,
        [Ok(acceleration())]
    );
    assert_eq!(
        decode(&handshake_bytes()).unwrap().packets,
        [Ok(Packet::Handshake(handshake()))]
    );
    let b = decode(&bundle(42, &[rotation(), acceleration()])).unwrap();
    assert_eq!((b.kind, b.number), (100, 42));
    assert_eq!(b.packets, [Ok(rotation()), Ok(acceleration())]);
    // Current firmware's handshake: the tail after the MAC is kept, the MAC read.
    let mut h = handshake();
    h.tail = Handshake::firmware_tail(1, ["SlimeVR", "", "", "", ""]);
    let p = Packet::Handshake(h.clone()).standalone(0);
    assert_eq!(decode(&p).unwrap().packets, [Ok(Packet::Handshake(h))]);
    // owoTrack: no MAC; an all-zero MAC is none either (as the server reads them).
    let short = decode(&handshake_bytes()[..30]).unwrap();
    let Ok(Packet::Handshake(h)) = &short.packets[0] else {
        panic!("{short:?}")
    };
    assert_eq!((h.board, h.imu, h.mac), (9, 10, None));
    let mut zero = handshake_bytes();
    let n = zero.len();
    zero[n - 6..].fill(0);
    assert!(
        matches!(&decode(&zero).unwrap().packets[0], Ok(Packet::Handshake(h)) if h.mac.is_none())
    );
    // Type 23 (Q15 quaternion, acceleration in 1/128 m/s²) and a compact bundle carrying it.
    let mut body = vec![3u8];
    for v in [0i16, 0, 0, 0x4000, 128, -256, 64] {
        body.extend(v.to_be_bytes());
    }
    let mut compact = vec![
        0,
        0,
        0,
        101,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        1,
        1 + body.len() as u8,
        23,
    ];
    compact.extend(&body);
    let d = decode(&compact).unwrap();
    assert_eq!(
        d.packets,
        [Ok(Packet::RotationAndAcceleration(
            Rotation {
                sensor_id: 3,
                data_type: DATA_TYPE_NORMAL,
                xyzw: [0.0, 0.0, 0.0, 1.0],
                accuracy: 0
            },
            Acceleration {
                sensor_id: 3,
                xyz: [1.0, -2.0, 0.5]
            }
        ))]
    );
    // Known types without use, and unknown ones.
    let battery = [
        0, 0, 0, 12, 0, 0, 0, 0, 0, 0, 0, 3, 0x40, 0x80, 0, 0, 0x3f, 0, 0, 0,
    ];
    assert_eq!(decode(&battery).unwrap().packets, [Ok(Packet::Ignored(12))]);
    let strange = [0, 0, 0, 77, 0, 0, 0, 0, 0, 0, 0, 3, 1, 2];
    assert_eq!(decode(&strange).unwrap().packets, [Ok(Packet::Unknown(77))]);
}

#[test]
fn short_and_broken_datagrams_are_errors_never_panics() {
    assert_eq!(
        decode(&[]),
        Err(PacketError::Short {
            what: "packet header",
            need: 4,
            got: 0
        })
    );
    assert!(decode(&rotation_bytes()[..11]).is_err());
    assert_eq!(
        decode(&rotation_bytes()[..20]).unwrap().packets,
        [Err(PacketError::Short {
            what: "rotation data",
            need: 10,
            got: 8
        })]
    );
    // A bundle entry longer than what is left: the entries before it survive.
    let mut overrun = bundle(1, &[acceleration()]);
    overrun.extend([0, 40, 0, 0, 0, 17]);
    assert_eq!(
        decode(&overrun).unwrap().packets,
        [
            Ok(acceleration()),
            Err(PacketError::BundleOverrun { len: 40, left: 4 })
        ]
    );
    let mut dangling = bundle(1, &[acceleration()]);
    dangling.push(0);
    assert!(matches!(
        decode(&dangling).unwrap().packets[1],
        Err(PacketError::Short {
            what: "bundle entry length",
            ..
        })
    ));
    // Every prefix of every packet, and random bytes behind valid headers: no panic.
    let all = [
        rotation_bytes(),
        acceleration_bytes(),
        handshake_bytes(),
        bundle(3, &[rotation(), acceleration(), Packet::Heartbeat]),
    ];
    for p in &all {
        for n in 0..=p.len() {
            let _ = decode(&p[..n]);
        }
    }
    let mut rng = Lcg(7);
    for _ in 0..20_000 {
        let len = (rng.next() % 80) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        if b.len() > 4 {
            // Mostly types the parser knows, to get past the type dispatch.
            b[..3].fill(0);
            b[3] = [0, 1, 3, 4, 10, 15, 16, 17, 22, 23, 100, 101][rng.next() as usize % 12];
        }
        let _ = decode(&b);
        let _ = decode_server(&b);
    }
}

#[test]
fn macs_read_and_print_in_the_mapping_form() {
    assert_eq!("02:53:4C:00:00:01".parse::<Mac>(), Ok(MAC1));
    assert_eq!("02-53-4c-00-00-01".parse::<Mac>(), Ok(MAC1));
    assert_eq!(MAC1.to_string(), "02:53:4c:00:00:01");
    for bad in [
        "",
        "02:53:4c:00:00",
        "02:53:4c:00:00:01:02",
        "2:53:4c:00:00:01",
        "zz:53:4c:00:00:01",
    ] {
        assert!(bad.parse::<Mac>().is_err(), "{bad}");
    }
}

/// A small deterministic generator for the fuzz loop.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 33
    }
}

// ---------------------------------------------------------------------------------------------
// Frames.

/// The frame of one sample alone.
fn frame(sample: &Sample) -> RawImuFrame {
    let mut assembler = Assembler::default();
    assert_eq!(assembler.push(sample), None);
    assembler.take().expect("a frame")
}

#[test]
fn samples_read_together_share_a_frame_until_a_site_repeats() {
    // Arrived at `received_ns`, sent 3 ns before.
    let sample = |site: usize, received_ns: u64| Sample {
        site,
        received_ns,
        sent_ns: received_ns - 3,
        rotation_xyzw: Some([0.0, 0.0, 0.0, 1.0]),
        acceleration: None,
    };
    let mut a = Assembler::default();
    assert_eq!(a.take(), None);
    assert_eq!(a.push(&sample(0, 10)), None);
    assert_eq!(a.push(&sample(3, 11)), None);
    // Site 0 again: the frame with sites 0 and 3 goes out, the new sample starts the next.
    let first = a.push(&sample(0, 12)).expect("closed");
    assert_eq!(
        (first.orientation_mask, first.header.capture_ns),
        (0b1001, 10)
    );
    // Sample times are the send times, the capture time the earliest arrival.
    assert_eq!(first.sample_time_ns[..4], [7, 0, 0, 8]);
    let second = a.take().expect("the frame collecting");
    assert_eq!((second.orientation_mask, second.header.capture_ns), (1, 12));
    assert_eq!(a.take(), None);
}

#[test]
fn a_sample_becomes_a_frame_of_its_site() {
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let sample = Sample {
        site: 4,
        received_ns: 123_456,
        sent_ns: 123_000,
        rotation_xyzw: Some([h, 0.0, 0.0, h]),
        acceleration: Some(([0.5, 0.0, 0.0], [h, 0.0, 0.0, h])),
    };
    let f = frame(&sample);
    assert_eq!((f.header.capture_ns, f.header.flags), (123_456, 0));
    assert_eq!(
        (f.valid_mask, f.orientation_mask, f.magnetometer_mask),
        (16, 16, 0)
    );
    assert_eq!(f.orientation_wxyz[4], [h, h, 0.0, 0.0]);
    assert_eq!(f.sample_time_ns[4], 123_000);
    // 90° about x: the tracker's y axis is up, so the reaction to gravity is +g along y.
    let g = FIRMWARE_GRAVITY_MPS2 as f32;
    let a = f.accelerometer_mps2[4];
    assert!(
        (a[0] - 0.5).abs() < 1e-6 && (a[1] - g).abs() < 1e-5 && a[2].abs() < 1e-5,
        "{a:?}"
    );
    assert!(f.gyroscope_radps.iter().all(|g| *g == [0.0; 3]));
    assert!(
        f.sample_time_ns
            .iter()
            .enumerate()
            .all(|(i, &t)| i == 4 || t == 0)
    );
    // A rotation alone, then broken values: the bit stays clear and the frame is INVALID.
    let alone = frame(&Sample {
        acceleration: None,
        ..sample
    });
    assert_eq!((alone.valid_mask, alone.orientation_mask), (0, 16));
    for bad in [[f32::NAN, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 2.0], [0.0; 4]] {
        let f = frame(&Sample {
            rotation_xyzw: Some(bad),
            acceleration: Some(([0.0; 3], bad)),
            ..sample
        });
        assert_eq!(
            (f.orientation_mask, f.header.flags),
            (0, flags::INVALID),
            "{bad:?}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// The receiver against a hand-driven tracker socket.

fn mapping(entries: &[(Mac, u8, &str)]) -> Mapping {
    let text: String = entries
        .iter()
        .map(|(mac, sensor, site)| {
            format!("[[tracker]]\nmac = \"{mac}\"\nsensor = {sensor}\nsite = \"{site}\"\n")
        })
        .collect();
    Mapping::parse(&text, "test").unwrap()
}

/// A socket that plays a tracker by hand.
struct FakeTracker {
    socket: UdpSocket,
    server: SocketAddr,
}

impl FakeTracker {
    fn new(server: SocketAddr) -> Self {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(5)))
            .unwrap();
        FakeTracker { socket, server }
    }

    fn send(&self, bytes: &[u8]) {
        self.socket.send_to(bytes, self.server).unwrap();
    }

    /// Everything the server sent so far.
    fn replies(&self) -> Vec<Vec<u8>> {
        let mut buf = [0u8; 2048];
        std::iter::from_fn(|| self.socket.recv(&mut buf).ok().map(|n| buf[..n].to_vec())).collect()
    }
}

/// Polls until nothing arrives for 50 ms; the samples.
fn drain(receiver: &mut Receiver) -> Vec<Sample> {
    let mut out = Vec::new();
    let mut quiet_since = Instant::now();
    while quiet_since.elapsed() < Duration::from_millis(50) {
        if receiver.poll(Duration::from_millis(5), &mut out).unwrap() {
            quiet_since = Instant::now();
        }
    }
    out
}

fn stats(receiver: &Receiver, mac: Mac) -> TrackerStats {
    receiver
        .tracker_stats()
        .find(|(m, _)| *m == mac)
        .map(|(_, s)| s)
        .unwrap_or_default()
}

/// Datagram `n`: a bundle of sensor `sensor_id`'s rotation (the identity) and acceleration (0).
fn still_bundle(n: u64, sensor_id: u8) -> Vec<u8> {
    bundle(
        n,
        &[
            Packet::Rotation(Rotation {
                sensor_id,
                data_type: DATA_TYPE_NORMAL,
                xyzw: [0.0, 0.0, 0.0, 1.0],
                accuracy: 0,
            }),
            Packet::Acceleration(Acceleration {
                sensor_id,
                xyz: [0.0; 3],
            }),
        ],
    )
}

fn connected(sites: &[(Mac, u8, &str)]) -> (Receiver, FakeTracker) {
    let mut receiver = Receiver::bind("127.0.0.1:0", mapping(sites)).unwrap();
    let tracker = FakeTracker::new(receiver.local_addr().unwrap());
    tracker.send(&handshake_bytes());
    drain(&mut receiver);
    (receiver, tracker)
}

#[test]
fn the_receiver_answers_a_mapped_tracker_as_the_server_does() {
    let (mut receiver, tracker) = connected(&[(MAC1, 0, "head")]);
    let started = Instant::now();
    let mut heartbeats = 0;
    let mut answers = |tracker: &FakeTracker| -> Vec<Vec<u8>> {
        let (beats, other): (Vec<_>, Vec<_>) = tracker
            .replies()
            .into_iter()
            .partition(|r| r[..] == reply::heartbeat());
        heartbeats += beats.len();
        other
    };
    assert_eq!(answers(&tracker), [reply::handshake().to_vec()]);
    // Sensor info is acknowledged, feature flags are answered with the receiver's.
    tracker.send(&[0, 0, 0, 15, 0, 0, 0, 0, 0, 0, 0, 1, 0, 1, 10]);
    tracker.send(&[0, 0, 0, 22, 0, 0, 0, 0, 0, 0, 0, 2, 0]);
    drain(&mut receiver);
    assert_eq!(
        answers(&tracker),
        [
            vec![0, 0, 0, 15, 0, 1],
            vec![0, 0, 0, 22, 0, 0, 0, 0, 0, 0, 0, 0, 0b11]
        ]
    );
    // Heartbeats every 500 ms keep it streaming.
    let mut out = Vec::new();
    while started.elapsed() < Duration::from_millis(1100) {
        receiver.poll(Duration::from_millis(20), &mut out).unwrap();
    }
    assert!(answers(&tracker).is_empty());
    assert!(
        (2..=3).contains(&heartbeats),
        "{heartbeats} heartbeats in 1.1 s"
    );
}

#[test]
fn unknown_trackers_and_strangers_are_ignored() {
    let mut receiver = Receiver::bind("127.0.0.1:0", mapping(&[(MAC1, 0, "head")])).unwrap();
    let stranger = FakeTracker::new(receiver.local_addr().unwrap());
    let mut unknown = handshake();
    unknown.mac = Some(Mac([0x02, 0, 0, 0, 0, 0x99]));
    stranger.send(&Packet::Handshake(unknown).standalone(0));
    // Data without a handshake (a tracker still connected to an earlier server).
    stranger.send(&rotation().standalone(1));
    assert!(drain(&mut receiver).is_empty());
    assert!(stranger.replies().is_empty());
    assert_eq!(receiver.other_stats().ignored, 2);
    assert_eq!(receiver.tracker_stats().count(), 0);
}

#[test]
fn rotations_pair_with_their_accelerations() {
    let (mut receiver, tracker) = connected(&[(MAC1, 0, "left_forearm"), (MAC1, 1, "pelvis")]);
    let rot = |n: u64, sensor_id: u8, x: f32| {
        Packet::Rotation(Rotation {
            sensor_id,
            data_type: DATA_TYPE_NORMAL,
            xyzw: [x, 0.0, 0.0, (1.0 - x * x).sqrt()],
            accuracy: 0,
        })
        .standalone(n)
    };
    let acc = |n: u64, sensor_id: u8| {
        Packet::Acceleration(Acceleration {
            sensor_id,
            xyz: [1.0, 2.0, 3.0],
        })
        .standalone(n)
    };
    // Pairs, a bundle, a rotation without acceleration (published alone after PAIR_WAIT), an
    // acceleration alone (with the last rotation's gravity), an unmapped sensor.
    tracker.send(&rot(1, 0, 0.1));
    tracker.send(&acc(2, 0));
    tracker.send(&still_bundle(3, 1));
    tracker.send(&rot(4, 0, 0.2));
    let samples = drain(&mut receiver);
    tracker.send(&acc(5, 0));
    tracker.send(&rot(6, 7, 0.3));
    tracker.send(&acc(7, 7));
    let later = drain(&mut receiver);
    let pattern: Vec<(usize, bool, bool)> = samples
        .iter()
        .chain(&later)
        .map(|s| (s.site, s.rotation_xyzw.is_some(), s.acceleration.is_some()))
        .collect();
    assert_eq!(
        pattern,
        [
            (0, true, true),
            (5, true, true),
            (0, true, false),
            (0, false, true)
        ]
    );
    // The lone acceleration takes the last rotation (x = 0.2) for its gravity direction.
    assert_eq!(later[0].acceleration.unwrap().1[0], 0.2);
    let s = stats(&receiver, MAC1);
    assert_eq!((s.samples, s.packets, s.lost), (4, 7, 0));
}

#[test]
fn lost_duplicated_and_late_datagrams_are_counted() {
    let (mut receiver, tracker) = connected(&[(MAC1, 0, "head")]);
    // Numbers 1, 2, 4, 4, 3, 6, 0 (a ping echo), then junk: 5 is lost, the second 4 is a
    // duplicate, 3 is late, the junk malformed and of an unknown type.
    for n in [1, 2, 4, 4, 3, 6, 0] {
        tracker.send(&Packet::Heartbeat.standalone(n));
    }
    tracker.send(&[0, 0, 0, 17, 0]);
    tracker.send(&[0, 0, 0, 88, 0, 0, 0, 0, 0, 0, 0, 7]);
    drain(&mut receiver);
    let s = stats(&receiver, MAC1);
    assert_eq!(
        (
            s.packets,
            s.lost,
            s.duplicated,
            s.out_of_order,
            s.malformed,
            s.unknown_types
        ),
        (9, 1, 1, 1, 1, 1)
    );
    // A reconnection starts the numbering anew and keeps what was lost.
    tracker.send(&handshake_bytes());
    for n in [100, 103] {
        tracker.send(&Packet::Heartbeat.standalone(n));
    }
    drain(&mut receiver);
    let s = stats(&receiver, MAC1);
    assert_eq!((s.lost, s.handshakes), (3, 2));
}

#[test]
fn random_datagrams_from_a_tracker_never_stop_the_receiver() {
    let (mut receiver, tracker) = connected(&[(MAC1, 0, "head"), (MAC1, 1, "pelvis")]);
    let mut rng = Lcg(11);
    let mut out = Vec::new();
    for i in 0..2000u64 {
        let len = (rng.next() % 60) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        if b.len() >= 12 {
            b[..3].fill(0);
            b[3] = [4, 15, 17, 22, 23, 100, 101][rng.next() as usize % 7];
            b[4..12].copy_from_slice(&(i + 1).to_be_bytes());
            if b.len() > 12 {
                b[12] %= 2; // a mapped sensor id for most types
            }
        }
        tracker.send(&b);
        receiver.poll(Duration::from_millis(1), &mut out).unwrap();
    }
    out.extend(drain(&mut receiver));
    for s in &out {
        let f = frame(s);
        assert!((f.valid_mask | f.orientation_mask) & !0b11_0000 == 0);
    }
    assert!(stats(&receiver, MAC1).packets > 1900);
}

// ---------------------------------------------------------------------------------------------
// The simulated trackers.

/// Runs the simulator on a thread and the receiver on this one until the simulator is done;
/// the reports and every sample.
fn simulate(options: SimOptions, receiver: &mut Receiver) -> (Vec<sim::SimReport>, Vec<Sample>) {
    let done = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let sim = {
        let done = done.clone();
        std::thread::spawn(move || {
            let reports = sim::run(&options, stop);
            done.store(true, Ordering::Relaxed);
            reports
        })
    };
    let mut samples = Vec::new();
    while !done.load(Ordering::Relaxed) {
        receiver
            .poll(Duration::from_millis(20), &mut samples)
            .unwrap();
    }
    samples.extend(drain(receiver));
    receiver.flush_all(&mut samples);
    let reports = sim.join().unwrap().expect("simulation");
    (reports, samples)
}

fn sim_options(server: SocketAddr, trackers: Vec<SimTracker>, ticks: u64) -> SimOptions {
    SimOptions {
        server: server.to_string(),
        trackers,
        rate_hz: 100.0,
        ticks,
        bundle: true,
        handshake_timeout: Duration::from_secs(5),
        faults: SimFaults::default(),
    }
}

/// Row-major 3×3 rotation about unit `axis` by `angle` (Rodrigues).
fn rodrigues(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = axis;
    let t = 1.0 - c;
    [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]
}

/// The specific force sensor `index` feels at tick `tick`, from rotation matrices:
/// `f_T = R_ITᵀ · (a_I + g·e_z)` with `R_IT = R_z(heading) · R(axis, rate·t)`.
fn expected_specific_force(index: usize, tick: u64, rate_hz: f64) -> [f64; 3] {
    let t = tick as f64 / rate_hz;
    let rz = rodrigues([0.0, 0.0, 1.0], sim::motion::heading_rad(index));
    let ra = rodrigues(sim::motion::axis(index), sim::motion::rate_radps(index) * t);
    let r: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| rz[i][k] * ra[k][j]).sum()));
    let mut a = sim::motion::acceleration_inertial(index, t);
    a[2] += FIRMWARE_GRAVITY_MPS2;
    std::array::from_fn(|j| (0..3).map(|i| r[i][j] * a[i]).sum())
}

#[test]
fn the_simulator_counts_what_the_receiver_counts() {
    let tracker = sim::default_trackers(1);
    let mut receiver = Receiver::bind(
        "127.0.0.1:0",
        Mapping::parse(&sim::trackers_toml(&tracker), "sim").unwrap(),
    )
    .unwrap();
    let mut options = sim_options(receiver.local_addr().unwrap(), tracker, 100);
    // One packet per datagram: 200 data datagrams, the last one not dropped (200 % 7 != 0).
    options.bundle = false;
    options.faults = SimFaults {
        drop_every: 7,
        duplicate_every: 11,
        swap_every: 13,
        stall: None,
    };
    let (reports, samples) = simulate(options, &mut receiver);
    let sent = &reports[0];
    let got = stats(&receiver, sent.mac.unwrap());
    assert_eq!(
        (got.lost, got.duplicated, got.out_of_order),
        (sent.dropped, sent.duplicated, sent.swapped)
    );
    assert!(
        sent.dropped >= 20 && sent.duplicated >= 10 && sent.swapped >= 10,
        "{sent:?}"
    );
    assert!(!samples.is_empty());
}

/// Six trackers at 100 Hz for 10 s: every rotation arrives exactly, in order, every
/// acceleration as the specific force the known motion gives, nothing is lost.
#[test]
fn six_simulated_trackers_stream_ten_seconds_without_loss() {
    let trackers = sim::default_trackers(6);
    let mapping = Mapping::parse(&sim::trackers_toml(&trackers), "sim").unwrap();
    let mut receiver = Receiver::bind("127.0.0.1:0", mapping).unwrap();
    let (rate_hz, ticks) = (100.0, 1000);
    let options = sim_options(receiver.local_addr().unwrap(), trackers, ticks);
    let (reports, samples) = simulate(options, &mut receiver);
    for r in &reports {
        assert_eq!((r.ticks_sent, r.connections), (ticks, 1), "{r:?}");
        // Heartbeats every 500 ms kept it from timing out; bundles once flags were answered.
        assert!(r.heartbeats >= 15 && r.bundles >= ticks - 10, "{r:?}");
    }
    for (mac, s) in receiver.tracker_stats() {
        assert_eq!(
            (
                s.lost,
                s.duplicated,
                s.out_of_order,
                s.malformed,
                s.unknown_types,
                s.unpaired
            ),
            (0, 0, 0, 0, 0, 0),
            "{mac}: {s:?}"
        );
    }
    for site in 0..6 {
        let mine: Vec<&Sample> = samples.iter().filter(|s| s.site == site).collect();
        let rotations: Vec<[f32; 4]> = mine.iter().filter_map(|s| s.rotation_xyzw).collect();
        let expected: Vec<[f32; 4]> = (0..ticks)
            .map(|k| sim::motion::sample(site, k, rate_hz).0)
            .collect();
        assert!(rotations == expected, "site {site}: rotations differ");
        let forces: Vec<[f32; 3]> = mine
            .iter()
            .filter_map(|s| s.acceleration)
            .map(|(a, q)| receiver::specific_force(a, q).unwrap())
            .collect();
        assert_eq!(forces.len(), ticks as usize, "site {site}");
        for (k, f) in forces.iter().enumerate() {
            let e = expected_specific_force(site, k as u64, rate_hz);
            let err = (0..3)
                .map(|i| (f64::from(f[i]) - e[i]).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-4, "site {site} tick {k}: {f:?} vs {e:?}");
        }
        // Bundled, rotation and acceleration travel together: (nearly) every sample has both.
        let paired = mine
            .iter()
            .filter(|s| s.rotation_xyzw.is_some() && s.acceleration.is_some())
            .count();
        assert!(
            paired >= ticks as usize - 10,
            "site {site}: {paired} paired"
        );
    }
}

#[test]
fn a_flood_from_elsewhere_is_counted_and_the_tracker_keeps_streaming() {
    // A mapped tracker streams 50 samples (bundles of rotation and acceleration) while a stranger
    // floods the port with 3000 datagrams of garbage and of data without a handshake (60 before
    // each sample): every sample of the tracker comes through, each with the poll that read it,
    // and the flood is counted as ignored, datagram for datagram.
    let (mut receiver, tracker) = connected(&[(MAC1, 0, "head")]);
    let stranger = FakeTracker::new(receiver.local_addr().unwrap());
    let mut out = Vec::new();
    for n in 1..=50u64 {
        for k in 0..60u64 {
            if k % 2 == 0 {
                stranger.send(&[0xff; 40]);
            } else {
                stranger.send(&rotation().standalone(k));
            }
        }
        tracker.send(&still_bundle(n, 0));
        // One wake-up reads what the socket holds: the flood and the sample behind it.
        receiver.poll(Duration::from_millis(50), &mut out).unwrap();
        assert_eq!(out.len() as u64, n, "sample {n} with its poll");
    }
    out.extend(drain(&mut receiver));
    assert_eq!(out.len(), 50);
    assert!(out.iter().all(|s| s.site == 4));
    let s = stats(&receiver, MAC1);
    assert_eq!((s.samples, s.lost, s.malformed), (50, 0, 0), "{s:?}");
    assert_eq!(receiver.other_stats().ignored, 3000);
}
