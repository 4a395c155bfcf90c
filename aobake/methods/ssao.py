"""Screen-space AO methods (``--method crytek | shanmugam | gtao``) and the height-field truth
(``--method heightfield``), on a camera's pixels.

Each reads only the view's G-buffer (``SamplePoints.image``: depth, or a hardware depth
linearised as an engine must; view-space normals; the camera record), never the mesh, per
pixel: a pixel's value is a pure function of the G-buffer, so any split of the points
gives the same arrays.  On vertices, texels or query points (no G-buffer) they are
refused.  The screen-space methods are deterministic (no stderr, no rays); the height-field
truth casts rays against the depth buffer and reports its standard error like the
ray-traced truth.  The algorithms are in ``aobake.screen`` (crytek, shanmugam, gtao,
refine, heightfield); conventions and numbers: docs/screen-space.md.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from aobake.errors import InputError
from aobake.methods.base import refuse_ray_settings
from aobake.records import Estimates
from aobake.screen import crytek, gbuffer, gtao, heightfield, refine, shanmugam
from aobake.settings.screen import CrytekOptions, GtaoOptions, HeightfieldOptions, SsaoOptions

#: pixels per unit of work on the thread pool (each a pure function of the G-buffer, so
#: the cut changes no bit)
CHUNK_PIXELS = 16384


def _refuse(name: str, config) -> None:
    """What a screen-space method cannot do, refused before any work."""
    quantities = tuple(getattr(config, "quantities", ("ao",)))
    if quantities != ("ao",):
        raise InputError(f"--method {name} estimates ao only, got quantities "
                         f"{', '.join(quantities)}")
    if getattr(config, "weighting", "cosine") != "cosine":
        raise InputError(f"--method {name} estimates cosine-weighted AO (--weighting cosine)")
    refuse_ray_settings(name, config)


def _chunks(n: int, threads: int):
    per = max(1024, min(CHUNK_PIXELS, -(-n // max(1, 4 * threads))))
    return [slice(s, min(n, s + per)) for s in range(0, n, per)]


def _map(function, pixels: np.ndarray, threads: int, progress=None) -> np.ndarray:
    """``function(pixels part) -> values`` over chunks of ``pixels`` on ``threads`` threads,
    landed by index."""
    out = np.empty(len(pixels))
    parts = _chunks(len(pixels), threads)
    done = 0
    if threads <= 1 or len(parts) <= 1:
        for part in parts:
            out[part] = function(pixels[part])
            done += part.stop - part.start
            if progress:
                progress(done, len(pixels))
        return out
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-ssao") as pool:
        for part, values in zip(parts, pool.map(lambda p: function(pixels[p]), parts)):
            out[part] = values
            done += part.stop - part.start
            if progress:
                progress(done, len(pixels))
    return out


class ScreenMethod:
    """What the three screen-space methods share: the G-buffer, the pixels, the rotation and
    the blur.  A subclass gives ``name``, ``raw(frame, pixels)`` and its parameters."""

    name = "screen"
    casts_rays = False
    #: the settings a method uses until the config carries them (``SsaoOptions.of``)
    options = SsaoOptions()

    def __init__(self, radius: float, ssao: SsaoOptions | None = None, seed: int = 0):
        if not (isinstance(radius, (int, float)) and math.isfinite(radius) and radius > 0):
            raise InputError(f"--method {self.name}: radius must be a finite number > 0, got "
                             f"{radius!r}")
        self.radius, self.ssao, self.seed = float(radius), ssao or SsaoOptions(), int(seed)

    @classmethod
    def _common(cls, scene, config):
        _refuse(cls.name, config)
        ssao = SsaoOptions.of(config, cls.options)
        return ssao.radius(scene.diagonal), ssao, getattr(config, "seed", 0)

    # -- what a method computes ------------------------------------------------------------

    def raw(self, frame: gbuffer.Frame, pixels: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def values(self, frame: gbuffer.Frame, pixels: np.ndarray, threads: int = 1,
               progress=None) -> np.ndarray:
        """(k,) float64 AO at flat ``pixels`` (k,) of ``frame``: raw, or blurred over the
        N x N window (``refine``) when ``ssao_blur`` is on."""
        pixels = gbuffer.check_pixels(frame, pixels, self.name)
        if not self.ssao.ssao_blur:
            return _map(lambda p: self.raw(frame, p), pixels, threads, progress)
        return _map(lambda p: refine.blurred(frame, p, lambda q: self.raw(frame, q),
                                             self.ssao.ssao_pattern, self.ssao.ssao_blur_depth,
                                             self.ssao.ssao_blur_normal),
                    pixels, threads, progress)

    def frame(self, image: gbuffer.GBuffer) -> gbuffer.Frame:
        return image.frame(self.ssao.ssao_depth, self.ssao.ssao_normals)

    def image(self, image: gbuffer.GBuffer, threads: int = 1) -> np.ndarray:
        """(H, W) float64 AO at every covered pixel of ``image`` (0 elsewhere)."""
        frame = self.frame(image)
        pixels = np.flatnonzero(frame.covered.reshape(-1))
        out = np.zeros(frame.height * frame.width)
        out[pixels] = self.values(frame, pixels, threads)
        return out.reshape(frame.height, frame.width)

    # -- the method protocol ---------------------------------------------------------------

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : ``SamplePoints`` of a view (``image`` its G-buffer, ``ids`` its pixels)
        -> Estimates with ``ao`` (n,) float64, no rays."""
        frame = self.frame(gbuffer.of(points, self.name))
        values = self.values(frame, points.ids, threads, progress)
        return Estimates({"ao": values}, None, {})

    def parameters(self) -> dict:
        s = self.ssao
        return {"method": self.name, "radius": self.radius, "ssao_radius": s.ssao_radius,
                "depth": s.ssao_depth, "normals": s.ssao_normals, "rotate": s.ssao_rotate,
                "pattern": s.ssao_pattern, "blur": s.ssao_blur,
                "blur_depth_pixels": s.ssao_blur_depth,
                "blur_normal_degrees": s.ssao_blur_normal,
                "reads": "G-buffer only: depth, view-space normals, camera (docs/screen-space.md)"}

    def record(self, estimates: Estimates) -> dict:
        return {"parameters": self.parameters()}

    def error_quantities(self) -> list:
        return []

    def kernel_stages(self) -> dict:
        return {}


