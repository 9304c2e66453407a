"""Run inside Blender: import a BVH with Blender's own importer and write where its joints are.

    blender -b --factory-startup --python benchmarks/blender_bvh.py -- IN.bvh OUT.json

Imports with the importer's default axes (forward -Z, up Y) and scale 0.01 (Ringside's BVH is in
centimetres), so positions come out in metres in Blender's z-up world. Writes {"frames": N,
"joints": [names], "positions": [[[x, y, z] per joint] per frame]}: each pose bone's head, the
joint's position, in world space.
"""

import builtins
import json
import sys

import bpy
from io_anim_bvh import import_bvh

# Debian's Blender 3.4 runs on Python 3.11, which dropped open()'s "U" mode that this importer
# still asks for ("ValueError: invalid mode: 'rU'"); the importer's own code is otherwise used
# as is.
import_bvh.open = lambda path, mode="r", *args, **kwargs: builtins.open(  # noqa: SIM115
    path, mode.replace("U", ""), *args, **kwargs
)

source, out = sys.argv[sys.argv.index("--") + 1 :]
bpy.ops.import_anim.bvh(filepath=source, global_scale=0.01, use_fps_scale=False)
armature = bpy.context.object
scene = bpy.context.scene
first, last = (round(f) for f in armature.animation_data.action.frame_range)
names = [bone.name for bone in armature.pose.bones]
positions = []
for frame in range(first, last + 1):
    scene.frame_set(frame)
    positions.append([list(armature.matrix_world @ armature.pose.bones[n].head) for n in names])
with open(out, "w") as file:
    json.dump({"frames": len(positions), "joints": names, "positions": positions}, file)
