"""The lightmap of a set of instances: one image, one region per baked instance.

Instances of one mesh share its UVs but not its lighting, so each baked instance gets a
region of its own in one atlas, and a material that reads it through the instance's scale
and offset (glTF's ``KHR_texture_transform``; the engines' per-instance lightmap scale and
offset: Unity's ``lightmapScaleOffset``, Unreal's per-component lightmap coordinates).

What each mesh is laid out in (its *layout*, made once and shared by every instance of it):

* its own UVs (set 0) when they can be baked as they are: every face inside [0, 1]^2 (a
  region cannot repeat a tile), no texel centre covered twice at the image's resolution
  (``uvcheck.check_uvs``; ``--uv-overlap average`` keeps overlapping ones, ``refuse``
  refuses them), as a lightmap of the mesh alone decides;
* else one new xatlas atlas of the unique mesh (``--unwrap always`` asks for it), packed
  for the side of its smallest region (not below a quarter of its largest): ``padding``
  texels around every chart at that size, more in larger regions.

Regions (:func:`place`): the layout's UV bounding box, scaled by s texels per UV unit, with
``padding`` texels of margin on every side (two regions' texels are at least 2 padding
apart, so each one's gutters are its own), packed in shelves (tallest first) into the image.
``--instance-regions density`` (default): s = D sqrt(A / a), A the instance's surface area
in scene units (its mesh's area times its transform's scale), a its layout's UV area, so
every instance has the same D texels per scene unit; ``mesh``: every instance of a mesh the
s of the mean A of its baked instances (one region size per mesh, as an engine that sizes
lightmaps per mesh does).  D is the largest that fits the image (``--resolution``), or the
one asked for (``--texel-density``: the smallest square image that holds the regions).

The set's layout is then the flattened scene's own UVs (instance k's region coordinates,
uv_atlas = offset_k + scale_k uv_layout) and baked as any own UVs are
(``atlas.make_atlas``): one rasterisation of the whole image, texel jitter and point ids
of the whole image, seams and gutters as for one mesh (no seam crosses two instances: they
share no vertex).  So the set's atlas is, bit for bit, the lightmap of the flattened scene
whose UVs are the atlas's, and each region is the lightmap of that instance's faces with
every other instance occluding (``tests/test_instances_atlas.py``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from aobake.errors import InputError

log = logging.getLogger(__name__)

#: the UV area assumed for a mesh's new atlas before it is made (its packing's coverage)
FIRST_COVERAGE = 0.6
#: a new atlas is packed for at least this share of its mesh's largest region side
MIN_UNWRAP_SHARE = 0.25
#: ... and never for fewer texels a side than this
MIN_UNWRAP_SIDE = 16
#: re-unwrap a mesh when its smallest region shrank below this share of the side it was
#: packed for (its charts' gutters would shrink with it); at most UNWRAPS unwraps a mesh
REUNWRAP_SHARE = 0.9
UNWRAPS = 3


@dataclass
class MeshLayout:
    """The UVs a mesh's instances are baked in (shared by every instance of it).

    mesh : index into ``Instances.meshes``; name : its name; kind : "own" (its UV set 0) or
    "xatlas" (a new atlas of the unique mesh); uv : (L, 2) float64 layout UVs (OBJ
    convention); faces : (f, 3) int64 into ``uv``, in the corner order of the mesh's faces;
    vertex : (L,) int64 the mesh vertex of each layout vertex; lo, hi : (2,) the bounding
    box of the UVs its faces use; area : float their UV area (|signed area| summed); charts
    : a new atlas's chart count; side : the side (texels) a new atlas was packed for; own :
    (v, 2) float64 | None the mesh's own UVs (kept beside a new atlas for base colours).
    """

    mesh: int
    name: str
    kind: str
    uv: np.ndarray
    faces: np.ndarray
    vertex: np.ndarray
    lo: np.ndarray = field(default_factory=lambda: np.zeros(2))
    hi: np.ndarray = field(default_factory=lambda: np.ones(2))
    area: float = FIRST_COVERAGE
    charts: int | None = None
    side: int | None = None
    own: np.ndarray | None = None
    charting: str | None = None
    packing_compiled: bool | None = None

    def __post_init__(self):
        if len(self.faces):
            corners = self.uv[self.faces].reshape(-1, 2)
            self.lo, self.hi = corners.min(axis=0), corners.max(axis=0)
            t = self.uv[self.faces]
            self.area = float(0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                                           - (t[:, 1, 1] - t[:, 0, 1])
                                           * (t[:, 2, 0] - t[:, 0, 0])).sum())

    def record(self) -> dict:
        return {"mesh": self.name, "uvs": "own UVs (set 0)" if self.kind == "own" else
                "new xatlas atlas of the mesh", "charts": self.charts,
                "packed_for_side": self.side, "uv_box": [*self.lo.tolist(), *self.hi.tolist()],
                "uv_area": self.area}


@dataclass(frozen=True)
class Region:
    """One baked instance's part of the set's atlas.

    instance : its place in the bake (k, the baked instances' order); name, node, mesh :
    the instance's; x, y, width, height : the region in texels (x from the left column, y
    from the top row), its margin of ``padding`` texels around it not included; scale :
    texels per layout UV unit; density : texels per scene unit along its surface;
    offset, uv_scale : (2,) OBJ-convention UVs (v = 0 at the bottom): atlas = offset +
    uv_scale * layout UV.
    """

    instance: int
    name: str
    node: str
    mesh: str
    x: int
    y: int
    width: int
    height: int
    scale: float
    density: float
    offset: tuple
    uv_scale: tuple

    def texture_transform(self) -> dict:
        """glTF's ``KHR_texture_transform`` of the region (glTF UVs: v = 0 at the top):
        uv' = offset + scale * uv."""
        su, sv = self.uv_scale
        return {"offset": [float(self.offset[0]), float(1.0 - self.offset[1] - sv)],
                "scale": [float(su), float(sv)]}

    def record(self) -> dict:
        return {"instance": self.instance, "name": self.name, "node": self.node,
                "mesh": self.mesh, "x": self.x, "y": self.y, "width": self.width,
                "height": self.height, "texels_per_unit": self.density,
                "uv_offset": [float(v) for v in self.offset],
                "uv_scale": [float(v) for v in self.uv_scale],
                "KHR_texture_transform": self.texture_transform()}


