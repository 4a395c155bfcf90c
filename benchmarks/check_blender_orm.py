"""Does Blender load an aobake ORM GLB with the AO wired to glTF occlusion?  (issue 25)

Run with a Python that has ``bpy`` (Blender as a module; Python 3.11 only, ~300 MB wheel, in
a venv of its own so it cannot move the project's numpy):

    python3.11 -m venv /tmp/bpy && /tmp/bpy/bin/pip install --no-deps bpy==5.0.1 "numpy<2"
    /tmp/bpy/bin/python benchmarks/check_blender_orm.py baked.glb

``tests/test_orm.py`` runs it when ``AOBAKE_BLENDER_PYTHON`` names such a Python.

Blender's glTF importer (io_import_scene_gltf2) turns ``occlusionTexture`` into an Image
Texture -> Separate Color -> Red -> the "Occlusion" input of its "glTF Material Output" node
group (Blender itself renders no AO from it; the exporter writes it back), and
``metallicRoughnessTexture`` into Image Texture -> Separate Color -> Green -> Roughness,
Blue -> Metallic of the Principled BSDF.  This script imports the file and checks, for every
material: occlusion wired through R; roughness through G and metalness through B; both from
the same image (the ORM map); both read through the UV layer of ``occlusionTexture.texCoord``.
It prints one JSON line (``ok``, Blender's version, what each material has) and exits 1 when a
check fails.
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


def _through_separate(links, node, socket, channel):
    """The image node behind ``node.socket`` <- Separate Color.<channel>, or None."""
    separate, out = _source(links, node, socket)
    if separate is None or separate.bl_idname != "ShaderNodeSeparateColor" or out != channel:
        return None
    image, _ = _source(links, separate, "Color")
    return image if image is not None and image.bl_idname == "ShaderNodeTexImage" else None


def _uv_layer(links, image):
    uv_node, _ = _source(links, image, "Vector")
    return getattr(uv_node, "uv_map", None)


def check(path: str) -> dict:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=path)
    with open(path, "rb") as handle:  # the texCoord the file asks for
        data = handle.read()
    length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20:20 + length])
    tex_coord = gltf["materials"][0]["occlusionTexture"].get("texCoord", 0)
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    layers = [layer.name for layer in meshes[0].data.uv_layers] if meshes else []
    expected_layer = layers[tex_coord] if tex_coord < len(layers) else None
    found, ok = [], bool(bpy.data.materials)
    for material in bpy.data.materials:
        nodes, links = material.node_tree.nodes, material.node_tree.links
        group = next((n for n in nodes if n.bl_idname == "ShaderNodeGroup" and n.node_tree
                      and n.node_tree.name in ("glTF Material Output", "glTF Settings")), None)
        bsdf = next((n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
        occlusion = _through_separate(links, group, "Occlusion", "Red") if group else None
        rough = _through_separate(links, bsdf, "Roughness", "Green") if bsdf else None
        metal = _through_separate(links, bsdf, "Metallic", "Blue") if bsdf else None
        images = {n.image.name for n in (occlusion, rough, metal) if n is not None and n.image}
        uv_maps = {_uv_layer(links, n) for n in (occlusion, rough, metal) if n is not None}
        entry = {"material": material.name, "occlusion_from_red": occlusion is not None,
                 "roughness_from_green": rough is not None,
                 "metallic_from_blue": metal is not None, "images": sorted(images),
                 "uv_maps": sorted(str(u) for u in uv_maps), "expected_uv_map": expected_layer}
        entry["ok"] = (occlusion is not None and rough is not None and metal is not None
                       and len(images) == 1 and uv_maps == {expected_layer})
        ok &= entry["ok"]
        found.append(entry)
    return {"ok": ok, "blender": bpy.app.version_string, "file": path,
            "occlusion_tex_coord": tex_coord, "uv_layers": layers, "materials": found}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: check_blender_orm.py FILE.glb")
    result = check(sys.argv[1])
    print(json.dumps(result))
    sys.exit(0 if result["ok"] else 1)
