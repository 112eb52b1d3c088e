//! `slimevr-sim`: simulated SlimeVR trackers for the imu-source stage's `slimevr` mode (or any
//! SlimeVR server). Each tracker sends the firmware's packets byte for byte
//! (`imuflow_imu_source::slimevr::packets`): it broadcasts its handshake until the server
//! answers, then streams a rotation and an acceleration packet per sensor at `--rate` for
//! `--seconds`, from a known motion (`imuflow_imu_source::slimevr::sim::motion`), answering
//! heartbeats and pings and bundling its packets when the server supports it.

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use clap::Parser;
use imuflow_imu_source::slimevr::packets::Mac;
use imuflow_imu_source::slimevr::sim::{self, SimFaults, SimOptions, SimTracker, Stall};

/// Simulated SlimeVR trackers streaming a known motion over UDP.
#[derive(Parser)]
#[command(name = "slimevr-sim", version)]
struct Args {
    /// Where the server listens (the slimevr mode's `bind`).
    #[arg(long, default_value = "127.0.0.1:6969")]
    server: String,
    /// Number of trackers, with MACs 02:53:4c:00:00:01, 02:53:4c:00:00:02, ... (ignored when
    /// --mac is given).
    #[arg(long, default_value_t = 6)]
    trackers: usize,
    /// A tracker's MAC address (repeat for several trackers).
    #[arg(long = "mac")]
    macs: Vec<String>,
    /// IMUs per tracker (sensor ids 0..N).
    #[arg(long, default_value_t = 1)]
    sensors: u8,
    /// Samples per second and sensor.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
    /// How long to stream, s.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// One packet per datagram even when the server supports bundles.
    #[arg(long)]
    no_bundle: bool,
    /// Give up when no server answers the handshake within this many seconds.
    #[arg(long, default_value_t = 30.0)]
    handshake_timeout: f64,
    /// Drop every N-th data datagram (0 = never).
    #[arg(long, default_value_t = 0)]
    drop_every: u64,
    /// Send every N-th data datagram twice (0 = never).
    #[arg(long, default_value_t = 0)]
    duplicate_every: u64,
    /// Hold every N-th data datagram back behind the next one (0 = never).
    #[arg(long, default_value_t = 0)]
    swap_every: u64,
    /// Stall every N ticks (0 = never): nothing is sent for --stall-ticks ticks, then their
    /// datagrams go out back to back, as after a Wi-Fi stall.
    #[arg(long, default_value_t = 0)]
    stall_every: u64,
    /// Ticks each stall holds back (10 at 100 Hz: a 100 ms stall).
    #[arg(long, default_value_t = 10)]
    stall_ticks: u64,
    /// Write a trackers file mapping the simulated sensors to the six sites here and exit.
    #[arg(long)]
    write_trackers: Option<std::path::PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), String> {
    let trackers = trackers(args)?;
    if let Some(path) = &args.write_trackers {
        return std::fs::write(path, sim::trackers_toml(&trackers))
            .map_err(|e| format!("cannot write '{}': {e}", path.display()));
    }
    let positive = |name: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(format!("--{name} must be a positive number (got {v})"))
        }
    };
    let rate_hz = positive("rate", args.rate)?;
    let seconds = positive("seconds", args.seconds)?;
    let options = SimOptions {
        server: args.server.clone(),
        trackers,
        rate_hz,
        ticks: (seconds * rate_hz).round() as u64,
        bundle: !args.no_bundle,
        handshake_timeout: Duration::from_secs_f64(positive(
            "handshake-timeout",
            args.handshake_timeout,
        )?),
        faults: SimFaults {
            drop_every: args.drop_every,
            duplicate_every: args.duplicate_every,
            swap_every: args.swap_every,
            stall: (args.stall_every > 0).then_some(Stall {
                every_ticks: args.stall_every,
                ticks: args.stall_ticks,
            }),
        },
    };
    let reports =
        sim::run(&options, Arc::new(AtomicBool::new(false))).map_err(|e| format!("{e:#}"))?;
    for r in reports {
        let mac = r.mac.map_or("?".to_owned(), |m| m.to_string());
        eprintln!(
            "tracker {mac}: {} ticks, {} datagrams ({} bundles), {} connection(s), {} heartbeats; \
             dropped {}, duplicated {}, swapped {}, {} ticks held back by stalls",
            r.ticks_sent,
            r.datagrams,
            r.bundles,
            r.connections,
            r.heartbeats,
            r.dropped,
            r.duplicated,
            r.swapped,
            r.stalled
        );
    }
    Ok(())
}

fn trackers(args: &Args) -> Result<Vec<SimTracker>, String> {
    if args.sensors == 0 {
        return Err("--sensors must be at least 1".to_owned());
    }
    let mut trackers = if args.macs.is_empty() {
        if args.trackers == 0 {
            return Err("--trackers must be at least 1".to_owned());
        }
        sim::default_trackers(args.trackers)
    } else {
        args.macs
            .iter()
            .map(|m| {
                Ok(SimTracker {
                    mac: m.parse::<Mac>()?,
                    sensors: 1,
                })
            })
            .collect::<Result<_, String>>()?
    };
    trackers.iter_mut().for_each(|t| t.sensors = args.sensors);
    Ok(trackers)
}
