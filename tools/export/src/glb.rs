//! `--format glb`: a motion as a glTF 2.0 binary file (the Khronos glTF 2.0 specification,
//! section "GLB File Format Specification").
//!
//! - **Joints**: one node per body-model joint, node `i` = joint `i`, named as SMPL names it
//!   (`pelvis`, `left_hip`, ...), children as in the skeleton. A joint node's rest translation is
//!   its offset from its parent at the subject's stature (the BVH export's offsets); its rest
//!   rotation is the identity (the T-pose). The root node's rest translation is the first frame's
//!   root position.
//! - **Animation**: one animation named after the channel: the root node's translation (the root
//!   position) and every joint node's rotation (its local rotation, the root's global one), one
//!   keyframe per exported frame at `k / rate`, sampler `LINEAR` (slerp for rotations). Successive
//!   quaternions of a joint keep the sign of the previous one, so slerp takes the short way.
//! - **Body**: a box per bone (parent joint to child joint, and from the head, hands and feet to
//!   their ends), each a mesh node child of the bone's parent joint node, so any viewer draws a
//!   moving figure without skinning. Left side blue, right side red, the rest grey.
//!
//! glTF's frame is right-handed, +Y up, +Z forward, metres (the specification's section
//! "Coordinate System and Units"): the body model's frame M (x left, y up, z forward, m) as it
//! is, so no axis is changed.

use gltf_json as json;
use imuflow_body::rotation::from_to;
use imuflow_body::skeleton::{ALL_JOINTS, cut_bone_end, joint_tree};
use imuflow_body::{BodyModel, JointId};
use imuflow_motion::retarget::MotionClip;
use json::accessor::{ComponentType, GenericComponentType, Type};
use json::validation::{Checked::Valid, USize64};
use nalgebra::{Rotation3, Unit, UnitQuaternion, Vector3};

/// GLB header magic "glTF", version, and chunk types "JSON" and "BIN\0" (glTF 2.0, "Binary glTF
/// Layout").
const GLB_MAGIC: u32 = 0x4654_6C67;
const GLB_VERSION: u32 = 2;
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// The subject the box widths below are drawn for (m); other statures scale them.
const REFERENCE_STATURE_M: f64 = 1.75;

/// A glTF 2.0 binary of `clip` on `body`'s skeleton, its animation named `animation`.
pub fn glb_from_clip(
    body: &BodyModel,
    clip: &MotionClip,
    animation: &str,
) -> Result<Vec<u8>, String> {
    glb_of_joints(body, clip, animation, ALL_JOINTS)
}

/// [`glb_from_clip`] of the joints in `joints` (a mask over joint indices, such as the joints a
/// sensor set observes) whose every ancestor is in it too, the root always: their nodes (in joint
/// order, so node `k` is the `k`-th joint written), their bones and their rotations. A written
/// joint whose children are all left out gets the box of the bone it turns, to its first child's
/// joint (a knee's shank reaches the ankle).
pub fn glb_of_joints(
    body: &BodyModel,
    clip: &MotionClip,
    animation: &str,
    joints: u32,
) -> Result<Vec<u8>, String> {
    let first = clip.poses.first().ok_or("the motion has no frame")?;
    let mut doc = Document::default();
    let nodes = JointNodes::of(joints);
    joint_nodes(&mut doc, body, &first.root_in_world_m, &nodes);
    bone_meshes(&mut doc, body, &nodes);
    animate(&mut doc, clip, animation, &nodes);
    doc.root.scenes.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some("imuflow".into()),
        nodes: vec![json::Index::new(0)],
    });
    doc.root.scene = Some(json::Index::new(0));
    doc.into_glb()
}

/// The glTF document being built and its binary buffer (the GLB's BIN chunk).
struct Document {
    root: json::Root,
    bin: Vec<u8>,
}

impl Default for Document {
    fn default() -> Document {
        let mut root = json::Root::default();
        root.asset.version = "2.0".into();
        root.asset.generator = Some(format!("imuflow export {}", env!("CARGO_PKG_VERSION")));
        Document {
            root,
            bin: Vec::new(),
        }
    }
}

