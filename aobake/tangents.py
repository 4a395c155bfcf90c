"""Per-vertex tangent frames, as MikkTSpace builds them in the common case.

UVs follow the OBJ convention (v = 0 at the bottom of the image; see
``aobake.targets.texels``).  A tangent frame is (T, B, N) with T the surface
direction of increasing u, N the unit normal, and the bitangent
``B = w * cross(N, T)`` pointing along increasing v; ``w = +-1`` is stored as
the tangent's 4th component, as in glTF and MikkTSpace.  Tangent-space vectors
are (x along T, y along B, z along N).

What is kept from MikkTSpace: per-face tangent and bitangent from the UV
derivatives, projected into each corner's normal plane and accumulated per
vertex weighted by the corner angle, then Gram-Schmidt against the normal.
What is not: MikkTSpace splits a vertex whose corners disagree in handedness or
lie on different smoothing groups; here each vertex keeps one frame (the mesh
is expected to be split at UV seams already, as an unwrapped mesh is).
"""

from __future__ import annotations

import numpy as np

from aobake.vectors import normalize


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalise rows of v; return (unit (n, 3), ok (n,) bool where length > 0)."""
    unit, length = normalize(v)
    return unit, length[..., 0] > 0


def _reject(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """v minus its component along unit n (rows)."""
    return v - n * np.sum(v * n, axis=-1, keepdims=True)


def _any_perpendicular(n: np.ndarray) -> np.ndarray:
    """(m, 3) unit vectors perpendicular to unit rows of n (for frames without UV data)."""
    # Cross with the axis least aligned with n, so the result is never tiny.
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    return _unit(np.cross(n, axis))[0]


def vertex_tangents(positions, normals, uv, faces) -> np.ndarray:
    """Per-vertex tangents for normal-map style tangent space.

    positions : (n, 3) float; normals : (n, 3) float (normalised here);
    uv : (n, 2) float, OBJ convention; faces : (f, 3) int.

    Returns (n, 4) float64: unit tangent xyz (perpendicular to the normal) and
    handedness w = +1 or -1 (w = +1 when (u, v, normal) form a right-handed
    frame, the unmirrored case).  Vertices touched only by faces with zero UV
    area get an arbitrary unit tangent perpendicular to the normal and w = +1.
    """
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n_vertices = len(positions)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must be (n, 3), got {positions.shape}")
    if normals.shape != positions.shape:
        raise ValueError(f"normals must be {positions.shape}, got {normals.shape}")
    if uv.shape != (n_vertices, 2):
        raise ValueError(f"uv must be ({n_vertices}, 2), got {uv.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be (f, 3), got {faces.shape}")
    normals, _ = _unit(normals)

    p = positions[faces]  # (f, 3, 3)
    t = uv[faces]  # (f, 3, 2)
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    s1, s2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area = s1[:, 0] * s2[:, 1] - s2[:, 0] * s1[:, 1]  # twice the signed UV area
    # dP/du and dP/dv times the UV area; only the sign of the area is divided
    # out because the vectors are normalised per corner anyway (as MikkTSpace).
    sign = np.sign(area)[:, None]
    face_t = (d1 * s2[:, 1:2] - d2 * s1[:, 1:2]) * sign
    face_b = (d2 * s1[:, 0:1] - d1 * s2[:, 0:1]) * sign
    has_uv = area != 0

    tan_sum = np.zeros((n_vertices, 3))
    bit_sum = np.zeros((n_vertices, 3))
    for corner in range(3):
        v = faces[:, corner]
        n = normals[v]
        tc, ok_t = _unit(_reject(face_t, n))
        bc, _ = _unit(_reject(face_b, n))
        # Corner angle between the two edges leaving this corner, measured in
        # the normal's plane, as MikkTSpace weights them.
        e1, _ = _unit(_reject(p[:, (corner + 1) % 3] - p[:, corner], n))
        e2, _ = _unit(_reject(p[:, (corner + 2) % 3] - p[:, corner], n))
        angle = np.arccos(np.clip(np.sum(e1 * e2, axis=1), -1.0, 1.0))
        w = np.where(has_uv & ok_t, angle, 0.0)[:, None]
        np.add.at(tan_sum, v, w * tc)
        np.add.at(bit_sum, v, w * bc)

    tangent, ok = _unit(_reject(tan_sum, normals))
    if not ok.all():
        tangent[~ok] = _any_perpendicular(normals[~ok])
    handed = np.where(np.sum(np.cross(normals, tangent) * bit_sum, axis=1) < 0, -1.0, 1.0)
    return np.concatenate([tangent, handed[:, None]], axis=1)


def _frame(normals, tangents) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    normals = np.asarray(normals, dtype=np.float64)
    tangents = np.asarray(tangents, dtype=np.float64)
    if normals.ndim != 2 or normals.shape[1] != 3:
        raise ValueError(f"normals must be (s, 3), got {normals.shape}")
    if tangents.shape != (len(normals), 4):
        raise ValueError(f"tangents must be ({len(normals)}, 4), got {tangents.shape}")
    n, _ = _unit(normals)
    # Interpolated tangents are neither unit nor perpendicular: Gram-Schmidt.
    t, ok = _unit(_reject(tangents[:, :3], n))
    if not ok.all():
        t[~ok] = _any_perpendicular(n[~ok])
    w = np.where(tangents[:, 3] < 0, -1.0, 1.0)[:, None]
    b = w * np.cross(n, t)
    return t, b, n


def to_tangent_space(vectors, normals, tangents) -> np.ndarray:
    """Express world-space vectors in each sample's tangent frame.

    vectors : (s, 3) float; normals : (s, 3) float; tangents : (s, 4) float
    (xyz, w).  Returns (s, 3) float64 components along (T, B, N); the frame is
    orthonormal, so lengths and angles are preserved and the normal itself maps
    to (0, 0, 1).
    """
    vectors = np.asarray(vectors, dtype=np.float64)
    t, b, n = _frame(normals, tangents)
    if vectors.shape != n.shape:
        raise ValueError(f"vectors must be {n.shape}, got {vectors.shape}")
    return np.stack([np.sum(vectors * t, 1), np.sum(vectors * b, 1), np.sum(vectors * n, 1)], axis=1)


def from_tangent_space(vectors, normals, tangents) -> np.ndarray:
    """Inverse of ``to_tangent_space``: (s, 3) tangent-space -> world space."""
    vectors = np.asarray(vectors, dtype=np.float64)
    t, b, n = _frame(normals, tangents)
    if vectors.shape != n.shape:
        raise ValueError(f"vectors must be {n.shape}, got {vectors.shape}")
    return vectors[:, 0:1] * t + vectors[:, 1:2] * b + vectors[:, 2:3] * n
