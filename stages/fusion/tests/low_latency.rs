//! `latency = "low"` with trackers that fuse on board (SlimeVR): six sensors at 100 Hz, each on
//! its own phase, turning at a known, changing rate (peak 6 rad/s, about what a forearm swings
//! at), no gyroscope (the rate is derived from the orientations), delivered 0.1 ms after their
//! sample time. Frames must go out as soon as a sample from half an interval before their time on
//! has arrived, close to the true orientation at their time; a stall's backlog must be dated
//! back, not bunched.

mod common;

use imuflow_body::NUM_IMUS;
use imuflow_fusion::assembler::{Assembler, Origin, Settings};
use imuflow_fusion::quat::{Quat, angle_between, from_rotation_vector};
use imuflow_fusion::sensor::Latency;
use imuflow_graph::frames::{ImuFrame, MAX_SITES, RawImuFrame, flags};

const RATE_HZ: f64 = 100.0;
const T0_NS: u64 = 1_700_000_000_000_000_000;
const DELIVERY_NS: u64 = 100_000;
const PEAK_RADPS: f64 = 6.0;

fn low() -> Settings {
    let mut s = common::settings(Origin::FirstCapture);
    s.sensor.latency = Latency::Low;
    s
}

/// Sensor `i`'s turn about its own axis at time `t` s: the rate is PEAK·sin(2π·1.5·t), so the
/// angle is its integral.
fn angle(t: f64) -> f64 {
    let w = 2.0 * std::f64::consts::PI * 1.5;
    PEAK_RADPS * (1.0 - (w * t).cos()) / w
}

fn axis(i: usize) -> [f64; 3] {
    let k = i as f64;
    let v = [k.cos(), k.sin(), 0.5];
    let n = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    v.map(|c| c / n)
}

fn truth(i: usize, t: f64) -> Quat {
    from_rotation_vector(&axis(i).map(|c| c * angle(t)))
}

/// Sample `n` of sensor `i`: its time (each sensor on its own phase within the 10 ms tick).
fn sample_s(i: usize, n: u64) -> f64 {
    n as f64 / RATE_HZ + i as f64 * 1.6e-3
}

/// One raw frame holding sample `n` of sensor `i`, sent at its sample time, captured at `arrival`.
fn raw(i: usize, n: u64, arrival_ns: u64) -> RawImuFrame {
    let t = sample_s(i, n);
    let q = truth(i, t);
    let mut f = RawImuFrame::default();
    f.header.capture_ns = arrival_ns;
    f.sample_time_ns[i] = T0_NS + (t * 1e9).round() as u64;
    f.orientation_wxyz[i] = q.map(|c| c as f32);
    f.accelerometer_mps2[i] = [0.0, 0.0, 9.81];
    f.valid_mask = 1 << i;
    f.orientation_mask = 1 << i;
    f.no_gyroscope_mask = 1 << i;
    f
}

/// Every sample of `seconds`, in arrival order: (sensor, sample, arrival ns).
fn deliveries(seconds: f64, arrival: impl Fn(usize, u64, u64) -> u64) -> Vec<(usize, u64, u64)> {
    let n = (seconds * RATE_HZ) as u64;
    let mut all: Vec<(usize, u64, u64)> = (0..n)
        .flat_map(|k| (0..NUM_IMUS).map(move |i| (i, k)))
        .map(|(i, k)| {
            let sent = T0_NS + (sample_s(i, k) * 1e9).round() as u64;
            (i, k, arrival(i, k, sent))
        })
        .collect();
    all.sort_by_key(|d| (d.2, d.0, d.1));
    all
}

/// Pushes the deliveries one by one; per output frame, the arrival of the raw frame after which
/// it went out.
fn run(settings: Settings, deliveries: &[(usize, u64, u64)]) -> (Assembler, Vec<(ImuFrame, u64)>) {
    let mut assembler = Assembler::new(settings);
    let mut out = Vec::new();
    let mut emitted = Vec::new();
    for &(i, k, arrival) in deliveries {
        assembler.push(&raw(i, k, arrival), &mut out).unwrap();
        emitted.extend(out.drain(..).map(|f| (f, arrival)));
    }
    (assembler, emitted)
}

/// Degrees between each frame's orientation of sensor `i` and the truth at the frame's time.
fn errors_deg(frames: &[(ImuFrame, u64)], i: usize) -> Vec<f64> {
    frames
        .iter()
        .filter(|(f, _)| f.valid_mask & (1 << i) != 0)
        .map(|(f, _)| {
            let t = (f.header.capture_ns - T0_NS) as f64 * 1e-9;
            angle_between(&f.orientation_wxyz[i].map(f64::from), &truth(i, t)).to_degrees()
        })
        .collect()
}

