//! Live degradation: a live graph (UDP source → T-pose calibration → PIP kinematics → recorder)
//! fed over loopback, after three still seconds for the calibration, with every fault a wireless sensor network produces at once: lost packets,
//! reordered, duplicated and late packets, one sensor dead for two seconds and a burst of NaN
//! samples from another. The graph must keep running at sensor rate to the end of the stream,
//! flag exactly the frames with a dead or NaN sensor INVALID, skip (and count) every packet that
//! is not newer than the last, show lost packets as sequence gaps, and never let a NaN through
//! the calibration or the kinematics networks.

mod common;

use std::collections::BTreeSet;
use std::time::Duration;

use common::{Sandbox, assert_clean, free_udp_port, mcap_messages, text, wait_with_timeout};
use imuflow_graph::FrameHeader;
use imuflow_graph::frames::{BodyImuFrame, ImuFrame, KinematicsFrame, flags, frame_from_bytes};
use imuflow_imu_source::udp;

const RATE_HZ: f64 = 60.0;
/// Packets the sender produces (8 s at 60 Hz).
const PACKETS: u64 = 480;
/// Sensor 2 is dead (marked not valid) for these packets: two seconds.
const DEAD: std::ops::Range<u64> = 200..320;
/// Sensor 4 reports NaN for these packets.
const NAN_BURST: std::ops::Range<u64> = 350..370;

/// Every fault at once (the options of `tools/udp-send`), after three still seconds for the T-pose
/// calibration: it needs 90 frames (1.5 s) still after a 15-frame window, and the faults take
/// about one packet in seven of them away.
fn faults() -> udp::Faults {
    udp::Faults {
        loss_every: 11,
        reorder_every: 20,
        duplicate_every: 13,
        late_every: 17,
        dead: Some((2, DEAD)),
        nan_burst: Some((4, NAN_BURST)),
        still: 0..180,
        ..udp::Faults::default()
    }
}

