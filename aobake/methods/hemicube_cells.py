"""The hemicube's cells: where each face lies in a point's tile, each pixel's direction, its
exact weight and its angular radius (numpy only: the GL child imports it without the rest
of ``aobake``).

A point's hemicube is the front face (looking along the normal n) at R x R pixels and the
upper halves of the four side faces (looking along +t, -t, +b, -b, up = n) at R x R/2
pixels each, on planes at distance 1 from the eye: 3 R^2 pixels, packed into one tile of
3R x R pixels (window coordinates, x right, y up, pixel (col, row) centred at
(col + 0.5, row + 0.5))::

    rows R/2..R-1 |         | -t side | -b side |
    rows 0..R/2-1 |  front  | +t side | +b side |
                    cols 0..R-1   R..2R-1   2R..3R-1

A face pixel covers [x0, x1] x [y0, y1] of its face plane in face coordinates (x right, y
up, the face's axis at (0, 0)): x, y in [-1, 1] on the front face, x in [-1, 1] and y in
[0, 1] (height above the horizon) on a side face; every pixel is 2/R across.  Each face's
frame (right, up, forward) is right-handed (right x up = forward), and so is (t, b, n).

Weights are the exact integrals over the pixel (not the classic delta form factors
evaluated at the pixel centre, Cohen and Greenberg 1985, whose sum misses 1 by O(1/R^2)):

- cosine: the pixel's form factor from the eye, (1/pi) int cos(theta) dw.  Front face:
  dF = dA / (pi (1 + x^2 + y^2)^2), whose antiderivative is the differential-area-to-
  parallel-rectangle form factor G(x, y) = (1/2pi) [x/sqrt(1+x^2) atan(y/sqrt(1+x^2)) +
  y/sqrt(1+y^2) atan(x/sqrt(1+y^2))]; side face: dF = y dA / (pi (1 + x^2 + y^2)^2), whose
  antiderivative is H(x, y) = -(1/2pi) atan(x/sqrt(1+y^2)) / sqrt(1+y^2).  The front face
  sums to 0.5541, each half side to 0.1115, all five to 1.
- uniform: the pixel's solid angle / (2 pi), with the antiderivative atan(x y / sqrt(1 + x^2
  + y^2)) / (2 pi) on every face (a side pixel's solid angle does not depend on which axis
  is up).

Either way a rectangle's integral is the antiderivative's four-corner sum; the weights are
then divided by their sum (1 to rounding), so "all pixels open" is exactly 1.
"""

from __future__ import annotations

import math

import numpy as np

#: side faces in tile order: (forward, right) as signed (t, b, n) axes, up = n for all
#: four; right = n x forward keeps each face right-handed.
SIDES = (("+t", "+b"), ("-t", "-b"), ("+b", "-t"), ("-b", "+t"))
#: the weightings the cells can be weighted by (aobake.warp.WEIGHTINGS' names)
WEIGHTINGS = ("cosine", "uniform")


def _axis(name: str) -> np.ndarray:
    """'+t' -> (1, 0, 0), '-b' -> (0, -1, 0), ... in (t, b, n) coordinates."""
    vector = np.zeros(3)
    vector["tbn".index(name[1])] = 1.0 if name[0] == "+" else -1.0
    return vector


def face_frames() -> np.ndarray:
    """(5, 3, 3) float64: for the front face and the four side faces in tile order, the rows
    (right, up, forward) in (t, b, n) coordinates."""
    n = _axis("+n")
    frames = [np.stack([_axis("+t"), _axis("+b"), n])]
    for forward, right in SIDES:
        frames.append(np.stack([_axis(right), n, _axis(forward)]))
    out = np.stack(frames)
    assert np.allclose(np.cross(out[:, 0], out[:, 1]), out[:, 2])  # right-handed
    return out


def check_resolution(resolution) -> int:
    """The resolution as an int, ValueError unless an even integer >= 2 (a side face is
    R x R/2 pixels)."""
    if isinstance(resolution, bool) or int(resolution) != resolution or resolution < 2 \
            or resolution % 2:
        raise ValueError(f"hemicube_resolution must be an even integer >= 2, got {resolution}")
    return int(resolution)


