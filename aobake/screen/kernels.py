"""Sample kernels of the screen-space methods, and the per-pixel rotation pattern.

Every kernel is a fixed, deterministic set of points (no random draws): a method's value
at a pixel is a pure function of the G-buffer.  The refinement of the course (Mittring
2007; Bavoil & Sainz 2008) rotates the kernel per pixel with a pattern that repeats every
N pixels in x and y (a pixel's rotation depends on (r mod N, c mod N) alone), so that the
kernel's structured error becomes high-frequency noise an N x N blur removes: every N x N
window holds each of the N^2 rotations exactly once.
"""

from __future__ import annotations

import math

import numpy as np

from aobake.rng import hash_uniform

#: hash stream of the pattern's 3D rotations (distinct from every other stream of aobake)
STREAM_ROTATION = 0x5EED_0023
#: the golden angle (radians): successive Vogel-spiral points turn by it
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
#: 1 / golden ratio: the additive recurrence that spreads the radii of the sphere kernel
INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


def sphere_kernel(samples: int) -> np.ndarray:
    """(samples, 3) float64 points in the unit ball, in antipodal pairs (s, -s).

    samples // 2 points: directions on a spherical Fibonacci lattice, radii
    ((j + 0.5) / m)^(1/3) (equal volume shells, j spread by the golden-ratio recurrence so
    radius and direction are not correlated), so a sample stands for an equal share of the
    ball's volume; then their mirror images; an odd count adds the centre.  The pairs are
    why a flat wall is exact: any plane through the centre has one of each pair on either
    side (docs/screen-space.md, "Crytek").
    """
    m = samples // 2
    i = np.arange(m, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / max(m, 1)
    phi = i * GOLDEN_ANGLE
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    directions = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    j = np.floor(np.mod(0.5 + i * INV_PHI, 1.0) * m)
    radius = np.cbrt((j + 0.5) / max(m, 1))
    half = directions * radius[:, None]
    out = np.concatenate([half, -half])
    if samples % 2:
        out = np.concatenate([out, np.zeros((1, 3))])
    return out


def disc_kernel(samples: int) -> np.ndarray:
    """(samples, 2) float64 points of the unit disc on a Vogel spiral: radius
    sqrt((i + 0.5) / K), angle i x the golden angle; each stands for an equal share (pi / K)
    of the disc's area."""
    i = np.arange(samples, dtype=np.float64)
    r = np.sqrt((i + 0.5) / samples)
    a = i * GOLDEN_ANGLE
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def pattern_index(pixels: np.ndarray, width: int, period: int) -> np.ndarray:
    """(k,) int64 in [0, N^2): the rotation of each flat pixel (r * W + c), a function of
    (r mod N, c mod N) alone.  The N^2 cells are numbered row-major and scattered by a
    step coprime to N^2 (near N^2 / golden ratio), so neighbouring pixels get rotations
    far apart."""
    r, c = np.divmod(np.asarray(pixels, dtype=np.int64), width)
    cells = period * period
    cell = (r % period) * period + (c % period)
    return (cell * scatter_step(cells)) % cells


def scatter_step(cells: int) -> int:
    """The step coprime to ``cells`` nearest cells x 0.618 (1 for one cell)."""
    if cells <= 2:
        return 1
    target = int(round(cells * INV_PHI))
    for delta in range(cells):
        for step in (target + delta, target - delta):
            if 0 < step < cells and math.gcd(step, cells) == 1:
                return step
    return 1  # pragma: no cover - 1 is always coprime


def angles(period: int) -> np.ndarray:
    """(N^2,) float64 rotation angles 2 pi (k + 1/2) / N^2 of the pattern's cells: evenly
    spread, so a window's N^2 rotations of a disc kernel tile the circle of angles."""
    cells = period * period
    return 2.0 * math.pi * (np.arange(cells) + 0.5) / cells


def fractions(period: int) -> np.ndarray:
    """(N^2,) float64 offsets (k + 1/2) / N^2 in (0, 1): GTAO's slice and step jitter."""
    cells = period * period
    return (np.arange(cells) + 0.5) / cells


def rotations(period: int, seed: int = 0) -> np.ndarray:
    """(N^2, 3, 3) float64 rotation matrices of the pattern's cells for a sphere kernel:
    uniformly distributed rotations (Shoemake's quaternion from three uniforms), a pure
    function of (seed, cell)."""
    cells = period * period
    k = np.arange(cells)
    u1, u2, u3 = (hash_uniform(seed, STREAM_ROTATION, k, dim) for dim in range(3))
    a, b = np.sqrt(1.0 - u1), np.sqrt(u1)
    x, y = a * np.sin(2 * math.pi * u2), a * np.cos(2 * math.pi * u2)
    z, w = b * np.sin(2 * math.pi * u3), b * np.cos(2 * math.pi * u3)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def blocks(n: int, per_block: int):
    """slices cutting 0..n-1 into consecutive blocks of ``per_block``: the methods work a
    block of pixels at a time so memory stays bounded (pixels x samples arrays)."""
    per_block = max(1, int(per_block))
    return [slice(start, min(n, start + per_block)) for start in range(0, n, per_block)]
