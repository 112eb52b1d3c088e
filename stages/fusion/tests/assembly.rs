//! The output grid without processes: numbering, origin, PRELUDE, empty stretches, on-board
//! orientations, refused input and the parameters that change what is fused.

mod common;

use common::settings;
use imuflow_fusion::FusionError;
use imuflow_fusion::assembler::{Assembler, Origin, Settings};
use imuflow_fusion::quat::angle_between;
use imuflow_fusion::sensor::{MagnetometerUse, OrientationSource};
use imuflow_graph::frames::{ImuFrame, RawImuFrame, flags};

const ALL: u32 = 0b111111;

/// Six sensors at rest (z up) sampled together at 100 Hz from source time `start_s` for
/// `duration_s`, on sensor clocks 5 s behind the source, delivered 1 ms later; `edit` changes
/// each frame (given its true time).
fn frames(start_s: f64, duration_s: f64, edit: impl Fn(&mut RawImuFrame, f64)) -> Vec<RawImuFrame> {
    let n = (duration_s * 100.0).round() as usize;
    (0..n)
        .map(|k| {
            let t = start_s + k as f64 / 100.0;
            let mut raw = RawImuFrame::default();
            raw.header.seq = k as u64;
            raw.header.capture_ns = ((t + 0.001) * 1e9).round() as u64;
            for i in 0..6 {
                raw.sample_time_ns[i] = ((t + 5.0) * 1e9).round() as u64;
                raw.accelerometer_mps2[i] = [0.0, 0.0, 9.81];
                raw.magnetometer_ut[i] = [0.0, 20.0, -40.0];
            }
            raw.valid_mask = ALL;
            raw.magnetometer_mask = ALL;
            edit(&mut raw, t);
            raw
        })
        .collect()
}

fn run(settings: Settings, raw: &[RawImuFrame]) -> (Assembler, Vec<ImuFrame>) {
    let mut assembler = Assembler::new(settings);
    let mut out = Vec::new();
    for frame in raw {
        assembler.push(frame, &mut out).unwrap();
    }
    assembler.finish(&mut out).unwrap();
    (assembler, out)
}

fn numbered_from_zero(out: &[ImuFrame], origin_ns: u64) {
    for (k, f) in out.iter().enumerate() {
        assert_eq!(f.header.seq, k as u64);
        let t = origin_ns + (k as f64 * 1e9 / 60.0).round() as u64;
        assert_eq!(f.header.capture_ns, t, "frame {k}");
    }
}

#[test]
fn offline_frame_k_lies_at_k_over_rate_and_frames_before_the_first_sample_are_invalid() {
    // The sensors start 0.2 s into the recording.
    let (_, out) = run(settings(Origin::Zero), &frames(0.2, 2.0, |_, _| {}));
    numbered_from_zero(&out, 0);
    // Frames before the first sample have nothing; frames until each sensor's rate is measured
    // (9 samples: 80 ms) wait max_latency_ms and go out INVALID; then all valid: the first at
    // 0.25 s, whose deadline falls after the ninth sample (0.28 s).
    let first_valid = out.iter().position(|f| f.valid_mask == ALL).unwrap();
    let t_first = first_valid as f64 / 60.0;
    assert!((0.24..0.26).contains(&t_first), "{t_first}");
    for f in &out[..first_valid] {
        assert!(f.header.has(flags::INVALID));
        assert_eq!(f.valid_mask, 0);
        assert_eq!(f.orientation_wxyz[..6], [[1.0, 0.0, 0.0, 0.0]; 6]);
        assert_eq!(f.specific_force_mps2[..6], [[0.0; 3]; 6]);
    }
    assert!(
        out[first_valid..]
            .iter()
            .all(|f| f.valid_mask == ALL && f.header.flags == 0)
    );
    // At rest, z up, field north: the 9D orientation is the identity (ENU).
    let last = out.last().unwrap();
    for q in &last.orientation_wxyz[..6] {
        let q = q.map(f64::from);
        assert!(
            angle_between(&q, &[1.0, 0.0, 0.0, 0.0]).to_degrees() < 0.01,
            "{q:?}"
        );
    }
    assert!((last.specific_force_mps2[3][2] - 9.81).abs() < 1e-4);
    // To the newest sample (2.19 s, dated 1 ms later): the last frame is at 2.183 s.
    let last_t = (out.len() - 1) as f64 / 60.0;
    assert!((2.18..2.19).contains(&last_t), "{last_t}");
}

