//! `imuflow dataset build`'s augmentation options: values that make no sense are refused with the
//! option named, before any clip is read.

mod common;

use common::{Sandbox, text};

#[test]
fn nonsense_augmentation_ranges_are_refused_by_name() {
    let sb = Sandbox::new("dataset-cli");
    let (input, out) = (sb.path("bvh"), sb.path("ds"));
    std::fs::create_dir_all(&input).unwrap();
    for (option, value) in [
        ("--vary-stature", "1.9,1.5"),
        ("--vary-stature", "1.6"),
        ("--vary-stature", "0.5,1.8"),
        ("--speeds", "0"),
    ] {
        let result = sb.run(&[
            "dataset",
            "build",
            "--bvh-dir",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            option,
            value,
            "--no-progress",
        ]);
        let stderr = text(&result.stderr);
        assert!(!result.status.success(), "{option} {value} was accepted");
        assert!(
            stderr.contains(&format!("error: {option}: ")),
            "{option} {value}: {stderr}"
        );
        assert!(!out.exists(), "{option} {value}: wrote {}", out.display());
    }
}
