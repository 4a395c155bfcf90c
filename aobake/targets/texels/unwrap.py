"""Fresh UV atlases, for meshes whose own UVs cannot be baked: xatlas charts, aobake packs.

xatlas cuts the mesh into charts and flattens them (``aobake.targets.texels.charts``); the
charts are then scaled to one texel density and packed (``aobake.targets.texels.packing``),
densely and with exact padding: each chart's texels are marked at the trial scale, grown by
``padding`` rings and laid without overlap.  All of it runs in a child Python process
(``aobake.child``, with a time limit and one retry): xatlas has been seen to segfault on some
inputs and, once, to deadlock in its thread pool; in a child either becomes an error
message.  The atlas follows the texel conventions of ``aobake.targets.texels``
(OBJ-convention UVs, charts on the texel grid of the target image, ``padding`` empty texels
around every chart).
"""

from __future__ import annotations

import logging
import math
import time
from typing import NamedTuple

import numpy as np

from aobake import child
from aobake.errors import InputError
from aobake.targets.texels.charts import chart_cap, chart_mesh, charting_library
from aobake.targets.texels.packing import (FIRST_EFFICIENCY, better_layout, layout_at_density,
                                           packing_kernels)

log = logging.getLogger(__name__)


class Unwrapped(NamedTuple):
    """A fresh atlas: new vertices referring back to the input ones.

    vmapping : (m,) int64   index into the input vertices of each new vertex
    faces : (f, 3) int64    triangles over the new vertices (same order as input)
    uv : (m, 2) float64     UVs in [0, 1], OBJ convention (v = 0 at the bottom)
    charts : int            number of charts
    size : (width, height)  the image the UVs are laid out for (the one asked for, or the
                            one chosen for a texel density); None when not known
    packing_compiled : bool | None  True when the charts were marked and packed by the
                            compiled kernels (aobake/_pack.c), False by the numpy reference
                            (the same atlas either way); None when not known
    charting : str | None   which xatlas charted: "aobake._xatlas" (built from
                            third_party/xatlas) or "xatlas" (the package), the same charts
    """

    vmapping: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    charts: int = 0
    size: tuple | None = None
    packing_compiled: bool | None = None
    charting: str | None = None