#[test]
fn a_given_sensor_rate_needs_no_start_up() {
    let mut s = settings(Origin::Zero);
    s.sensor.sensor_rate_hz = Some(100.0);
    let (assembler, out) = run(s, &frames(0.0, 1.0, |_, _| {}));
    // Frame 0 at t = 0: the first samples are dated 1 ms after it (the delivery delay is the
    // offset the clock fit sees), so only frame 0 has no sample before it.
    assert_eq!(out[0].valid_mask, 0);
    assert!(
        out[1..].iter().all(|f| f.valid_mask == ALL),
        "{:?}",
        out[1].valid_mask
    );
    assert_eq!(assembler.sensor(0).rate_hz(), Some(100.0));
}

#[test]
fn live_frame_0_is_at_the_first_capture_and_offline_far_captures_start_there_too() {
    let epoch = 1_700_000_000.0;
    let (_, out) = run(
        settings(Origin::FirstCapture),
        &frames(epoch, 1.0, |_, _| {}),
    );
    numbered_from_zero(&out, ((epoch + 0.001) * 1e9).round() as u64);
    assert!(out.len() > 50);
    let mut assembler = Assembler::new(settings(Origin::Zero));
    let mut out = Vec::new();
    for f in &frames(epoch, 1.0, |_, _| {}) {
        assembler.push(f, &mut out).unwrap();
    }
    numbered_from_zero(&out, ((epoch + 0.001) * 1e9).round() as u64);
    let notices = assembler.take_notices();
    assert!(
        notices.iter().any(|n| n.text.contains("not near 0")),
        "{notices:?}"
    );
}

#[test]
fn prelude_follows_the_raw_frames_at_each_output_time() {
    let raw = frames(0.0, 2.0, |f, t| {
        if t < 1.0 {
            f.header.flags |= flags::PRELUDE;
        }
    });
    let (_, out) = run(settings(Origin::Zero), &raw);
    // Frame k is PRELUDE when it lies before the first sample without PRELUDE (1.0 s), as the
    // synthesizing source flags its truth frames.
    for f in &out {
        let t = f.header.capture_ns as f64 * 1e-9;
        assert_eq!(f.header.has(flags::PRELUDE), t < 1.0, "{t}");
    }
    let prelude = out.iter().filter(|f| f.header.has(flags::PRELUDE)).count();
    assert_eq!(prelude, 60);
}

#[test]
fn a_silent_stretch_gives_invalid_frames_in_order_and_none_skipped() {
    // Nothing at all from 1.0 s to 1.5 s (every sensor silent), then the sensors are back.
    let raw = frames(0.0, 2.5, |f, t| {
        if (1.0..1.5).contains(&t) {
            f.valid_mask = 0;
        }
    });
    let raw: Vec<RawImuFrame> = raw.into_iter().filter(|f| f.valid_mask != 0).collect();
    let (assembler, out) = run(settings(Origin::Zero), &raw);
    numbered_from_zero(&out, 0);
    for f in &out {
        let t = f.header.capture_ns as f64 * 1e-9;
        if (1.0..1.49).contains(&t) {
            assert_eq!(f.valid_mask, 0, "{t}");
            assert!(f.header.has(flags::INVALID));
        } else if (0.3..0.98).contains(&t) || (1.52..2.4).contains(&t) {
            assert_eq!(f.valid_mask, ALL, "{t}");
        }
    }
    let c = assembler.sensor_counters(0);
    assert_eq!((c.lost, c.long_gaps), (50, 1));
}

