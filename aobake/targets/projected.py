"""High-to-low targets: AO of a detailed *source* mesh, stored on a simplified *low* mesh.

The pipeline's scene is the source (the high-poly mesh): its occluders are the ones the
pipeline builds, and every AO ray is traced through them.  The target loads the low mesh
itself, finds its points (the texel samples of its UVs, as the lightmap target does, or
its vertices), projects each along its cage ray onto the source
(``aobake.targets.projected_cage``: the first hit within twice the cage distance), and
hands the method the projected points with the source's shading normal there.  A point
whose ray missed gets a zero normal: it casts no ray and is left out of its texel (or gets
the no-information value, per vertex).

Two targets:

* ``projected_texels`` (:class:`ProjectedTexelTarget`): a lightmap in the low mesh's UVs
  (or a new atlas of it), made by the lightmap target's stages (atlas, raster, surface,
  gather: seams, gutters, denoising as there), plus three channels: ``missed`` (the
  fraction of the texel's samples whose cage ray missed the source), ``back_hit`` (the
  fraction that hit the back of a source face) and ``projection_distance`` (the mean
  height of its projected points above the low surface, L - t, over the samples that
  hit), each 0 outside the charts and not gutter-filled, like ``coverage``.
* ``projected_vertices`` (:class:`ProjectedVertexTarget`): one value per low vertex, its
  projection kept in ``result.projection``.

The report's ``scene`` is the source's; ``projection`` says the low mesh, the cage and
what the projection did (hits, misses, back hits, distances, per point and per texel).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from aobake import _native
from aobake.errors import InputError
from aobake.groups import dark_warning
from aobake.records import BakeResult, TexelResult
from aobake.scene import ExtraOccluder, Scene, load_scene
from aobake.records import Finished, SamplePoints
from aobake.targets.projected_cage import (Cage, Projection, mesh_cage, offset_cage,
                                           parse_offset, project)
from aobake.targets.texels import TexelTarget
from aobake.targets.texels.splat import splat, subset, texel_counts
from aobake.targets.texels.surface import surface_points
from aobake.vectors import defined

#: the cage offset when neither an offset nor a cage mesh is given: 1% of the low mesh's
#: diagonal (docs/studio.md: the decimated bunny needs about 0.5%)
DEFAULT_CAGE_OFFSET = "1%"
#: the channels a projected lightmap adds, after the lightmap's own
CHANNELS = ("missed", "back_hit", "projection_distance")


@dataclass
class ProjectedTexelResult(TexelResult):
    """A projected lightmap (a :class:`TexelResult`: it writes as one).

    channels : the lightmap's and :data:`CHANNELS`; atlas : the low mesh's;
    projection : the :class:`Projection` of every texel sample, samples : their
    ``TexelSamples`` (texel of each), low : the low mesh's Scene.
    """

    projection: Projection | None = None
    samples: object = None
    low: Scene | None = None


@dataclass
class ProjectedBakeResult(BakeResult):
    """Per low vertex (a :class:`BakeResult` on the low mesh: it writes as one).

    normals : the source's shading normal at each vertex's projected point (zero where it
    missed); projection : the :class:`Projection` of every low vertex, in vertex order;
    low : the low mesh's Scene.
    """

    projection: Projection | None = None
    low: Scene | None = None


class _Projecting:
    """What both targets share: the low mesh, the cage, the projection's report."""

    def __init__(self, low, *, cage_offset=None, cage=None, low_occludes=False):
        if cage is not None and cage_offset is not None:
            raise InputError("give a cage offset or a cage mesh, not both")
        self.low_source = low
        self.cage_source = cage
        self.cage_offset = None if cage is not None else parse_offset(
            DEFAULT_CAGE_OFFSET if cage_offset is None else cage_offset)
        self.low_occludes = bool(low_occludes)
        self.receivers = None  # set by aobake.groups for the faces that may receive
        self._loaded = None  # (low, cage, seconds) when extend_scene loaded them first

    def _load_both(self, config, warnings) -> tuple[Scene, Cage]:
        low = load_scene(self.low_source, config.normals, config.fix_normals)
        if self.cage_source is None:
            cage = offset_cage(low, self.cage_offset)
        else:  # the user's winding is the cage's: no repair may renumber its corners
            cage = mesh_cage(low, load_scene(self.cage_source, "angle", "off"), warnings)
        return low, cage

    def extend_scene(self, scene, config, timings) -> Scene:
        """The pipeline's scene with the low mesh among its occluders when
        ``low_occludes`` (``aobake.backends.extra``: front faces only, beyond
        :func:`occluder_skip` of each ray's origin); else ``scene`` itself."""
        if not self.low_occludes:
            return scene
        clock = time.perf_counter()
        pending: list = []
        low, cage = self._load_both(config, pending)
        self._loaded = (low, cage, time.perf_counter() - clock, pending)
        extra = ExtraOccluder(f"low mesh {low.source}", low.vertices, low.faces,
                              occluder_skip(low, cage))
        return replace(scene, extra_occluders=(*scene.extra_occluders, extra))

    def _load(self, config, timings, warnings, phase) -> tuple[Scene, Cage]:
        phase("loading")
        if self._loaded is not None:
            low, cage, seconds, pending = self._loaded
            warnings.extend(pending)
            warnings.extend(low.warnings)
            timings["load_low_s"] = seconds
            return low, cage
        clock = time.perf_counter()
        low = load_scene(self.low_source, config.normals, config.fix_normals,
                         config.uv_set if self.name == "projected_texels" else 0)
        if self.cage_source is None:
            cage = offset_cage(low, self.cage_offset)
        else:  # the user's winding is the cage's: no repair may renumber its corners
            cage = mesh_cage(low, load_scene(self.cage_source, "angle", "off"), warnings)
        for message in low.warnings:
            warnings.append(message)
        timings["load_low_s"] = time.perf_counter() - clock
        return low, cage

    def _project(self, scene, occluders, low_points, cage_points, threads, timings, phase):
        phase("projecting")
        clock = time.perf_counter()
        built = occluders()  # the projection rays need the source's structure: wait for it
        receivers = self.receivers(built) if self.receivers is not None else None
        projection = project(built, scene, low_points, cage_points, threads, receivers)
        timings["projection_s"] = time.perf_counter() - clock
        return projection

    def _record(self, scene, low, cage, projection) -> dict:
        hit = projection.hit
        record = {"source": scene.source, "low": low.stats(), "cage": cage.record(low),
                  "rule": "first hit of the source on the ray from the cage point through "
                          "the low point, within twice their distance",
                  **projection.counts()}
        height = projection.distance[hit]
        record["distance"] = None if not len(height) else {
            "min": float(height.min()), "p50": float(np.median(height)),
            "max": float(height.max())}
        return record


