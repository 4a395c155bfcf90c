"""Slow, exact ray/triangle intersection in pure numpy: the test oracle for the Embree backend,
and a bake backend of its own (:class:`ReferenceBackend`, ``--backend reference``).

Every ray is tested against every triangle with the Moller-Trumbore algorithm, in float64,
in blocks of (rays x faces) pairs so that memory stays bounded whatever the scene size.
Nothing here is fast; it is written to be obviously right, so that the Embree backend
(float32, rebased coordinates, scale-aware offsets) can be compared against it.

Conventions shared by every function:

* Rays are ``origin + t * direction``. ``t`` is measured in multiples of ``|direction|``,
  which is the distance along the ray when directions are unit vectors (as the callers pass).
* A ray hits a triangle only for ``0 < t <= max_distance``. No offset (tnear) is added here:
  a ray whose origin lies exactly on a triangle does not hit it (t == 0), and the caller that
  wants a self-intersection offset moves the origin itself.
* Both sides of a triangle are hit (no back-face culling).
* A hit on an edge or vertex (barycentric coordinate exactly 0) counts, so a ray through a
  shared edge hits one of the two faces rather than slipping between them.
* Degenerate triangles (zero area, up to rounding) are never hit; parallel rays (ray in or
  parallel to the triangle's plane) never hit. Neither produces NaN or a floating-point warning.
* When several faces are hit at exactly the same nearest ``t``, the lowest face index is returned,
  independent of the block size.
"""

from __future__ import annotations

import logging

import numpy as np

from aobake.backends.base import TriangleBackend

log = logging.getLogger(__name__)

# Upper bound on (rays in a block) x (faces in a block). The largest temporaries are
# (rays, faces, 3) float64, so 2**20 pairs keeps each of them at 24 MiB.
BLOCK_PAIRS = 1 << 20

# A triangle is degenerate when |e1 x e2| <= DEGENERATE_SINE * |e1| * |e2|, i.e. when the
# sine of the angle between its edges is at rounding-noise level. A relative test, so it
# does not depend on the scene's scale; exactly collinear or repeated vertices land here
# even when rounding leaves a cross product of ~1e-17 instead of 0.
DEGENERATE_SINE = 1e-12


