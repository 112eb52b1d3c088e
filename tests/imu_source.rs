//! The imu-source stage in real multi-process graphs: synthesize from a BVH, replay a recording,
//! receive UDP packets, and named errors, with no shared-memory leftovers after any of them.

mod common;

use std::path::{Path, PathBuf};

use common::{Sandbox, assert_clean, free_udp_port, mcap_messages, text};
use imuflow_graph::frames::{FrameHeader, ImuFrame, MotionFrame, flags, frame_from_bytes};
use imuflow_imu_source::udp;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("libs/motion/tests/fixtures/bandai-walk-normal-trimmed.bvh")
}

/// Frames at 60 Hz over the fixture's duration, from its header (independent of the body crate):
/// every output time k/60 within [0, (frames − 1)·frame_time], allowing for the rounded frame time.
fn expected_frames_at_60_hz(bvh: &Path) -> usize {
    let text = std::fs::read_to_string(bvh).expect("fixture");
    let value = |key: &str| -> f64 {
        text.lines()
            .find_map(|l| l.trim().strip_prefix(key))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("fixture has '{key}'"))
    };
    let (frames, frame_time) = (value("Frames:"), value("Frame Time:"));
    let duration = (frames - 1.0) * frame_time;
    let mut n = 0;
    while (n as f64) / 60.0 <= duration + 1e-3 / 60.0 {
        n += 1;
    }
    n
}

fn synth_graph(sb: &Sandbox, out: &str) -> PathBuf {
    sb.graph(
        "synth.toml",
        &format!(
            r#"
name = "synth-test"
[stages.source]
kind = "imu-source"
params = {{ mode = "synthesize", path = "{}" }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "source.imu", truth = "source.truth" }}
params = {{ path = "{{dir}}/{out}" }}
"#,
            fixture().display()
        ),
    )
}

/// A graph replaying `{dir}/a.mcap` into `{dir}/b.mcap`, under the graph-level keys `head`.
fn replay_graph(sb: &Sandbox, head: &str) -> PathBuf {
    let stages = r#"
[stages.player]
kind = "imu-source"
params = { mode = "replay", path = "{dir}/a.mcap" }
[stages.record]
kind = "recorder"
inputs = { imu = "player.imu", truth = "player.truth" }
params = { path = "{dir}/b.mcap" }
"#;
    sb.graph("replay.toml", &format!("{head}\n{stages}"))
}

fn run_ok(sb: &Sandbox, graph: &Path) {
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
}

fn frames_of(messages: &[(String, u32, Vec<u8>)], topic: &str) -> Vec<Vec<u8>> {
    messages
        .iter()
        .filter(|m| m.0 == topic)
        .map(|m| m.2.clone())
        .collect()
}

#[test]
fn synthesize_publishes_the_resampled_motion_and_its_truth() {
    let sb = Sandbox::new("synth");
    let graph = synth_graph(&sb, "a.mcap");
    run_ok(&sb, &graph);
    let messages = mcap_messages(&sb.path("a.mcap"));
    let imu = frames_of(&messages, "source.imu");
    let truth = frames_of(&messages, "source.truth");
    let expected = expected_frames_at_60_hz(&fixture());
    assert_eq!(expected, 95, "48 frames at 30 Hz span 1.567 s");
    assert_eq!(imu.len(), expected);
    assert_eq!(truth.len(), expected);
    for (i, (raw, raw_truth)) in imu.iter().zip(&truth).enumerate() {
        let f: ImuFrame = frame_from_bytes(raw).expect("one ImuFrame");
        let t: MotionFrame = frame_from_bytes(raw_truth).expect("one MotionFrame");
        assert_eq!(f.header.seq, i as u64);
        assert_eq!(t.header.seq, f.header.seq);
        assert_eq!(t.header.capture_ns, f.header.capture_ns);
        assert_eq!(f.header.capture_ns, (i as f64 * 1e9 / 60.0) as u64);
        assert_eq!(f.valid_mask, 0b11_1111, "frame {i}");
        assert!(!f.header.has(flags::INVALID), "frame {i}");
        for s in 0..6 {
            let q = f.orientation_wxyz[s];
            let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!(
                (norm - 1.0).abs() < 1e-4,
                "frame {i} sensor {s}: |q| = {norm}"
            );
            // Walking: gravity's reaction plus at most a few g of body acceleration.
            let a = f.specific_force_mps2[s];
            let mag = a.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!(
                (2.0..60.0).contains(&mag),
                "frame {i} sensor {s}: |f| = {mag} m/s²"
            );
            assert!(f.angular_rate_radps[s].iter().all(|w| w.abs() < 30.0));
        }
        for q in t.local_pose_wxyz {
            let norm = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-4, "truth frame {i}: |q| = {norm}");
        }
        // A walking pelvis is around a metre above the floor.
        assert!(
            (0.5..1.5).contains(&t.root_position_m[1]),
            "{:?}",
            t.root_position_m
        );
        assert!(t.tau.iter().all(|&v| v == 0.0), "physics fields stay zero");
    }
    // Mean specific force over the clip is close to gravity.
    let mean: f32 = imu
        .iter()
        .map(|raw| {
            let f: ImuFrame = frame_from_bytes(raw).expect("one ImuFrame");
            let a = f.specific_force_mps2[5];
            a.iter().map(|v| v * v).sum::<f32>().sqrt()
        })
        .sum::<f32>()
        / imu.len() as f32;
    assert!((8.0..12.0).contains(&mean), "pelvis mean |f| = {mean}");
    assert_clean(&sb);
}

