//! `--format glb` on the bundled sample's true motion (models/sample/walk.mcap, channel
//! `source.truth`), read back by the `gltf` crate (an independent reader that validates the
//! document): the GLB container, the joint hierarchy, the bone boxes, the animation's samplers and
//! its values against the recorded MotionFrames, and the joints' world positions composed from the
//! file's own transforms against imuflow's forward kinematics.

mod common;

use std::collections::BTreeSet;
use std::path::Path;

use common::{sample, truth_after_prelude};

use gltf::animation::Property;
use gltf::animation::util::ReadOutputs;
use imuflow_body::kinematics::{FkData, forward_kinematics};
use imuflow_body::{BodyModel, BodyParams, JointId, Pose};
use imuflow_export::{ExportOptions, Format, export, read_motion};
use imuflow_motion::retarget::LengthUnit;
use nalgebra::{Matrix4, Quaternion, UnitQuaternion, Vector3};

fn export_glb(out: &Path, stature_m: f64) -> imuflow_export::Exported {
    export(&ExportOptions {
        input: sample(),
        channel: "source.truth".into(),
        format: Format::Glb,
        out: out.to_owned(),
        unit: LengthUnit::Metre,
        keep_all: false,
        stature_m,
        all_joints: false,
    })
    .expect("exports")
}

fn body(stature_m: f64) -> BodyModel {
    BodyModel::new(&BodyParams::builtin().expect("body"), stature_m, 70.0).expect("body")
}

/// A node's local transform from its decomposed translation, rotation (x, y, z, w) and scale.
fn trs(t: [f32; 3], r: [f32; 4], s: [f32; 3]) -> Matrix4<f64> {
    let q = UnitQuaternion::from_quaternion(Quaternion::new(r[3], r[0], r[1], r[2]).cast::<f64>());
    Matrix4::new_translation(&Vector3::from(t).cast::<f64>())
        * q.to_homogeneous()
        * Matrix4::new_nonuniform_scaling(&Vector3::from(s).cast::<f64>())
}

fn point(m: &Matrix4<f64>, p: Vector3<f64>) -> Vector3<f64> {
    m.transform_point(&p.into()).coords
}

/// The GLB container as glTF 2.0's "Binary glTF Layout" lays it out, read byte by byte: header,
/// a JSON chunk padded with spaces, a BIN chunk padded with zeros, lengths that add up.
#[test]
fn the_container_is_a_glb() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("truth.glb");
    export_glb(&out, 1.75);
    let bytes = std::fs::read(&out).expect("read");
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    assert_eq!(&bytes[0..4], b"glTF");
    assert_eq!(word(4), 2, "version");
    assert_eq!(word(8) as usize, bytes.len(), "total length");
    let json_len = word(12) as usize;
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0);
    let json = &bytes[20..20 + json_len];
    let text = std::str::from_utf8(json).expect("utf8");
    assert!(
        text.trim_end_matches(' ').ends_with('}'),
        "padded with spaces"
    );
    let bin_at = 20 + json_len;
    let bin_len = word(bin_at) as usize;
    assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
    assert_eq!(bin_len % 4, 0);
    assert_eq!(
        bin_at + 8 + bin_len,
        bytes.len(),
        "nothing after the BIN chunk"
    );
    let doc: serde_json::Value = serde_json::from_str(text).expect("JSON");
    assert_eq!(doc["asset"]["version"], "2.0");
    assert_eq!(doc["buffers"][0]["byteLength"], bin_len);
}

