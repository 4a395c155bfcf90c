"""The lightmap target (``TexelTarget``): the texels of a UV atlas, each the mean of K surface
samples; the stages are the modules of this package (``aobake.targets.texels``)."""

from __future__ import annotations

import math
import time

import numpy as np

from aobake import _native
from aobake.errors import InputError
from aobake.records import Finished, SamplePoints, TexelResult
from aobake.targets.texels.atlas import check_texture_budget, make_atlas, split_corners
from aobake.targets.texels.charts import chart_texel_density
from aobake.targets.texels.denoise import CREASE_ANGLE, RANGE_K, SIGMA_TEXELS
from aobake.targets.texels.gather import channels as gather_channels
from aobake.targets.texels.gather import plain_channels
from aobake.targets.texels.seams import SeamMesh
from aobake.targets.texels.surface import surface_points
from aobake.vectors import defined


#: fewer covered texels per chart (new atlas) or per face (own UVs) than this draws a warning
MIN_TEXELS_PER_CHART = 16


class TexelTarget:
    """A lightmap of ``config.resolution`` texels; ``config.rays`` is per texel, split over
    its ``config.texel_samples`` samples (each casts ceil(rays / K))."""

    name = "texels"

    def check(self, config) -> None:
        """Refuse an image too large for this machine before loading anything."""
        if config.keep_distances:
            raise InputError("keep_distances is for per-vertex and query-point bakes (NPZ), "
                             "not lightmaps")
        width, height = config.resolution
        if config.texel_density is None:  # else checked once the size is known
            check_texture_budget(width, height, config.texel_samples)

    def rays_per_point(self, config) -> int:
        return -(-config.rays // config.texel_samples)

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        width, height = config.resolution
        phases: dict = {}
        compiled = _native.kernels() is not None  # decided once, recorded as decided
        if scene.instances is not None and hasattr(scene.instances, "transforms"):
            # a set of instances: one region per baked instance (targets.texels.instanced)
            from aobake.targets.texels.instanced import make_set_atlas

            atlas, bake_uv, bake_faces_uv, check, samples = make_set_atlas(
                scene, config, width, height, threads, warnings, phases, compiled,
                phase or (lambda name: None))
        else:
            atlas, bake_uv, bake_faces_uv, check, samples = make_atlas(
                scene, config.unwrap, width, height, config.padding, config.texel_samples,
                config.seed, threads, warnings, phases, compiled, phase or (lambda name: None),
                texel_density=config.texel_density, uv_overlap=config.uv_overlap,
                overlap_mask=config.overlap_mask)
        timings["uv_check_s"] = phases["uv_check_s"]
        timings["unwrap_s"] = phases["unwrap_s"]
        clock = time.perf_counter()
        points, normals, _ = surface_points(scene.vertices, scene.vertex_normals, scene.faces,
                                            samples, threads,
                                            _native.kernels() if compiled else None,
                                            face_normals=False)
        # Rasterising the UVs baked into (a rejected own-UV pass is in uv_check_s) + surface points.
        timings["rasterize_s"] = phases["raster_s"] + time.perf_counter() - clock
        # Point ids: position in the (texel, sample, face)-sorted sample list, a pure
        # function of the inputs, so texels are reproducible for any threads/chunks.
        ids = np.arange(len(points), dtype=np.int64)
        sizes = np.sqrt(2.0 * scene.areas()[samples.face])
        state = dict(atlas=atlas, uv=bake_uv, faces_uv=bake_faces_uv, check=check,
                     samples=samples, compiled=compiled, size=atlas.size, seams=None,
                     threads=threads)
        if config.seams != "off":  # UV seams erased in gather
            state["seams"] = SeamMesh(scene.vertices, scene.vertex_normals, scene.faces,
                                      bake_uv, bake_faces_uv, atlas.wrap)
        kernels = {"rasterizer": compiled, "atlas_packing": atlas.packing_compiled,  # None: own UVs
                   "seam_solve": None if config.seams == "off" else compiled,
                   "gutters": compiled if config.padding > 0 else None}
        return SamplePoints(points, normals, ids, sizes=sizes, kernels=kernels, state=state,
                            faces=samples.face, bary=samples.bary)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        from aobake.quantities import QUANTITIES

        values, rays = estimates.fields, estimates.rays
        clock = time.perf_counter()
        state = plan.state
        samples = state["samples"]
        to_tangent = None
        if config.bent_space == "tangent":
            def to_tangent(sub, traced, bent):
                return _to_tangent(scene, state["uv"], state["faces_uv"], sub,
                                   plan.normals[traced], bent)
        quantities = [QUANTITIES[name] for name in config.quantities]
        # Degrees of freedom of one sample's stderr, as the method says (the fewest).
        dof = estimates.dof
        seam_info: dict = {}
        denoise = None
        if config.denoise:  # guided by the surface: points, normals, charts, texel spacing
            denoise = (plan.points, plan.normals, state["uv"], state["faces_uv"],
                       scene.areas())
        if rays is None:  # a method that casts no rays: values only, no error to carry
            if config.denoise:
                raise InputError("--denoise filters by the noise of ray-traced values; the "
                                 "method cast no rays")
            images, covered, filled = plain_channels(samples, values, defined(plan.normals),
                                                     config.padding, state["seams"], timings,
                                                     seam_info, compiled=state["compiled"],
                                                     threads=state["threads"],
                                                     to_tangent=to_tangent)
            quantities = [q for q in quantities if q.value.name in values]
        else:
            images, covered, filled = gather_channels(quantities, samples, values, rays,
                                                      config.padding, to_tangent, dof,
                                                      config.confidence, state["seams"],
                                                      timings, seam_info, denoise,
                                                      compiled=state["compiled"],
                                                      threads=state["threads"])
        timings["splat_dilate_s"] = time.perf_counter() - clock
        shared = int(np.count_nonzero(samples.shared >= 2))
        if shared:
            warnings.append(f"{scene.source}: {shared} texels are shared by overlapping or "
                            "mirrored UV shells; their values average the surfaces that share them")
        width, height = state["size"]  # config.resolution, or chosen for config.texel_density
        texture = _texture_stats(images, covered, filled, shared, width, height, config.padding,
                                 config.texel_samples, state["atlas"], state["check"],
                                 config.bent_space, config.uv_overlap)
        texture["seams"] = seam_info or {"mode": config.seams}
        texture["denoise"] = _denoise_stats(images, covered, quantities) if config.denoise \
            else None
        if config.texel_density is not None:  # the size was chosen for it
            texture["texel_density_requested"] = config.texel_density
        if state["atlas"].instances is not None:  # a set: where each instance's region is
            texture["atlas"] = "instance regions"
            texture["instances"] = state["atlas"].instances.record()
        # Texels per scene unit along the surface, and a warning where charts shrink to a few
        # texels (the map then holds little more than one value per chart).
        area = float(scene.areas().sum())
        texture["texel_density"] = math.sqrt(texture["texels_covered"] / area) if area > 0 else None
        # How much of the image the surface covers, and how evenly the charts share it.
        texture["covered_fraction"] = texture["texels_covered"] / (width * height)
        texture["chart_density"] = _chart_density(scene, state["uv"], state["faces_uv"], width,
                                                  height)
        pieces = state["atlas"].charts or len(scene.faces)
        per_piece = texture["texels_covered"] / max(pieces, 1)
        if per_piece < MIN_TEXELS_PER_CHART:
            what = "charts" if state["atlas"].charts else "faces"
            warnings.append(
                f"{scene.source}: the lightmap covers {texture['texels_covered']} texels for "
                f"{pieces} {what} ({per_piece:.1f} each, {texture['texel_density'] or 0:.3g} "
                f"texels per scene unit): raise "
                f"{'--texel-density' if config.texel_density is not None else '--resolution'}"
                " or lower --padding")
        result = TexelResult(images, covered, {}, atlas=state["atlas"])
        return Finished(result, values, rays, len(plan.points),
                        report={"texture": texture, "timings": timings},
                        rays_key="rays_per_texel_sample")


def _denoise_stats(images, covered, quantities) -> dict:
    """What ``--denoise`` did: its parameters and, per scalar quantity, the mean stderr
    over the covered texels before and after (the noise left; the bias it adds is measured
    in benchmarks/bench_denoise.py, docs/lightmaps.md)."""
    stats = {"method": "joint bilateral on the surface (same chart, world distance, "
                       "normals, value step in noise units)",
             "sigma_texels": SIGMA_TEXELS, "crease_angle": CREASE_ANGLE, "range_k": RANGE_K}
    for q in quantities:
        if q.texel == "direction" or not covered.any():
            continue
        name = q.value.exr[0]
        raw = float(images[q.error.exr[0]][covered].mean())
        after = float(images[name + "_denoised_stderr"][covered].mean())
        stats[name] = {"stderr_mean": raw, "denoised_stderr_mean": after,
                       "noise_reduction": raw / after if after > 0 else None}
    return stats


def _chart_density(scene, uv, faces_uv, width, height):
    """Texel density of the UV islands (charts): sqrt(an island's UV area in texels / its
    surface area), texels per scene unit; 5th, 50th and 95th percentile over the islands
    and ``spread`` = p95 / p5 (1 = every chart at the same density)."""
    density = chart_texel_density(uv, faces_uv, scene.vertices, scene.faces, width, height)
    if not len(density):
        return None
    p5, p50, p95 = (float(x) for x in np.percentile(density, [5, 50, 95]))
    return {"islands": int(len(density)), "p5": p5, "p50": p50, "p95": p95,
            "spread": p95 / p5 if p5 > 0 else None}


def _to_tangent(scene, uv, faces_uv, samples, normals, bent):
    """Bent normals (s, 3) -> tangent space of the bake UVs (MikkTSpace-style frames)."""
    from aobake.tangents import to_tangent_space, vertex_tangents

    keys, faces = split_corners(scene.faces, faces_uv)
    tangents = vertex_tangents(scene.vertices[keys[:, 0]], scene.vertex_normals[keys[:, 0]],
                               uv[keys[:, 1]], faces)
    corner = tangents[faces[samples.face]]  # (s, 3, 4)
    t = np.einsum("sc,scd->sd", samples.bary, corner[..., :3])
    w = np.where(np.einsum("sc,sc->s", samples.bary, corner[..., 3]) < 0, -1.0, 1.0)
    return to_tangent_space(bent, normals, np.concatenate([t, w[:, None]], axis=1))


def _texture_stats(channels, covered, filled, shared, width, height, padding, k, atlas, check,
                   bent_space, uv_overlap="atlas"):
    stats = {
        "width": width,
        "height": height,
        "padding": padding,
        "texel_samples": k,
        "texels_covered": int(covered.sum()),
        "texels_padded": int(np.count_nonzero(filled & ~covered)),
        "texels_shared": shared,
        "atlas": "xatlas" if atlas.new else "mesh UVs",
        # which build of xatlas charted it (the same charts): "aobake._xatlas" or "xatlas"
        "charting": atlas.charting,
        # how the map is sampled: "repeat" when own UVs outside [0, 1] were baked wrapped
        "wrap": atlas.wrap,
        "charts": atlas.charts,
        "uv_check": None if check is None else {
            "valid": check.valid, "out_of_range_faces": check.out_of_range_faces,
            "overlapping_texels": check.overlapping_texels, "mirrored_faces": check.mirrored_faces,
            "bakeable": check.bakeable,
            "message": check.message},
        "bent_space": bent_space,
        # the input's UV set the map belongs to (glTF TEXCOORD_<uv_set>), and what
        # overlapping own UVs got
        "uv_set": atlas.uv_set,
        "uv_overlap": uv_overlap,
        "convention": "row 0 is the top of the image (v = 1); texel (r, c) centre at "
                      "u = (c + 0.5) / W, v = 1 - (r + 0.5) / H",
    }
    for name in ("ao", "obscurance"):
        if name + "_stderr" in channels and covered.any():
            se = channels[name + "_stderr"][covered]
            stats[name + "_stderr"] = {"mean": float(se.mean()), "p50": float(np.median(se)),
                                       "p95": float(np.percentile(se, 95)), "max": float(se.max())}
    return stats
