//! The `fusion` stage process: reads `raw`, writes `imu`, logs what it counted.

use anyhow::{Context, bail};
use imuflow_graph::frames::{ImuFrame, RawImuFrame};
use imuflow_graph::spec::{InputsSpec, PortSpec, Role, StageSpec};
use imuflow_graph::stage::EndOutput;
use imuflow_graph::transport::{Output, TransportError};
use imuflow_graph::{FrameType, Mode, StageContext};

use crate::assembler::{Assembler, Notice, Origin, Settings};
use crate::filter::VqfParams;
use crate::sensor::{Latency, MagnetometerUse, OrientationSource, SensorSettings};
use crate::sensor_name;
use imuflow_body::{Imu, SiteMask};

imuflow_graph::stage_params! {
    /// The fusion stage's parameters.
    pub struct FusionParams {
        /// auto: a sensor's on-board orientation when its first sample carries one, else fused;
        /// fuse: always fused (VQF); onboard: on-board only (a sample without one is an error)
        orientation: String = "auto", choice(&["auto", "fuse", "onboard"]);
        /// auto: 9D (ENU earth frame) for samples with a magnetometer reading; ignore: 6D always
        magnetometer: String = "auto", choice(&["auto", "ignore"]);
        // Laidig & Seel 2023, Table 1: the authors' defaults.
        /// VQF: time constant of the accelerometer (inclination) correction, s
        tau_acc_s: f64 = 3, float(0.01, 1000.0);
        /// VQF: time constant of the magnetometer (heading) correction, s
        tau_mag_s: f64 = 9, float(0.01, 1000.0);
        /// VQF: rest detection and gyroscope bias estimation at rest
        rest_bias: bool = true, bool;
        // VQF's default is 1.5 s and 2°/s; a natural recording's stand may last 0.3–0.7 s, and
        // consumer MEMS gyroscopes have biases up to ±3°/s (BMI160 data sheet), which VQF with a
        // 2°/s clip never detects at rest: with VQF's values the raw-sensor graph is refused
        // (docs/real-sensors.md). 0.25 s, not 0.5: after a 0.5 s stand, without a magnetometer,
        // SIP +4.9/+6.2/+2.9/+3.3° against ideal sensors (seeds 3-6) with 0.5, +0.8/+1.1/+2.3/
        // +1.6° with 0.25; after 1 s within 0.1° (journal 2026-11-29-natural-start-onset-and-facing).
        /// VQF: how long a sensor must be still before rest is detected (and its gyroscope bias
        /// estimated), s
        rest_min_s: f64 = 0.25, float(0.1, 60.0);
        /// VQF: largest gyroscope bias estimated, per axis, deg/s (a sensor with a larger bias
        /// is never detected at rest)
        bias_clip_dps: f64 = 5, float(0.1, 100.0);
        /// VQF: magnetic disturbance detection and rejection
        mag_rejection: bool = true, bool;
        /// every sensor's sample rate, Hz (0: measured per sensor from its timestamps)
        sensor_rate_hz: f64 = 0, float(0.0, 100000.0);
        /// a sensor without a sample for longer than this is missing (its frames INVALID);
        /// shorter gaps are interpolated, ms
        max_gap_ms: Option<f64> = computed("50 live, 100 offline"), float(0.1, 600000.0);
        /// an output frame waits at most this long (source time) for a late sensor, ms (latency
        /// smooth; offline at least max_gap_ms, so a lost packet's gap is interpolated over
        /// instead of the frame going out without the sensor)
        max_latency_ms: f64 = 30, float(0.0, 600000.0);
        /// low: a frame goes out as soon as a sample from half an interval before its time on
        /// arrived, sensors behind extrapolated (at most one sample interval), no band limit; smooth: accelerometer and
        /// gyroscope band-limited, a frame waits for every sensor (10-30 ms more); auto: low in
        /// live graphs, smooth offline
        latency: String = "auto", choice(&["auto", "low", "smooth"]);
    }
}

