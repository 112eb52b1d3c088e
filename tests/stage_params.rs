//! Every built-in stage kind's parameter defaults: each default a spec states type-checks against
//! its parameter's type with `ParamType::check`, as the validator checks a graph's values, and each
//! kind declared with `stage_params!` reads its stated defaults back as its `Default`.

use std::process::Command;

use imuflow_graph::StageSpec;
use imuflow_graph::params::toml::Table;
use imuflow_graph::params::{StageParams, check_defaults, parse_default};

/// A built-in kind, with its stated defaults where it is declared with `stage_params!` (the other
/// default texts of such a kind describe a default the stage computes, e.g. "false offline, true
/// live").
struct Kind {
    spec: StageSpec,
    stated: Option<Table>,
}

fn declared<P: StageParams>(spec: StageSpec) -> Kind {
    let names = |specs: &[imuflow_graph::spec::ParamSpec]| -> Vec<&'static str> {
        specs.iter().map(|p| p.name).collect()
    };
    assert_eq!(
        names(spec.params),
        names(P::SPECS),
        "{}: SPEC.params are its params struct's SPECS",
        spec.kind
    );
    if let Err(e) = check_defaults::<P>() {
        panic!("{}: {e}", spec.kind);
    }
    Kind {
        spec,
        stated: Some(P::stated_defaults()),
    }
}

/// Every kind `src/registry.rs` registers.
fn kinds() -> Vec<Kind> {
    vec![
        declared::<imuflow_test_source::stage::TestSourceParams>(imuflow_test_source::SPEC),
        declared::<imuflow_recorder::stage::RecorderParams>(imuflow_recorder::SPEC),
        Kind {
            spec: imuflow_rerun_logger::SPEC,
            stated: None,
        },
        declared::<imuflow_imu_source::stage::ImuSourceParams>(imuflow_imu_source::SPEC),
        declared::<imuflow_fusion::stage::FusionParams>(imuflow_fusion::SPEC),
        declared::<imuflow_calibration::stage::CalibrationParams>(imuflow_calibration::SPEC),
        declared::<imuflow_kinematics::stage::KinematicsParams>(imuflow_kinematics::SPEC),
        declared::<imuflow_contact_stage::stage::ContactParams>(imuflow_contact_stage::SPEC),
        declared::<imuflow_optimizer::stage::OptimizerParams>(imuflow_optimizer::SPEC),
        declared::<imuflow_validation::stage::ValidationParams>(imuflow_validation::SPEC),
        declared::<imuflow_vmc::stage::VmcParams>(imuflow_vmc::SPEC),
        Kind {
            spec: imuflow_bench::SOURCE_SPEC,
            stated: None,
        },
        Kind {
            spec: imuflow_bench::RELAY_SPEC,
            stated: None,
        },
    ]
}

#[test]
fn every_stated_default_type_checks() {
    let mut checked = 0;
    for kind in kinds() {
        for p in kind.spec.params {
            let name = format!("{}.{}", kind.spec.kind, p.name);
            if p.default.is_empty() {
                continue;
            }
            assert!(!p.required, "{name}: required, yet has a default");
            let computed = kind
                .stated
                .as_ref()
                .is_some_and(|stated| !stated.contains_key(p.name));
            if computed {
                continue;
            }
            let value = parse_default(p).unwrap_or_else(|| {
                panic!("{name}: default '{}' is not {}", p.default, p.ty.expected())
            });
            if let Err(e) = p.ty.check(&value) {
                panic!("{name}: default {e}");
            }
            checked += 1;
        }
    }
    assert!(checked > 80, "only {checked} defaults checked");
}

#[test]
fn every_registered_kind_is_checked() {
    let out = Command::new(env!("CARGO_BIN_EXE_imuflow"))
        .args(["stage", "--list"])
        .output()
        .expect("imuflow runs");
    assert!(out.status.success(), "{out:?}");
    let listed: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| !l.is_empty() && !l.starts_with(' '))
        .filter_map(|l| l.split_once(' ').map(|(kind, _)| kind.to_owned()))
        .collect();
    let checked: Vec<String> = kinds().iter().map(|k| k.spec.kind.to_owned()).collect();
    assert_eq!(listed, checked);
}
