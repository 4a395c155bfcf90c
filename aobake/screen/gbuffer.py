"""The G-buffer a screen-space method reads, as a renderer would hand it over.

``GBuffer`` holds exactly the camera target's G-buffer channels (float32 (H, W), row 0 =
top; ``aobake.targets.view.GBUFFER``, docs/conventions.md "Camera views") that a
screen-space method may read: ``coverage``, the linear view ``depth``, the three hardware
depths (``hwdepth_gl``, ``hwdepth_d3d``, ``hwdepth_reversed``), the view-space geometric
normal ``Ng`` and shading normal ``N``, and the camera (``aobake.camera.Camera``, with
near/far).  It is built from the primary hits with the same arithmetic as the target's
``finish`` (so its channels equal the view's EXR bit for bit: tested), or read back from a
view's channels (``from_channels``: a view EXR, or another tool's G-buffer in aobake's
conventions).

``Frame`` is what every method computes on, in float64: the depth linearised from the
chosen buffer (``linear``, or a hardware depth turned back into view depth with
``camera.linearize_depth`` and the camera's near/far, as an engine must: a pixel holding
the cleared value (1, or 0 reversed) is sky, depth inf), unit view-space normals, and the
pinhole's maps between continuous pixel coordinates and view space.  Pixel (r, c) covers
[c, c + 1) x [r, r + 1) (x = column, y = row, row 0 = top), its centre is (c + 0.5, r + 0.5);
view space is right-handed, the eye at the origin looking down -Z, +Y up; depth d = -z.
A method reads a pixel's position from its depth (``positions``), never the hit point: the
reconstruction at a pixel centre is where the pixel's primary ray met the surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake import camera as cameras
from aobake.errors import InputError
# the depth buffers and normals a method may read: the settings' choices, stated in
# ``aobake.settings.screen``
from aobake.settings.screen import DEPTH_SOURCES, NORMAL_SOURCES

#: the G-buffer channel of each depth source
DEPTH_CHANNELS = {"linear": "depth", "opengl": "hwdepth_gl", "d3d": "hwdepth_d3d",
                  "reversed": "hwdepth_reversed"}
#: the cleared value of each hardware depth buffer (what a pixel that sees nothing holds)
CLEARED = {"opengl": 1.0, "d3d": 1.0, "reversed": 0.0}
NORMAL_CHANNELS = {"geometric": "Ng", "shading": "N"}
#: the channels a GBuffer holds
CHANNELS = ("coverage", "depth", "hwdepth_gl", "hwdepth_d3d", "hwdepth_reversed",
            "Ng.X", "Ng.Y", "Ng.Z", "N.X", "N.Y", "N.Z")


@dataclass(frozen=True, eq=False)
class GBuffer:
    """One view's G-buffer.

    channels : name -> (H, W) float32 (``CHANNELS``; a G-buffer read from another tool may
    lack the hardware depths or one of the normals: a method asking for a missing one is
    refused), camera : ``aobake.camera.Camera`` with near and far set.
    """

    channels: dict
    camera: cameras.Camera

    def __post_init__(self):
        cam = self.camera
        if cam.near is None or cam.far is None:
            raise InputError("G-buffer: the camera has no near/far planes")
        shape = (cam.height, cam.width)
        for name, image in self.channels.items():
            if np.shape(image) != shape:
                raise InputError(f"G-buffer: channel {name} is {np.shape(image)}, the camera's "
                                 f"image is {shape} (H, W)")
        if "coverage" not in self.channels:
            raise InputError("G-buffer: no coverage channel")

    @property
    def shape(self) -> tuple:
        return self.camera.height, self.camera.width

    def frame(self, depth: str = "linear", normals: str = "geometric") -> "Frame":
        """The float64 ``Frame`` a method computes on, from the ``depth`` buffer
        (``DEPTH_SOURCES``) and the ``normals`` (``NORMAL_SOURCES``)."""
        if depth not in DEPTH_SOURCES:
            raise InputError(f"depth source must be one of {list(DEPTH_SOURCES)}, got {depth!r}")
        if normals not in NORMAL_SOURCES:
            raise InputError(f"normal source must be one of {list(NORMAL_SOURCES)}, got "
                             f"{normals!r}")
        name = DEPTH_CHANNELS[depth]
        if name not in self.channels:
            raise InputError(f"G-buffer has no {name} channel (depth source {depth!r})")
        key = NORMAL_CHANNELS[normals]
        if any(f"{key}.{a}" not in self.channels for a in "XYZ"):
            raise InputError(f"G-buffer has no {key}.X/Y/Z channels ({normals} normals)")
        cam = self.camera
        buffer = np.asarray(self.channels[name], dtype=np.float64)
        if depth == "linear":
            covered = np.asarray(self.channels["coverage"]) > 0
            view_depth = np.where(covered, buffer, np.inf)
        else:
            # As an engine must: the cleared value marks the sky (it cannot tell a hit at the
            # far plane from no hit), every other value is linearised with near/far.
            sky = buffer == CLEARED[depth]
            view_depth = cameras.linearize_depth(buffer, cam.near, cam.far, depth)
            view_depth = np.where(sky | ~(view_depth > 0), np.inf, view_depth)
            covered = np.isfinite(view_depth)
        n = np.stack([np.asarray(self.channels[f"{key}.{a}"], dtype=np.float64)
                      for a in "XYZ"], axis=-1)
        length = np.linalg.norm(n, axis=-1)
        good = covered & (length > 0)
        n = np.where(good[..., None], n / np.where(length > 0, length, 1.0)[..., None], 0.0)
        return Frame(cam, view_depth, n, covered, depth, normals)

    @classmethod
    def from_hits(cls, cam: cameras.Camera, index: np.ndarray, points: np.ndarray,
                  ng: np.ndarray, ns: np.ndarray) -> "GBuffer":
        """The G-buffer of a view whose covered pixels ``index`` (k,) int64 (r * W + c) hit
        world ``points`` (k, 3) float64 with geometric and shading normals ``ng``, ``ns``
        (k, 3) float64 facing the eye: the arithmetic of ``ViewTarget.finish``, so every
        channel equals the view's output bit for bit."""
        h, w = cam.height, cam.width
        n = h * w
        channels = {name: np.zeros(n, dtype=np.float32) for name in CHANNELS}
        channels["coverage"][index] = 1.0
        rotation = cam.world_to_view()[:3, :3]
        p_view = (points - cam.eye) @ rotation.T
        depth = -p_view[:, 2]
        channels["depth"][index] = depth
        full = np.full(n, np.inf)
        full[index] = depth
        for convention, name in (("opengl", "hwdepth_gl"), ("d3d", "hwdepth_d3d"),
                                 ("reversed", "hwdepth_reversed")):
            channels[name][:] = cameras.hardware_depth(full, cam.near, cam.far, convention)
        for key, vectors in (("Ng", ng), ("N", ns)):
            in_view = vectors @ rotation.T
            for axis, letter in enumerate("XYZ"):
                channels[f"{key}.{letter}"][index] = in_view[:, axis]
        return cls({name: a.reshape(h, w) for name, a in channels.items()}, cam)

    @classmethod
    def from_channels(cls, channels: dict, camera) -> "GBuffer":
        """A G-buffer from a view's channels (name -> (H, W); a ``ViewResult``'s or a view
        EXR's; those of ``CHANNELS`` present are kept, as float32) and its camera (a
        ``Camera``, or a view's camera record: ``report["camera"]``)."""
        if isinstance(camera, dict):
            camera = camera_from_record(camera)
        kept = {name: np.asarray(channels[name], dtype=np.float32) for name in CHANNELS
                if name in channels}
        return cls(kept, camera)

    @classmethod
    def from_view(cls, result) -> "GBuffer":
        """The G-buffer of a ``ViewResult`` (``aobake.bake_view``)."""
        return cls.from_channels(result.channels, result.camera)


