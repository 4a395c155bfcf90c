"""The depth-map baker's GPU side: OpenGL 4.3 through moderngl on a headless EGL context, run
in a child process (``aobake.child``), never in the baker's own (a driver can take its process
down).  ``render(inputs) -> outputs`` takes and returns arrays; imports numpy and moderngl
only.

Per direction w_k (k = 0 .. K-1, in order):

1. **The map.**  The scene drawn orthographically along -w_k into an N x N float32 *height*
   map: each texel keeps the largest height h = (x - c) . w_k of the triangles covering its
   centre (the first surface met coming from infinity along -w_k; a depth buffer keeps the
   nearest, the colour its exact float32 height, interpolated at the texel centre).  The map
   spans the scene's bounding sphere (centre c, radius rho) on the plane spanned by
   (e1_k, e2_k): texel (i, j) covers [-H + i s, -H + (i + 1) s] x ..., s = 2 H / N, H a hair
   above rho; a texel no triangle covers keeps EMPTY (below every height).  Depend on the
   scene alone: any set of points reads the same maps.
2. **The points.**  A compute shader over the point buffer: point p with unit normal n reads
   the texel its projection falls in (nearest: no filtering) and is *open* along w_k when

       h_map <= (p - c) . w_k + b s / (n . w_k)           (slope-scaled bias)

   b = the bias in texels (``depthmaps_bias``).  The bias is what a flat surface needs not to
   shadow itself: the map holds the surface's height at a texel centre up to s / sqrt 2 from
   p's projection, which differs from p's by at most (s / sqrt 2) tan(theta) <= (s / sqrt 2)
   / cos(theta), theta the angle between n and w_k; b >= 1/sqrt 2 covers it (b = 1 leaves room
   for the rasteriser's 1/256-texel snapping and float32 rounding).  Geometrically, the bias
   misses exactly the occluders in a slab of height b s above p's tangent plane.
   A direction below p's horizon (n . w_k <= 0) has weight 0; above it the weight is
   n . w_k (cosine) or 1 (uniform), and p accumulates in float64, in direction order,

       open += weight [open],   total += weight,   bent += weight [open] w_k

   into its own slot of a storage buffer: no read-back per direction, and the sums of a point
   are the same bits whatever else the buffer holds (its own slot, its own order).
   With a ground plane (axis a, height g): w_k with w_k[a] < 0 is blocked (the solid below
   the plane meets every ray going down from above it), and a point flagged inside the
   ground (its lifted position p + b s n below g: computed by the parent) is blocked in
   every direction, as the ray tracer's origins below the plane are.

The sums are read back once, after the K directions.
"""

from __future__ import annotations

import os

import numpy as np

#: the height a texel no triangle covers keeps: below any point's height plus bias
EMPTY = -3.0e38
#: invocations per work group of the point pass
GROUP = 64
#: the most work groups along x (GL guarantees 65535): the most points per dispatch
MAX_GROUPS = 65535

VERTEX_SHADER = """
#version 430
in vec3 in_position;
uniform vec3 center;
uniform vec3 e1;
uniform vec3 e2;
uniform vec3 w;
uniform float inv_half;
out float height;

void main() {
    vec3 q = in_position - center;
    float h = dot(q, w);
    height = h;
    // orthographic along -w: the highest point (nearest the light at +infinity w) has the
    // smallest depth; |h| <= rho < H, so nothing of the scene is clipped
    gl_Position = vec4(dot(q, e1) * inv_half, dot(q, e2) * inv_half, -h * inv_half, 1.0);
}
"""

FRAGMENT_SHADER = """
#version 430
in float height;
out float value;

void main() {
    value = height;
}
"""