#[test]
fn replay_republishes_a_recording_byte_for_byte() {
    let sb = Sandbox::new("replay");
    let graph = synth_graph(&sb, "a.mcap");
    run_ok(&sb, &graph);
    let replay = replay_graph(&sb, "name = \"replay-test\"");
    run_ok(&sb, &replay);
    let a = mcap_messages(&sb.path("a.mcap"));
    let b = mcap_messages(&sb.path("b.mcap"));
    let strip = |frames: Vec<Vec<u8>>| -> Vec<Vec<u8>> {
        frames
            .into_iter()
            .map(|mut bytes| {
                // publish_ns is stamped anew; every other byte must match.
                let at = std::mem::offset_of!(FrameHeader, publish_ns);
                bytes[at..at + 8].fill(0);
                bytes
            })
            .collect()
    };
    let (imu_a, imu_b) = (
        strip(frames_of(&a, "source.imu")),
        strip(frames_of(&b, "player.imu")),
    );
    assert_eq!(imu_a.len(), 95);
    assert!(
        imu_a == imu_b,
        "replayed ImuFrames differ from the recording"
    );
    let (truth_a, truth_b) = (
        strip(frames_of(&a, "source.truth")),
        strip(frames_of(&b, "player.truth")),
    );
    assert_eq!(truth_a.len(), 95);
    assert!(
        truth_a == truth_b,
        "replayed truth differs from the recording"
    );

    // `frames = 40`: the first 40 samples, each with its truth, nothing after them.
    let limited = sb.graph(
        "limited.toml",
        &std::fs::read_to_string(&replay)
            .expect("graph")
            .replace("/a.mcap\" }", "/a.mcap\", frames = 40 }")
            .replace("b.mcap", "c.mcap"),
    );
    run_ok(&sb, &limited);
    let c = mcap_messages(&sb.path("c.mcap"));
    let (imu_c, truth_c) = (
        strip(frames_of(&c, "player.imu")),
        strip(frames_of(&c, "player.truth")),
    );
    assert_eq!(imu_c.as_slice(), &imu_a[..40]);
    assert_eq!(truth_c.as_slice(), &truth_a[..40]);
    assert_clean(&sb);
}

