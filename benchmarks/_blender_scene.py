"""What the Blender runners share (``_cycles_bake.py``, ``_peers_blender.py``; run inside a
Python that has ``bpy``): an empty scene holding one OBJ as the file has it."""

from __future__ import annotations

import time


def import_one_mesh(mesh: str):
    """Factory settings with no objects, then ``mesh`` imported with Blender's own OBJ
    importer, axes untouched (forward Y, up Z: the vertex coordinates are the file's), its
    one mesh object selected and active.  Returns (object, seconds the import took); exits
    naming the file if the import made other than one mesh object."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    start = time.perf_counter()
    bpy.ops.wm.obj_import(filepath=mesh, forward_axis="Y", up_axis="Z")
    import_s = time.perf_counter() - start
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    if len(objects) != 1:
        raise SystemExit(f"{mesh}: expected one mesh object after import, got {len(objects)}")
    obj = objects[0]
    for other in bpy.context.scene.objects:
        other.select_set(other is obj)
    bpy.context.view_layer.objects.active = obj
    return obj, import_s