def camera_from_record(record: dict) -> cameras.Camera:
    """The ``Camera`` of a view's camera record (``Camera.record()``, ``report["camera"]``,
    an EXR's ``aobake:camera``)."""
    try:
        return cameras.look_at(record["eye"], record["target"], record["up"],
                               record["fov_y_deg"], (int(record["width"]), int(record["height"])),
                               near=record["near"], far=record["far"], name=record.get("name"))
    except KeyError as error:
        raise InputError(f"camera record has no {error.args[0]!r}") from None


def of(points, method: str) -> GBuffer:
    """The G-buffer that ``points`` (``SamplePoints`` / a work item's) carry, with their
    pixels checked; InputError naming ``method`` where there is none (vertices, texels,
    query points: no depth buffer to read)."""
    image = getattr(points, "image", None)
    if image is None:
        raise InputError(f"--method {method} reads a camera's G-buffer (depth and normals): "
                         "it runs on a view (aobake view / bake_view), not on vertices, "
                         "texels or query points, which have no depth buffer")
    if not isinstance(image, GBuffer):
        raise InputError(f"--method {method}: the points carry {type(image).__name__}, not a "
                         "G-buffer")
    return image


@dataclass(frozen=True, eq=False)
class Frame:
    """A G-buffer linearised for computing, float64.

    camera : Camera, depth : (H, W) view depth (inf: nothing there), normals : (H, W, 3)
    unit view-space normals facing the eye (0 where nothing), covered : (H, W) bool,
    depth_source, normal_source : what they were read from.
    """

    camera: cameras.Camera
    depth: np.ndarray
    normals: np.ndarray
    covered: np.ndarray
    depth_source: str = "linear"
    normal_source: str = "geometric"

    @property
    def height(self) -> int:
        return self.depth.shape[0]

    @property
    def width(self) -> int:
        return self.depth.shape[1]

    @property
    def half_height(self) -> float:
        """tan(fov_y / 2): the image's half-height at view depth 1."""
        return self.camera.tan_half_fov

    @property
    def half_width(self) -> float:
        return self.camera.tan_half_fov * self.camera.aspect

    def pixel_size(self, depth):
        """The side of one pixel at view depth ``depth`` (array): 2 d tan(fov/2) / H (pixels
        are square: aspect = W / H)."""
        return np.asarray(depth) * (2.0 * self.half_height / self.height)

    def rays(self, x, y) -> np.ndarray:
        """(..., 3) view-space vectors with z = -1 through continuous pixel coordinates x
        (column), y (row): the position at view depth d is d times this."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        return np.stack([(2.0 * x / self.width - 1.0) * self.half_width,
                         (1.0 - 2.0 * y / self.height) * self.half_height,
                         -np.ones_like(x)], axis=-1)

    def centres(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) (k,) float64 continuous coordinates of the centres of flat ``pixels``."""
        r, c = np.divmod(np.asarray(pixels, dtype=np.int64), self.width)
        return c + 0.5, r + 0.5

    def positions(self, pixels: np.ndarray) -> np.ndarray:
        """(k, 3) view-space positions reconstructed at the centres of ``pixels`` from their
        depths (non-finite where a pixel sees nothing)."""
        x, y = self.centres(pixels)
        d = self.depth.reshape(-1)[pixels]
        return self.rays(x, y) * d[:, None]

    def project(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """View-space points q (..., 3) -> continuous pixel coordinates x, y and view depth d
        (each (...)); x, y are NaN at or behind the eye plane (d <= 0)."""
        q = np.asarray(q, dtype=np.float64)
        d = -q[..., 2]
        front = d > 0
        safe = np.where(front, d, 1.0)
        x = (q[..., 0] / (safe * self.half_width) + 1.0) * (0.5 * self.width)
        y = (1.0 - q[..., 1] / (safe * self.half_height)) * (0.5 * self.height)
        return np.where(front, x, np.nan), np.where(front, y, np.nan), d

    def lookup(self, x, y) -> np.ndarray:
        """Flat index of the pixel containing continuous coordinates (x, y) (arrays), -1 off
        the image (or NaN): the point-sampled lookup a shader's texel fetch makes."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        c = np.where(inside, np.floor(np.where(inside, x, 0.0)), 0).astype(np.int64)
        r = np.where(inside, np.floor(np.where(inside, y, 0.0)), 0).astype(np.int64)
        return np.where(inside, r * self.width + c, -1)

    def depth_at(self, index: np.ndarray) -> np.ndarray:
        """View depth of flat pixel ``index`` (array), inf where -1 (off the image)."""
        flat = self.depth.reshape(-1)
        return np.where(index >= 0, flat[np.maximum(index, 0)], np.inf)

    def normals_at(self, pixels: np.ndarray) -> np.ndarray:
        return self.normals.reshape(-1, 3)[pixels]

    def facet_depth(self, index: np.ndarray, x, y) -> np.ndarray:
        """View depth under continuous coordinates (x, y) (arrays) of the facet of flat pixel
        ``index`` (same shape; -1 or a pixel that sees nothing: inf): the plane through the
        pixel's reconstructed position with its normal, d = (n . P) / (n . ray(x, y)), exact
        for a planar surface; the pixel's own depth where the facet is seen edge-on or from
        behind (n . ray >= 0)."""
        index = np.asarray(index)
        q = np.maximum(index, 0)
        d_q = np.where(index >= 0, self.depth.reshape(-1)[q], np.inf)
        ok = np.isfinite(d_q)
        cx, cy = self.centres(q)
        n = self.normals.reshape(-1, 3)[q]
        p_q = self.rays(cx, cy) * np.where(ok, d_q, 0.0)[..., None]
        facing = np.einsum("...j,...j->...", n, self.rays(x, y))
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.einsum("...j,...j->...", n, p_q) / facing
        return np.where(ok & (facing < 0) & (d > 0), d, d_q)


def check_pixels(frame: Frame, pixels: np.ndarray, method: str) -> np.ndarray:
    """``pixels`` (k,) as int64 flat indices of covered pixels; InputError otherwise (a
    view's sample-stream ids are its pixel indices r * W + c)."""
    pixels = np.asarray(pixels)
    if pixels.ndim != 1 or not np.issubdtype(pixels.dtype, np.integer):
        raise InputError(f"--method {method}: pixels must be (k,) integers")
    pixels = pixels.astype(np.int64)
    n = frame.height * frame.width
    if len(pixels) and (pixels.min() < 0 or pixels.max() >= n):
        raise InputError(f"--method {method}: the points' ids are not pixel indices of the "
                         f"{frame.width}x{frame.height} G-buffer")
    if not frame.covered.reshape(-1)[pixels].all():
        raise InputError(f"--method {method}: a point lies on a pixel the G-buffer does not "
                         "cover")
    return pixels


#: float32's relative spacing (one ulp at most 2^-23 of the value)
F32_SPACING = 2.0 ** -23


def depth_step(frame: Frame, depth) -> np.ndarray:
    """The view-depth change of one float32 step of the frame's depth buffer at view depth
    ``depth`` (array, finite): what a depth comparison must tolerate before it means
    anything.  Linear depth: one ulp of d; a hardware depth z(d): one ulp of z divided by
    |dz/dd| (``hardware_depth``'s forms: |dz/dd| = 2 f n / ((f - n) d^2) for OpenGL,
    f n / ((f - n) d^2) for Direct3D and reversed-Z), which grows as d^2: the depth
    buffer's famous loss of precision far from the near plane."""
    d = np.asarray(depth, dtype=np.float64)
    if frame.depth_source == "linear":
        return d * F32_SPACING
    n, f = frame.camera.near, frame.camera.far
    z = cameras.hardware_depth(np.where(np.isfinite(d), d, f), n, f, frame.depth_source)
    ulp = np.maximum(np.abs(z), np.finfo(np.float32).tiny) * F32_SPACING
    slope = (2.0 if frame.depth_source == "opengl" else 1.0) * f * n / ((f - n) * d * d)
    return ulp / slope
