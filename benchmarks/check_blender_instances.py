"""Does Blender load aobake's lightmap of a set of instances with each instance reading its own
region of the atlas?  (issue 34)

Run with a Python that has ``bpy`` (as ``check_blender_orm.py``; ``tests/test_instances_atlas.py``
runs it when ``AOBAKE_BLENDER_PYTHON`` names one):

    $AOBAKE_BLENDER_PYTHON benchmarks/check_blender_instances.py set_ao.glb

aobake writes one material per instance whose ``occlusionTexture`` (and, packed as ORM, its
``metallicRoughnessTexture``) carries ``KHR_texture_transform`` (offset, scale: the
instance's region).  Blender's glTF importer turns that into UV Map -> Mapping (Location,
Scale, in Blender's UV space: v up) -> Image Texture -> Separate Color.Red -> the
"Occlusion" input of its "glTF Material Output" group (and, for an ORM map, Separate
Color.Green -> Roughness of the Principled BSDF from the same image, region and UV map).
For every mesh object this script checks: its material's occlusion is wired through R from the one atlas image, through a
Mapping node fed by a UV map the object has; and every UV of the object, mapped by that
node, lands inside the region the file's node names (``extras.aobake_region``, texels, y
from the top row) with its margin.  It also checks that each object stands where its node's
matrix puts it.  It prints one JSON line (``ok``, Blender's version, one entry per object)
and exits 1 when a check fails.
"""

from __future__ import annotations

import json
import sys


def _source(links, node, socket):
    """(node, socket name) feeding ``node``'s input ``socket``, or (None, None)."""
    for link in links:
        if link.to_node == node and link.to_socket.name == socket:
            return link.from_node, link.from_socket.name
    return None, None


def _occlusion_image(material, socket="Occlusion", channel="Red"):
    """(image node, mapping node, uv map name) of a material's occlusion (or, with
    ``socket`` "Roughness" / channel "Green", of its packed ORM map's roughness), or Nones."""
    nodes, links = material.node_tree.nodes, material.node_tree.links
    if socket == "Occlusion":
        group = next((n for n in nodes if n.bl_idname == "ShaderNodeGroup" and n.node_tree
                      and n.node_tree.name in ("glTF Material Output", "glTF Settings")), None)
    else:
        group = next((n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
    if group is None:
        return None, None, None
    separate, out = _source(links, group, socket)
    if separate is None or separate.bl_idname != "ShaderNodeSeparateColor" or out != channel:
        return None, None, None
    image, _ = _source(links, separate, "Color")
    if image is None or image.bl_idname != "ShaderNodeTexImage":
        return None, None, None
    mapping, _ = _source(links, image, "Vector")
    if mapping is None or mapping.bl_idname != "ShaderNodeMapping":
        return image, None, None
    uv_node, _ = _source(links, mapping, "Vector")
    return image, mapping, getattr(uv_node, "uv_map", None)


def check(path: str) -> dict:
    import bpy
    import numpy as np

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=path)
    with open(path, "rb") as handle:
        data = handle.read()
    length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20:20 + length])
    width = gltf["images"][0].get("extras", {}).get("width")
    nodes = {node["name"]: node for node in gltf["nodes"]}
    size = json.loads(json.dumps(gltf["asset"]["extras"]["texture"]["instances"]["size"]))
    width, height = size
    margin = gltf["asset"]["extras"]["texture"]["instances"]["margin"]
    found, ok, images = [], True, set()
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    for obj in meshes:
        node = nodes.get(obj.name)
        entry = {"object": obj.name, "node_found": node is not None}
        material = obj.active_material
        image, mapping, uv_map = _occlusion_image(material) if material else (None,) * 3
        entry.update(material=getattr(material, "name", None),
                     occlusion_from_red=image is not None, mapping=mapping is not None,
                     uv_map=uv_map)
        good = node is not None and image is not None and mapping is not None \
            and uv_map in obj.data.uv_layers
        if good:
            images.add(image.image.name)
            location = np.array(mapping.inputs["Location"].default_value[:2])
            scale = np.array(mapping.inputs["Scale"].default_value[:2])
            layer = obj.data.uv_layers[uv_map]
            uv = np.array([loop.uv[:] for loop in layer.data])
            mapped = location + scale * uv  # Blender's UV space: v up, as aobake's OBJ UVs
            x, y, w, h = node["extras"]["aobake_region"]
            lo = np.array([(x - margin) / width, 1.0 - (y + h + margin) / height])
            hi = np.array([(x + w + margin) / width, 1.0 - (y - margin) / height])
            inside = bool(np.all(mapped >= lo - 1e-5) and np.all(mapped <= hi + 1e-5))
            entry.update(location=location.tolist(), scale=scale.tolist(), inside_region=inside,
                         mapped_box=[*mapped.min(axis=0).tolist(), *mapped.max(axis=0).tolist()],
                         region_box=[*lo.tolist(), *hi.tolist()])
            good &= inside
            # a packed ORM map: roughness from G of the same image, through the same region
            packed = any(m.get("pbrMetallicRoughness", {}).get("metallicRoughnessTexture")
                         for m in gltf.get("materials", []))
            if packed:
                rough, rough_map, rough_uv = _occlusion_image(material, "Roughness", "Green")
                same = (rough is not None and rough_map is not None
                        and rough.image == image.image and rough_uv == uv_map
                        and np.allclose(rough_map.inputs["Location"].default_value[:2],
                                        location)
                        and np.allclose(rough_map.inputs["Scale"].default_value[:2], scale))
                entry["roughness_through_region"] = bool(same)
                good &= bool(same)
            matrix = np.array(node.get("matrix", np.eye(4).T.reshape(-1).tolist())).reshape(4, 4).T
            # Blender's importer turns glTF's +Y up into its +Z up: compare the translation's
            # length (the conversion is a rotation)
            here = np.array(obj.matrix_world.translation[:])
            placed = bool(abs(np.linalg.norm(here) - np.linalg.norm(matrix[:3, 3])) < 1e-4)
            entry["placed"] = placed
            good &= placed
        entry["ok"] = bool(good)
        ok &= entry["ok"]
        found.append(entry)
    ok &= len(images) == 1 and len(meshes) == len(gltf["nodes"])
    return {"ok": bool(ok), "blender": bpy.app.version_string, "file": path,
            "objects": len(meshes), "nodes": len(gltf["nodes"]), "images": sorted(images),
            "instances": found}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: check_blender_instances.py FILE.glb")
    result = check(sys.argv[1])
    print(json.dumps(result))
    sys.exit(0 if result["ok"] else 1)
