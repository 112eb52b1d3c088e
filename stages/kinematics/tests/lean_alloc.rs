//! The lean step allocates nothing: every buffer it writes is made when the net is built.

use std::path::Path;

use imuflow_kinematics::Method;
use imuflow_kinematics::lean::LeanRnn;
use imuflow_kinematics::weights::Weights;

// The body crate's counting allocator (its integration tests' shared module), compiled in here.
#[path = "../../../libs/body/tests/common/mod.rs"]
mod common;

use common::{Counting, allocations};

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn lean_step_allocates_nothing() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    for (method, file) in [
        (Method::Pip, "models/pip.safetensors"),
        (Method::GlobalPose, "models/globalpose.safetensors"),
    ] {
        let weights = Weights::load(&root.join(file), method).unwrap();
        for net in &weights.nets {
            let mut lean = LeanRnn::new(net).unwrap();
            let x: Vec<f32> = (0..net.spec.input).map(|k| (k as f32).sin()).collect();
            let before = allocations();
            let mut sum = 0.0;
            for _ in 0..20 {
                sum += lean.step(&x).iter().sum::<f32>();
            }
            let made = allocations() - before;
            assert_eq!(made, 0, "{}: {made} allocations in 20 steps", net.spec.name);
            assert!(sum.is_finite() && sum != 0.0, "{}: {sum}", net.spec.name);
        }
    }
}