@dataclass
class SetLayout:
    """The set's atlas: each mesh's layout and each baked instance's region (``Atlas.instances``).

    layouts : {mesh index: MeshLayout}; regions : [Region] in the bake's order; mode :
    ``--instance-regions``; density : D (texels per scene unit; with mode "mesh", per
    scene unit on an instance of a mesh's mean area); size : (width, height) of the image;
    padding : margin texels around each region; vertex_start : (k + 1,) where each
    instance's layout vertices start in the set's UV array; geometry : {mesh index:
    (vertices (v, 3) mesh units, normals (v, 3) mesh units | None, face_material (f,) |
    None)} what a GLB of the set stores once per mesh; transforms : (k, 4, 4) each region's
    instance, mesh -> scene units.
    """

    layouts: dict
    regions: list
    mode: str
    density: float
    size: tuple
    padding: int
    vertex_start: np.ndarray = field(repr=False, default=None)
    geometry: dict = field(repr=False, default_factory=dict)
    transforms: np.ndarray = field(repr=False, default=None)

    def gltf(self) -> tuple[list, list]:
        """(meshes, instances) as ``aobake.outputs.glb.write_textured_instances`` takes them."""
        order = sorted(self.layouts)
        index = {m: n for n, m in enumerate(order)}
        meshes = []
        for m in order:
            layout = self.layouts[m]
            vertices, normals, face_material = self.geometry[m]
            meshes.append({"name": layout.name, "positions": vertices, "normals": normals,
                           "uv": layout.uv, "faces": layout.faces, "vertex": layout.vertex,
                           "own_uv": layout.own,
                           "face_material": face_material})
        by_name = {layout.name: m for m, layout in self.layouts.items()}
        instances = [{"name": region.name, "mesh": index[by_name[region.mesh]],
                      "matrix": self.transforms[k], "transform": region.texture_transform(),
                      "extras": {"aobake_region": [region.x, region.y, region.width,
                                                   region.height]}}
                     for k, region in enumerate(self.regions)]
        return meshes, instances

    def record(self) -> dict:
        """The report's ``texture.instances``: how the regions were sized and where each is."""
        width, height = self.size
        return {"regions": "one per baked instance, in the bake's order",
                "sizing": {"density": "the same texels per scene unit on every instance (its "
                                      "world area)",
                           "mesh": "one region size per mesh (its instances' mean area)"}
                [self.mode], "instance_regions": self.mode, "texels_per_unit": self.density,
                "margin": self.padding,
                "convention": "x, y, width, height in texels, y from the top row, margin "
                              "not included; uv_offset / uv_scale in OBJ UVs (v up): atlas = "
                              "offset + scale * layout; KHR_texture_transform in glTF UVs "
                              "(v down)",
                "size": [width, height],
                "meshes": [layout.record() for _, layout in sorted(self.layouts.items())],
                "placed": [region.record() for region in self.regions]}


