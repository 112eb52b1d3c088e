//! `udp-send`: sends synthetic IMU packets (the format documented in `imuflow_imu_source::udp`)
//! of a sensor set's sensors (`--sensors`, the six by default) to an imu-source stage in `udp`
//! mode, so the mode can be tried and tested without sensors.
//!
//! Sensor i turns about the vertical at 0.5·(i+1) rad/s at rest (or holds still, `--still`). The
//! fault options inject what wireless sensor networks do: NaN samples, sensors not valid, lost,
//! reordered, duplicated and late packets, a sensor dead for a while, a burst of NaN samples
//! (`imuflow_imu_source::udp::Faults`; `tests/live_degradation.rs` runs them all at once).

use std::process::ExitCode;

use clap::Parser;

/// Send synthetic IMU UDP packets to an imu-source stage in udp mode.
#[derive(Parser)]
#[command(name = "udp-send", version)]
struct Args {
    /// Where the imu-source stage listens (its `bind` parameter).
    #[arg(long, default_value = "127.0.0.1:8777")]
    to: String,
    /// Packets to send.
    #[arg(long, default_value_t = 600)]
    frames: u64,
    /// The sensor set the packets carry (the receiving graph's `sensors`): six, lower-body,
    /// full-suit or a set file's path.
    #[arg(long, default_value = "six")]
    sensors: String,
    /// Send rate, Hz.
    #[arg(long, default_value_t = 60.0)]
    rate: f64,
    /// Put a NaN into sensor 0 of every N-th packet (0 = never).
    #[arg(long, default_value_t = 0)]
    nan_every: u64,
    /// Mark sensor 1 not valid in every N-th packet (0 = never).
    #[arg(long, default_value_t = 0)]
    missing_every: u64,
    /// Lose every N-th packet (0 = never).
    #[arg(long, default_value_t = 0)]
    loss_every: u64,
    /// Every N packets, send a pair in swapped order (0 = never).
    #[arg(long, default_value_t = 0)]
    reorder_every: u64,
    /// Send every N-th packet twice (0 = never).
    #[arg(long, default_value_t = 0)]
    duplicate_every: u64,
    /// Every N-th packet, also send the one of half a second before (0 = never).
    #[arg(long, default_value_t = 0)]
    late_every: u64,
    /// A sensor dead (not valid) for a range of packets: SENSOR:FIRST..END, e.g. 2:120..240.
    #[arg(long, value_parser = sensor_range)]
    dead: Option<(usize, std::ops::Range<u64>)>,
    /// A sensor reporting NaN for a range of packets: SENSOR:FIRST..END.
    #[arg(long, value_parser = sensor_range)]
    nan_burst: Option<(usize, std::ops::Range<u64>)>,
    /// Hold still (no rotation) for the first N packets, e.g. for a T-pose calibration.
    #[arg(long, default_value_t = 0)]
    still: u64,
}

/// `SENSOR:FIRST..END` (a sensor of the packet, from 0; packets FIRST up to END, END excluded).
fn sensor_range(text: &str) -> Result<(usize, std::ops::Range<u64>), String> {
    let bad = || {
        format!(
            "expected SENSOR:FIRST..END with SENSOR a sensor index from 0 (e.g. 2:120..240), got '{text}'"
        )
    };
    let (sensor, range) = text.split_once(':').ok_or_else(bad)?;
    let (first, end) = range.split_once("..").ok_or_else(bad)?;
    let sensor: usize = sensor.trim().parse().map_err(|_| bad())?;
    let (first, end): (u64, u64) = (
        first.trim().parse().map_err(|_| bad())?,
        end.trim().parse().map_err(|_| bad())?,
    );
    if first >= end {
        return Err(bad());
    }
    Ok((sensor, first..end))
}

fn main() -> ExitCode {
    let args = Args::parse();
    if !(args.rate.is_finite() && args.rate > 0.0) {
        eprintln!(
            "error: --rate must be a positive number of Hz (got {})",
            args.rate
        );
        return ExitCode::from(2);
    }
    let sensors = match imuflow_body::SensorSet::resolve(&args.sensors) {
        Ok(set) => set.len(),
        Err(e) => {
            eprintln!("error: --sensors: {e}");
            return ExitCode::from(2);
        }
    };
    for (option, range) in [("--dead", &args.dead), ("--nan-burst", &args.nan_burst)] {
        if let Some((sensor, _)) = range
            && *sensor >= sensors
        {
            eprintln!(
                "error: {option}: sensor {sensor}, but the set {} has {sensors} sensors (0 to {})",
                args.sensors,
                sensors - 1
            );
            return ExitCode::from(2);
        }
    }
    let faults = imuflow_imu_source::udp::Faults {
        nan_every: args.nan_every,
        missing_every: args.missing_every,
        loss_every: args.loss_every,
        reorder_every: args.reorder_every,
        duplicate_every: args.duplicate_every,
        late_every: args.late_every,
        dead: args.dead,
        nan_burst: args.nan_burst,
        still: 0..args.still,
    };
    match imuflow_imu_source::udp::send_synthetic(
        &args.to,
        args.frames,
        args.rate,
        &faults,
        sensors,
    ) {
        Ok(sent) => {
            eprintln!("sent {sent} packets ({} steps) to {}", args.frames, args.to);
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
