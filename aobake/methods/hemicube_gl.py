"""The hemicube's rasteriser: OpenGL through moderngl on a headless EGL context, run in a
child process (``aobake.child``), never in the baker's own: a driver can take its process
down.  One context per child; its function ``render(inputs) -> outputs`` takes and returns
arrays (see :func:`render`).  Imports numpy, moderngl and ``hemicube_cells`` only.

Per point, the mesh is drawn once for each of the hemicube's five faces (``hemicube_cells``:
the front face and the four half side faces), laid out in the point's 3R x R tile of one
framebuffer; a batch of points fills the framebuffer's tiles, then the tiles are read back
together.  Two ways, the same pixels:

- whole (small meshes, and the reference): one instanced draw per point, instance f = 0..4
  is face f, every triangle drawn five times;
- culled (meshes of ``CULL_MIN_TRIANGLES`` or more): the triangles are kept in clusters of
  ``CLUSTER_TRIANGLES`` neighbours (sorted along a Morton curve of their centroids), and per
  point and face only the runs of clusters that may reach that face are drawn, as one
  multi-draw (``glMultiDrawElementsIndirect``, one command per run).  On llvmpipe, whose
  geometry work (vertex shading, clipping, binning) is single-threaded and costs about the
  same for a triangle the clipper rejects as for one it draws, a point on the 69k-triangle
  bunny then draws ~9% of the 5 x 69k triangle-faces (docs/hemicube.md: the cost per point
  falls ~5x on the bunny).  A cluster is skipped for a face only when its bounding box lies
  wholly beyond one of that face's clip planes (its four gl_ClipDistance planes or the near
  plane) by a margin far above float32 rounding (``cull_commands``), so every skipped
  triangle is one the GL clips away entirely: it makes no fragment either way.

Why the pixels are the same bits: a pixel's colour is 1 ("blocked") exactly when at least one
fragment that is not discarded covers its centre, whatever the order of the triangles (with
the depth test '<=' a fragment can only fail against an earlier one that passed and wrote 1;
a discarded fragment writes nothing), and each drawn triangle is rasterised from the same
float32 vertices through the same shader arithmetic (the culled shaders are the whole ones
with the face taken from a per-command attribute instead of gl_InstanceID, and the triangle
from a per-command base + gl_PrimitiveID); the triangles a cull skips make no fragments.
``tests/test_hemicube.py`` compares the two ways' tiles bit for bit (clipped triangles, a
max distance, back faces culled).

What a pixel says: whether the ray through its centre from the eye (the point moved along its
normal by the ray offset, as the ray-traced method's origins) meets a triangle within the
max distance.  GL samples coverage at pixel centres, so a pixel is the one ray through its
centre:
- near plane at the ray offset (nothing nearer than it along a face's axis is seen), no far
  plane (an infinite perspective: z_clip = w - 2 near, w = depth along the axis);
- the far limit is a sphere: a fragment whose hit distance along its pixel's ray exceeds the
  max distance is discarded.  The distance is not interpolated: it is the pixel ray's
  intersection with the fragment's triangle plane (gl_PrimitiveID -> that triangle's first
  corner and normal, from a float texture), so it depends only on the pixel and the triangle;
- no face culling by default: back faces occlude, as rays do (``--backfaces occlude``);
  ``backfaces = ignore`` culls the faces seen from behind, as rays pass through them;
- depth test on ('<=': a pixel keeps its nearest fragment); the colour is 1 for "blocked".

Every point's pixels are the same bits wherever its tile lies, so any split of the points
gives the same values.  Everything up to clipping is computed in the tile's own clip space,
the same for every tile: the face's offset within the tile and the clip planes that cut a
face to its rectangle (gl_ClipDistance) are constants.  The tile is placed by the viewport
alone, at integer coordinates in [S, 2S) (S a power of two, the framebuffer 2S across): the
viewport transform then adds an integer to window coordinates that all lie in one binade, so
the sum is exact, and the rasteriser's fixed-point snapping and integer edge functions move
with it by whole pixels.  (Tiles placed by offsets in a shared clip space would not be: the
perspective divide of a different sum rounds differently.)
"""

from __future__ import annotations

