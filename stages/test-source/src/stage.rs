//! The `test-source` stage process: publishes the synthetic frames of [`crate::synthesize`] on
//! output `imu`, paced to the graph's rate in a live graph.

use std::time::{Duration, Instant};

use anyhow::Context;
use imuflow_body::NUM_IMUS;
use imuflow_graph::frames::{FrameHeader, ImuFrame, flags};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::stage::Step;
use imuflow_graph::transport::now_ns;
use imuflow_graph::{FrameType, Mode, StageContext};

use crate::motion::{SensorMotion, synthesize};

imuflow_graph::stage_params! {
    /// The test source's parameters.
    pub struct TestSourceParams {
        /// number of frames to emit before END_OF_STREAM (600 = 10 s at 60 Hz)
        frames: u64 = 600, int(0, 1 << 40);
        /// selects the motion (amplitudes, frequencies, phases)
        seed: u64 = 0, int(0, i64::MAX);
        /// every N-th frame sensor 0 reports NaN (valid bit cleared, frame INVALID); 0 = never
        invalid_every: u64 = 0, int(0, 1 << 40);
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "test-source",
    role: Role::Source,
    summary: "deterministic synthetic IMU frames (sensors rotating about fixed axes) for testing graphs",
    inputs: InputsSpec::Fixed(&[]),
    outputs: &[PortSpec {
        name: "imu",
        frame: FrameType::Imu,
        required: false,
        doc: "six IMUs, orientation/specific force/angular rate in the sensor frame",
    }],
    params: TestSourceParams::SPECS,
};

/// Runs the test source as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let TestSourceParams {
        frames,
        seed,
        invalid_every,
    } = TestSourceParams::from_params(ctx.params());
    let rate_hz = ctx.graph().rate_hz;
    let live = ctx.mode() == Mode::Live;
    let motions = SensorMotion::for_seed(seed);
    let mut out = ctx.output::<ImuFrame>("imu")?;
    if !ctx.ready()? {
        ctx.finish(&mut [&mut out])?;
        return Ok(());
    }
    let start = Instant::now();
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    for seq in 0..frames {
        if ctx.should_stop() {
            break;
        }
        if live {
            // Pace to the sensor rate against the start, so the rate does not drift.
            let due = start + period.mul_f64(seq as f64);
            imuflow_graph::wait::sleep_until(due);
        }
        let t0 = Instant::now();
        let capture_ns = if live {
            now_ns()
        } else {
            (seq as f64 * 1e9 / rate_hz) as u64
        };
        let mut header = FrameHeader {
            seq,
            capture_ns,
            ..Default::default()
        };
        let mut flags_out = 0;
        out.publish(header, |f| {
            synthesize(f, &motions, seq, rate_hz, invalid_every);
            if f.valid_mask != (1 << NUM_IMUS) - 1 {
                f.header.flags |= flags::INVALID;
                flags_out = flags::INVALID;
            }
        })
        .with_context(|| format!("publishing frame {seq}"))?;
        header.flags = flags_out;
        ctx.record_source_step(
            Step {
                seq,
                capture_ns,
                flags: header.flags,
            },
            t0.elapsed(),
        );
        if seq % 30 == 0 || seq + 1 == frames {
            ctx.progress(seq + 1, frames)?;
        }
    }
    ctx.finish(&mut [&mut out])?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<TestSourceParams>().unwrap();
    }
}