#[test]
fn a_live_graph_rides_out_lost_reordered_duplicated_late_dead_and_nan_samples() {
    let sb = Sandbox::new("live-degradation");
    let port = free_udp_port();
    let root = env!("CARGO_MANIFEST_DIR");
    let graph = sb.graph(
        "live.toml",
        &format!(
            r#"
name = "live-degradation"
rate_hz = 60
mode = "live"
[stages.sensors]
kind = "imu-source"
params = {{ mode = "udp", bind = "127.0.0.1:{port}", timeout_ms = 1500 }}
[stages.calib]
kind = "calibration"
inputs = {{ imu = "sensors.imu" }}
params = {{ method = "tpose", frame = "model" }}
[stages.kin]
kind = "kinematics"
inputs = {{ imu = "calib.body_imu" }}
params = {{ net = "pip", weights = "{root}/models/pip.safetensors" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "sensors.imu", body_imu = "calib.body_imu", kinematics = "kin.kinematics" }}
params = {{ path = "{{dir}}/live.mcap" }}
"#
        ),
    );
    let child = sb.spawn(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    // Wait until the source listens (its port is taken), then send at sensor rate.
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("sender socket");
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while std::net::UdpSocket::bind(("127.0.0.1", port)).is_ok() {
        assert!(
            std::time::Instant::now() < deadline,
            "the UDP source listens"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let faults = faults();
    let mut accepted: Vec<u64> = Vec::new();
    let mut stale = 0;
    let start = std::time::Instant::now();
    for step in 0..PACKETS {
        imuflow_graph::wait::sleep_until(start + Duration::from_secs_f64(step as f64 / RATE_HZ));
        for seq in faults.plan(step, RATE_HZ) {
            socket
                .send_to(
                    &faults.packet(seq, RATE_HZ, 6).encode(),
                    ("127.0.0.1", port),
                )
                .expect("loopback send");
            if accepted.last().is_some_and(|last| seq <= *last) {
                stale += 1;
            } else {
                accepted.push(seq);
            }
        }
    }
    let out = wait_with_timeout(child, Duration::from_secs(60));
    let stderr = text(&out.stderr);
    assert!(
        out.status.success(),
        "the run goes on to the end:\n{stderr}"
    );
    assert!(
        stderr.contains(&format!(
            "skipped 0 malformed and {stale} out-of-order packet(s)"
        )),
        "the source counts the {stale} stale packets:\n{stderr}"
    );

    let messages = mcap_messages(&sb.path("live.mcap"));
    let of = |topic: &str| -> Vec<&Vec<u8>> {
        messages
            .iter()
            .filter(|m| m.0 == topic)
            .map(|m| &m.2)
            .collect()
    };
    // Every accepted packet became one frame; lost ones are gaps in seq.
    let imu: Vec<ImuFrame> = of("sensors.imu")
        .iter()
        .map(|raw| frame_from_bytes(raw).expect("an ImuFrame"))
        .filter(|f: &ImuFrame| !f.header.is_end())
        .collect();
    let first = accepted[0];
    let seqs: Vec<u64> = imu.iter().map(|f| f.header.seq).collect();
    let expected: Vec<u64> = accepted.iter().map(|s| s - first).collect();
    // Live, a subscriber that falls behind drops its oldest frames and counts them: the recorder
    // may lose some while the graph starts up (its first frames arrive with the kinematics
    // stage still loading its weights). What it kept is in order, every frame after the first
    // second is there, and the summary counts the ones it dropped.
    let kept: BTreeSet<u64> = seqs.iter().copied().collect();
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "in order, no repeats");
    assert!(kept.is_subset(&expected.iter().copied().collect()));
    let missing: Vec<u64> = expected
        .iter()
        .copied()
        .filter(|s| !kept.contains(s))
        .collect();
    assert!(
        missing.iter().all(|s| *s < RATE_HZ as u64),
        "frames missing after the first second: {missing:?}"
    );
    // INVALID exactly on the frames with a dead or NaN sensor.
    let faulty: BTreeSet<u64> = DEAD.chain(NAN_BURST).collect();
    for f in &imu {
        let seq = f.header.seq + first;
        assert_eq!(
            f.header.has(flags::INVALID),
            faulty.contains(&seq),
            "frame of packet {seq}"
        );
    }
    // Nothing non-finite past the source: the calibrated IMUs and every kinematics output.
    let body: Vec<BodyImuFrame> = of("calib.body_imu")
        .iter()
        .map(|raw| frame_from_bytes(raw).expect("a BodyImuFrame"))
        .collect();
    for f in &body {
        let valid = |i: usize| f.valid_mask & (1 << i) != 0;
        for i in 0..6 {
            let values = f.bone_orientation_wxyz[i]
                .iter()
                .chain(&f.free_acceleration_mps2[i])
                .chain(&f.angular_velocity_radps[i]);
            assert!(
                !valid(i) || values.copied().all(f32::is_finite),
                "body imu {i} of frame {}",
                f.header.seq
            );
        }
    }
    let kin: Vec<KinematicsFrame> = of("kin.kinematics")
        .iter()
        .map(|raw| frame_from_bytes(raw).expect("a KinematicsFrame"))
        .collect();
    assert!(
        kin.len() + 5 >= imu.len(),
        "{} of {} frames",
        kin.len(),
        imu.len()
    );
    for f in &kin {
        let finite = f
            .local_pose_wxyz
            .iter()
            .flatten()
            .chain(f.joint_position_m.iter().flatten())
            .chain(f.joint_velocity_mps.iter().flatten())
            .chain(f.root_velocity_mps.iter())
            .all(|x| x.is_finite());
        assert!(
            finite,
            "kinematics frame {} has a non-finite value",
            f.header.seq
        );
    }
    // The recorder's `dropped` counts, over its three inputs, every frame it did not get: the
    // sequence gaps of the lost packets and what it dropped itself.
    let body_seqs: Vec<FrameHeader> = body.iter().map(|f| f.header).collect();
    let kin_seqs: Vec<FrameHeader> = kin.iter().map(|f| f.header).collect();
    let imu_seqs: Vec<FrameHeader> = imu.iter().map(|f| f.header).collect();
    let not_received: u64 = [imu_seqs, body_seqs, kin_seqs]
        .iter()
        .map(|headers| {
            let data: Vec<u64> = headers
                .iter()
                .filter(|h| !h.is_end())
                .map(|h| h.seq)
                .collect();
            data.iter()
                .max()
                .map_or(0, |last| last + 1 - data.len() as u64)
        })
        .sum();
    let stdout = text(&out.stdout);
    let dropped: u64 = stdout
        .lines()
        .find(|l| l.starts_with("record "))
        .and_then(|l| l.split_whitespace().nth(4))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("the summary has the recorder's drops:\n{stdout}"));
    assert_eq!(
        dropped, not_received,
        "the summary counts every frame not received:\n{stdout}"
    );
    assert_clean(&sb);
}