/// `max_gap_ms` when a graph leaves it unset.
pub const LIVE_MAX_GAP_MS: f64 = 50.0;
pub const OFFLINE_MAX_GAP_MS: f64 = 100.0;

impl FusionParams {
    /// The stage's configuration at the graph's rate (> 0) and mode.
    pub fn settings(&self, rate_hz: f64, mode: Mode) -> anyhow::Result<Settings> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            bail!("the graph's rate_hz must be positive, got {rate_hz}");
        }
        let orientation = match self.orientation.as_str() {
            "auto" => OrientationSource::Auto,
            "fuse" => OrientationSource::Fuse,
            "onboard" => OrientationSource::Onboard,
            other => bail!("params.orientation: unknown '{other}' (auto, fuse, onboard)"),
        };
        let magnetometer = match self.magnetometer.as_str() {
            "auto" => MagnetometerUse::Auto,
            "ignore" => MagnetometerUse::Ignore,
            other => bail!("params.magnetometer: unknown '{other}' (auto, ignore)"),
        };
        let latency = match (self.latency.as_str(), mode) {
            ("low", _) | ("auto", Mode::Live) => Latency::Low,
            ("smooth", _) | ("auto", Mode::Offline) => Latency::Smooth,
            (other, _) => bail!("params.latency: unknown '{other}' (auto, low, smooth)"),
        };
        let max_gap_ms = self.max_gap_ms.unwrap_or(match mode {
            // Live, a sensor that long without a sample is shown missing rather than held.
            Mode::Live => LIVE_MAX_GAP_MS,
            // Offline nobody waits, and a gap is better filled than left out: wireless sensors
            // lose packets in runs (a Movella DOT export: runs of 3-4 at 60 Hz, gaps of 67-83
            // ms; an x-IMU3 at 50 Hz: 60 ms), and each frame left without a sensor is INVALID
            // and breaks a natural start's walk (journal 2026-11-29-lost-packets-offline).
            Mode::Offline => OFFLINE_MAX_GAP_MS,
        });
        Ok(Settings {
            sensor: SensorSettings {
                vqf: VqfParams {
                    tau_acc_s: self.tau_acc_s,
                    tau_mag_s: self.tau_mag_s,
                    rest_bias: self.rest_bias,
                    rest_min_s: self.rest_min_s,
                    bias_clip_dps: self.bias_clip_dps,
                    mag_rejection: self.mag_rejection,
                },
                orientation,
                magnetometer,
                sensor_rate_hz: (self.sensor_rate_hz > 0.0).then_some(self.sensor_rate_hz),
                max_gap_s: max_gap_ms * 1e-3,
                output_rate_hz: rate_hz,
                latency,
            },
            // Offline nobody waits for a frame: it waits for a sensor as long as a gap it would
            // fill lasts (a lost packet of a 50 Hz x-IMU3 is a 40 ms gap; at the 30 ms deadline
            // the frame went out without that sensor, and a natural start with it).
            max_latency_s: match mode {
                Mode::Live => self.max_latency_ms,
                Mode::Offline => self.max_latency_ms.max(max_gap_ms),
            } * 1e-3,
            origin: match mode {
                Mode::Live => Origin::FirstCapture,
                Mode::Offline => Origin::Zero,
            },
            sites: SiteMask::of(Imu::SIX),
        })
    }
}

pub const SPEC: StageSpec = StageSpec {
    kind: "fusion",
    role: Role::Transform,
    summary: "raw IMU samples on each sensor's clock -> oriented IMU frames at the graph's rate (VQF, clock alignment, resampling)",
    inputs: InputsSpec::Fixed(&[PortSpec {
        name: "raw",
        frame: FrameType::RawImu,
        required: true,
        doc: "raw accelerometer, gyroscope, magnetometer (and on-board orientation) samples, each sensor on its own clock and rate",
    }]),
    outputs: &[PortSpec {
        name: "imu",
        frame: FrameType::Imu,
        required: false,
        doc: "per sensor R_IS (VQF earth frame, z up; ENU with a magnetometer), specific force and angular rate in S at the graph's rate; seq k at k / rate_hz; INVALID where a sensor has no sample",
    }],
    params: FusionParams::SPECS,
};

