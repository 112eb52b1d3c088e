//! The BVH reader must never panic: every truncation and corruption of a real file gives either a
//! valid result or an error that names the file and a line inside it.

use std::path::Path;

use imuflow_body::{BodyModel, BodyParams};
use imuflow_motion::bvh::{Bvh, BvhErrorKind};
use imuflow_motion::retarget::{RetargetOptions, SourceSkeleton, retarget_bvh};

fn fixture_text() -> String {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/bandai-walk-normal-trimmed.bvh");
    std::fs::read_to_string(p).unwrap()
}

/// The fixture cut down to its first three frames (header updated), to keep thousands of parses fast.
fn short_text() -> String {
    let text = fixture_text();
    let lines: Vec<&str> = text.lines().collect();
    let motion = lines.iter().position(|l| *l == "MOTION").unwrap();
    let mut out: Vec<String> = lines[..=motion].iter().map(|l| l.to_string()).collect();
    out.push("Frames: 3".into());
    out.extend(lines[motion + 2..motion + 6].iter().map(|l| l.to_string()));
    out.join("\n") + "\n"
}

#[test]
fn every_truncation_fails_cleanly_with_a_line_inside_the_file() {
    let text = short_text();
    assert!(text.is_ascii());
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.7, 65.0).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    // Cut at every byte of the first 3000 (deep inside the hierarchy), then every 13th byte.
    let cuts = (0..3000).chain((3000..text.len() - 1).step_by(13));
    for cut in cuts {
        let part = &text[..cut];
        let lines = part.lines().count().max(1);
        match Bvh::parse(part, "cut.bvh") {
            Ok(bvh) => {
                // Parsing succeeds only when the cut removed nothing but trailing whitespace.
                let all = text.split_whitespace().count();
                assert_eq!(
                    part.split_whitespace().count(),
                    all,
                    "cut at byte {cut} parsed"
                );
                assert_eq!(bvh.num_frames(), 3);
            }
            Err(e) => {
                assert!(
                    e.line >= 1 && e.line <= lines,
                    "cut {cut}: line {} of {lines}",
                    e.line
                );
                assert!(e.to_string().starts_with(&format!("cut.bvh:{}: ", e.line)));
            }
        }
    }
    // The full text parses and retargets.
    let bvh = Bvh::parse(&text, "full.bvh").unwrap();
    assert!(retarget_bvh(&bvh, &map, &body, &RetargetOptions::default()).is_ok());
}

#[test]
fn corrupting_any_single_token_never_panics() {
    let text = short_text();
    let body = BodyModel::new(&BodyParams::builtin().unwrap(), 1.7, 65.0).unwrap();
    let map = SourceSkeleton::bandai_namco().unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 137);
    let mut errors = 0;
    // Replace each token of the hierarchy (and the first frame line) with junk of several kinds.
    for (li, line) in lines.iter().enumerate().take(136) {
        let tokens: Vec<&str> = line.split_whitespace().collect();
        for ti in 0..tokens.len() {
            for junk in ["", "NaN", "1e999", "x", "{", "}", "-1", "JOINT"] {
                let mut t = tokens.clone();
                t[ti] = junk;
                let mut out = lines.clone();
                let new_line = t.join(" ");
                out[li] = &new_line;
                let corrupted = out.join("\n");
                match Bvh::parse(&corrupted, "c.bvh") {
                    Ok(bvh) => {
                        // Some substitutions stay valid (a different number); they must retarget or
                        // fail with a typed error, never panic.
                        let _ = retarget_bvh(&bvh, &map, &body, &RetargetOptions::default());
                    }
                    Err(e) => {
                        errors += 1;
                        assert!(e.line >= 1 && e.line <= out.len(), "{e}");
                        if junk == "NaN" || junk == "1e999" {
                            // A non-finite number where a number belongs is reported as such.
                            if tokens[ti].parse::<f64>().is_ok() && li >= 134 {
                                assert!(matches!(e.kind, BvhErrorKind::NonFinite { .. }), "{e}");
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(errors > 1000, "only {errors} corruptions were rejected");
}
