"""Fresh UV atlases with xatlas, for meshes whose own UVs cannot be baked.

xatlas runs in a child Python process (with a time limit and one retry): it has
been seen to segfault on some inputs and, once, to deadlock in its thread pool;
in a child either becomes an error message.  The atlas follows the texel
conventions of ``aobake.targets.texels`` (OBJ-convention UVs, charts on the texel
grid of the target image, ``padding`` empty texels around every chart).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aobake.errors import InputError

log = logging.getLogger(__name__)


class Unwrapped(NamedTuple):
    """A fresh atlas: new vertices referring back to the input ones.

    vmapping : (m,) int64   index into the input vertices of each new vertex
    faces : (f, 3) int64    triangles over the new vertices (same order as input)
    uv : (m, 2) float64     UVs in [0, 1], OBJ convention (v = 0 at the bottom)
    charts : int            number of charts
    """

    vmapping: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    charts: int = 0



#: A chart covers at most this many triangles' worth of the mean triangle area.
CHART_FACES = 500
#: Meshes larger than this are split into spatial parts charted in parallel.
PART_FACES = 20000
#: Aim the packed side at this fraction of the resolution; accept >= ACCEPT.
AIM, ACCEPT = 0.975, 0.95
MAX_REPACKS = 8


def _split_faces(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> list[np.ndarray]:
    """Median-split face centroids along the widest axis into parts of <= max_faces."""
    centroids = vertices[faces].mean(axis=1)
    todo, parts = [np.arange(len(faces))], []
    while todo:
        part = todo.pop()
        if len(part) <= max_faces:
            parts.append(part)
            continue
        c = centroids[part]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = np.argsort(c[:, axis], kind="stable")
        half = len(part) // 2
        todo += [part[order[half:]], part[order[:half]]]
    return sorted(parts, key=lambda p: int(p[0]))


def _uv_face_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    t = uv[faces]
    return 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                        - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0]))


def _xatlas_atlas(positions, faces, resolution, padding, chart_image=False):
    """Run xatlas and return (vmapping, faces, uv_xatlas, image or None, info).

    ``uv_xatlas`` is in xatlas's own orientation: ``v * resolution`` is the row
    of the chart image counted from its FIRST row (the top, as stored), i.e.
    xatlas's v runs downwards, opposite to OBJ.  ``unwrap`` flips it.  Faces
    come back in input order.  ``info`` holds the chart count and xatlas's
    utilisation (padded chart footprints over the whole image).

    Why it is shaped like this (bunny, 69k triangles, 2 cores: 50 s -> 3 s):

    1. Charting was ~95% of the time and grows faster than linearly with chart
       size, so the chart area is capped at CHART_FACES mean triangles' worth.
       xatlas charts one mesh per thread, so meshes above PART_FACES triangles
       are cut into spatial parts (a function of the face count only, never of
       the core count) added as separate meshes.  The first pack only has to
       produce charts, so it is cheap (no padding, no bilinear, small scale).
    2. The scale for the final pack is predicted from the padded chart areas.
    3. The charts are repacked with no fixed resolution (one atlas of w x h) at
       that scale, corrected by a secant step on the measured side, keeping the
       largest scale whose layout fits in R x R, R = min(width, height)
       (typically 1-2 repacks).  That layout is placed in the top-left corner of
       the width x height image: the charts stay on the texel grid with exactly
       ``padding`` texels around them.  xatlas packs square-ish layouts, so a
       non-square image leaves the part beyond R unused.

    ``resolution`` : N or (width, height).
    """
    import xatlas

    W, H = (int(resolution), int(resolution)) if np.ndim(resolution) == 0 else map(int, resolution)
    R, P = min(W, H), int(padding)
    F = np.asarray(faces, dtype=np.int64)
    # xatlas works in float32 with absolute tolerances: recentre on the used vertices'
    # bounding box and scale so the mean triangle area is 1, so the atlas depends on
    # neither where the mesh sits nor its units (a mesh 1e5 from the origin, or 1e-4
    # across, charts like the same mesh at unit size).  Per-triangle rather than
    # whole-mesh scale: at unit diagonal the ogre's 124k triangles are so small that
    # xatlas cut it into 2562 charts (981 at unit mean area), too many to pack.
    V = np.asarray(positions, dtype=np.float64)
    used_v = V[np.unique(F)]
    lo, hi = used_v.min(axis=0), used_v.max(axis=0)
    V = V - 0.5 * (lo + hi)
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    area = float(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1).sum())
    if not area > 0:
        raise InputError("cannot unwrap a mesh whose triangles all have zero area")
    unit = math.sqrt(area / len(F))
    V /= unit
    area /= unit * unit

    # 1. charts: capped chart area, big meshes in parallel parts, cheap first pack
    chart_options = xatlas.ChartOptions()
    if len(F) > 20 * CHART_FACES:
        chart_options.max_chart_area = area * CHART_FACES / len(F)
    parts = _split_faces(V, F, PART_FACES) if len(F) > PART_FACES else [np.arange(len(F))]
    first = xatlas.Atlas()
    part_vertices = []
    for part in parts:
        used, local = np.unique(F[part], return_inverse=True)
        part_vertices.append(used)
        first.add_mesh(np.ascontiguousarray(V[used], dtype=np.float32),
                       np.ascontiguousarray(local.reshape(-1, 3), dtype=np.uint32))
    cheap = xatlas.PackOptions()
    cheap.padding, cheap.bilinear, cheap.texels_per_unit = 0, False, 256.0 / math.sqrt(area)
    first.generate(chart_options=chart_options, pack_options=cheap)

    # gather the parts into one UV mesh in the first pack's texel units, faces in input order
    vm_list, face_list, uv_list, offset = [], [], [], 0
    for i, used in enumerate(part_vertices):
        vm, fi, uv = first[i]
        vm_list.append(used[vm.astype(np.int64)])
        face_list.append(fi.astype(np.int64) + offset)
        uv_list.append(uv)
        offset += len(vm)
    vm_a = np.concatenate(vm_list)
    faces_a = np.empty_like(F)
    faces_a[np.concatenate(parts)] = np.concatenate(face_list)
    uv_a = np.concatenate(uv_list).astype(np.float64) * [first.width, first.height]
    log.debug("xatlas charts: %d charts in %d parts", first.chart_count, len(parts))

    # 2. predict the scale: padded chart footprints over a packing efficiency
    face_area = _uv_face_areas(uv_a, faces_a)
    chart_area = [face_area[part[first.get_mesh_chart(i, c).faces.astype(np.int64)]].sum()
                  for i, part in enumerate(parts) for c in range(first.get_mesh_chart_count(i))]
    root_area = np.sqrt(np.asarray(chart_area, dtype=np.float64))
    efficiency = 0.68

    def predicted_side(s):
        return math.sqrt(np.sum((1.15 * s * root_area + 2 * P + 2) ** 2) / efficiency)

    lo, hi = 1e-9, 1e9
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if predicted_side(mid) > AIM * R else (mid, hi)
    scale = lo

    # 3. unbounded repacks aimed at R; keep the largest scale whose layout fits
    uv32 = np.ascontiguousarray(uv_a, dtype=np.float32)
    faces32 = np.ascontiguousarray(faces_a, dtype=np.uint32)

    def pack_at(s):
        options = xatlas.PackOptions()
        options.padding, options.bilinear, options.texels_per_unit = P, True, s
        options.create_image = bool(chart_image)
        atlas = xatlas.Atlas()
        atlas.add_uv_mesh(uv32, faces32)
        atlas.generate(pack_options=options)
        return atlas

    tried, best = [], None
    for _ in range(MAX_REPACKS):
        atlas = pack_at(scale)
        side = max(atlas.width, atlas.height)
        tried.append((scale, side))
        if atlas.atlas_count == 1 and side <= R:
            if best is None or scale > best[0]:
                best = (scale, atlas)
            if side >= ACCEPT * R:
                break
        if len(tried) >= 2 and tried[-1][0] != tried[-2][0] and tried[-1][1] != tried[-2][1]:
            (s1, m1), (s2, m2) = tried[-2], tried[-1]
            slope = (m2 - m1) / (s2 - s1)
            new = s2 + (AIM * R - m2) / slope if slope > 0 else s2 * AIM * R / m2
        else:
            new = scale * AIM * R / side
        if best is not None and new <= best[0]:
            break  # would go below a scale that already fits
        if best is None and side > R:
            new = min(new, 0.97 * scale)  # must shrink
        scale = new
    while best is None and len(tried) < MAX_REPACKS + 20:  # safety net: plain shrinking
        scale *= 0.9
        atlas = pack_at(scale)
        tried.append((scale, max(atlas.width, atlas.height)))
        if atlas.atlas_count == 1 and max(atlas.width, atlas.height) <= R:
            best = (scale, atlas)
    if best is None:
        raise InputError(f"xatlas could not pack the charts into one {W}x{H} atlas with {P} texels "
                         "of padding: raise --resolution or lower --padding")
    scale, atlas = best
    w, h = atlas.width, atlas.height
    vm_b, faces_b, uv_b = atlas[0]
    # embed the w x h layout in the top-left corner of the W x H image (xatlas orientation)
    uv_out = uv_b.astype(np.float64) * [w / W, h / H]
    image = None
    if chart_image:
        image = np.zeros((H, W, 3), np.uint8)
        image[:h, :w] = atlas.get_chart_image(0)
    utilization = float(atlas.utilization) * w * h / (W * H)
    log.debug("xatlas: %d repacks %s, final %dx%d in %dx%d, utilisation %.3f",
              len(tried), tried, w, h, W, H, utilization)
    info = {"charts": int(atlas.chart_count), "utilization": utilization}
    return vm_a[vm_b.astype(np.int64)], faces_b.astype(np.int64), uv_out, image, info


def _unwrap_in_process(positions, faces, resolution, padding) -> tuple[Unwrapped, dict]:
    vmapping, new_faces, uv, _, info = _xatlas_atlas(positions, faces, resolution, padding)
    # xatlas's v runs down the image (row 0 first); OBJ's v runs up.  Flipping
    # keeps texel boundaries on texel boundaries because resolution is integral,
    # so the texel grid xatlas packed for (and its padding) is preserved.
    uv[:, 1] = 1.0 - uv[:, 1]
    return Unwrapped(vmapping, new_faces, uv), info


def _unwrap_worker(argv: list[str]) -> None:
    """Entry point of the isolated xatlas process: ``in.npz out.npz``."""
    with np.load(argv[0]) as data:
        result, info = _unwrap_in_process(
            data["positions"], data["faces"], tuple(int(x) for x in data["resolution"]),
            int(data["padding"])
        )
    np.savez(argv[1], vmapping=result.vmapping, faces=result.faces, uv=result.uv,
             charts=info["charts"], utilization=info["utilization"])


#: time limit of one xatlas child process: base + per triangle (the bunny's 69k
#: triangles take ~3 s on 2 cores; the limit is generous because xatlas's thread
#: pool has been seen to deadlock, which only the time limit catches).
XATLAS_TIMEOUT_BASE_S = 120.0
XATLAS_TIMEOUT_PER_FACE_S = 2e-3

# The child imports this module and runs the worker; kept as data so tests can
# swap in a crashing stand-in.
_WORKER_CODE = "import sys; from aobake.targets.texels.unwrap import _unwrap_worker; _unwrap_worker(sys.argv[1:])"


def _unwrap_isolated(positions, faces, resolution, padding) -> tuple[Unwrapped, dict]:
    # xatlas segfaults on some inputs (for example finely subdivided
    # icospheres, jpcy/xatlas#146); in a child process that becomes an error
    # message instead of killing the caller.
    package_root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH")) if p)
    with tempfile.TemporaryDirectory(prefix="aobake-xatlas-") as tmp:
        src, dst = Path(tmp, "in.npz"), Path(tmp, "out.npz")
        np.savez(src, positions=positions, faces=faces, resolution=resolution, padding=padding)
        # xatlas's own thread pool has been seen to deadlock now and then (all
        # threads in futex waits, no CPU); a child that outlives a generous limit
        # is killed and the unwrap tried once more before giving up.
        limit = XATLAS_TIMEOUT_BASE_S + XATLAS_TIMEOUT_PER_FACE_S * len(faces)
        for attempt in (1, 2):
            try:
                proc = subprocess.run(
                    [sys.executable, "-c", _WORKER_CODE, str(src), str(dst)],
                    env=env, capture_output=True, text=True, timeout=limit,
                )
                break
            except subprocess.TimeoutExpired:
                log.warning("xatlas did not finish in %.0f s (attempt %d of 2)", limit, attempt)
        else:
            raise InputError(f"xatlas did not finish unwrapping {len(faces)} triangles in "
                             f"{limit:.0f} s, twice; provide your own UVs")
        if proc.returncode < 0:
            try:
                how = f"crashed with {signal.Signals(-proc.returncode).name}"
            except ValueError:
                how = f"was killed by signal {-proc.returncode}"
            raise InputError(
                f"xatlas {how} while unwrapping a mesh of {len(faces)} triangles; "
                "very regular meshes such as finely subdivided icospheres are known to crash it "
                "(jpcy/xatlas#146): provide your own UVs or perturb the mesh"
            )
        if proc.returncode != 0:
            last = proc.stderr.strip().splitlines()[-1:] or [f"exit status {proc.returncode}"]
            message = last[0].split("InputError: ", 1)[-1]  # the child's own message, not its type
            raise InputError(f"unwrapping a mesh of {len(faces)} triangles failed: {message}")
        with np.load(dst) as data:
            info = {"charts": int(data["charts"]), "utilization": float(data["utilization"])}
            return Unwrapped(data["vmapping"], data["faces"], data["uv"]), info


def unwrap(positions, faces, resolution, padding: int, *, isolate: bool = True) -> Unwrapped:
    """Make a fresh, non-overlapping UV atlas with xatlas.

    positions : (n, 3) float; faces : (f, 3) int.
    resolution : N (square) or (width, height) of the target image in texels; the
        charts are packed into the top-left min(width, height) square.
    padding : empty texels kept around each chart (xatlas ``padding``, with
        ``bilinear=True``).  Two charts' covered texels end up at least
        ``2 * padding`` empty texels apart, so dilating each chart by
        ``padding`` rings (``aobake.post.dilate``) never mixes two charts.
    isolate : run xatlas in a child Python process so that an xatlas crash
        raises InputError instead of killing this process (costs ~0.3 s).

    Returns ``Unwrapped(vmapping (m,) int64, faces (f, 3) int64, uv (m, 2)
    float64)``: new vertex ``i`` sits at ``positions[vmapping[i]]``; uv is in
    [0, 1] in the OBJ convention (v = 0 at the bottom), charts aligned to the
    ``resolution`` texel grid.
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
    start = time.perf_counter()
    run = _unwrap_isolated if isolate else _unwrap_in_process
    result, info = run(positions, faces.astype(np.int64), (width, height), int(padding))
    log.info(
        "unwrapped %d triangles into %dx%d texels in %.1f s: %d charts covering %.0f%%, "
        "%d -> %d vertices",
        len(faces), width, height, time.perf_counter() - start, info["charts"],
        100 * info["utilization"], len(positions), len(result.vmapping),
    )
    return result._replace(charts=int(info["charts"]))
