//! `imuflow export` on the command line: the sample's truth exported (exit 0, what was written
//! said), bad input refused with exit 2, the file and channel named, and no output file.

mod common;

use common::{Sandbox, text};

const SAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/sample/walk.mcap");

#[test]
fn the_sample_exports_and_bad_input_exits_2_with_nothing_written() {
    let sb = Sandbox::new("export-cli");
    let out = sb.path("truth.bvh");
    let out_s = out.to_str().expect("utf8");
    let args = [
        "export",
        SAMPLE,
        "--channel",
        "source.truth",
        "--format",
        "bvh",
        "-o",
        out_s,
    ];
    let run = sb.run(&args);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let said = text(&run.stdout);
    // models/sample/README.md: 1511 frames; the prelude before frame 732 is left out.
    assert!(
        said.contains("779 frames of 'source.truth' at 60 Hz, from frame 732"),
        "{said}"
    );
    assert!(std::fs::metadata(&out).is_ok_and(|m| m.len() > 10_000));

    let bad = sb.path("bad.npz");
    let bad_s = bad.to_str().expect("utf8");
    for (channel, expect) in [
        ("opt.motion", "no channel 'opt.motion'"),
        (
            "source.imu",
            "channel 'source.imu' carries imuflow.ImuFrame",
        ),
    ] {
        let run = sb.run(&[
            "export",
            SAMPLE,
            "--channel",
            channel,
            "--format",
            "npz",
            "-o",
            bad_s,
        ]);
        let stderr = text(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains("walk.mcap") && stderr.contains(expect),
            "{stderr}"
        );
        assert!(!bad.exists(), "no partial output");
    }
}
