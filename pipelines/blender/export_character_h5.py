"""Export an animated Blender object as a knitvox HDF5 character cache
(schemas/character-hdf5.md), evaluated with every modifier and deformer
(armature, shape keys, corrective smooth, cloth layers, ...).

    blender -b scene.blend --python pipelines/blender/export_character_h5.py -- \
        --object Body --frames 1-120 -o body.h5

Needs h5py in Blender's own Python (once: `<blender>/python/bin/python3.* -m pip install h5py`).
Writes metres (the scene's unit scale applied) and Blender's +Z up, declared in the
file (`up_axis = "z"`); knitvox converts to +Y on read. The rest pose is the
object evaluated with its armature modifiers disabled at the first frame (the
bind pose), so the garment is placed as on a glTF character's bind pose.
"""
import argparse
import sys

import bpy
import h5py
import numpy as np


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--object", required=True, help="name of the animated mesh object")
    p.add_argument("--frames", required=True, help="first-last (scene frames, inclusive)")
    p.add_argument("-o", "--output", required=True, help="output .h5 (written to a temporary, then renamed)")
    return p.parse_args(argv)


def evaluated_positions(obj, depsgraph):
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        co = np.empty(len(mesh.vertices) * 3, "f8")
        mesh.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3)
        m = np.array(ev.matrix_world)
        co = co @ m[:3, :3].T + m[:3, 3]
        mesh.calc_loop_triangles()
        tris = np.empty(len(mesh.loop_triangles) * 3, "i8")
        mesh.loop_triangles.foreach_get("vertices", tris)
        return co, tris.reshape(-1, 3)
    finally:
        ev.to_mesh_clear()


def main():
    args = parse_args()
    scene = bpy.context.scene
    obj = bpy.data.objects[args.object]
    first, last = (int(x) for x in args.frames.split("-"))
    scale = scene.unit_settings.scale_length
    fps = scene.render.fps / scene.render.fps_base

    scene.frame_set(first)
    armatures = [m for m in obj.modifiers if m.type == "ARMATURE" and m.show_viewport]
    for m in armatures:
        m.show_viewport = False
    rest, tris = evaluated_positions(obj, bpy.context.evaluated_depsgraph_get())
    for m in armatures:
        m.show_viewport = True

    frames = []
    for f in range(first, last + 1):
        scene.frame_set(f)
        co, t = evaluated_positions(obj, bpy.context.evaluated_depsgraph_get())
        if co.shape != rest.shape or not np.array_equal(t, tris):
            sys.exit(f"frame {f}: the topology changed ({len(co)} vertices); a cache needs a fixed mesh")
        frames.append(co)

    tmp = args.output + ".partial"
    with h5py.File(tmp, "w") as h:
        h.attrs["knitvox_format"] = "character"
        h.attrs["knitvox_format_version"] = np.int64(1)
        h.attrs["units"] = repr(float(scale))
        h.attrs["up_axis"] = "z"
        h.attrs["generator"] = f"Blender {bpy.app.version_string} export_character_h5.py"
        g = h.create_group("character")
        g["triangles"] = tris
        g["times"] = (np.arange(first, last + 1) - first) / fps
        g.create_dataset("points", data=np.stack(frames), chunks=(1, len(rest), 3),
                         shuffle=True, compression="gzip", compression_opts=4)
        g["rest_points"] = rest
    import os
    os.replace(tmp, args.output)


if __name__ == "__main__":
    main()