COMPUTE_SHADER = """
#version 430
layout(local_size_x = %(group)d) in;
layout(std430, binding = 0) readonly buffer Points { vec4 points[]; };    // xyz, w: inside
layout(std430, binding = 1) readonly buffer Normals { vec4 normals[]; };  // xyz unit
layout(std430, binding = 2) buffer Sums { dvec2 sums[]; };                // open, total
layout(std430, binding = 3) buffer Bent { dvec4 bent[]; };                // xyz
uniform sampler2D heights;
uniform vec3 center;
uniform vec3 e1;
uniform vec3 e2;
uniform vec3 w;
uniform float inv_half;
uniform float resolution;   // N
uniform float bias;         // b s, local units
uniform bool cosine;        // weight n . w, else 1
uniform int ground_axis;    // -1: no ground plane
uniform bool with_bent;
uniform uint n_points;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_points) return;
    vec3 n = normals[i].xyz;
    float c = dot(n, w);
    if (!(c > 0.0)) return;   // below the horizon: weight 0
    float weight = cosine ? c : 1.0;
    vec4 point = points[i];
    vec3 q = point.xyz - center;
    bool open;
    if (point.w != 0.0 || (ground_axis >= 0 && w[ground_axis] < 0.0)) {
        open = false;
    } else {
        // the texel the projection falls in (the viewport's mapping of the map's draw)
        float x = (dot(q, e1) * inv_half + 1.0) * 0.5 * resolution;
        float y = (dot(q, e2) * inv_half + 1.0) * 0.5 * resolution;
        if (x < 0.0 || y < 0.0 || x >= resolution || y >= resolution) {
            open = true;   // beyond the scene's sphere: nothing above it
        } else {
            float h = texelFetch(heights, ivec2(int(x), int(y)), 0).r;
            open = h <= dot(q, w) + bias / c;
        }
    }
    double wd = double(weight);
    sums[i] += dvec2(open ? wd : 0.0LF, wd);
    if (with_bent && open) bent[i] += dvec4(dvec3(w) * wd, 0.0LF);
}
"""