def _xatlas_atlas(positions, faces, resolution, padding, chart_image=False,
                  texel_density=None, compiled: bool | None = None):
    """Chart (``charts``), then pack (``packing``): (vmapping, faces, uv_xatlas, image or
    None, info).

    ``uv_xatlas`` is in xatlas's orientation: ``v * height`` is the row counted from the
    FIRST row (the top, as stored), i.e. v runs downwards, opposite to OBJ; ``unwrap`` flips
    it.  Faces come back in input order.  ``info``: the chart count, the estimated coverage
    (texels the charts touch / all texels), the padded footprint over the image
    (``utilization``), the texel density reached (``texels_per_unit``, texels per scene unit
    along the surface, the same in every chart), the packs tried and ``packing_compiled``
    (which packer ran).  ``image`` (``chart_image=True``): (H, W, 3) uint8, each chart's
    texels in its colour.  ``compiled``: mark and pack the charts in the compiled kernels
    (True; default None: when built and not forced off, see ``aobake._native``) or in numpy
    (False, the reference); the atlas is the same bits either way.

    Why it is shaped like this:

    1. Charting: xatlas on parts normalised on their own triangles (``charts._parts``, chart area
       capped at CHART_FACES triangles' worth: the bunny's 69k triangles chart in ~1.5 s on
       2 cores instead of ~20 s uncapped; larger at a low resolution or a large padding,
       ``charts.chart_cap``).
    2. Each chart scaled to its surface area, so one scale gives one texel density.
    3. Packing (here, not xatlas's: its random placement left 37% of the bunny's image
       empty, like random sequential packing jams): every chart's texels are marked at a
       trial scale, grown by ``padding`` rings, and the grown masks are laid without overlap
       (skyline drop + holes, ``packing._Packer``), moved by whole texels and quarter turns, so the
       marks hold every texel the rasteriser can cover.  The scale is searched
       for the largest one whose layout fits in R x R, R = min(width, height) (2-4 packs);
       the layout sits in the top-left corner of the image.  It is made twice, of the
       charts as xatlas turned them and of their mirror images, the better kept
       (``packing.better_layout``).
    4. The marks (``packing._chart_masks`` from the frame coordinates on: the per-texel tests and
       the growing) and each pack (``_pack_in_order``'s whole loop) run in aobake/_pack.c
       when it was built, step for step as the numpy reference, which stays the fallback
       (tests/test_pack_kernel.py: the same masks, packs, placements, packer state and UVs,
       bit for bit).  The layout (``packing._layout`` on the same charts, CPU seconds, one thread),
       numpy -> compiled, the atlases identical: the bunny (227 charts) 1024^2 P2 (4 packs)
       1.13 -> 0.15, 1024^2 P8 (2 packs, 70 charts) 0.40 -> 0.07, 512^2 P4 (4) 0.48 -> 0.06;
       the ogre (826 charts) 1024^2 P2 (2) 1.58 -> 0.21, P8 (6) 3.87 -> 0.30, 512^2 P4 (6)
       2.78 -> 0.20.  What is left is ~20 ms per bunny pack, ~9 ms per marking.

    ``resolution`` : N or (width, height); ``texel_density`` (texels per scene unit) or
    None: the charts at exactly that density in the smallest square that holds them
    (``packing.layout_at_density``; ``resolution`` is then ignored and ``info["width"]``,
    ``info["height"]`` say the size chosen).
    """
    P = int(padding)
    kernels = packing_kernels(compiled)
    if texel_density is None:
        W, H = (int(resolution), int(resolution)) if np.ndim(resolution) == 0 \
            else map(int, resolution)
        R = min(W, H)
        cap = chart_cap(R, P)
    else:
        # the charts' size follows the texels per triangle: the image side at about the
        # first pack's efficiency (the surface area in texels over FIRST_EFFICIENCY)
        p = np.asarray(positions, np.float64)[np.asarray(faces)]
        area = 0.5 * float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                                          axis=1).sum())
        cap = chart_cap(max(1, int(texel_density * math.sqrt(area / FIRST_EFFICIENCY))), P)
    vmapping, new_faces, uv_a, face_chart, unit = chart_mesh(positions, faces, cap)
    if texel_density is None:
        uv, scale, image, info = better_layout(uv_a, new_faces, face_chart, R, P,
                                               chart_image, kernels)
    else:
        uv, scale, image, info, R = layout_at_density(uv_a, new_faces, face_chart,
                                                      float(texel_density) * unit, P,
                                                      chart_image, kernels)
        W = H = R
    info["packing_compiled"] = kernels is not None
    info["charting"] = charting_library()
    info["width"], info["height"] = W, H
    if image is not None:
        full = np.zeros((H, W, 3), np.uint8)
        full[:R, :R] = image
        image = full
    info["coverage"] *= R * R / (W * H)
    info["utilization"] *= (R + 2 * P) ** 2 / (W * H)
    info["texels_per_unit"] = scale / unit
    return vmapping, new_faces, uv / [W, H], image, info


def _unwrap_in_process(positions, faces, resolution, padding, texel_density=None,
                       compiled: bool | None = None) -> tuple[Unwrapped, dict]:
    vmapping, new_faces, uv, _, info = _xatlas_atlas(positions, faces, resolution, padding,
                                                     texel_density=texel_density,
                                                     compiled=compiled)
    # The packed v runs down the image (row 0 first, as xatlas's); OBJ's v runs up.
    # Flipping keeps texel boundaries on texel boundaries because resolution is
    # integral, so the texel grid the charts were packed on (and its padding) is kept.
    uv[:, 1] = 1.0 - uv[:, 1]
    return Unwrapped(vmapping, new_faces, uv, size=(info["width"], info["height"]),
                     packing_compiled=info["packing_compiled"], charting=info["charting"]), info


