"""Small glTF scenes written by the tests and benchmarks: parts with materials (alpha-cutout):
embedded buffers and PNG images, one mesh and one material per part; and scenes whose nodes
share meshes (instances, EXT_mesh_gpu_instancing): ``write_instanced``."""

from __future__ import annotations

import base64
import io
import json

import numpy as np


def png(alpha: np.ndarray) -> bytes:
    """(H, W) uint8 alpha -> RGBA PNG bytes (white)."""
    from PIL import Image

    rgba = np.full(alpha.shape + (4,), 255, dtype=np.uint8)
    rgba[..., 3] = alpha
    buffer = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buffer, format="PNG")
    return buffer.getvalue()


def write_gltf(path, parts) -> str:
    """A .gltf with embedded buffers and images: parts are dicts of vertices (v, 3), faces
    (f, 3), uv (v, 2) in glTF's convention (v = 0 at the image's top) and material {alphaMode,
    alphaCutoff (optional), factor, png (optional)}."""
    blob, views, accessors, meshes, materials, images, textures = (bytearray(), [], [], [], [],
                                                                   [], [])

    def add(array, target, component, kind):
        array = np.ascontiguousarray(array)
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": array.nbytes,
                      "target": target})
        blob.extend(array.tobytes())
        accessor = {"bufferView": len(views) - 1, "componentType": component,
                    "count": len(array), "type": kind}
        if kind == "VEC3":
            accessor.update(min=array.min(0).tolist(), max=array.max(0).tolist())
        accessors.append(accessor)
        return len(accessors) - 1

    for i, part in enumerate(parts):
        primitive = {"attributes": {
            "POSITION": add(part["vertices"].astype(np.float32), 34962, 5126, "VEC3"),
            "TEXCOORD_0": add(part["uv"].astype(np.float32), 34962, 5126, "VEC2")},
            "indices": add(part["faces"].astype(np.uint32).ravel(), 34963, 5125, "SCALAR"),
            "material": i}
        given = part["material"]
        material = {"name": f"material{i}", "alphaMode": given["alphaMode"],
                    "pbrMetallicRoughness": {"baseColorFactor": given.get("factor",
                                                                          [1, 1, 1, 1])}}
        if "alphaCutoff" in given:
            material["alphaCutoff"] = given["alphaCutoff"]
        if given.get("png") is not None:
            images.append({"uri": "data:image/png;base64,"
                                  + base64.b64encode(given["png"]).decode()})
            textures.append({"source": len(images) - 1})
            material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": len(textures) - 1}
        materials.append(material)
        meshes.append({"name": f"mesh{i}", "primitives": [primitive]})
    gltf = {"asset": {"version": "2.0"}, "scene": 0,
            "scenes": [{"nodes": list(range(len(parts)))}],
            "nodes": [{"mesh": i, "name": f"node{i}"} for i in range(len(parts))],
            "meshes": meshes, "materials": materials, "accessors": accessors,
            "bufferViews": views,
            "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                         + base64.b64encode(bytes(blob)).decode()}]}
    if images:
        gltf["images"], gltf["textures"] = images, textures
    with open(path, "w") as handle:
        json.dump(gltf, handle)
    return str(path)


def write_instanced(path, meshes, nodes, roots=None, base_color_png=None,
                    metallic_roughness_png=None) -> str:
    """A glTF scene whose nodes may share meshes (instances), as .gltf (embedded buffers) or
    .glb by the suffix of ``path``.

    meshes : list of {"name": str (optional), "primitives": [{"vertices" (v, 3), "faces"
    (f, 3), "normals" (v, 3) optional, "uv" (v, 2) optional (OBJ convention, v = 0 at the
    bottom: written as glTF's TEXCOORD_0, v flipped, with a plain material: trimesh reads a
    primitive's UVs only where it has a material)}, ...]} (or one primitive's keys at the top
    level);
    nodes : list of glTF node dicts (name, mesh, matrix | translation / rotation / scale,
    children) as written, except "instancing": {"TRANSLATION" (k, 3), "ROTATION" (k, 4)
    xyzw, "SCALE" (k, 3)} (any of them) becomes the node's EXT_mesh_gpu_instancing with
    its accessors; roots : the scene's root nodes (default: every node no other lists as a
    child); base_color_png, metallic_roughness_png : PNG bytes the plain material's
    baseColorTexture and metallicRoughnessTexture (TEXCOORD_0)."""
    import struct
    from pathlib import Path

    blob, views, accessors = bytearray(), [], []

    def add(array, target, component, kind):
        array = np.ascontiguousarray(array)
        blob.extend(b"\0" * (-len(blob) % 4))
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": array.nbytes}
        if target is not None:
            view["target"] = target
        views.append(view)
        blob.extend(array.tobytes())
        accessor = {"bufferView": len(views) - 1, "componentType": component,
                    "count": len(array), "type": kind}
        if kind == "VEC3":
            accessor.update(min=array.min(0).tolist(), max=array.max(0).tolist())
        accessors.append(accessor)
        return len(accessors) - 1

    out_meshes = []
    for i, mesh in enumerate(meshes):
        primitives = []
        for part in mesh.get("primitives", [mesh]):
            attributes = {"POSITION": add(np.asarray(part["vertices"], np.float32), 34962, 5126,
                                          "VEC3")}
            if part.get("normals") is not None:
                attributes["NORMAL"] = add(np.asarray(part["normals"], np.float32), 34962, 5126,
                                           "VEC3")
            if part.get("uv") is not None:
                uv = np.asarray(part["uv"], np.float64)
                attributes["TEXCOORD_0"] = add(np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])
                                               .astype(np.float32), 34962, 5126, "VEC2")
            primitive = {"attributes": attributes, "indices": add(
                np.asarray(part["faces"], np.uint32).ravel(), 34963, 5125, "SCALAR")}
            if part.get("uv") is not None:
                primitive["material"] = 0
            primitives.append(primitive)
        out_meshes.append({"name": mesh.get("name", f"mesh{i}"), "primitives": primitives})
    out_nodes, used = [], set()
    for node in nodes:
        node = dict(node)
        instancing = node.pop("instancing", None)
        if instancing is not None:
            attributes = {key: add(np.asarray(value, np.float32), None, 5126,
                                   "VEC4" if key == "ROTATION" else "VEC3")
                          for key, value in instancing.items()}
            node.setdefault("extensions", {})["EXT_mesh_gpu_instancing"] = {
                "attributes": attributes}
            used.add("EXT_mesh_gpu_instancing")
        out_nodes.append(node)
    children = {c for node in nodes for c in node.get("children", ())}
    roots = [i for i in range(len(nodes)) if i not in children] if roots is None else roots
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(roots)}],
            "nodes": out_nodes, "meshes": out_meshes, "accessors": accessors,
            "bufferViews": views}
    if used:
        gltf["extensionsUsed"] = sorted(used)
    if any("material" in p for m in out_meshes for p in m["primitives"]):
        gltf["materials"] = [{"name": "plain", "pbrMetallicRoughness": {
            "baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 0.0}}]
        for key, data in (("baseColorTexture", base_color_png),
                          ("metallicRoughnessTexture", metallic_roughness_png)):
            if data is None:
                continue
            blob.extend(b"\0" * (-len(blob) % 4))
            views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
            blob.extend(data)
            images = gltf.setdefault("images", [])
            images.append({"bufferView": len(views) - 1, "mimeType": "image/png"})
            textures = gltf.setdefault("textures", [])
            textures.append({"source": len(images) - 1})
            gltf["materials"][0]["pbrMetallicRoughness"][key] = {"index": len(textures) - 1}
    if Path(path).suffix.lower() == ".glb":
        blob.extend(b"\0" * (-len(blob) % 4))
        gltf["buffers"] = [{"byteLength": len(blob)}]
        text = json.dumps(gltf).encode()
        text += b" " * (-len(text) % 4)
        with open(path, "wb") as handle:
            handle.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(blob)))
            handle.write(struct.pack("<II", len(text), 0x4E4F534A))
            handle.write(text)
            handle.write(struct.pack("<II", len(blob), 0x004E4942))
            handle.write(bytes(blob))
        return str(path)
    gltf["buffers"] = [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                        + base64.b64encode(bytes(blob)).decode()}]
    with open(path, "w") as handle:
        json.dump(gltf, handle)
    return str(path)
