"""Points on a scene's triangles, where a ray found them: the exact surface point and its
barycentrics, and the interpolated shading normal.  Shared by the targets that place
points by casting rays (a view's primary rays, a high-to-low bake's cage rays).

Float64 throughout: the tracer's float32 hit distance only says which triangle; the
point is then put on it exactly.
"""

from __future__ import annotations

import numpy as np


def on_triangle(scene, prim: np.ndarray, points: np.ndarray):
    """The points (k, 3) float64 near triangles ``prim`` (k,) moved onto them: (surface points
    (k, 3) float64, barycentric coordinates (k, 3) float64), the closest point of each
    triangle's plane clamped into the triangle (float64 throughout)."""
    tri = scene.vertices[scene.faces[prim]]  # (k, 3, 3)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    q = points - tri[:, 0]
    d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    q1, q2 = np.einsum("ij,ij->i", q, e1), np.einsum("ij,ij->i", q, e2)
    det = d11 * d22 - d12 * d12
    safe = np.where(det > 0, det, 1.0)
    b1 = np.clip((d22 * q1 - d12 * q2) / safe, 0.0, 1.0)
    b2 = np.clip((d11 * q2 - d12 * q1) / safe, 0.0, 1.0 - b1)
    bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
    bary[det <= 0] = 1.0 / 3.0  # a degenerate triangle Embree hit: its centroid
    return np.einsum("kc,kcd->kd", bary, tri), bary


def shading_normals(scene, prim: np.ndarray, bary: np.ndarray, ng: np.ndarray) -> np.ndarray:
    """(k, 3) unit shading normals on triangles ``prim`` at barycentric ``bary`` (k, 3): the
    vertex normals interpolated, on the side of ``ng``; the geometric normal where the
    vertex normals cancel or are undefined."""
    n = np.einsum("kc,kcd->kd", bary, scene.vertex_normals[scene.faces[prim]])
    length = np.linalg.norm(n, axis=1)
    good = length > 1e-12
    out = ng.copy()
    out[good] = n[good] / length[good, None]
    flip = np.einsum("ij,ij->i", out, ng) < 0
    out[flip] = -out[flip]
    return out


#: the keys of a ``look`` dict: the two points are needed, up and fov have defaults