def _unwrap_worker(inputs: dict) -> dict:
    """The unwrap in its child (``WORKER``): inputs positions, faces, resolution, padding,
    texel_density (0: none) and compiled, the parent's decision (its ``_native.numpy_only``
    is thread-local and does not reach this process; absent: this process's default).
    Returns vmapping, faces, uv and the ``_INFO`` fields."""
    density = float(inputs["texel_density"]) if "texel_density" in inputs else 0.0
    compiled = bool(inputs["compiled"]) if "compiled" in inputs else None
    result, info = _unwrap_in_process(
        inputs["positions"], inputs["faces"], tuple(int(x) for x in inputs["resolution"]),
        int(inputs["padding"]), density if density > 0 else None, compiled
    )
    return dict(vmapping=result.vmapping, faces=result.faces, uv=result.uv,
                **{key: info[key] for key in _INFO})


#: what the child reports besides the atlas (see ``_xatlas_atlas``)
_INFO = {"charts": int, "coverage": float, "utilization": float, "texels_per_unit": float,
         "packs": int, "width": int, "height": int, "packing_compiled": bool, "charting": str}


#: time limit of one xatlas child process: base + per triangle (the bunny's 69k
#: triangles take ~3 s on 2 cores; the limit is generous because xatlas's thread
#: pool has been seen to deadlock, which only the time limit catches).
XATLAS_TIMEOUT_BASE_S = 120.0
XATLAS_TIMEOUT_PER_FACE_S = 2e-3

#: The unwrap's child: it imports this module (not the packages' __init__) and runs
#: ``_unwrap_worker``; a prestarted one imports xatlas too when the package charts.  Read at
#: call time, so tests can swap in a crashing stand-in.
WORKER = child.worker("xatlas", __name__, "_unwrap_worker", warm_up="""\
from aobake.targets.texels.charts import charting_library
if charting_library() == "xatlas":
    import xatlas
""")


def prestart() -> None:
    """Start the xatlas child now, before the mesh is read, so that its interpreter start
    and imports (~0.15 s) overlap the loading instead of delaying the unwrap; the next
    ``unwrap`` in this process hands it its job.  At most one waits.  For a command that
    will probably unwrap (aobake's CLI making a lightmap); ``discard_prestarted`` ends it
    when the mesh's own UVs are baked."""
    child.prestart(WORKER)


def discard_prestarted() -> None:
    """End a prestarted child that no unwrap will use."""
    child.discard(WORKER)


def _unwrap_isolated(positions, faces, resolution, padding, texel_density=None,
                     compiled: bool | None = None) -> tuple[Unwrapped, dict]:
    # xatlas segfaults on some inputs (for example finely subdivided
    # icospheres, jpcy/xatlas#146); in a child process that becomes an error
    # message instead of killing the caller.
    # Which packer runs is decided here, on the caller's thread (``numpy_only`` is
    # thread-local), and handed to the child explicitly.
    compiled = packing_kernels(compiled) is not None
    # xatlas's own thread pool has been seen to deadlock now and then (all threads in futex
    # waits, no CPU); a child that outlives a generous limit is killed and the unwrap tried
    # once more before giving up.
    limit = XATLAS_TIMEOUT_BASE_S + XATLAS_TIMEOUT_PER_FACE_S * len(faces)
    inputs = dict(positions=positions, faces=faces, resolution=resolution, padding=padding,
                  texel_density=texel_density or 0.0,  # 0: none
                  compiled=bool(compiled))
    try:
        data = child.run(WORKER, inputs, limit)
    except child.TimedOut:
        raise InputError(f"xatlas did not finish unwrapping {len(faces)} triangles in "
                         f"{limit:.0f} s, twice; provide your own UVs") from None
    except child.Crashed as exc:
        raise InputError(
            f"xatlas {exc.how} while unwrapping a mesh of {len(faces)} triangles; "
            "very regular meshes such as finely subdivided icospheres are known to crash it "
            "(jpcy/xatlas#146): provide your own UVs or perturb the mesh"
        ) from None
    except child.Failed as exc:
        message = exc.line.split("InputError: ", 1)[-1]  # the child's own message, not its type
        raise InputError(f"unwrapping a mesh of {len(faces)} triangles failed: {message}") \
            from None
    info = {key: kind(data[key]) for key, kind in _INFO.items()}
    return Unwrapped(data["vmapping"], data["faces"], data["uv"],
                     size=(info["width"], info["height"]),
                     packing_compiled=info["packing_compiled"], charting=info["charting"]), info


