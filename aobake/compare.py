"""``aobake compare REFERENCE CANDIDATE``: how far a bake (ours or another tool's) is from a
reference, measured against the reference's own noise.

    from aobake.compare import compare
    metrics = compare("reference.npz", "candidate.ply", quantity="ao")
    metrics["rmse"], metrics["excess_rmse"]

Per vertex (``.npz``, ``.ply``, ``.glb``) the candidate's vertices are matched to the
reference's by position when their order differs; per texel (``.exr``, ``.png``, ``.tif``)
only the texels the reference covers are compared (and, when the candidate has its own
coverage, the texels both cover).  Every metric is over those n points of the error
``e = candidate - reference`` (float64 arithmetic on the stored float32 values):

- ``rmse = sqrt(mean e^2)``, ``bias = mean e``, ``max_error = max |e|``,
  ``mean_abs_error = mean |e|``, ``psnr = 10 log10(1 / mean e^2)`` (peak 1; None when the
  files agree exactly);
- ``reference_noise_rms = sqrt(mean se_ref^2)`` from the reference's ``*_stderr``;
- ``rmse_in_reference_se = rmse / reference_noise_rms``: about 1 for an exact candidate, about
  sqrt(2) for an independent bake as noisy as the reference;
- ``excess_rmse = sqrt(max(0, rmse^2 - reference_noise_rms^2))``: the part of the difference
  the reference's own noise does not explain (the candidate's noise is part of it;
  ``candidate_noise_rms`` says how much, when the candidate has a stderr).

Values the metrics cannot have (no stderr in the reference, an infinite PSNR) are None, so
the record is strict JSON.  The library logs and never prints; ``main`` is the command.
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import click
import numpy as np

from aobake.errors import AobakeError, InputError, OutputError
from aobake.outputs.atomic import atomic_path
from aobake.outputs.registry import suffixes
from aobake.outputs.report import metadata_json
from aobake.quantities import QUANTITIES

log = logging.getLogger(__name__)

#: quantities whose value is one number per point (the ones an error in [0, 1] describes)
COMPARABLE = tuple(name for name, q in QUANTITIES.items() if q.value.width == 1)
#: --candidate-convention -> what the candidate's numbers mean
CONVENTIONS = {
    "ao": "as aobake: 1 = fully open, 0 = fully occluded",
    "occlusion": "1 minus that: 1 = fully occluded (libigl's ambient_occlusion); compared as 1 - value",
}
VERTEX_SUFFIXES = suffixes("vertices")  # .npz .ply .glb
TEXEL_SUFFIXES = tuple(s for s in suffixes("texels") if s not in VERTEX_SUFFIXES)  # .exr .png .tif
#: Vertices match when every coordinate agrees within this fraction of the reference's size
#: (the larger of its largest |coordinate| and its extent): 2^-19 is 32 float32 half-ulps, so
#: float32 (GLB) and 9-digit text copies of float64 positions match, while distinct
#: vertices of any mesh that float32 can represent stay apart.
POSITION_TOLERANCE = 2.0 ** -19
#: config keys that change what a quantity means (besides the weighting, which is refused)
_SAME_QUANTITY = ("max_distance", "ground_plane", "backfaces", "normals")
#: tie features this close (normals, faces' centroids / size) cannot tell two vertices apart
_FEATURE_TIE = 1e-6
#: heatmap colours (sRGB bytes): e = -scale, 0, +scale
_BLUE, _WHITE, _RED = np.array([59, 76, 192]), np.array([255, 255, 255]), np.array([180, 4, 38])
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass
class Values:
    """One file's values of a quantity.

    target : 'vertices' | 'texels'
    value : (n,) float64 per vertex | (H, W) float64 per texel
    stderr : same shape, the file's standard error of ``value``, or None
    positions, normals : (n, 3) float64 or None (texels: None)
    faces : (f, 3) int64 or None
    mask : (H, W) bool texels the file covers, or None (no coverage: per vertex, or an image
      without a coverage channel)
    metadata : the aobake metadata the file carries ({} for another tool's file)
    key : the array / property / attribute / channel the value was read from
    warnings : what the reader could not honour (e.g. a GLB's node transforms)
    """

    path: Path
    target: str
    value: np.ndarray
    stderr: np.ndarray | None = None
    positions: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    mask: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    key: str = ""
    warnings: list = field(default_factory=list)


@dataclass
class _Table:
    """What a reader found: columns name -> (n,) | (n, k) | (H, W) arrays, and the rest."""

    columns: Mapping
    naming: str  # the Field attribute that names columns in this format: name | ply | gltf | exr
    positions: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


class _Unreadable(Exception):
    """A reader's reason a file is malformed (becomes ``InputError('FILE: cannot read ...')``)."""


# ---------------------------------------------------------------------------------------------
# the library entry point


def compare(reference_path, candidate_path, quantity: str = "ao", *, candidate_key: str | None = None,
            candidate_convention: str = "ao", heatmap=None) -> dict:
    """Compare ``candidate_path`` against ``reference_path`` for ``quantity`` ('ao' | 'obscurance').

    candidate_key : the candidate's array (NPZ), vertex property (PLY), attribute (GLB) or
      channel (image) holding the quantity, when it is not aobake's name for it
    candidate_convention : 'ao' (1 = open) | 'occlusion' (the candidate holds 1 - value)
    heatmap : path of a .ply (per vertex) or .png (per texel) to write the error to

    Returns one record, always with the same keys (see the module docstring for the metrics;
    None where a value does not exist).  Raises ``InputError`` naming the file and the
    problem (missing, unreadable, no such key, meshes or images that do not line up,
    different weightings) and ``OutputError`` when the heatmap cannot be written.
    """
    if quantity not in COMPARABLE:
        raise InputError(f"quantity must be one of {COMPARABLE}, got {quantity!r}")
    if candidate_convention not in CONVENTIONS:
        raise InputError(f"candidate_convention must be one of {tuple(CONVENTIONS)}, "
                         f"got {candidate_convention!r}")
    reference_path, candidate_path = Path(reference_path), Path(candidate_path)
    target = _target(reference_path)
    heatmap = None if heatmap is None else Path(heatmap)
    if heatmap is not None:
        _check_heatmap(heatmap, target, (reference_path, candidate_path))
    reference = read(reference_path, quantity)
    candidate = read(candidate_path, quantity, key=candidate_key, role="candidate")
    if candidate.target != reference.target:
        raise InputError(f"{candidate_path}: holds {_kind(candidate.target)}, but the reference "
                         f"{reference_path} holds {_kind(reference.target)}")
    warnings = reference.warnings + candidate.warnings
    warnings += _check_same_quantity(reference, candidate, quantity)
    if candidate_convention == "occlusion":
        if candidate.metadata:
            raise InputError(f"{candidate_path}: is an aobake output, which holds {quantity} "
                             "(1 = open); --candidate-convention occlusion is for tools that "
                             "write 1 minus it")
        candidate.value = 1.0 - candidate.value

    if not reference.value.size:
        raise InputError(f"{reference_path}: holds no {quantity} values")
    aligned = (_align_texels if target == "texels" else _align_vertices)(reference, candidate)
    ref, cand, ref_se, cand_se, where, extra = aligned
    for values, path in ((ref, reference_path), (cand, candidate_path)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        if bad:
            raise InputError(f"{path}: {bad} of the {len(values)} compared {quantity} values "
                             "are not finite")
    result = {"quantity": quantity, "target": target, "reference": str(reference_path),
              "candidate": str(candidate_path), "reference_key": reference.key,
              "candidate_key": candidate.key, "candidate_convention": candidate_convention}
    result.update(metrics(ref, cand, ref_se, cand_se))
    warnings += extra.pop("warnings")
    result.update(extra)
    result["heatmap"], result["heatmap_scale"] = None, None
    result["warnings"] = warnings
    if heatmap is not None:
        scale = result["max_error"] or 1.0
        error = cand - ref
        try:
            if target == "texels":
                _write_heatmap_png(heatmap, error, where, scale, quantity)
            else:
                _write_heatmap_ply(heatmap, reference, error, scale, quantity)
        except OutputError:
            raise
        except OSError as exc:  # a full disk, a lost mount: the file and the reason, one line
            raise OutputError(f"{heatmap}: {(exc.strerror or str(exc)).lower()}") from None
        result["heatmap"], result["heatmap_scale"] = str(heatmap), scale
        log.info("wrote %s (full colour at |error| = %.6g)", heatmap, scale)
    log.info("compared %s over %d %s: rmse %.6g, bias %+.6g", quantity, result["n"], target,
             result["rmse"], result["bias"])
    return result


def metrics(reference: np.ndarray, candidate: np.ndarray, reference_stderr: np.ndarray | None = None,
            candidate_stderr: np.ndarray | None = None) -> dict:
    """The error metrics of ``candidate - reference``.

    reference, candidate : (n,) float, n >= 1; *_stderr : (n,) float or None.
    Returns a dict of Python floats / None (n an int): n, rmse, bias, max_error,
    mean_abs_error, psnr (peak 1, None when the error is exactly 0), reference_noise_rms,
    rmse_in_reference_se, excess_rmse, candidate_noise_rms (None without the stderr).
    """
    error = np.asarray(candidate, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    n = error.size
    mse = float(np.mean(error * error))
    noise = _rms(reference_stderr)
    out = {
        "n": int(n),
        "rmse": math.sqrt(mse),
        "bias": float(np.mean(error)),
        "max_error": float(np.max(np.abs(error))),
        "mean_abs_error": float(np.mean(np.abs(error))),
        "psnr": 10.0 * math.log10(1.0 / mse) if mse > 0 else None,  # peak 1: AO spans [0, 1]
        "reference_noise_rms": noise,
        "rmse_in_reference_se": None,
        "excess_rmse": None,
        "candidate_noise_rms": _rms(candidate_stderr),
    }
    if noise is not None:
        # the reference's noise alone gives mean e^2 = noise^2 against an exact candidate
        out["excess_rmse"] = math.sqrt(max(0.0, mse - noise * noise))
        if noise > 0:
            out["rmse_in_reference_se"] = out["rmse"] / noise
    return out


def _rms(stderr) -> float | None:
    if stderr is None:
        return None
    stderr = np.asarray(stderr, dtype=np.float64)
    if not np.isfinite(stderr).all():
        return None
    return math.sqrt(float(np.mean(stderr * stderr)))


def _kind(target: str) -> str:
    return "per-vertex values" if target == "vertices" else "a lightmap (per texel)"


def _target(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in VERTEX_SUFFIXES:
        return "vertices"
    if suffix in TEXEL_SUFFIXES:
        return "texels"
    raise InputError(f"{path}: unsupported format {suffix or '(none)'!r}; compare reads "
                     f"{', '.join(VERTEX_SUFFIXES)} (per vertex) and {', '.join(TEXEL_SUFFIXES)} "
                     "(per texel)")


def _check_heatmap(path: Path, target: str, inputs) -> None:
    want = ".png" if target == "texels" else ".ply"
    if path.suffix.lower() != want:
        raise OutputError(f"{path}: a heatmap of {_kind(target)} is written as {want}")
    if not path.parent.resolve().is_dir():
        raise OutputError(f"{path}: directory {path.parent} does not exist")
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; --heatmap needs a file name")
    if any(path.resolve() == p.resolve() for p in inputs):
        raise OutputError(f"{path}: refusing to overwrite an input with the heatmap")


def _check_same_quantity(reference: Values, candidate: Values, quantity: str) -> list:
    """Refuse different weightings (different quantities); warn about other settings that
    change the number.  Only when both files carry aobake metadata."""
    ref, cand = (v.metadata.get("config") or {} for v in (reference, candidate))
    if not isinstance(ref, dict) or not isinstance(cand, dict) or not ref or not cand:
        return []
    rw, cw = ref.get("weighting"), cand.get("weighting")
    if rw is not None and cw is not None and rw != cw:
        raise InputError(f"{candidate.path}: holds {cw}-weighted {quantity}, the reference "
                         f"{reference.path} {rw}-weighted {quantity}: different quantities, which "
                         "no conversion relates (bake both with the same --weighting)")
    keys = _SAME_QUANTITY + (("tau",) if quantity == "obscurance" else ())
    warnings = []
    for key in keys:
        # resolved values (scene units) where the report has them: '10%' of the same mesh agrees
        a = _setting(reference.metadata, key)
        b = _setting(candidate.metadata, key)
        if a is not None and b is not None and not _same(a, b):
            text = (f"{key} differs ({reference.path}: {a}, {candidate.path}: {b}): the files "
                    f"may hold different {quantity}; compared anyway")
            log.warning("%s", text)
            warnings.append(text)
    return warnings


def _setting(metadata: dict, key: str):
    for part in ("parameters", "config"):
        section = metadata.get(part)
        if isinstance(section, dict) and key in section:
            return section[key]
    return None


def _same(a, b) -> bool:
    try:
        fa, fb = float(a), float(b)  # "inf" strings of the strict JSON metadata included
    except (TypeError, ValueError):
        return a == b
    return fa == fb or math.isclose(fa, fb, rel_tol=1e-9)


# ---------------------------------------------------------------------------------------------
# lining the two files up


def _align_texels(reference: Values, candidate: Values):
    """The covered texels of both: (ref (n,), cand (n,), ref_se, cand_se, mask (H, W), extra)."""
    if candidate.value.shape != reference.value.shape:
        h, w = candidate.value.shape
        rh, rw = reference.value.shape
        raise InputError(f"{candidate.path}: is {w}x{h} texels, the reference {reference.path} "
                         f"{rw}x{rh}")
    mask = np.ones(reference.value.shape, bool) if reference.mask is None else reference.mask.copy()
    excluded = 0
    if candidate.mask is not None:
        excluded = int(np.count_nonzero(mask & ~candidate.mask))
        mask &= candidate.mask
    if not mask.any():
        raise InputError(f"{candidate.path}: no texel is covered by both it and the reference "
                         f"{reference.path}")
    if reference.mask is None:
        log.info("%s has no coverage: every texel is compared", reference.path)

    def pick(a):
        return None if a is None else a[mask]

    extra = {"matched_by": "texel", "position_tolerance": None,
             "n_uncovered_in_candidate": excluded, "warnings": []}
    return (reference.value[mask], candidate.value[mask], pick(reference.stderr),
            pick(candidate.stderr), mask, extra)


def _align_vertices(reference: Values, candidate: Values):
    """The candidate's vertices in the reference's order: (ref, cand, ref_se, cand_se, None, extra)."""
    n, m = len(reference.value), len(candidate.value)
    tol, warnings = None, []
    if reference.positions is None or candidate.positions is None:
        if n != m:
            which = candidate if candidate.positions is None else reference
            raise InputError(f"{which.path}: has no vertex positions to match by, and "
                             f"{candidate.path} has {m} values where the reference "
                             f"{reference.path} has {n}")
        order, how = np.arange(n), "order"
        log.info("no positions in %s: vertices compared in file order",
                 candidate.path if candidate.positions is None else reference.path)
    elif n != m:
        raise InputError(f"{candidate.path}: has {m} vertices, the reference "
                         f"{reference.path} {n}: not the same mesh")
    else:
        tol = position_tolerance(reference.positions)
        if np.all(np.abs(reference.positions - candidate.positions) <= tol):
            order, how = np.arange(n), "order"
        else:
            order, how, warning = _match_files(reference, candidate, tol)
            warnings += [warning] if warning else []

    def pick(a):
        return None if a is None else a[order]

    extra = {"matched_by": how, "position_tolerance": tol, "n_uncovered_in_candidate": 0,
             "warnings": warnings}
    return (reference.value, candidate.value[order], reference.stderr, pick(candidate.stderr),
            None, extra)


def _match_files(reference: Values, candidate: Values, tol: float):
    """``match_vertices`` on two files, coincident vertices told apart by what both files
    have (normals, faces): (order, how, warning text or None)."""
    both = [name for name in ("normals", "faces")
            if getattr(reference, name) is not None and getattr(candidate, name) is not None]

    def features(v):
        return tie_features(v.positions, v.normals if "normals" in both else None,
                            v.faces if "faces" in both else None, tol / POSITION_TOLERANCE)

    try:
        order, how, ambiguous = match_vertices(reference.positions, candidate.positions, tol,
                                               (features(reference), features(candidate)))
    except ValueError as exc:
        raise InputError(f"{candidate.path}: {exc} of the reference {reference.path} "
                         "(not the same mesh?)") from None
    if not ambiguous:
        return order, how, None
    text = (f"{ambiguous} vertices coincide with others in position"
            f"{''.join(' and ' + name for name in both)}: paired in file order")
    if both:  # the same point twice: pairing them either way only swaps two estimates' noise
        log.info("%s: %s", candidate.path, text)
        return order, how, None
    text = f"{candidate.path}: {text}, which may pair the wrong ones (no normals or faces to tell)"
    log.warning("%s", text)
    return order, how, text


def position_tolerance(positions: np.ndarray) -> float:
    """The matching tolerance for ``positions`` (n, 3) float: ``POSITION_TOLERANCE`` times the
    larger of the largest |coordinate| (float32's spacing grows with it) and the extent."""
    positions = np.asarray(positions, dtype=np.float64)
    if not len(positions):
        return 0.0
    extent = float(np.max(positions.max(axis=0) - positions.min(axis=0)))
    return POSITION_TOLERANCE * max(float(np.max(np.abs(positions))), extent, np.finfo(float).tiny)


def match_vertices(reference: np.ndarray, candidate: np.ndarray, tol: float,
                   features: tuple | None = None) -> tuple[np.ndarray, str, int]:
    """Match two copies of the same vertices, in any order.

    reference, candidate : (n, 3) float positions; tol : a coordinate difference allowed;
    features : (reference (n, d), candidate (n, d)) float or None: what tells coincident
      vertices apart (``tie_features``: normals, the faces around them); among coincident
      vertices each reference vertex takes the candidate nearest in features (greedily),
      ties in file order.
    Returns (order (n,) int64, how, ambiguous): ``candidate[order[i]]`` is reference vertex i;
    how is 'order' (same order already) or 'position'; ambiguous counts the reference
    vertices that coincide with another in position and features (paired in file order).
    Raises ValueError describing the mismatch.
    """
    reference = np.asarray(reference, dtype=np.float64)
    candidate = np.asarray(candidate, dtype=np.float64)
    n = len(reference)
    if len(candidate) != n:
        raise ValueError(f"{len(candidate)} vertices against {n}")
    if np.all(np.abs(reference - candidate) <= tol):
        return np.arange(n), "order", 0
    # Coincident reference vertices form one cluster (named by its smallest index); each
    # candidate vertex belongs to the cluster of the reference vertices within tol of it.
    rq, rp = _neighbours(reference, reference, tol)
    ref_cluster = np.arange(n)
    np.minimum.at(ref_cluster, rq, rp)
    cq, cp = _neighbours(candidate, reference, tol)
    cand_cluster = np.full(n, n, dtype=np.int64)
    np.minimum.at(cand_cluster, cq, cp)
    lost = np.flatnonzero(cand_cluster == n)
    if len(lost):
        x, y, z = candidate[lost[0]]
        raise ValueError(f"{len(lost)} vertices (the first, {lost[0]}, at ({x:.9g}, {y:.9g}, "
                         f"{z:.9g})) are not within {tol:.3g} of any vertex")
    if not np.array_equal(np.sort(ref_cluster), np.sort(cand_cluster)):
        raise ValueError("the vertex positions do not pair up one to one with those")
    # clusters in the same sequence on both sides; within one, file order for now
    ref_order = np.lexsort((np.arange(n), ref_cluster))
    cand_order = np.lexsort((np.arange(n), cand_cluster))
    order = np.empty(n, dtype=np.int64)
    order[ref_order] = cand_order
    size = np.bincount(ref_cluster, minlength=n)[ref_cluster[ref_order]]  # per sorted slot
    ambiguous = 0
    fr, fc = (np.zeros((n, 0)), np.zeros((n, 0))) if features is None else \
        (np.asarray(f, dtype=np.float64) for f in features)
    for k in np.unique(size[size > 1]):
        slots = np.flatnonzero(size == k)
        r, c = ref_order[slots].reshape(-1, k), cand_order[slots].reshape(-1, k)
        # features apart: |difference| per pair (clusters, k reference, k candidate)
        apart = np.abs(fr[r][:, :, None, :] - fc[c][:, None, :, :]).max(axis=3, initial=0.0)
        self_apart = np.abs(fr[r][:, :, None, :] - fr[r][:, None, :, :]).max(axis=3, initial=0.0)
        self_apart[:, np.arange(k), np.arange(k)] = np.inf
        ambiguous += int(np.count_nonzero(self_apart.min(axis=2) <= _FEATURE_TIE))
        rows = np.arange(len(r))
        for _ in range(k):  # greedy: the closest remaining pair of each cluster first
            a, b = np.divmod(apart.reshape(len(r), -1).argmin(axis=1), k)
            order[r[rows, a]] = c[rows, b]
            apart[rows, a, :] = np.inf
            apart[rows, :, b] = np.inf
    if not np.all(np.abs(reference - candidate[order]) <= tol):
        raise ValueError("the vertex positions do not pair up one to one with those")
    return order, "position", ambiguous


def tie_features(positions: np.ndarray, normals: np.ndarray | None, faces: np.ndarray | None,
                 size: float) -> np.ndarray:
    """What tells coincident vertices apart: (n, d) float64 of the normal (3, when given)
    and, when faces are given, the mean centroid of the faces around the vertex divided by
    ``size`` and the unit sum of their area vectors (3 + 3: a seam's or a hard edge's copies
    differ in the first, a double-sided surface's in the second; zero on no face); d = 0
    with neither.  All are properties of the geometry, not of the vertex order, so two
    files of one mesh agree on them."""
    parts = []
    if normals is not None:
        parts.append(np.asarray(normals, dtype=np.float64))
    if faces is not None:
        corners = np.asarray(positions, dtype=np.float64)[faces]  # (f, 3 corners, 3)
        centroid = corners.mean(axis=1)
        area = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        n, at = len(positions), faces.reshape(-1)  # each face's values go to its 3 corners
        per_face = np.repeat(np.hstack([centroid, area]), 3, axis=0)
        total = np.column_stack([np.bincount(at, per_face[:, j], n) for j in range(6)])
        count = np.bincount(at, minlength=n).astype(np.float64)
        length = np.linalg.norm(total[:, 3:], axis=1, keepdims=True)
        parts += [total[:, :3] / np.maximum(count, 1.0)[:, None] / size,
                  total[:, 3:] / np.where(length > 0, length, 1.0)]
    return np.hstack(parts) if parts else np.zeros((len(positions), 0))


def _neighbours(query: np.ndarray, points: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) with every |query[i] - points[j]| coordinate <= tol: (q,) int64 and (q,)
    int64 arrays.  Sorted along a generic direction (not an axis, on which a grid's vertices
    line up), the candidates for each query are a short window."""
    direction = np.array([1.0, math.sqrt(2.0), math.sqrt(3.0)])
    direction /= direction.sum()  # a coordinate difference <= tol moves the projection <= tol
    proj_p = points @ direction
    proj_q = query @ direction
    order = np.argsort(proj_p, kind="stable")
    sorted_p = proj_p[order]
    lo = np.searchsorted(sorted_p, proj_q - tol, side="left")
    hi = np.searchsorted(sorted_p, proj_q + tol, side="right")
    width = hi - lo
    qi = np.repeat(np.arange(len(query)), width)
    start = np.repeat(np.cumsum(width) - width, width)
    pj = order[np.repeat(lo, width) + np.arange(int(width.sum())) - start]
    keep = np.all(np.abs(query[qi] - points[pj]) <= tol, axis=1)
    return qi[keep], pj[keep]


# ---------------------------------------------------------------------------------------------
# reading


def read(path, quantity: str = "ao", *, key: str | None = None, role: str = "reference") -> Values:
    """Read ``quantity`` (and its stderr, positions, coverage where the file has them) from an
    NPZ, PLY, GLB, EXR, PNG or TIFF file.

    key : the name of the array / property / attribute / channel holding it (default:
    aobake's name for it); role : 'reference' | 'candidate' (for the messages).
    Raises InputError('FILE: problem').
    """
    path = Path(path)
    target = _target(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a {path.suffix} file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: permission denied")
    suffix = path.suffix.lower()
    reader = {".npz": _read_npz, ".ply": _read_ply, ".glb": _read_glb}.get(suffix, _read_image)
    try:
        table = reader(path)
    except InputError:
        raise
    except (_Unreadable, ValueError, KeyError, IndexError, TypeError, EOFError, OSError,
            struct.error, UnicodeDecodeError) as exc:
        reason = f"no {exc}" if isinstance(exc, KeyError) else \
            " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{path}: cannot read as {suffix[1:].upper()}: {reason}") from None
    values = _pick(path, table, quantity, key, role, target)
    values.warnings = [f"{path}: {text}" for text in table.warnings]
    for text in values.warnings:
        log.warning("%s", text)
    log.debug("%s: %s from %r, %s", path, quantity, values.key, values.value.shape)
    return values


def _pick(path: Path, table: _Table, quantity: str, key, role: str, target: str) -> Values:
    """The quantity's column (``key``, else its aobake name) and, with aobake's names, its stderr."""
    q = QUANTITIES[quantity]
    standard = getattr(q.value, table.naming)
    standard = standard[0] if isinstance(standard, tuple) else standard
    columns = table.columns
    mask = None
    name = key if key is not None else standard
    if key is None and standard not in columns and target == "texels":
        name = _image_channel(path, table, quantity)
    if name not in columns:
        have = ", ".join(sorted(columns)) or "nothing"
        hint = "; name the candidate's with --candidate-key NAME" if role == "candidate" else ""
        what = {"name": "array", "ply": "vertex property", "gltf": "vertex attribute",
                "exr": "channel"}[table.naming]
        extra = ""
        if table.naming == "gltf" and "TEXCOORD_0" in columns:
            extra = " (a lightmap GLB's AO is a texture: compare its .exr or .png)"
        raise InputError(f"{path}: no {what} {name!r} (it has {have}){extra}{hint}")
    value = _scalar(path, name, columns[name], target)
    stderr = None
    if name == standard:  # aobake's own names: its stderr sits beside it
        error_name = getattr(q.error, table.naming)
        error_name = error_name[0] if isinstance(error_name, tuple) else error_name
        if error_name in columns:
            stderr = _scalar(path, error_name, columns[error_name], target)
    if target == "texels":
        mask = _coverage(table)
    else:
        n = len(value)
        for label, array in (("positions", table.positions), ("normals", table.normals)):
            if array is not None and array.shape != (n, 3):
                raise InputError(f"{path}: {label} are {array.shape}, expected ({n}, 3)")
        if table.faces is not None and len(table.faces) and \
                (table.faces.min() < 0 or table.faces.max() >= n):
            raise InputError(f"{path}: faces index vertices {table.faces.min()}.."
                             f"{table.faces.max()}, but there are {n}")
    return Values(path, target, value, stderr, table.positions, table.normals, table.faces, mask,
                  table.metadata, name)


def _image_channel(path: Path, table: _Table, quantity: str) -> str:
    """The channel of an image without one named after the quantity: an aobake PNG/TIFF's R
    (its metadata says which map it is), else the only channel, else R of a grey image."""
    columns, meta = table.columns, table.metadata
    if "map" in meta:
        if meta["map"] != quantity:
            raise InputError(f"{path}: holds {meta['map']}, not {quantity}")
        return "R"
    names = list(columns)
    if len(names) == 1:
        return names[0]
    if {"R", "G", "B"} <= set(names) and np.array_equal(columns["R"], columns["G"]) \
            and np.array_equal(columns["R"], columns["B"]):
        return "R"
    return QUANTITIES[quantity].value.exr[0]  # not there: _pick names what there is


def _coverage(table: _Table) -> np.ndarray | None:
    """(H, W) bool texels an aobake image covers: its coverage channel (> 0), else ray counts
    (> 0), else an aobake PNG/TIFF's alpha (the coverage, quantised); None for other files."""
    columns = table.columns
    if "coverage" in columns:
        return columns["coverage"] > 0
    if "rays" in columns:
        return columns["rays"] > 0
    if "map" in table.metadata and "A" in columns:
        return columns["A"] > 0
    return None


def _scalar(path: Path, name: str, array, target: str) -> np.ndarray:
    """(H, W) float64 from a channel, (n,) float64 from a per-vertex column: (n, 1) squeezed,
    an RGB(A) colour whose R, G, B agree gives R (aobake's grey COLOR_0), other vectors refused."""
    array = np.asarray(array)
    if array.dtype.kind not in "biuf":
        raise InputError(f"{path}: {name!r} holds {array.dtype} values, not numbers")
    if target == "vertices" and array.ndim == 2:
        grey = array.shape[1] in (3, 4) and np.array_equal(array[:, 0], array[:, 1]) \
            and np.array_equal(array[:, 0], array[:, 2])
        if array.shape[1] != 1 and not grey:
            raise InputError(f"{path}: {name!r} has {array.shape[1]} components per vertex; "
                             "compare needs one number per vertex")
        array = array[:, 0]
    if array.ndim != (2 if target == "texels" else 1):
        raise InputError(f"{path}: {name!r} is {array.shape}, not one number per "
                         f"{'texel' if target == 'texels' else 'vertex'}")
    return array.astype(np.float64)


def _read_npz(path: Path) -> _Table:
    """The archive's arrays, loaded when asked for (an archive may also hold every ray's
    distance, which compare never needs), positions, normals, faces and metadata."""
    with np.load(path, allow_pickle=False) as data:
        names = set(data.files) - {"metadata", "positions", "faces"}

        def get(name):
            return data[name] if name in data.files else None

        positions, normals, faces = get("positions"), get("normals"), get("faces")
        metadata = json.loads(str(data["metadata"][()])) if "metadata" in data.files else {}
    return _Table(_LazyArchive(path, names), "name", _float(positions), _float(normals),
                  _faces(faces), metadata if isinstance(metadata, dict) else {})


class _LazyArchive(Mapping):
    """name -> array of an NPZ archive, each read from the file when first looked up."""

    def __init__(self, path: Path, names):
        self.path, self.names, self.loaded = path, sorted(names), {}

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def __getitem__(self, name):
        if name not in self.names:
            raise KeyError(name)
        if name not in self.loaded:
            try:
                with np.load(self.path, allow_pickle=False) as data:
                    self.loaded[name] = data[name]
            except ValueError as exc:  # e.g. an object array, which is never unpickled
                raise InputError(f"{self.path}: cannot read array {name!r}: {exc}") from None
        return self.loaded[name]


def _float(array):
    return None if array is None else np.asarray(array, dtype=np.float64)


def _faces(array):
    if array is None:
        return None
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] != 3 or array.dtype.kind not in "iu":
        return None
    return array.astype(np.int64)


def _read_ply(path: Path) -> _Table:
    """PLY in any of its three formats: every scalar vertex property, triangle faces when the
    face element is a list of 3 (else None), the ``aobake-metadata`` comment."""
    from aobake.outputs.ply import METADATA_COMMENT

    data = path.read_bytes()
    if not data.startswith(b"ply"):
        raise _Unreadable("not a PLY file (no 'ply' line)")
    end = data.find(b"end_header")
    if end < 0:
        raise _Unreadable("no end_header")
    body = data.index(b"\n", end) + 1
    fmt, metadata, elements = None, {}, []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment" and words[1:2] == [METADATA_COMMENT]:
            metadata = json.loads(line.split(None, 2)[2])
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise _Unreadable("a property before any element")
            if words[1] == "list":
                elements[-1][2].append((words[4], _ply_type(words[2]), _ply_type(words[3])))
            else:
                elements[-1][2].append((words[2], _ply_type(words[1])))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _Unreadable(f"unknown format {fmt!r}")
    parsed = _ply_ascii(data[body:], elements) if fmt == "ascii" else \
        _ply_binary(data, body, elements, "<" if fmt == "binary_little_endian" else ">")
    if "vertex" not in parsed:
        raise _Unreadable("no vertex element")
    vertex = parsed["vertex"]
    columns = {name: vertex[name] for name in vertex.dtype.names}
    for name, array in columns.items():  # colour bytes mean [0, 1]
        if array.dtype.kind == "u" and array.dtype.itemsize <= 2:
            columns[name] = array / float(np.iinfo(array.dtype).max)
    positions = normals = None
    if {"x", "y", "z"} <= set(columns):
        positions = np.column_stack([columns.pop(a) for a in "xyz"]).astype(np.float64)
    if {"nx", "ny", "nz"} <= set(columns):
        normals = np.column_stack([columns[a] for a in ("nx", "ny", "nz")]).astype(np.float64)
    faces = parsed.get("face")
    return _Table(columns, "ply", positions, normals, faces,
                  metadata if isinstance(metadata, dict) else {})


def _ply_type(name: str) -> str:
    if name not in _PLY_TYPES:
        raise _Unreadable(f"unknown property type {name!r}")
    return _PLY_TYPES[name]


def _ply_binary(data: bytes, offset: int, elements, order: str) -> dict:
    """{'vertex': structured (n,), 'face': (f, 3) int64} as far as they can be read (a face
    list that is not all triangles ends the reading: later elements cannot be located)."""
    out = {}
    for name, count, props in elements:
        dtype = []
        for prop in props:
            if len(prop) == 2:
                dtype.append((prop[0], order + prop[1]))
            else:  # a list, read as if of 3, then checked
                dtype += [(prop[0] + "#count", order + prop[1]), (prop[0], order + prop[2], (3,))]
        dtype = np.dtype(dtype)
        if offset + dtype.itemsize * count > len(data):
            if name == "vertex" or "vertex" not in out:
                raise _Unreadable(f"truncated: element {name!r} runs past the end of the file")
            break
        array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        lists = [p[0] for p in props if len(p) == 3]
        if any((array[p + "#count"] != 3).any() for p in lists):
            break  # not all triangles: stop (the vertices were read first, or are not here)
        offset += array.nbytes
        if name == "vertex":
            out["vertex"] = array
        elif name == "face" and lists:
            out["face"] = array[lists[0]].astype(np.int64)
        if "vertex" in out and "face" in out:
            break
    return out


def _ply_ascii(body: bytes, elements) -> dict:
    """The ASCII layout, read as one stream of tokens (line breaks do not matter)."""
    tokens = body.decode("ascii").split()
    out, at = {}, 0
    for name, count, props in elements:
        lists = [i for i, p in enumerate(props) if len(p) == 3]
        width = len(props) + 3 * len(lists)  # every list assumed to hold 3 (checked)
        chunk = tokens[at:at + width * count]
        if len(chunk) < width * count:
            if name == "vertex" or "vertex" not in out:
                raise _Unreadable(f"truncated: element {name!r} runs past the end of the file")
            break
        table = np.array(chunk, dtype=np.float64).reshape(count, width)
        columns, col = {}, 0
        for prop in props:
            if len(prop) == 2:
                columns[prop[0]] = table[:, col].astype(prop[1])
                col += 1
            else:
                if (table[:, col] != 3).any():
                    return out  # not all triangles
                columns[prop[0]] = table[:, col + 1:col + 4].astype(np.int64)
                col += 4
        at += width * count
        if name == "vertex":
            vertex = np.empty(count, dtype=[(p[0], p[1]) for p in props if len(p) == 2])
            for key in vertex.dtype.names:
                vertex[key] = columns[key]
            out["vertex"] = vertex
        elif name == "face" and lists:
            out["face"] = columns[props[lists[0]][0]]
        if "vertex" in out and "face" in out:
            break
    return out


def _read_glb(path: Path) -> _Table:
    """Every vertex attribute of the file's triangle primitives (primitives sharing a POSITION
    accessor share their vertices, as in aobake's files), positions as stored (node
    transforms are not applied), ``asset.extras`` as metadata when aobake wrote it."""
    from aobake.outputs.glb import _CHUNK_BIN, _CHUNK_JSON, _MAGIC, _VERSION, GENERATOR

    data = path.read_bytes()
    if len(data) < 20:
        raise _Unreadable("too short to be a GLB file")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _MAGIC or version != _VERSION:
        raise _Unreadable("not a glTF 2.0 binary file")
    if length != len(data):
        raise _Unreadable(f"header says {length} bytes, the file has {len(data)}")
    chunks, offset = [], 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise _Unreadable(f"chunk at byte {offset} runs past the end of the file")
        chunks.append((kind, data[offset + 8:offset + 8 + size]))
        offset += 8 + size
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise _Unreadable("the first chunk is not JSON")
    gltf = json.loads(chunks[0][1].decode("utf-8"))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN else b""

    groups: dict = {}  # POSITION accessor -> (attributes, [index arrays])
    for mesh in gltf.get("meshes", []):
        for prim in mesh.get("primitives", []):
            attributes = prim.get("attributes", {})
            if prim.get("mode", 4) != 4 or "POSITION" not in attributes:
                continue
            group = groups.setdefault(attributes["POSITION"], (attributes, []))
            if "indices" in prim:
                group[1].append(_accessor(gltf, binary, prim["indices"]).astype(np.int64))
    if not groups:
        raise _Unreadable("no triangle mesh with POSITION")
    names = set.intersection(*(set(a) for a, _ in groups.values()))
    parts: dict = {name: [] for name in names}
    faces, base = [], 0
    for attributes, indices in groups.values():
        for name in names:
            parts[name].append(_accessor(gltf, binary, attributes[name]))
        count = len(parts["POSITION"][-1])
        flat = np.concatenate(indices) if indices else np.arange(count)
        faces.append(flat.reshape(-1, 3) + base)
        base += count
    columns = {name: np.concatenate(arrays) for name, arrays in parts.items()}
    asset = gltf.get("asset", {})
    metadata = asset.get("extras", {}) if asset.get("generator") == GENERATOR else {}
    warnings = []
    if any(k in node for node in gltf.get("nodes", []) for k in ("matrix", "translation",
                                                                  "rotation", "scale")):
        warnings.append("node transforms are not applied: positions are matched as stored")
    positions = columns.pop("POSITION").astype(np.float64)
    normals = columns.get("NORMAL")
    return _Table(columns, "gltf", positions, _float(normals), np.concatenate(faces),
                  metadata if isinstance(metadata, dict) else {}, warnings)


def _accessor(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """Accessor ``index`` as (count,) or (count, k); normalised integers scaled to [0, 1]."""
    from aobake.outputs.glb import _COMPONENT_DTYPES

    accessor = gltf["accessors"][index]
    if "sparse" in accessor:
        raise _Unreadable(f"accessor {index} is sparse (not supported)")
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}.get(accessor["type"])
    if width is None:
        raise _Unreadable(f"accessor {index} has type {accessor['type']} (not supported)")
    dtype = _COMPONENT_DTYPES[accessor["componentType"]]
    count = accessor["count"]
    if "bufferView" not in accessor:
        values = np.zeros((count, width), dtype=dtype)
    else:
        view = gltf["bufferViews"][accessor["bufferView"]]
        start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
        stride = view.get("byteStride", dtype.itemsize * width)
        if count and start + stride * (count - 1) + dtype.itemsize * width > len(binary):
            raise _Unreadable(f"accessor {index} runs past the end of the buffer")
        values = np.ndarray((count, width), dtype=dtype, buffer=binary, offset=start,
                            strides=(stride, dtype.itemsize)).copy()
    if accessor.get("normalized") and dtype.kind in "iu":
        values = np.maximum(values / float(np.iinfo(dtype).max), -1.0)
    return values[:, 0] if width == 1 else values


def _read_image(path: Path) -> _Table:
    """Every channel as (H, W) float (integer files scaled to [0, 1]), alpha unassociated
    (coverage is not opacity), the first subimage; aobake's metadata attribute."""
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise _Unreadable(oiio.geterror() or "OpenImageIO cannot open it")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise _Unreadable(inp.geterror() or "cannot read its pixels")
        attrs = {p.name: p.value for p in spec.extra_attribs}
        names = list(spec.channelnames)
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    columns = {name: pixels[:, :, i] for i, name in enumerate(names)}
    metadata = {}
    for attr in ("aobake:metadata", "ImageDescription"):  # TIFF keeps only the description
        try:
            candidate = json.loads(attrs.get(attr, ""))
        except (TypeError, ValueError):
            continue
        if isinstance(candidate, dict) and "config" in candidate:
            metadata = candidate
            break
    return _Table(columns, "exr", metadata=metadata)


# ---------------------------------------------------------------------------------------------
# heatmaps


def diverging(t: np.ndarray) -> np.ndarray:
    """(n,) float error / scale -> (n, 3) uint8 sRGB: blue at -1, white at 0, red at +1
    (clipped beyond)."""
    t = np.clip(np.asarray(t, dtype=np.float64), -1.0, 1.0)[:, None]
    end = np.where(t < 0, _BLUE, _RED)
    return np.rint(_WHITE + np.abs(t) * (end - _WHITE)).astype(np.uint8)


def _heatmap_metadata(quantity: str, scale: float) -> dict:
    return {"heatmap": {"quantity": quantity, "error": f"candidate - reference {quantity}",
                        "scale": scale, "colours": "white = equal; red = candidate higher "
                        "(more open), blue = candidate lower; full colour at |error| = scale"}}


def _write_heatmap_ply(path: Path, reference: Values, error: np.ndarray, scale: float,
                       quantity: str) -> None:
    """The reference's vertices (and faces) with ``error`` (n,) as a float property and as
    diverging red/green/blue, binary little-endian PLY, written atomically."""
    if reference.positions is None:
        raise OutputError(f"{path}: the reference {reference.path} has no vertex positions to "
                          "draw a heatmap on")
    n = len(error)
    colours = diverging(error / scale)
    vertex = np.empty(n, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("error", "<f4"),
                                ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = reference.positions[:, i]
    vertex["error"] = error
    for i, channel in enumerate(("red", "green", "blue")):
        vertex[channel] = colours[:, i]
    faces = reference.faces if reference.faces is not None else np.zeros((0, 3), np.int64)
    face = np.empty(len(faces), dtype=[("count", "u1"), ("vertex_indices", "<i4", (3,))])
    face["count"], face["vertex_indices"] = 3, faces
    from aobake.outputs.ply import METADATA_COMMENT

    header = ["ply", "format binary_little_endian 1.0",
              f"comment {METADATA_COMMENT} "
              f"{metadata_json(_heatmap_metadata(quantity, scale), compact=True)}",
              f"element vertex {n}", "property double x", "property double y",
              "property double z", "property float error", "property uchar red",
              "property uchar green", "property uchar blue", f"element face {len(faces)}",
              "property list uchar int vertex_indices", "end_header"]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(("\n".join(header) + "\n").encode("ascii"))
            handle.write(vertex.tobytes())
            handle.write(face.tobytes())


def _write_heatmap_png(path: Path, error: np.ndarray, mask: np.ndarray, scale: float,
                       quantity: str) -> None:
    """An 8-bit RGBA PNG: the compared texels (mask (H, W) bool) in diverging colours of
    ``error`` (n,) (in mask order), opaque; the others transparent black."""
    import OpenImageIO as oiio

    from aobake.outputs.image import _write

    pixels = np.zeros((*mask.shape, 4), dtype=np.uint8)
    pixels[mask, :3] = diverging(error / scale)
    pixels[mask, 3] = 255
    attrs = {"oiio:UnassociatedAlpha": 1, "Software": "aobake",
             "aobake:metadata": json.dumps(_heatmap_metadata(quantity, scale), allow_nan=False)}
    _write(path, pixels, oiio.UINT8, ("R", "G", "B", "A"), attrs)


# ---------------------------------------------------------------------------------------------
# the command


def format_table(result: dict) -> str:
    """The short human summary of a ``compare`` record."""
    def num(value, spec=".6f"):
        return "-" if value is None else format(value, spec)

    where = {"order": "vertices (same order)", "position": "vertices (matched by position)",
             "texel": "covered texels"}[result["matched_by"]]
    rows = [
        ("rmse", num(result["rmse"])),
        ("bias (candidate - reference)", num(result["bias"], "+.6f")),
        ("max |error|", num(result["max_error"])),
        ("mean |error|", num(result["mean_abs_error"])),
        ("psnr (peak 1)", "inf (identical)" if result["psnr"] is None else f"{result['psnr']:.2f} dB"),
        ("reference noise rms", num(result["reference_noise_rms"])),
        ("rmse / reference noise rms", num(result["rmse_in_reference_se"], ".3f")),
        ("excess rmse", num(result["excess_rmse"])),
    ]
    if result["candidate_noise_rms"] is not None:
        rows.append(("candidate noise rms", num(result["candidate_noise_rms"])))
    lines = [f"{result['quantity']}: {result['candidate']} against {result['reference']}, "
             f"{result['n']} {where}"]
    width = max(len(label) for label, _ in rows)
    lines += [f"  {label:<{width}}  {value}" for label, value in rows]
    if result["n_uncovered_in_candidate"]:
        lines.append(f"  ({result['n_uncovered_in_candidate']} texels the reference covers are "
                     "not covered by the candidate: left out)")
    if result["heatmap"]:
        lines.append(f"  heatmap: {result['heatmap']} (full colour at |error| = "
                     f"{result['heatmap_scale']:.4g})")
    return "\n".join(lines)


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("reference", type=click.Path(path_type=Path))
@click.argument("candidate", type=click.Path(path_type=Path))
@click.option("--quantity", "-q", type=click.Choice(COMPARABLE), default="ao", show_default=True,
              help="What to compare.")
@click.option("--candidate-key", metavar="NAME", default=None,
              help="The candidate's NPZ array / PLY property / GLB attribute / image channel "
                   "holding the quantity, when it is not aobake's name for it.")
@click.option("--candidate-convention", type=click.Choice(tuple(CONVENTIONS)), default="ao",
              show_default=True,
              help="occlusion: the candidate holds 1 - AO (libigl); compared as 1 - value.")
@click.option("--heatmap", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the error (candidate - reference) in a blue-white-red map: "
                   ".ply per vertex, .png per texel.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of the table.")
def main(reference, candidate, quantity, candidate_key, candidate_convention, heatmap, as_json):
    """Compare CANDIDATE against REFERENCE: RMSE, bias, max error, PSNR and how much of the
    difference the reference's own noise explains.

    Both are per-vertex files (.npz, .ply, .glb; vertices matched by position) or lightmaps
    (.exr, .png, .tif; the texels the reference covers).  The candidate may come from
    another tool (see --candidate-key, --candidate-convention).  Uniform- and
    cosine-weighted AO are different quantities and are not compared.
    """
    logging.basicConfig(level=logging.WARNING, format="aobake: warning: %(message)s",
                        stream=sys.stderr)
    try:
        result = compare(reference, candidate, quantity, candidate_key=candidate_key,
                         candidate_convention=candidate_convention, heatmap=heatmap)
    except (AobakeError, ValueError) as exc:
        click.echo(f"aobake: error: {exc}", err=True)
        sys.exit(1)
    if as_json:
        click.echo(json.dumps(result, allow_nan=False))
    else:
        click.echo(format_table(result))


if __name__ == "__main__":
    main()
