"""Analytic scenes and closed forms for the numerical tests.

Every scene is built here, in memory, from a few triangles, so the test suite
needs no external assets.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh
from scipy import special, stats


def quad(center, half_u, half_v, axis_u=0, axis_v=1, flip=False) -> trimesh.Trimesh:
    """Axis-aligned rectangle: center (3,), half extents along axis_u and axis_v."""
    center = np.asarray(center, dtype=float)
    eu, ev = np.eye(3)[axis_u] * half_u, np.eye(3)[axis_v] * half_v
    vertices = np.array([center - eu - ev, center + eu - ev, center + eu + ev, center - eu + ev])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if flip:
        faces = faces[:, ::-1]
    return trimesh.Trimesh(vertices, faces, process=False)


def polygon(center, radius, sides, axis=2) -> trimesh.Trimesh:
    """Regular polygon (a tessellated disc) in the plane normal to ``axis``, fan-triangulated."""
    angle = 2 * np.pi * np.arange(sides) / sides
    ring = np.zeros((sides, 3))
    others = [a for a in range(3) if a != axis]
    ring[:, others[0]] = radius * np.cos(angle)
    ring[:, others[1]] = radius * np.sin(angle)
    vertices = np.vstack([np.zeros(3), ring]) + np.asarray(center, dtype=float)
    faces = np.array([[0, 1 + i, 1 + (i + 1) % sides] for i in range(sides)])
    return trimesh.Trimesh(vertices, faces, process=False)


def combine(*meshes) -> trimesh.Trimesh:
    return trimesh.util.concatenate(meshes)


def floor_and_ceiling(h, half) -> trimesh.Trimesh:
    """Two facing squares of half extent ``half``: a floor at z = 0 and a ceiling at z = h."""
    return combine(quad([0, 0, 0], half, half), quad([0, 0, h], half, half))


def floor_points(n, spread, height=0.0, seed=1):
    """n seeded points uniform on [-spread, spread]^2 at z = height, with normals (0, 0, 1)."""
    rng = np.random.default_rng(seed)
    pts = np.zeros((n, 3))
    pts[:, :2] = rng.uniform(-spread, spread, size=(n, 2))
    pts[:, 2] = height
    return pts, up(n)


def up(n) -> np.ndarray:
    """(n, 3) normals (0, 0, 1)."""
    return np.tile([0.0, 0.0, 1.0], (n, 1))


def polygon_form_factor(point, normal, corners) -> float:
    """Lambert's point-to-polygon form factor (cosine-weighted solid angle / pi).

    corners : (k, 3) polygon vertices in order, wholly above the point's tangent
    plane.  F = 1/(2 pi) sum_i angle(r_i, r_i+1) * n . unit(r_i x r_i+1).
    """
    r = np.asarray(corners, float) - np.asarray(point, float)
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        cross = np.cross(a, b)
        angle = np.arctan2(np.linalg.norm(cross), np.dot(a, b))
        total += angle * np.dot(normal, cross / np.linalg.norm(cross))
    return abs(total) / (2 * np.pi)


def ceiling_obscurance(h, d, tau, weighting="cosine") -> float:
    """Obscurance of a floor point under an infinite ceiling at height h, max distance d > h.

    cosine:  W = 1 - 2 E3(tau h) + 2 (h/d)^2 E3(tau d)  (En: exponential integral of order n);
    uniform: W = 1 - E2(tau h) + (h/d) E2(tau d)  (cos(theta) is uniform on [0, 1], L = h / cos).
    """
    if weighting == "uniform":
        return 1 - special.expn(2, tau * h) + (h / d) * special.expn(2, tau * d)
    return 1 - 2 * special.expn(3, tau * h) + 2 * (h / d) ** 2 * special.expn(3, tau * d)


def solid_angle(p, corners) -> float:
    """Solid angle of a convex polygon (corners (n, 3)) seen from point p, by fanning it into
    triangles (Van Oosterom and Strackee 1983)."""
    total = 0.0
    a = np.asarray(corners[0], float) - p
    for i in range(1, len(corners) - 1):
        b, c = np.asarray(corners[i], float) - p, np.asarray(corners[i + 1], float) - p
        la, lb, lc = np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(c)
        num = abs(np.dot(a, np.cross(b, c)))
        den = la * lb * lc + np.dot(a, b) * lc + np.dot(a, c) * lb + np.dot(b, c) * la
        total += 2.0 * math.atan2(num, den)
    return total


def z_bound(n_tests: int, dof: float | None, alpha: float = 1e-4) -> float:
    """k such that P(any |estimate - exact| > k * stderr) <= alpha over n_tests points.

    The statistic is Student-t with ``dof`` degrees of freedom when the standard
    error comes from that many replicates (None: normal).  Bonferroni over points.
    """
    q = 1 - alpha / (2 * n_tests)
    return float(stats.norm.ppf(q) if dof is None else stats.t.ppf(q, dof))


def dof_for(sampler: str, rays: int) -> float | None:
    """Degrees of freedom of the stderr estimate (see aobake.samplers)."""
    from aobake.samplers import REPLICATES

    if sampler == "random":
        return None if rays > 100 else rays - 1
    return min(REPLICATES, rays) - 1


def polygon_form_factors(points, normals, corners) -> np.ndarray:
    """:func:`polygon_form_factor` of many points at once: points, normals (n, 3), corners (k, 3)
    (one polygon, wholly above every point's tangent plane) -> (n,) float64."""
    r = np.asarray(corners, float)[None, :, :] - np.asarray(points, float)[:, None, :]
    a, b = r, np.roll(r, -1, axis=1)
    cross = np.cross(a, b)
    norm = np.linalg.norm(cross, axis=2)
    angle = np.arctan2(norm, np.einsum("nkc,nkc->nk", a, b))
    total = np.einsum("nk,nkc,nc->n", angle / norm, cross, np.asarray(normals, float))
    return np.abs(total) / (2 * np.pi)


#: the box-filter scenes' ceiling height and eye height (``step_scene``)
STEP_CEILING, STEP_EYE = 0.5, 0.4


def step_scene(a=0.5, f=0.35, g=1.0, size=(8, 128), column=3):
    """A view whose every pixel's area mean is known in closed form (the box filter's
    oracle, tests/test_view_box*.py): (mesh, camera, truths, D, drop).

    Seen straight down from z = ``STEP_EYE``, a floor strip (z = 0) under an infinite
    ceiling at h = ``STEP_CEILING``, max distance D = h / sqrt(a): its cosine-weighted AO
    is exactly (h / D)^2 = ``a``.  The strip's edge crosses column ``column`` at a
    fraction f of its width; strips of AO exactly 1 at z = -drop (farther than D from
    everything) fill the bottom fraction g of every row.  truths: 'left' / 'mixed' /
    'right' (the columns before, at and after ``column``) -> (coverage, covered mean)."""
    from aobake import camera as cameras

    distance = STEP_CEILING / math.sqrt(a)
    drop = max(1.0, 1.5 * distance)  # the lower strips see nothing within D
    cam = cameras.look_at([0, 0, STEP_EYE], [0, 0, 0], [0, 1, 0], 20.0, size=size)

    def world(x, y, height):
        """Where the ray through pixel coordinates (x, y) meets z = STEP_EYE - height."""
        d = cam.directions_through(np.array([[x, y]], float))[0]
        return cam.eye + height / -d[2] * d

    edge = world(column + f, 0.5, STEP_EYE)[0]
    parts = [quad([0, 0, STEP_CEILING], 6, 6, flip=True),
             quad([(edge - 6) / 2, 0, 0], (edge + 6) / 2, 6)]
    if g >= 1:
        parts.append(quad([0, 0, -drop], 8, 8))
    else:
        for row in range(size[1]):  # the bottom fraction g of each row of pixels
            top = world(0.5, row + 1 - g, STEP_EYE + drop)[1]
            bottom = world(0.5, row + 1, STEP_EYE + drop)[1]
            parts.append(quad([0, (top + bottom) / 2, -drop], 8, (top - bottom) / 2))
    cover = f + (1 - f) * g
    truths = {"left": (1.0, a), "mixed": (cover, (a * f + (1 - f) * g) / cover),
              "right": (g, 1.0)}
    return combine(*parts), cam, truths, distance, drop
