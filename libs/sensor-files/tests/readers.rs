//! Every reader against hand-derived values: unit conversions, time columns, quaternion orders,
//! free acceleration turned into specific force, missing cells, and the shipped layouts.

use std::f32::consts::{FRAC_1_SQRT_2, PI};
use std::path::{Path, PathBuf};

use imuflow_graph::frames::RawImuFrame;
use imuflow_sensor_files::{Format, Layout, SITES, SensorRecording, read, read_csv, read_mvnx};

const G: f32 = 9.80665;
const LF: usize = 0; // left_forearm
const LL: usize = 2; // left_lower_leg
const PV: usize = 5; // pelvis

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(rel)
}

fn shipped_layout(name: &str) -> Layout {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../configs/sensor-layouts")
        .join(name);
    Layout::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// The shipped layout with only the sensors the fixture has.
fn shipped_layout_for(name: &str, sites: &[&str]) -> Layout {
    let mut layout = shipped_layout(name);
    layout.sensors.retain(|k, _| sites.contains(&k.as_str()));
    layout
}

fn close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() <= tol, "{what}: got {got:?}, want {want:?}");
    }
}

fn bit(mask: u32, i: usize) -> bool {
    mask >> i & 1 == 1
}

fn frame(r: &SensorRecording, i: usize) -> &RawImuFrame {
    &r.frames[i]
}

#[test]
fn generic_csv_units_quaternion_order_remap_and_missing_cells() {
    let layout = Layout::load(&fixture("csv/one-file.toml")).unwrap();
    let r = read_csv(&fixture("csv/one-file.csv"), &layout).unwrap();
    // Both sensors share the time column: one frame per row.
    assert_eq!(r.frames.len(), 3);
    for (k, f) in r.frames.iter().enumerate() {
        assert_eq!(f.header.seq, k as u64);
        assert_eq!(f.header.capture_ns, k as u64 * 10_000_000, "10 ms rows");
        assert_eq!(f.sample_time_ns[LF], k as u64 * 10_000_000);
        assert_eq!(f.sample_time_ns[PV], k as u64 * 10_000_000);
    }
    let f0 = frame(&r, 0);
    close(&f0.accelerometer_mps2[LF], &[0.0, 0.0, G], 1e-6, "1 g up");
    close(
        &f0.gyroscope_radps[LF],
        &[PI / 2.0, 0.0, 0.0],
        1e-6,
        "90 deg/s",
    );
    close(
        &f0.magnetometer_ut[LF],
        &[50.0, 0.0, 0.0],
        1e-5,
        "0.5 gauss",
    );
    // x, y, z, w = 0, 0, 0.7071068, 0.7071068 -> w, x, y, z.
    close(
        &f0.orientation_wxyz[LF],
        &[FRAC_1_SQRT_2, 0.0, 0.0, FRAC_1_SQRT_2],
        1e-6,
        "xyzw",
    );
    assert!(
        bit(f0.valid_mask, LF) && bit(f0.magnetometer_mask, LF) && bit(f0.orientation_mask, LF)
    );
    // Pelvis (0.1, 0.2, 1) g and (10, 0, 0) deg/s in the file's axes; ours: x = -y, y = x.
    close(
        &f0.accelerometer_mps2[PV],
        &[-0.2 * G, 0.1 * G, G],
        1e-5,
        "remapped",
    );
    close(
        &f0.gyroscope_radps[PV],
        &[0.0, 10.0 * PI / 180.0, 0.0],
        1e-6,
        "remapped",
    );
    assert!(!bit(f0.orientation_mask, PV) && !bit(f0.magnetometer_mask, PV));

    let f1 = frame(&r, 1);
    close(
        &f1.accelerometer_mps2[LF],
        &[0.5 * G, 0.0, G],
        1e-5,
        "0.5 g",
    );
    close(
        &f1.gyroscope_radps[LF],
        &[0.0, -PI, 0.0],
        1e-6,
        "-180 deg/s",
    );
    close(
        &f1.magnetometer_ut[LF],
        &[0.0, 25.0, 0.0],
        1e-5,
        "0.25 gauss",
    );
    assert!(!bit(f1.valid_mask, PV), "NaN accelerometer: not valid");
    let f2 = frame(&r, 2);
    assert!(
        bit(f2.valid_mask, LF) && !bit(f2.magnetometer_mask, LF),
        "empty magnetometer cells"
    );

    let (lf, pv) = (r.counts[LF], r.counts[PV]);
    assert_eq!((lf.samples, lf.valid, lf.missing_magnetometer), (3, 3, 1));
    assert_eq!((pv.samples, pv.valid, pv.missing_accelerometer), (3, 2, 1));
    assert_eq!(r.counts[1].samples, 0, "right forearm not in the layout");
}