def unwrap(positions, faces, resolution, padding: int, *, isolate: bool = True,
           texel_density: float | None = None, compiled: bool | None = None) -> Unwrapped:
    """Make a fresh, non-overlapping UV atlas with xatlas.

    positions : (n, 3) float; faces : (f, 3) int.
    resolution : N (square) or (width, height) of the target image in texels; the
        charts are packed into the top-left min(width, height) square.
    padding : empty texels kept around each chart.  Two charts' covered texels
        (any texel a triangle overlaps) end up at least ``2 * padding`` empty
        texels apart (8-neighbour rings), so dilating each chart by ``padding``
        rings (``aobake.post.dilate``) never mixes two charts.
    isolate : run xatlas in a child Python process so that an xatlas crash
        raises InputError instead of killing this process (costs ~0.3 s).
    texel_density : None, or texels per scene unit along the surface: every chart at
        exactly this density in the smallest square image that holds them (``resolution``
        is then ignored; ``Unwrapped.size`` is the size chosen).
    compiled : mark and pack the charts in the compiled kernels (True), in numpy (False), or
        (None) when built and not forced off on this thread (``aobake._native``); the atlas
        is the same bits either way and ``Unwrapped.packing_compiled`` says which ran.

    Returns ``Unwrapped(vmapping (m,) int64, faces (f, 3) int64, uv (m, 2)
    float64, charts, size (width, height), packing_compiled)``: new vertex ``i`` sits at ``positions[vmapping[i]]``; uv is in
    [0, 1] in the OBJ convention (v = 0 at the bottom), charts aligned to the
    ``resolution`` texel grid, every chart at the same texel density (its UV area
    over its surface area is the same in all charts).
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must be (n, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be (f, 3) integers, got {faces.shape} {faces.dtype}")
    if len(faces) == 0:
        raise InputError("cannot unwrap a mesh without triangles")
    if faces.min() < 0 or faces.max() >= len(positions):
        raise ValueError(f"faces index vertices outside 0..{len(positions) - 1}")
    size = (resolution, resolution) if np.ndim(resolution) == 0 else tuple(resolution)
    if len(size) != 2 or any(int(x) != x or x < 1 for x in size):
        raise ValueError(f"resolution must be a positive integer or two, got {resolution}")
    width, height = (int(x) for x in size)
    if int(padding) != padding or padding < 0:
        raise ValueError(f"padding must be a non-negative integer, got {padding}")
    if texel_density is not None and not (math.isfinite(texel_density) and texel_density > 0):
        raise ValueError(f"texel density must be a positive number, got {texel_density}")
    start = time.perf_counter()
    run = _unwrap_isolated if isolate else _unwrap_in_process
    result, info = run(positions, faces.astype(np.int64), (width, height), int(padding),
                       texel_density, compiled)
    width, height = info["width"], info["height"]
    log.info(
        "unwrapped %d triangles into %dx%d texels in %.1f s (%d packs): %d charts covering "
        "%.0f%% of the texels (%.0f%% with padding), %.4g texels per unit, %d -> %d vertices",
        len(faces), width, height, time.perf_counter() - start, info["packs"], info["charts"],
        100 * info["coverage"], 100 * info["utilization"], info["texels_per_unit"],
        len(positions), len(result.vmapping),
    )
    return result._replace(charts=int(info["charts"]))