class ProjectedTexelTarget(_Projecting):
    """A lightmap of the low mesh ``low`` (a path, trimesh mesh or Scene) holding the AO of
    the pipeline's scene (the source) at the projected texel samples.

    cage_offset : the offset cage's distance (a number of scene units or 'P%' of the low
    mesh's diagonal; default :data:`DEFAULT_CAGE_OFFSET`), or cage : a cage mesh with the
    low mesh's topology (a path, trimesh mesh or Scene).  Give at most one.  The lightmap
    settings (resolution, padding, texel samples, unwrap, seams, denoise) are the config's.
    """

    name = "projected_texels"

    def check(self, config) -> None:
        TexelTarget().check(config)

    def rays_per_point(self, config) -> int:
        return TexelTarget().rays_per_point(config)

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        phase = phase or (lambda name: None)
        low, cage = self._load(config, timings, warnings, phase)

        def no_occluders():  # the low mesh's texels need no rays of the source
            raise RuntimeError("the lightmap target of the low mesh asked for occluders")
        inner = TexelTarget().sample(low, config, no_occluders, threads, timings, warnings,
                                     phase)
        samples = inner.state["samples"]
        clock = time.perf_counter()
        compiled = inner.state["compiled"]
        cage_points, _, _ = surface_points(cage.positions, None, low.faces, samples, threads,
                                           _native.kernels() if compiled else None,
                                           face_normals=False)
        timings["cage_s"] = time.perf_counter() - clock
        projection = self._project(scene, occluders, inner.points, cage_points, threads,
                                   timings, phase)
        del cage_points
        sizes = _sizes(scene, projection)
        state = dict(inner=inner.state, low=low, cage=cage, projection=projection)
        return SamplePoints(projection.points, projection.normals, inner.ids, sizes=sizes,
                            kernels=inner.kernels, state=state, faces=projection.faces,
                            bary=projection.bary)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        state = plan.state
        low, projection = state["low"], state["projection"]
        samples = state["inner"]["samples"]
        done = TexelTarget().finish(low, config, replace(plan, state=state["inner"]),
                                    estimates, timings, warnings)
        images = dict(done.result.channels)
        images.update(_projection_channels(samples, projection))
        record = self._record(scene, low, state["cage"], projection)
        record["texels"] = texels = _texel_counts(samples, projection)
        dark = dark_warning(estimates, low.source)
        if dark:
            warnings.append(dark)
        if texels["missed_any"] or texels["back_any"]:
            warnings.append(_texel_warning(scene, low, texels, projection, state["cage"]))
        texture = done.result
        result = ProjectedTexelResult(images, texture.covered, {}, atlas=texture.atlas,
                                      projection=projection, samples=samples, low=low)
        report = dict(done.report)
        report["projection"] = record
        return replace(done, result=result, report=report)