class Baker:
    """One GL 4.3 context, the scene's buffers and the map's framebuffer.  vertices (v, 3)
    float32 and faces (f, 3) int64 in local units, center (3,) and half H (the map's half
    size) local units, resolution N."""

    def __init__(self, vertices, faces, center, half: float, resolution: int):
        import moderngl

        self.ctx = ctx = moderngl.create_standalone_context(backend="egl", require=430)
        self.resolution = int(resolution)
        self.center = tuple(float(x) for x in center)
        self.inv_half = float(np.float32(1.0 / half))
        vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        faces = np.ascontiguousarray(faces, dtype=np.uint32)
        self.program = ctx.program(vertex_shader=VERTEX_SHADER,
                                   fragment_shader=FRAGMENT_SHADER)
        self.vbo = ctx.buffer(vertices.tobytes())
        self.ibo = ctx.buffer(faces.tobytes())
        self.vao = ctx.vertex_array(self.program, [(self.vbo, "3f", "in_position")],
                                    index_buffer=self.ibo, index_element_size=4)
        size = (self.resolution, self.resolution)
        self.heights = ctx.texture(size, 1, dtype="f4")
        self.heights.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer(color_attachments=[self.heights],
                                   depth_attachment=self.depth)
        self.compute = ctx.compute_shader(COMPUTE_SHADER % {"group": GROUP})
        for program in (self.program, self.compute):
            program["center"].value = self.center
            program["inv_half"].value = self.inv_half
        self.compute["heights"].value = 0
        self.compute["resolution"].value = float(self.resolution)
        self.info = {key: str(ctx.info.get(key)) for key in ("GL_RENDERER", "GL_VERSION")}

    def bake(self, directions, axes, points, normals, inside, bias: float, weighting: str,
             ground_axis: int, with_bent: bool) -> dict:
        """directions (K, 3) float32 unit, axes (K, 2, 3) float32 (e1, e2), points (P, 3) and
        normals (P, 3) float32 local units, inside (P,) bool, bias b s (local units) ->
        {"open": (P,) float64, "total": (P,) float64, "bent": (P, 3) float64 (with_bent)}."""
        import moderngl

        ctx, n = self.ctx, len(points)
        if n > GROUP * MAX_GROUPS:
            raise ValueError(f"at most {GROUP * MAX_GROUPS} points per call, got {n}")
        packed = np.zeros((max(n, 1), 4), dtype=np.float32)
        packed[:n, :3] = points
        packed[:n, 3] = inside
        unit = np.zeros((max(n, 1), 4), dtype=np.float32)
        unit[:n, :3] = normals
        point_buffer = ctx.buffer(packed.tobytes())
        normal_buffer = ctx.buffer(unit.tobytes())
        sums = ctx.buffer(np.zeros((max(n, 1), 2)).tobytes())
        bent = ctx.buffer(np.zeros((max(n, 1) if with_bent else 1, 4)).tobytes())
        for binding, buffer in enumerate((point_buffer, normal_buffer, sums, bent)):
            buffer.bind_to_storage_buffer(binding)
        cs = self.compute
        cs["bias"].value = float(bias)
        cs["cosine"].value = weighting == "cosine"
        cs["ground_axis"].value = int(ground_axis)
        cs["with_bent"].value = bool(with_bent)
        cs["n_points"].value = n
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        groups = -(-n // GROUP)
        for k in range(len(directions)):
            w = tuple(float(x) for x in directions[k])
            e1 = tuple(float(x) for x in axes[k, 0])
            e2 = tuple(float(x) for x in axes[k, 1])
            for program in (self.program, cs):
                program["w"].value = w
                program["e1"].value = e1
                program["e2"].value = e2
            self.fbo.use()
            self.fbo.clear(EMPTY, EMPTY, EMPTY, EMPTY, depth=1.0)
            self.vao.render(moderngl.TRIANGLES)
            if groups:
                self.heights.use(0)
                cs.run(groups)
                # the next dispatch reads the sums this one wrote; the next draw overwrites
                # the map this one read
                ctx.memory_barrier()
        totals = np.frombuffer(sums.read(), dtype=np.float64).reshape(-1, 2)[:n]
        out = {"open": totals[:, 0].copy(), "total": totals[:, 1].copy()}
        if with_bent:
            out["bent"] = np.frombuffer(bent.read(), dtype=np.float64).reshape(-1, 4)[:n, :3]
        for buffer in (point_buffer, normal_buffer, sums, bent):
            buffer.release()
        return out

    def release(self) -> None:
        self.ctx.release()


def _threads(inputs: dict) -> None:
    """llvmpipe's threads (LP_NUM_THREADS, read when a context is made): the bake's
    ``threads``; the values do not depend on it."""
    threads = int(inputs.get("threads", 0))
    if threads > 0:
        os.environ["LP_NUM_THREADS"] = str(threads)


def render(inputs: dict) -> dict:
    """The child's work.  inputs: vertices (v, 3) float32, faces (f, 3) int64, center (3,),
    half, resolution, directions (K, 3) float32, axes (K, 2, 3) float32, points (P, 3) and
    normals (P, 3) float32, inside (P,) bool, bias (local units), weighting ('cosine' |
    'uniform'), ground_axis (-1: none), bent (bool), threads.  outputs: open, total (P,)
    float64, bent (P, 3) float64 (with bent), renderer, gl_version."""
    _threads(inputs)
    baker = Baker(inputs["vertices"], inputs["faces"], inputs["center"],
                  float(inputs["half"]), int(inputs["resolution"]))
    try:
        out = baker.bake(inputs["directions"], inputs["axes"], inputs["points"],
                         inputs["normals"], inputs["inside"], float(inputs["bias"]),
                         str(inputs["weighting"]), int(inputs["ground_axis"]),
                         bool(inputs["bent"]))
    finally:
        baker.release()
    out["renderer"] = np.array(baker.info["GL_RENDERER"])
    out["gl_version"] = np.array(baker.info["GL_VERSION"])
    return out


def probe(inputs: dict) -> dict:
    """The child's check that a GL 4.3 context with compute shaders and float64 can be made:
    its renderer and version."""
    import moderngl

    ctx = moderngl.create_standalone_context(backend="egl", require=430)
    try:
        ctx.compute_shader(COMPUTE_SHADER % {"group": GROUP})
        return {"renderer": np.array(str(ctx.info.get("GL_RENDERER"))),
                "gl_version": np.array(str(ctx.info.get("GL_VERSION")))}
    finally:
        ctx.release()