# ---------------------------------------------------------------------------------------------
# the meshes' layouts


def _mesh_faces(instances, m) -> np.ndarray:
    return np.asarray(instances.meshes[m][1], dtype=np.int64)


def _own_layout(scene, m, width, height, config, warnings) -> MeshLayout | None:
    """Mesh ``m``'s own UVs as its layout when a lightmap may bake them (module docstring),
    else None (a new atlas); InputError where ``--uv-overlap refuse`` or ``--no-unwrap``
    forbids the alternative."""
    from aobake.targets.texels.seams import degenerate_faces
    from aobake.targets.texels.uvcheck import check_uvs

    instances = scene.instances
    name = instances.mesh_names[m]
    uvs = instances.uvs[m] if m < len(instances.uvs) else None
    if uvs is None or config.unwrap == "always":
        if uvs is None and config.unwrap == "never":
            raise InputError(f"{scene.source}: mesh {name!r} has no UVs and --no-unwrap was "
                             "given")
        return None
    vertices, faces = instances.meshes[m][0], _mesh_faces(instances, m)
    check = check_uvs(uvs, faces, width, height,
                      has_area=~degenerate_faces(np.asarray(vertices, np.float64), faces))
    layout = MeshLayout(m, name, "own", uvs, faces, np.arange(len(uvs), dtype=np.int64),
                        own=uvs)
    what = f"{scene.source}: mesh {name!r}"
    if check.out_of_range_faces:
        text = (f"{what}: {check.out_of_range_faces} faces' UVs reach outside [0, 1]: a region "
                "of the set's atlas cannot repeat them")
        if config.unwrap == "never":
            raise InputError(f"{text} (--no-unwrap): give the mesh UVs in [0, 1]")
        warnings.append(f"{text}; made a new atlas of the mesh with xatlas")
        return None
    if check.valid:
        return layout
    if check.overlapping_texels:
        if config.uv_overlap == "refuse":
            raise InputError(f"{what}: the own UVs overlap (--uv-overlap refuse): "
                             f"{check.message}")
        if config.uv_overlap == "average" and check.bakeable:
            warnings.append(f"{what}: baking the overlapping own UVs as asked (--uv-overlap "
                            f"average): {check.message}; each shared texel is the mean of "
                            "the surfaces that share it")
            return layout
    if config.unwrap == "never":
        warnings.append(f"{what}: baking into its own UVs although {check.message}")
        return layout
    warnings.append(f"{what}: its UVs cannot be baked ({check.message}); made a new atlas of "
                    "the mesh with xatlas")
    return None


def _unwrapped(scene, m, side, padding, compiled, own) -> MeshLayout:
    """A new xatlas atlas of mesh ``m`` (mesh units) packed for ``side`` texels."""
    from aobake.targets.texels.unwrap import unwrap

    instances = scene.instances
    vertices = np.asarray(instances.meshes[m][0], dtype=np.float64)
    faces = _mesh_faces(instances, m)
    try:
        result = unwrap(vertices, faces, (side, side), padding, compiled=compiled)
    except InputError as exc:
        raise InputError(f"{scene.source}: mesh {instances.mesh_names[m]!r}: {exc}") from None
    if not np.array_equal(result.vmapping[result.faces], faces):
        raise RuntimeError("xatlas changed the face order")
    return MeshLayout(m, instances.mesh_names[m], "xatlas", result.uv, result.faces,
                      np.asarray(result.vmapping, dtype=np.int64), charts=result.charts,
                      side=int(side), own=own, charting=result.charting,
                      packing_compiled=result.packing_compiled)


