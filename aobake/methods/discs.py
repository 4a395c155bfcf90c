"""Bunnell's dynamic ambient occlusion (``--method discs``; GPU Gems 2, ch. 14, 2005).

The mesh is replaced by oriented discs, one per vertex (the chapter's elements):
position = the vertex, normal = the normalised sum of the unit normals of the faces
around it, area = the sum of a third of each of those faces' areas.  A receiver (any
sample point with a normal: a vertex, a texel sample, a pixel's first hit, a query point)
is darkened by every disc without any visibility test:

    shadow(E -> R) = (1 - 1 / sqrt(A / (pi d^2) + 1)) * sat(n_E . v) * sat(k n_R . v)

with v the unit vector from the receiver to the element, d their distance, sat = clamp to
[0, 1] (the chapter's ``occlusion.cg``).  The first factor is exactly the fraction of the
hemisphere's solid angle, Omega / (2 pi), that a disc of area A subtends on its axis (the
uniform-weighted, not the cosine-weighted, measure).  Signs, as in the Cg code
(``v = emitterPosition - receiverPosition``): ``n_E . v > 0`` when the receiver is behind
the element, so shadows are cast from an element's back face (light is emitted and
reflected from the front); on a closed mesh every occluder is counted once, by its far
side.  An open sheet shadows only receivers that see its back.  ``k`` is 4 in the listing
printed in the book and 3 in the CD's shader; the default is the book's.

Because no visibility is tested, overlapping occluders are counted twice and pass 1,
``A_1 = sat(1 - sum shadow)``, is too dark.  Pass j weights each element's shadow by that
element's own accessibility from pass j - 1 (the CD's ``ambientOcclusionPass2PS`` reads the
*next* element's value, its index having already advanced: not copied here), which is too
light; the result is ``weight * A_P + (1 - weight) * A_(P-1)`` of the last two of P passes
(the CD: 0.6 pass 2 + 0.4 pass 1).  A receiver that is not an element gathers the elements'
pass values, computed once when the method is prepared.

Elements farther than the configured max distance (centre to receiver) contribute
nothing.  A receiver with a zero normal gets the no-information answer of
``aobake.quantities.ao`` (0.5).  The value is deterministic: no stderr, no rays.

Indirect light (``-q indirect``, the chapter's section 14.4): every element reflects the
sky it sees, radiance ``L_E = albedo * AO_E`` (AO_E its own disc AO, the result above),
from its front face; a receiver gathers it through the disc-to-disc form factor

    F(E -> R) = A sat(n_E . -v) sat(n_R . v) / (pi d^2 + A)

(v the unit vector from the receiver to the element; ``n_E . -v > 0``: the element's front
faces the receiver), which on axis is exactly the cosine-weighted fraction of the
hemisphere the disc covers, so ``sum_E F L_E`` is in the units of the ray-traced
``indirect`` (``(1/pi) int (1 - V) L cos dw``).  Pass 1 is that sum without visibility,
too bright (light from behind occluders is counted).  Pass j subtracts the light each
element blocks: an element whose back the receiver sees stands in front of what lies
beyond it, and the light reaching it there is the light it receives on its front, its
own pass j - 1 value I_(j-1)(B):

    I_j(R) = max(0, I_1(R) - sum_B G(B -> R) I_(j-1)(B)),
    G(B -> R) = A sat(n_B . v) sat(n_R . v) / (pi d^2 + A)

(the same form factor seen from the element's back: the sign of the AO shadow).  The result
is ``indirect_weight * I_Q + (1 - indirect_weight) * I_(Q-1)`` of Q passes.  With
``bounces`` N > 1 the elements' radiance is iterated: ``L_E = albedo (AO_E + J_E)``, J_E the
element's indirect light of N - 1 bounces by the same passes.

The hierarchy (``aobake.methods.discs_tree``) makes a receiver's cost O(log n): a node
stands in for its elements (summed area, area-weighted position and normal, area-weighted
pass values) wherever the receiver is at least ``kappa`` times the node's equivalent-disc
radius sqrt(A / pi) away.  ``traversal="brute"`` sums every element (O(n) per receiver).

All arithmetic runs in a local frame: positions rebased on the elements' per-axis median
and scaled by a power of two (exact), so the numbers do not depend on where the mesh sits
or on its scale; every shadow term is invariant under that scaling.

The robust model (``discs_model="robust"``, the default; Hoberock and Jia, GPU Gems 3,
ch. 12) keeps the elements, the passes and the hierarchy and changes the terms:

- each shadow is the cosine-weighted form factor ``A sat(n_E . v) sat(n_R . v) / (pi d^2
  + A)`` (exact on a disc's axis; no gain k), and near the receiver (a leaf within kappa
  equivalent radii) Lambert's exact form factor of the element's own triangles, a third
  of each, clipped to the receiver's hemisphere;
- a node is blended with its children (a leaf with its triangles) over a band of distances
  (``discs_tree.TRANSITION``) instead of switched at kappa: the result is continuous;
- every element has a flipped twin (its normal reversed) weighted by its ``presence``,
  how open its back is: 0 on closed (or nearly closed) surfaces facing out, found with
  the vertices welded by position (``aobake.repair.orient``), else the one-sided layer's
  AO at the element's back.  An open sheet (a floor) then casts from both sides; a closed
  surface from its back only, as in the chapter;
- a receiver on another surface's triangle (contact: an object resting on a floor) is
  blocked for certain where it faces into a closed surface or along the triangle's plane.

It computes cosine-weighted AO (``--weighting uniform`` is the chapter's model's).  The
indirect light keeps the chapter's one-sided emission and blocking with the robust terms.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict

import numpy as np

from aobake import repair as repairs
from aobake.errors import InputError
from aobake.records import Estimates
from aobake.methods import discs_tree
from aobake.methods.base import refuse_ray_settings
# the settings record and its constants live apart (read by every config), re-exported here
from aobake.settings.discs import (DEFAULT_INDIRECT_PASSES,  # noqa: F401
                                   DEFAULT_INDIRECT_WEIGHT, DEFAULT_KAPPA, DEFAULT_MODEL,
                                   MAX_PASSES, MODELS, TRAVERSALS, DiscsOptions)
from aobake.vectors import defined




#: the no-information value of ``aobake.quantities.ao`` (the midpoint: nothing is known)
NO_INFORMATION_AO = 0.5

#: the hierarchy's stated accuracy at the default kappa: RMSE against brute force at most
#: this (measured at kappa = 4: 0.015 and 0.019 on generated tori, 0.016 on the Stanford
#: bunny's vertices; docs/discs.md), tested in tests/test_discs.py
HIERARCHY_RMSE = 0.025

#: receivers per work chunk (a thread's unit of work): the hierarchy holds a few hundred
#: (receiver, node) pairs per receiver at a time (``terms_per_point`` in the record), its
#: front cut to the pair budget (``chunk_rays``); brute force takes budget // n receivers
#: at a time within a chunk.  256 to 4096 run at the same speed on the bunny.
RECEIVERS_PER_CHUNK = 1024

#: the pair budget of the elements' own passes at prepare time (the tracer's default chunk)
PREPARE_PAIRS = 131072

#: the quantities the method estimates
DISC_QUANTITIES = ("ao", "indirect")




def chapter_shadow(area, distance, cos_e, cos_r, k: float = 4.0):
    """The chapter's shadow of one disc (arrays broadcast): area A, distance d > 0, cos_e =
    n_E . v, cos_r = n_R . v (v unit, receiver -> element) -> (1 - 1/sqrt(A/(pi d^2) + 1))
    sat(cos_e) sat(k cos_r), in [0, 1): 0 = casts nothing.  On axis (cos_e = cos_r = 1) it is
    Omega / (2 pi), Omega the solid angle of a disc of radius sqrt(A / pi) at distance d;
    far away it falls as A / (2 pi d^2)."""
    area, distance = np.asarray(area, np.float64), np.asarray(distance, np.float64)
    x = area / (math.pi * distance * distance)
    s = np.sqrt(1.0 + x)
    return x / (s * (s + 1.0)) * np.clip(cos_e, 0.0, 1.0) * np.clip(k * np.asarray(cos_r), 0.0, 1.0)


def lecture_shadow(area, distance, cos_e, cos_r):
    """The form printed in the lecture, ``1 - r cos(theta_E) max(1, 4 cos(theta_R)) /
    sqrt(A/pi + r^2)``: kept for the record, not used.  It does not vanish with distance:
    as r -> infinity it tends to ``1 - cos(theta_E) max(1, 4 cos(theta_R))``, a constant
    (tests/test_discs.py shows it), so summing it over a mesh's elements diverges."""
    area, distance = np.asarray(area, np.float64), np.asarray(distance, np.float64)
    return 1.0 - distance * np.asarray(cos_e) * np.maximum(1.0, 4.0 * np.asarray(cos_r)) \
        / np.sqrt(area / math.pi + distance * distance)