class CrytekMethod(ScreenMethod):
    """Crytek SSAO (Mittring 2007): ``aobake.screen.crytek``."""

    name = "crytek"
    crytek_options = CrytekOptions()

    def __init__(self, radius: float, ssao: SsaoOptions | None = None,
                 crytek_options: CrytekOptions | None = None, seed: int = 0):
        super().__init__(radius, ssao, seed)
        self.crytek_options = crytek_options or CrytekOptions()

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "CrytekMethod":
        radius, ssao, seed = cls._common(scene, config)
        return cls(radius, ssao, CrytekOptions.of(config, cls.crytek_options), seed)

    def raw(self, frame, pixels):
        s = self.ssao
        c = self.crytek_options
        return crytek.ao(frame, pixels, self.radius, s.ssao_samples, s.ssao_rotate,
                         s.ssao_pattern, c.crytek_normalise, self.seed, c.crytek_range)

    def parameters(self) -> dict:
        normalise = self.crytek_options.crytek_normalise
        return {**super().parameters(), "samples": self.ssao.ssao_samples,
                "kernel": "ball, equal-volume, antipodal pairs",
                "normalise": normalise, "range_check": self.crytek_options.crytek_range,
                "normalisation": {"double": "AO = min(1, 2A)", "crytek": "AO = min(1, A + A^2)",
                                  "none": "AO = A"}[normalise],
                "flat_value": crytek.FLAT_VALUE[normalise]}


class ShanmugamMethod(ScreenMethod):
    """Shanmugam & Arikan (I3D 2007): ``aobake.screen.shanmugam``."""

    name = "shanmugam"

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "ShanmugamMethod":
        radius, ssao, seed = cls._common(scene, config)
        return cls(radius, ssao, seed)

    def raw(self, frame, pixels):
        s = self.ssao
        return shanmugam.ao(frame, pixels, self.radius, s.ssao_samples, s.ssao_rotate,
                            s.ssao_pattern)

    def parameters(self) -> dict:
        return {**super().parameters(), "samples": self.ssao.ssao_samples,
                "kernel": "Vogel disc of the ball's screen radius",
                "normalisation": "occlusion = sum S_Omega max(n.pc/|pc|, 0) / pi; AO = 1 - "
                                 "min(1, occlusion)",
                "flat_value": shanmugam.FLAT_VALUE}


class GtaoMethod(ScreenMethod):
    """GTAO (Jimenez et al. 2016, as XeGTAO): ``aobake.screen.gtao``."""

    name = "gtao"
    gtao_options = GtaoOptions()

    def __init__(self, radius: float, ssao: SsaoOptions | None = None,
                 gtao_options: GtaoOptions | None = None, seed: int = 0):
        super().__init__(radius, ssao, seed)
        self.gtao_options = gtao_options or GtaoOptions()

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "GtaoMethod":
        radius, ssao, seed = cls._common(scene, config)
        return cls(radius, ssao, GtaoOptions.of(config, cls.gtao_options), seed)

    def raw(self, frame, pixels):
        g, s = self.gtao_options, self.ssao
        return gtao.ao(frame, pixels, self.radius * g.gtao_multiplier, g.gtao_slices,
                       g.gtao_steps, g.gtao_falloff, s.ssao_rotate, s.ssao_pattern)

    def parameters(self) -> dict:
        g = self.gtao_options
        return {**super().parameters(), "slices": g.gtao_slices, "steps": g.gtao_steps,
                "falloff": g.gtao_falloff, "multiplier": g.gtao_multiplier,
                "search_radius": self.radius * g.gtao_multiplier,
                "normalisation": "AO = mean over slices of the analytic cosine-weighted "
                                 "slice integral",
                "flat_value": "(1/S) sum_s |n_s| (cos g_s + g_s sin g_s): 1 facing the eye"}