/// Nodes 0..24 are the joints, named and nested as the skeleton; each bone's box hangs from its
/// parent joint and spans from it to the child joint; the rest offsets are the body model's at the
/// stature asked for.
#[test]
fn the_nodes_are_the_skeleton_with_a_box_per_bone() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("truth.glb");
    let done = export_glb(&out, 1.75);
    let gltf = gltf::Gltf::from_slice(&std::fs::read(&out).expect("read")).expect("valid glTF");
    let body = body(1.75);
    let nodes: Vec<gltf::Node> = gltf.nodes().collect();
    // 24 joints, 23 bones between them, 5 ends (head, hands, feet).
    assert_eq!(nodes.len(), 24 + 23 + 5);
    let scene = gltf.default_scene().expect("a scene");
    let roots: Vec<usize> = scene.nodes().map(|n| n.index()).collect();
    assert_eq!(roots, vec![JointId::ROOT.index()]);
    let truth = truth_after_prelude();
    assert_eq!(done.frames, truth.len());
    for j in JointId::all() {
        let node = &nodes[j.index()];
        assert_eq!(node.name(), Some(j.name()));
        assert!(node.mesh().is_none(), "{j}: a joint node carries no mesh");
        let children: BTreeSet<&str> = node.children().filter_map(|c| c.name()).collect();
        let mut want: BTreeSet<String> = j.children().map(|c| c.name().to_owned()).collect();
        want.extend(j.children().map(|c| format!("{}-{}", j.name(), c.name())));
        if j.children().next().is_none() {
            want.insert(format!("{}-end", j.name()));
        }
        let want: BTreeSet<&str> = want.iter().map(String::as_str).collect();
        assert_eq!(children, want, "{j}'s children");
        let (t, r, s) = node.transform().decomposed();
        assert_eq!(
            (r, s),
            ([0.0, 0.0, 0.0, 1.0], [1.0; 3]),
            "{j}: rest is the T-pose"
        );
        let expect = match j.parent() {
            None => truth[0].root_position_m.map(f64::from).into(),
            Some(_) => *body.skeleton.offset_in_parent_m(j),
        };
        assert!(
            (Vector3::from(t).cast() - expect).norm() < 1e-6,
            "{j}: {t:?}"
        );
        // The box of the bone to each child: its ends (0, ∓0.5, 0) at this joint and the child.
        for c in j.children() {
            let name = format!("{}-{}", j.name(), c.name());
            let bone = node
                .children()
                .find(|n| n.name() == Some(name.as_str()))
                .expect("bone");
            assert!(bone.mesh().is_some(), "{name} is a mesh");
            let (t, r, s) = bone.transform().decomposed();
            let m = trs(t, r, s);
            let start = point(&m, Vector3::new(0.0, -0.5, 0.0));
            let end = point(&m, Vector3::new(0.0, 0.5, 0.0));
            assert!(start.norm() < 1e-6, "{name} starts at {start:?}");
            let offset = body.skeleton.offset_in_parent_m(c);
            assert!((end - offset).norm() < 1e-6, "{name} ends at {end:?}");
        }
    }
    // Another stature scales every offset by the ratio of statures.
    let small = dir.path().join("small.glb");
    export_glb(&small, 1.5);
    let small = gltf::Gltf::from_slice(&std::fs::read(&small).expect("read")).expect("valid");
    for (a, b) in small.nodes().zip(gltf.nodes()).skip(1).take(23) {
        let (ta, tb) = (a.transform().decomposed().0, b.transform().decomposed().0);
        let ratio = Vector3::from(ta).norm() / Vector3::from(tb).norm();
        assert!((ratio - 1.5 / 1.75).abs() < 1e-5, "{:?}: {ratio}", a.name());
    }
}