class ProjectedVertexTarget(_Projecting):
    """One value per vertex of the low mesh ``low``: the AO of the pipeline's scene (the
    source) at the vertex's projected point (cage options as :class:`ProjectedTexelTarget`).
    Vertices with the same position and cage position share one projection and one sample
    stream (the first one's index), as vertices split at UV seams do in the vertex target.
    """

    name = "projected_vertices"

    def rays_per_point(self, config) -> int:
        return config.rays

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        phase = phase or (lambda name: None)
        low, cage = self._load(config, timings, warnings, phase)
        keys = np.ascontiguousarray(np.concatenate([low.vertices, cage.positions], axis=1))
        rows = keys.view(np.dtype((np.void, keys.itemsize * keys.shape[1]))).ravel()
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        low_points = low.vertices[first]
        cage_points = cage.positions[first].copy()
        used = np.zeros(len(low.vertices), dtype=bool)
        used[low.used] = True
        # An unreferenced vertex (or one without a normal) has no cage ray: not projected.
        skip = ~(used & defined(low.vertex_normals))[first]
        cage_points[skip] = low_points[skip]
        projection = self._project(scene, occluders, low_points, cage_points, threads,
                                   timings, phase)
        state = dict(low=low, cage=cage, projection=projection, inverse=inverse.reshape(-1))
        return SamplePoints(projection.points, projection.normals, first.astype(np.int64),
                            sizes=_sizes(scene, projection), state=state,
                            faces=projection.faces, bary=projection.bary)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        state = plan.state
        low, inverse, projection = state["low"], state["inverse"], state["projection"]
        values = {name: array[inverse] for name, array in estimates.fields.items()}
        per_vertex = Projection(*(getattr(projection, f)[inverse] for f in
                                  ("hit", "back", "faces", "bary", "points", "normals",
                                   "distance", "reach")))
        record = self._record(scene, low, state["cage"], per_vertex)
        used = np.zeros(len(low.vertices), dtype=bool)
        used[low.used] = True
        missed = int(np.count_nonzero(~per_vertex.hit & used))
        back = int(np.count_nonzero(per_vertex.back))
        record["vertices"] = {"used": int(used.sum()), "missed": missed, "back": back}
        if missed or back:
            warnings.append(f"{low.source}: of {int(used.sum())} vertices, {missed} "
                            f"projections missed {scene.source} and {back} hit the back of "
                            f"a face ({_advice(state['cage'])})")
        dark = dark_warning(estimates, low.source)
        if dark:
            warnings.append(dark)
        normals = per_vertex.normals
        rays = None if estimates.rays is None else estimates.rays[inverse]
        result = ProjectedBakeResult(low.vertices, low.faces, normals, rays,
                                     {**values, **projection_fields(per_vertex)},
                                     projection=per_vertex, low=low)
        cast = None if estimates.rays is None else int(estimates.rays.astype(np.int64).sum())
        return Finished(result, values, rays, len(low.vertices), cast=cast,
                        report={"projection": record})


