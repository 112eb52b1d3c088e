//! Checkpoint import against an independent computation: `make_checkpoint_fixture.py` wrote small
//! checkpoints in torch.save's format with the authors' key names and the streaming outputs of every
//! net computed in plain Python (`*-expected.json`). Importing and streaming must reproduce them.

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use imuflow_kinematics::Method;
use imuflow_kinematics::features::InputOrder;
use imuflow_kinematics::weights::{Weights, nets_from_tensors};
use imuflow_train::import::{import_checkpoint, read_checkpoint};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn check_method(method: Method) {
    let stem = method.name();
    let out = std::env::temp_dir().join(format!(
        "imuflow-import-{stem}-{}.safetensors",
        std::process::id()
    ));
    import_checkpoint(method, &fixture(&format!("{stem}-small.pt")), &out).unwrap();
    let weights = Weights::load(&out, method).unwrap();
    std::fs::remove_file(&out).ok();
    let expected: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixture(&format!("{stem}-small-expected.json"))).unwrap(),
    )
    .unwrap();
    let mut worst = 0.0f64;
    for net in &weights.nets {
        let e = &expected["nets"][&net.spec.name];
        let vec = |v: &serde_json::Value| -> Vec<f32> {
            v.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32)
                .collect()
        };
        let init = (!e["init"].is_null())
            .then(|| Tensor::from_vec(vec(&e["init"]), (1, ()), &Device::Cpu).unwrap());
        let mut state = net.initial_state(1, init.as_ref()).unwrap();
        let inputs = e["inputs"].as_array().unwrap();
        let outputs = e["outputs"].as_array().unwrap();
        assert_eq!(inputs.len(), outputs.len());
        for (x, want) in inputs.iter().zip(outputs) {
            let x = Tensor::from_vec(vec(x), (1, ()), &Device::Cpu).unwrap();
            let y: Vec<f32> = net
                .step(&x, &mut state)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap();
            let want = vec(want);
            assert_eq!(y.len(), want.len(), "{}", net.spec.name);
            for (a, b) in y.iter().zip(&want) {
                worst = worst.max((a - b).abs() as f64);
            }
        }
    }
    assert!(
        worst < 1e-4,
        "{stem}: largest difference to the Python reference {worst}"
    );
}

#[test]
fn imported_pip_checkpoint_streams_like_the_reference() {
    check_method(Method::Pip);
}

#[test]
fn imported_globalpose_checkpoint_streams_like_the_reference() {
    check_method(Method::GlobalPose);
}

#[test]
fn wrong_method_and_corrupt_files_are_named() {
    // A GlobalPose checkpoint is not PIP: the first foreign tensor is named.
    let err = read_checkpoint(Method::Pip, &fixture("globalpose-small.pt"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("not used by the pip networks"), "{err}");
    // Not a checkpoint at all.
    let err = read_checkpoint(Method::Pip, &fixture("pip-small-expected.json"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("pip-small-expected.json") && err.contains("not a PyTorch checkpoint"),
        "{err}"
    );
    let err = read_checkpoint(Method::Pip, &fixture("missing.pt"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("missing.pt") && err.contains("no such file"),
        "{err}"
    );
}

#[test]
fn missing_and_misshapen_tensors_are_named() {
    let mut tensors = read_checkpoint(Method::Pip, &fixture("pip-small.pt")).unwrap();
    let good = tensors.clone();
    tensors.remove("rnn3.rnn.bias_hh_l1");
    let err = nets_from_tensors(Method::Pip, &tensors, &InputOrder::six())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("rnn3.rnn.bias_hh_l1") && err.contains("missing"),
        "{err}"
    );
    // rnn2 reading 70 inputs instead of [leaf 15, imu 72] = 87.
    let mut tensors = good;
    tensors.insert(
        "rnn2.linear1.weight".into(),
        Tensor::zeros((12, 70), candle_core::DType::F32, &Device::Cpu).unwrap(),
    );
    let err = nets_from_tensors(Method::Pip, &tensors, &InputOrder::six())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("rnn2.linear1.weight") && err.contains("87"),
        "{err}"
    );
}
