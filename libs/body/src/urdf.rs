//! URDF export of the dynamic body model, so other tools (Pinocchio, RBDL, PyBullet, Drake, ...) can load
//! the same masses, centres of mass, inertias and bone offsets as [`crate::dynamics`].
//!
//! Layout (all in the model frame M: x left, y up, z forward; SI units; the T-pose is the zero configuration):
//!
//! - a massless link `world` and a `floating` joint `root` to the link `pelvis` (the free root);
//! - per SMPL joint `name` (skeleton names, e.g. `left_knee`), URDF having no spherical joint, three
//!   `continuous` (unlimited revolute) joints `name_rx`, `name_ry`, `name_rz` about the x, y and z axes.
//!   `name_rx` sits at the bone offset in the parent's frame; the chain passes through the massless links
//!   `name_rx_link` and `name_ry_link` and ends at the link `name`, which carries the segment's inertial.
//!   The three angles are intrinsic XYZ Euler angles, `R = Rx(a)·Ry(b)·Rz(c)`
//!   ([`crate::rotation::euler_xyz_from_rotation`]); they have gimbal lock at b = ±π/2, which our own
//!   spherical-joint dynamics does not. Tools that support spherical joints should merge each triple
//!   (Pinocchio check: `scripts/verify/check_dynamics.py`).
//! - Massless joints (spine2, neck, collars, feet, hands) get links without `<inertial>`.
//! - URDF cannot express armature (rotor inertia); a comment records the value the dynamics adds
//!   ([`crate::dynamics::DEFAULT_ARMATURE_KGM2`] per rotational DoF) and gravity (0, −9.81, 0) in M.
//!
//! Numbers are written with Rust's shortest round-trip formatting, so a reader recovers the exact f64s.

use std::fmt::Write;

use crate::body_model::{BodyModel, GRAVITY_IN_MODEL_MPS2};
use crate::dynamics::{DEFAULT_ARMATURE_KGM2, RigidBodyModel};
use crate::skeleton::JointId;