import math
import os

import numpy as np

from aobake.methods import hemicube_cells

#: the framebuffer: tiles lie in [S + MARGIN, 2S - MARGIN) on both axes, S a power of two at
#: least MIN_HALF (a 2S x 2S framebuffer of which only the tiles are cleared and read)
MIN_HALF = 1024
MARGIN = 1
#: texels per row of the triangle texture (two RGBA32F texels per triangle)
TEXTURE_WIDTH = 4096
#: triangles per cluster of the culled draw: a box per cluster, a command per run of
#: clusters (benchmarks/bench_hemicube_batched.py --cluster: 32 and 64 cost about the same
#: on the bunny, 64 culls in less time; 16 makes the numpy cull cost more than it saves)
CLUSTER_TRIANGLES = 64
#: meshes with fewer triangles are drawn whole: their per-point cost is mostly the draw
#: call's, not the triangles', and culling does not pay (bench_hemicube_batched: an
#: 80-triangle icosphere 0.9x, a 626-triangle torus 1.2x, spot's 5,856 triangles 2.4x)
CULL_MIN_TRIANGLES = 512
#: points whose clusters are culled in one numpy pass
CULL_GROUP = 16
#: the cull's margin, relative to the |coordinates| of the box in the point's frame: a
#: cluster is skipped for a plane only when its box lies beyond it by more than this.  The
#: GL computes the same clip distances in float32 (relative error ~1e-7 of those
#: coordinates), so 2^-12 leaves a factor ~2000 of room
CULL_SLACK = 2.0 ** -12

VERTEX_SHADER = """
#version 410
in vec3 in_position;
uniform vec3 eye;
uniform mat3 frame;   // columns t, b, n: the point's frame
uniform float near;
out float gl_ClipDistance[4];
flat out int face;

void main() {
    // (t, b, n) coordinates of the vertex seen from the eye
    vec3 q = (in_position - eye) * frame;
    int f = gl_InstanceID;
    vec3 v;         // face coordinates: (right, up, forward), as hemicube_cells.face_frames
    float ax, ay, ylo;
    if (f == 0)      { v = vec3( q.x,  q.y,  q.z); ax = -2.0 / 3.0; ay =  0.0; ylo = -1.0; }
    else if (f == 1) { v = vec3( q.y,  q.z,  q.x); ax =  0.0;       ay = -1.0; ylo =  0.0; }
    else if (f == 2) { v = vec3(-q.y,  q.z, -q.x); ax =  0.0;       ay =  0.0; ylo =  0.0; }
    else if (f == 3) { v = vec3(-q.x,  q.z,  q.y); ax =  2.0 / 3.0; ay = -1.0; ylo =  0.0; }
    else             { v = vec3( q.x,  q.z, -q.y); ax =  2.0 / 3.0; ay =  0.0; ylo =  0.0; }
    float w = v.z;
    // the face's rectangle: x in [-1, 1], y in [ylo, 1] (a side face above the horizon)
    gl_ClipDistance[0] = w + v.x;
    gl_ClipDistance[1] = w - v.x;
    gl_ClipDistance[2] = w - v.y;
    gl_ClipDistance[3] = v.y - ylo * w;
    // into the tile: a third of its width per face column, a side face's upper half into
    // its half of the tile's height; near plane at w = near, no far plane
    gl_Position = vec4(ax * w + v.x / 3.0, ay * w + v.y, w - 2.0 * near, w);
    face = f;
}
"""