# ---------------------------------------------------------------------------------------------
# the regions


def _growth(scene, layouts, mode) -> np.ndarray:
    """(k,) float64 g per baked instance: its scale s = D g texels per layout UV unit."""
    instances = scene.instances
    areas = scene.areas()
    offsets = instances.face_offsets
    own_area = np.array([float(areas[offsets[k]:offsets[k + 1]].sum())
                         for k in range(len(instances.baked))])
    meshes = instances.mesh[instances.baked]
    if mode == "mesh":  # one size per mesh: its baked instances' mean area
        for m in np.unique(meshes):
            own_area[meshes == m] = own_area[meshes == m].mean()
    uv_area = np.array([max(layouts[m].area, 1e-12) for m in meshes])
    return np.sqrt(np.maximum(own_area, 0.0) / uv_area)


def _sizes(scene, layouts, growth, density) -> np.ndarray:
    """(k, 2) int64 each region's (width, height) in texels at density ``density``."""
    meshes = scene.instances.mesh[scene.instances.baked]
    box = np.array([layouts[m].hi - layouts[m].lo for m in meshes])
    return np.maximum(1, np.ceil(density * growth[:, None] * box - 1e-9)).astype(np.int64)


def shelves(cells, width: int, height: int | None = None):
    """Shelf packing: (k, 2) places (x, y) of the cells (k, 2) (width, height), tallest first
    (ties: wider, then in order) left to right in rows of the tallest, into ``width`` columns
    and (if given) ``height`` rows; None when they do not fit.  Also returns the rows used."""
    cells = np.asarray(cells, dtype=np.int64)
    order = np.lexsort((np.arange(len(cells)), -cells[:, 0], -cells[:, 1]))
    place = np.zeros((len(cells), 2), dtype=np.int64)
    x = y = row = 0
    for k in order.tolist():
        w, h = int(cells[k, 0]), int(cells[k, 1])
        if w > width:
            return None, None
        if x + w > width:
            y, x, row = y + row, 0, 0
        place[k] = (x, y)
        x, row = x + w, max(row, h)
        if height is not None and y + row > height:
            return None, None
    return place, y + row


def place(scene, layouts, mode, width, height, padding, texel_density=None):
    """(D, sizes (k, 2), places (k, 2) of each region's top-left margin corner, (width,
    height)): the largest D whose regions fit ``width`` x ``height``, or at
    ``texel_density`` the smallest square that holds them.  InputError when none fits."""
    from aobake.targets.texels.packing import MAX_RESOLUTION

    growth = _growth(scene, layouts, mode)
    margin = 2 * int(padding)
    if texel_density is not None:
        density = float(texel_density)
        cells = _sizes(scene, layouts, growth, density) + margin
        side = max(int(math.ceil(math.sqrt(float((cells[:, 0] * cells[:, 1]).sum())))),
                   int(cells.max()))
        while side <= MAX_RESOLUTION:
            places, used = shelves(cells, side, side)
            if places is not None:
                return density, cells - margin, places, (side, side)
            side = max(side + 1, int(math.ceil(side * 1.01)))
        raise InputError(f"{scene.source}: the {len(cells)} instances' regions at texel "
                         f"density {density:g} need an image larger than {MAX_RESOLUTION}x"
                         f"{MAX_RESOLUTION}: lower --texel-density")
    meshes = scene.instances.mesh[scene.instances.baked]
    box = np.array([np.prod(layouts[m].hi - layouts[m].lo) for m in meshes])
    total = float((growth ** 2 * np.maximum(box, 1e-12)).sum())
    high = math.sqrt(width * height / total) if total > 0 else 1.0
    low, best = 0.0, None
    for _ in range(48):  # bisection on D: the packing fits at low, not at high
        middle = 0.5 * (low + high)
        cells = _sizes(scene, layouts, growth, middle) + margin
        places, _ = shelves(cells, width, height)
        if places is None:
            high = middle
        else:
            low, best = middle, (middle, cells - margin, places)
        if high - low <= 1e-4 * high:
            break
    if best is None:
        need = int(margin + 1)
        raise InputError(f"{scene.source}: {len(meshes)} instances' regions, each at least "
                         f"{need}x{need} texels with --padding {padding}, do not fit "
                         f"{width}x{height}: raise --resolution or lower --padding")
    return (*best, (width, height))


