//! The crate's VQF against the authors' implementation: `scripts/verify/vqf_reference.py` ran the
//! PyPI package `vqf` (the Cython wrapper of the authors' C++ code) on `fixtures/vqf_input.csv`
//! and wrote `fixtures/vqf_expected.csv`. Every quaternion must agree within 1e-4 per component
//! (after aligning the sign: q and −q are one rotation).

use std::path::PathBuf;

mod common;

use imuflow_fusion::assembler::{Assembler, Origin, Settings};
use imuflow_fusion::filter::{OrientationFilter, VqfParams};
use imuflow_fusion::sensor::SensorSettings;
use imuflow_graph::frames::{ImuFrame, RawImuFrame};

const TOLERANCE: f64 = 1e-4;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// A CSV of numbers with a header line: (header, rows).
fn read_csv(name: &str) -> (Vec<String>, Vec<Vec<f64>>) {
    let path = fixture(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_owned)
        .collect();
    let rows = lines
        .enumerate()
        .map(|(n, line)| {
            line.split(',')
                .map(|v| {
                    v.parse()
                        .unwrap_or_else(|e| panic!("{name}:{}: {v}: {e}", n + 2))
                })
                .collect()
        })
        .collect();
    (header, rows)
}

struct Input {
    t: Vec<f64>,
    gyr: Vec<[f64; 3]>,
    acc: Vec<[f64; 3]>,
    mag: Vec<[f64; 3]>,
}

fn input() -> Input {
    let (header, rows) = read_csv("vqf_input.csv");
    assert_eq!(header[0], "t_s");
    assert_eq!(rows.len(), 600);
    let v3 = |r: &Vec<f64>, i: usize| [r[i], r[i + 1], r[i + 2]];
    Input {
        t: rows.iter().map(|r| r[0]).collect(),
        gyr: rows.iter().map(|r| v3(r, 1)).collect(),
        acc: rows.iter().map(|r| v3(r, 4)).collect(),
        mag: rows.iter().map(|r| v3(r, 7)).collect(),
    }
}

/// The expected quaternions: sample index → column name → [w, x, y, z].
struct Expected {
    header: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Expected {
    fn load() -> Expected {
        let (header, rows) = read_csv("vqf_expected.csv");
        Expected { header, rows }
    }

    /// (sample index, quaternion) of column group `name` (`default_9d`, ...).
    fn series(&self, name: &str) -> Vec<(usize, [f64; 4])> {
        let col = self
            .header
            .iter()
            .position(|h| h == &format!("{name}_w"))
            .unwrap_or_else(|| panic!("no column {name}_w"));
        self.rows
            .iter()
            .map(|r| {
                let k = (r[0] * 100.0).round() as usize;
                (k, [r[col], r[col + 1], r[col + 2], r[col + 3]])
            })
            .collect()
    }
}

/// Largest component difference after aligning the sign.
fn difference(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let dot: f64 = (0..4).map(|i| a[i] * b[i]).sum();
    let s = if dot < 0.0 { -1.0 } else { 1.0 };
    (0..4).map(|i| (a[i] - s * b[i]).abs()).fold(0.0, f64::max)
}

fn params(name: &str) -> VqfParams {
    match name {
        "default" => VqfParams::default(),
        // scripts/verify/vqf_reference.py, CONFIGS["custom"].
        "custom" => VqfParams {
            tau_acc_s: 1.5,
            tau_mag_s: 5.0,
            rest_bias: false,
            rest_min_s: 1.5,
            bias_clip_dps: 2.0,
            mag_rejection: false,
        },
        _ => unreachable!(),
    }
}

#[test]
fn the_filter_matches_the_authors_vqf_in_6d_and_9d() {
    let input = input();
    let expected = Expected::load();
    for config in ["default", "custom"] {
        for nine in [false, true] {
            let mut filter = OrientationFilter::new(0.01, &params(config));
            let mut quats = Vec::new();
            for k in 0..input.t.len() {
                let mag = nine.then_some(input.mag[k]);
                filter.update(input.gyr[k], input.acc[k], mag);
                quats.push(filter.orientation());
            }
            assert_eq!(filter.magnetic(), nine);
            let name = format!("{config}_{}", if nine { "9d" } else { "6d" });
            let series = expected.series(&name);
            assert_eq!(series.len(), 300, "{name}");
            let worst = series
                .iter()
                .map(|(k, q)| (difference(&quats[*k], q), *k))
                .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a });
            assert!(worst.0 < TOLERANCE, "{name}: {worst:?}");
        }
    }
    // The 9D and 6D results differ (the magnetometer did something), and the configurations too.
    let d = difference(
        &expected.series("default_9d")[299].1,
        &expected.series("default_6d")[299].1,
    );
    assert!(d > 0.05, "{d}");
    let d = difference(
        &expected.series("default_9d")[299].1,
        &expected.series("custom_9d")[299].1,
    );
    assert!(d > 1e-3, "{d}");
}

/// The same input through the whole stage path (raw frames, rate measurement, clock mapping, output
/// grid): at an output rate equal to the sensor rate, on a clock without offset or delay, output
/// frame k is sample k. Sensors 0..3 carry the magnetometer (9D), sensors 3..6 do not (6D).
#[test]
fn the_stage_path_reproduces_the_reference_at_the_sensor_rate() {
    let input = input();
    let expected = Expected::load();
    let base = common::settings(Origin::Zero);
    let settings = Settings {
        sensor: SensorSettings {
            output_rate_hz: 100.0,
            latency: imuflow_fusion::sensor::Latency::Smooth,
            ..base.sensor
        },
        // Long enough for the first frames to wait for the rate measurement (9 samples).
        max_latency_s: 0.2,
        ..base
    };
    let mut assembler = Assembler::new(settings);
    let mut frames: Vec<ImuFrame> = Vec::new();
    for k in 0..input.t.len() {
        let mut raw = RawImuFrame::default();
        let ns = (input.t[k] * 1e9).round() as u64;
        raw.header.seq = k as u64;
        raw.header.capture_ns = ns;
        for i in 0..6 {
            raw.sample_time_ns[i] = ns;
            raw.gyroscope_radps[i] = input.gyr[k].map(|v| v as f32);
            raw.accelerometer_mps2[i] = input.acc[k].map(|v| v as f32);
            raw.magnetometer_ut[i] = input.mag[k].map(|v| v as f32);
        }
        raw.valid_mask = 0b111111;
        raw.magnetometer_mask = 0b000111;
        assembler.push(&raw, &mut frames).unwrap();
    }
    assembler.finish(&mut frames).unwrap();
    assert_eq!(frames.len(), 600);
    // The wire carries f32: the input is rounded to f32 first, which moves the filter by far less
    // than the tolerance.
    let mut worst = 0.0f64;
    for (name, sensors) in [("default_9d", 0..3), ("default_6d", 3..6)] {
        for (k, q) in expected.series(name) {
            let frame = &frames[k];
            assert_eq!(frame.header.seq, k as u64);
            assert_eq!(frame.valid_mask, 0b111111, "frame {k}");
            for i in sensors.clone() {
                let got = frame.orientation_wxyz[i].map(f64::from);
                let d = difference(&got, &q);
                assert!(d < TOLERANCE, "{name} sensor {i} frame {k}: {d}");
                worst = worst.max(d);
            }
        }
    }
    eprintln!("largest difference through the stage path: {worst:.1e}");
}
