"""Blender reads imuflow's exports as imuflow moves the body: a check of `imuflow export`.

    blender -b --python scripts/verify/blender_check.py -- EXPORT.bvh EXPORT.glb EXPECTED.json OUT.png

EXPORT.bvh and EXPORT.glb are one channel exported by `imuflow export --format bvh|glb`;
EXPECTED.json is imuflow's forward kinematics of some of their frames (the `fk_reference`
example of tools/export). Both files are imported with Blender's own importers (BVH as an
armature, glTF as a node hierarchy of empties and meshes); at each expected frame every joint's
world position and world rotation in Blender is turned back into imuflow's model frame M and
compared with the expected ones. Passes when every joint is within 5 mm and 0.5 degrees. Then one
frame of the imported glb is rendered with the Workbench engine to OUT.png.

Axes: both importers turn a Y-up file into Blender's Z-up the same way, (x, y, z) -> (x, -z, y);
that is the rotation `BLENDER_FROM_MODEL` below, undone before comparing. Frames: the BVH's frame
k is Blender's frame 1 + k (the importer's frame_start = 1); the glb's keyframe k at k / rate s is
Blender's frame k once the scene runs at the recording's rate (set before importing).

Prints lines starting with `blender_check:`; exits 1 when a difference is over its tolerance or
a file does not import.
"""

import builtins
import contextlib
import json
import math
import sys

import bpy
from mathutils import Matrix, Quaternion, Vector

TOLERANCE_MM = 5.0
TOLERANCE_DEG = 0.5
BVH_FRAME_START = 1

# Blender's frame from imuflow's model frame M (x left, y up, z forward): the Y-up to Z-up
# conversion both importers apply.
BLENDER_FROM_MODEL = Matrix(((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)))
MODEL_FROM_BLENDER = BLENDER_FROM_MODEL.transposed()


def say(text):
    print(f"blender_check: {text}", flush=True)


def arguments():
    argv = sys.argv
    rest = argv[argv.index("--") + 1:] if "--" in argv else []
    if len(rest) != 4:
        raise SystemExit("usage: blender -b --python blender_check.py -- EXPORT.bvh EXPORT.glb EXPECTED.json OUT.png")
    return rest


def to_model(position, rotation):
    """A Blender world position (Vector) and world rotation (3x3 Matrix) in frame M."""
    return MODEL_FROM_BLENDER @ position, MODEL_FROM_BLENDER @ rotation @ BLENDER_FROM_MODEL


def angle_deg(a, b):
    """The angle between two rotations given as quaternions of either sign (degrees): from the
    relative rotation conj(a)·b in double precision, 2·atan2(|vector part|, |w|) (acos of the dot
    product would lose small angles to float32 rounding: 1 - 1e-7 is already 0.05 degrees)."""
    aw, ax, ay, az = (float(v) for v in a)
    bw, bx, by, bz = (float(v) for v in b)
    w = aw * bw + ax * bx + ay * by + az * bz
    x = aw * bx - ax * bw - ay * bz + az * by
    y = aw * by + ax * bz - ay * bw - az * bx
    z = aw * bz - ax * by + ay * bx - az * bw
    return math.degrees(2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)))


def new_scene(rate_hz):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    # Keyframe k of the glb (at k / rate s) lands on frame k.
    scene.render.fps = max(1, round(rate_hz))
    scene.render.fps_base = scene.render.fps / rate_hz
    return scene


@contextlib.contextmanager
def open_without_universal_newlines():
    """Blender 3.4's BVH importer opens its file with mode 'rU', an error on Python 3.11 (which
    Debian's Blender 3.4 runs on); 'U' has meant nothing since Python 3.0, so drop it meanwhile."""
    original = builtins.open

    def open_(file, mode="r", *args, **kwargs):
        return original(file, mode.replace("U", ""), *args, **kwargs)

    builtins.open = open_
    try:
        yield
    finally:
        builtins.open = original


def import_bvh(path):
    before = set(bpy.data.objects)
    with open_without_universal_newlines():
        bpy.ops.import_anim.bvh(filepath=path, axis_forward="-Z", axis_up="Y", global_scale=1.0,
                                frame_start=BVH_FRAME_START, use_fps_scale=False,
                                update_scene_fps=False, update_scene_duration=False,
                                rotate_mode="NATIVE")
    armatures = [o for o in set(bpy.data.objects) - before if o.type == "ARMATURE"]
    if len(armatures) != 1:
        raise RuntimeError(f"{path}: imported {len(armatures)} armatures, expected 1")
    return armatures[0]


@contextlib.contextmanager
def numpy_bool_alias():
    """Blender 3.4's glTF importer uses `numpy.bool`, an alias of `bool` that numpy 1.24 (Debian
    12's) removed; give it back meanwhile."""
    try:
        import numpy
    except ImportError:
        raise RuntimeError("Blender's glTF importer needs numpy: apt-get install -y python3-numpy") from None
    missing = "bool" not in numpy.__dict__
    if missing:
        numpy.bool = bool
    try:
        yield
    finally:
        if missing:
            del numpy.bool


def import_glb(path, joints):
    before = set(bpy.data.objects)
    with numpy_bool_alias():
        bpy.ops.import_scene.gltf(filepath=path)
    new = {o.name: o for o in set(bpy.data.objects) - before}
    missing = [j for j in joints if j not in new]
    if missing:
        raise RuntimeError(f"{path}: no object for joints {missing} (imported: {sorted(new)})")
    return new


