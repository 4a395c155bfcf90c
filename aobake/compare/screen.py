"""A camera view scored as screen-space AO: ``compare`` of a view EXR (the reference, from
``aobake view``) against another view EXR or another tool's image of the same pixels.

What the per-texel metrics do not say about a view, ``aobake.screen.score`` does: the
covered pixels split into the interior and a band around the reference's depth edges
(silhouettes and occlusion boundaries, found from its depth, geometric normals and camera),
SSIM (Wang et al.'s settings), the error in units of the reference's stderr, and every
metric again after the best gain of the candidate's occlusion.  The reference's G-buffer
and camera come from the file itself; a file edited by hand is checked before it is used.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from aobake.errors import InputError
from aobake.outputs.values import Values
from aobake.screen import score as scoring
from aobake.screen.gbuffer import CHANNELS, GBuffer, camera_from_record

log = logging.getLogger(__name__)

#: the view-space channels the depth edges are found from
EDGE_CHANNELS = ("coverage", "depth", "Ng.X", "Ng.Y", "Ng.Z")
#: how far apart two views' rays may be and still be the same pixels, in pixels at the
#: nearest content (float noise of a record written and read back, a target elsewhere on
#: the same line of sight: the same rays)
SAME_RAYS_PX = 1e-3


def is_view(values: Values) -> bool:
    """Whether ``values`` were read from a camera view (an aobake view's metadata)."""
    return isinstance(values.metadata.get("camera"), dict)


def camera_of(values: Values):
    """The ``aobake.camera.Camera`` of a view file, checked against its image; InputError
    naming the file when the record is unusable."""
    record = values.metadata["camera"]
    try:
        cam = camera_from_record(record)
    except InputError as exc:
        raise InputError(f"{values.path}: {exc}") from None
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise InputError(f"{values.path}: its camera record cannot be used: {exc}") from None
    if (cam.height, cam.width) != values.value.shape:
        h, w = values.value.shape
        raise InputError(f"{values.path}: its camera record is {cam.width}x{cam.height} "
                         f"pixels, its image {w}x{h}")
    return cam


def _same_view(reference: Values, candidate: Values) -> None:
    """InputError when two view files are not views of the same camera: another image size,
    or rays that differ by more than ``SAME_RAYS_PX`` pixels (the eye's shift seen at the
    nearest content, the frame's turn, the field of view's change at the image's edge).  The
    records' ``target`` need not agree: a point anywhere on the same line of sight."""
    a, b = camera_of(reference), camera_of(candidate)
    if (a.width, a.height) != (b.width, b.height):
        raise InputError(f"{candidate.path}: is a {b.width}x{b.height} view, the reference "
                         f"{reference.path} {a.width}x{a.height}: render both from one camera")
    pixel = 2.0 * a.tan_half_fov / a.height  # a pixel's angle at the image's centre, rad
    nears = [c.near for c in (a, b) if c.near]  # the nearest content (the clip plane)
    near = min(nears) if nears else float(np.linalg.norm(a.target - a.eye))
    shift = {
        "eye": float(np.linalg.norm(np.subtract(a.eye, b.eye))) / near / pixel,
        "view direction": float(np.linalg.norm(np.subtract(a.forward, b.forward))) / pixel,
        "up": float(np.linalg.norm(np.subtract(a.up, b.up))) / pixel,
        "field of view": abs(a.tan_half_fov - b.tan_half_fov) / a.tan_half_fov
        * max(a.width, a.height) / 2.0,
    }
    for what, pixels in shift.items():
        if not pixels <= SAME_RAYS_PX:
            raise InputError(f"{candidate.path}: is another view than the reference "
                             f"{reference.path} (its {what} moves the rays by {pixels:.3g} "
                             "pixels): render both from one camera")


def edges_of(reference: Values, cam) -> tuple[np.ndarray | None, str | None]:
    """(H, W) bool depth edges of the reference's G-buffer, or (None, why) when the file has
    not the channels they are found from."""
    columns = reference.columns or {}
    missing = [name for name in EDGE_CHANNELS if name not in columns]
    if missing:
        return None, (f"{reference.path}: has no {', '.join(missing)}: no depth edges, every "
                      "covered pixel is scored as interior")
    channels = {name: np.asarray(columns[name], dtype=np.float32) for name in CHANNELS
                if name in columns}
    covered = channels["coverage"] > 0
    depth = channels["depth"][covered]
    if not (np.isfinite(depth).all() and (depth > 0).all()):
        bad = int(np.count_nonzero(~(np.isfinite(depth) & (depth > 0))))
        raise InputError(f"{reference.path}: {bad} covered pixels have a depth that is not "
                         "finite and positive")
    normals = np.stack([channels[f"Ng.{a}"][covered] for a in "XYZ"], axis=1)
    if not np.isfinite(normals).all():
        raise InputError(f"{reference.path}: Ng holds values that are not finite")
    frame = GBuffer(channels, cam).frame()
    return scoring.depth_edges(frame), None


def score_view(reference: Values, candidate: Values, mask: np.ndarray,
               stderr: np.ndarray | None = None) -> dict:
    """The screen-space scores of ``candidate`` against the view ``reference`` on ``mask``
    (H, W) bool (the pixels both cover): ``aobake.screen.score.score``'s record plus the
    band width, the edge tolerance and the pixel counts, and ``notes``.  ``stderr`` (H, W)
    is the error z is measured in (compare's: the reference's, or combined with the
    candidate's); None: the reference's."""
    cam = camera_of(reference)
    if is_view(candidate):
        _same_view(reference, candidate)
    edges, why = edges_of(reference, cam)
    notes = [] if why is None else [why]
    stderr = reference.stderr if stderr is None else stderr
    if stderr is not None and not (stderr[mask] > 0).any():
        stderr = None  # a method without noise (an approximation): no stderr units
    record = scoring.score(reference.value, candidate.value, mask,
                           edges=None if edges is None else edges & mask, stderr=stderr)
    for region in record["regions"].values():
        for values in region.values():
            for key, value in values.items():  # strict JSON: an identical region's psnr
                if isinstance(value, float) and not math.isfinite(value):
                    values[key] = None
    record.update(band_pixels=scoring.BAND, edge_tolerance=scoring.EDGE_TOLERANCE,
                  edge_pixels=None if edges is None else int((edges & mask).sum()),
                  notes=notes)
    log.info("scored a view of %d pixels: best gain %.4g", int(mask.sum()), record["gain"])
    return record


def format_screen(record: dict) -> list[str]:
    """The lines of the human summary for a view's scores."""
    def num(value, spec):
        width = int(spec.lstrip("+").split(".")[0])
        return f"{'-':>{width}}" if value is None else format(value, spec)

    lines = [f"  screen-space scores (depth-edge band {record['band_pixels']} px; best gain of "
             f"the occlusion g = {record['gain']:.4f}):",
             f"    {'region':<9}{'pixels':>8}  {'rmse':>8}{'bias':>9}{'psnr':>7}{'ssim':>7}"
             f"{'z_rms':>8}   | gained: {'rmse':>7}{'bias':>9}{'ssim':>7}"]
    for name, region in record["regions"].items():
        raw, gained = region["raw"], region["gained"]
        lines.append(f"    {name:<9}{raw['pixels']:>8}  {num(raw['rmse'], '8.5f')}"
                     f"{num(raw['bias'], '+9.5f')}{num(raw['psnr'], '7.2f')}"
                     f"{num(raw['ssim'], '7.4f')}{num(raw['z_rms'], '8.3f')}   |         "
                     f"{num(gained['rmse'], '7.5f')}{num(gained['bias'], '+9.5f')}"
                     f"{num(gained['ssim'], '7.4f')}")
    lines += [f"  note: {text}" for text in record["notes"]]
    return lines
