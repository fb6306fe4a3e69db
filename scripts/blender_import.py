"""Imports a facecap capture into Blender: `animation.glb` (mesh, shape keys, the morph
weight animation and the head motion), with the scene's frame rate and frame range set
from the capture's `summary.json`, so every keyframe lands on a whole frame.

    blender -b --factory-startup --python scripts/blender_import.py -- OUT/video [--save OUT.blend] [--check]

`OUT/video` is a capture folder (`animation.glb` and `summary.json`), or the path of an
`animation.glb` with its `summary.json` beside it. Without `summary.json` the frame rate
comes from the glTF (`animations[0].extras.fps`, written by facecap).

With `--check` the script verifies what Blender built and exits non-zero when something
is missing: a mesh with shape keys, a shape-key action with one curve per key, the head's
object action (location and rotation curves) unless the capture was made with
`--still-head`, the scene rate equal to the video's, and every keyframe on a whole frame.
It prints `BLENDER IMPORT OK` on success.

facecap's glTF keys frame `i` at `i / fps` seconds; Blender's importer converts seconds to
frames at the scene rate (`bpy.context.scene.render.fps`) when importing, so the rate is set
*before* the import. Rates that are not whole numbers (29.97) go through `fps_base`.

(Debian's Blender: `apt-get install blender`; see docs/capture.md "Checked in Blender" for
the numpy it needs. Blender is not needed by facecap itself.)
"""
import json
import os
import struct
import sys

import bpy


def glb_fps(path):
    """The frame rate facecap wrote into the GLB's first animation's extras, or None."""
    with open(path, "rb") as f:
        head = f.read(20)
        if len(head) < 20 or head[:4] != b"glTF":
            return None
        length, kind = struct.unpack("<II", head[12:20])
        if kind != 0x4E4F534A:  # JSON
            return None
        doc = json.loads(f.read(length))
    anims = doc.get("animations") or []
    return (anims[0].get("extras") or {}).get("fps") if anims else None


def set_rate(scene, fps):
    """Scene rate `fps` as Blender's integer `fps` and float `fps_base`."""
    whole = round(fps)
    if abs(whole - fps) < 1e-6:
        scene.render.fps, scene.render.fps_base = int(whole), 1.0
    else:
        # e.g. 29.97 = 30 / 1.001
        scene.render.fps = int(whole)
        scene.render.fps_base = whole / fps


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if not argv:
        sys.exit("usage: blender -b --python blender_import.py -- CAPTURE_DIR|animation.glb [--save F.blend] [--check]")
    target = argv[0]
    check = "--check" in argv
    save = argv[argv.index("--save") + 1] if "--save" in argv else None
    glb = os.path.join(target, "animation.glb") if os.path.isdir(target) else target
    summary_path = os.path.join(os.path.dirname(glb), "summary.json")
    summary = {}
    if os.path.isfile(summary_path):
        with open(summary_path) as f:
            summary = json.load(f)
    fps = summary.get("fps") or glb_fps(glb)
    if not fps or fps <= 0:
        sys.exit("no frame rate: neither summary.json nor the glTF says it")
    frames = summary.get("frames")

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    set_rate(scene, fps)
    bpy.ops.import_scene.gltf(filepath=glb)
    rate = scene.render.fps / scene.render.fps_base

    keys = []
    meshes = [o for o in scene.objects if o.type == "MESH"]
    head_curves = 0
    for o in meshes:
        sk = o.data.shape_keys
        nkeys = len(sk.key_blocks) - 1 if sk else 0
        anim = sk.animation_data if sk else None
        curves = anim.action.fcurves if anim and anim.action else []
        keys += [k.co.x for c in curves for k in c.keyframe_points]
        print(f"mesh {o.name}: {len(o.data.vertices)} vertices, {nkeys} shape keys, {len(curves)} shape-key curves")
        for obj in [o] + ([o.parent] if o.parent else []):
            if obj.animation_data and obj.animation_data.action:
                oc = obj.animation_data.action.fcurves
                head_curves += sum(1 for c in oc if c.data_path in ("location", "rotation_quaternion", "rotation_euler"))
                keys += [k.co.x for c in oc for k in c.keyframe_points]
    if keys:
        first, last = int(round(min(keys))), int(round(max(keys)))
    else:
        first, last = 0, max((frames or 1) - 1, 0)
    if frames:
        last = max(last, first + frames - 1)
    scene.frame_start, scene.frame_end = first, last
    off_frame = [k for k in keys if abs(k - round(k)) > 1e-3]
    print(f"scene: {rate:.3f} fps, frames {scene.frame_start}-{scene.frame_end}, {len(keys)} keyframes, "
          f"{len(off_frame)} off whole frames, {head_curves} head curves")
    if save:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(save))
        print(f"saved {save}")
    if check:
        problems = []
        if not meshes or not any(o.data.shape_keys for o in meshes):
            problems.append("no mesh with shape keys")
        if not keys:
            problems.append("no animation imported")
        if off_frame:
            problems.append(f"{len(off_frame)} keyframes off whole frames (first at {off_frame[0]})")
        if abs(rate - fps) > 1e-6:
            problems.append(f"scene rate {rate} != video rate {fps}")
        if summary.get("head_animated") and head_curves < 2:
            problems.append("the head motion did not arrive (no location/rotation curves)")
        if frames and scene.frame_end - scene.frame_start + 1 != frames:
            problems.append(f"frame range {scene.frame_start}-{scene.frame_end} != {frames} frames")
        if problems:
            sys.exit("; ".join(problems))
        print("BLENDER IMPORT OK")


main()
