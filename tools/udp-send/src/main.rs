//! `udp-send`: sends synthetic six-IMU packets (the format documented in
//! `imuflow_imu_source::udp`) to an imu-source stage in `udp` mode, so the mode can be tried and
//! tested without sensors.
//!
//! Sensor i turns about the vertical at 0.5·(i+1) rad/s at rest; `--nan-every N` puts a NaN into
//! sensor 0 of every N-th packet and `--missing-every N` marks sensor 1 not valid in every N-th.

use std::process::ExitCode;

use clap::Parser;

/// Send synthetic six-IMU UDP packets to an imu-source stage in udp mode.
#[derive(Parser)]
#[command(name = "udp-send", version)]
struct Args {
    /// Where the imu-source stage listens (its `bind` parameter).
    #[arg(long, default_value = "127.0.0.1:8777")]
    to: String,
    /// Packets to send.
    #[arg(long, default_value_t = 600)]
    frames: u64,
    /// Send rate, Hz.
    #[arg(long, default_value_t = 60.0)]
    rate: f64,
    /// Put a NaN into sensor 0 of every N-th packet (0 = never).
    #[arg(long, default_value_t = 0)]
    nan_every: u64,
    /// Mark sensor 1 not valid in every N-th packet (0 = never).
    #[arg(long, default_value_t = 0)]
    missing_every: u64,
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
    match imuflow_imu_source::udp::send_synthetic(
        &args.to,
        args.frames,
        args.rate,
        args.nan_every,
        args.missing_every,
    ) {
        Ok(()) => {
            eprintln!("sent {} packets to {}", args.frames, args.to);
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
