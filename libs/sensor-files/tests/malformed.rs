//! Malformed recordings and layouts: each is an error that names the file, the line where there
//! is one, and the column or element.

use std::path::{Path, PathBuf};

use imuflow_sensor_files::{Error, Layout, read_csv, read_mvnx};

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(rel)
}

fn layout() -> Layout {
    Layout::load(&fixture("csv/one-file.toml")).unwrap()
}

/// Asserts `e` is at `line` of a file named `file` and its message holds every one of `words`.
fn assert_at(e: &Error, file: &str, line: Option<usize>, words: &[&str]) {
    let text = e.to_string();
    let (path, got_line) = match e {
        Error::Line { path, line, .. } => (path, Some(*line)),
        Error::File { path, .. } | Error::Io { path, .. } => (path, None),
    };
    assert!(path.ends_with(file), "names {file}: {text}");
    assert_eq!(got_line, line, "line: {text}");
    for w in words {
        assert!(text.contains(w), "'{w}' in: {text}");
    }
}

fn csv_error(name: &str) -> Error {
    read_csv(&fixture(&format!("malformed/{name}")), &layout()).unwrap_err()
}

#[test]
fn a_bad_number_names_line_and_column() {
    assert_at(
        &csv_error("bad-number.csv"),
        "bad-number.csv",
        Some(4),
        &["'la_gy'", "bad number 'abc'"],
    );
}

#[test]
fn a_missing_column_names_it_and_the_columns_there_are() {
    assert_at(
        &csv_error("missing-column.csv"),
        "missing-column.csv",
        None,
        &["no column 'la_mz'", "'la_mzz'"],
    );
}

#[test]
fn a_short_row_names_its_line_and_the_column_it_lacks() {
    assert_at(
        &csv_error("short-row.csv"),
        "short-row.csv",
        Some(5),
        &["short row", "8 cells", "'la_my'"],
    );
}

#[test]
fn time_going_backwards_is_an_error() {
    assert_at(
        &csv_error("backwards-time.csv"),
        "backwards-time.csv",
        Some(5),
        &["does not increase", "'time_ms'"],
    );
}

#[test]
fn a_quaternion_far_from_unit_length_is_an_error() {
    assert_at(
        &csv_error("bad-quaternion.csv"),
        "bad-quaternion.csv",
        Some(4),
        &["norm 2", "'la_qx'"],
    );
}

#[test]
fn a_wrong_unit_name_in_the_layout_names_its_line() {
    let e = Layout::load(&fixture("malformed/wrong-unit.toml")).unwrap_err();
    assert_at(&e, "wrong-unit.toml", Some(10), &["kg", "m/s2"]);
}

#[test]
fn an_unknown_site_in_the_layout_lists_the_sites() {
    let e = Layout::load(&fixture("malformed/unknown-site.toml")).unwrap_err();
    assert_at(
        &e,
        "unknown-site.toml",
        None,
        &["[sensors.left_arm]", "unknown site", "left_forearm"],
    );
}

#[test]
fn layout_contradictions_are_named() {
    let bad = [
        (
            "[time]\nrate_hz = 60\n[sensors.pelvis]\nfree_acceleration = [2, 3, 4]\n",
            "needs the orientation",
        ),
        (
            "[time]\ncolumn = \"t\"\n[sensors.pelvis]\naccelerometer = [\"a\", \"b\", \"c\"]\n",
            "`unit`",
        ),
        (
            "[time]\nrate_hz = 60\n[sensors.pelvis]\naxes = [\"y\", \"x\", \"z\"]\naccelerometer = [1, 2, 3]\n",
            "right-handed",
        ),
        (
            "[table]\nheader = false\n[time]\nrate_hz = 60\n[sensors.pelvis]\naccelerometer = [\"a\", 2, 3]\n",
            "column numbers",
        ),
        (
            "[time]\nrate_hz = 60\n[sensors.pelvis]\naccelerometer = [0, 1, 2]\n",
            "numbered from 1",
        ),
        (
            "[time]\nrate_hz = 60\n[sensors.pelvis]\nacceleromter = [1, 2, 3]\n",
            "acceleromter",
        ),
        ("[time]\nrate_hz = 60\n", "no [sensors.<site>]"),
    ];
    for (text, want) in bad {
        let e = Layout::parse(text, Path::new("l.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("l.toml") && e.contains(want),
            "'{want}' in: {e}"
        );
    }
}

#[test]
fn an_mvnx_without_one_of_our_sensors_names_it() {
    let e = read_mvnx(&fixture("malformed/unknown-label.mvnx")).unwrap_err();
    assert_at(
        &e,
        "unknown-label.mvnx",
        None,
        &["no sensor 'LeftLowerLeg'", "left_lower_leg", "LeftForeArm"],
    );
}

#[test]
fn broken_xml_names_its_line() {
    let e = read_mvnx(&fixture("malformed/broken.mvnx")).unwrap_err();
    assert_at(&e, "broken.mvnx", Some(69), &["broken XML"]);
}

#[test]
fn a_bad_number_in_mvnx_names_element_and_line() {
    let e = read_mvnx(&fixture("malformed/bad-number.mvnx")).unwrap_err();
    assert_at(
        &e,
        "bad-number.mvnx",
        Some(71),
        &["<sensorFreeAcceleration>", "bad number 'zero'"],
    );
}

#[test]
fn a_wrong_number_count_in_mvnx_names_the_frame() {
    let e = read_mvnx(&fixture("malformed/wrong-count.mvnx")).unwrap_err();
    assert_at(
        &e,
        "wrong-count.mvnx",
        Some(68),
        &[
            "<sensorFreeAcceleration> has 52 numbers",
            "3 for each of 17",
        ],
    );
}

#[test]
fn a_truncated_mvnx_is_an_error() {
    let e = read_mvnx(&fixture("malformed/truncated.mvnx")).unwrap_err();
    assert!(
        e.to_string().contains("truncated.mvnx") && e.to_string().contains("ends inside"),
        "{e}"
    );
}

#[test]
fn a_file_without_data_rows_is_an_error() {
    assert_at(
        &csv_error("no-rows.csv"),
        "no-rows.csv",
        None,
        &["no samples"],
    );
}

#[test]
fn a_missing_file_names_it() {
    let e = read_mvnx(&fixture("malformed/nothing-here.mvnx")).unwrap_err();
    assert_at(&e, "nothing-here.mvnx", None, &["nothing-here.mvnx"]);
    let e = read_csv(&fixture("malformed/nothing-here.csv"), &layout()).unwrap_err();
    assert_at(&e, "nothing-here.csv", None, &["no such file"]);
}