fn p99(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[(v.len() * 99).div_ceil(100) - 1]
}

#[test]
fn each_frame_goes_out_with_the_first_sample_near_its_time_and_sensors_behind_are_extrapolated() {
    let d = deliveries(4.0, |_, _, sent| sent + DELIVERY_NS);
    let (assembler, frames) = run(low(), &d);
    // After the 8 samples that measure each sensor's rate, every frame is complete.
    let settled: Vec<&(ImuFrame, u64)> =
        frames.iter().filter(|(f, _)| f.header.seq >= 12).collect();
    assert!(settled.len() > 220, "{}", settled.len());
    for (f, released_at) in &settled {
        assert_eq!(f.valid_mask, (1 << NUM_IMUS) - 1, "frame {}", f.header.seq);
        assert!(!f.header.has(flags::DEGRADED) && !f.header.has(flags::INVALID));
        // Out with the first delivery from half an interval (5 ms) before its time on: at most
        // one sensor's phase step (1.6 ms) plus the delivery after that.
        let wait = *released_at as i64 - f.header.capture_ns as i64;
        assert!(
            (-5_000_000..=-5_000_000 + 1_600_000 + DELIVERY_NS as i64).contains(&wait),
            "frame {}: {wait} ns",
            f.header.seq
        );
    }
    let settled: Vec<(ImuFrame, u64)> = settled.into_iter().copied().collect();
    // Extrapolated at the derived rate (up to one interval plus the half interval a frame may lie
    // after every sample), the sensors lie within a degree of where they truly are; held, they
    // would lag by up to a sample interval at 6 rad/s (3.4°).
    for i in 0..NUM_IMUS {
        let extrapolated = p99(errors_deg(&settled, i));
        // Held instead: the newest sample at or before the frame's time, as it was.
        let held = p99(settled
            .iter()
            .map(|(f, _)| {
                let t = (f.header.capture_ns - T0_NS) as f64 * 1e-9;
                let newest = sample_s(i, ((t - sample_s(i, 0)) * RATE_HZ + 1e-9).floor() as u64);
                angle_between(&truth(i, newest), &truth(i, t)).to_degrees()
            })
            .collect());
        println!("sensor {i}: p99 {extrapolated:.3}° extrapolated, {held:.3}° held");
        assert!(extrapolated < 1.0, "sensor {i}: p99 {extrapolated:.3}°");
        assert!(
            extrapolated < held / 2.0,
            "sensor {i}: {extrapolated:.3}° vs {held:.3}°"
        );
    }
    let c = assembler.counters();
    assert_eq!(c.sensor_late, [0; MAX_SITES]);
    assert_eq!(c.sensor_stale, [0; MAX_SITES]);
    for i in 0..NUM_IMUS {
        assert_eq!(assembler.sensor_counters(i).lost, 0);
    }
}

#[test]
fn a_stall_of_every_tracker_is_dated_back_and_nothing_is_lost_late_or_bunched() {
    // From 2.0 s every sample is held back until 2.1 s; then the trackers' backlogs arrive one
    // tracker after the other (as each one's link recovers), 60 samples within 90 µs, before
    // the samples sent after them. The first backlog must not release the stalled frames before
    // the others have come.
    let stall = (2.0, 2.1);
    let d = deliveries(4.0, |i, k, sent| {
        let t = (sent - T0_NS) as f64 * 1e-9;
        if (stall.0..stall.1).contains(&t) {
            T0_NS + (stall.1 * 1e9) as u64 + (i as u64 * 15 + k % 10) * 1000
        } else {
            sent + DELIVERY_NS
        }
    });
    let (assembler, frames) = run(low(), &d);
    let seqs: Vec<u64> = frames.iter().map(|(f, _)| f.header.seq).collect();
    assert_eq!(
        seqs,
        (0..seqs.len() as u64).collect::<Vec<_>>(),
        "every frame, in order"
    );
    let settled: Vec<(ImuFrame, u64)> = frames
        .into_iter()
        .filter(|(f, _)| f.header.seq >= 12)
        .collect();
    for (f, _) in &settled {
        assert_eq!(f.valid_mask, (1 << NUM_IMUS) - 1, "frame {}", f.header.seq);
        assert!(!f.header.has(flags::DEGRADED), "frame {}", f.header.seq);
        // The rate derived across the backlog stays the motion's (its samples are 10 ms apart in
        // their times, not 20 µs in their arrivals).
        for w in f.angular_rate_radps {
            let norm = w.iter().map(|c| f64::from(*c).powi(2)).sum::<f64>().sqrt();
            assert!(
                norm < 1.05 * PEAK_RADPS,
                "frame {}: {norm} rad/s",
                f.header.seq
            );
        }
    }
    for i in 0..NUM_IMUS {
        let p = p99(errors_deg(&settled, i));
        assert!(p < 1.0, "sensor {i}: p99 {p:.3}°");
        assert_eq!(assembler.sensor_counters(i).lost, 0);
    }
    assert_eq!(assembler.counters().sensor_late, [0; MAX_SITES]);
}