def first_hit(vertices, faces, origins, directions, max_distance, *, block_pairs=BLOCK_PAIRS):
    """Nearest intersection of each ray with the triangle mesh.

    Parameters
    ----------
    vertices : (v, 3) float
      Vertex positions.
    faces : (f, 3) int
      Vertex indices of each triangle.
    origins : (n, 3) float
      Ray origins.
    directions : (n, 3) float
      Ray directions (unit vectors, so that t is a distance).
    max_distance : float or (n,) float
      Largest accepted t per ray, >= 0; may be np.inf.
    block_pairs : int
      Upper bound on rays x faces handled at once (memory bound). Results do not depend on it.

    Returns
    -------
    t : (n,) float64
      Distance to the nearest hit with 0 < t <= max_distance; np.inf on a miss.
    face : (n,) int64
      Index of the face hit; -1 on a miss. Ties in t go to the lowest face index.
    """
    vertices, faces, origins, directions, max_distance = _validate(
        vertices, faces, origins, directions, max_distance
    )
    if block_pairs < 1:
        raise ValueError(f"block_pairs must be >= 1, got {block_pairs}")
    n_rays, n_faces = len(origins), len(faces)

    best_t = np.full(n_rays, np.inf)
    best_face = np.full(n_rays, -1, dtype=np.int64)
    if n_rays == 0 or n_faces == 0:
        return best_t, best_face

    v0, e1, e2, usable = _triangle_edges(vertices, faces)

    faces_per_block = min(n_faces, block_pairs)
    rays_per_block = max(1, block_pairs // faces_per_block)
    log.debug(
        "reference first_hit: %d rays x %d faces in blocks of %d x %d",
        n_rays, n_faces, rays_per_block, faces_per_block,
    )

    # Faces in the outer loop, in increasing index order: a later block replaces the
    # current best only when strictly nearer, so ties keep the lowest face index.
    for f0 in range(0, n_faces, faces_per_block):
        fs = slice(f0, f0 + faces_per_block)
        for r0 in range(0, n_rays, rays_per_block):
            rs = slice(r0, r0 + rays_per_block)
            t_block = _intersect_block(
                origins[rs], directions[rs], max_distance[rs],
                v0[fs], e1[fs], e2[fs], usable[fs],
            )
            nearest = np.argmin(t_block, axis=1)
            t_near = t_block[np.arange(len(t_block)), nearest]
            better = t_near < best_t[rs]
            best_t[rs] = np.where(better, t_near, best_t[rs])
            best_face[rs] = np.where(better, nearest + f0, best_face[rs])
    return best_t, best_face


def occluded(vertices, faces, origins, directions, max_distance, *, block_pairs=BLOCK_PAIRS):
    """Whether each ray hits any triangle with 0 < t <= max_distance.

    Parameters are those of `first_hit`.

    Returns
    -------
    is_occluded : (n,) bool
      True when the ray is blocked within max_distance (AO counts it as not visible).
    """
    _, face = first_hit(
        vertices, faces, origins, directions, max_distance, block_pairs=block_pairs
    )
    return face >= 0


def hit_distance(vertices, faces, origins, directions, max_distance, *, block_pairs=BLOCK_PAIRS):
    """Distance to the nearest hit of each ray.

    Parameters are those of `first_hit`.

    Returns
    -------
    t : (n,) float64
      Distance to the nearest hit with 0 < t <= max_distance; np.inf on a miss.
    """
    t, _ = first_hit(vertices, faces, origins, directions, max_distance, block_pairs=block_pairs)
    return t


def _validate(vertices, faces, origins, directions, max_distance):
    """Check shapes and values once, return float64 / int64 arrays with max_distance as (n,)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)

    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be (v, 3), got {vertices.shape}")
    if faces.size == 0:
        faces = np.zeros((0, 3), dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be (f, 3), got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integer indices, got dtype {faces.dtype}")
    faces = faces.astype(np.int64, copy=False)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(
            f"faces index vertices 0..{len(vertices) - 1}, got indices "
            f"{faces.min()}..{faces.max()}"
        )
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise ValueError(f"origins must be (n, 3), got {origins.shape}")
    if directions.shape != origins.shape:
        raise ValueError(
            f"directions must have the shape of origins {origins.shape}, got {directions.shape}"
        )

    # Non-finite coordinates would turn the arithmetic below into NaN and warnings.
    for name, array in (("vertices", vertices), ("origins", origins), ("directions", directions)):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} must be finite, got NaN or inf")

    max_distance = np.asarray(max_distance, dtype=np.float64)
    if max_distance.ndim == 0:
        max_distance = np.full(len(origins), float(max_distance))
    if max_distance.shape != (len(origins),):
        raise ValueError(
            f"max_distance must be a scalar or ({len(origins)},), got {max_distance.shape}"
        )
    # NaN fails this comparison too, so it is rejected with the negatives.
    if not np.all(max_distance >= 0):
        raise ValueError("max_distance must be >= 0 (np.inf allowed), got negative or NaN values")
    return vertices, faces, origins, directions, max_distance


def _triangle_edges(vertices, faces):
    """Per-face corner and edges, and which faces can be hit at all.

    Returns
    -------
    v0 : (f, 3) float64
      First corner.
    e1, e2 : (f, 3) float64
      Edges v1 - v0 and v2 - v0.
    usable : (f,) bool
      False for degenerate triangles.
    """
    corners = vertices[faces]
    v0 = corners[:, 0]
    e1 = corners[:, 1] - v0
    e2 = corners[:, 2] - v0
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    edge_product = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    # Strict '>' so that a zero-length edge (0 > 0) is degenerate too.
    usable = twice_area > DEGENERATE_SINE * edge_product
    return v0, e1, e2, usable


def _intersect_block(origins, directions, max_distance, v0, e1, e2, usable):
    """Moller-Trumbore for every (ray, face) pair of one block.

    Parameters
    ----------
    origins, directions : (r, 3) float64
    max_distance : (r,) float64
    v0, e1, e2 : (b, 3) float64
    usable : (b,) bool

    Returns
    -------
    t : (r, b) float64
      Hit distance of each pair, np.inf where that pair does not hit.
    """
    d = directions[:, None, :]
    s = origins[:, None, :] - v0[None, :, :]          # (r, b, 3)
    p = np.cross(d, e2[None, :, :])                   # (r, b, 3)
    q = np.cross(s, e1[None, :, :])                   # (r, b, 3)
    det = np.einsum("bk,rbk->rb", e1, p)              # (r, b)

    # Division-free tests: multiply the numerators by sign(det) and compare against |det|,
    # so u >= 0, v >= 0, u + v <= 1 and t > 0 are decided without dividing by a det that
    # may be 0 (parallel ray, degenerate face) or tiny. No NaN or inf can arise here.
    sign = np.sign(det)
    abs_det = np.abs(det)
    u_num = np.einsum("rbk,rbk->rb", s, p) * sign
    v_num = np.einsum("rk,rbk->rb", directions, q) * sign
    t_num = np.einsum("bk,rbk->rb", e2, q) * sign
    hit = (
        usable[None, :]
        & (det != 0.0)
        & (u_num >= 0.0)
        & (v_num >= 0.0)
        & (u_num + v_num <= abs_det)
        & (t_num > 0.0)
    )

    t = np.full(det.shape, np.inf)
    # A nearly parallel ray can have t beyond float range; over='ignore' lets that
    # overflow to inf, and the finiteness test below turns it into a miss.
    with np.errstate(over="ignore"):
        np.divide(t_num, abs_det, out=t, where=hit)
    hit &= (t <= max_distance[:, None]) & np.isfinite(t)
    t[~hit] = np.inf
    return t


class ReferenceBackend(TriangleBackend):
    """The float64 numpy intersector as a bake backend (``--backend reference``).

    Slow (every ray against every triangle), for validating the Embree backend on
    small scenes: the geometry stays float64 (in the tracer's local frame) and the float32
    rays are widened to float64, so the only float32 rounding left is the rays'.
    """

    name = "reference"

    def __init__(self, vertices, faces, face_normals, step, robust: bool = True):
        super().__init__(face_normals, step)  # exact in float64: robust or not, the same
        self._vertices = np.asarray(vertices, dtype=np.float64)
        self._faces = np.asarray(faces, dtype=np.int64)

    def _first_hit(self, origins, directions, tmax):
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(origins),))
        return first_hit(self._vertices, self._faces, origins.astype(np.float64),
                         directions.astype(np.float64), tmax)

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        return self._first_hit(origins, directions, tmax)[1] >= 0

    def distance(self, origins, directions, tmax) -> np.ndarray:
        return self._first_hit(origins, directions, tmax)[0].astype(np.float32)

    def intersect(self, origins, directions, tmax):
        t, face = self._first_hit(origins, directions, tmax)
        return t.astype(np.float32), face
