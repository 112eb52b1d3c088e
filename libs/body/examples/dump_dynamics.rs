//! Dump the exported URDF and our dynamics at random states, for the independent Pinocchio check
//! `scripts/verify/check_dynamics.py`.
//!
//! ```sh
//! cargo run --release -p imuflow-body --example dump_dynamics -- out/dynamics
//! python scripts/verify/check_dynamics.py out/dynamics
//! ```
//!
//! Writes `DIR/body.urdf` and `DIR/dynamics.json`: the model (joint names and parents, armature, gravity),
//! test points, and per state the pose (root position, row-major local rotations), `v`, `M`, `h`, the
//! gravity part of `h`, and per point its position, `J` and `J̇·v`. The first states have every joint at
//! identity (a random root), where the URDF's Euler-angle chains coincide with our coordinates, so the
//! check can also compare against Pinocchio's own URDF parser there.

use std::fmt::Write as _;
use std::path::PathBuf;

use imuflow_body::dynamics::{DofVector, DynamicsData, NUM_DOFS, PointJacobian, RigidBodyModel};
use imuflow_body::urdf::export_urdf;
use imuflow_body::{BodyModel, BodyParams, JointId, NUM_JOINTS, Pose};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

/// Random states in all; the first `IDENTITY_STATES` have identity joint rotations.
const STATES: usize = 20;
const IDENTITY_STATES: usize = 4;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "out/dynamics".into()),
    );
    std::fs::create_dir_all(&dir)?;
    let body = BodyModel::new(&BodyParams::builtin()?, 1.741, 73.0)?;
    std::fs::write(dir.join("body.urdf"), export_urdf(&body))?;

    let model = RigidBodyModel::new(&body);
    let mut data = DynamicsData::new();
    let mut rng = StdRng::seed_from_u64(2025);
    let points: [(JointId, Vector3<f64>); 6] = [
        (JointId::ROOT, Vector3::new(0.0, -0.15, 0.0)),
        (JointId::LEFT_FOOT, Vector3::new(0.0, -0.02, 0.05)),
        (JointId::RIGHT_FOOT, Vector3::zeros()),
        (JointId::LEFT_HAND, Vector3::new(0.03, 0.0, 0.01)),
        (JointId::RIGHT_HAND, Vector3::zeros()),
        (JointId::HEAD, Vector3::new(0.0, 0.12, 0.03)),
    ];

    let mut s = String::new();
    s.push_str("{\n");
    let _ = writeln!(s, "\"stature_m\": {},", body.stature_m);
    let _ = writeln!(s, "\"mass_kg\": {},", body.mass_kg);
    let _ = writeln!(s, "\"total_mass_kg\": {},", model.total_mass_kg());
    let _ = writeln!(s, "\"gravity\": {},", list(model.gravity_mps2.iter()));
    let _ = writeln!(
        s,
        "\"armature_kgm2\": {},",
        list(model.armature_kgm2.iter())
    );
    let names: Vec<String> = JointId::all()
        .map(|j| format!("\"{}\"", j.name()))
        .collect();
    let _ = writeln!(s, "\"joints\": [{}],", names.join(", "));
    let parents: Vec<String> = JointId::all()
        .map(|j| j.parent().map_or(-1, |p| p.index() as i64).to_string())
        .collect();
    let _ = writeln!(s, "\"parents\": [{}],", parents.join(", "));
    let pts: Vec<String> = points
        .iter()
        .map(|(j, p)| {
            format!(
                "{{\"joint\": {}, \"point\": {}}}",
                j.index(),
                list(p.iter())
            )
        })
        .collect();
    let _ = writeln!(s, "\"points\": [{}],", pts.join(", "));
    let _ = writeln!(s, "\"identity_states\": {IDENTITY_STATES},");
    s.push_str("\"states\": [\n");
    let mut jac = PointJacobian::zeros();
    for k in 0..STATES {
        let mut pose = Pose::t_pose(Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(0.0..2.0),
            rng.random_range(-1.0..1.0),
        ));
        for (j, r) in pose.parent_from_joint.iter_mut().enumerate() {
            if j == 0 || k >= IDENTITY_STATES {
                *r = random_rotation(&mut rng);
            }
        }
        let v = DofVector::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal) * 2.0);
        data.set_state(&model, &pose, &v);
        let m = *data.mass_matrix(&model);
        let h = *data.bias_forces(&model);
        let mut g = DofVector::zeros();
        data.gravity_forces(&model, &mut g);
        s.push('{');
        let _ = write!(
            s,
            "\"root_position\": {}, ",
            list(pose.root_in_world_m.iter())
        );
        let rots: Vec<String> = (0..NUM_JOINTS)
            .map(|j| list(pose.parent_from_joint[j].matrix().transpose().iter()))
            .collect();
        let _ = writeln!(s, "\"rotations_row_major\": [{}],", rots.join(", "));
        let _ = writeln!(s, "\"v\": {},", list(v.iter()));
        let rows: Vec<String> = (0..NUM_DOFS).map(|r| list(m.row(r).iter())).collect();
        let _ = writeln!(s, "\"M\": [{}],", rows.join(",\n"));
        let _ = writeln!(s, "\"h\": {},", list(h.iter()));
        let _ = writeln!(s, "\"gravity_h\": {},", list(g.iter()));
        let mut pj = Vec::new();
        for (joint, p) in &points {
            data.point_jacobian(*joint, p, &mut jac);
            let rows: Vec<String> = (0..3).map(|r| list(jac.row(r).iter())).collect();
            pj.push(format!(
                "{{\"position\": {}, \"J\": [{}], \"jdot_v\": {}}}",
                list(data.point_position(*joint, p).iter()),
                rows.join(", "),
                list(data.point_jdot_v(*joint, p).iter())
            ));
        }
        let _ = write!(s, "\"points\": [{}]", pj.join(",\n"));
        s.push('}');
        s.push_str(if k + 1 < STATES { ",\n" } else { "\n" });
    }
    s.push_str("]\n}\n");
    std::fs::write(dir.join("dynamics.json"), s)?;
    println!(
        "wrote {} and {} ({STATES} states)",
        dir.join("body.urdf").display(),
        dir.join("dynamics.json").display()
    );
    Ok(())
}

/// A rotation from a normalised 4D Gaussian (uniform on SO(3)).
fn random_rotation(rng: &mut StdRng) -> nalgebra::Rotation3<f64> {
    let mut n = || rng.sample::<f64, _>(StandardNormal);
    UnitQuaternion::new_normalize(Quaternion::new(n(), n(), n(), n())).to_rotation_matrix()
}

/// A JSON array of numbers (shortest round-trip formatting).
fn list<'a>(values: impl Iterator<Item = &'a f64>) -> String {
    let v: Vec<String> = values.map(|x| format!("{x:?}")).collect();
    format!("[{}]", v.join(", "))
}