# ---------------------------------------------------------------------------------------------
# the atlas


def _corner_order(placed: np.ndarray, own: np.ndarray, source, name) -> np.ndarray:
    """(f, 3) int64: corner c of the placed face is corner [c] of the mesh's face (a
    mirroring transform reverses the faces it places; ``--fix-normals fix`` may flip some)."""
    same = np.all(placed == own, axis=1)
    order = np.tile(np.arange(3), (len(own), 1))
    if same.all():
        return order
    hit = placed[~same][:, :, None] == own[~same][:, None, :]  # (g, 3 placed, 3 own)
    if not np.all(hit.any(axis=2)):
        raise InputError(f"{source}: an instance of mesh {name!r} does not have the mesh's "
                         "faces: its lightmap region cannot share the mesh's UVs")
    order[~same] = np.argmax(hit, axis=2)
    return order


def _geometry(scene, layouts) -> dict:
    """``SetLayout.geometry``: each mesh's vertices (mesh units), its first baked instance's
    vertex normals mapped back by its transform (normals map by the inverse transpose, so
    back by the transpose), and that instance's face materials (one per mesh face)."""
    instances = scene.instances
    out = {}
    for k, i in enumerate(instances.baked.tolist()):
        m = int(instances.mesh[i])
        if m in out:
            continue
        v0, v1 = instances.vertex_offsets[k], instances.vertex_offsets[k + 1]
        f0, f1 = instances.face_offsets[k], instances.face_offsets[k + 1]
        normals = scene.vertex_normals[v0:v1] @ instances.transforms[i, :3, :3]
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
        material = None if scene.face_material is None else scene.face_material[f0:f1]
        out[m] = (np.asarray(instances.meshes[m][0], dtype=np.float64), normals, material)
    return out