#[test]
fn semicolons_decimal_commas_column_numbers_and_a_fixed_rate() {
    let layout = Layout::parse(
        r#"
[table]
delimiter = "semicolon"
decimal = ","
skip_lines = 1
header = false
[time]
rate_hz = 50
[units]
accelerometer = "g"
gyroscope = "deg/s"
[sensors.head]
accelerometer = [1, 2, 3]
gyroscope = [4, 4, 4]
"#,
        Path::new("inline.toml"),
    )
    .unwrap();
    let r = read_csv(&fixture("csv/semicolon.txt"), &layout).unwrap();
    assert_eq!(r.frames.len(), 2);
    assert_eq!(r.frames[1].header.capture_ns, 20_000_000, "row 1 at 1/50 s");
    let f0 = frame(&r, 0);
    close(
        &f0.accelerometer_mps2[4],
        &[0.5 * G, 0.0, -G],
        1e-5,
        "0,5 g",
    );
    let w = 12.5 * PI / 180.0;
    close(&f0.gyroscope_radps[4], &[w, w, w], 1e-6, "12,5 deg/s");
    assert!(!bit(frame(&r, 1).valid_mask, 4), "empty gyroscope cell");
}

#[test]
fn movella_dot_microsecond_counter_wraps_and_free_acceleration_becomes_specific_force() {
    let layout = shipped_layout_for("movella-dot.toml", &["left_forearm", "pelvis"]);
    let r = read_csv(&fixture("dot"), &layout).unwrap();
    assert_eq!(r.frames.len(), 3, "synced sensors share frames");
    // SampleTimeFine 4294950000, 4294966667, then 16037 after the 2^32 wrap.
    let own = [4_294_950_000_000u64, 4_294_966_667_000, 4_294_983_333_000];
    for (k, f) in r.frames.iter().enumerate() {
        assert_eq!(f.sample_time_ns[LF], own[k]);
        assert_eq!(f.header.capture_ns, own[k] - own[0], "shared clock from 0");
    }
    // Left forearm turned 90° about x (ENU), free acceleration (1, 0, 0):
    // f_S = R_ISᵀ(a − g) = Rx(−90°)·(1, 0, 9.81) = (1, 9.81, 0).
    let f0 = frame(&r, 0);
    close(
        &f0.accelerometer_mps2[LF],
        &[1.0, 9.81, 0.0],
        1e-5,
        "specific force",
    );
    close(
        &f0.orientation_wxyz[LF],
        &[FRAC_1_SQRT_2, FRAC_1_SQRT_2, 0.0, 0.0],
        1e-6,
        "quat",
    );
    // Pelvis level and at rest: gravity's reaction along its z.
    close(
        &f0.accelerometer_mps2[PV],
        &[0.0, 0.0, 9.81],
        1e-6,
        "at rest",
    );
    // No gyroscope column: the rate comes from the (constant) orientations.
    close(
        &f0.gyroscope_radps[LF],
        &[0.0, 0.0, 0.0],
        1e-6,
        "derived rate",
    );
    assert!(bit(f0.valid_mask, LF));
    assert!(!bit(frame(&r, 2).valid_mask, LF), "empty FreeAcc cells");
    assert_eq!(r.counts[LF].derived_gyroscope, 3);
    assert_eq!(r.counts[LF].missing_accelerometer, 1);
}

