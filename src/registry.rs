//! The built-in stage kinds this binary links, and how `imuflow stage <kind>` runs them.

use std::fmt::Write;

use anyhow::bail;
use imuflow_graph::spec::{InputsSpec, Registry, StageSpec};

/// A built-in stage kind: what it declares, and the main loop its process runs.
pub struct BuiltinStage {
    pub spec: StageSpec,
    pub run: fn() -> anyhow::Result<()>,
}

/// Every built-in stage kind, in the order `imuflow stage --list` prints them. A new kind is one
/// line here (and its crate in the workspace's and this binary's Cargo.toml).
pub const STAGES: &[BuiltinStage] = &[
    builtin(imuflow_test_source::SPEC, imuflow_test_source::run),
    builtin(imuflow_recorder::SPEC, imuflow_recorder::run),
    builtin(imuflow_rerun_logger::SPEC, imuflow_rerun_logger::run),
    builtin(imuflow_imu_source::SPEC, imuflow_imu_source::run),
    builtin(imuflow_fusion::SPEC, imuflow_fusion::run),
    builtin(imuflow_calibration::SPEC, imuflow_calibration::run),
    builtin(imuflow_kinematics::SPEC, imuflow_kinematics::run),
    builtin(imuflow_contact_stage::SPEC, imuflow_contact_stage::run),
    builtin(imuflow_optimizer::SPEC, imuflow_optimizer::run),
    builtin(imuflow_validation::SPEC, imuflow_validation::run),
    builtin(imuflow_vmc::SPEC, imuflow_vmc::run),
    builtin(imuflow_bench::SOURCE_SPEC, imuflow_bench::run_source),
    builtin(imuflow_bench::RELAY_SPEC, imuflow_bench::run_relay),
];

const fn builtin(spec: StageSpec, run: fn() -> anyhow::Result<()>) -> BuiltinStage {
    BuiltinStage { spec, run }
}

fn specs() -> impl Iterator<Item = StageSpec> {
    STAGES.iter().map(|stage| stage.spec)
}

pub fn registry() -> Registry {
    Registry::new(specs())
}

/// Runs stage `kind` in this process (the launcher set up the environment).
pub fn run_stage(kind: &str) -> anyhow::Result<()> {
    match STAGES.iter().find(|stage| stage.spec.kind == kind) {
        Some(stage) => (stage.run)(),
        None => bail!("unknown stage kind '{kind}' (see `imuflow stage --list`)"),
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