def projection_fields(projection: Projection) -> dict:
    """The per-vertex outputs' projection fields (``quantities.PROJECTION_FIELDS``): missed
    (n,) uint8 1 where nothing was projected, back_hit (n,) uint8, projection_distance (n,)
    float64 the height L - t (scene units), 0 where missed: never NaN or inf."""
    hit = projection.hit
    return {"missed": (~hit).astype(np.uint8),
            "back_hit": (projection.back & hit).astype(np.uint8),
            "projection_distance": np.where(hit, projection.distance, 0.0)}


def occluder_skip(low: Scene, cage: Cage) -> float:
    """The distance (scene units) within which the low mesh does not occlude a ray of its own
    bake (``--low-occludes``): the longest cage ray, 2 L, L the largest distance between a
    used low vertex and its cage vertex.  A projected point lies within L of the low surface
    along its ray (its height, in [-L, L]): a ray of its bake that dips below the low
    surface's tangent plane (where the source's normal differs from the low mesh's) meets
    that surface within 2 L when it dips by 30 degrees or more."""
    gap = np.linalg.norm(cage.positions[low.used] - low.vertices[low.used], axis=1)
    return 2.0 * float(gap.max()) if len(gap) else 0.0


def _sizes(scene, projection: Projection) -> np.ndarray:
    """(n,) float64 the ray offset's size at each projected point: the source triangle's
    (sqrt of twice its area); a miss casts nothing, its size is the median triangle's."""
    areas = scene.areas()
    sizes = np.full(len(projection.hit), math.sqrt(2.0 * float(np.median(areas))))
    sizes[projection.hit] = np.sqrt(2.0 * areas[projection.faces[projection.hit]])
    return sizes


def _projection_channels(samples, projection: Projection) -> dict:
    """``missed``, ``back_hit`` and ``projection_distance`` (H, W) float32: per texel the
    fraction of its samples that missed, that hit a back face, and the mean height of those
    that hit; 0 where the texel has no sample (or no hit)."""
    out = {"missed": splat(samples, (~projection.hit).astype(np.float64))[..., 0],
           "back_hit": splat(samples, projection.back.astype(np.float64))[..., 0]}
    hit = projection.hit
    out["projection_distance"] = splat(subset(samples, hit), projection.distance[hit])[..., 0]
    return {name: np.ascontiguousarray(image, dtype=np.float32) for name, image in out.items()}


def _texel_counts(samples, projection: Projection) -> dict:
    """Per texel of the low mesh's charts: how many there are, how many had a sample miss
    (any, all) or hit a back face (any)."""
    count = texel_counts(samples).ravel()
    missed = np.bincount(samples.texel, weights=~projection.hit, minlength=len(count))
    back = np.bincount(samples.texel, weights=projection.back, minlength=len(count))
    charted = count > 0
    return {"charted": int(charted.sum()),
            "missed_any": int(np.count_nonzero(missed > 0)),
            "missed_all": int(np.count_nonzero(charted & (missed == count))),
            "back_any": int(np.count_nonzero(back > 0))}


def _advice(cage: Cage) -> str:
    if cage.kind == "offset":
        return (f"cage offset {cage.offset:.4g}: misses and back hits where the source lies "
                "farther from the low mesh than that; raise --cage-offset, or give --cage")
    return "the cage mesh does not enclose the source everywhere"


def _texel_warning(scene, low, texels: dict, projection: Projection, cage: Cage) -> str:
    counts = projection.counts()
    return (f"{low.source}: of {texels['charted']} texels, {texels['missed_any']} have samples "
            f"whose cage ray missed {scene.source} ({texels['missed_all']} entirely: filled "
            f"from their neighbours; {counts['missed']} of {counts['points']} samples) and "
            f"{texels['back_any']} hit the back of a source face ({counts['back']} samples); "
            f"the `missed` and `back_hit` channels show where ({_advice(cage)})")
