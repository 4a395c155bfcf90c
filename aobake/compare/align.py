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
    are (a candidate without the vertices no face uses, or a bake of some of a set's
    instances or objects: :func:`align_subset`)."""
    aligned = align_subset(reference, candidate)
    if aligned is not None:
        return aligned
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


# ---------------------------------------------------------------------------------------------
# a bake of some instances (or objects) against the whole set's


def _source(values: Values) -> dict | None:
    """A ``--bake`` bake's ``parameters.instances.source`` (where its vertices stand in the
    whole set's bake), or None."""
    instances = ((values.metadata or {}).get("parameters") or {}).get("instances") or {}
    source = instances.get("source")
    return source if isinstance(source, dict) and "vertex_runs" in source else None


def _layout(values: Values) -> list:
    instances = ((values.metadata or {}).get("parameters") or {}).get("instances") or {}
    layout = instances.get("layout")
    return layout if isinstance(layout, list) else []


def _by_instance(part: Values, whole: Values) -> np.ndarray | None:
    """(m,) int64 each of ``part``'s vertices' index in ``whole`` by instance: the same node
    (name, mesh, and which of the node's placements of that mesh) and the same vertex index in
    it; None when either has no instance layout.  InputError naming an instance the whole
    set's bake lacks or holds with another vertex count."""
    mine, theirs = _layout(part), _layout(whole)
    if not mine or not theirs:
        return None

    def keyed(layout):
        seen, out = {}, {}
        for entry in layout:
            key = (str(entry.get("name")), str(entry.get("mesh")))
            seen[key] = seen.get(key, -1) + 1
            out[key + (seen[key],)] = entry
        return out

    available = keyed(theirs)
    index = np.empty(len(part.value), dtype=np.int64)
    covered = 0
    for key, entry in keyed(mine).items():
        (a, b), other = entry["vertices"], available.get(key)
        if other is None:
            raise InputError(f"{part.path}: instance {key[0]!r} (mesh {key[1]!r}) is not in "
                             f"{whole.path}'s instances: not the same set's bakes")
        c, d = other["vertices"]
        if d - c != b - a:
            raise InputError(f"{part.path}: instance {key[0]!r} has {b - a} vertices, in "
                             f"{whole.path} {d - c}: not the same mesh")
        index[a:b] = np.arange(c, d)
        covered += b - a
    if covered != len(index):
        raise InputError(f"{part.path}: its instance layout covers {covered} of its "
                         f"{len(index)} vertices")
    return index


def _places(values: Values, count: int) -> np.ndarray:
    """(len,) int64 each of ``values``' vertices' index in the whole set's bake of ``count``
    vertices: its ``source`` runs, or (a bake without them, which must be the whole set's)
    its own order.  InputError for a bake of another size."""
    from aobake.instances import expand_runs

    source = _source(values)
    if source is not None:
        if int(source.get("vertices", -1)) != count:
            raise InputError(f"{values.path}: is a bake of a set of {source.get('vertices')} "
                             f"vertices, the other file's of {count}: not the same set")
        places = expand_runs(source["vertex_runs"])
        if len(places) != len(values.value):
            raise InputError(f"{values.path}: its source runs cover {len(places)} vertices, "
                             f"it has {len(values.value)}")
        return places
    if len(values.value) != count:
        raise InputError(
            f"{values.path}: has {len(values.value)} vertices, where the other file is a bake "
            f"of some of a set of {count} (--bake): it is not that set's whole bake (bake the "
            "same file without --bake, or with --instances flatten)")
    return np.arange(count, dtype=np.int64)


def align_subset(reference: Values, candidate: Values):
    """A bake of some of a set's instances (``--bake``: glTF nodes, OBJ objects) against the
    whole set's bake (or a bake of more of it), either way round: each of the smaller bake's
    vertices is the larger one's vertex of the same instance (node and mesh) and vertex
    index where both files have their instance layouts, else the one at the same place in
    the whole set (``source_vertex``, the metadata's ``parameters.instances.source``);
    positions must agree.  Returns ``align_vertices``' tuple, or None when neither file is
    such a bake, or both are of the same vertices (compared as any two bakes are)."""
    n, m = len(reference.value), len(candidate.value)
    mine, theirs = _source(candidate), _source(reference)
    if mine is None and theirs is None:
        return None
    count = int((mine or theirs).get("vertices", -1))
    places_c, places_r = _places(candidate, count), _places(reference, count)
    if np.array_equal(places_c, places_r):
        return None
    inside_c = np.isin(places_c, places_r)
    if inside_c.all():
        part, whole, places_part, places_whole, part_is_candidate = \
            candidate, reference, places_c, places_r, True
    elif np.isin(places_r, places_c).all():
        part, whole, places_part, places_whole, part_is_candidate = \
            reference, candidate, places_r, places_c, False
    else:
        raise InputError(f"{candidate.path}: holds {int((~inside_c).sum())} vertices of the set "
                         f"that {reference.path} does not, and lacks some it has: neither bake "
                         "holds the other's vertices")
    how, index = "instance", _by_instance(part, whole)
    if index is None:
        how = "source"
        lookup = np.full(count, -1, dtype=np.int64)
        lookup[places_whole] = np.arange(len(places_whole))
        index = lookup[places_part]
    tol = None
    if part.positions is not None and whole.positions is not None:
        tol = position_tolerance(whole.positions)
        apart = np.abs(part.positions - whole.positions[index]).max(axis=1)
        bad = np.flatnonzero(apart > tol)
        if len(bad):
            i = int(bad[0])
            raise InputError(
                f"{part.path}: {len(bad)} of its {len(index)} vertices are not where "
                f"{whole.path} has them (vertex {i} at {part.positions[i].tolist()}, the other's "
                f"vertex {int(index[i])} at {whole.positions[index[i]].tolist()}; tolerance "
                f"{tol:.3g}): not the same set, or placed differently")
    by = "instance and vertex index" if how == "instance" else "their place in the whole set"
    note = (f"{part.path}: a bake of {len(index)} of the set's {count} vertices, matched to "
            f"{whole.path}'s {len(whole.value)} by {by}")
    log.info("%s", note)
    extra = {"matched_by": how, "position_tolerance": tol,
             "n_uncovered_in_candidate": (n - m) if part_is_candidate else 0,
             "warnings": [], "notes": [note]}

    def pick(a, rows):
        return None if a is None else a[rows]

    if part_is_candidate:  # the reference's vertices the candidate holds, in their order
        compared = np.zeros(n, dtype=bool)
        compared[index] = True
        order = np.argsort(index, kind="stable")
        rows = index[order]
        return (reference.value[rows], candidate.value[order], pick(reference.stderr, rows),
                pick(candidate.stderr, order), compared, extra)
    return (reference.value, candidate.value[index], reference.stderr,
            pick(candidate.stderr, index), None, extra)
