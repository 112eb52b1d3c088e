//! The imu-source stage's `slimevr` mode in a live graph (imu-source → recorder on `source.raw`),
//! fed by six simulated SlimeVR trackers (`imuflow_imu_source::slimevr::sim`, what
//! `tools/slimevr-sim` runs) at 100 Hz: the stage must shake hands with every tracker, keep them
//! streaming, and record every sample: each rotation exactly as sent, each acceleration as the
//! specific force the known motion gives, frames numbered without gaps (a live reader keeps two
//! frames: the source merges the trackers' bursts so none is overwritten).

mod common;

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use common::{Sandbox, assert_clean, free_udp_port, mcap_messages, text, wait_with_timeout};
use imuflow_graph::frames::{NUM_IMUS, RawImuFrame, frame_from_bytes};
use imuflow_imu_source::slimevr::receiver::FIRMWARE_GRAVITY_MPS2;
use imuflow_imu_source::slimevr::sim::{self, SimFaults, SimOptions, motion};

const RATE_HZ: f64 = 100.0;
const TICKS: u64 = 300;

#[test]
fn six_simulated_trackers_are_recorded_sample_for_sample() {
    let sb = Sandbox::new("slimevr-live");
    let port = free_udp_port();
    let trackers = sim::default_trackers(NUM_IMUS);
    std::fs::write(sb.path("trackers.toml"), sim::trackers_toml(&trackers)).expect("trackers");
    let graph = sb.graph(
        "slimevr.toml",
        &format!(
            r#"
name = "slimevr-live"
rate_hz = 60
mode = "live"
[stages.source]
kind = "imu-source"
params = {{ mode = "slimevr", bind = "127.0.0.1:{port}", trackers = "{{dir}}/trackers.toml", timeout_ms = 1500 }}
[stages.record]
kind = "recorder"
inputs = {{ raw = "source.raw" }}
params = {{ path = "{{dir}}/slimevr.mcap" }}
"#
        ),
    );
    let child = sb.spawn(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    // The simulated trackers broadcast their handshake every second until the stage answers.
    let options = SimOptions {
        server: format!("127.0.0.1:{port}"),
        trackers,
        rate_hz: RATE_HZ,
        ticks: TICKS,
        bundle: true,
        handshake_timeout: Duration::from_secs(60),
        faults: SimFaults::default(),
    };
    let reports = sim::run(&options, Arc::new(AtomicBool::new(false))).expect("simulation");
    let out = wait_with_timeout(child, Duration::from_secs(60));
    let log = format!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(
        out.status.success(),
        "the run ends after the trackers:\n{log}"
    );
    for r in &reports {
        assert_eq!((r.ticks_sent, r.connections), (TICKS, 1), "{r:?}");
    }
    assert!(
        log.contains("6 tracker(s)") && log.contains(" 0 lost, 0 duplicated, 0 out of order"),
        "the summary counts six trackers and no loss:\n{log}"
    );

    let frames: Vec<RawImuFrame> = mcap_messages(&sb.path("slimevr.mcap"))
        .iter()
        .filter(|m| m.0 == "source.raw")
        .map(|m| frame_from_bytes(&m.2).expect("a RawImuFrame"))
        .collect();
    let seqs: Vec<u64> = frames.iter().map(|f| f.header.seq).collect();
    assert_eq!(seqs, (0..frames.len() as u64).collect::<Vec<_>>());
    for site in 0..NUM_IMUS {
        let bit = 1u32 << site;
        let rotations: Vec<[f32; 4]> = frames
            .iter()
            .filter(|f| f.orientation_mask & bit != 0)
            .map(|f| f.orientation_wxyz[site])
            .collect();
        let sent: Vec<[f32; 4]> = (0..TICKS)
            .map(|k| {
                let [x, y, z, w] = motion::sample(site, k, RATE_HZ).0;
                [w, x, y, z]
            })
            .collect();
        assert!(
            rotations == sent,
            "site {site}: the rotations arrive exactly"
        );
        let forces: Vec<[f32; 3]> = frames
            .iter()
            .filter(|f| f.valid_mask & bit != 0)
            .map(|f| f.accelerometer_mps2[site])
            .collect();
        assert_eq!(forces.len(), TICKS as usize, "site {site}");
        for (k, f) in forces.iter().enumerate() {
            let e = specific_force(site, k as u64);
            let err = (0..3)
                .map(|i| (f64::from(f[i]) - e[i]).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-4, "site {site} tick {k}: {f:?} vs {e:?}");
        }
    }
    // Samples of several sites share frames; each site's sample time is its arrival, the
    // frame's capture time the earliest of them.
    assert!(
        frames.len() < NUM_IMUS * TICKS as usize,
        "{} frames",
        frames.len()
    );
    for f in &frames {
        let times: Vec<u64> = (0..NUM_IMUS)
            .filter(|i| (f.valid_mask | f.orientation_mask) & (1 << i) != 0)
            .map(|i| f.sample_time_ns[i])
            .collect();
        assert_eq!(times.iter().min(), Some(&f.header.capture_ns));
        assert_eq!(f.header.flags, 0);
    }
    assert_clean(&sb);
}

/// `R_ITᵀ·(a_I + g·e_z)` from rotation matrices: `R_IT = R_z(heading)·R(axis, rate·t)`.
fn specific_force(index: usize, tick: u64) -> [f64; 3] {
    let t = tick as f64 / RATE_HZ;
    let rz = rodrigues([0.0, 0.0, 1.0], motion::heading_rad(index));
    let ra = rodrigues(motion::axis(index), motion::rate_radps(index) * t);
    let r: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| rz[i][k] * ra[k][j]).sum()));
    let mut a = motion::acceleration_inertial(index, t);
    a[2] += FIRMWARE_GRAVITY_MPS2;
    std::array::from_fn(|j| (0..3).map(|i| r[i][j] * a[i]).sum())
}

/// Row-major rotation about unit `axis` by `angle`.
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
