"""The records every stage passes, in one module: a target's sample points
(:class:`SamplePoints`), a method's estimates at them (:class:`Estimates`, merged by index
with :func:`merge`), what a target makes of them (:class:`Finished`) and what a bake
returns (:class:`BakeResult`, :class:`TexelResult`, :class:`ViewResult`).

Stages import these records and nothing of each other: an executor splits
``SamplePoints`` and merges ``Estimates`` without knowing any target or method.

Each point's estimate depends on that point alone (its position, normal, size and
sample-stream id), so :func:`merge` of the estimates of any split of the points gives
the same arrays as one call on all of them: that is what lets an executor split a
bake over threads, processes or machines.

Results come in two kinds: per-point results (``points``: vertices, query points) and
images (``image``: lightmap texels and camera pixels).  Writers are chosen by (kind,
extension) (``aobake.outputs.registry``); each result says its kind and the target that
made it, so nothing is guessed from its attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aobake.quantities import FIELDS


class PointRange:
    """(n,) int64 0, 1, ..., n-1 without the array (8 bytes a point): the ``ids`` and
    ``state`` of a per-vertex plan whose every vertex is its own point.  Indexing gives the
    indices themselves (a slice: their range; an index array: a copy of it as int64; a
    bool mask: its true places), and numpy reads the whole as the array (``__array__``), so
    it stands wherever the (n,) array stood; only a bake that indexes it a chunk at a time
    (the tracer) never makes the whole."""

    dtype = np.dtype(np.int64)
    ndim = 1

    def __init__(self, n: int):
        self.n = int(n)
        self.shape = (self.n,)

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, key):
        if isinstance(key, slice):
            return np.arange(*key.indices(self.n), dtype=np.int64)
        key = np.asarray(key)
        if key.dtype == bool:
            if key.shape != self.shape:
                raise IndexError(f"boolean index of shape {key.shape} for ({self.n},)")
            return np.flatnonzero(key)
        if key.dtype.kind not in "iu":
            raise IndexError(f"only integers, slices and bool masks index ids, got {key.dtype}")
        out = key.astype(np.int64)
        if out.size and (out.min() < -self.n or out.max() >= self.n):
            raise IndexError(f"index out of range for {self.n} points")
        return np.where(out < 0, out + self.n, out) if out.size and out.min() < 0 else out

    def __array__(self, dtype=None, copy=None):
        whole = np.arange(self.n, dtype=np.int64)
        return whole if dtype is None else whole.astype(dtype)

    def __reduce__(self):
        return (PointRange, (self.n,))


class BlockRows:
    """(n, ...) rows made a block of rows at a time, never held whole: a plan's per-point
    array whose blocks each depend on that block alone (a set's instances).

    bounds : (b + 1,) int64 increasing from 0 to n: block k is rows bounds[k] ..
    bounds[k + 1] - 1; make : k -> that block's rows, (bounds[k + 1] - bounds[k],) + tail of
    ``dtype``.  Readers take a block at a time (``block``); indexing gives the rows asked for
    (a slice, an index array or a bool mask over the rows: the blocks they fall in are
    made; a tuple indexes those rows further), and numpy reads the whole as the array
    (``__array__``), so it stands wherever the array stood.  Pickled, it is that array (a
    worker gets values, not the scene)."""

    def __init__(self, bounds, make, dtype=np.float64, tail: tuple = ()):
        self.bounds = np.asarray(bounds, dtype=np.int64)
        self.make = make
        self.dtype = np.dtype(dtype)
        self.tail = tuple(tail)
        self.shape = (int(self.bounds[-1]),) + self.tail
        self.ndim = len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def block(self, k: int) -> np.ndarray:
        """The rows of block k."""
        return self.make(k)

    def __getitem__(self, key):
        if isinstance(key, tuple):  # rows first, then the rest of the key on them
            return self[key[0]][(slice(None),) + key[1:]]
        n = len(self)
        if isinstance(key, slice):
            start, stop, step = key.indices(n)
            if step != 1:
                return self[np.arange(start, stop, step)]
            first = int(np.searchsorted(self.bounds, start, side="right")) - 1
            pieces = []
            for k in range(max(first, 0), len(self.bounds) - 1):
                b0, b1 = int(self.bounds[k]), int(self.bounds[k + 1])
                if b0 >= stop:
                    break
                if b1 > start:
                    pieces.append(self.block(k)[max(start, b0) - b0:min(stop, b1) - b0])
            return (np.concatenate(pieces) if pieces
                    else np.zeros((0,) + self.tail, dtype=self.dtype))
        key = np.asarray(key)
        if key.dtype == bool:
            if key.shape != self.shape[:1]:
                raise IndexError(f"boolean index of shape {key.shape} for ({n},)")
            key = np.flatnonzero(key)
        if key.dtype.kind not in "iu":
            raise IndexError(f"only integers, slices and bool masks index rows, got {key.dtype}")
        index = key.astype(np.int64).reshape(-1)
        if index.size and (index.min() < -n or index.max() >= n):
            raise IndexError(f"index out of range for {n} rows")
        index = np.where(index < 0, index + n, index)
        out = np.empty((len(index),) + self.tail, dtype=self.dtype)
        which = np.searchsorted(self.bounds, index, side="right") - 1
        for k in np.unique(which).tolist():
            here = which == k
            out[here] = self.block(k)[index[here] - self.bounds[k]]
        return out.reshape(key.shape + self.tail)

    def __array__(self, dtype=None, copy=None):
        whole = self[0:len(self)]
        return whole if dtype is None else whole.astype(dtype)

    def copy(self) -> np.ndarray:
        """The whole as an array of its own (``ndarray.copy``: a stage that edits the rows,
        ``--occluder-only`` zeroing normals, gets them made whole)."""
        return np.asarray(self)

    def __reduce__(self):
        return (np.asarray, (np.asarray(self),))


class BlockSizes(BlockRows):
    """(n,) float64 per-point sizes made a block of points at a time (:class:`BlockRows`):
    the ``sizes`` of a plan whose points fall into blocks whose sizes each depend on that
    block alone (a set's instances: a vertex's triangles are its instance's).  The tracer
    reads it a block at a time, each block's points in their own order."""

    def __init__(self, bounds, make):
        super().__init__(bounds, make, np.float64)


def block_rows(array, bounds, k: int):
    """Rows bounds[k] .. bounds[k + 1] - 1 of ``array``: the block itself where the array
    is made a block at a time with the same bounds (:class:`BlockRows`), else a slice."""
    if isinstance(array, BlockRows) and np.array_equal(array.bounds, bounds):
        return array.block(k)
    return array[int(bounds[k]):int(bounds[k + 1])]


@dataclass
class SamplePoints:
    """Where to trace.

    points : (n, 3) float64 scene units, normals : (n, 3) float64 unit (zero = not
    traced: 0 rays, no-information values), ids : (n,) int64 sample-stream ids (or a
    :class:`PointRange`: 0..n-1 without the array) (a
    point's rays are a pure function of (seed, id, sample id): equal ids get equal
    rays), sizes : (n,) float64 the size of each point's own triangles (sqrt of twice their
    mean area; sets the ray offset; or a :class:`BlockSizes`: made a block at a time) or
    None when unknown, kernels : stage -> compiled? for
    the compiled stages the target ran, state : whatever ``finish`` needs back, faces :
    (n,) int64 the triangle each point lies on (-1: none) and bary : (n, 3) float64 its
    barycentric coordinates there, or None when the target does not know them (vertices,
    query points): a method that interpolates on the surface (``file``) needs them;
    image : the view's G-buffer (``aobake.screen.gbuffer.GBuffer``: depth, hardware depths,
    view-space normals, coverage, the camera) when the points are a camera's pixels (their
    ids are then the pixel indices r * W + c), else None: what a screen-space method reads.
    """

    points: np.ndarray
    normals: np.ndarray
    ids: np.ndarray
    sizes: np.ndarray | None = None
    kernels: dict = field(default_factory=dict)
    state: object = None
    faces: np.ndarray | None = None
    bary: np.ndarray | None = None
    image: object = None


@dataclass
class Finished:
    """A target's result before the report, and what the report needs from it.

    result : BakeResult | TexelResult (``report`` filled in by ``run``),
    values, rays : the per-point fields and rays (n,) the error summary is taken over,
    points : how many points the report counts, cast : rays traced (None = sum of rays),
    report : extra report sections (e.g. ``texture``),
    rays_key : the report's name for the rays each point cast.
    """

    result: object
    values: dict
    rays: np.ndarray
    points: int
    cast: int | None = None
    report: dict = field(default_factory=dict)
    rays_key: str = "rays_per_point"


@dataclass
class Estimates:
    """What a method says at n sample points.

    fields : name -> (n,) / (n, 3) float64 (names of ``aobake.quantities.FIELDS``),
    rays : (n,) int32 rays cast per point, or None for a method that casts none (it then
    reports no ``rays`` field and no stderr: it is deterministic),
    extras : name -> (n, ...) per-point arrays the method's record is made from (the ray
    offset used, kept ray distances, ``--tolerance``'s final counts); merged by index like
    the fields,
    dof : the degrees of freedom of a point's stderr (the fewest any point has: a target
    that pools points' errors, a lightmap's texel, needs it), or None without a stderr.
    """

    fields: dict
    rays: np.ndarray | None
    extras: dict = field(default_factory=dict)
    dof: int | None = None

    def __len__(self) -> int:
        first = next(iter(self.fields.values()), None)
        if first is not None:
            return len(first)
        return 0 if self.rays is None else len(self.rays)

    @property
    def rays_cast(self) -> int | None:
        """Rays traced in all (None for a method that casts none)."""
        return None if self.rays is None else int(np.sum(self.rays, dtype=np.int64))


def merge(parts, n: int) -> Estimates:
    """One Estimates of n points from ``parts``: (index (k,) int64, Estimates of k points)
    pairs that cover 0..n-1 once.  Rows land by index, so the split and the order of the
    parts change nothing."""
    parts = list(parts)
    if not parts:
        raise ValueError("merge needs at least one part")
    first = parts[0][1]

    def like(array):
        return np.empty((n,) + array.shape[1:], dtype=array.dtype)

    fields = {name: like(a) for name, a in first.fields.items()}
    extras = {name: like(a) for name, a in first.extras.items()}
    rays = None if first.rays is None else like(first.rays)
    seen = np.zeros(n, dtype=np.int64)
    for index, part in parts:
        seen[index] += 1
        for name, array in part.fields.items():
            fields[name][index] = array
        for name, array in part.extras.items():
            extras[name][index] = array
        if rays is not None:
            rays[index] = part.rays
    if not (seen == 1).all():
        raise ValueError("merge: the parts must cover every point exactly once")
    dofs = {part.dof for _, part in parts}
    if len(dofs) != 1:  # a property of the method's settings, not of the points
        raise ValueError(f"merge: the parts disagree on their degrees of freedom {dofs}")
    return Estimates(fields, rays, extras, first.dof)


class Merged:
    """The Estimates of n points filled in place as parts land (``add``): what an executor
    that splits the points into ranges holds beyond the result is the parts in flight, never
    every part until the end, nor an index or a count per point.

    folds : extra name -> a fold that takes that extra of each part (``add(start, stop,
    part)``) and stands for it in the result (``result()``: an object numpy reads as the
    (n, ...) array, or a summary the method's record reads), instead of an (n, ...) array
    of it: the method's say (``RaysMethod.folds``); a fold named for several extras takes
    each part once.  Rows land by index, so the split and
    the order the parts arrive in change nothing."""

    def __init__(self, n: int, folds: dict | None = None):
        self.n, self.folds = int(n), dict(folds or {})
        self.fields = self.extras = self.rays = self.dof = None
        self.ranges: list = []

    def add(self, start: int, stop: int, part: "Estimates") -> None:
        """Rows start..stop-1 are ``part`` (an Estimates of stop - start points)."""
        if self.fields is None:  # the first part says the fields' kinds and shapes
            def like(array):
                return np.empty((self.n,) + array.shape[1:], dtype=array.dtype)

            self.fields = {name: like(a) for name, a in part.fields.items()}
            self.extras = {name: like(a) for name, a in part.extras.items()
                           if name not in self.folds}
            self.rays = None if part.rays is None else like(part.rays)
            self.dof = part.dof
        elif part.dof != self.dof:  # a property of the method's settings, not of the points
            raise ValueError(f"merge: the parts disagree on their degrees of freedom "
                             f"{{{self.dof}, {part.dof}}}")
        rows = slice(start, stop)
        for name, array in part.fields.items():
            self.fields[name][rows] = array
        for name, array in part.extras.items():
            if name not in self.folds:
                self.extras[name][rows] = array
        for fold in {id(f): f for f in self.folds.values()}.values():  # each fold once
            fold.add(start, stop, part)
        if self.rays is not None:
            self.rays[rows] = part.rays
        self.ranges.append((int(start), int(stop)))

    def result(self) -> "Estimates":
        """The merged Estimates; the ranges added must tile 0..n-1 exactly once."""
        if self.fields is None:
            raise ValueError("merge needs at least one part")
        end = 0
        for start, stop in sorted(self.ranges):
            if start != end or stop < start:
                raise ValueError("merge: the parts must cover every point exactly once")
            end = stop
        if end != self.n:
            raise ValueError("merge: the parts must cover every point exactly once")
        extras = dict(self.extras)
        for name, fold in self.folds.items():
            extras[name] = fold.result()
        return Estimates(self.fields, self.rays, extras, self.dof)


@dataclass
class BakeResult:
    """Per-point results.

    positions : (n, 3) float64, faces : (f, 3) int64 | None (None for query points),
    normals : (n, 3) float64 (the normals the hemispheres were built on),
    rays : (n,) int32 rays cast per point,
    values : field name -> (n,) / (n, 3) float64 for the quantities baked (see
    ``aobake.quantities.FIELDS``); each is also an attribute (``result.ao``,
    ``result.ao_stderr``, ``result.bent_normal`` ...), None when not baked,
    report : dict (configuration, parameters used, statistics, versions),
    kept : with ``keep_distances``, {"ray_distances": (p, R m) float32 every traced point's
    hit distances in the tracer's local units (inf on a miss; ``parameters.trace_scale``
    converts), "ray_point": (n,) int32 the row of each result point}, else {}.
    """

    positions: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray
    rays: np.ndarray
    values: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)
    kept: dict = field(default_factory=dict)

    #: the result kind (writers are chosen by kind and extension) and the target writers
    #: check formats against (query points write the same formats as vertices)
    kind = "points"
    target = "vertices"

    def __getattr__(self, name):
        if name in FIELDS and name != "values":
            return self.__dict__.get("values", {}).get(name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    def fields(self) -> dict:
        """Per-point arrays that were computed, keyed and ordered as in the NPZ/PLY/GLB outputs."""
        known = {"normals": self.normals, "rays": self.rays, **self.values}
        return {name: known[name] for name in FIELDS if known.get(name) is not None}


@dataclass
class ImageResult:
    """An image of per-pixel values (the ``image`` kind).

    channels : name -> (H, W) float32 (EXR channel names of ``aobake.quantities.FIELDS``,
    plus ``coverage``), row 0 = top of the image; covered : (H, W) bool pixels with values;
    report : dict.
    """

    channels: dict
    covered: np.ndarray
    report: dict

    kind = "image"


@dataclass
class TexelResult(ImageResult):
    """A baked lightmap.

    channels : name -> (H, W) float32 images after gutter dilation ('ao', 'ao_stderr',
    'obscurance', 'obscurance_stderr', 'bent_normal.X/.Y/.Z', 'bent_normal_stderr', 'rays',
    'coverage'; the EXR names of ``aobake.quantities.FIELDS``),
    row 0 = top of the image (v near 1), texel centres at u = (c + 0.5) / W,
    v = 1 - (r + 0.5) / H; covered : (H, W) bool texels with surface samples;
    atlas : ``aobake.targets.texels.atlas.Atlas``; report : dict.
    """

    atlas: object = None

    target = "texels"


@dataclass
class ViewResult(ImageResult):
    """A camera view (``aobake view``): the G-buffer and per-pixel values.

    channels : name -> (H, W) float32 (``aobake.targets.view.GBUFFER`` and the method's
    fields; docs/conventions.md), covered : (H, W) bool pixels that see the scene,
    camera : ``aobake.camera.Camera``; report : dict (its ``camera`` section re-projects a
    pixel exactly).
    """

    camera: object = None

    target = "view"