def form_factor(area, distance, cos_e, cos_r):
    """The chapter's disc-to-disc form factor (arrays broadcast): ``A sat(cos_e) sat(cos_r) /
    (pi d^2 + A)``, area A, distance d > 0, cos_e the cosine at the element on the side that
    faces the receiver (its front for light, its back for blocked light), cos_r = n_R . v.
    On axis it is sin^2(alpha), alpha = atan(r / d), r = sqrt(A / pi): the cosine-weighted
    fraction of the hemisphere that a disc covers, exact for a real disc."""
    area, distance = np.asarray(area, np.float64), np.asarray(distance, np.float64)
    return area / (math.pi * distance * distance + area) * np.clip(cos_e, 0.0, 1.0) \
        * np.clip(cos_r, 0.0, 1.0)


def combine(passes: np.ndarray, weight: float) -> np.ndarray:
    """passes (n, P) float64 accessibilities of passes 1..P -> (n,) the result:
    ``weight * pass P + (1 - weight) * pass P-1`` (pass 1 itself when P = 1)."""
    if passes.shape[1] == 1:
        return passes[:, 0].copy()
    return weight * passes[:, -1] + (1.0 - weight) * passes[:, -2]


def elements(scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chapter's discs of ``scene``, one per vertex that some face of non-zero area uses
    and whose face normals do not cancel: (position (e, 3), normal (e, 3) unit, area (e,))
    float64 in scene units.  area = sum over the vertex's faces of (face area / 3) (so the
    elements' areas sum to the mesh's), normal = normalised sum of those faces' unit normals."""
    position, normal, area, _keep = _elements(scene)
    return position, normal, area