FRAGMENT_SHADER = """
#version 410
uniform vec3 eye;
uniform mat3 frame;
uniform vec2 origin;          // the tile's lower-left corner (window pixels, integers)
uniform float resolution;     // R
uniform float max_distance;   // local units
uniform bool limited;         // max_distance is finite
uniform sampler2D triangles;  // per triangle: texel 2i = first corner, 2i + 1 = unit normal
flat in int face;
out float blocked;

vec4 fetch(int texel) {
    return texelFetch(triangles, ivec2(texel % %(width)d, texel / %(width)d), 0);
}

void main() {
    if (limited) {
        // the pixel centre on its face plane (exact: integers + 0.5 minus integers)
        vec2 p = gl_FragCoord.xy - origin;
        float step = 2.0 / resolution;
        float col = p.x - resolution * floor(p.x / resolution);
        float x = col * step - 1.0;
        float y;
        if (face == 0) y = p.y * step - 1.0;
        else y = (p.y - (face == 2 || face == 4 ? 0.5 * resolution : 0.0)) * step;
        vec3 t = frame[0], b = frame[1], n = frame[2];
        vec3 d;   // the pixel's direction (x right + y up + forward)
        if (face == 0)      d = x * t + y * b + n;
        else if (face == 1) d = x * b + y * n + t;
        else if (face == 2) d = -x * b + y * n - t;
        else if (face == 3) d = -x * t + y * n + b;
        else                d = x * t + y * n - b;
        vec3 corner = fetch(2 * gl_PrimitiveID).xyz;
        vec3 normal = fetch(2 * gl_PrimitiveID + 1).xyz;
        // distance along the unit ray to the triangle's plane; NaN (edge-on) is discarded
        float along = dot(normal, corner - eye) / dot(normal, d) * length(d);
        if (!(along <= max_distance)) discard;
    }
    blocked = 1.0;
}
"""


def _replace(text: str, old: str, new: str) -> str:
    """text with old replaced by new; old must be there (the culled shaders are the whole
    ones with these lines changed, so the arithmetic they share stays one text)."""
    if old not in text:
        raise AssertionError(f"shader text changed: {old!r} not found")
    return text.replace(old, new)


#: the culled draw's shaders: the face comes from a per-command attribute (the command's
#: baseInstance selects it) instead of gl_InstanceID, and the triangle for the distance test
#: is the command's first triangle + gl_PrimitiveID (the primitive's index in its command)
CULLED_VERTEX_SHADER = _replace(_replace(_replace(
    VERTEX_SHADER,
    "flat out int face;",
    "in int in_face;   // per command: the face\n"
    "in int in_base;   // per command: its first triangle\n"
    "flat out int face;\nflat out int base;"),
    "int f = gl_InstanceID;", "int f = in_face;"),
    "    face = f;\n", "    face = f;\n    base = in_base;\n")
CULLED_FRAGMENT_SHADER = _replace(_replace(_replace(
    FRAGMENT_SHADER,
    "flat in int face;", "flat in int face;\nflat in int base;"),
    "fetch(2 * gl_PrimitiveID)", "fetch(2 * (base + gl_PrimitiveID))"),
    "fetch(2 * gl_PrimitiveID + 1)", "fetch(2 * (base + gl_PrimitiveID) + 1)")


def _face_planes() -> tuple:
    """(planes (5, 4, 3), axes (5, 3)) float64 in (t, b, n) coordinates: for each face (the
    vertex shader's order) the four clip planes a . q >= 0 that cut it to its rectangle
    (gl_ClipDistance[0..3]: w + x, w - x, w - y, y - ylo w) and its axis w (the near plane
    is w >= near)."""
    frames = hemicube_cells.face_frames()  # rows right, up, forward
    planes, axes = [], []
    for f, (x, y, w) in enumerate(frames):
        ylo = -1.0 if f == 0 else 0.0
        planes.append(np.stack([w + x, w - x, w - y, y - ylo * w]))
        axes.append(w)
    return np.array(planes), np.array(axes)


_PLANES, _AXES = _face_planes()
#: (6, 25): [c, e] @ _BOUNDS is the largest value of each plane a . q over a box with centre
#: c and half extents e (a . c + |a| . e); columns 5 j + f: plane j of face f (j = 0..3 the
#: clip planes, j = 4 the axis w, compared with the near plane)
_BOUNDS = (lambda a: np.concatenate([a, np.abs(a)], axis=1).T)(
    np.concatenate([_PLANES.transpose(1, 0, 2).reshape(20, 3), _AXES]))


