//! The built-in stage kinds this binary links, and how `imuflow stage <kind>` runs them.

use std::fmt::Write;

use anyhow::bail;
use imuflow_graph::spec::{InputsSpec, Registry, StageSpec};

use crate::bench;

/// Every built-in stage kind, in the order `imuflow stage --list` prints them.
fn specs() -> Vec<StageSpec> {
    vec![
        imuflow_test_source::SPEC,
        imuflow_recorder::SPEC,
        imuflow_rerun_logger::SPEC,
        imuflow_imu_source::SPEC,
        imuflow_calibration::SPEC,
        imuflow_kinematics::SPEC,
        imuflow_contact_stage::SPEC,
        imuflow_optimizer::SPEC,
        imuflow_validation::SPEC,
        bench::SOURCE_SPEC,
        bench::RELAY_SPEC,
    ]
}

pub fn registry() -> Registry {
    Registry::new(specs())
}

/// Runs stage `kind` in this process (the launcher set up the environment).
pub fn run_stage(kind: &str) -> anyhow::Result<()> {
    match kind {
        k if k == imuflow_test_source::SPEC.kind => imuflow_test_source::run(),
        k if k == imuflow_imu_source::SPEC.kind => imuflow_imu_source::run(),
        k if k == imuflow_recorder::SPEC.kind => imuflow_recorder::run(),
        k if k == imuflow_rerun_logger::SPEC.kind => imuflow_rerun_logger::run(),
        k if k == imuflow_calibration::SPEC.kind => imuflow_calibration::run(),
        k if k == imuflow_kinematics::SPEC.kind => imuflow_kinematics::run(),
        k if k == imuflow_contact_stage::SPEC.kind => imuflow_contact_stage::run(),
        k if k == imuflow_optimizer::SPEC.kind => imuflow_optimizer::run(),
        k if k == imuflow_validation::SPEC.kind => imuflow_validation::run(),
        k if k == bench::SOURCE_SPEC.kind => bench::run_source(),
        k if k == bench::RELAY_SPEC.kind => bench::run_relay(),
        other => bail!("unknown stage kind '{other}' (see `imuflow stage --list`)"),
    }
}

/// The kinds with their ports and parameters, as text.
pub fn describe_kinds() -> String {
    let mut out = String::new();
    for spec in specs() {
        let _ = writeln!(out, "{} ({:?}): {}", spec.kind, spec.role, spec.summary);
        match spec.inputs {
            InputsSpec::Any => {
                let _ = writeln!(out, "  inputs: any names, any frame types");
            }
            InputsSpec::Fixed(ports) => {
                for p in ports {
                    let req = if p.required { "required" } else { "optional" };
                    let _ = writeln!(
                        out,
                        "  in  {:<12} {:<16} {req}: {}",
                        p.name,
                        p.frame.name(),
                        p.doc
                    );
                }
            }
        }
        for p in spec.outputs {
            let _ = writeln!(out, "  out {:<12} {:<16} {}", p.name, p.frame.name(), p.doc);
        }
        for p in spec.params {
            let default = if p.required {
                "required".to_owned()
            } else if p.default.is_empty() {
                "optional".to_owned()
            } else {
                format!("default {}", p.default)
            };
            let _ = writeln!(
                out,
                "  param {:<16} {} ({default}): {}",
                p.name,
                p.ty.expected(),
                p.doc
            );
        }
        out.push('\n');
    }
    out
}

/// Points every rerun-logger stage at a live viewer instead of its file; returns how many.
pub fn connect_rerun_loggers(graph: &mut imuflow_graph::Graph, url: &str) -> usize {
    let mut count = 0;
    for node in graph.stages.values_mut() {
        if matches!(&node.runner, imuflow_graph::graph::Runner::Builtin { kind } if kind == imuflow_rerun_logger::SPEC.kind)
        {
            node.params.remove("path");
            node.params
                .insert("connect".into(), toml::Value::String(url.to_owned()));
            count += 1;
        }
    }
    count
}
