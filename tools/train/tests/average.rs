//! `imuflow average-weights`: the mean against values derived by hand (a file and its tensors
//! scaled by 3 and by −1 average to the file scaled by 1), every refusal naming the file and what
//! differs, and the shipped GlobalPose file being exactly the average its provenance names.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use imuflow_kinematics::Method;
use imuflow_kinematics::weights::{self, WeightsMetadata};
use imuflow_train::average::average_weights;
use imuflow_train::import::import_checkpoint;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// A small weight file of `method` (the import test's checkpoint) in `dir`.
fn small_weights(dir: &Path, method: Method) -> PathBuf {
    let out = dir.join(format!("{}.safetensors", method.name()));
    import_checkpoint(
        method,
        &fixture(&format!("{}-small.pt", method.name())),
        &out,
    )
    .unwrap();
    out
}

fn read(path: &Path) -> (HashMap<String, Tensor>, WeightsMetadata) {
    let bytes = std::fs::read(path).unwrap();
    let tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).unwrap();
    let meta = weights::read_metadata(&bytes)
        .unwrap()
        .expect("imuflow metadata");
    (tensors, meta)
}

/// `path`'s tensors passed through `f`, written to `out` with `meta`.
fn rewrite(
    path: &Path,
    out: &Path,
    f: impl Fn(&str, &Tensor) -> Tensor,
    meta: impl Fn(&mut WeightsMetadata),
) -> PathBuf {
    let (tensors, mut metadata) = read(path);
    let mut named: Vec<(String, Tensor)> =
        tensors.iter().map(|(n, t)| (n.clone(), f(n, t))).collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    meta(&mut metadata);
    weights::save(out, &named, &metadata).unwrap();
    out.to_owned()
}

fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

#[test]
fn the_mean_of_a_file_scaled_by_3_and_by_minus_1_is_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let base = small_weights(dir.path(), Method::GlobalPose);
    let times = |k: f64| move |_: &str, t: &Tensor| (t * k).unwrap();
    let three = rewrite(&base, &dir.path().join("three.st"), times(3.0), |_| {});
    let minus = rewrite(&base, &dir.path().join("minus.st"), times(-1.0), |_| {});
    let out = dir.path().join("mean.safetensors");
    average_weights(&[three.clone(), minus, base.clone()], &out, "cmd").unwrap();

    // (3x − x + x) / 3 = x
    let (want, _) = read(&base);
    let (got, meta) = read(&out);
    assert_eq!(got.len(), want.len());
    for (name, w) in &want {
        for (g, w) in values(&got[name]).iter().zip(values(w)) {
            assert!(
                (g - w).abs() <= 1e-6 * w.abs().max(1.0),
                "{name}: {g} vs {w}"
            );
        }
    }
    let p = &meta.provenance;
    assert_eq!(p["command"], "cmd");
    let ingredients = p["ingredients"].as_array().unwrap();
    assert_eq!(ingredients.len(), 3);
    // Files as named, each with its hash and its own provenance; never a machine path.
    assert_eq!(ingredients[0]["file"], "three.st");
    assert_eq!(ingredients[0]["sha256"].as_str().unwrap().len(), 64);
    assert!(ingredients[2]["provenance"].is_string() || ingredients[2]["provenance"].is_object());
    assert_eq!(meta.method, Method::GlobalPose);
}

#[test]
fn files_that_do_not_match_are_refused_with_the_file_and_the_difference() {
    let dir = tempfile::tempdir().unwrap();
    let gp = small_weights(dir.path(), Method::GlobalPose);
    let pip = small_weights(dir.path(), Method::Pip);
    let out = dir.path().join("out.safetensors");
    let err = |inputs: &[PathBuf]| {
        let e = average_weights(inputs, &out, "cmd").unwrap_err();
        assert!(!out.exists(), "nothing is written on a refusal");
        format!("{e:#}")
    };

    let e = err(std::slice::from_ref(&gp));
    assert!(e.contains("at least two"), "{e}");

    let e = err(&[gp.clone(), pip.clone()]);
    assert!(
        e.contains("pip.safetensors") && e.contains("pip networks"),
        "{e}"
    );

    let missing = dir.path().join("none.safetensors");
    let e = err(&[gp.clone(), missing]);
    assert!(e.contains("none.safetensors"), "{e}");

    let text = dir.path().join("notes.safetensors");
    std::fs::write(&text, "not weights").unwrap();
    let e = err(&[gp.clone(), text]);
    assert!(
        e.contains("notes.safetensors") && e.contains("not a safetensors"),
        "{e}"
    );

    // The same tensors under other metadata.
    let relabelled = |file: &str, change: fn(&mut WeightsMetadata)| {
        rewrite(&gp, &dir.path().join(file), |_, t| t.clone(), change)
    };
    let relicensed = relabelled("relicensed.st", |m| m.licence = "MIT".into());
    let e = err(&[gp.clone(), relicensed]);
    assert!(e.contains("relicensed.st") && e.contains("licence"), "{e}");

    let renormalized = relabelled("renormalized.st", |m| m.normalization = "other".into());
    let e = err(&[gp.clone(), renormalized]);
    assert!(
        e.contains("renormalized.st") && e.contains("normaliz"),
        "{e}"
    );

    // A diverged run's NaN: refused, naming the file and the tensor.
    let diverged = rewrite(
        &gp,
        &dir.path().join("diverged.st"),
        |n, t| {
            if n == "plnet.linear2.bias" {
                (t * f64::NAN).unwrap()
            } else {
                t.clone()
            }
        },
        |_| {},
    );
    let e = err(&[gp.clone(), diverged]);
    assert!(
        e.contains("diverged.st") && e.contains("plnet.linear2.bias") && e.contains("not finite"),
        "{e}"
    );
}

#[test]
fn the_shipped_globalpose_file_is_the_average_its_provenance_names() {
    let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models");
    let shipped = models.join("globalpose.safetensors");
    let (want, meta) = read(&shipped);
    let command = meta.provenance["command"]
        .as_str()
        .expect("an averaged file");
    let inputs: Vec<PathBuf> = meta.provenance["ingredients"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| models.join("..").join(i["file"].as_str().unwrap()))
        .collect();
    assert_eq!(inputs.len(), 3, "{command}");

    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("again.safetensors");
    average_weights(&inputs, &out, command).unwrap();
    let (got, again) = read(&out);
    for (name, w) in &want {
        assert_eq!(values(&got[name]), values(w), "{name}");
    }
    // And the ingredients are the files it names, byte for byte.
    let hashes = |p: &serde_json::Value| -> Vec<String> {
        p["ingredients"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["sha256"].as_str().unwrap().to_owned())
            .collect()
    };
    assert_eq!(hashes(&again.provenance), hashes(&meta.provenance));
}
