"""The pinhole camera of ``aobake view``: one primary ray per pixel centre, the matrices that
say where a world point lands, and the depth values a renderer's depth buffer would hold.

Conventions (written into every output's metadata through ``Camera.record``):

- World and view space are right-handed.  View space: the eye at the origin, looking down
  -Z, +Y up, +X right (OpenGL's convention, and glTF's for camera nodes).
- Matrices are (4, 4) float64 numpy arrays (row-major storage) for *column* vectors:
  ``v = M @ [p, 1]``.  ``world_to_view()`` is rigid; ``view_to_clip()`` is OpenGL's
  perspective (``gluPerspective``), NDC x, y, z in [-1, 1], NDC +y up.
- ``fov_y`` is the *vertical* field of view in degrees: the angle between the top and bottom
  edges of the image (not pixel centres).  aspect = width / height.
- Pixels: (row r, column c), image origin top-left (row 0 = top), pixel (r, c) covers
  [c, c + 1) x [r, r + 1) in continuous pixel coordinates (x = column, y = row), its centre is
  (c + 0.5, r + 0.5), and flattened arrays are row-major: index = r * width + c.
  NDC (x, y) -> pixel: x = (x_ndc + 1) / 2 * width, y = (1 - y_ndc) / 2 * height.
- Depth: *view depth* = -z_view, the distance along the view axis (not along the ray),
  positive in front of the eye.  ``hardware_depth`` turns it into a depth-buffer value.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from aobake import constants
from aobake.errors import InputError

#: Image size used when none is given (``default_camera``, glTF cameras).
DEFAULT_SIZE = (960, 540)
#: Largest image side and pixel count accepted (a 64 M-pixel image's rays are 3 GB already).
MAX_SIDE = 16384
MAX_PIXELS = 2 ** 26
#: Up vectors within this angle (radians, as its sine) of the view direction are rejected:
#: the right vector cross(forward, up) would be mostly rounding error.
PARALLEL_SINE = 1e-6
#: Depth-buffer conventions of ``hardware_depth`` / ``linearize_depth`` (``aobake.constants``).
DEPTH_CONVENTIONS = constants.DEPTH_CONVENTIONS
#: The text ``Camera.record`` writes for each convention (one name per concept).
MATRIX_LAYOUT = "row-major, column vectors (v = M @ [p, 1])"
HANDEDNESS = "right-handed, looks down -Z, +Y up"
PIXEL_CENTRE = "+0.5"
IMAGE_ORIGIN = "top-left (row 0 = top)"
DEPTH = "view depth = -z_view, along the view axis, positive in front"
#: Up axis -> (right, up, toward the viewer) world axes of the "front" view that
#: ``default_camera`` orbits: the y-up frame (+X, +Y, +Z) turned by the rotation that takes +Y
#: to the up axis (z-up: about +X, giving Blender's front view; x-up: about +Z).
UP_AXES = {
    "x": ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "y": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "z": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
}
#: ``default_camera``'s viewing direction from the target, in (right, up, toward) terms.
THREE_QUARTER = (1.0, 0.6, 1.2)
#: ``default_camera``'s margin: the bounding sphere fills 1 / 1.05 of the smaller half-fov.
FRAME_MARGIN = 1.05


def _vector(name: str, value) -> np.ndarray:
    """``value`` as a (3,) float64 array of finite numbers; InputError naming ``name``."""
    try:
        array = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"camera: {name} must be 3 numbers, got {value!r}") from None
    if array.shape != (3,):
        raise InputError(f"camera: {name} must be 3 numbers, got {array.size}")
    if not np.isfinite(array).all():
        raise InputError(f"camera: {name} must be finite, got {array.tolist()}")
    return array


def check_size(size) -> tuple[int, int]:
    """(width, height) as positive ints within MAX_SIDE and MAX_PIXELS; InputError otherwise."""
    try:
        width, height = size
    except (TypeError, ValueError):
        raise InputError(f"camera: size must be (width, height), got {size!r}") from None
    for value in (width, height):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise InputError(f"camera: size must be two positive integers (width, height), "
                             f"got {width!r}x{height!r}")
    width, height = int(width), int(height)
    if max(width, height) > MAX_SIDE:
        raise InputError(f"camera: size {width}x{height} exceeds {MAX_SIDE} pixels per side")
    if width * height > MAX_PIXELS:
        raise InputError(f"camera: size {width}x{height} = {width * height} pixels exceeds "
                         f"2^26 = {MAX_PIXELS}")
    return width, height


def _clip_plane(name: str, value) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"camera: {name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"camera: {name} must be positive and finite, got {value}")
    return value


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera; construct it with ``look_at`` (validated there and here).

    eye : (3,) float64 world position.  target : (3,) float64 a world point on the view axis
    (the look-at point; for glTF cameras the point one unit in front of the eye).
    up : (3,) float64 unit, orthogonal to the view direction (the given up vector with its
    component along the view removed), the image's upward direction.
    fov_y : vertical field of view, degrees, in (0, 180).  width, height : pixels.
    near, far : clip planes, view depths in scene units, 0 < near < far; None = not set yet
    (``fit_clip`` sets both); only ``view_to_clip`` needs them.
    name : e.g. the glTF camera name, or None.
    The arrays are read-only copies; ``dataclasses.replace`` re-validates.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y: float
    width: int
    height: int
    near: float | None = None
    far: float | None = None
    name: str | None = None

    def __post_init__(self):
        eye = _vector("look-from", self.eye)
        target = _vector("look-at", self.target)
        up = _vector("up", self.up)
        with np.errstate(over="ignore"):  # an overflow is the error below, not a warning
            view = target - eye
        distance = math.hypot(*view)  # no overflow of the squares (np.linalg.norm's)
        if not distance > 0:
            raise InputError("camera: look-from equals look-at")
        if not math.isfinite(distance):
            raise InputError(f"camera: look-from {eye.tolist()} and look-at "
                             f"{target.tolist()} are too far apart: their distance is "
                             "beyond float64's range")
        forward = view / distance
        up_length = math.hypot(*up)  # no overflow: an up of 1e300 is a direction too
        if not up_length > 0:
            raise InputError("camera: up vector is zero")
        up = up / up_length
        if np.linalg.norm(np.cross(forward, up)) < PARALLEL_SINE:
            raise InputError(f"camera: up {up.tolist()} is parallel to the view direction "
                             f"{forward.tolist()}")
        up = up - np.dot(up, forward) * forward  # Gram-Schmidt: the image's up, exactly
        up = up / np.linalg.norm(up)
        fov = self.fov_y
        if isinstance(fov, bool) or not isinstance(fov, (int, float, np.integer, np.floating)):
            raise InputError(f"camera: fov_y must be a number of degrees, got {fov!r}")
        fov = float(fov)
        if not (math.isfinite(fov) and 0.0 < fov < 180.0):
            raise InputError(f"camera: fov_y must be in (0, 180) degrees, got {fov}")
        width, height = check_size((self.width, self.height))
        near, far = _clip_plane("near", self.near), _clip_plane("far", self.far)
        if near is not None and far is not None and not near < far:
            raise InputError(f"camera: near ({near}) must be less than far ({far})")
        if self.name is not None and not isinstance(self.name, str):
            raise InputError(f"camera: name must be text, got {self.name!r}")
        for key, value in (("eye", eye), ("target", target), ("up", up)):
            value.setflags(write=False)
            object.__setattr__(self, key, value)
        for key, value in (("fov_y", fov), ("width", width), ("height", height),
                           ("near", near), ("far", far)):
            object.__setattr__(self, key, value)

    @property
    def forward(self) -> np.ndarray:
        """(3,) float64 unit view direction (view -Z in world space)."""
        view = self.target - self.eye
        return view / np.linalg.norm(view)

    @property
    def right(self) -> np.ndarray:
        """(3,) float64 unit, forward x up (view +X in world space)."""
        return np.cross(self.forward, self.up)

    @property
    def aspect(self) -> float:
        """width / height."""
        return self.width / self.height

    @property
    def tan_half_fov(self) -> float:
        """tan(fov_y / 2): the half-height of the image at view depth 1."""
        return math.tan(math.radians(self.fov_y) / 2.0)

    def _rotation(self) -> np.ndarray:
        """(3, 3) float64 world -> view rotation: rows are right, up, -forward."""
        return np.stack([self.right, self.up, -self.forward])

    def world_to_view(self) -> np.ndarray:
        """(4, 4) float64 rigid world -> view matrix, column vectors (``v = M @ [p, 1]``).

        View space is right-handed: eye at the origin, looking down -Z, +Y up, +X right.
        """
        rotation = self._rotation()
        matrix = np.eye(4)
        matrix[:3, :3] = rotation
        matrix[:3, 3] = -rotation @ self.eye
        return matrix

    def view_to_clip(self) -> np.ndarray:
        """(4, 4) float64 OpenGL perspective (``gluPerspective``), column vectors.

        Clip w = -z_view (the view depth); after the divide, NDC x, y in [-1, 1] span the
        image (NDC +y = top) and NDC z = -1 at ``near``, +1 at ``far``.
        InputError when near/far are not set (see ``fit_clip``).
        """
        if self.near is None or self.far is None:
            raise InputError("camera: near/far clip planes are not set (fit_clip sets them)")
        n, f = self.near, self.far
        focal = 1.0 / self.tan_half_fov
        return np.array([
            [focal / self.aspect, 0.0, 0.0, 0.0],
            [0.0, focal, 0.0, 0.0],
            [0.0, 0.0, (f + n) / (n - f), 2.0 * f * n / (n - f)],
            [0.0, 0.0, -1.0, 0.0],
        ])

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Primary rays through pixel centres, no jitter.

        Returns origins : (H*W, 3) float64, every row the eye, and directions : (H*W, 3)
        float64 unit; row r * W + c goes through the centre (c + 0.5, r + 0.5) of pixel
        (row r, column c), row 0 at the top.
        """
        half_h = self.tan_half_fov
        half_w = half_h * self.aspect
        # NDC of pixel centres; NDC y is up and row 0 is the top, hence 1 - ...
        x = (np.arange(self.width) + 0.5) * (2.0 / self.width) - 1.0
        y = 1.0 - (np.arange(self.height) + 0.5) * (2.0 / self.height)
        view = np.empty((self.height, self.width, 3))
        view[..., 0] = (x * half_w)[None, :]
        view[..., 1] = (y * half_h)[:, None]
        view[..., 2] = -1.0
        view = view.reshape(-1, 3)
        directions = view @ self._rotation()  # rows: R^T @ d, view -> world
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.repeat(self.eye[None, :], len(directions), axis=0)
        return origins, directions

    def directions_through(self, pixels) -> np.ndarray:
        """(n, 3) float64 unit world directions of the primary rays through continuous pixel
        coordinates ``pixels`` (n, 2) float (x = column, y = row, origin at the image's
        top-left corner: pixel (r, c) covers [c, c + 1) x [r, r + 1)), as ``pixel_rays``
        makes them: through (c + 0.5, r + 0.5) the same direction, bit for bit.  A box
        filter's jittered positions (``aobake.targets.view``) go through here."""
        pixels = np.asarray(pixels, dtype=np.float64)
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise InputError(f"camera: pixels must be (n, 2), got {pixels.shape}")
        half_h = self.tan_half_fov
        half_w = half_h * self.aspect
        view = np.empty((len(pixels), 3))
        # the arithmetic of pixel_rays: x (2 / W) - 1 and 1 - y (2 / H)
        view[:, 0] = (pixels[:, 0] * (2.0 / self.width) - 1.0) * half_w
        view[:, 1] = (1.0 - pixels[:, 1] * (2.0 / self.height)) * half_h
        view[:, 2] = -1.0
        directions = view @ self._rotation()
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        return directions

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Where world ``points`` (n, 3) float land in the image.

        Returns pixels : (n, 2) float64 continuous pixel coordinates (x = column, y = row,
        origin at the image's top-left corner, pixel centres at +0.5; values outside
        [0, W] x [0, H] are off-image), NaN for points at or behind the eye plane
        (depth <= 0); and depth : (n,) float64 view depth (-z_view, positive in front).
        Equals ``view_to_clip() @ world_to_view()`` and the NDC -> pixel map of the module
        docstring, without needing near/far.
        """
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"camera: points must be (n, 3), got {points.shape}")
        view = (points - self.eye) @ self._rotation().T
        depth = -view[:, 2]
        in_front = depth > 0
        safe = np.where(in_front, depth, 1.0)
        half_h = self.tan_half_fov
        x_ndc = view[:, 0] / (safe * half_h * self.aspect)
        y_ndc = view[:, 1] / (safe * half_h)
        pixels = np.stack([(x_ndc + 1.0) * (0.5 * self.width),
                           (1.0 - y_ndc) * (0.5 * self.height)], axis=1)
        pixels[~in_front] = np.nan
        return pixels, depth

    def record(self) -> dict:
        """JSON-able description with its conventions, for reports and image metadata.

        Same keys always; ``view_to_clip``, ``near``, ``far`` are None until set.
        """
        clip = None if self.near is None or self.far is None else self.view_to_clip().tolist()
        return {
            "name": self.name,
            "eye": self.eye.tolist(),
            "target": self.target.tolist(),
            "up": self.up.tolist(),
            "forward": self.forward.tolist(),
            "fov_y_deg": self.fov_y,
            "aspect": self.aspect,
            "width": self.width,
            "height": self.height,
            "near": self.near,
            "far": self.far,
            "world_to_view": self.world_to_view().tolist(),
            "view_to_clip": clip,
            "matrix_layout": MATRIX_LAYOUT,
            "handedness": HANDEDNESS,
            "projection": "OpenGL perspective, NDC z in [-1, 1], NDC +y up",
            "pixel_centre": PIXEL_CENTRE,
            "image_origin": IMAGE_ORIGIN,
            "depth": DEPTH,
        }


def look_at(look_from, look_at, up, fov_y, size=DEFAULT_SIZE, near=None, far=None,
            name=None) -> Camera:
    """A camera at ``look_from`` (3,) looking at ``look_at`` (3,), with ``up`` (3,) (any
    length, not parallel to the view) showing as up in the image; ``fov_y`` vertical degrees;
    ``size`` (width, height) pixels; ``near``/``far`` view depths or None (``fit_clip``).

    InputError with a message naming the problem: equal look-from and look-at, zero or
    parallel up, non-finite numbers, fov outside (0, 180), a size that is not two positive
    ints of at most MAX_SIDE each and MAX_PIXELS in all, bad clip planes.
    """
    width, height = check_size(size)
    return Camera(eye=look_from, target=look_at, up=up, fov_y=fov_y, width=width,
                  height=height, near=near, far=far, name=name)


def _corners(lo, hi) -> np.ndarray:
    lo, hi = _vector("bounding box low corner", lo), _vector("bounding box high corner", hi)
    if (lo > hi).any():
        raise InputError(f"camera: bounding box low {lo.tolist()} exceeds high {hi.tolist()}")
    pick = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=bool)
    return np.where(pick, hi, lo)


def fit_clip(camera: Camera, lo, hi) -> Camera:
    """``camera`` with near/far fitted to the axis-aligned box [lo, hi] ((3,) each).

    The rule (view depths of the box's 8 corners; a linear function's extremes over a box are
    at corners):
    - far = 1.01 x the largest corner depth; if no corner is in front of the eye (the box is
      behind it), 1.01 x the distance to the farthest corner; 1 for a point box at the eye.
    - near = max(0.99 x the smallest corner depth, far x 1e-4) when the whole box is in
      front; far x 1e-4 when it reaches the eye plane (the eye inside or beside the box):
      the depth buffer then keeps ~4 decades of range, and geometry closer than that is
      clipped (it is nearer than 1e-4 of the scene's depth).
    The 1% margins keep the box's own faces off the clip planes.
    """
    corners = _corners(lo, hi)
    with np.errstate(over="ignore"):  # beyond float64: the error below, not a warning
        offsets = corners - camera.eye
        depth = offsets @ camera.forward
    farthest = max(math.hypot(*row) for row in offsets)  # hypot: no overflow of squares
    if not (np.isfinite(depth).all() and math.isfinite(farthest)):
        raise InputError(f"camera: the eye {camera.eye.tolist()} is too far from the scene "
                         f"(box {np.asarray(lo).tolist()} - {np.asarray(hi).tolist()}): "
                         "their distance is beyond float64's range")
    if depth.max() > 0:
        far = 1.01 * float(depth.max())
    elif farthest > 0:
        far = 1.01 * farthest
    else:
        far = 1.0
    near = far * 1e-4
    if depth.min() > 0:
        near = max(0.99 * float(depth.min()), near)
    return replace(camera, near=near, far=far)


def default_camera(lo, hi, size=DEFAULT_SIZE, fov_y: float = 40.0, up_axis: str = "y",
                   name: str | None = None) -> Camera:
    """A three-quarter view of the box [lo, hi] ((3,) each), near/far by ``fit_clip``.

    Looks at the box centre from the direction THREE_QUARTER = (1, 0.6, 1.2) normalised, in
    (right, up, toward-the-viewer) terms of ``up_axis`` ('x', 'y' or 'z'; UP_AXES gives the
    frames: y-up is +X right, +Z toward; z-up is +X right, -Y toward), from the nearest
    distance (to 0.1%, by bisection) at which every corner of the box lies within 1 / 1.05
    of the image's half-width and half-height, in front of the eye.  The bounding sphere
    filling 1 / 1.05 of the smaller half-fov is the bisection's far end: a flat scene (a
    floor under objects) then fills the frame instead of a tenth of it.
    """
    if up_axis not in UP_AXES:
        raise InputError(f"camera: up axis must be one of {sorted(UP_AXES)}, got {up_axis!r}")
    corners = _corners(lo, hi)
    width, height = check_size(size)
    lo, hi = corners[0], corners[7]
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo)) or 1.0
    probe = look_at([0, 0, 1], [0, 0, 0], [0, 1, 0], fov_y, (width, height))  # validates fov
    half_y = math.radians(probe.fov_y) / 2.0
    half_x = math.atan(math.tan(half_y) * probe.aspect)
    distance = FRAME_MARGIN * radius / math.sin(min(half_x, half_y))
    right, up, toward = (np.array(axis) for axis in UP_AXES[up_axis])
    direction = np.array(THREE_QUARTER) @ np.stack([right, up, toward])
    direction /= np.linalg.norm(direction)

    def fits(d: float) -> bool:
        cam = look_at(centre + d * direction, centre, up, probe.fov_y, (width, height))
        pixels, depth = cam.project(corners)
        if not (depth > 0).all():
            return False
        x = np.abs(pixels[:, 0] / width * 2.0 - 1.0)
        y = np.abs(pixels[:, 1] / height * 2.0 - 1.0)
        return bool(max(x.max(), y.max()) <= 1.0 / FRAME_MARGIN)

    near_end, far_end = 0.0, distance
    while far_end - near_end > 1e-3 * distance:
        middle = 0.5 * (near_end + far_end)
        near_end, far_end = (near_end, middle) if fits(middle) else (middle, far_end)
    camera = look_at(centre + far_end * direction, centre, up, probe.fov_y, (width, height),
                     name=name)
    return fit_clip(camera, lo, hi)


def linear_depth(view_z):
    """View depth (positive in front of the eye) from view-space z: -z_view."""
    return -np.asarray(view_z, dtype=np.float64)


def _check_depth_range(near, far, convention):
    if convention not in DEPTH_CONVENTIONS:
        raise InputError(f"depth convention must be one of {list(DEPTH_CONVENTIONS)}, "
                         f"got {convention!r}")
    near, far = _clip_plane("near", near), _clip_plane("far", far)
    if near is None or far is None or not near < far:
        raise InputError(f"depth: need 0 < near < far, got near={near}, far={far}")
    return near, far


def hardware_depth(depth, near, far, convention: str = "opengl") -> np.ndarray:
    """Depth-buffer values (n,) float64 from view depths ``depth`` (n,) (positive; non-finite =
    no hit), for clip planes ``near`` < ``far``.

    - 'opengl': NDC z of ``Camera.view_to_clip`` after the divide,
      (f + n)/(f - n) - 2 f n / ((f - n) d): -1 at near, +1 at far.
    - 'd3d': z/w of Direct3D's perspective (``XMMatrixPerspectiveFovRH``),
      f (d - n) / ((f - n) d): 0 at near, 1 at far.
    - 'reversed': reversed-Z, the d3d form with near and far swapped,
      n (f - d) / ((f - n) d): 1 at near, 0 at far.
    No clipping: depths outside [near, far] map outside the range, as the formula says.
    A non-finite depth (no hit) gets what a cleared buffer holds, the far value (1, 1, 0),
    not the formula's limit at infinity.  InputError for a finite depth <= 0.
    """
    near, far = _check_depth_range(near, far, convention)
    depth = np.asarray(depth, dtype=np.float64)
    hit = np.isfinite(depth)
    if (depth[hit] <= 0).any():
        raise InputError(f"depth: view depths must be positive, got {int((depth[hit] <= 0).sum())} "
                         "values <= 0")
    d = np.where(hit, depth, far)
    span = far - near
    if convention == "opengl":
        value = (far + near) / span - 2.0 * far * near / (span * d)
        cleared = 1.0
    elif convention == "d3d":
        value = far * (d - near) / (span * d)
        cleared = 1.0
    else:
        value = near * (far - d) / (span * d)
        cleared = 0.0
    return np.where(hit, value, cleared)


def linearize_depth(hardware, near, far, convention: str = "opengl") -> np.ndarray:
    """View depths (n,) float64 from depth-buffer values ``hardware`` (n,): the inverse of
    ``hardware_depth``, as an engine linearises its buffer.

    A cleared value gives ``far`` (not infinity: the buffer does not tell a hit at the far
    plane from no hit).  Values past the one for infinite depth give inf or a negative depth
    (behind the eye), as the formula says; NaN stays NaN.
    - 'opengl': 2 f n / ((f + n) - z (f - n));  'd3d': f n / (f - z (f - n));
    - 'reversed': f n / (n + z (f - n)).
    """
    near, far = _check_depth_range(near, far, convention)
    z = np.asarray(hardware, dtype=np.float64)
    span = far - near
    if convention == "opengl":
        numerator, denominator = 2.0 * far * near, (far + near) - z * span
    elif convention == "d3d":
        numerator, denominator = far * near, far - z * span
    else:
        numerator, denominator = far * near, near + z * span
    with np.errstate(divide="ignore"):
        return numerator / denominator


def parse_vector(text: str) -> np.ndarray:
    """(3,) float64 from "X,Y,Z" (spaces allowed); InputError on anything else."""
    parts = str(text).split(",")
    try:
        if len(parts) != 3:
            raise ValueError
        vector = np.array([float(part) for part in parts])
    except ValueError:
        raise InputError(f"vector must be X,Y,Z (three numbers), got {text!r}") from None
    if not np.isfinite(vector).all():
        raise InputError(f"vector must be finite, got {text!r}")
    return vector


_SIZE = re.compile(r"\s*(\d+)\s*[xX]\s*(\d+)\s*")


def parse_size(text: str) -> tuple[int, int]:
    """(width, height) from "WxH", e.g. "1920x1080"; InputError unless both are positive
    integers within MAX_SIDE per side and MAX_PIXELS in all."""
    match = _SIZE.fullmatch(str(text))
    if match is None:
        raise InputError(f"size must be WxH (two positive integers, e.g. 1920x1080), "
                         f"got {text!r}")
    return check_size((int(match.group(1)), int(match.group(2))))


# ---- glTF cameras ------------------------------------------------------------------------

def _gltf_json(path: Path) -> dict:
    """The JSON document of a .gltf file or a GLB container (detected by its magic)."""
    from aobake.outputs.gltf import MAGIC, read_gltf

    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
    if magic != MAGIC and path.suffix.lower() not in (".gltf", ".glb"):
        raise InputError(f"{path}: a camera is read from a glTF file (.gltf or .glb); this "
                         f"is a {path.suffix or 'file without extension'}, which has no "
                         "cameras (--camera needs a glTF)")
    return read_gltf(path)[0]


def _numbers(path, what, value, count) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != count
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise InputError(f"{path}: {what} must be {count} numbers")
    array = np.array(value, dtype=np.float64)
    if not np.isfinite(array).all():
        raise InputError(f"{path}: {what} must be finite")
    return array


def _local_matrix(path, index, node) -> np.ndarray:
    """(4, 4) float64 node -> parent matrix, column vectors: ``matrix`` (stored column-major
    in glTF) or T @ R @ S from translation, rotation (unit quaternion [x, y, z, w]), scale."""
    if "matrix" in node:
        return _numbers(path, f"node {index} matrix", node["matrix"], 16).reshape(4, 4).T
    t = _numbers(path, f"node {index} translation", node.get("translation", [0, 0, 0]), 3)
    q = _numbers(path, f"node {index} rotation", node.get("rotation", [0, 0, 0, 1]), 4)
    s = _numbers(path, f"node {index} scale", node.get("scale", [1, 1, 1]), 3)
    length = np.linalg.norm(q)
    if not length > 0:
        raise InputError(f"{path}: node {index} rotation is a zero quaternion")
    x, y, z, w = q / length
    rotation = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * s[None, :]
    matrix[:3, 3] = t
    return matrix


def gltf_cameras(path) -> dict[str, dict]:
    """The camera nodes of a .gltf or .glb file, by key, in node order.

    Key: the camera's name, else the node's name, else "camera<k>" (k counts camera nodes
    from 0); a key already taken falls through to the next choice.  Each value:
    {"type": "perspective" | "orthographic" | ..., "node": node index, "eye": (3,),
    "forward": (3,) unit, "up": (3,) float64 (the node's -Z and +Y in world space, the world
    matrix composed through the node's parents), "yfov_deg", "aspect_ratio", "znear",
    "zfar" (None where absent or not perspective)}.
    InputError naming the file for an unreadable file, bad GLB header or lengths, malformed
    nodes or cameras, a node cycle, or no camera at all.
    """
    path = Path(path)
    document = _gltf_json(path)
    nodes, cameras = document.get("nodes", []), document.get("cameras", [])
    if not isinstance(nodes, list) or not isinstance(cameras, list):
        raise InputError(f"{path}: invalid glTF: nodes and cameras must be arrays")
    parent: dict[int, int] = {}
    for index, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise InputError(f"{path}: node {index} is not an object")
        for child in node.get("children", []):
            if not isinstance(child, int) or not 0 <= child < len(nodes):
                raise InputError(f"{path}: node {index} has a bad child {child!r}")
            if child in parent:
                raise InputError(f"{path}: node {child} has two parents")
            parent[child] = index
    found: dict[str, dict] = {}
    for index, node in enumerate(nodes):
        if "camera" not in node:
            continue
        which = node["camera"]
        if not isinstance(which, int) or not 0 <= which < len(cameras):
            raise InputError(f"{path}: node {index} refers to a missing camera {which!r}")
        camera = cameras[which]
        if not isinstance(camera, dict):
            raise InputError(f"{path}: camera {which} is not an object")
        world, seen, at = np.eye(4), set(), index
        while at is not None:  # world = parent's world @ local, up to the root
            if at in seen:
                raise InputError(f"{path}: node {at} is its own ancestor")
            seen.add(at)
            world = _local_matrix(path, at, nodes[at]) @ world
            at = parent.get(at)
        eye = world[:3, 3].copy()
        forward = -world[:3, 2]
        length = np.linalg.norm(forward)
        if not (np.isfinite(world).all() and length > 0):
            raise InputError(f"{path}: node {index}'s transform is singular")
        kind = camera.get("type")
        params = {"type": kind, "node": index, "eye": eye, "forward": forward / length,
                  "up": world[:3, 1].copy(), "yfov_deg": None, "aspect_ratio": None,
                  "znear": None, "zfar": None}
        if kind == "perspective":
            lens = camera.get("perspective")
            if not isinstance(lens, dict):
                raise InputError(f"{path}: camera {which} has no perspective parameters")
            for key in ("yfov", "znear", "aspectRatio", "zfar"):
                value = lens.get(key)
                required = key in ("yfov", "znear")
                if value is None and not required:
                    continue
                if (isinstance(value, bool) or not isinstance(value, (int, float))
                        or not (math.isfinite(value) and value > 0)):
                    raise InputError(f"{path}: camera {which} {key} must be a positive "
                                     f"number, got {value!r}")
            params.update(yfov_deg=math.degrees(lens["yfov"]), znear=float(lens["znear"]),
                          aspect_ratio=lens.get("aspectRatio"), zfar=lens.get("zfar"))
        for key in (camera.get("name"), node.get("name"), f"camera{len(found)}",
                    f"camera{len(found)}#node{index}"):
            if isinstance(key, str) and key not in found:
                found[key] = params
                break
    if not found:
        raise InputError(f"{path}: no cameras in the file")
    return found


def gltf_camera(path, name: str | None = None, size=None) -> Camera:
    """The camera ``name`` (a key of ``gltf_cameras``; None = the first) of a glTF file.

    glTF cameras look down -Z of their node with +Y up; yfov (radians) becomes fov_y
    (degrees), znear/zfar near/far (far None when the file gives none: infinite projection;
    ``fit_clip`` sets both).  ``size`` (width, height): None = height 540 and width
    round(540 x aspectRatio), or DEFAULT_SIZE without aspectRatio.  A given size whose
    aspect differs from aspectRatio keeps yfov (the horizontal fov follows the size).
    InputError: unknown name (listing the available ones), orthographic or unknown camera
    types, and what ``gltf_cameras`` and ``look_at`` reject (prefixed by the file).
    """
    path = Path(path)
    cameras = gltf_cameras(path)
    key = next(iter(cameras)) if name is None else name
    if key not in cameras:
        raise InputError(f"{path}: no camera named {name!r}; available: "
                         + ", ".join(repr(k) for k in cameras))
    params = cameras[key]
    if params["type"] == "orthographic":
        raise InputError(f"{path}: camera {key!r} is orthographic; orthographic cameras are "
                         "not supported")
    if params["type"] != "perspective":
        raise InputError(f"{path}: camera {key!r} has unknown type {params['type']!r}")
    if size is None:
        ratio = params["aspect_ratio"]
        height = DEFAULT_SIZE[1]
        size = DEFAULT_SIZE if ratio is None else (max(1, round(height * ratio)), height)
    try:
        return look_at(params["eye"], params["eye"] + params["forward"], params["up"],
                       params["yfov_deg"], size, near=params["znear"], far=params["zfar"],
                       name=key)
    except InputError as error:
        raise InputError(f"{path}: camera {key!r}: {error}") from None