def _elements(scene):
    """:func:`elements` and keep (v,) bool: the vertices that have an element."""
    faces = np.asarray(scene.faces, dtype=np.int64)
    n = len(scene.vertices)
    corners = faces.ravel()
    area = np.bincount(corners, weights=np.repeat(scene.areas() / 3.0, 3), minlength=n)
    face_normals = np.repeat(np.asarray(scene.face_normals, dtype=np.float64), 3, axis=0)
    summed = np.stack([np.bincount(corners, weights=face_normals[:, axis], minlength=n)
                       for axis in range(3)], axis=1)
    length = np.sqrt(discs_tree._dot(summed, summed))
    keep = (area > 0) & (length > 0)
    normal = summed[keep] / length[keep, None]
    return np.asarray(scene.vertices, dtype=np.float64)[keep], normal, area[keep], keep


def element_faces(faces: np.ndarray, face_area: np.ndarray, keep: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Each element's own triangles: faces (f, 3) int64 vertex indices, face_area (f,),
    keep (v,) bool the vertices that have an element (in order) -> (start (e + 1,) int64,
    faces (m,) int64): element i's triangles of non-zero area are ``faces[start[i]:start[i +
    1]]``, in increasing order."""
    element_of = np.full(len(keep), -1, dtype=np.int64)
    element_of[keep] = np.arange(int(keep.sum()), dtype=np.int64)
    with_area = np.flatnonzero(face_area > 0)
    owner = element_of[faces[with_area].ravel()]
    face = np.repeat(with_area, 3)
    has = owner >= 0
    owner, face = owner[has], face[has]
    order = np.lexsort((face, owner))
    owner, face = owner[order], face[order]
    start = np.searchsorted(owner, np.arange(int(keep.sum()) + 1)).astype(np.int64)
    return start, face.astype(np.int64)


def closed_elements(vertices: np.ndarray, faces: np.ndarray, start: np.ndarray,
                    owned: np.ndarray) -> np.ndarray:
    """(e,) bool: the elements whose triangles all lie on closed (or nearly closed: small
    holes) components facing out, with the vertices welded by position (a slab written as
    separate patches is one closed component).  vertices (v, 3), faces (f, 3) int64; start,
    owned as :func:`element_faces`.  ``aobake.repair.orient`` finds the components."""
    vertices = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64))
    _, first, weld = np.unique(vertices.view(np.dtype((np.void, 24))).ravel(),
                               return_index=True, return_inverse=True)
    welded = vertices[first]
    # re-centred and scaled (orient's volumes are products of three coordinates)
    welded = welded - welded.mean(axis=0) if len(welded) else welded
    reach = float(np.abs(welded).max()) if len(welded) else 0.0
    found = repairs.orient(welded / reach if reach > 0 else welded, weld.reshape(-1)[faces])
    shut = (found.closed | found.nearly_closed) & ~found.inward
    on_shut = np.zeros(len(faces), dtype=bool)
    has = found.component >= 0
    on_shut[has] = shut[found.component[has]]
    # an element is closed when none of its triangles is on an open (or inward) component
    open_count = np.add.reduceat((~on_shut[owned]).astype(np.int64), start[:-1]) \
        if len(owned) else np.zeros(len(start) - 1, dtype=np.int64)
    empty = start[1:] == start[:-1]
    return (open_count == 0) & ~empty


class DiscsMethod:
    """Bunnell's disc AO: one deterministic value per point (``ao``), no rays, no stderr.

    Build with :meth:`prepare` (from a scene and a BakeConfig; the registry's entry point)
    or :meth:`from_elements` (explicit discs).  ``options`` (a :class:`DiscsOptions`) is a
    class-level default until the CLI passes its own.
    """

    name = "discs"
    casts_rays = False
    options = DiscsOptions()

    def __init__(self, position: np.ndarray, normal: np.ndarray, area: np.ndarray,
                 options: DiscsOptions, max_distance: float, threads: int | None = None,
                 quantities: tuple = ("ao",), albedo: float = 0.5, bounces: int = 1,
                 triangles: tuple | None = None, closed: np.ndarray | None = None):
        """position (e, 3), normal (e, 3) unit, area (e,) > 0 float64 in scene units;
        max_distance in scene units (inf: no limit); quantities some of ``DISC_QUANTITIES``;
        albedo in [0, 1] and bounces >= 1 (``indirect`` only); triangles : the robust model's
        exact near field, (corners (f, 3, 3) float64 scene units, normals (f, 3) unit,
        start (e + 1,), faces (m,): :func:`element_faces`), None: discs at every distance;
        closed : (e,) bool the elements on closed surfaces facing out (:func:`closed_elements`:
        the robust model's presence is 0 there without a gather), None: none known.
        Builds the frame, the hierarchy (the robust model: its flipped layer) and the
        elements' pass values (passes 1..P-1; with ``indirect``, the elements' AO, their
        radiance and their indirect passes 1..Q-1) once."""
        quantities = tuple(q for q in DISC_QUANTITIES if q in quantities)
        if not quantities:
            raise InputError(f"discs: quantities must be some of {DISC_QUANTITIES}")
        if not (0.0 <= albedo <= 1.0) or int(bounces) < 1:
            raise InputError(f"discs: albedo must be in [0, 1] and bounces >= 1, got "
                             f"{albedo!r}, {bounces!r}")
        self.quantities = quantities
        self.albedo, self.bounces = float(albedo), int(bounces)
        self.options = options
        self.max_distance = float(max_distance)
        self.n_elements = len(position)
        # The local frame: rebased on the per-axis median, scaled by a power of two (exact)
        # so the elements span [-1, 1]; A / d^2 and the cosines do not change.
        self.center = np.median(position, axis=0)
        reach = float(np.abs(position - self.center).max())
        self.scale = 2.0 ** -math.frexp(reach)[1] if reach > 0 else 1.0
        self.position = (position - self.center) * self.scale
        self.normal = normal
        self.area = area * (self.scale * self.scale)
        self.local_max_distance = self.max_distance * self.scale
        self.robust = options.discs_model == "robust"
        # the robust model always walks the tree (brute force: every node above the leaves
        # opened), whose leaves blend into their triangles
        self.tree = (discs_tree.build(self.position, self.normal, self.area)
                     if options.discs_traversal == "hierarchy" or self.robust else None)
        threads = threads or _default_threads()
        self.triangles = None
        self.presence = np.zeros(self.n_elements)  # the flipped layer (robust model)
        if self.robust:
            if triangles is not None:
                corners, face_normal, start, faces = triangles
                self.triangles = discs_tree.Triangles(
                    (np.asarray(corners, dtype=np.float64) - self.center) * self.scale,
                    np.asarray(face_normal, dtype=np.float64), np.asarray(start, np.int64),
                    np.asarray(faces, np.int64))
            # How open each element's back is: the receiver at its position facing the
            # other way, under the one-sided layer alone.  Inside a closed surface it is 0
            # (the far side covers it), behind an open sheet 1: the flipped layer's weight.
            self.flipped = discs_tree.flipped_levels(self.tree, self.position, self.normal,
                                                     self.area, self.presence)
            open_back = (np.ones(self.n_elements, dtype=bool) if closed is None
                         else ~np.asarray(closed, dtype=bool))
            if open_back.any():
                sums, _ = self._gather(self._weights(np.ones((self.n_elements, 1))),
                                       self.position[open_back], -self.normal[open_back],
                                       threads, PREPARE_PAIRS, contact=False, presence=True)
                self.presence[open_back] = np.clip(1.0 - sums[:, 0], 0.0, 1.0)
            self.flipped = discs_tree.flipped_levels(self.tree, self.position, self.normal,
                                                     self.area, self.presence)
        # Passes 1..P-1 at the elements: what a receiver's pass j weights each shadow by.
        # The receivers here are the elements themselves (their own normals).
        accessible = np.ones((self.n_elements, 1))  # "pass 0": every element casts fully
        computed = []
        for _ in range(options.discs_passes - 1):
            sums, _terms = self._gather(self._weights(accessible), self.position, self.normal,
                                        threads, PREPARE_PAIRS)
            accessible = np.clip(1.0 - sums, 0.0, 1.0)
            computed.append(accessible[:, 0])
        self.element_passes = (np.stack(computed, axis=1) if computed
                               else np.zeros((self.n_elements, 0)))
        ao_columns = np.concatenate([np.ones((self.n_elements, 1)), self.element_passes], axis=1)
        self.element_light = None  # (e,) radiance of the elements' fronts (indirect)
        self.element_indirect_passes = np.zeros((self.n_elements, 0))
        columns, kinds = [], []
        if "ao" in quantities:
            columns.append(ao_columns)
            kinds += ["shadow"] * ao_columns.shape[1]
        if "indirect" in quantities:
            self._prepare_indirect(ao_columns, threads)
            columns += [self.element_light[:, None], self.element_indirect_passes]
            kinds += ["light"] + ["blocked"] * self.element_indirect_passes.shape[1]
        self._kinds = tuple(kinds)
        self._all = self._weights(np.concatenate(columns, axis=1))

    def _prepare_indirect(self, ao_columns: np.ndarray, threads: int) -> None:
        """The elements' AO (all P passes, combined), then per bounce their radiance
        L = albedo (AO + J) and indirect passes; keeps the last bounce's radiance
        (``element_light``) and its passes 1..Q-1 (``element_indirect_passes``), what a
        receiver's passes weight the light and the blocked light by."""
        opt = self.options
        sums, _ = self._gather(self._weights(ao_columns), self.position, self.normal, threads,
                               PREPARE_PAIRS)
        self.element_ao = combine(np.clip(1.0 - sums, 0.0, 1.0), opt.discs_weight)
        carried = np.zeros(self.n_elements)  # J: indirect light of the bounces so far
        Q = opt.discs_indirect_passes
        for bounce in range(1, self.bounces + 1):
            light = self.albedo * (self.element_ao + carried)
            last = bounce == self.bounces
            passes = self._indirect_passes(light, Q - 1 if last else Q, threads)
            if not last:
                carried = combine(passes, opt.discs_indirect_weight)
        self.element_light = light
        self.element_indirect_passes = passes

    def _indirect_passes(self, light: np.ndarray, count: int, threads: int) -> np.ndarray:
        """(e, count) float64 the elements' indirect passes 1..count under the radiance
        ``light`` (e,): pass 1 the unshadowed gather, pass j = max(0, pass 1 - the light
        blocked by elements of pass j - 1 light)."""
        e = self.n_elements
        if count == 0:
            return np.zeros((e, 0))
        sums, _ = self._gather(self._weights(light[:, None]), self.position, self.normal,
                               threads, PREPARE_PAIRS, kinds=("light",))
        first = sums[:, 0]
        out = [first]
        for _ in range(count - 1):
            blocked, _ = self._gather(self._weights(out[-1][:, None]), self.position,
                                      self.normal, threads, PREPARE_PAIRS, kinds=("blocked",))
            out.append(np.maximum(first - blocked[:, 0], 0.0))
        return np.stack(out, axis=1)

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None, options: DiscsOptions | None = None
                ) -> "DiscsMethod":
        """Once per scene: the elements, their hierarchy and their pass values.  Reads
        ``config.quantities`` (``ao`` only) and ``config.max_distance``; ``occluders``,
        ``rays_per_point`` and ``compiled`` are not used (no rays are cast).  Refuses what it
        cannot honour: other quantities, a ground plane, ``tolerance`` and
        ``keep_distances`` (both about rays)."""
        quantities = tuple(config.quantities)
        if not set(quantities) <= set(DISC_QUANTITIES):
            raise InputError(f"--method discs estimates {' and '.join(DISC_QUANTITIES)} only, "
                             f"got quantities {', '.join(quantities)}")
        if "indirect" in quantities and getattr(config, "weighting", "cosine") != "cosine":
            raise InputError("--method discs -q indirect: the form factor is the cosine-"
                             "weighted measure; --weighting uniform is not approximated")
        if getattr(config, "ground_plane", False):
            raise InputError("--method discs has no ground plane (its elements are the mesh's "
                             "vertices)")
        refuse_ray_settings("discs", config)
        position, normal, area, keep = _elements(scene)
        if len(position) == 0:
            raise InputError(f"{scene.source}: no faces with area: --method discs has no "
                             "elements")
        max_distance = config.resolve_max_distance(scene.diagonal)
        if options is None:  # the config's settings once it carries them, else the class's
            options = DiscsOptions.of(config, cls.options)
        triangles = closed = None
        if options.discs_model == "robust":
            if getattr(config, "weighting", "cosine") != "cosine":
                raise InputError("--method discs --discs-model robust computes cosine-weighted "
                                 "AO (its form factors are the cosine measure); --weighting "
                                 "uniform is the chapter's model's (--discs-model chapter)")
            faces = np.asarray(scene.faces, dtype=np.int64)
            face_area = scene.areas()
            start, owned = element_faces(faces, face_area, keep)
            triangles = (np.asarray(scene.vertices, dtype=np.float64)[faces],
                         np.asarray(scene.face_normals, dtype=np.float64), start, owned)
            closed = closed_elements(scene.vertices, faces, start, owned)
        return cls(position, normal, area, options, max_distance, quantities=quantities,
                   albedo=getattr(config, "albedo", 0.5), bounces=getattr(config, "bounces", 1),
                   triangles=triangles, closed=closed)

    @classmethod
    def from_elements(cls, position, normal, area, options: DiscsOptions | None = None,
                      max_distance: float = math.inf, threads: int | None = None,
                      quantities: tuple = ("ao",), albedo: float = 0.5, bounces: int = 1
                      ) -> "DiscsMethod":
        """Explicit discs: position (e, 3), normal (e, 3) (normalised here), area (e,) float64;
        discs of zero area or normal are dropped.  quantities, albedo, bounces: as
        ``__init__``."""
        position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
        normal = np.asarray(normal, dtype=np.float64).reshape(-1, 3)
        area = np.asarray(area, dtype=np.float64).reshape(-1)
        if not (len(position) == len(normal) == len(area)):
            raise InputError(f"discs: position {position.shape}, normal {normal.shape} and "
                             f"area {area.shape} must have one row per element")
        if not (np.isfinite(position).all() and np.isfinite(normal).all()
                and np.isfinite(area).all() and (area >= 0).all()):
            raise InputError("discs: positions, normals and areas must be finite, areas >= 0")
        length = np.sqrt(discs_tree._dot(normal, normal))
        keep = (area > 0) & (length > 0)
        if not keep.any():
            raise InputError("discs: no element has an area and a normal")
        if not (max_distance >= 0):
            raise InputError(f"discs: max_distance must be >= 0, got {max_distance!r}")
        return cls(position[keep], normal[keep] / length[keep, None], area[keep],
                   options or cls.options, max_distance, threads, quantities=quantities,
                   albedo=albedo, bounces=bounces)

    def _weights(self, per_element: np.ndarray):
        """Per-element weight columns (e, w) -> what the traversal reads: per level for the
        hierarchy (area-weighted means at the nodes), as is for brute force."""
        if self.tree is None:
            return per_element
        return self.tree.node_values(per_element)

    def _gather(self, weights, receivers: np.ndarray, normals: np.ndarray, threads: int,
                budget: int, advance=None, kinds=None, contact: bool = True,
                presence: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Sums (c, w) and terms (c,) at receivers (c, 3) in the local frame, each column
        with its kernel (``kinds``, ``discs_tree.KINDS``; None: shadows), in chunks on
        ``threads`` threads (results land by index); ``advance(k)`` as k more receivers are
        done."""
        c = len(receivers)
        # Work chunks of RECEIVERS_PER_CHUNK receivers; inside one, brute force takes
        # budget // n receivers at a time (many small calls cost 3x more: measured).
        per = RECEIVERS_PER_CHUNK
        ranges = [(s, min(c, s + per)) for s in range(0, c, per)]
        columns = weights[0].shape[1] if self.tree is not None else weights.shape[1]
        sums, terms = np.zeros((c, columns)), np.zeros(c, dtype=np.int64)
        opt = self.options

        def run(bounds):
            lo, hi = bounds
            if self.robust:
                # the presence (how open each back is: 0 or 1 but near an open rim, a
                # coarse quantity) with a switch between levels: half the terms
                return discs_tree.gather_robust(
                    self.tree, self.flipped, self.triangles, self.presence, weights,
                    receivers[lo:hi], normals[lo:hi], opt.discs_kappa,
                    self.local_max_distance, budget, kinds,
                    brute=opt.discs_traversal == "brute", contact=contact,
                    band=0.0 if presence else None)
            if self.tree is not None:
                return discs_tree.gather_tree(self.tree, weights, receivers[lo:hi],
                                              normals[lo:hi], opt.discs_k, opt.discs_kappa,
                                              self.local_max_distance, budget, kinds)
            return discs_tree.gather_brute(self.position, self.normal, self.area, weights,
                                           receivers[lo:hi], normals[lo:hi], opt.discs_k,
                                           self.local_max_distance, budget, kinds)

        if threads <= 1 or len(ranges) <= 1:
            results = map(run, ranges)
        else:
            pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-discs")
            results = pool.map(run, ranges)
        try:
            for (lo, hi), (s, t) in zip(ranges, results):
                sums[lo:hi], terms[lo:hi] = s, t
                if advance is not None:
                    advance(hi - lo)
        finally:
            if threads > 1 and len(ranges) > 1:
                pool.shutdown(wait=True, cancel_futures=True)
        return sums, terms

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : ``SamplePoints`` (points (n, 3), normals (n, 3) unit, zero = no
        information) -> Estimates(fields {"ao": (n,) float64 in [0, 1]: 1 = open;
        "indirect": (n,) float64 >= 0: 0 = no indirect light; each when asked for}, rays
        None, extras {"discs_passes": (n, P) float64 each AO pass's accessibility,
        "discs_indirect_passes": (n, Q) float64 each indirect pass (each when its quantity
        is asked for; NaN where the normal is zero, whose values are the no-information
        0.5), "discs_terms": (n,) int64 disc terms summed per point}).  chunk_rays : the most
        (receiver, node) pairs a thread holds at once."""
        p = np.asarray(points.points, dtype=np.float64)
        nrm = np.asarray(points.normals, dtype=np.float64)
        n = len(p)
        P = self.options.discs_passes
        Q = self.options.discs_indirect_passes
        sampled = defined(nrm) if n else np.zeros(0, dtype=bool)
        terms = np.zeros(n, dtype=np.int64)
        fields, extras = {}, {}
        if "ao" in self.quantities:
            fields["ao"] = np.full(n, NO_INFORMATION_AO)
            extras["discs_passes"] = np.full((n, P), np.nan)
        if "indirect" in self.quantities:
            fields["indirect"] = np.full(n, NO_INFORMATION_AO)
            extras["discs_indirect_passes"] = np.full((n, Q), np.nan)
        index = np.flatnonzero(sampled)
        if len(index):
            receivers = (p[index] - self.center) * self.scale
            done = [0]

            def advance(k):
                done[0] += k
                if progress is not None:
                    progress(done[0], len(index))

            sums, t = self._gather(self._all, receivers, nrm[index], max(1, int(threads)),
                                   max(1, int(chunk_rays)), advance, self._kinds)
            terms[index] = t
            column = 0
            if "ao" in self.quantities:
                passes = np.clip(1.0 - sums[:, :P], 0.0, 1.0)
                extras["discs_passes"][index] = passes
                fields["ao"][index] = combine(passes, self.options.discs_weight)
                column = P
            if "indirect" in self.quantities:
                first = sums[:, column]
                light = [first] + [np.maximum(first - sums[:, column + j], 0.0)
                                   for j in range(1, Q)]
                passes = np.stack(light, axis=1)
                extras["discs_indirect_passes"][index] = passes
                fields["indirect"][index] = combine(passes, self.options.discs_indirect_weight)
        extras["discs_terms"] = terms
        return Estimates(fields, None, extras)

    def record(self, estimates: Estimates) -> dict:
        """The report's ``parameters``: every option, the max distance (scene units), the
        elements and the hierarchy's depth, each pass's mean at the elements and at the
        sampled points (pass 1's over-darkening and its correction; with ``indirect``, the
        indirect passes, the albedo and bounces), terms per point."""
        def means(passes):
            sampled = ~np.isnan(passes[:, 0]) if len(passes) else np.zeros(0, dtype=bool)
            return sampled, [float(passes[sampled, j].mean()) if sampled.any() else None
                             for j in range(passes.shape[1])]

        first = "discs_passes" if "ao" in self.quantities else "discs_indirect_passes"
        sampled, _ = means(estimates.extras[first])
        terms = estimates.extras["discs_terms"][sampled]
        parameters = {"method": self.name, **asdict(self.options),
                      "max_distance": self.max_distance,
                      "elements": int(self.n_elements),
                      "tree_depth": None if self.tree is None else int(self.tree.depth),
                      "points_sampled": int(np.count_nonzero(sampled)),
                      "element_pass_means": [float(m) for m in self.element_passes.mean(axis=0)],
                      "terms_per_point": float(terms.mean()) if len(terms) else None}
        if "ao" in self.quantities:
            parameters["pass_means"] = means(estimates.extras["discs_passes"])[1]
        if "indirect" in self.quantities:
            parameters.update(
                albedo=self.albedo, bounces=self.bounces,
                indirect_pass_means=means(estimates.extras["discs_indirect_passes"])[1],
                element_indirect_pass_means=[
                    float(m) for m in self.element_indirect_passes.mean(axis=0)],
                element_light_mean=float(self.element_light.mean()))
        else:
            for name in ("discs_indirect_passes", "discs_indirect_weight"):
                parameters.pop(name)  # not used without indirect light
        if self.tree is None:
            parameters["discs_kappa"] = None  # not used by brute force
        if self.robust:
            parameters["discs_k"] = None  # the chapter's receiver gain: not used
            parameters["two_sided_elements"] = int(np.count_nonzero(self.presence > 0))
            parameters["exact_near_field"] = self.triangles is not None
        return {"parameters": parameters}

    def error_quantities(self) -> list:
        """None: an approximation has no error bar (its error is what ``aobake compare``
        measures against the ray-traced truth)."""
        return []

    def kernel_stages(self) -> dict:
        return {}


def _default_threads() -> int:
    from aobake.trace import default_threads

    return default_threads()