class HeightfieldMethod:
    """The height-field truth (``--method heightfield``): ``aobake.screen.heightfield``.
    Reads the G-buffer only; casts ``rays`` per pixel against it with the sampler,
    replicates, seed, max distance and confidence of the config; reports ao with its
    stderr and interval, and its rays."""

    name = "heightfield"
    casts_rays = True

    options = HeightfieldOptions()

    def __init__(self, rays: int, max_distance: float, sampler: str = "sobol",
                 replicates: int = 8, seed: int = 0, confidence: float = 0.95,
                 depth: str = "linear", normals: str = "geometric",
                 thickness: float = math.inf):
        if not (max_distance > 0):
            raise InputError(f"--method heightfield: max distance must be > 0, got "
                             f"{max_distance}")
        if not (thickness > 0):
            raise InputError(f"--method heightfield: thickness must be > 0, got {thickness}")
        self.thickness = float(thickness)
        self.rays, self.max_distance = int(rays), float(max_distance)
        self.sampler, self.replicates, self.seed = sampler, int(replicates), int(seed)
        self.confidence, self.depth, self.normals = float(confidence), depth, normals

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "HeightfieldMethod":
        quantities = tuple(config.quantities)
        if quantities != ("ao",):
            raise InputError(f"--method heightfield estimates ao only, got quantities "
                             f"{', '.join(quantities)}")
        if config.tolerance is not None or config.keep_distances:
            raise InputError("--method heightfield takes a fixed --rays (no --tolerance, no "
                             "--keep-distances)")
        ssao = SsaoOptions.of(config, ScreenMethod.options)
        own = HeightfieldOptions.of(config, cls.options)
        return cls(rays_per_point, config.resolve_max_distance(scene.diagonal), config.sampler,
                   config.replicates, config.seed, config.confidence, ssao.ssao_depth,
                   ssao.ssao_normals, own.thickness(scene.diagonal))

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        frame = gbuffer.of(points, self.name).frame(self.depth, self.normals)
        pixels = gbuffer.check_pixels(frame, points.ids, self.name)
        return self.estimates(frame, pixels, threads, progress)

    def estimates(self, frame, pixels, threads: int = 1, progress=None) -> Estimates:
        fields = {name: np.empty(len(pixels)) for name in
                  ("ao", "ao_stderr", "ao_ci_low", "ao_ci_high")}
        rays = np.empty(len(pixels), dtype=np.int32)
        dof = [0]

        def one(part):
            mean, se, low, high, cast, d = heightfield.estimate(
                frame, pixels[part], self.rays, self.max_distance, self.sampler,
                self.replicates, self.seed, "cosine", self.confidence, self.thickness)
            dof[0] = d
            return part, (mean, se, low, high, cast)

        parts = _chunks(len(pixels), threads)
        done = 0
        with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
            for part, (mean, se, low, high, cast) in pool.map(one, parts):
                for name, value in zip(("ao", "ao_stderr", "ao_ci_low", "ao_ci_high"),
                                       (mean, se, low, high)):
                    fields[name][part] = value
                rays[part] = cast
                done += part.stop - part.start
                if progress:
                    progress(done, len(pixels))
        return Estimates(fields, rays, {}, dof[0] if len(pixels) else None)

    def image(self, image: gbuffer.GBuffer, threads: int = 1) -> dict:
        """(H, W) float64 ``ao`` and ``ao_stderr`` at every covered pixel of ``image``."""
        frame = image.frame(self.depth, self.normals)
        pixels = np.flatnonzero(frame.covered.reshape(-1))
        est = self.estimates(frame, pixels, threads)
        out = {}
        for name in ("ao", "ao_stderr"):
            full = np.zeros(frame.height * frame.width)
            full[pixels] = est.fields[name]
            out[name] = full.reshape(frame.height, frame.width)
        return out

    def record(self, estimates: Estimates) -> dict:
        return {"parameters": {
            "method": self.name, "max_distance": self.max_distance, "sampler": self.sampler,
            "replicates": self.replicates, "rays": self.rays, "depth": self.depth,
            "normals": self.normals, "march_step_pixels": heightfield.STEP,
            "thickness": self.thickness,
            "solid": "behind each pixel's facet (its depth and normal), to the thickness; "
                     "off the image and sky pixels empty"}}

    def error_quantities(self) -> list:
        from aobake.quantities import QUANTITIES

        return [QUANTITIES["ao"]]

    def kernel_stages(self) -> dict:
        return {}


#: the methods of this module, by name (for ``aobake.methods.METHODS``)
SCREEN_METHODS = {"crytek": CrytekMethod, "shanmugam": ShanmugamMethod, "gtao": GtaoMethod,
                  "heightfield": HeightfieldMethod}

__all__ = ["CrytekMethod", "GtaoMethod", "HeightfieldMethod", "SCREEN_METHODS",
           "ScreenMethod", "ShanmugamMethod"]