/// The output, closed with END_OF_STREAM numbered after the stage's own last frame (the input's
/// numbering is the raw frames', not the output grid's).
struct EndAfter<'a> {
    output: &'a mut Output<ImuFrame>,
    seq: u64,
    capture_ns: u64,
}

impl EndOutput for EndAfter<'_> {
    fn end(&mut self, _input_seq: u64, _input_capture_ns: u64) -> Result<(), TransportError> {
        self.output.publish_end(self.seq, self.capture_ns)
    }
    fn frames_sent(&self) -> u64 {
        self.output.sent()
    }
}

/// Runs the fusion as the current process's stage.
pub fn run() -> anyhow::Result<()> {
    let mut ctx = StageContext::from_env()?;
    let stage = ctx.id().to_owned();
    let params = FusionParams::from_params(ctx.params());
    let mut settings = params
        .settings(ctx.graph().rate_hz, ctx.mode())
        .with_context(|| format!("stage '{stage}'"))?;
    settings.sites = imuflow_body::SensorSet::resolve(ctx.sensors())
        .with_context(|| format!("stage '{stage}': `sensors`"))?
        .mask();
    let input = ctx.input::<RawImuFrame>("raw")?;
    let mut output = ctx.output::<ImuFrame>("imu")?;
    if !ctx.ready()? {
        ctx.finish(&mut [&mut output])?;
        return Ok(());
    }
    let mut assembler = Assembler::new(settings);
    let mut frames = Vec::new();
    let mut outcome = Ok(());
    while let Some(step) = ctx.next()? {
        let raw = *ctx.get(&input);
        outcome = assembler.push(&raw, &mut frames);
        publish(&stage, &mut output, &mut frames, &mut assembler)
            .with_context(|| format!("stage '{stage}': after raw frame {}", step.seq))?;
        if outcome.is_err() {
            break;
        }
    }
    // END_OF_STREAM goes downstream after what can still be emitted, also when the input was bad.
    if outcome.is_ok() {
        outcome = assembler.finish(&mut frames);
    }
    publish(&stage, &mut output, &mut frames, &mut assembler)
        .with_context(|| format!("stage '{stage}': at the end"))?;
    for line in sensor_lines(&assembler) {
        tracing::info!(stage, "{line}");
    }
    let line = summary_line(&assembler);
    tracing::info!(stage, "{line}");
    ctx.set_summary_detail(line);
    let next = assembler.counters().frames;
    let capture_ns = assembler.time_of(next).unwrap_or(0).max(0) as u64;
    ctx.finish(&mut [&mut EndAfter {
        output: &mut output,
        seq: next,
        capture_ns,
    }])?;
    outcome.with_context(|| format!("stage '{stage}'"))
}

fn publish(
    stage: &str,
    output: &mut Output<ImuFrame>,
    frames: &mut Vec<ImuFrame>,
    assembler: &mut Assembler,
) -> anyhow::Result<()> {
    for notice in assembler.take_notices() {
        log(stage, &notice);
    }
    for frame in frames.drain(..) {
        output
            .publish(frame.header, |f| *f = frame)
            .with_context(|| format!("publishing frame {}", frame.header.seq))?;
    }
    Ok(())
}

fn log(stage: &str, notice: &Notice) {
    if notice.warning {
        tracing::warn!(stage, "{}", notice.text);
    } else {
        tracing::info!(stage, "{}", notice.text);
    }
}

