"""Lining two files' values up: the texels both cover, or the candidate's vertices in the
reference's order (``matching``).  Each returns
(ref (n,), cand (n,), ref_se (n,) | None, cand_se (n,) | None, mask, extra): mask (H, W) bool
of the compared texels, or per vertex (N,) bool of the compared reference vertices (None:
all); extra the record's matched_by, position_tolerance, n_uncovered_in_candidate, warnings
and notes."""

from __future__ import annotations

import logging

import numpy as np

from aobake.compare.matching import (POSITION_TOLERANCE, match_vertices, position_tolerance,
                                     tie_features)
from aobake.errors import InputError
from aobake.outputs.values import Values

log = logging.getLogger(__name__)


def align_texels(reference: Values, candidate: Values):
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
             "n_uncovered_in_candidate": excluded, "warnings": [], "notes": []}
    return (reference.value[mask], candidate.value[mask], pick(reference.stderr),
            pick(candidate.stderr), mask, extra)


def align_vertices(reference: Values, candidate: Values):
    """The candidate's vertices in the reference's order: (ref, cand, ref_se, cand_se, mask,
    extra), mask None when every reference vertex is compared, else (n,) bool of those that
    are (a candidate without the vertices no face uses)."""
    n, m = len(reference.value), len(candidate.value)
    tol, warnings, notes = None, [], []
    if reference.positions is None or candidate.positions is None:
        if n != m:
            which = candidate if candidate.positions is None else reference
            raise InputError(f"{which.path}: has no vertex positions to match by, and "
                             f"{candidate.path} has {m} values where the reference "
                             f"{reference.path} has {n}")
        order, how = np.arange(n), "order"
        log.info("no positions in %s: vertices compared in file order",
                 candidate.path if candidate.positions is None else reference.path)
    elif m > n or (m < n and (reference.faces is None or not len(reference.faces))):
        why = "" if m > n else " (without faces, which would say the vertices it may lack)"
        raise InputError(f"{candidate.path}: has {m} vertices, the reference "
                         f"{reference.path} {n}{why}: not the same mesh")
    else:
        tol = position_tolerance(reference.positions)
        if n == m and np.all(np.abs(reference.positions - candidate.positions) <= tol):
            order, how = np.arange(n), "order"
        else:
            order, how, warning = _match_files(reference, candidate, tol)
            warnings += [warning] if warning else []
    compared = None
    left = int(np.count_nonzero(order < 0))
    if left:
        compared = order >= 0
        order = order[compared]
        text = (f"{candidate.path}: has no partner for {left} of the reference's {n} vertices, "
                f"none of them used by a face (as when a tool drops unreferenced vertices): "
                f"compared on the other {n - left}")
        log.info("%s", text)
        notes.append(text)

    def pick(a, index):
        return None if a is None else a if index is None else a[index]

    extra = {"matched_by": how, "position_tolerance": tol, "n_uncovered_in_candidate": left,
             "warnings": warnings, "notes": notes}
    return (pick(reference.value, compared), candidate.value[order],
            pick(reference.stderr, compared), pick(candidate.stderr, order), compared, extra)


def _match_files(reference: Values, candidate: Values, tol: float):
    """``match_vertices`` on two files, coincident vertices told apart by what both files
    have (normals, faces), reference vertices no face uses allowed to be missing:
    (order (n,) with -1 for those, how, warning text or None)."""
    both = [name for name in ("normals", "faces")
            if getattr(reference, name) is not None and getattr(candidate, name) is not None]

    def features(v):
        return tie_features(v.positions, v.normals if "normals" in both else None,
                            v.faces if "faces" in both else None, tol / POSITION_TOLERANCE)

    n, m = len(reference.positions), len(candidate.positions)
    used = None  # without faces every reference vertex needs a partner
    if reference.faces is not None and len(reference.faces):
        used = np.bincount(reference.faces.reshape(-1), minlength=n) > 0
    try:
        order, how, ambiguous = match_vertices(reference.positions, candidate.positions, tol,
                                               (features(reference), features(candidate)), used)
    except ValueError as exc:
        if m != n:
            raise InputError(f"{candidate.path}: has {m} vertices, the reference "
                             f"{reference.path} {n}, and {exc}: not the same mesh") from None
        raise InputError(f"{candidate.path}: {exc} (the reference {reference.path}: not the "
                         "same mesh?)") from None
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