#[test]
fn on_board_orientations_are_used_in_auto_and_onboard_and_missing_ones_are_an_error() {
    let about_z = |a: f64| [(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()];
    let raw = frames(0.0, 1.5, |f, t| {
        for i in 0..6 {
            // Sensors 0..3 report on board, the orientation turning at 0.5 rad/s about z.
            if i < 3 {
                f.orientation_wxyz[i] = about_z(0.5 * t).map(|v| v as f32);
                f.orientation_mask |= 1 << i;
            }
        }
    });
    let (assembler, out) = run(settings(Origin::Zero), &raw);
    assert_eq!(assembler.sensor(0).source_name(), "on-board");
    assert_eq!(assembler.sensor(4).source_name(), "9D");
    for f in out.iter().filter(|f| f.valid_mask == ALL) {
        let t = f.header.capture_ns as f64 * 1e-9;
        // The sample dated 1 ms after its true time (the delivery delay is taken as offset).
        let q = f.orientation_wxyz[1].map(f64::from);
        assert!(angle_between(&q, &about_z(0.5 * (t - 0.001))) < 1e-5, "{t}");
    }
    // fuse: the on-board values are ignored.
    let mut fuse = settings(Origin::Zero);
    fuse.sensor.orientation = OrientationSource::Fuse;
    let (assembler, _) = run(fuse, &raw);
    assert_eq!(assembler.sensor(0).source_name(), "9D");
    // onboard: sensor 3 has none.
    let mut onboard = settings(Origin::Zero);
    onboard.sensor.orientation = OrientationSource::Onboard;
    onboard.sensor.sensor_rate_hz = Some(100.0);
    let mut assembler = Assembler::new(onboard);
    let err = assembler.push(&raw[0], &mut Vec::new()).unwrap_err();
    assert!(matches!(
        err,
        FusionError::NoOnboardOrientation { sensor: 3, .. }
    ));
    assert!(
        err.to_string().contains("sensor 3 (right_lower_leg)"),
        "{err}"
    );
    // auto: an on-board sensor's sample without its orientation is skipped and counted.
    let mut raw = raw;
    raw[50].orientation_mask &= !1;
    raw[51].orientation_wxyz[0] = [0.0; 4];
    let (assembler, _) = run(settings(Origin::Zero), &raw);
    let c = assembler.sensor_counters(0);
    assert_eq!((c.no_orientation, c.nonfinite, c.lost), (1, 1, 0));
}

#[test]
fn magnetometer_ignore_fuses_6d_and_non_finite_readings_are_skipped() {
    let mut s = settings(Origin::Zero);
    s.sensor.magnetometer = MagnetometerUse::Ignore;
    let (assembler, out) = run(s, &frames(0.0, 1.0, |_, _| {}));
    assert_eq!(assembler.sensor(0).source_name(), "6D");
    assert!(out.iter().skip(20).all(|f| f.valid_mask == ALL));
    let raw = frames(0.0, 1.0, |f, t| {
        if (0.5..0.52).contains(&t) {
            f.accelerometer_mps2[2][0] = f32::INFINITY;
            f.magnetometer_ut[4][1] = f32::NAN;
        }
    });
    let (assembler, out) = run(settings(Origin::Zero), &raw);
    assert_eq!(assembler.sensor_counters(2).nonfinite, 2);
    assert_eq!(assembler.sensor_counters(4).nonfinite_mag, 2);
    for f in &out {
        assert!(f.orientation_wxyz.iter().flatten().all(|v| v.is_finite()));
        assert!(
            f.specific_force_mps2
                .iter()
                .flatten()
                .all(|v| v.is_finite())
        );
    }
    assert!(out.iter().skip(20).all(|f| f.valid_mask == ALL));
}

#[test]
fn a_restarted_sensor_clock_and_a_corrupt_capture_time_are_survived_and_counted() {
    let mut raw = frames(0.0, 2.0, |f, t| {
        if t >= 1.0 {
            // Sensor 1 reboots at 1 s: its clock starts again at 0.
            f.sample_time_ns[1] = ((t - 1.0) * 1e9).round() as u64;
        }
    });
    raw[120].header.capture_ns = u64::MAX / 2;
    let (assembler, out) = run(settings(Origin::Zero), &raw);
    numbered_from_zero(&out, 0);
    assert_eq!(assembler.counters().refused_raw, 1);
    assert_eq!(assembler.sensor_counters(1).clock_resets, 1);
    // The clock fit starts again, the rate and filter are kept: back after a frame or two.
    let missing = out
        .iter()
        .filter(|f| f.header.capture_ns > 500_000_000 && f.valid_mask & 0b10 == 0)
        .count();
    assert!(missing <= 2, "{missing}");
    assert!(out.len() > 110);
}

#[test]
fn without_a_gyroscope_the_rate_comes_from_the_on_board_orientations() {
    // A tracker turning at 0.8 rad/s about its own tilted axis, sending orientations but no rate.
    let axis = [0.0, 0.6, 0.8];
    let turn = |a: f64| {
        let (s, c) = ((a / 2.0).sin(), (a / 2.0).cos());
        [c, axis[0] * s, axis[1] * s, axis[2] * s]
    };
    let raw = frames(0.0, 2.0, |f, t| {
        for i in 0..6 {
            f.orientation_wxyz[i] = turn(0.8 * t).map(|v| v as f32);
            f.orientation_mask |= 1 << i;
            f.gyroscope_radps[i] = [0.0; 3];
        }
        f.no_gyroscope_mask = ALL;
    });
    let (assembler, out) = run(settings(Origin::Zero), &raw);
    let valid: Vec<&ImuFrame> = out.iter().filter(|f| f.valid_mask == ALL).collect();
    assert!(valid.len() > 100);
    // A turn about a fixed axis has the same rate in the sensor frame: 0.8·axis (once the
    // band limit's start-up has passed).
    for f in valid.iter().filter(|f| f.header.capture_ns > 500_000_000) {
        for w in &f.angular_rate_radps[..6] {
            let err = (0..3)
                .map(|j| (f64::from(w[j]) - 0.8 * axis[j]).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-3, "rate {w:?}");
        }
    }
    assert!(assembler.sensor_counters(0).derived_rates > 150);
    // With the mask clear, the zero gyroscope is taken as measured.
    let zero = frames(0.0, 2.0, |f, t| {
        for i in 0..6 {
            f.orientation_wxyz[i] = turn(0.8 * t).map(|v| v as f32);
            f.orientation_mask |= 1 << i;
        }
    });
    let (_, out) = run(settings(Origin::Zero), &zero);
    assert!(
        out.iter()
            .filter(|f| f.valid_mask == ALL)
            .all(|f| f.angular_rate_radps[2] == [0.0; 3])
    );
}

#[test]
fn a_lower_body_set_fuses_its_own_slots_and_ignores_the_others_saying_so() {
    use imuflow_body::{Imu, SensorSet};
    let legs = SensorSet::builtin("lower-body").unwrap();
    let mask = legs.mask().0;
    let raw = frames(0.0, 2.0, |f, t| {
        // The six's samples as before, plus the thighs', on the same clock; the set lacks the
        // forearms and the head.
        for i in [6, 7] {
            f.sample_time_ns[i] = ((t + 5.0) * 1e9).round() as u64;
            f.accelerometer_mps2[i] = [0.0, 0.0, 9.81];
            f.magnetometer_ut[i] = [0.0, 20.0, -40.0];
        }
        f.valid_mask = ALL | 0b11 << 6;
        f.magnetometer_mask = f.valid_mask;
    });
    let (mut assembler, out) = run(
        Settings {
            sites: legs.mask(),
            ..settings(Origin::Zero)
        },
        &raw,
    );
    assert_eq!(assembler.slots(), [2, 3, 5, 6, 7]);
    let valid: Vec<&ImuFrame> = out.iter().filter(|f| f.valid_mask != 0).collect();
    assert!(valid.len() > 60);
    for f in &valid[1..] {
        // Every frame once the rates are measured holds exactly the set's sites.
        assert_eq!(f.valid_mask, mask, "frame {}", f.header.seq);
        assert!(!f.header.has(flags::INVALID));
        let q = f.orientation_wxyz[Imu::LeftUpperLeg.index()];
        assert!((q.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
        assert_eq!(f.orientation_wxyz[Imu::Head.index()], [0.0; 4]);
    }
    let notices = assembler.take_notices();
    let ignored: Vec<&str> = notices
        .iter()
        .filter(|n| n.text.contains("outside the graph's sensor set"))
        .map(|n| n.text.as_str())
        .collect();
    assert_eq!(ignored.len(), 3, "{notices:?}");
    assert!(ignored.iter().any(|t| t.contains("left_forearm")));
    assert!(ignored.iter().all(|t| {
        t.contains("(left_lower_leg, right_lower_leg, pelvis, left_upper_leg, right_upper_leg)")
    }));
}

#[test]
fn offline_a_lost_packets_gap_is_waited_for_and_filled_not_left_out() {
    // Three samples of sensor 2 lost in a row: a 40 ms gap (under max_gap_ms), whose frames are
    // due before its next sample by the 30 ms deadline.
    let raw = frames(0.0, 2.0, |f, t| {
        if (1.0..1.035).contains(&t) {
            f.valid_mask &= !(1 << 2);
            f.magnetometer_mask &= !(1 << 2);
        }
    });
    let offline = imuflow_fusion::stage::FusionParams::default()
        .settings(60.0, imuflow_graph::Mode::Offline)
        .unwrap();
    let live_deadline = Settings {
        max_latency_s: 0.03,
        ..offline
    };
    let after_start = |out: &[ImuFrame]| {
        out.iter()
            .filter(|f| f.header.capture_ns > 500_000_000 && f.valid_mask != ALL)
            .count()
    };
    // At the live deadline the frames in the gap go out without the sensor; offline they wait
    // for its next sample and the gap is interpolated over.
    assert!(after_start(&run(live_deadline, &raw).1) > 0);
    assert_eq!(after_start(&run(offline, &raw).1), 0);
    // Offline a frame waits as long as the gap it fills: the offline max_gap_ms.
    assert_eq!(
        offline.max_latency_s,
        imuflow_fusion::stage::OFFLINE_MAX_GAP_MS * 1e-3
    );
}

#[test]
fn offline_runs_of_lost_packets_are_filled_live_they_leave_the_sensor_out() {
    // Samples of sensor 2 lost at 100 Hz: three in a row (a 40 ms gap), then seven at 1.5 s (an
    // 80 ms gap; a Movella DOT export loses runs of 3-4 packets at 60 Hz: gaps up to 83 ms).
    let raw = frames(0.0, 2.0, |f, t| {
        if (1.0..1.025).contains(&t) || (1.5..1.565).contains(&t) {
            f.valid_mask &= !(1 << 2);
            f.magnetometer_mask &= !(1 << 2);
        }
    });
    let defaults = imuflow_fusion::stage::FusionParams::default();
    let settings = |mode| defaults.settings(60.0, mode).unwrap();
    let without_sensor_2 = |out: &[ImuFrame]| {
        out.iter()
            .filter(|f| f.header.capture_ns > 500_000_000 && f.valid_mask & (1 << 2) == 0)
            .count()
    };
    let offline = run(settings(imuflow_graph::Mode::Offline), &raw).1;
    assert_eq!(without_sensor_2(&offline), 0);
    // With the live default (50 ms) the 80 ms gap is left out: its frames (at 60 Hz, the four or
    // five between 1.49 and 1.57 s) are without the sensor; the 40 ms gap is filled.
    let offline_settings = settings(imuflow_graph::Mode::Offline);
    let live_gap = imuflow_fusion::stage::LIVE_MAX_GAP_MS * 1e-3;
    let live_gaps = Settings {
        sensor: imuflow_fusion::SensorSettings {
            max_gap_s: live_gap,
            ..offline_settings.sensor
        },
        max_latency_s: live_gap,
        ..offline_settings
    };
    let n = without_sensor_2(&run(live_gaps, &raw).1);
    assert!((4..=5).contains(&n), "{n} frames without sensor 2");
}