#[test]
fn one_stalled_tracker_is_held_stale_and_its_backlog_late() {
    // Sensor 2 alone stalls 100 ms; the others go on.
    let stall = (2.0, 2.1);
    let d = deliveries(4.0, |i, _, sent| {
        let t = (sent - T0_NS) as f64 * 1e-9;
        if i == 2 && (stall.0..stall.1).contains(&t) {
            T0_NS + (stall.1 * 1e9) as u64
        } else {
            sent + DELIVERY_NS
        }
    });
    let (assembler, frames) = run(low(), &d);
    let c = assembler.counters();
    // Its last sample before the stall is at 1.9932 s; the frames at 2.0000, 2.0167, ... 2.0833 s
    // lie 6.8, 23.5, 40.1, 56.8, 73.5 and 90.1 ms after it: extrapolated, then stale (over two
    // intervals: held, the frame DEGRADED) five times, never missing (a tracker that sends only its
    // orientation is held up to ORIENTATION_ONLY_HOLD_S); the frame at 2.1 s waits for the
    // backlog, which comes at 2.1 s.
    let invalid_after_start = frames
        .iter()
        .filter(|(f, _)| f.header.seq >= 12 && f.valid_mask & (1 << 2) == 0)
        .count();
    assert_eq!((c.sensor_stale[2], invalid_after_start), (5, 0), "{c:?}");
    assert_eq!(c.degraded, 5);
    let others: u64 = (0..NUM_IMUS)
        .filter(|&i| i != 2)
        .map(|i| c.sensor_stale[i] + c.sensor_late[i])
        .sum();
    assert_eq!(others, 0);
    // Its backlog: the samples more than one interval before the newest frame when they came.
    assert!((6..=10).contains(&c.sensor_late[2]), "{}", c.sensor_late[2]);
    assert_eq!(assembler.sensor_counters(2).lost, 0, "late is not lost");
    assert!(
        frames
            .iter()
            .all(|(f, _)| f.header.seq < 12 || f.valid_mask & !(1 << 2) == 0b111011)
    );
}

#[test]
fn a_tracker_at_rest_that_falls_silent_is_held_then_missing_and_nobody_waits_for_it() {
    // Sensor 3 sends nothing from 2.0 s to 3.5 s (a SlimeVR tracker at rest sends a rotation only
    // when it changed), the others go on.
    let d: Vec<(usize, u64, u64)> = deliveries(4.0, |_, _, sent| sent + DELIVERY_NS)
        .into_iter()
        .filter(|&(i, k, _)| !(i == 3 && (200..350).contains(&k)))
        .collect();
    let (assembler, frames) = run(low(), &d);
    let c = assembler.counters();
    let silent = |f: &ImuFrame| {
        let t = (f.header.capture_ns - T0_NS) as f64 * 1e-9;
        (2.0..3.5).contains(&t)
    };
    // Held for ORIENTATION_ONLY_HOLD_S after its last sample (1.9948 s), stale (DEGRADED) from two
    // intervals on; missing (INVALID) after that, until it sends again.
    let held = frames
        .iter()
        .filter(|(f, _)| silent(f) && f.valid_mask & (1 << 3) != 0)
        .count();
    let missing = frames
        .iter()
        .filter(|(f, _)| silent(f) && f.valid_mask & (1 << 3) == 0)
        .count();
    assert_eq!((held, missing), (60, 30), "{c:?}");
    assert_eq!(c.sensor_stale[3] as usize, held - 1, "{c:?}");
    // Nobody waits for it past its first 150 ms: every frame after that goes out with the first
    // sample from half an interval before its time on.
    for (f, released_at) in frames.iter().filter(|(f, _)| {
        let t = (f.header.capture_ns - T0_NS) as f64 * 1e-9;
        (2.2..3.5).contains(&t)
    }) {
        let wait = *released_at as i64 - f.header.capture_ns as i64;
        assert!(wait <= 2_000_000, "frame {}: {wait} ns", f.header.seq);
    }
}