/// One animation: the root's translation and 24 rotations, LINEAR, a keyframe per exported frame
/// at k / 60 s; at every frame each joint's rotation is the MotionFrame's local rotation and the
/// root's translation its root position.
#[test]
fn the_animation_is_the_recorded_motion() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("truth.glb");
    export_glb(&out, 1.75);
    let gltf = gltf::Gltf::from_slice(&std::fs::read(&out).expect("read")).expect("valid glTF");
    let blob = gltf.blob.as_deref().expect("a BIN chunk");
    let truth = truth_after_prelude();
    let animations: Vec<gltf::Animation> = gltf.animations().collect();
    assert_eq!(animations.len(), 1);
    let animation = &animations[0];
    assert_eq!(animation.name(), Some("source.truth"));
    assert_eq!(animation.samplers().count(), 25);
    assert_eq!(animation.channels().count(), 25);
    let mut rotated = BTreeSet::new();
    let mut translated = 0;
    for channel in animation.channels() {
        assert_eq!(
            channel.sampler().interpolation(),
            gltf::animation::Interpolation::Linear
        );
        let node = channel.target().node().index();
        let reader = channel.reader(|_| Some(blob));
        let times: Vec<f32> = reader.read_inputs().expect("times").collect();
        assert_eq!(times.len(), truth.len());
        for (k, t) in times.iter().enumerate() {
            assert!(
                (f64::from(*t) - k as f64 / 60.0).abs() < 1e-5,
                "time {k}: {t}"
            );
        }
        match reader.read_outputs().expect("values") {
            ReadOutputs::Rotations(r) => {
                assert_eq!(channel.target().property(), Property::Rotation);
                assert!(rotated.insert(node), "one rotation channel per joint");
                let values: Vec<[f32; 4]> = r.into_f32().collect();
                assert_eq!(values.len(), truth.len());
                for (k, (q, frame)) in values.iter().zip(&truth).enumerate() {
                    let [w, x, y, z] = frame.local_pose_wxyz[node];
                    // q and −q are one rotation; successive keyframes keep one sign.
                    let dot = q[0] * x + q[1] * y + q[2] * z + q[3] * w;
                    let sign = dot.signum();
                    let d = (0..4)
                        .map(|i| (q[i] - sign * [x, y, z, w][i]).abs())
                        .fold(0.0f32, f32::max);
                    assert!(
                        d <= 1e-6,
                        "joint {node} frame {k}: {q:?} vs wxyz {w} {x} {y} {z}"
                    );
                    if k > 0 {
                        let p = values[k - 1];
                        let cos = (0..4).map(|i| p[i] * q[i]).sum::<f32>();
                        assert!(cos >= 0.0, "joint {node} frame {k}: sign flip");
                    }
                }
            }
            ReadOutputs::Translations(t) => {
                assert_eq!(node, JointId::ROOT.index(), "only the root moves");
                translated += 1;
                for (k, (p, frame)) in t.zip(&truth).enumerate() {
                    let d = (0..3)
                        .map(|i| (p[i] - frame.root_position_m[i]).abs())
                        .fold(0.0f32, f32::max);
                    assert!(d <= 1e-6, "root frame {k}: {p:?}");
                }
            }
            _ => panic!("only rotations and translations are animated"),
        }
    }
    assert_eq!((rotated.len(), translated), (24, 1));
}

/// The joints' world positions composed from the file (node rest transforms with the animated
/// values substituted, parent by parent) equal imuflow's forward kinematics of the same frame.
#[test]
fn the_file_composes_to_imuflows_forward_kinematics() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("truth.glb");
    export_glb(&out, 1.75);
    let gltf = gltf::Gltf::from_slice(&std::fs::read(&out).expect("read")).expect("valid glTF");
    let blob = gltf.blob.as_deref().expect("a BIN chunk");
    let motion = read_motion(&sample(), "source.truth", false).expect("motion");
    let body = body(1.75);
    let animation = gltf.animations().next().expect("animation");
    let mut fk = FkData::new();
    for k in [0, 123, 400, motion.clip.poses.len() - 1] {
        let mut local: Vec<Matrix4<f64>> = Vec::new();
        let mut parent: Vec<Option<usize>> = vec![None; gltf.nodes().count()];
        for node in gltf.nodes() {
            let (mut t, mut r, s) = node.transform().decomposed();
            for channel in animation
                .channels()
                .filter(|c| c.target().node().index() == node.index())
            {
                match channel
                    .reader(|_| Some(blob))
                    .read_outputs()
                    .expect("values")
                {
                    ReadOutputs::Rotations(v) => r = v.into_f32().nth(k).expect("frame k"),
                    ReadOutputs::Translations(mut v) => t = v.nth(k).expect("frame k"),
                    _ => unreachable!("only rotations and translations"),
                }
            }
            local.push(trs(t, r, s));
            for c in node.children() {
                parent[c.index()] = Some(node.index());
            }
        }
        let world = |mut i: usize| {
            let mut m = local[i];
            while let Some(p) = parent[i] {
                m = local[p] * m;
                i = p;
            }
            m
        };
        let pose: &Pose = &motion.clip.poses[k];
        forward_kinematics(&body.skeleton, pose, &mut fk);
        for j in JointId::all() {
            let p = point(&world(j.index()), Vector3::zeros());
            let d = (p - fk.position(j)).norm();
            assert!(d < 1e-5, "frame {k} {j}: {d} m from forward kinematics");
        }
    }
}