/// The URDF document (UTF-8 XML) of `body`; see the module docs for the layout.
pub fn export_urdf(body: &BodyModel) -> String {
    let model = RigidBodyModel::new(body);
    let mut s = String::with_capacity(32 * 1024);
    // Writing to a String cannot fail; the results are ignored on purpose.
    let _ = writeln!(s, r#"<?xml version="1.0"?>"#);
    let _ = writeln!(
        s,
        "<!-- imuflow body model: stature {} m, mass {} kg, frame M (x left, y up, z forward), \
         gravity ({}, {}, {}) m/s^2.\n     Each spherical joint is three continuous joints (x, y, z: \
         intrinsic XYZ Euler angles) with massless intermediate links.\n     The dynamics adds an \
         armature of {} kg m^2 on every rotational DoF (not expressible in URDF). -->",
        body.stature_m,
        body.mass_kg,
        GRAVITY_IN_MODEL_MPS2.x,
        GRAVITY_IN_MODEL_MPS2.y,
        GRAVITY_IN_MODEL_MPS2.z,
        DEFAULT_ARMATURE_KGM2,
    );
    let _ = writeln!(s, r#"<robot name="imuflow_body">"#);
    let _ = writeln!(s, r#"  <link name="world"/>"#);
    let _ = writeln!(s, r#"  <joint name="root" type="floating">"#);
    let _ = writeln!(s, r#"    <parent link="world"/>"#);
    let _ = writeln!(s, r#"    <child link="{}"/>"#, JointId::ROOT.name());
    let _ = writeln!(s, r#"    <origin xyz="0 0 0" rpy="0 0 0"/>"#);
    let _ = writeln!(s, r#"  </joint>"#);
    write_link(&mut s, &model, JointId::ROOT);
    for j in JointId::all().skip(1) {
        let Some(parent) = j.parent() else { continue };
        let name = j.name();
        let o = body.skeleton.offset_in_parent_m(j);
        let stages = [
            (
                "rx",
                "1 0 0",
                parent.name().to_owned(),
                format!("{name}_rx_link"),
            ),
            (
                "ry",
                "0 1 0",
                format!("{name}_rx_link"),
                format!("{name}_ry_link"),
            ),
            ("rz", "0 0 1", format!("{name}_ry_link"), name.to_owned()),
        ];
        for (k, (suffix, axis, parent_link, child_link)) in stages.iter().enumerate() {
            let _ = writeln!(s, r#"  <joint name="{name}_{suffix}" type="continuous">"#);
            let _ = writeln!(s, r#"    <parent link="{parent_link}"/>"#);
            let _ = writeln!(s, r#"    <child link="{child_link}"/>"#);
            if k == 0 {
                let _ = writeln!(
                    s,
                    r#"    <origin xyz="{} {} {}" rpy="0 0 0"/>"#,
                    o.x, o.y, o.z
                );
            } else {
                let _ = writeln!(s, r#"    <origin xyz="0 0 0" rpy="0 0 0"/>"#);
            }
            let _ = writeln!(s, r#"    <axis xyz="{axis}"/>"#);
            let _ = writeln!(s, r#"  </joint>"#);
            if k < 2 {
                let _ = writeln!(s, r#"  <link name="{child_link}"/>"#);
            }
        }
        write_link(&mut s, &model, j);
    }
    let _ = writeln!(s, "</robot>");
    s
}

/// The link carrying joint `j`'s segment(s): inertial frame at the centre of mass, joint-frame axes.
fn write_link(s: &mut String, model: &RigidBodyModel, j: JointId) {
    let l = model.link(j);
    if l.mass_kg <= 0.0 {
        let _ = writeln!(s, r#"  <link name="{}"/>"#, j.name());
        return;
    }
    let (c, i) = (&l.com_in_joint_m, &l.inertia_about_com_kgm2);
    let _ = writeln!(s, r#"  <link name="{}">"#, j.name());
    let _ = writeln!(s, r#"    <inertial>"#);
    let _ = writeln!(
        s,
        r#"      <origin xyz="{} {} {}" rpy="0 0 0"/>"#,
        c.x, c.y, c.z
    );
    let _ = writeln!(s, r#"      <mass value="{}"/>"#, l.mass_kg);
    let _ = writeln!(
        s,
        r#"      <inertia ixx="{}" ixy="{}" ixz="{}" iyy="{}" iyz="{}" izz="{}"/>"#,
        i[(0, 0)],
        i[(0, 1)],
        i[(0, 2)],
        i[(1, 1)],
        i[(1, 2)],
        i[(2, 2)]
    );
    let _ = writeln!(s, r#"    </inertial>"#);
    let _ = writeln!(s, r#"  </link>"#);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body_model::BodyParams;
    use crate::skeleton::NUM_JOINTS;

    fn body() -> BodyModel {
        BodyModel::new(&BodyParams::builtin().unwrap(), 1.8, 80.0).unwrap()
    }

    /// Values of attribute `attr` in every tag that starts with `tag`.
    fn attrs<'a>(doc: &'a str, tag: &str, attr: &str) -> Vec<&'a str> {
        doc.split('<')
            .filter(|t| t.starts_with(tag))
            .filter_map(|t| {
                let key = format!("{attr}=\"");
                let start = t.find(&key)? + key.len();
                t[start..].split('"').next()
            })
            .collect()
    }

    #[test]
    fn urdf_has_a_floating_root_three_revolutes_per_joint_and_the_body_mass() {
        let body = body();
        let doc = export_urdf(&body);
        assert!(doc.starts_with("<?xml"));
        assert!(doc.trim_end().ends_with("</robot>"));
        // Balanced elements: every non-self-closing open tag has its close tag.
        for tag in ["robot", "joint", "link", "inertial"] {
            let opens =
                doc.matches(&format!("<{tag} ")).count() + doc.matches(&format!("<{tag}>")).count();
            let self_closing = doc
                .split('<')
                .filter(|t| t.starts_with(&format!("{tag} ")) && t.trim_end().ends_with("/>"))
                .count();
            assert_eq!(
                opens - self_closing,
                doc.matches(&format!("</{tag}>")).count(),
                "{tag}"
            );
        }
        let types = attrs(&doc, "joint ", "type");
        assert_eq!(types.iter().filter(|t| **t == "floating").count(), 1);
        assert_eq!(
            types.iter().filter(|t| **t == "continuous").count(),
            3 * (NUM_JOINTS - 1)
        );
        let links = attrs(&doc, "link ", "name");
        assert_eq!(links.len(), 1 + NUM_JOINTS + 2 * (NUM_JOINTS - 1));
        let mut unique = links.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), links.len());
        for j in JointId::all() {
            assert!(links.contains(&j.name()), "{j}");
        }
        // Every parent/child names a link.
        for l in attrs(&doc, "parent ", "link")
            .into_iter()
            .chain(attrs(&doc, "child ", "link"))
        {
            assert!(links.contains(&l), "{l}");
        }
        let mass: f64 = attrs(&doc, "mass ", "value")
            .iter()
            .map(|v| v.parse::<f64>().unwrap())
            .sum();
        assert!((mass - 80.0).abs() < 1e-9);
        // The knee's origin is the exact bone offset.
        let knee = doc.split("<joint name=\"left_knee_rx\"").nth(1).unwrap();
        let xyz: Vec<f64> = attrs(knee, "origin ", "xyz")[0]
            .split(' ')
            .map(|v| v.parse().unwrap())
            .collect();
        let o = body.skeleton.offset_in_parent_m(JointId::LEFT_KNEE);
        assert_eq!(xyz, vec![o.x, o.y, o.z]);
    }
}
