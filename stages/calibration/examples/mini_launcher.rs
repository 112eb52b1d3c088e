//! Development aid: runs a graph of imu-source, calibration and recorder stages as real processes
//! (the `imuflow` binary does this for every stage kind).
//!
//!   cargo run -p imuflow-calibration --example mini_launcher -- run GRAPH [key=value ...]

use imuflow_graph::Graph;
use imuflow_graph::launch::{LaunchOptions, run};
use imuflow_graph::spec::Registry;

fn main() -> anyhow::Result<()> {
    tracing_subscriber_init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("stage") => match args.get(1).map(String::as_str) {
            Some("imu-source") => imuflow_imu_source::run(),
            Some("calibration") => imuflow_calibration::run(),
            Some("recorder") => imuflow_recorder::run(),
            other => anyhow::bail!("unknown stage {other:?}"),
        },
        Some("run") => {
            let path =
                std::path::PathBuf::from(args.get(1).ok_or_else(|| anyhow::anyhow!("GRAPH"))?);
            let registry = Registry::new([
                imuflow_imu_source::SPEC,
                imuflow_calibration::SPEC,
                imuflow_recorder::SPEC,
            ]);
            let graph = Graph::load(&path, &args[2..], &registry)?;
            let options = LaunchOptions {
                imuflow_exe: std::env::current_exe()?,
                progress: false,
                forward_logs: true,
            };
            let report = run(&graph, &options)?;
            for (id, (kind, summary)) in &report.stages {
                println!(
                    "{id} ({kind}): in {} out {}",
                    summary.frames_in, summary.frames_out
                );
            }
            Ok(())
        }
        _ => anyhow::bail!("usage: mini_launcher run GRAPH [key=value ...] | stage KIND"),
    }
}

fn tracing_subscriber_init() {
    // Stages log to stderr; stdout carries the launcher's control lines.
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(tracing_subscriber::EnvFilter::new("info"))
        .init();
}
