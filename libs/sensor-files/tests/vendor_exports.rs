//! Real vendors' exports as they come (fixtures copied from public recordings, each folder with
//! its licence; sources in tests/fixtures/README.md), read with the shipped layouts: sample
//! counts, units, a hand-checked value per format, lost packets, and the refusal of the partial
//! (lower-body) sets naming the sites they lack.

use std::path::{Path, PathBuf};

use imuflow_graph::frames::RawImuFrame;
use imuflow_sensor_files::{Error, Format, Layout, SITES, SensorRecording, read, read_csv};

const LF: usize = 0; // left_forearm
const LL: usize = 2; // left_lower_leg
const RL: usize = 3; // right_lower_leg
const PV: usize = 5; // pelvis

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(rel)
}

fn layout_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../configs/sensor-layouts")
        .join(name)
}

fn shipped(name: &str) -> Layout {
    Layout::load(&layout_path(name)).unwrap_or_else(|e| panic!("{e}"))
}

/// The shipped layout with only `sites`: what the recording holds, to check the values read.
fn shipped_for(name: &str, sites: &[usize]) -> Layout {
    let mut layout = shipped(name);
    layout
        .sensors
        .retain(|k, _| sites.iter().any(|&i| SITES[i] == k.as_str()));
    layout
}

fn close(got: &[f32], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    for (g, w) in got.iter().zip(want) {
        assert!(
            (f64::from(*g) - w).abs() <= tol,
            "{what}: got {got:?}, want {want:?}"
        );
    }
}