#[test]
fn x_io_quaternions_from_a_second_file_join_the_nearest_sample() {
    let layout = shipped_layout_for("x-io.toml", &["left_forearm", "pelvis"]);
    let r = read_csv(&fixture("xio"), &layout).unwrap();
    assert_eq!(r.frames.len(), 3);
    let f0 = frame(&r, 0);
    close(
        &f0.gyroscope_radps[LF],
        &[PI / 2.0, 0.0, 0.0],
        1e-6,
        "deg/s",
    );
    close(&f0.accelerometer_mps2[LF], &[0.0, 0.0, G], 1e-6, "g");
    close(&f0.magnetometer_ut[LF], &[20.0, -5.0, -40.0], 1e-6, "uT");
    close(
        &f0.orientation_wxyz[LF],
        &[1.0, 0.0, 0.0, 0.0],
        1e-6,
        "quat row 1 ms later",
    );
    let f1 = frame(&r, 1);
    assert_eq!(f1.sample_time_ns[LF], 20_053_287);
    close(
        &f1.gyroscope_radps[LF],
        &[0.0, 0.0, -PI / 4.0],
        1e-6,
        "-45 deg/s",
    );
    close(
        &f1.orientation_wxyz[LF],
        &[FRAC_1_SQRT_2, 0.0, 0.0, FRAC_1_SQRT_2],
        1e-6,
        "joined",
    );
    // The quaternion row at 0.5 s is nowhere near a sample: counted, not silently lost.
    assert_eq!(r.counts[LF].unjoined_rows, 1);
    assert_eq!(r.counts[LF].valid, 3);
}

#[test]
fn noraxon_milli_g_per_sensor_columns() {
    let r = read_csv(
        &fixture("noraxon/session.csv"),
        &shipped_layout("noraxon.toml"),
    )
    .unwrap();
    assert_eq!(r.frames.len(), 3);
    let f0 = frame(&r, 0);
    assert_eq!(f0.valid_mask, 0b11_1111);
    close(
        &f0.accelerometer_mps2[LF],
        &[0.5 * G, 0.0, -G],
        1e-5,
        "500, 0, -1000 mG",
    );
    close(&f0.accelerometer_mps2[PV], &[0.0, 0.0, G], 1e-5, "1000 mG");
    close(
        &f0.gyroscope_radps[PV],
        &[0.0, PI / 2.0, 0.0],
        1e-6,
        "90 deg/s",
    );
    assert_eq!(frame(&r, 2).header.capture_ns, 20_000_000);
}

#[test]
fn opensense_quaternion_strings_with_gravity_only_accelerations() {
    // The six's columns (the layout also names the lower body's and the arms').
    let r = imuflow_sensor_files::read_csv_sites(
        &fixture("opensense/orientations.sto"),
        &shipped_layout("opensense-sto.toml"),
        imuflow_sensor_files::SiteMask(0b11_1111),
    )
    .unwrap();
    assert_eq!(r.frames.len(), 3);
    let f1 = frame(&r, 1);
    // Pelvis turns 0.5 rad about z (up) per 10 ms row.
    let (c, s) = (0.25f32.cos(), 0.25f32.sin());
    close(
        &f1.orientation_wxyz[PV],
        &[c, 0.0, 0.0, s],
        1e-6,
        "w,x,y,z in one cell",
    );
    close(
        &f1.gyroscope_radps[PV],
        &[0.0, 0.0, 50.0],
        1e-3,
        "0.5 rad per 10 ms",
    );
    // A turn about up keeps gravity's reaction on z.
    close(
        &f1.accelerometer_mps2[PV],
        &[0.0, 0.0, 9.81],
        1e-5,
        "gravity only",
    );
    assert!(bit(f1.valid_mask, PV));
    assert!(
        !bit(f1.orientation_mask, LL) && !bit(f1.valid_mask, LL),
        "nan quaternion"
    );
    assert_eq!(r.counts[LL].missing_orientation, 1);
}