def make_set_atlas(scene, config, width, height, threads, warnings, timings, compiled,
                   phase=lambda name: None):
    """``atlas.make_atlas``'s result for a scene of instances: (atlas, bake_uv, bake_faces_uv,
    uv_check, samples), ``atlas.instances`` the :class:`SetLayout` (module docstring)."""
    import time

    from aobake.targets.texels.atlas import Atlas, check_texture_budget, split_corners
    from aobake.targets.texels.packing import MAX_RESOLUTION
    from aobake.targets.texels.raster import rasterize
    from aobake.targets.texels.seams import degenerate_faces
    from aobake.targets.texels.unwrap import discard_prestarted
    from aobake.targets.texels.uvcheck import bake_collapsed, check_uvs, wrap_uvs

    instances = scene.instances
    padding = int(config.padding)
    mode = getattr(config, "instance_regions", "density")
    density_given = config.texel_density
    clock = time.perf_counter()
    meshes = [int(m) for m in dict.fromkeys(instances.mesh[instances.baked].tolist())]
    check_side = (max(width, height) if density_given is None else
                  min(MAX_RESOLUTION, max(MIN_UNWRAP_SIDE, 1024)))
    layouts, pending = {}, []
    for m in meshes:
        layout = _own_layout(scene, m, check_side, check_side, config, warnings)
        if layout is None:
            uvs = instances.uvs[m] if m < len(instances.uvs) else None
            layouts[m] = MeshLayout(m, instances.mesh_names[m], "xatlas",
                                    np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                                    np.zeros((0, 3), np.int64), np.zeros(0, np.int64),
                                    area=FIRST_COVERAGE, own=uvs)
            pending.append(m)
        else:
            layouts[m] = layout
    timings["uv_check_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    unwraps = dict.fromkeys(pending, 0)
    for _ in range(UNWRAPS + 1):
        density, sizes, places, size = place(scene, layouts, mode, width, height, padding,
                                             density_given)
        redo = []
        baked_mesh = instances.mesh[instances.baked]
        for m in pending:
            sides = sizes[baked_mesh == m].max(axis=1)
            want = int(max(MIN_UNWRAP_SIDE, sides.min(), math.ceil(MIN_UNWRAP_SHARE *
                                                                     sides.max())))
            want = min(want, MAX_RESOLUTION)
            side = layouts[m].side
            if unwraps[m] < UNWRAPS and (side is None or want < REUNWRAP_SHARE * side):
                redo.append((m, want))
        if not redo:
            break
        phase("unwrapping")
        for m, want in redo:
            layouts[m] = _unwrapped(scene, m, want, padding, compiled, layouts[m].own)
            unwraps[m] += 1
    timings["unwrap_s"] = time.perf_counter() - clock
    discard_prestarted()  # (the CLI's prestarted xatlas child, where no mesh unwrapped)
    width, height = size
    check_texture_budget(width, height, config.texel_samples)
    # each baked instance's region: its layout's UVs mapped, faces in its own corner order
    regions, uv_parts, face_parts, start = [], [], [], [0]
    offsets_v, offsets_f = instances.vertex_offsets, instances.face_offsets
    for k, i in enumerate(instances.baked.tolist()):
        m = int(instances.mesh[i])
        layout = layouts[m]
        x, y = (int(places[k, 0]) + padding, int(places[k, 1]) + padding)
        w, h = int(sizes[k, 0]), int(sizes[k, 1])
        # s texels per UV unit; the box's longer side decides (the other rounds up)
        box = layout.hi - layout.lo
        s = min(w / box[0] if box[0] > 0 else math.inf, h / box[1] if box[1] > 0 else math.inf)
        s = float(s if math.isfinite(s) else max(w, h))
        uv_scale = (s / width, s / height)
        offset = ((x - s * layout.lo[0]) / width, 1.0 - (y + s * layout.hi[1]) / height)
        placed = np.asarray(scene.faces[offsets_f[k]:offsets_f[k + 1]] - offsets_v[k])
        order = _corner_order(placed, _mesh_faces(instances, m), scene.source, layout.name)
        uv_parts.append(np.asarray(offset) + np.asarray(uv_scale) * layout.uv)
        face_parts.append(np.take_along_axis(layout.faces, order, axis=1) + start[-1])
        start.append(start[-1] + len(layout.uv))
        area = float(scene.areas()[offsets_f[k]:offsets_f[k + 1]].sum())
        covered = s * s * layout.area
        regions.append(Region(k, instances.names[i], instances.nodes[i], layout.name, x, y, w,
                              h, s, math.sqrt(covered / area) if area > 0 else 0.0,
                              offset, uv_scale))
    uv = np.concatenate(uv_parts)
    faces_uv = np.concatenate(face_parts)
    # baked as own UVs: the flattened scene's, whose UVs are the atlas's (all in [0, 1])
    phase("rasterising")
    clock = time.perf_counter()
    samples = rasterize(uv, faces_uv, width, height, config.texel_samples, config.seed,
                        threads=threads, compiled=compiled)
    timings["raster_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    has_area = ~degenerate_faces(scene.vertices, scene.faces)
    check = check_uvs(uv, faces_uv, width, height, shared=samples.shared,
                      layout=wrap_uvs(uv, faces_uv), has_area=has_area)
    if check.collapsed_faces:  # faces with area whose UVs have none: baked, said so
        samples, collapsed = bake_collapsed(samples, uv, faces_uv, has_area)
        warnings.append(f"{scene.source}: {collapsed.message()}")
    timings["uv_check_s"] += time.perf_counter() - clock
    keys, faces = split_corners(scene.faces, faces_uv)
    atlas = Atlas(scene.vertices[keys[:, 0]], scene.vertex_normals[keys[:, 0]], faces,
                  uv[keys[:, 1]], None, keys[:, 0], new=True, materials=scene.materials,
                  face_material=scene.face_material, size=(width, height))
    # atlas.new: the map is laid out in regions, so the input's UVs alone do not read it
    atlas.charts = sum(layouts[int(instances.mesh[i])].charts or 0
                       for i in instances.baked.tolist()) or None
    made = [layout for layout in layouts.values() if layout.kind == "xatlas"]
    if made:  # which xatlas charted, which packer packed (the report's, as for one mesh)
        atlas.charting = made[0].charting
        atlas.packing_compiled = made[0].packing_compiled
    atlas.instances = SetLayout(layouts, regions, mode, float(density), (width, height),
                                padding, np.asarray(start, dtype=np.int64),
                                _geometry(scene, layouts),
                                instances.transforms[instances.baked])
    log.info("%s: %d instances of %d meshes in a %dx%d atlas, %.4g texels per unit",
             scene.source, len(regions), len(layouts), width, height, density)
    return atlas, uv, faces_uv, check, samples
