"""Imports a facecap `animation.glb` into Blender (headless) and prints what Blender sees:
mesh, vertex count, shape keys and the animated shape-key curves with their keyframe range.
Exits non-zero when the import fails or the morph animation did not arrive.

    blender -b --factory-startup --python scripts/blender_import_check.py -- OUT/video/animation.glb

(Blender from Debian: `apt-get install blender`; not needed by facecap itself.)
"""
import sys

import bpy


def main():
    path = sys.argv[sys.argv.index("--") + 1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=path)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    if not meshes:
        sys.exit("no mesh imported")
    ok = False
    for o in meshes:
        keys = o.data.shape_keys
        nkeys = len(keys.key_blocks) - 1 if keys else 0
        print(f"mesh {o.name}: {len(o.data.vertices)} vertices, {nkeys} shape keys")
        anim = keys.animation_data if keys else None
        if anim and anim.action:
            curves = anim.action.fcurves
            frames = [k.co.x for c in curves for k in c.keyframe_points]
            moving = sum(1 for c in curves if len({round(k.co.y, 6) for k in c.keyframe_points}) > 1)
            print(f"  shape-key action {anim.action.name}: {len(curves)} curves, {len(frames)} keyframes, "
                  f"frames {min(frames):.1f}-{max(frames):.1f}, {moving} curves that change")
            ok = nkeys > 0 and len(curves) == nkeys and moving > 0
    if not ok:
        sys.exit("shape keys or their animation missing")
    print("BLENDER IMPORT OK")


main()
