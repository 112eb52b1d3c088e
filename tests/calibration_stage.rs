//! The calibration stage's refusals before it calibrates anything, through the binary.

mod common;

use common::*;

#[test]
fn a_capture_days_headings_without_its_file_are_refused_naming_both_settings() {
    let sb = Sandbox::new("calib-headings");
    let out = sb
        .command(&[
            "run",
            "configs/examples/calibrate-walking.toml",
            "--no-progress",
            "--set",
            "stages.calib.params.headings=recording",
            "--set",
            &format!("stages.record.params.path={}", sb.path("c.mcap").display()),
            "--set",
            &format!("stages.viz.params.path={}", sb.path("c.rrd").display()),
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run imuflow");
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("stage 'calib'")
            && stderr.contains("params.headings = \"recording\"")
            && stderr.contains("set params.from_file"),
        "{stderr}"
    );
    assert_clean(&sb);
}