def bvh_joint(armature, name):
    """A BVH joint's world position and its world rotation relative to the rest pose (the T-pose,
    in which every joint frame is M's): the pose bone's matrix times its rest matrix inverted."""
    bone = armature.pose.bones[name]
    world = armature.matrix_world
    position = world @ bone.head
    rotation = world.to_3x3() @ bone.matrix.to_3x3() @ bone.bone.matrix_local.to_3x3().inverted()
    return position, rotation


def glb_joint(obj):
    world = obj.matrix_world
    return world.to_translation(), world.to_3x3().normalized()


def compare(scene, expected, armature, objects):
    """Every expected frame and joint; the worst differences per file: (mm, degrees, where)."""
    worst = {"bvh": [0.0, 0.0, ""], "glb": [0.0, 0.0, ""]}
    joints = expected["joints"]
    for frame in expected["frames"]:
        k = frame["index"]
        readings = {}
        scene.frame_set(BVH_FRAME_START + k)
        readings["bvh"] = [bvh_joint(armature, j) for j in joints]
        scene.frame_set(k)
        readings["glb"] = [glb_joint(objects[j]) for j in joints]
        for i, joint in enumerate(joints):
            want_p = Vector(frame["position_m"][i])
            want_q = Quaternion(frame["rotation_wxyz"][i])
            for kind, values in readings.items():
                p, r = to_model(*values[i])
                mm = (p - want_p).length * 1000.0
                deg = angle_deg(r.to_quaternion(), want_q)
                w = worst[kind]
                if mm > w[0]:
                    w[0] = mm
                if deg > w[1]:
                    w[1] = deg
                if mm > TOLERANCE_MM or deg > TOLERANCE_DEG:
                    w[2] = w[2] or f"frame {k} {joint}: {mm:.3f} mm, {deg:.4f} deg"
    return worst


def show_materials_in_workbench():
    """The glb's colours live in each material's node tree; Workbench draws the viewport colour."""
    for material in bpy.data.materials:
        nodes = material.node_tree.nodes if material.use_nodes and material.node_tree else []
        for node in nodes:
            if node.type == "BSDF_PRINCIPLED":
                material.diffuse_color = node.inputs["Base Color"].default_value


def render(scene, objects, frame, out_png, view_deg=35.0):
    """Frame `frame` of the imported glb (`objects`) rendered with Workbench to `out_png`, the
    camera level with the pelvis, `view_deg` degrees off the body's forward (+z in M) to its left
    (90: from the side)."""
    show_materials_in_workbench()
    scene.frame_set(frame)
    pelvis, rotation = glb_joint(objects["pelvis"])
    forward = rotation @ (BLENDER_FROM_MODEL @ Vector((0.0, 0.0, 1.0)))
    forward.z = 0.0
    forward = forward.normalized() if forward.length > 1e-6 else Vector((0.0, -1.0, 0.0))
    view = Matrix.Rotation(math.radians(view_deg), 3, "Z") @ forward
    bpy.ops.mesh.primitive_plane_add(size=6.0, location=(pelvis.x, pelvis.y, 0.0))
    floor = bpy.context.active_object
    floor_material = bpy.data.materials.new("floor")
    floor_material.diffuse_color = (0.8, 0.8, 0.76, 1.0)
    floor.data.materials.append(floor_material)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.lens = 50.0
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    camera.location = pelvis + view * 4.2 + Vector((0.0, 0.0, 0.25))
    target = Vector((pelvis.x, pelvis.y, pelvis.z * 0.95))
    camera.rotation_euler = (target - camera.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = camera
    scene.world = bpy.data.worlds.new("background")
    scene.world.color = (0.78, 0.80, 0.84)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "MATERIAL"
    scene.display.shading.show_shadows = True
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_x, scene.render.resolution_y = 480, 360
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100
    scene.render.filepath = out_png
    bpy.ops.render.render(write_still=True)


def main():
    bvh_path, glb_path, expected_path, out_png = arguments()
    with open(expected_path) as f:
        expected = json.load(f)
    scene = new_scene(expected["rate_hz"])
    armature = import_bvh(bvh_path)
    objects = import_glb(glb_path, expected["joints"])
    n = expected["frames_exported"]
    first, last = armature.animation_data.action.frame_range
    bvh_frames = round(last - first) + 1
    say(f"Blender {bpy.app.version_string}: {bvh_path} ({bvh_frames} frames), {glb_path}; "
        f"{len(expected['frames'])} frames x {len(expected['joints'])} joints compared")
    if bvh_frames != n:
        raise RuntimeError(f"{bvh_path}: Blender imported {bvh_frames} frames, imuflow exported {n}")
    worst = compare(scene, expected, armature, objects)
    failed = False
    for kind in ("bvh", "glb"):
        mm, deg, where = worst[kind]
        say(f"{kind}: max position difference {mm:.4f} mm, max rotation difference {deg:.5f} deg "
            f"(tolerance {TOLERANCE_MM} mm, {TOLERANCE_DEG} deg)")
        if where:
            say(f"{kind}: FAILED, first over tolerance: {where}")
            failed = True
    frames = [f["index"] for f in expected["frames"]]
    armature.hide_render = True
    render(scene, objects, frames[len(frames) // 2], out_png)
    say(f"rendered frame {frames[len(frames) // 2]} of {glb_path} to {out_png}")
    return 1 if failed else 0


if __name__ == "__main__":
    try:
        code = main()
    except Exception as e:  # any failure is a failed check, said on one line
        say(f"FAILED: {type(e).__name__}: {e}")
        code = 1
    sys.exit(code)
