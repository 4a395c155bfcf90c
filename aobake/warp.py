"""Warp u in [0,1)^2 to hemisphere directions, and build frames around normals.

Each weighting maps (u0, u1) to a local direction (x, y, z) with z = cos(theta)
along the normal and phi = 2*pi*u1, and knows its pdf.  A weighting is the
measure AO averages visibility over, and directions are drawn from exactly that
measure, so every estimate is a plain mean over rays (AO = fraction of escaping
rays; contributions in [0, 1]):

* ``cosine`` (default): pdf = cos(theta) / pi;
  AO = (1/pi) int V cos dw, the definition of ambient occlusion aobake bakes.
* ``uniform``: pdf = 1 / (2 pi); AO = (1/2pi) int V dw, the fraction of the
  hemisphere's solid angle that is open: the convention of libigl's
  ``ambient_occlusion`` (which reports 1 minus it) and xNormal's default, so
  aobake can produce reference data for them.  It is a different quantity:
  under a disc of half-angle a it is cos(a), where cosine AO is cos^2(a).
"""

from __future__ import annotations

import math

import numpy as np


def cosine_sample(u0: np.ndarray):
    """Elevation part of the cosine warp: u0 -> (sin_theta, cos_theta).

    r = sqrt(u0) (disc radius = sin theta), z = sqrt(1 - u0); pdf = z / pi.
    """
    return np.sqrt(u0), np.sqrt(1.0 - u0)


def uniform_sample(u0: np.ndarray):
    """Elevation part of the uniform warp: z = 1 - u0 (in (0, 1]), r = sqrt(1 - z^2); pdf = 1/(2 pi)."""
    z = 1.0 - u0
    return np.sqrt(u0 * (2.0 - u0)), z


#: weighting name -> elevation warp u0 -> (sin theta, cos theta).  No estimator needs the pdf:
#: directions are drawn from the weighting's own measure, so each ray counts 1/n.
WEIGHTINGS = {
    "cosine": cosine_sample,
    "uniform": uniform_sample,
}


#: Taylor coefficients of sin(x) / x and cos(x) in x^2, for |x| <= pi/4: the truncation
#: error is below 2e-9 (sin, x^11 term) and 2e-10 (cos, x^12), far below the float32
#: directions (ulp 6e-8) they feed; fewer terms keep the kernel's per-ray cost small.
_SIN = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(5))
_COS = tuple((-1) ** k / math.factorial(2 * k) for k in range(6))
_HALF_PI = 1.5707963267948966
_SQRT_HALF = 0.7071067811865476


def cos_sin_2pi(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos 2 pi u, sin 2 pi u) for u in [0, 1), float64, from + and * only.

    Why not np.cos: numpy's float64 cos/sin may use SIMD code whose last bit differs
    from the C library's, and the compiled kernel must reproduce the numpy reference
    bit for bit.  A polynomial in + and * rounds the same everywhere (the kernel is
    built without fused multiply-add).  Quadrant q = floor(4u); within it
    x = (frac(4u) - 1/2) pi/2 in [-pi/4, pi/4) and the angle is x + pi/4 + q pi/2.
    """
    t = u * 4.0
    q = np.floor(t)
    x = ((t - q) - 0.5) * _HALF_PI
    x2 = x * x
    s = np.full_like(x, _SIN[-1])
    for coefficient in _SIN[-2::-1]:
        s = s * x2 + coefficient
    s = s * x
    c = np.full_like(x, _COS[-1])
    for coefficient in _COS[-2::-1]:
        c = c * x2 + coefficient
    sa, ca = (s + c) * _SQRT_HALF, (c - s) * _SQRT_HALF  # sin, cos of x + pi/4
    quadrant = q.astype(np.int64) & 3
    cos = np.where(quadrant == 0, ca, np.where(quadrant == 1, -sa, np.where(quadrant == 2, -ca, sa)))
    sin = np.where(quadrant == 0, sa, np.where(quadrant == 1, ca, np.where(quadrant == 2, -sa, -ca)))
    return cos, sin


def warp(u: np.ndarray, weighting: str = "cosine") -> np.ndarray:
    """(..., 2) u -> (..., 3) float64 local unit directions (z along the normal)."""
    r, z = WEIGHTINGS[weighting](u[..., 0])
    c, s = cos_sin_2pi(u[..., 1])
    return np.stack([r * c, r * s, z], axis=-1)


def frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent and bitangent (each (n, 3) float64) completing unit ``normals`` (n, 3) to a right-handed frame.

    Duff et al. 2017, "Building an orthonormal basis, revisited": branchless and
    continuous except on the -z half-axis seam, exact to rounding.
    """
    x, y, z = normals[:, 0], normals[:, 1], normals[:, 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=1)
    bitangent = np.stack([b, sign + y * y * a, -y], axis=1)
    return tangent, bitangent
