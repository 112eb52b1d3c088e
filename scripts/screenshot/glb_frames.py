"""Render frames of an `imuflow export --format glb` file with Blender's Workbench engine.

    blender -b --factory-startup --python scripts/screenshot/glb_frames.py -- \
        MOTION.glb RATE_HZ VIEW_DEG OUT_PREFIX FRAME [FRAME ...]

Writes OUT_PREFIX-FRAME.png for each frame (the glb's keyframe index): the figure on a floor
plane, the camera level with the pelvis, VIEW_DEG degrees off the body's forward to its left (90:
from the side, where knees and elbows bend in the picture's plane). Used for the pictures of
retargeted motion in the docs (libs/motion/mappings/README.md). The import and the camera are
scripts/verify/blender_check.py's.
"""

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "verify"))

import blender_check  # noqa: E402  (Blender's Python, after the path above)

JOINTS = ["pelvis"]


def main():
    argv = sys.argv
    rest = argv[argv.index("--") + 1:] if "--" in argv else []
    if len(rest) < 5:
        raise SystemExit("usage: blender -b --python glb_frames.py -- MOTION.glb RATE_HZ VIEW_DEG OUT_PREFIX FRAME [FRAME ...]")
    glb, rate_hz, view_deg, prefix = rest[0], float(rest[1]), float(rest[2]), rest[3]
    frames = [int(f) for f in rest[4:]]
    for frame in frames:
        # A fresh scene per frame: render() adds its floor and camera to the scene it is given.
        scene = blender_check.new_scene(rate_hz)
        objects = blender_check.import_glb(glb, JOINTS)
        out = f"{prefix}-{frame}.png"
        blender_check.render(scene, objects, frame, out, view_deg)
        print(f"glb_frames: rendered frame {frame} of {glb} to {out}", flush=True)


if __name__ == "__main__":
    main()