#[test]
fn missing_bvh_fails_naming_the_stage_and_the_path() {
    let sb = Sandbox::new("synth-missing");
    let graph = sb.graph(
        "missing.toml",
        r#"
name = "missing-bvh"
[stages.motion]
kind = "imu-source"
params = { mode = "synthesize", path = "{dir}/no-such-walk.bvh" }
[stages.record]
kind = "recorder"
inputs = { imu = "motion.imu" }
params = { path = "{dir}/out.mcap" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr:\n{stderr}");
    assert!(stderr.contains("motion"), "names the stage:\n{stderr}");
    assert!(
        stderr.contains("no-such-walk.bvh"),
        "names the path:\n{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_clean(&sb);
}

#[test]
fn replay_of_a_non_mcap_file_fails_with_a_named_error() {
    let sb = Sandbox::new("replay-bad");
    std::fs::copy(fixture(), sb.path("walk.mcap")).expect("copy");
    let graph = sb.graph(
        "bad.toml",
        r#"
name = "replay-bad"
[stages.player]
kind = "imu-source"
params = { mode = "replay", path = "{dir}/walk.mcap" }
[stages.record]
kind = "recorder"
inputs = { imu = "player.imu" }
params = { path = "{dir}/out.mcap" }
"#,
    );
    let out = sb.run(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr:\n{stderr}");
    assert!(stderr.contains("player"), "names the stage:\n{stderr}");
    assert!(stderr.contains("walk.mcap"), "names the path:\n{stderr}");
    assert!(stderr.contains("not an mcap file"), "says why:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_clean(&sb);
}

#[test]
fn udp_packets_become_frames_with_invalid_sensors_marked() {
    // The six-site set: its six slots.
    udp_packets_of_a_set("six", 6, 0b11_1111);
}

#[test]
fn udp_packets_of_a_lower_body_set_fill_its_slots() {
    // Pelvis, upper and lower legs: slots 2, 3, 5, 6, 7, five sensors a packet.
    udp_packets_of_a_set("lower-body", 5, 1 << 2 | 1 << 3 | 1 << 5 | 1 << 6 | 1 << 7);
}

/// A udp source of the sensor set `sensors` receives 60 packets of `count` sensors (every 10th
/// with a NaN, every 7th with its second sensor not valid): frames whose valid mask is `slots`
/// unless a sensor was not valid, and then flagged INVALID.
fn udp_packets_of_a_set(sensors: &str, count: usize, slots: u32) {
    let sb = Sandbox::new(&format!("udp-{sensors}"));
    let port = free_udp_port();
    let graph = sb.graph(
        "udp.toml",
        &format!(
            r#"
name = "udp-test"
sensors = "{sensors}"
[stages.sensors]
kind = "imu-source"
params = {{ mode = "udp", bind = "127.0.0.1:{port}", timeout_ms = 1500, frames = 60 }}
[stages.record]
kind = "recorder"
inputs = {{ imu = "sensors.imu" }}
params = {{ path = "{{dir}}/udp.mcap" }}
"#
        ),
    );
    let child = sb.spawn(&["run", graph.to_str().expect("utf8"), "--no-progress"]);
    // Send at 200 Hz until the run is over (the stage may start listening after the first ones).
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sender = {
        let done = done.clone();
        std::thread::spawn(move || {
            let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("sender socket");
            let mut seq = 0;
            while !done.load(std::sync::atomic::Ordering::Relaxed) && seq < 12_000 {
                let packet = udp::synthetic_packet(seq, 200.0, 10, 7, count);
                let _ = socket.send_to(&packet.encode(), ("127.0.0.1", port));
                seq += 1;
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
        })
    };
    let out = child.wait_with_output().expect("imuflow finishes");
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    sender.join().expect("sender thread");
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    let messages = mcap_messages(&sb.path("udp.mcap"));
    let frames: Vec<ImuFrame> = frames_of(&messages, "sensors.imu")
        .iter()
        .map(|raw| frame_from_bytes(raw).expect("one ImuFrame"))
        .collect();
    assert_eq!(frames.len(), 60);
    let mut invalid = 0;
    for f in &frames {
        assert_eq!(f.valid_mask & !slots, 0, "a slot outside the set");
        let bad = f.valid_mask != slots;
        assert_eq!(f.header.has(flags::INVALID), bad);
        invalid += usize::from(bad);
        assert!(f.header.capture_ns > 0);
    }
    assert!(
        invalid > 0,
        "every 10th packet has a NaN, every 7th a missing sensor"
    );
    assert_clean(&sb);
}

#[test]
fn imuflow_run_without_a_graph_replays_the_bundled_sample() {
    let sb = Sandbox::new("bundled-sample");
    let rec = sb.path("sample.mcap");
    let rrd = sb.path("sample.rrd");
    let out = sb
        .command(&[
            "run",
            "--no-progress",
            "--set",
            &format!("stages.record.params.path={}", rec.display()),
            "--set",
            &format!("stages.viz.params.path={}", rrd.display()),
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run imuflow");
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("graph 'sample' finished"),
        "{}",
        text(&out.stdout)
    );
    let messages = mcap_messages(&rec);
    let imu: Vec<_> = messages.iter().filter(|m| m.0 == "source.imu").collect();
    let truth: Vec<MotionFrame> = messages
        .iter()
        .filter(|m| m.0 == "source.truth")
        .map(|m| frame_from_bytes(&m.2).expect("MotionFrame"))
        .collect();
    let motion: Vec<MotionFrame> = messages
        .iter()
        .filter(|m| m.0 == "opt.motion")
        .map(|m| frame_from_bytes(&m.2).expect("MotionFrame"))
        .collect();
    // models/sample/README.md: 1511 frames (25.2 s at 60 Hz) with the true pose beside each.
    assert_eq!(imu.len(), 1511);
    assert_eq!(truth.len(), 1511);
    assert_eq!(motion.len(), 1511);
    let last: ImuFrame = frame_from_bytes(&imu[1510].2).expect("ImuFrame");
    assert_eq!(last.header.seq, 1510);
    assert_eq!(last.header.capture_ns, (1510.0_f64 * 1e9 / 60.0) as u64);
    // The whole pipeline ran: calibration ended inside the prelude (12.2 s), and from then on the
    // physics stands the subject on the floor (root height near the truth's) and carries its weight.
    let calibrated: Vec<&MotionFrame> = motion
        .iter()
        .filter(|m| !m.header.has(flags::CALIBRATING))
        .collect();
    assert!(
        calibrated.len() > 900 && calibrated.len() < 1300,
        "{} calibrated frames",
        calibrated.len()
    );
    let first = 1511 - calibrated.len();
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
        sum / n as f64
    };
    let root_height = mean(&mut calibrated.iter().map(|m| f64::from(m.root_position_m[1])));
    let true_height = mean(
        &mut truth[first..]
            .iter()
            .map(|m| f64::from(m.root_position_m[1])),
    );
    assert!(
        (root_height - true_height).abs() < 0.1,
        "root height {root_height} vs truth {true_height}"
    );
    let weight_share = mean(&mut calibrated.iter().map(|m| {
        let fy: f32 = m.ground_reaction_force_n.iter().map(|f| f[1]).sum();
        f64::from(fy) / (70.0 * 9.81)
    }));
    assert!(
        (0.8..1.2).contains(&weight_share),
        "mean vertical ground force {weight_share} × body weight"
    );
    assert!(std::fs::metadata(&rrd).map(|m| m.len()).unwrap_or(0) > 10_000);
    assert_clean(&sb);
}

/// A live replay is a live source: capture times on the Unix epoch (the instant each sample is
/// due, its recorded spacing kept, IMU and truth of one sample alike), so the run's summary
/// reports every sink input's latency from capture.
#[test]
fn a_live_replay_stamps_capture_on_the_epoch_and_the_summary_reports_latency_from_capture() {
    let sb = Sandbox::new("live-replay");
    let graph = synth_graph(&sb, "a.mcap");
    run_ok(&sb, &graph);
    let replay = replay_graph(&sb, "name = \"live-replay-test\"\nmode = \"live\"");
    let before = now_ns();
    let out = sb.run(&["run", replay.to_str().expect("utf8"), "--no-progress"]);
    let after = now_ns();
    assert!(out.status.success(), "stderr:\n{}", text(&out.stderr));

    let header = |bytes: &Vec<u8>| frame_from_bytes::<ImuFrame>(bytes).expect("imu").header;
    let a = mcap_messages(&sb.path("a.mcap"));
    let b = mcap_messages(&sb.path("b.mcap"));
    let recorded: Vec<FrameHeader> = frames_of(&a, "source.imu").iter().map(header).collect();
    let live: Vec<FrameHeader> = frames_of(&b, "player.imu").iter().map(header).collect();
    // A live graph may drop a frame under load; what arrived is compared by seq.
    assert!(
        live.len() * 10 >= recorded.len() * 9,
        "{}",
        text(&out.stdout)
    );
    let first = live[0];
    for l in &live {
        let r = recorded[l.seq as usize];
        assert!(
            (before..=after).contains(&l.capture_ns),
            "seq {}: capture {} not within the run",
            l.seq,
            l.capture_ns
        );
        // The recorded spacing, shifted onto the epoch.
        assert_eq!(
            l.capture_ns - first.capture_ns,
            r.capture_ns - recorded[first.seq as usize].capture_ns
        );
    }
    let imu_capture: std::collections::BTreeMap<u64, u64> =
        live.iter().map(|h| (h.seq, h.capture_ns)).collect();
    for bytes in frames_of(&b, "player.truth") {
        let h = frame_from_bytes::<MotionFrame>(&bytes)
            .expect("truth")
            .header;
        if let Some(capture) = imu_capture.get(&h.seq) {
            assert_eq!(h.capture_ns, *capture, "truth of seq {}", h.seq);
        }
    }

    let summary = text(&out.stdout);
    assert!(summary.contains("end to end (capture→sink)"), "{summary}");
    let row = summary
        .lines()
        .find(|l| l.starts_with("record.imu "))
        .unwrap_or_else(|| panic!("no record.imu row:\n{summary}"));
    let cols: Vec<&str> = row.split_whitespace().collect();
    assert_eq!(cols[1], live.len().to_string(), "{row}");
    let p50_ms: f64 = cols[2].parse().expect("p50");
    assert!(p50_ms > 0.0 && p50_ms < 1000.0, "{row}");
}

fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock")
        .as_nanos() as u64
}