def layout(resolution: int) -> dict:
    """The tile's cells, each (R, 3R) in window layout (row 0 at the bottom):

    face : int8 0 = front, 1..4 = the side faces in ``SIDES`` order,
    x0, x1, y0, y1 : float64 the pixel's extent on its face plane (face coordinates),
    direction : (R, 3R, 3) float64 the pixel centre's direction (x, y, 1) in the face frame
    rotated into (t, b, n) coordinates, not normalised.
    """
    r = check_resolution(resolution)
    half = r // 2
    col = np.arange(3 * r)[None, :].repeat(r, axis=0)
    row = np.arange(r)[:, None].repeat(3 * r, axis=1)
    block = col // r  # 0: front, 1: +t / -t, 2: +b / -b
    upper = row >= half
    face = np.where(block == 0, 0, 1 + 2 * (block - 1) + upper).astype(np.int8)
    step = 2.0 / r
    local_col = col - block * r
    local_row = np.where(block == 0, row, row - upper * half)
    x0 = -1.0 + local_col * step
    y0 = np.where(block == 0, -1.0, 0.0) + local_row * step
    x1, y1 = x0 + step, y0 + step
    frames = face_frames()[face]  # (R, 3R, 3, 3): rows right, up, forward
    xc, yc = (x0 + x1) / 2, (y0 + y1) / 2
    direction = (xc[..., None] * frames[..., 0, :] + yc[..., None] * frames[..., 1, :]
                 + frames[..., 2, :])
    return {"face": face, "x0": x0, "x1": x1, "y0": y0, "y1": y1, "direction": direction}


def _corner_sum(antiderivative, x0, x1, y0, y1) -> np.ndarray:
    return (antiderivative(x1, y1) - antiderivative(x0, y1) - antiderivative(x1, y0)
            + antiderivative(x0, y0))


def _front_form_factor(x, y):
    sx, sy = np.sqrt(1.0 + x * x), np.sqrt(1.0 + y * y)
    return (x / sx * np.arctan(y / sx) + y / sy * np.arctan(x / sy)) / (2.0 * math.pi)


def _side_form_factor(x, y):
    sy = np.sqrt(1.0 + y * y)
    return -np.arctan(x / sy) / sy / (2.0 * math.pi)


def _solid_angle(x, y):
    return np.arctan(x * y / np.sqrt(1.0 + x * x + y * y)) / (2.0 * math.pi)


def raw_weights(resolution: int, weighting: str) -> np.ndarray:
    """(R, 3R) float64 each pixel's exact weight, not normalised: its form factor (cosine;
    the five faces sum to 1) or its solid angle / (2 pi) (uniform; they sum to 1)."""
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    cells = layout(resolution)
    box = cells["x0"], cells["x1"], cells["y0"], cells["y1"]
    if weighting == "uniform":
        return _corner_sum(_solid_angle, *box)
    front = _corner_sum(_front_form_factor, *box)
    side = _corner_sum(_side_form_factor, *box)
    return np.where(cells["face"] == 0, front, side)


def weights(resolution: int, weighting: str) -> np.ndarray:
    """(R, 3R) float64 pixel weights summing to 1 (``raw_weights`` over their sum): the AO
    of a point is the sum of its open pixels' weights (1 = every pixel open)."""
    raw = raw_weights(resolution, weighting)
    return raw / raw.sum()


def angular_radius(resolution: int) -> np.ndarray:
    """(R, 3R) float64 radians: the largest angle between a pixel's centre direction and its
    corners' directions.  The spherical cap of that radius about the centre holds the whole
    pixel (a pixel's edges are great-circle arcs and a cap narrower than a hemisphere is
    convex), so a pixel whose cap does not meet an occluder's silhouette is wholly open or
    wholly blocked: its centre sample is exact there."""
    cells = layout(resolution)
    xc, yc = (cells["x0"] + cells["x1"]) / 2, (cells["y0"] + cells["y1"]) / 2
    centre = np.stack([xc, yc, np.ones_like(xc)], axis=-1)
    centre /= np.linalg.norm(centre, axis=-1, keepdims=True)
    largest = np.zeros(xc.shape)
    for x in (cells["x0"], cells["x1"]):
        for y in (cells["y0"], cells["y1"]):
            corner = np.stack([x, y, np.ones_like(x)], axis=-1)
            corner /= np.linalg.norm(corner, axis=-1, keepdims=True)
            cos = np.clip(np.einsum("...c,...c->...", centre, corner), -1.0, 1.0)
            # the angle through atan2 of |cross| and dot: accurate for small angles
            sin = np.linalg.norm(np.cross(centre, corner), axis=-1)
            largest = np.maximum(largest, np.arctan2(sin, cos))
    return largest
