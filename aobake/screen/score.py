"""A screen-space method's AO image scored against a per-pixel truth.

``score(reference, candidate, covered, edges=, stderr=)`` compares two (H, W) AO images on
the covered pixels, in three regions: ``all``, ``interior`` (covered pixels farther than
``band`` pixels from a depth edge) and ``edges`` (the band: where screen-space methods halo
and miss what is hidden), each raw and after the best gain:

- ``rmse`` sqrt(mean (c - r)^2); ``bias`` mean (c - r) (> 0: the candidate is too light);
- ``psnr`` 10 log10(1 / mse) (AO spans [0, 1]: the peak is 1; inf when equal);
- ``ssim``: Wang, Bovik, Sheikh & Simoncelli (IEEE TIP 2004) with their settings: an
  11 x 11 circular Gaussian window of sigma 1.5, K1 = 0.01, K2 = 0.03, dynamic range
  L = 1, population (weighted) statistics; the map is averaged over the region.  Pixels
  outside the coverage carry no value, so the local statistics are normalised convolutions
  (sums of w m x over sums of w m, m the coverage mask), computed where at least half of
  the window's weight is covered; elsewhere the map is undefined and not averaged;
- with the reference's standard error s (a ray-traced truth's ``ao_stderr``): ``z_rms``
  sqrt(mean ((c - r) / s)^2), about 1 when the candidate is as good as the truth's own
  noise allows, and ``z_over_3`` the share of pixels with |c - r| > 3 s;
- **the best gain** (a method's intensity knob must not pass as accuracy): engines scale
  the occlusion, 1 - AO, so the candidate becomes 1 - g (1 - c) with the least-squares g
  over all covered pixels, g = sum (1 - c)(1 - r) / sum (1 - c)^2 (reported), and every
  metric is given again for it (``gained``).

Depth edges (``depth_edges``): a covered pixel one of whose 4-neighbours is uncovered or
lies more than ``tolerance`` pixel sizes off its tangent plane (the blur's test), i.e. a
silhouette or an occlusion boundary; a crease is not a depth edge.
"""

from __future__ import annotations

import math

import numpy as np

#: Wang et al.'s SSIM settings
SSIM_SIGMA, SSIM_RADIUS, SSIM_K1, SSIM_K2, SSIM_RANGE = 1.5, 5, 0.01, 0.03, 1.0
#: the least share of a window's weight that must be covered for the SSIM map to be defined
SSIM_MIN_COVER = 0.5
#: default width of the band around depth edges (pixels)
BAND = 3
#: default depth-edge tolerance (pixel sizes off the tangent plane)
EDGE_TOLERANCE = 2.0
REGIONS = ("all", "interior", "edges")


