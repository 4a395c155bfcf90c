"""Shanmugam & Arikan's ambient occlusion from the depth buffer ("Hardware accelerated ambient
occlusion techniques on GPUs", I3D 2007): the high-frequency (near-field) pass, each
neighbour pixel a small sphere.

For a pixel p (position P, normal n), K neighbour pixels q are read at the points of a disc
kernel (``kernels.disc_kernel``, a Vogel spiral) of screen radius R_pix = R / (the pixel
size at p's depth), i.e. the screen footprint of the ball of radius R around P; each is
back-projected to its view-space position P_q and stands for a sphere:

    centre c = P_q - r_q n_q          (biased along -n_q: the sphere touches the surface
                                       at P_q from below, so a flat wall casts nothing)
    radius r_q = (d_q / d_p) R / sqrt(K)

The radius is the pixel's footprint radius of the paper (the radius of a disc of one
pixel's area at depth d_q, pixel_size(d_q) / sqrt(pi)) scaled by sqrt(M / K), M = pi R_pix^2
the pixels of the disc: each of the K samples stands for M / K pixels, so the sum over K
samples estimates the paper's sum over all M neighbours (a small sphere's term grows as
r^2; with K = M every pixel is its own sphere, the paper's form).  Per occluder

    A(p, q) = S_Omega(p, c, r) max(n . (c - P) / |c - P|, 0),
    S_Omega = 2 pi (1 - cos(asin(r / |c - P|)))     (the solid angle of the sphere; r >= |c - P|:
                                                     the whole sphere, 2 pi)

counted when |P_q - P| <= R (the range).  **Normalisation:** occlusion = sum_q A(p, q) / pi,
AO = 1 - min(1, occlusion).  Dividing by pi makes a term the cosine-weighted occlusion
(1/pi) int_cap cos dw of the sphere in the limit of a small sphere above the horizon: the
exact value for a cap of half-angle a centred at angle t from n is sin^2(a) cos(t), the
term is 2 (1 - cos a) cos(t), and their ratio is 2 / (1 + cos a) = 1 + tan^2(a / 2)
(``exact_cap`` and the tests).  A flat open wall gives exactly 1: every centre lies r
below the tangent plane (n . (c - P) = -r < 0).  Overlapping spheres are summed, not
occluded by each other: the method's known over-darkening in crowded corners.
"""

from __future__ import annotations

import math

import numpy as np

from aobake.screen import kernels
from aobake.screen.gbuffer import Frame

#: the value an open flat wall gets (docs/screen-space.md): exactly 1
FLAT_VALUE = 1.0
#: pixels per block (pixels x samples arrays)
BLOCK = 16384


def sphere_term(distance, radius, cosine):
    """S_Omega(p, c, r) max(cos, 0) / pi (arrays broadcast): the summed term of one sphere of
    ``radius`` at ``distance`` from p, its centre at angle acos(``cosine``) from n."""
    t = np.minimum(np.asarray(radius, np.float64) / np.asarray(distance, np.float64), 1.0)
    solid = 2.0 * math.pi * (1.0 - np.sqrt(1.0 - t * t))
    return solid * np.maximum(cosine, 0.0) / math.pi


def exact_cap(distance, radius, cosine):
    """The exact cosine-weighted occlusion (1/pi) int cos dw of a sphere wholly above the
    horizon (arrays broadcast; acos(cosine) + asin(radius / distance) <= pi/2): sin^2(a)
    cos(t), a = asin(r / distance), t = acos(cosine)."""
    t = np.asarray(radius, np.float64) / np.asarray(distance, np.float64)
    return t * t * np.asarray(cosine, np.float64)


def ao(frame: Frame, pixels: np.ndarray, radius: float, samples: int = 16,
       rotate: bool = True, period: int = 4) -> np.ndarray:
    """Shanmugam-Arikan AO at flat ``pixels`` (k,) int64 (covered) -> (k,) float64 in [0, 1]
    (1 = open, 0 = the summed occlusion reaches 1); ``radius`` in scene units, ``samples``
    neighbours per pixel, ``rotate``: the kernel turned by the pixel's cell of the
    ``period`` x ``period`` pattern (``kernels.angles``)."""
    pixels = np.asarray(pixels, dtype=np.int64)
    kernel = kernels.disc_kernel(samples)
    turns = kernels.angles(period) if rotate else None
    out = np.empty(len(pixels))
    for part in kernels.blocks(len(pixels), BLOCK):
        out[part] = _block(frame, pixels[part], radius, kernel, turns, period)
    return out


def sample_pixels(frame: Frame, pixels: np.ndarray, radius: float, kernel: np.ndarray,
                  turns: np.ndarray | None, period: int) -> np.ndarray:
    """(k, K) int64 flat indices of the neighbours each pixel reads (-1 off the image): the
    pixel containing centre + R_pix x (the kernel point, turned), x right, y down."""
    x, y = frame.centres(pixels)
    d = frame.depth.reshape(-1)[pixels]
    scale = radius / frame.pixel_size(d)  # R_pix: the ball's screen radius at p's depth
    if turns is None:
        ox = np.broadcast_to(kernel[:, 0], (len(pixels), len(kernel)))
        oy = np.broadcast_to(kernel[:, 1], (len(pixels), len(kernel)))
    else:
        angle = turns[kernels.pattern_index(pixels, frame.width, period)][:, None]
        c, s = np.cos(angle), np.sin(angle)
        ox = c * kernel[None, :, 0] - s * kernel[None, :, 1]
        oy = s * kernel[None, :, 0] + c * kernel[None, :, 1]
    return frame.lookup(x[:, None] + scale[:, None] * ox, y[:, None] + scale[:, None] * oy)


def _block(frame, pixels, radius, kernel, turns, period):
    p = frame.positions(pixels)
    n = frame.normals_at(pixels)
    d_p = -p[:, 2]
    q = sample_pixels(frame, pixels, radius, kernel, turns, period)
    valid = q >= 0
    q = np.where(valid, q, 0)
    valid &= frame.covered.reshape(-1)[q]
    d_q = frame.depth.reshape(-1)[q]
    x, y = frame.centres(q)
    p_q = frame.rays(x, y) * np.where(valid, d_q, 0.0)[..., None]
    n_q = frame.normals.reshape(-1, 3)[q]
    r_q = radius * np.where(valid, d_q, 0.0) / d_p[:, None] / math.sqrt(len(kernel))
    c = p_q - r_q[..., None] * n_q
    v = c - p[:, None, :]
    length = np.linalg.norm(v, axis=-1)
    within = valid & (np.linalg.norm(p_q - p[:, None, :], axis=-1) <= radius) & (length > 0)
    safe = np.where(within, length, 1.0)
    cosine = np.einsum("kj,ksj->ks", n, v) / safe
    term = np.where(within, sphere_term(safe, r_q, cosine), 0.0)
    return 1.0 - np.minimum(1.0, term.sum(axis=1))
