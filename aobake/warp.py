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


def warp(u: np.ndarray, weighting: str = "cosine") -> np.ndarray:
    """(n, 2) u -> (n, 3) float64 local unit directions (z along the normal).  For tests and docs."""
    sample = WEIGHTINGS[weighting]
    r, z = sample(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


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