impl Document {
    /// Appends `bytes` to the buffer as a view of its own, 4-byte aligned (glTF 2.0, "Data
    /// Alignment": an accessor's offset is a multiple of its component size).
    fn view(
        &mut self,
        bytes: &[u8],
        target: Option<json::buffer::Target>,
    ) -> json::Index<json::buffer::View> {
        pad_to_4(&mut self.bin, 0);
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64::from(bytes.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Valid),
            extensions: None,
            extras: Default::default(),
        })
    }

    /// An f32 accessor of `type_` (`values.len()` a multiple of its width), with its per-component
    /// bounds where glTF requires them (positions and animation inputs).
    fn floats(
        &mut self,
        values: &[f32],
        type_: Type,
        bounds: bool,
        target: Option<json::buffer::Target>,
    ) -> json::Index<json::Accessor> {
        let width = type_.multiplicity();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, target);
        let (min, max) = if bounds {
            let (min, max) = component_bounds(values, width);
            (Some(min.into()), Some(max.into()))
        } else {
            (None, None)
        };
        self.accessor(
            view,
            values.len() / width,
            ComponentType::F32,
            type_,
            min,
            max,
        )
    }

    fn accessor(
        &mut self,
        view: json::Index<json::buffer::View>,
        count: usize,
        component: ComponentType,
        type_: Type,
        min: Option<json::Value>,
        max: Option<json::Value>,
    ) -> json::Index<json::Accessor> {
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(GenericComponentType(component)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn node(&mut self, node: json::Node) -> json::Index<json::Node> {
        self.root.push(node)
    }

    fn add_child(&mut self, parent: usize, child: json::Index<json::Node>) {
        self.root.nodes[parent]
            .children
            .get_or_insert_with(Vec::new)
            .push(child);
    }

    /// The GLB container: 12-byte header, the JSON chunk padded with spaces, the BIN chunk padded
    /// with zeros, each chunk 4-byte aligned (glTF 2.0, "Chunks").
    fn into_glb(mut self) -> Result<Vec<u8>, String> {
        pad_to_4(&mut self.bin, 0);
        self.root.buffers.push(json::Buffer {
            byte_length: USize64::from(self.bin.len()),
            name: None,
            uri: None,
            extensions: None,
            extras: Default::default(),
        });
        let mut text = self.root.to_vec().map_err(|e| e.to_string())?;
        pad_to_4(&mut text, b' ');
        let total = 12 + 8 + text.len() + 8 + self.bin.len();
        let total = u32::try_from(total).map_err(|_| format!("{total} bytes: over GLB's 4 GiB"))?;
        let mut out = Vec::with_capacity(total as usize);
        for word in [GLB_MAGIC, GLB_VERSION, total] {
            out.extend_from_slice(&word.to_le_bytes());
        }
        for (kind, chunk) in [(CHUNK_JSON, &text), (CHUNK_BIN, &self.bin)] {
            // Both fit: each is shorter than `total`.
            out.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
            out.extend_from_slice(&kind.to_le_bytes());
            out.extend_from_slice(chunk);
        }
        Ok(out)
    }
}

fn pad_to_4(bytes: &mut Vec<u8>, with: u8) {
    while !bytes.len().is_multiple_of(4) {
        bytes.push(with);
    }
}

/// Per-component minimum and maximum of `values` taken `width` at a time.
fn component_bounds(values: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let mut min = vec![f32::INFINITY; width];
    let mut max = vec![f32::NEG_INFINITY; width];
    for (i, v) in values.iter().enumerate() {
        min[i % width] = min[i % width].min(*v);
        max[i % width] = max[i % width].max(*v);
    }
    (min, max)
}

fn f32x3(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// The joints written and their node indices: the first nodes, in joint order (a parent's index
/// is below its children's, so every parent is written before them).
struct JointNodes {
    /// The joints written ([`joint_tree`]), as a mask over joint indices.
    tree: u32,
    node: [Option<usize>; imuflow_body::NUM_JOINTS],
}

impl JointNodes {
    /// The joints of `mask` whose every ancestor is in it, and the root.
    fn of(mask: u32) -> JointNodes {
        let tree = joint_tree(mask);
        let mut node = [None; imuflow_body::NUM_JOINTS];
        let written = JointId::all().filter(|j| tree & (1 << j.index()) != 0);
        for (k, j) in written.enumerate() {
            node[j.index()] = Some(k);
        }
        JointNodes { tree, node }
    }

    fn of_joint(&self, j: JointId) -> Option<usize> {
        self.node[j.index()]
    }

    /// The joints written, in joint (and node) order.
    fn joints(&self) -> impl Iterator<Item = JointId> + '_ {
        JointId::all().filter(|j| self.of_joint(*j).is_some())
    }
}

/// The first nodes: the joints written, in joint order, each the child of its parent joint.
fn joint_nodes(
    doc: &mut Document,
    body: &BodyModel,
    root_position_m: &Vector3<f64>,
    nodes: &JointNodes,
) {
    for j in nodes.joints() {
        let translation = match j.parent() {
            None => root_position_m,
            Some(_) => body.skeleton.offset_in_parent_m(j),
        };
        let index = doc.node(json::Node {
            name: Some(j.name().to_owned()),
            translation: Some(f32x3(translation)),
            ..Default::default()
        });
        if let Some(parent) = j.parent().and_then(|p| nodes.of_joint(p)) {
            doc.add_child(parent, index);
        }
    }
}

/// Which side of the body a bone is on, for its colour.
#[derive(Clone, Copy)]
enum Side {
    Left,
    Right,
    Centre,
}

impl Side {
    fn of(joint: JointId) -> Side {
        let name = joint.name();
        if name.starts_with("left_") {
            Side::Left
        } else if name.starts_with("right_") {
            Side::Right
        } else {
            Side::Centre
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// One unit box mesh per side (the same geometry, a different material), then a scaled box node
/// per bone under its parent joint's node.
fn bone_meshes(doc: &mut Document, body: &BodyModel, nodes: &JointNodes) {
    let k = body.stature_m / REFERENCE_STATURE_M;
    // Every box, then a mesh per side in use (a mesh nothing uses is one a validator flags).
    let mut boxes: Vec<BoneBox> = Vec::new();
    for j in nodes.joints() {
        let Some(node) = nodes.of_joint(j) else {
            continue;
        };
        if let Some(parent) = j.parent()
            && let Some(parent_node) = nodes.of_joint(parent)
        {
            let offset = *body.skeleton.offset_in_parent_m(j);
            let name = format!("{}-{}", parent.name(), j.name());
            boxes.push(BoneBox::new(parent_node, name, j, offset, bone_size_m(j)));
        }
        if let Some(child) = cut_bone_end(j, nodes.tree) {
            // The bone this joint turns, to its first child's joint (not written).
            let offset = *body.skeleton.offset_in_parent_m(child);
            let name = format!("{}-{}", j.name(), child.name());
            boxes.push(BoneBox::new(node, name, child, offset, bone_size_m(child)));
        } else if let Some(end) = end_of(body, j) {
            let name = format!("{}-end", j.name());
            boxes.push(BoneBox::new(node, name, j, end, end_size_m(j)));
        }
    }
    let mut used = [false; 3];
    for b in &boxes {
        used[b.side.index()] = true;
    }
    let meshes = side_meshes(doc, used);
    for b in boxes {
        if let Some(mesh) = meshes[b.side.index()] {
            bone_node(doc, b.parent, b.name, mesh, &b.to, b.size.map(|w| w * k));
        }
    }
}

/// One box of the figure: under node `parent`, from it to `to` (in its frame), `size` across at
/// the reference stature, coloured by the side of the joint it leads to.
struct BoneBox {
    parent: usize,
    name: String,
    side: Side,
    to: Vector3<f64>,
    size: [f64; 2],
}

impl BoneBox {
    fn new(parent: usize, name: String, toward: JointId, to: Vector3<f64>, size: [f64; 2]) -> Self {
        BoneBox {
            parent,
            name,
            side: Side::of(toward),
            to,
            size,
        }
    }
}

/// Where a leaf's box ends, in the leaf joint's frame: the head to the top of the head, hands and
/// feet on along their last bone by 0.1 m (as the BVH export's end sites).
fn end_of(body: &BodyModel, joint: JointId) -> Option<Vector3<f64>> {
    if joint.children().next().is_some() {
        return None;
    }
    if joint == JointId::HEAD {
        return Some(Vector3::new(0.0, body.head_top_above_head_joint_m, 0.0));
    }
    let along = body
        .skeleton
        .offset_in_parent_m(joint)
        .try_normalize(1e-12)?;
    Some(along * 0.1)
}

/// The box from a joint to its child `child` is this wide across (its extent along the parent's x
/// and z axes at rest, m, at 1.75 m stature): a figure that reads as a body, not an anatomical
/// measurement. The trunk is wider than deep.
fn bone_size_m(child: JointId) -> [f64; 2] {
    match child {
        JointId::SPINE1 | JointId::SPINE2 | JointId::SPINE3 => [0.26, 0.16],
        JointId::NECK => [0.09, 0.09],
        JointId::HEAD => [0.07, 0.07],
        JointId::LEFT_HIP | JointId::RIGHT_HIP => [0.14, 0.14],
        JointId::LEFT_KNEE | JointId::RIGHT_KNEE => [0.11, 0.11],
        JointId::LEFT_ANKLE | JointId::RIGHT_ANKLE => [0.08, 0.08],
        JointId::LEFT_FOOT | JointId::RIGHT_FOOT => [0.07, 0.06],
        JointId::LEFT_COLLAR | JointId::RIGHT_COLLAR => [0.08, 0.08],
        JointId::LEFT_WRIST | JointId::RIGHT_WRIST => [0.05, 0.05],
        JointId::LEFT_HAND | JointId::RIGHT_HAND => [0.045, 0.045],
        // Shoulder to elbow, collar to shoulder.
        _ => [0.065, 0.065],
    }
}

/// The box beyond a leaf (m, at 1.75 m stature): the head's is the largest.
fn end_size_m(leaf: JointId) -> [f64; 2] {
    if leaf == JointId::HEAD {
        [0.16, 0.18]
    } else {
        [0.05, 0.05]
    }
}

/// A node under `parent` holding `mesh` (a unit box centred on the origin) stretched from the
/// parent joint to `to` (in the parent's frame), `size` across: along the parent's x and z for a
/// bone along y, turned with the bone otherwise.
fn bone_node(
    doc: &mut Document,
    parent: usize,
    name: String,
    mesh: json::Index<json::Mesh>,
    to: &Vector3<f64>,
    size: [f64; 2],
) {
    let Some(along) = Unit::try_new(*to, 1e-9) else {
        return;
    };
    // The box's long axis is its y: turn y onto the bone (the shortest turn, so a bone straight
    // up keeps the parent's x and z across).
    let turn = from_to(&Vector3::y_axis(), &along);
    let node = doc.node(json::Node {
        name: Some(name),
        mesh: Some(mesh),
        translation: Some(f32x3(&(to * 0.5))),
        rotation: Some(json::scene::UnitQuaternion(quat_xyzw(&turn))),
        scale: Some([size[0] as f32, to.norm() as f32, size[1] as f32]),
        ..Default::default()
    });
    doc.add_child(parent, node);
}

/// glTF's quaternion order `[x, y, z, w]`.
fn quat_xyzw(r: &Rotation3<f64>) -> [f32; 4] {
    let q = UnitQuaternion::from_rotation_matrix(r);
    [q.i as f32, q.j as f32, q.k as f32, q.w as f32]
}

/// The unit box (−0.5..0.5 on each axis) with flat normals, and a mesh of it per side.
fn side_meshes(doc: &mut Document, used: [bool; 3]) -> [Option<json::Index<json::Mesh>>; 3] {
    let (positions, normals, indices) = unit_box();
    let positions = doc.floats(
        &positions,
        Type::Vec3,
        true,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let normals = doc.floats(
        &normals,
        Type::Vec3,
        false,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let index_bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let view = doc.view(&index_bytes, Some(json::buffer::Target::ElementArrayBuffer));
    let indices = doc.accessor(
        view,
        indices.len(),
        ComponentType::U16,
        Type::Scalar,
        None,
        None,
    );
    // Linear RGB: a blue left, a red right, a light grey trunk and head.
    let colours = [
        ("left", [0.15, 0.35, 0.85, 1.0]),
        ("right", [0.85, 0.25, 0.15, 1.0]),
        ("centre", [0.75, 0.75, 0.75, 1.0]),
    ];
    let mut side = 0;
    colours.map(|(name, colour)| {
        side += 1;
        if !used[side - 1] {
            return None;
        }
        let material = doc.root.push(json::Material {
            name: Some(name.to_owned()),
            pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                base_color_factor: json::material::PbrBaseColorFactor(colour),
                metallic_factor: json::material::StrengthFactor(0.0),
                roughness_factor: json::material::StrengthFactor(0.8),
                ..Default::default()
            },
            ..Default::default()
        });
        let attributes = [
            (Valid(json::mesh::Semantic::Positions), positions),
            (Valid(json::mesh::Semantic::Normals), normals),
        ];
        Some(doc.root.push(json::Mesh {
            extensions: None,
            extras: Default::default(),
            name: Some(format!("box-{name}")),
            primitives: vec![json::mesh::Primitive {
                attributes: attributes.into_iter().collect(),
                extensions: None,
                extras: Default::default(),
                indices: Some(indices),
                material: Some(material),
                mode: Valid(json::mesh::Mode::Triangles),
                targets: None,
            }],
            weights: None,
        }))
    })
}

/// Positions, normals (4 vertices per face) and triangle indices of the unit box, the triangles
/// counter-clockwise seen from outside (glTF's front face, section "Meshes").
fn unit_box() -> (Vec<f32>, Vec<f32>, Vec<u16>) {
    let mut positions = Vec::with_capacity(24 * 3);
    let mut normals = Vec::with_capacity(24 * 3);
    let mut indices = Vec::with_capacity(36);
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let n = Vector3::from_fn(|i, _| if i == axis { sign } else { 0.0 });
            // (u, v, n) right-handed, so u, u+v, v runs counter-clockwise seen from +n.
            let u = Vector3::from_fn(|i, _| if i == (axis + 1) % 3 { 1.0 } else { 0.0 }) * sign;
            let v = n.cross(&u);
            let base = (positions.len() / 3) as u16;
            for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let p = (n + u * a + v * b) * 0.5;
                positions.extend_from_slice(p.as_slice());
                normals.extend_from_slice(n.as_slice());
            }
            indices.extend([0, 1, 2, 0, 2, 3].map(|i| base + i));
        }
    }
    (positions, normals, indices)
}

/// The animation: keyframe times, the root translation, and every joint's rotation.
fn animate(doc: &mut Document, clip: &MotionClip, name: &str, nodes: &JointNodes) {
    let times: Vec<f32> = (0..clip.poses.len())
        .map(|k| (k as f64 * clip.frame_time_s) as f32)
        .collect();
    let input = doc.floats(&times, Type::Scalar, true, None);
    let root: Vec<f32> = clip
        .poses
        .iter()
        .flat_map(|p| f32x3(&p.root_in_world_m))
        .collect();
    let mut channels = vec![(
        JointId::ROOT,
        json::animation::Property::Translation,
        doc.floats(&root, Type::Vec3, false, None),
    )];
    for j in nodes.joints() {
        let rotations = continuous_quaternions(clip, j);
        let output = doc.floats(&rotations, Type::Vec4, false, None);
        channels.push((j, json::animation::Property::Rotation, output));
    }
    let mut animation = json::Animation {
        extensions: None,
        extras: Default::default(),
        channels: Vec::with_capacity(channels.len()),
        name: Some(name.to_owned()),
        samplers: Vec::with_capacity(channels.len()),
    };
    for (k, (joint, path, output)) in channels.into_iter().enumerate() {
        animation.samplers.push(json::animation::Sampler {
            extensions: None,
            extras: Default::default(),
            input,
            interpolation: Valid(json::animation::Interpolation::Linear),
            output,
        });
        animation.channels.push(json::animation::Channel {
            sampler: json::Index::new(k as u32),
            target: json::animation::Target {
                extensions: None,
                extras: Default::default(),
                node: json::Index::new(nodes.of_joint(joint).unwrap_or(0) as u32),
                path: Valid(path),
            },
            extensions: None,
            extras: Default::default(),
        });
    }
    doc.root.animations.push(animation);
}

/// Joint `j`'s local rotation in every frame as `[x, y, z, w]`, each quaternion on the side of
/// the previous one (q and −q are the same rotation; a viewer's slerp between opposite signs
/// would take the long way round).
fn continuous_quaternions(clip: &MotionClip, j: JointId) -> Vec<f32> {
    let mut out = Vec::with_capacity(clip.poses.len() * 4);
    let mut previous: Option<UnitQuaternion<f64>> = None;
    for pose in &clip.poses {
        let mut q = UnitQuaternion::from_rotation_matrix(&pose.parent_from_joint[j.index()]);
        if previous.is_some_and(|p| p.coords.dot(&q.coords) < 0.0) {
            q = UnitQuaternion::new_unchecked(-q.into_inner());
        }
        out.extend([q.i, q.j, q.k, q.w].map(|v| v as f32));
        previous = Some(q);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every face of the unit box: its 4 vertices on the face, its normal pointing out, both
    /// triangles counter-clockwise seen from outside (their cross product along the normal).
    #[test]
    fn the_unit_box_faces_outwards_counter_clockwise() {
        let (p, n, idx) = unit_box();
        assert_eq!((p.len(), n.len(), idx.len()), (72, 72, 36));
        let at = |v: &[f32], i: u16| {
            Vector3::new(
                v[3 * i as usize],
                v[3 * i as usize + 1],
                v[3 * i as usize + 2],
            )
        };
        for tri in idx.chunks(3) {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| at(&p, i));
            let normal = at(&n, tri[0]);
            assert!(a.iter().all(|x| x.abs() == 0.5), "{a:?} is a corner");
            assert!(
                (a.dot(&normal) - 0.5).abs() < 1e-6,
                "on the face of {normal:?}"
            );
            let face = (b - a).cross(&(c - a));
            assert!(face.dot(&normal) > 0.0, "counter-clockwise from outside");
        }
    }

    #[test]
    fn bounds_are_per_component() {
        let (min, max) = component_bounds(&[1.0, -2.0, 3.0, 0.5, 4.0, -1.0], 3);
        assert_eq!((min, max), (vec![0.5, -2.0, -1.0], vec![1.0, 4.0, 3.0]));
    }
}