def morton_order(centroids: np.ndarray) -> np.ndarray:
    """(f,) int64: the triangles ordered along a Morton (Z-order) curve of their centroids
    (f, 3) float64, 10 bits per axis over their bounding box: neighbours end up in the same
    clusters."""
    lo, hi = centroids.min(axis=0), centroids.max(axis=0)
    cells = ((centroids - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023.0).astype(np.uint64)
    code = np.zeros(len(centroids), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) \
                << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def cluster_boxes(vertices: np.ndarray, faces: np.ndarray, size: int) -> tuple:
    """(starts (c,) int64, ends (c,) int64, centre (c, 3) float64, half (c, 3) float64): the
    clusters of ``size`` consecutive triangles of faces (f, 3) and the bounding boxes of
    their float32 vertices (v, 3) (exact in float64)."""
    starts = np.arange(0, len(faces), size, dtype=np.int64)
    ends = np.minimum(starts + size, len(faces))
    corners = np.asarray(vertices, dtype=np.float64)[faces]
    lo = np.minimum.reduceat(corners.min(axis=1), starts, axis=0)
    hi = np.maximum.reduceat(corners.max(axis=1), starts, axis=0)
    return starts, ends, (lo + hi) / 2.0, (hi - lo) / 2.0


def cull_commands(clusters: tuple, eyes: np.ndarray, frames: np.ndarray, near: np.ndarray
                  ) -> tuple:
    """The culled draw's commands for k points: eyes (k, 3), frames (k, 3, 3) (rows t, b,
    n) and near (k,), the float32 values the shaders get (float64 arrays holding them),
    clusters from ``cluster_boxes``.

    A cluster is skipped for a face when its box lies beyond one of the face's planes by
    more than CULL_SLACK x (the box's |coordinates| in the point's frame + near): exactly,
    every point q of the box has a . q below that.  The GL's float32 clip distance of a
    vertex differs from the exact one by far less, so every vertex of every skipped triangle
    is outside that plane in the GL too: the triangle is clipped away whole.

    Returns (commands (m, 5) uint32: count, 1, first index, 0, base instance = the
    command's row; records (m, 2) int32: face, first triangle; point (m,) int64: the
    point's index in 0..k-1), sorted by (point, face, first triangle)."""
    starts, ends, centre, half = clusters
    k = len(eyes)
    # the box in each point's frame: centre c and half extents e (|frame| . half)
    c = centre @ frames.transpose(0, 2, 1) - (frames @ eyes[:, :, None])[:, None, :, 0]
    e = half @ np.abs(frames).transpose(0, 2, 1)                        # (k, C, 3)
    reach = np.abs(c).sum(axis=2) + e.sum(axis=2)                       # (k, C)
    slack = CULL_SLACK * (reach + near[:, None])                        # (k, C)
    # the largest a . q over the box of each plane a: a . c + |a| . e, one product
    top = np.concatenate([c, e], axis=2) @ _BOUNDS                      # (k, C, 25)
    lowest = np.minimum(np.minimum(top[:, :, 0:5], top[:, :, 5:10]),
                        np.minimum(top[:, :, 10:15], top[:, :, 15:20]))  # (k, C, 5)
    beyond = lowest < -slack[:, :, None]
    beyond |= top[:, :, 20:] < near[:, None, None] - slack[:, :, None]
    beyond = beyond.transpose(0, 2, 1)                                  # (k, 5, C)
    # runs of kept clusters per (point, face) row
    kept = np.zeros((k * 5, len(starts) + 2), dtype=np.int8)
    kept[:, 1:-1] = ~beyond.reshape(k * 5, -1)
    step = np.diff(kept, axis=1)
    row, first = np.nonzero(step == 1)
    _, stop = np.nonzero(step == -1)  # the same rows in the same order
    lo, hi = starts[first], ends[stop - 1]
    m = len(row)
    commands = np.zeros((m, 5), dtype=np.uint32)
    commands[:, 0] = 3 * (hi - lo)
    commands[:, 1] = 1
    commands[:, 2] = 3 * lo
    commands[:, 4] = np.arange(m)
    records = np.stack([row % 5, lo], axis=1).astype(np.int32)
    return commands, records, row // 5


def half_size(resolution: int) -> int:
    """S: the power of two at least MIN_HALF whose [S + MARGIN, 2S - MARGIN) holds a tile."""
    need = 3 * resolution + 2 * MARGIN
    return max(MIN_HALF, 1 << (need - 1).bit_length())


def tiles_per_batch(resolution: int) -> tuple[int, int]:
    """(columns, rows) of tiles in one framebuffer."""
    span = half_size(resolution) - 2 * MARGIN
    return span // (3 * resolution), span // resolution


def _triangle_texture(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(rows, TEXTURE_WIDTH, 4) float32: per triangle its first corner and unit normal (from
    the float32 corners the rasteriser draws; zero for a degenerate triangle: its distance is
    NaN and it is discarded, if it ever covers a pixel centre)."""
    corners = vertices.astype(np.float64)[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    texels = np.zeros((2 * len(faces), 4), dtype=np.float32)
    texels[0::2, :3] = vertices[faces[:, 0]]
    texels[1::2, :3] = normal
    rows = max(1, -(-len(texels) // TEXTURE_WIDTH))
    out = np.zeros((rows * TEXTURE_WIDTH, 4), dtype=np.float32)
    out[:len(texels)] = texels
    return out.reshape(rows, TEXTURE_WIDTH, 4)


class Rasteriser:
    """One GL context and the scene's buffers; ``draw(eyes, frames, near, weight)`` renders
    hemicubes.  vertices (v, 3) float32 local units, faces (f, 3) int64, resolution R (even),
    max_distance local units (inf: none), backfaces 'occlude' | 'ignore', cull: draw culled
    runs of clusters (True) or the whole mesh per point (False); None: culled from
    CULL_MIN_TRIANGLES triangles.  The values are the same bits either way.

    When culling, the triangles are held in Morton order (``order``: drawn triangle i is
    faces[order[i]]; ``ibo``, the triangle texture and ``vao`` follow it)."""

    def __init__(self, vertices, faces, resolution: int, max_distance: float,
                 backfaces: str = "occlude", cull: bool | None = None):
        import moderngl

        self.resolution = hemicube_cells.check_resolution(resolution)
        vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        faces = np.asarray(faces, dtype=np.int64)
        self.cull = len(faces) >= CULL_MIN_TRIANGLES if cull is None else bool(cull)
        self.order = None
        if self.cull:
            self.order = morton_order(vertices.astype(np.float64)[faces].mean(axis=1))
            faces = faces[self.order]
        faces = np.ascontiguousarray(faces, dtype=np.uint32)
        self.ctx = ctx = moderngl.create_standalone_context(backend="egl")
        self.program = ctx.program(
            vertex_shader=VERTEX_SHADER,
            fragment_shader=FRAGMENT_SHADER.replace("%(width)d", str(TEXTURE_WIDTH)))
        self.vbo = ctx.buffer(vertices.tobytes())
        self.ibo = ctx.buffer(faces.tobytes())
        self.vao = ctx.vertex_array(self.program, [(self.vbo, "3f", "in_position")],
                                    index_buffer=self.ibo, index_element_size=4)
        table = _triangle_texture(vertices, faces.astype(np.int64))
        self.texture = ctx.texture((TEXTURE_WIDTH, table.shape[0]), 4, table.tobytes(),
                                   dtype="f4")
        self.texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.texture.use(0)
        self.program["triangles"].value = 0
        self.program["resolution"].value = float(self.resolution)
        limited = math.isfinite(max_distance) and max_distance < 3.0e38
        self.program["limited"].value = limited
        self.program["max_distance"].value = float(max_distance) if limited else 0.0
        self.half = half_size(self.resolution)
        size = (2 * self.half, 2 * self.half)
        self.colour = ctx.renderbuffer(size, components=1, dtype="f1")
        self.depth = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer(color_attachments=[self.colour], depth_attachment=self.depth)
        self.fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        # '<=', not '<': with a near plane tiny against the scene (a point at the local
        # origin with a tiny triangle has an offset of ~1e-11) the depth 1 - near / w of
        # everything rounds to the cleared 1.0 in a 24-bit buffer, and '<' would drop it
        ctx.depth_func = "<="
        # hemicube_cells' face frames are right-handed and look along +forward, so a triangle
        # whose (counter-clockwise) front faces the eye is drawn clockwise
        ctx.front_face = "cw"
        if backfaces == "ignore":
            ctx.enable(moderngl.CULL_FACE)
            ctx.cull_face = "back"
        elif backfaces != "occlude":
            raise ValueError(f"backfaces must be 'occlude' or 'ignore', got {backfaces!r}")
        self.info = {key: str(ctx.info.get(key)) for key in ("GL_RENDERER", "GL_VERSION")}
        if self.cull:
            self.culled_program = ctx.program(
                vertex_shader=CULLED_VERTEX_SHADER,
                fragment_shader=CULLED_FRAGMENT_SHADER.replace("%(width)d",
                                                               str(TEXTURE_WIDTH)))
            for name in ("triangles", "resolution", "limited", "max_distance"):
                self.culled_program[name].value = self.program[name].value
            self.clusters = cluster_boxes(vertices, faces.astype(np.int64),
                                          CLUSTER_TRIANGLES)
            self._buffers(5 * CULL_GROUP * 16)

    def _buffers(self, commands: int) -> None:
        """The culled draw's command and record buffers, room for ``commands``, and its vertex
        array (the records are per-instance attributes: a command's baseInstance picks its
        record)."""
        self.commands = self.ctx.buffer(reserve=20 * commands)
        self.records = self.ctx.buffer(reserve=8 * commands)
        self.culled_vao = self.ctx.vertex_array(
            self.culled_program,
            [(self.vbo, "3f", "in_position"), (self.records, "1i 1i /i", "in_face", "in_base")],
            index_buffer=self.ibo, index_element_size=4)

    def _set_point(self, program, eye, frame, near, x: int, y: int) -> None:
        """Viewport, scissor and uniforms of the point whose tile is at (x, y)."""
        r = self.resolution
        self.ctx.viewport = (x, y, 3 * r, r)
        self.ctx.scissor = (x, y, 3 * r, r)
        program["eye"].value = tuple(float(c) for c in eye)
        # GLSL's mat3 from 9 floats is column-major: columns t, b, n
        program["frame"].write(np.ascontiguousarray(frame, dtype=np.float32))
        program["near"].value = float(near)
        program["origin"].value = (float(x), float(y))

    def _draw_whole(self, eyes, frames, near, tiles_at) -> None:
        """Each point's five faces as one instanced draw of every triangle."""
        for i, (x, y) in tiles_at:
            self._set_point(self.program, eyes[i], frames[i], near[i], x, y)
            self.vao.render(instances=5)

    def _draw_culled(self, eyes, frames, near, tiles_at) -> None:
        """Each point's five faces as one multi-draw of the runs of clusters that may reach
        them (``cull_commands``; CULL_GROUP points culled at a time)."""
        import moderngl

        program = self.culled_program
        for g in range(0, len(tiles_at), CULL_GROUP):
            group = tiles_at[g:g + CULL_GROUP]
            index = np.array([i for i, _ in group])
            commands, records, point = cull_commands(
                self.clusters, eyes[index].astype(np.float64),
                frames[index].astype(np.float64), near[index].astype(np.float64))
            if len(commands) > self.commands.size // 20:
                self._buffers(2 * len(commands))
            self.commands.write(commands.tobytes())
            self.records.write(records.tobytes())
            bounds = np.searchsorted(point, np.arange(len(group) + 1))
            for k, (i, (x, y)) in enumerate(group):
                count = int(bounds[k + 1] - bounds[k])
                if count:
                    self._set_point(program, eyes[i], frames[i], near[i], x, y)
                    self.culled_vao.render_indirect(self.commands, moderngl.TRIANGLES,
                                                    count, int(bounds[k]))

    def draw(self, eyes, frames, near, weight, keep_tiles: bool = False) -> dict:
        """Hemicubes of the points with eyes (n, 3) float32, frames (n, 3, 3) float32 (rows t,
        b, n) and near planes (n,) float32, reduced batch by batch with ``weight`` (R, 3R)
        float64 (``hemicube_cells.weights``): {"ao": (n,) float64 the open pixels' weight,
        "blocked_pixels": (n,) int64} and with keep_tiles "tiles" (n, R, 3R) uint8, 255
        where the pixel's ray is blocked."""
        r = self.resolution
        columns, rows = tiles_per_batch(r)
        per_batch = columns * rows
        n = len(eyes)
        ao = np.empty(n)
        blocked = np.empty(n, dtype=np.int64)
        tiles = np.empty((n, r, 3 * r), dtype=np.uint8) if keep_tiles else None
        base = self.half + MARGIN
        draw = self._draw_culled if self.cull else self._draw_whole
        for start in range(0, n, per_batch):
            count = min(per_batch, n - start)
            used_rows = -(-count // columns)
            region = (base, base, (columns if used_rows > 1 else count) * 3 * r,
                      used_rows * r)
            self.ctx.scissor = None
            self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=region)
            # (point, its tile's lower-left corner): tiles row-major from (base, base)
            draw(eyes, frames, near,
                 [(start + k, (base + (k % columns) * 3 * r, base + (k // columns) * r))
                  for k in range(count)])
            self.ctx.scissor = None
            data = np.frombuffer(self.fbo.read(viewport=region, components=1), dtype=np.uint8)
            # (rows of tiles, R, columns of tiles, 3R) -> (tile, R, 3R), tiles row-major
            image = data.reshape(used_rows, r, region[2] // (3 * r), 3 * r)
            batch = image.transpose(0, 2, 1, 3).reshape(-1, r, 3 * r)[:count]
            is_open = batch == 0
            # each tile's sum on its own contiguous row (pairwise summation of 3R^2 values):
            # the same bits whatever the batch holds
            ao[start:start + count] = np.where(is_open, weight, 0.0).reshape(count, -1).sum(axis=1)
            blocked[start:start + count] = 3 * r * r - np.count_nonzero(is_open, axis=(1, 2))
            if tiles is not None:
                tiles[start:start + count] = batch
        out = {"ao": ao, "blocked_pixels": blocked}
        if tiles is not None:
            out["tiles"] = tiles
        return out

    def release(self) -> None:
        self.ctx.release()


def _threads(inputs: dict) -> None:
    """llvmpipe's rasteriser threads (LP_NUM_THREADS, read when a context is made): the
    bake's ``threads``; the values do not depend on it."""
    threads = int(inputs.get("threads", 0))
    if threads > 0:
        os.environ["LP_NUM_THREADS"] = str(threads)


def render(inputs: dict) -> dict:
    """The child's work.  inputs: vertices (v, 3) float32 and faces (f, 3) int64 (local
    units), eyes (n, 3) float32, frames (n, 3, 3) float32 (rows t, b, n), near (n,) float32,
    resolution, max_distance (local units, inf: none), weighting ('cosine' | 'uniform'),
    backfaces ('occlude' | 'ignore'), threads (llvmpipe's), keep_tiles (bool), optionally
    cull (1 culled, 0 whole, -1 or absent: by the mesh's size; the same values).  outputs: ao
    (n,) float64 the weight of the open pixels (1 = open), blocked_pixels (n,) int64,
    renderer and gl_version (str), and with keep_tiles the tiles (n, R, 3R) uint8."""
    _threads(inputs)
    resolution = int(inputs["resolution"])
    weight = hemicube_cells.weights(resolution, str(inputs["weighting"]))
    cull = inputs.get("cull")
    cull = None if cull is None or int(cull) < 0 else bool(cull)
    raster = Rasteriser(inputs["vertices"], inputs["faces"], resolution,
                        float(inputs["max_distance"]), str(inputs["backfaces"]), cull)
    try:
        out = raster.draw(inputs["eyes"], inputs["frames"], inputs["near"], weight,
                          bool(inputs.get("keep_tiles", False)))
    finally:
        raster.release()
    out["renderer"] = np.array(raster.info["GL_RENDERER"])
    out["gl_version"] = np.array(raster.info["GL_VERSION"])
    return out


def probe(inputs: dict) -> dict:
    """The child's check that a context can be made: its renderer and version."""
    import moderngl

    ctx = moderngl.create_standalone_context(backend="egl")
    try:
        return {"renderer": np.array(str(ctx.info.get("GL_RENDERER"))),
                "gl_version": np.array(str(ctx.info.get("GL_VERSION")))}
    finally:
        ctx.release()
