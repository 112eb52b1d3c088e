//! The lean step allocates nothing: every buffer it writes is made when the net is built.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use imuflow_kinematics::Method;
use imuflow_kinematics::lean::LeanRnn;
use imuflow_kinematics::weights::Weights;

/// Counts this thread's allocations (the test harness's own thread allocates now and then).
struct Counting;

thread_local! {
    // A const initializer: reading it never allocates (which would recurse into the allocator).
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // `try_with`: during thread teardown the slot may be gone; such allocations are not ours.
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: forwarding the caller's layout to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

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
            let before = ALLOCATIONS.with(Cell::get);
            let mut sum = 0.0;
            for _ in 0..20 {
                sum += lean.step(&x).iter().sum::<f32>();
            }
            let made = ALLOCATIONS.with(Cell::get) - before;
            assert_eq!(made, 0, "{}: {made} allocations in 20 steps", net.spec.name);
            assert!(sum.is_finite() && sum != 0.0, "{}: {sum}", net.spec.name);
        }
    }
}