#[test]
fn mvnx_sensors_truth_and_de_jittered_times() {
    let six = imuflow_sensor_files::SiteMask(0b11_1111);
    let r = read(&fixture("mvnx/session.mvnx"), Format::Mvnx, None, six).unwrap();
    assert_eq!(
        r.frames.len(),
        4,
        "four normal frames; identity and tpose skipped"
    );
    let truth = r.truth.as_ref().expect("MVNX has a truth");
    assert_eq!(truth.len(), 4);
    for (k, (f, t)) in r.frames.iter().zip(truth).enumerate() {
        // Written as 0, 17, 33, 50 ms; at 60 Hz frame k is at k/60 s.
        let ns = (k as f64 * 1e9 / 60.0).round() as u64;
        assert_eq!(
            (f.header.capture_ns, t.header.capture_ns),
            (ns, ns),
            "frame {k}"
        );
        assert_eq!(
            f.valid_mask & 0b11_1111 & !(1 << LL),
            0b11_1111 & !(1 << LL)
        );
    }
    let f0 = frame(&r, 0);
    // LeftForeArm: 90° about x, free acceleration (1, 0, 0): f_S = (1, 9.81, 0).
    close(
        &f0.accelerometer_mps2[LF],
        &[1.0, 9.81, 0.0],
        1e-5,
        "specific force",
    );
    // Pelvis level, free acceleration (0, 0, 0.5) up: 9.81 + 0.5.
    close(
        &f0.accelerometer_mps2[PV],
        &[0.0, 0.0, 10.31],
        1e-5,
        "specific force",
    );
    // The forearm sensor turns at 1.2 rad/s about its x: derived from the orientations.
    for f in &r.frames {
        close(
            &f.gyroscope_radps[LF],
            &[1.2, 0.0, 0.0],
            1e-4,
            "derived rate",
        );
    }
    // Magnetometer in MVN's normalised units: each sensor's median norm scaled to 50 µT.
    close(
        &f0.magnetometer_ut[LF],
        &[40.0, 0.0, -30.0],
        1e-4,
        "0.4, 0, -0.3 a.u.",
    );
    close(
        &f0.magnetometer_ut[PV],
        &[40.0, 0.0, -30.0],
        1e-4,
        "0.8, 0, -0.6 a.u.",
    );
    assert!(!bit(frame(&r, 2).valid_mask, LL), "NaN free acceleration");
    assert_eq!(r.counts[LL].missing_accelerometer, 1);
    assert_eq!(r.counts[LF].derived_gyroscope, 4);

    // Truth: the left forearm and hand segments turn 0.5 rad per frame about MVN's z (up), so
    // the left elbow turns about M's y; the root is the pelvis origin, (y, z, x) of MVN's.
    let t2 = &truth[2];
    let elbow = 18;
    close(
        &t2.local_pose_wxyz[elbow],
        &[0.5f32.cos(), 0.0, 0.5f32.sin(), 0.0],
        1e-5,
        "elbow",
    );
    close(
        &t2.local_pose_wxyz[20],
        &[1.0, 0.0, 0.0, 0.0],
        1e-6,
        "wrist carried along",
    );
    close(&t2.root_position_m, &[0.2, 0.95, 0.12], 1e-6, "root in M");
}

#[test]
fn every_shipped_layout_loads_and_places_the_six_sites_at_least() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/sensor-layouts");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "movella-dot.toml",
            "noraxon.toml",
            "opensense-sto.toml",
            "x-imu3.toml",
            "x-io.toml",
            "xsens-mt-manager.toml"
        ]
    );
    for name in names {
        let layout = shipped_layout(&name);
        // Every one places at least the six-site set's sites (sites of other sets where the
        // export's columns are the same for every sensor).
        for site in &SITES[..6] {
            assert!(layout.sensors.contains_key(*site), "{name}: {site}");
        }
        let text = std::fs::read_to_string(dir.join(&name)).unwrap();
        assert!(
            text.starts_with("# Reads "),
            "{name}: first line says which export it reads"
        );
    }
}

#[test]
fn format_detection_and_a_csv_without_layout() {
    assert_eq!(Format::detect(Path::new("a/b.MVNX")), Format::Mvnx);
    assert_eq!(Format::detect(Path::new("a/b.csv")), Format::Csv);
    let six = imuflow_sensor_files::SiteMask(0b11_1111);
    let e = read(&fixture("csv/one-file.csv"), Format::Csv, None, six).unwrap_err();
    assert!(e.to_string().contains("layout"), "{e}");
    assert!(read_mvnx(&fixture("csv/one-file.csv")).is_err());
}