def gaussian_window(sigma: float = SSIM_SIGMA, radius: int = SSIM_RADIUS) -> np.ndarray:
    """(2 radius + 1,) float64 normalised Gaussian weights."""
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _correlate(image: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Separable correlation of (H, W) ``image`` with ``weights`` along both axes, zeros
    outside the image."""
    radius = len(weights) // 2
    out = image
    for axis in (0, 1):
        padded = np.pad(out, [(radius, radius) if a == axis else (0, 0) for a in (0, 1)])
        size = out.shape[axis]
        acc = np.zeros_like(out)
        for i, w in enumerate(weights):
            acc += w * (padded[i:i + size] if axis == 0 else padded[:, i:i + size])
        out = acc
    return out


def ssim_map(x: np.ndarray, y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W) float64 SSIM of images x, y (H, W) over ``mask`` (bool): NaN where less than
    SSIM_MIN_COVER of the window's weight is masked in (module docstring)."""
    w = gaussian_window()
    m = mask.astype(np.float64)
    x = np.where(mask, x, 0.0).astype(np.float64)
    y = np.where(mask, y, 0.0).astype(np.float64)
    g = _correlate(m, w)
    ok = mask & (g >= SSIM_MIN_COVER)
    safe = np.where(ok, g, 1.0)

    def mean(a):
        return _correlate(a, w) / safe

    mx, my = mean(x), mean(y)
    vx = np.maximum(mean(x * x) - mx * mx, 0.0)
    vy = np.maximum(mean(y * y) - my * my, 0.0)
    cxy = mean(x * y) - mx * my
    c1, c2 = (SSIM_K1 * SSIM_RANGE) ** 2, (SSIM_K2 * SSIM_RANGE) ** 2
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return np.where(ok, s, np.nan)


def depth_edges(frame, tolerance: float = EDGE_TOLERANCE) -> np.ndarray:
    """(H, W) bool: covered pixels at a depth edge of ``frame`` (``aobake.screen.Frame``):
    a 4-neighbour uncovered, off the image edge excluded, or more than ``tolerance`` pixel
    sizes off the pixel's tangent plane (or the pixel off the neighbour's)."""
    h, w = frame.height, frame.width
    covered = frame.covered
    # positions of the covered pixels only: an empty pixel's depth is inf, and inf times the
    # zero ray component of a centre row or column (odd sizes) is NaN with a RuntimeWarning
    pos = np.zeros((h * w, 3))
    seen = np.flatnonzero(covered)
    pos[seen] = frame.positions(seen)
    pos = pos.reshape(h, w, 3)
    n = frame.normals
    size = np.where(covered, frame.pixel_size(np.where(covered, frame.depth, 0.0)), 0.0)
    edge = np.zeros((h, w), dtype=bool)
    for dy, dx in ((0, 1), (1, 0)):
        a = (slice(0, h - dy), slice(0, w - dx))
        b = (slice(dy, h), slice(dx, w))
        both = covered[a] & covered[b]
        delta = pos[b] - pos[a]
        off_a = np.abs(np.einsum("ijk,ijk->ij", n[a], delta)) > tolerance * size[a]
        off_b = np.abs(np.einsum("ijk,ijk->ij", n[b], delta)) > tolerance * size[b]
        jump = (covered[a] != covered[b]) | (both & (off_a | off_b))
        edge[a] |= jump & covered[a]
        edge[b] |= jump & covered[b]
    return edge


def dilate(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` grown by ``steps`` pixels (8-neighbourhood: a (2 steps + 1)^2 square)."""
    out = mask.copy()
    for _ in range(int(steps)):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        out = grown.copy()
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def regions(covered: np.ndarray, edges: np.ndarray | None, band: int = BAND) -> dict:
    """name -> (H, W) bool: ``all`` covered, ``edges`` within ``band`` pixels of a depth edge,
    ``interior`` the rest (without edges: all interior, no band)."""
    if edges is None:
        near = np.zeros_like(covered)
    else:
        near = dilate(edges, band) & covered
    return {"all": covered, "interior": covered & ~near, "edges": near}


def best_gain(reference: np.ndarray, candidate: np.ndarray, mask: np.ndarray) -> float:
    """The least-squares gain g of the candidate's occlusion over ``mask``: minimises
    sum (1 - g (1 - c) - r)^2; 1 where the candidate has no occlusion."""
    oc = 1.0 - candidate[mask].astype(np.float64)
    orf = 1.0 - reference[mask].astype(np.float64)
    denominator = float(np.dot(oc, oc))
    return float(np.dot(oc, orf) / denominator) if denominator > 0 else 1.0


def metrics(reference, candidate, mask, ssim=None, stderr=None) -> dict:
    """The metrics of one region (module docstring); ``ssim`` the SSIM map (H, W) or None."""
    count = int(mask.sum())
    out = {"pixels": count}
    if count == 0:
        return {**out, "rmse": None, "bias": None, "psnr": None, "ssim": None, "z_rms": None,
                "z_over_3": None}
    diff = candidate[mask].astype(np.float64) - reference[mask].astype(np.float64)
    mse = float(np.mean(diff * diff))
    out.update(rmse=math.sqrt(mse), bias=float(diff.mean()),
               psnr=math.inf if mse == 0 else 10.0 * math.log10(SSIM_RANGE ** 2 / mse))
    if ssim is not None:
        values = ssim[mask]
        values = values[np.isfinite(values)]
        out["ssim"] = float(values.mean()) if len(values) else None
    else:
        out["ssim"] = None
    if stderr is not None:
        se = stderr[mask].astype(np.float64)
        good = se > 0
        z = diff[good] / se[good]
        out["z_rms"] = float(np.sqrt(np.mean(z * z))) if len(z) else None
        out["z_over_3"] = float(np.mean(np.abs(z) > 3)) if len(z) else None
    else:
        out["z_rms"] = out["z_over_3"] = None
    return out


def score(reference: np.ndarray, candidate: np.ndarray, covered: np.ndarray,
          edges: np.ndarray | None = None, stderr: np.ndarray | None = None,
          band: int = BAND) -> dict:
    """Scores of ``candidate`` against ``reference`` (each (H, W), AO in [0, 1]) on
    ``covered`` (H, W) bool, by region: {"gain": g, "regions": {name: {"raw": metrics,
    "gained": metrics}}} (module docstring); ``edges`` (H, W) bool depth edges
    (``depth_edges``) or None (no band), ``stderr`` (H, W) the reference's standard error
    or None."""
    reference = np.asarray(reference, dtype=np.float64)
    candidate = np.asarray(candidate, dtype=np.float64)
    covered = np.asarray(covered, dtype=bool)
    if reference.shape != candidate.shape or reference.shape != covered.shape:
        raise ValueError(f"reference {reference.shape}, candidate {candidate.shape} and "
                         f"coverage {covered.shape} must have one shape")
    gain = best_gain(reference, candidate, covered)
    gained = 1.0 - gain * (1.0 - candidate)
    maps = {"raw": ssim_map(reference, candidate, covered),
            "gained": ssim_map(reference, gained, covered)}
    out = {"gain": gain, "regions": {}}
    for name, mask in regions(covered, edges, band).items():
        out["regions"][name] = {
            "raw": metrics(reference, candidate, mask, maps["raw"], stderr),
            "gained": metrics(reference, gained, mask, maps["gained"], stderr)}
    return out