/// R_IS·v for the frame's orientation of sensor `i` (w, x, y, z).
fn rotate(f: &RawImuFrame, i: usize, v: [f32; 3]) -> [f64; 3] {
    let [w, x, y, z] = f.orientation_wxyz[i].map(f64::from);
    let v = v.map(f64::from);
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    r.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

/// The first frame holding a sample of sensor `i`.
fn first_of(r: &SensorRecording, i: usize) -> &RawImuFrame {
    r.frames
        .iter()
        .find(|f| f.sample_time_ns[i] > 0 || f.valid_mask >> i & 1 == 1)
        .expect("a sample")
}

fn refusal(e: &Error, folder: &str, missing: &[&str], present: &[&str]) {
    let text = e.to_string();
    assert!(text.contains(folder), "names the folder: {text}");
    let sites_part = text
        .split(". The sensor set read needs")
        .next()
        .unwrap_or_default();
    for m in missing {
        assert!(sites_part.contains(m), "names the missing {m}: {text}");
    }
    for p in present {
        assert!(
            text.contains(&format!("found {p}")) || text.contains(&format!(", {p}")),
            "names the present {p}: {text}"
        );
    }
    assert!(
        text.contains("needs every one of its sites") && text.contains("lower-body"),
        "{text}"
    );
}

#[test]
fn xsens_mtw_awinda_csv_per_sensor_mapped_by_sensors_csv() {
    let folder = fixture("xsens-mtw-awinda-walk");
    let r = read(
        &folder,
        Format::detect(&folder),
        Some(&layout_path("xsens-mt-manager.toml")),
        imuflow_sensor_files::SiteMask(0b11_1111),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    // Every file: PacketCounter 28597..=29849 at the header's 60 Hz, no gap, all six sensors on
    // the same counter (one Awinda network): 1253 frames of six samples each.
    assert_eq!(r.frames.len(), 1253);
    for (i, c) in r.counts.iter().enumerate().take(6) {
        assert_eq!(
            (c.samples, c.valid, c.lost, c.derived_gyroscope),
            (1253, 1253, 0, 0),
            "{}",
            SITES[i]
        );
    }
    let last = r.frames.last().unwrap();
    assert_eq!(last.valid_mask, 0b11_1111);
    // 1252 packets at 60 Hz: 20.8667 s.
    assert!(last.header.capture_ns.abs_diff(20_866_666_667) <= 1);
    // example_calibration_xsens_00b45c27.csv (left_forearm by sensors.csv), first row, as written:
    // Acc m/s², Gyr rad/s, Quat_q0..q3 = w, x, y, z.
    let f = &r.frames[0];
    close(
        &f.accelerometer_mps2[LF],
        &[9.478544, 2.304355, 1.014515],
        1e-5,
        "left forearm Acc",
    );
    close(
        &f.gyroscope_radps[LF],
        &[0.115573, 0.006008, 0.023340],
        1e-6,
        "left forearm Gyr",
    );
    close(
        &f.orientation_wxyz[LF],
        &[0.632299, -0.206753, -0.636743, -0.389884],
        1e-6,
        "left forearm Quat",
    );
    // Standing still: the specific force turned into the sensor's ENU frame points up with
    // |f| = 9.8072 (hand-computed: R_IS·f = (0.0004, −0.0019, 9.8072)).
    close(
        &rotate(f, LF, f.accelerometer_mps2[LF]).map(|v| v as f32),
        &[0.0, 0.0, 9.8072],
        0.01,
        "gravity up in ENU",
    );
    assert_eq!(f.magnetometer_mask, 0b11_1111, "Mag_* read");
    assert_eq!(f.orientation_mask, 0b11_1111);
}

#[test]
fn xsens_mt_manager_text_with_rotation_matrices_and_no_gyroscope() {
    let folder = fixture("xsens-mtw-lower-body-opensense");
    // The whole set: myIMUMappings.xml names pelvis_imu, tibia_r_imu, tibia_l_imu (and thighs,
    // heels, torso): no forearms, no head.
    let e = read_csv(&folder, &shipped("xsens-mt-manager.toml")).unwrap_err();
    refusal(
        &e,
        "xsens-mtw-lower-body-opensense",
        &["left_forearm", "right_forearm", "head"],
        &["left_lower_leg", "right_lower_leg", "pelvis"],
    );
    // The sites it has read: 300 rows each (PacketCounter 472..=771 at 100 Hz), the left tibia's
    // export ends 50 rows earlier; no gap in any counter.
    let r = read_csv(
        &folder,
        &shipped_for("xsens-mt-manager.toml", &[LL, RL, PV]),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.counts[PV].samples, 300);
    assert_eq!(r.counts[RL].samples, 300);
    assert_eq!(r.counts[LL].samples, 250);
    for i in [LL, RL, PV] {
        let c = r.counts[i];
        assert_eq!(c.lost, 0, "{}", SITES[i]);
        // No Gyr_* columns: every angular rate comes from the rotation matrices.
        assert_eq!(c.derived_gyroscope, c.samples, "{}", SITES[i]);
        assert_eq!(c.valid, c.samples, "{}", SITES[i]);
    }
    assert_eq!(r.frames.len(), 300);
    assert_eq!(r.frames[299].header.capture_ns, 2_990_000_000);
    // MT_012005D6_009-001_00B42279.txt (pelvis_imu), first row: Acc and Mat[i][j] = R_IS(i, j).
    let f = &r.frames[0];
    close(
        &f.accelerometer_mps2[PV],
        &[9.414882, 0.727244, -2.823645],
        1e-5,
        "pelvis Acc",
    );
    // Hand-computed R·f = (−0.0353, 0.0845, 9.8556): gravity up, so the matrix was read by rows
    // of R (a transpose would put 0.96·9.41 − ... elsewhere).
    close(
        &rotate(f, PV, f.accelerometer_mps2[PV]).map(|v| v as f32),
        &[-0.0353, 0.0845, 9.8556],
        2e-3,
        "R·f",
    );
}

#[test]
fn mt_manager_delimiters_euler_angles_nan_cells_and_a_missing_rate() {
    let dir = fixture("export-formats-opensim/Xsens");
    // MT Manager 2022 writes no "Update Rate" line: the shipped layout says to set rate_hz.
    let one = |file: &str, rate: Option<f64>| {
        let mut layout = shipped_for("xsens-mt-manager.toml", &[PV]);
        layout.files = None;
        if let Some(t) = layout.time.as_mut() {
            t.rate_hz = rate;
        }
        read_csv(&dir.join(file), &layout)
    };
    let e = one("MT2022_ACC_GYRO_ROT_MAT_COMMA_00B42D4B.txt", None).unwrap_err();
    assert!(
        e.to_string()
            .contains("MT2022_ACC_GYRO_ROT_MAT_COMMA_00B42D4B.txt")
            && e.to_string().contains("rate_hz"),
        "{e}"
    );
    // The same five samples written with commas, semicolons and spaces (empty cells as runs of
    // spaces) read alike.
    let reads: Vec<SensorRecording> = ["COMMA", "SEMICOLON", "SPACE"]
        .iter()
        .map(|d| {
            one(
                &format!("MT2022_ACC_GYRO_ROT_MAT_{d}_00B42D4B.txt"),
                Some(100.0),
            )
            .unwrap_or_else(|e| panic!("{d}: {e}"))
        })
        .collect();
    for r in &reads {
        assert_eq!(r.frames.len(), 5);
        assert_eq!(
            r.frames[4].header.capture_ns, 40_000_000,
            "counter at 100 Hz"
        );
        let f = &r.frames[0];
        close(
            &f.accelerometer_mps2[PV],
            &[0.074225, -0.040975, 9.922524],
            1e-6,
            "Acc",
        );
        close(
            &f.gyroscope_radps[PV],
            &[0.003078, 0.004280, 0.002706],
            1e-6,
            "Gyr",
        );
        // Hand-computed R·f = (−0.0188, 0.0404, 9.9228).
        close(
            &rotate(f, PV, f.accelerometer_mps2[PV]).map(|v| v as f32),
            &[-0.0188, 0.0404, 9.9228],
            2e-3,
            "R·f",
        );
        assert_eq!(f.orientation_wxyz, reads[0].frames[0].orientation_wxyz);
    }
    // Euler angles (Roll, Pitch, Yaw in degrees, R = Rz·Ry·Rx): hand-computed R·f for the first
    // row = (−0.0571, −0.0951, 9.9780).
    let r = one("MT2022_ACC_GYRO_ROT_EULER_TAB_00B42D4F.txt", Some(100.0)).unwrap();
    let f = &r.frames[0];
    close(
        &rotate(f, PV, f.accelerometer_mps2[PV]).map(|v| v as f32),
        &[-0.0571, -0.0951, 9.9780],
        2e-3,
        "Euler R·f",
    );
    // Quaternion, Euler and matrix all in one file: the quaternion is used; the first row's
    // Acc_X is NaN, so that sample has no accelerometer (counted, not an error).
    let r = one("MT2022_ACC_GYRO_ROT_ALL_TAB_NAN_00B42D4B.txt", Some(100.0)).unwrap();
    assert_eq!(r.counts[PV].samples, 5);
    assert_eq!(r.counts[PV].missing_accelerometer, 1);
    assert_eq!(r.counts[PV].valid, 4);
    close(
        &r.frames[0].orientation_wxyz[PV],
        &[0.529130, -0.004539, -0.002454, -0.848525],
        1e-6,
        "Quat_q0..q3, w made positive",
    );
}

#[test]
fn x_imu3_folders_named_after_the_body_part_with_lost_packets() {
    let folder = fixture("x-io-lower-body");
    let e = read_csv(&folder, &shipped("x-imu3.toml")).unwrap_err();
    refusal(
        &e,
        "x-io-lower-body",
        &["left_forearm", "right_forearm", "head"],
        &["left_lower_leg", "right_lower_leg", "pelvis"],
    );
    let r = read_csv(&folder, &shipped_for("x-imu3.toml", &[LL, RL, PV]))
        .unwrap_or_else(|e| panic!("{e}"));
    // 300 Inertial.csv rows each; gaps in the µs timestamps (hand-counted: gaps over 1.5 median
    // intervals, each round(gap / median) − 1 samples) are the packets lost over UDP.
    for (i, lost) in [(LL, 4), (RL, 2), (PV, 9)] {
        let c = r.counts[i];
        assert_eq!(
            (c.samples, c.valid, c.lost),
            (300, 300, lost),
            "{}",
            SITES[i]
        );
        assert_eq!(c.missing_orientation, 0, "{}", SITES[i]);
    }
    // Left Lower Leg 64F61CB3 (UDP)/Inertial.csv, first row: gyroscope deg/s, accelerometer g.
    let f = first_of(&r, LL);
    close(
        &f.gyroscope_radps[LL],
        &[
            -0.521662_f64.to_radians(),
            0.249247_f64.to_radians(),
            -0.009101_f64.to_radians(),
        ],
        1e-6,
        "deg/s to rad/s",
    );
    close(
        &f.accelerometer_mps2[LL],
        &[-0.977279 * 9.80665, 0.168695 * 9.80665, 0.142709 * 9.80665],
        1e-4,
        "g to m/s²",
    );
    close(
        &f.orientation_wxyz[LL],
        &[0.638984, -0.251069, 0.605224, 0.403251],
        // Normalised: the written one's norm is 1.00013.
        2e-4,
        "Quaternion.csv joined",
    );
}

#[test]
fn movella_dot_app_files_named_by_device_tag_with_lost_packets() {
    let folder = fixture("movella-dot-lower-body");
    let e = read_csv(&folder, &shipped("movella-dot.toml")).unwrap_err();
    refusal(
        &e,
        "movella-dot-lower-body",
        &["left_forearm", "right_forearm", "head"],
        &["left_lower_leg", "right_lower_leg", "pelvis"],
    );
    let r = read_csv(&folder, &shipped_for("movella-dot.toml", &[LL, RL, PV]))
        .unwrap_or_else(|e| panic!("{e}"));
    // Data rows per file (LTibia, RTibia, Pelvis), counted by hand.
    for (i, rows) in [(LL, 381), (RL, 382), (PV, 382)] {
        assert_eq!(r.counts[i].samples, rows, "{}", SITES[i]);
        assert_eq!(r.counts[i].lost, 0, "{}", SITES[i]);
    }
    // Pelvis_20210820_202113_836.csv, first row: quaternion (−0.679148, 0.020083, −0.728430,
    // 0.088013) and FreeAcc (0.038134, 0.002781, 0.003076) m/s² in ENU. Hand-computed
    // f_S = R_ISᵀ·(a + 9.81·z) = (−9.6779, −1.5198, −0.5711).
    let f = first_of(&r, PV);
    close(
        &f.accelerometer_mps2[PV],
        &[-9.6779, -1.5198, -0.5711],
        2e-3,
        "free acceleration to specific force",
    );
    // The left femur's sensor lost most packets (PacketCounter gaps: 157 in its first 195 rows);
    // femurs are no site of ours, so it is read with a layout that puts it on one.
    let mut layout = shipped_for("movella-dot.toml", &[LL]);
    layout.files = None;
    let r = read_csv(&folder.join("LFemur_20210820_202113_831.csv"), &layout)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.counts[LL].samples, 195);
    assert_eq!(r.counts[LL].lost, 157);
}

#[test]
fn mvnx_3_from_mvn_studio_4_2_4() {
    let r = imuflow_sensor_files::read_mvnx(&fixture("mvnx-mvn-4.2.4/Meri-020.mvnx"))
        .unwrap_or_else(|e| panic!("{e}"));
    // Four `normal` frames at 240 Hz (the npose and tpose frames are calibration poses).
    assert_eq!(r.frames.len(), 4);
    assert_eq!(r.frames[3].header.capture_ns, 12_500_000);
    assert_eq!(r.truth.as_ref().map(Vec::len), Some(4));
    for (i, c) in r.counts.iter().enumerate().take(6) {
        assert_eq!((c.samples, c.valid), (4, 4), "{}", SITES[i]);
    }
    // The suit's other 11 sensors are there, left out of the six-site set's reading; read for
    // the full suit, every one of the 17.
    assert_eq!(r.left_out.len(), 11, "{:?}", r.left_out);
    let suit = imuflow_sensor_files::read(
        &fixture("mvnx-mvn-4.2.4/Meri-020.mvnx"),
        Format::Mvnx,
        None,
        imuflow_sensor_files::SiteMask((1 << 17) - 1),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(suit.left_out.is_empty());
    for (i, c) in suit.counts.iter().enumerate() {
        assert_eq!((c.samples, c.valid), (4, 4), "{}", SITES[i]);
    }
    let mut seen = 0u32;
    for f in &suit.frames {
        seen |= f.valid_mask;
    }
    assert_eq!(seen, (1 << 17) - 1);
}

#[test]
fn gzip_recordings_read_as_the_file_they_hold_and_other_archives_are_named() {
    let layout = Layout::load(&fixture("csv/one-file.toml")).unwrap();
    let plain = read_csv(&fixture("csv/one-file.csv"), &layout).unwrap();
    let gz = read_csv(&fixture("csv/one-file.csv.gz"), &layout).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(gz.frames.len(), plain.frames.len());
    for (a, b) in gz.frames.iter().zip(&plain.frames) {
        assert_eq!(a.accelerometer_mps2, b.accelerometer_mps2);
        assert_eq!(a.orientation_wxyz, b.orientation_wxyz);
        assert_eq!(a.header.capture_ns, b.header.capture_ns);
    }
    let dir = std::env::temp_dir().join(format!("imuflow-gz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let zip = dir.join("session.csv");
    std::fs::write(&zip, b"PK\x03\x04\x14\x00\x00\x00rest of a zip").unwrap();
    let e = read_csv(&zip, &layout).unwrap_err().to_string();
    assert!(
        e.contains("session.csv") && e.contains("zip") && e.contains("not supported"),
        "{e}"
    );
    let latin1 = dir.join("latin1.csv");
    std::fs::write(&latin1, b"t,a\n0,1\n1,\xb5\n").unwrap();
    let e = read_csv(&latin1, &layout).unwrap_err().to_string();
    assert!(
        e.contains("latin1.csv:3") && e.contains("not UTF-8"),
        "names the file and line: {e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The lower-body set's sites, by wire slot: left and right lower leg (2, 3), pelvis (5), left and
/// right upper leg (6, 7).
const LOWER_BODY: u32 = 1 << LL | 1 << RL | 1 << PV | 1 << 6 | 1 << 7;

#[test]
fn a_lower_body_export_reads_as_the_lower_body_set_and_a_partial_one_is_refused_naming_what_it_lacks()
 {
    let legs = imuflow_sensor_files::SiteMask(LOWER_BODY);
    // Movella DOT's five: pelvis, femurs, tibias, each file named by its device tag.
    let folder = fixture("movella-dot-lower-body");
    let r = read(
        &folder,
        Format::Csv,
        Some(&layout_path("movella-dot.toml")),
        legs,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.sites, legs);
    let mut seen = 0u32;
    for f in &r.frames {
        seen |= f.valid_mask;
    }
    assert_eq!(seen, LOWER_BODY);
    // The left femur's sensor lost most packets (PacketCounter gaps: 157 in its first 195 rows),
    // the right one none.
    assert_eq!((r.counts[6].samples, r.counts[6].lost), (195, 157));
    assert_eq!(r.counts[7].lost, 0);
    assert!(r.left_out.is_empty(), "{:?}", r.left_out);
    assert!(
        r.summary().starts_with("left_lower_leg: 381 samples"),
        "{}",
        r.summary()
    );
    // The same folder read for the six: the forearms and the head are not there.
    let six = imuflow_sensor_files::SiteMask(0b11_1111);
    let e = read(
        &folder,
        Format::Csv,
        Some(&layout_path("movella-dot.toml")),
        six,
    )
    .unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("no sensor for left_forearm, right_forearm, head")
            && text.contains("found left_lower_leg, right_lower_leg, pelvis"),
        "{text}"
    );
    // x-IMU3's excerpt holds the lower body (its folders named after the body part).
    let r = read(
        &fixture("x-io-lower-body"),
        Format::Csv,
        Some(&layout_path("x-imu3.toml")),
        legs,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.sites, legs);
    assert!((6..8).all(|k| r.counts[k].samples == 300));
    // OpenSense's MTw excerpt holds the shanks and the pelvis but not the thighs: refused naming
    // them, for the set read.
    let Err(e) = read(
        &fixture("xsens-mtw-lower-body-opensense"),
        Format::Csv,
        Some(&layout_path("xsens-mt-manager.toml")),
        legs,
    ) else {
        panic!("the OpenSense excerpt without thighs was read as the lower body");
    };
    let text = e.to_string();
    assert!(
        text.contains("no sensor for left_upper_leg, right_upper_leg")
            && text.contains(
                "(left_lower_leg, right_lower_leg, pelvis, left_upper_leg, right_upper_leg)"
            ),
        "{text}"
    );
    // A layout without tables for a set's site is refused naming them.
    let e = read(
        &fixture("movella-dot-lower-body"),
        Format::Csv,
        Some(&layout_path("noraxon.toml")),
        legs,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("the layout has no [sensors.<site>] for left_upper_leg, right_upper_leg"),
        "{e}"
    );
}