/// One line per sensor: rate, orientation source, counts, clock.
pub fn sensor_lines(assembler: &Assembler) -> Vec<String> {
    assembler
        .slots()
        .iter()
        .map(|&i| {
            let track = assembler.sensor(i);
            let c = track.counters();
            let frames = assembler.counters();
            let rate = track
                .rate_hz()
                .map_or("rate unknown".to_owned(), |r| format!("{r:.1} Hz"));
            let clock = match track.clock() {
                Some((offset_ns, Some(ppm))) => {
                    format!(
                        "clock offset {:+.3} ms, drift {ppm:+.1} ppm",
                        offset_ns * 1e-6
                    )
                }
                Some((offset_ns, None)) => {
                    format!(
                        "clock offset {:+.3} ms, drift not estimated",
                        offset_ns * 1e-6
                    )
                }
                None => "no clock".to_owned(),
            };
            format!(
                "{}: {rate} {}, {} samples ({} fused), {} lost, {} late, {} discarded as \
                 duplicate, {} as out of order, {} non-finite, {} without orientation, {} gaps \
                 over max_gap_ms, {} clock restarts; {} INVALID frames, {} stale, {} built at \
                 the latency deadline; {clock}",
                sensor_name(i),
                track.source_name(),
                c.samples,
                c.fused,
                c.lost,
                frames.sensor_late[i],
                c.duplicates,
                c.out_of_order,
                c.nonfinite + c.nonfinite_mag,
                c.no_orientation,
                c.long_gaps,
                c.clock_resets,
                frames.sensor_invalid[i],
                frames.sensor_stale[i],
                frames.sensor_held[i],
            )
        })
        .collect()
}

/// The stage's result in one line (the run summary's detail). The words mean the same in every
/// stage: lost, a sample that never came (a gap in the sensor's sample times); late, a sample
/// that came after a frame that needed it was built; discarded, a repeated or out-of-order one.
pub fn summary_line(assembler: &Assembler) -> String {
    let per = |f: &dyn Fn(usize) -> String| {
        let slots = assembler.slots().iter().map(|&i| f(i));
        slots.collect::<Vec<_>>().join("/")
    };
    let counts = |i| *assembler.sensor_counters(i);
    let frames = assembler.counters();
    let mut line = format!(
        "fusion: {} frames, {} INVALID, {} DEGRADED; per sensor: samples {}, lost {}, late {}, \
         discarded {}, INVALID {}, stale {}, drift ppm {}",
        frames.frames,
        frames.invalid,
        frames.degraded,
        per(&|i| counts(i).samples.to_string()),
        per(&|i| counts(i).lost.to_string()),
        per(&|i| frames.sensor_late[i].to_string()),
        per(&|i| (counts(i).duplicates + counts(i).out_of_order).to_string()),
        per(&|i| frames.sensor_invalid[i].to_string()),
        per(&|i| frames.sensor_stale[i].to_string()),
        per(&|i| match assembler.sensor(i).clock() {
            Some((_, Some(ppm))) => format!("{ppm:+.0}"),
            _ => "-".to_owned(),
        }),
    );
    if frames.refused_raw > 0 {
        line += &format!(", {} raw frames refused", frames.refused_raw);
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_params_defaults_are_the_specs() {
        imuflow_graph::params::check_defaults::<FusionParams>().unwrap();
        let defaults = FusionParams::default()
            .settings(60.0, Mode::Offline)
            .unwrap();
        // The authors' defaults except the two a natural recording needs: rest detected within
        // its short stand, and consumer MEMS gyroscope biases (up to ±3°/s) estimated.
        assert_eq!(
            defaults.sensor.vqf,
            VqfParams {
                rest_min_s: 0.25,
                bias_clip_dps: 5.0,
                ..VqfParams::default()
            }
        );
        assert_eq!(defaults.sensor.sensor_rate_hz, None);
        assert_eq!(defaults.origin, Origin::Zero);
        // Offline frames wait for every sensor, band-limited; live ones go out at once.
        assert_eq!(defaults.sensor.latency, Latency::Smooth);
        let live = FusionParams::default().settings(60.0, Mode::Live).unwrap();
        assert_eq!(live.sensor.latency, Latency::Low);
        assert!(FusionParams::default().settings(0.0, Mode::Live).is_err());
    }
}
