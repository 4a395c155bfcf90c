"""Small glTF scenes written by the tests and benchmarks that need materials (alpha-cutout):
embedded buffers and PNG images, one mesh and one material per part."""

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