/// A lower body's joints only (pelvis, hips, knees): five joint nodes nested as the skeleton,
/// the bones between them, and each knee's shank to the ankle (the bone a knee turns, its child
/// left out); the animation turns those five and moves the root, nothing else.
#[test]
fn a_glb_of_some_joints_holds_their_nodes_bones_and_rotations_only() {
    let body = body(1.75);
    let motion = read_motion(&sample(), "source.truth", false).expect("reads");
    let joints = [
        JointId::ROOT,
        JointId::LEFT_HIP,
        JointId::RIGHT_HIP,
        JointId::LEFT_KNEE,
        JointId::RIGHT_KNEE,
    ];
    let mask = joints.iter().fold(0u32, |m, j| m | 1 << j.index());
    let bytes =
        imuflow_export::glb::glb_of_joints(&body, &motion.clip, "legs", mask).expect("writes");
    let gltf = gltf::Gltf::from_slice(&bytes).expect("valid glTF");
    let nodes: Vec<gltf::Node> = gltf.nodes().collect();
    let names: Vec<&str> = nodes.iter().filter_map(|n| n.name()).collect();
    assert_eq!(
        names,
        [
            "pelvis",
            "left_hip",
            "right_hip",
            "left_knee",
            "right_knee",
            "pelvis-left_hip",
            "pelvis-right_hip",
            "left_hip-left_knee",
            "left_knee-left_ankle",
            "right_hip-right_knee",
            "right_knee-right_ankle",
        ]
    );
    // The shank's box hangs from the knee and ends at the ankle's rest offset.
    let shank = &nodes[8];
    let (t, r, s) = shank.transform().decomposed();
    let ankle = body.skeleton.offset_in_parent_m(JointId::LEFT_ANKLE);
    let far_end = point(&trs(t, r, s), Vector3::new(0.0, 0.5, 0.0));
    assert!((far_end - ankle).norm() < 1e-5, "{far_end} vs {ankle}");
    assert!(
        nodes[3]
            .children()
            .any(|c| c.name() == Some("left_knee-left_ankle"))
    );
    // Root translation and five rotations, each on a joint node.
    let animation = gltf.animations().next().expect("an animation");
    let targets: Vec<(usize, Property)> = animation
        .channels()
        .map(|c| (c.target().node().index(), c.target().property()))
        .collect();
    assert_eq!(targets.len(), 6);
    assert_eq!(targets[0], (0, Property::Translation));
    assert!(
        targets[1..]
            .iter()
            .enumerate()
            .all(|(k, t)| *t == (k, Property::Rotation))
    );
    // Only the two sides' box meshes are used: the centre's is not written.
    let meshes: Vec<&str> = gltf.meshes().filter_map(|m| m.name()).collect();
    assert_eq!(meshes, ["box-left", "box-right"]);
}
