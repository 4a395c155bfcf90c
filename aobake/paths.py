"""Paths beyond the first hit: the ray-traced truth of indirect light (``-q indirect``).

A uniform white sky (radiance 1) lights Lambertian surfaces of albedo rho
(``--albedo``).  One bounce: the light a point receives from the surfaces it sees,
normalised like AO, ``(1/pi) int (1 - V(w)) L(h(w)) cos dw`` with ``L(h) = rho A(h)``
(the radiance a surface at h reflects: rho times its own cosine AO, the sky it sees).
Estimated without bias by the point's own rays: where a ray hits at h, one further
cosine ray leaves h about its normal; the sample is rho when that ray escapes, else 0
(E[escape] = A(h)).  With ``--bounces N`` the path goes on from each hit: its sample is
rho^k when it escapes after k bounces (k = 1 .. N), 0 when it never does or when the first
ray escapes (the sky seen directly is AO, not indirect light).  Each sample lies in
[0, 1], one per ray, so the replicates' spread gives an error bar as honest as AO's.

Conventions (docs/conventions.md, "Indirect light"): the surfaces are two-sided (a ray
that hits the back of a face is reflected about the face's normal turned towards it);
the ground plane reflects too; every ray of a path obeys ``--max-distance`` (a hit
beyond it is a miss: the sky); the bounce rays are cosine-distributed whatever
``--weighting`` (Lambertian reflection), which weights only the first level.  Random
numbers: a pure function of (seed, point id, replicate, sample, bounce), a key stream of
its own (independent of the first rays' sampler).
"""

from __future__ import annotations

import numpy as np

from aobake.rng import mix
from aobake.samplers.base import uniforms
from aobake.offsets import point_offsets
from aobake.vectors import normalize
from aobake.warp import frames, warp

#: the key stream of the bounce directions (``samplers.base`` has the others)
STREAM_BOUNCE = 0x5EED_0006
#: added per bounce to a ray's hash (any odd constant keeps the bounces' numbers apart)
_BOUNCE_SALT = np.uint64(0xA0761D6478BD642F)


def path_values(occluders, scene, hashes: np.ndarray, origins: np.ndarray,
                directions: np.ndarray, tmax: float, albedo: float, bounces: int,
                ray_offset: float) -> np.ndarray:
    """(n,) float64 sample of each first-level ray: rho^k when its path escapes after k
    bounces (1 <= k <= bounces), else 0.

    occluders : ``aobake.occluders.Occluders``; scene : the Scene (face normals and areas);
    hashes : (n,) uint64 one per ray (a pure function of seed, point, replicate, sample);
    origins, directions : (n, 3) float32 local first-level rays; tmax : float32 local max
    distance; albedo : rho in [0, 1]; bounces : N >= 1; ray_offset : the offset fraction of
    a hit triangle's size (``aobake.trace.point_offsets``).
    """
    n = len(hashes)
    value = np.zeros(n)
    if albedo == 0 or n == 0:
        return value  # every path carries rho^k = 0: exact
    face_normals = scene.face_normals
    sizes = np.sqrt(2.0 * scene.areas()) * occluders.scale  # local units
    ground_size = float(np.median(sizes))
    up = np.zeros(3)
    if occluders.ground is not None:
        up["xyz".index(occluders.ground["axis"])] = 1.0
    alive = np.arange(n)
    o = np.asarray(origins, dtype=np.float32)
    d = np.asarray(directions, dtype=np.float32)
    weight = 1.0
    for bounce in range(1, bounces + 2):
        t, prim, ground = occluders.nearest(o, d, np.float32(tmax))
        hit = np.isfinite(t)
        if bounce > 1:  # escaped after bounce - 1 reflections: the sky, times rho^(b-1)
            value[alive[~hit]] = weight
        if bounce == bounces + 1:
            break
        alive, o, d, t, prim, ground = (a[hit] for a in (alive, o, d, t, prim, ground))
        if not len(alive):
            break
        weight = weight * albedo
        # The hit, in float64 local units, and its normal turned against the ray (two-sided).
        h = o.astype(np.float64) + t.astype(np.float64)[:, None] * d.astype(np.float64)
        normal = np.where(ground[:, None], up[None, :], face_normals[np.maximum(prim, 0)])
        flip = np.einsum("ij,ij->i", normal, d.astype(np.float64)) > 0
        normal[flip] = -normal[flip]
        normal = normalize(normal)[0]
        size = np.where(ground, ground_size, sizes[np.maximum(prim, 0)])
        lift = point_offsets(h, size, ray_offset)
        start = h + lift[:, None] * normal
        with np.errstate(over="ignore"):
            u = uniforms(mix(hashes[alive] + np.uint64(bounce) * _BOUNCE_SALT))
        local = warp(u, "cosine")
        tangent, bitangent = frames(normal)
        new = (local[:, 0:1] * tangent + local[:, 1:2] * bitangent) + local[:, 2:3] * normal
        o, d = start.astype(np.float32), new.astype(np.float32)
    return value
