"""High-to-low baking (``aobake.targets.projected``): a bumpy high-poly sphere over a
low-poly sphere, both generated here.

1. the projection equals an independent float64 ray cast (numpy Moller-Trumbore over every
   source triangle): the same hits, misses and back hits, the same points;
2. the low map equals AO baked at the projected points within its error bars: the texels'
   95% intervals cover a many-ray reference at the independently projected points in >= 93%
   of (texel, seed) pairs, and errors / stderr are calibrated; per vertex the same;
3. a cage too tight: the texels whose cage rays miss are flagged (``missed``), counted in the
   report and warned of, and agree with the independent cast; a source turned inside out is
   hit on its back everywhere, and says so;
4. a cage mesh: the offset cage given as a mesh bakes the same bits; a wrong topology is
   refused with the reason;
5. outputs: the EXR holds the projection channels, the per-vertex result writes as PLY.

Tolerances are statistical bounds at a family-wise false-failure rate ``FWER`` per test.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import trimesh
from scipy import stats

import aobake
from aobake.errors import InputError
from aobake.scene import make_scene
from aobake.api import bake_projected
from aobake.targets.projected import CHANNELS

FWER = 1e-4
PROMISED = 0.93
THREADS = 2
#: the low sphere's radius: the source lies both outside it (bumps) and inside it (valleys)
LOW_RADIUS = 1.05
#: a cage that encloses every bump (the highest reaches 1.25, 0.2 above the low sphere) and
#: whose rays reach the pits' bottoms (0.74, 0.31 below it) within twice its offset
CAGE = 0.35
#: a cage the bumps pierce and whose rays stop short of the pits
TIGHT = 0.05
RESOLUTION = 32


def directions(solid) -> np.ndarray:
    """Unit directions of an icosahedron's 12 vertices ("vertices") or 20 face centres."""
    ico = trimesh.creation.icosahedron()
    v = ico.vertices if solid == "vertices" else ico.triangles_center
    return v / np.linalg.norm(v, axis=1)[:, None]


def bumpy_sphere(subdivisions: int = 4, flip: bool = False):
    """The source: a unit icosphere (5120 triangles) with 12 Gaussian bumps (height 0.25,
    angular width 0.3 rad) at the icosahedron's vertices and 20 pits (depth 0.3, width 0.15)
    at its face centres: radii 0.74-1.25, AO 0.33-1 (the pits are dark).  ``flip``: wound
    inside out."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = m.vertices / np.linalg.norm(m.vertices, axis=1)[:, None]
    bumps = np.arccos(np.clip(d @ directions("vertices").T, -1, 1))
    pits = np.arccos(np.clip(d @ directions("faces").T, -1, 1))
    r = 1.0 + 0.25 * np.exp(-(bumps / 0.3) ** 2).sum(axis=1) \
        - 0.3 * np.exp(-(pits / 0.15) ** 2).sum(axis=1)
    faces = m.faces[:, ::-1] if flip else m.faces
    return make_scene(d * r[:, None], faces, normals_mode="angle", fix_normals="off")


def low_sphere(subdivisions: int = 2, radius: float = LOW_RADIUS):
    """The low mesh: a coarse icosphere (320 triangles), no UVs (a new atlas is made),
    turned so that its vertices do not lie on the source's (a cage ray through a vertex
    would test float rounding, not the projection)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1.0, 2.0, 3.0]))
    return make_scene(m.vertices, m.faces, normals_mode="angle")


@functools.lru_cache(maxsize=None)
def meshes():
    return bumpy_sphere(), low_sphere()


def first_hits(scene, origins, directions, tmax):
    """The independent cast: float64 Moller-Trumbore of every ray against every triangle.
    Returns (t (n,) inf on a miss, face (n,) -1 on a miss)."""
    tri = scene.vertices[scene.faces]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    t_best = np.full(len(origins), np.inf)
    face = np.full(len(origins), -1)
    for lo in range(0, len(origins), 32):
        o, d = origins[lo:lo + 32, None], directions[lo:lo + 32, None]
        p = np.cross(d, e2)
        det = np.einsum("rfk,fk->rf", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = o - v0
            u = np.einsum("rfk,rfk->rf", s, p) * inv
            q = np.cross(s, e1)
            v = np.einsum("rfk,rfk->rf", d, q) * inv
            t = np.einsum("fk,rfk->rf", e2, q) * inv
            ok = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) \
                & (t <= tmax[lo:lo + 32, None])
        t = np.where(ok, t, np.inf)
        best = t.argmin(axis=1)
        t_best[lo:lo + 32] = t[np.arange(len(best)), best]
        face[lo:lo + 32] = np.where(np.isfinite(t_best[lo:lo + 32]), best, -1)
    return t_best, face


def independent_projection(high, low_points, cage_points):
    """(hit, back, points, normals) of the cage rays by :func:`first_hits`; normals are the
    source's vertex normals interpolated at the hit (flat where they cancel)."""
    ray = low_points - cage_points
    reach = np.linalg.norm(ray, axis=1)
    unit = ray / reach[:, None]
    t, face = first_hits(high, cage_points, unit, 2 * reach)
    hit = face >= 0
    points = cage_points + np.where(hit, t, 0)[:, None] * unit
    back = np.zeros(len(hit), bool)
    back[hit] = np.einsum("ij,ij->i", high.face_normals[face[hit]], unit[hit]) > 0
    normals = np.zeros_like(points)
    tri = high.vertices[high.faces[face[hit]]]
    # barycentric coordinates of the hit, then the interpolated vertex normal
    e1, e2, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], points[hit] - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    det = d11 * d22 - d12 * d12
    b1, b2 = (d22 * w1 - d12 * w2) / det, (d11 * w2 - d12 * w1) / det
    bary = np.stack([1 - b1 - b2, b1, b2], axis=1)
    n = np.einsum("kc,kcd->kd", bary, high.vertex_normals[high.faces[face[hit]]])
    normals[hit] = n / np.linalg.norm(n, axis=1)[:, None]
    return hit, back, points, normals


def cage_points_of(result):
    """The cage point of every texel sample: low point + offset x interpolated normal."""
    low, samples = result.low, result.samples
    corners = low.faces[samples.face]
    n = np.einsum("kc,kcd->kd", samples.bary, low.vertex_normals[corners])
    p = np.einsum("kc,kcd->kd", samples.bary, low.vertices[corners])
    offset = result.report["projection"]["cage"]["offset"]
    return p, p + offset * n


def bake(seed=0, offset=CAGE, rays=64, **options):
    high, low = meshes()
    options = dict(dict(resolution=RESOLUTION, texel_samples=1, padding=0, seams="off",
                        rays=rays, seed=seed, threads=THREADS), **options)
    return bake_projected(low, high, cage_offset=offset, **options)


# --------------------------------------------------------------------------- 1. projection


@pytest.mark.slow
@pytest.mark.parametrize("offset", [CAGE, TIGHT])
def test_projection_equals_an_independent_cast(offset):
    high, _ = meshes()
    res = bake(offset=offset, rays=8)
    low_points, cage = cage_points_of(res)
    hit, back, points, normals = independent_projection(high, low_points, cage)
    proj = res.projection
    # a ray grazing an edge may go either way in float32: allow a handful
    assert np.count_nonzero(proj.hit != hit) <= 2
    both = proj.hit & hit
    assert np.abs(proj.points[both] - points[both]).max() < 1e-5
    assert np.einsum("ij,ij->i", proj.normals[both], normals[both]).min() > 1 - 1e-6
    assert not proj.back.any() and not back.any()
    # the height above the low surface: the projected point's radius minus the low point's
    # is that height along the (nearly radial) ray
    assert np.abs(proj.distance[both] - (np.linalg.norm(proj.points[both], axis=1)
                                         - np.linalg.norm(low_points[both], axis=1))).max() < 0.02


# --------------------------------------------------------------------------- 2. AO values


@functools.lru_cache(maxsize=None)
def reference():
    """AO at the independently projected texel samples, 16384 rays each (other seeds)."""
    high, _ = meshes()
    res = bake(rays=8)
    low_points, cage = cage_points_of(res)
    hit, _, points, normals = independent_projection(high, low_points, cage)
    assert hit.all()
    ref = aobake.bake_points(high, points, normals, rays=16384, seed=999, threads=THREADS,
                             point_sizes=np.sqrt(2 * high.areas()[res.projection.faces]))
    size = RESOLUTION * RESOLUTION
    texel = res.samples.texel
    count = np.bincount(texel, minlength=size)
    value = np.bincount(texel, weights=ref.ao, minlength=size) / np.maximum(count, 1)
    var = np.bincount(texel, weights=ref.ao_stderr ** 2, minlength=size) / np.maximum(count, 1) ** 2
    shape = (RESOLUTION, RESOLUTION)
    return value.reshape(shape), np.sqrt(var).reshape(shape), (count > 0).reshape(shape)


@pytest.mark.slow
def test_low_map_equals_ao_at_the_projected_points_within_its_error_bars():
    """20 seeds x ~700 texels at 64 rays against the 16384-ray reference: the intervals
    cover it in >= 93% (one-sided binomial), and on the interior texels (reference in
    (0.1, 0.9)) the errors have mean ~0 and sum e^2 / sum stderr^2 ~1 (the stderr with the
    reference's added: no bias, no understated error); the pits are dark (the test has something to
    measure)."""
    value, ref_se, charted = reference()
    errors, variances, covered = [], [], []
    for seed in range(20):
        res = bake(seed=seed)
        ch = res.channels
        mask = charted & res.covered
        assert mask.sum() == charted.sum()
        ao, se = ch["ao"][mask].astype(float), ch["ao_stderr"][mask].astype(float)
        ref = value[mask]
        inside = (ch["ao_ci_low"][mask] <= ref + 2 * ref_se[mask]) \
            & (ref - 2 * ref_se[mask] <= ch["ao_ci_high"][mask])
        covered.append(inside)
        # calibration on interior texels: near 1 a stderr of 0 spread is floored at 1/n
        interior = (ref > 0.1) & (ref < 0.9)
        errors.append((ao - ref)[interior])
        variances.append((se ** 2 + ref_se[mask] ** 2)[interior])
    assert value[charted].min() < 0.6  # the pits
    covered = np.concatenate(covered)
    e, v = np.concatenate(errors), np.concatenate(variances)
    assert stats.binom.cdf(covered.sum(), covered.size, PROMISED) >= FWER / 3, covered.mean()
    # no bias: the mean error within its own bound (the seeds share the reference's error,
    # which the variances hold)
    assert abs(e.mean()) < stats.norm.ppf(1 - FWER / 6) * math.sqrt(v.sum()) / len(e)
    # Q = sum e^2 / sum stderr^2 ~ chi2(nu) / nu, nu the Satterthwaite dof of the sum
    q = np.square(e).sum() / v.sum()
    nu = v.sum() ** 2 / np.square(v).sum()
    lo, hi = (stats.chi2.ppf(p, nu) / nu for p in (FWER / 6, 1 - FWER / 6))
    assert 0.9 * lo <= q <= 1.1 * hi, (q, lo, hi)


@pytest.mark.slow
def test_per_vertex_equals_ao_at_the_projected_vertices():
    """Each low vertex projected (independent cast) and baked: within the FWER bound of the
    combined stderr everywhere (162 vertices x 10 seeds), z-scores calibrated.  The bake's
    stderr has R - 1 degrees of freedom (R replicates) and dominates the reference's (64x
    the rays), so (value - reference) / combined stderr is Student t with R - 1 dof; it is
    mapped to a normal score through the t's CDF for the calibration."""
    high, low = meshes()
    cage = low.vertices + CAGE * low.vertex_normals
    hit, _, points, normals = independent_projection(high, low.vertices, cage)
    assert hit.all()
    ref = aobake.bake_points(high, points, normals, rays=16384, seed=77, threads=THREADS)
    z, dof = [], None
    for seed in range(10):
        res = bake_projected(low, high, per="vertices", cage_offset=CAGE, rays=256, seed=seed,
                             threads=THREADS)
        assert res.projection.hit.all() and res.positions is low.vertices
        assert np.abs(res.projection.points - points).max() < 1e-5
        combined = np.sqrt(res.ao_stderr ** 2 + ref.ao_stderr ** 2)
        z.append((res.ao - ref.ao)[combined > 0] / combined[combined > 0])
        dof = res.report["parameters"]["replicates"] - 1
    t = np.concatenate(z)
    assert np.abs(t).max() < stats.t.ppf(1 - FWER / (2 * len(t)), dof) + 0.5
    normal = stats.norm.ppf(stats.t.cdf(t, dof))
    # Never narrower than the spread: mean normal^2 at most 1 plus 4 of its standard errors
    # (sqrt(2 / n) for chi-square(1) terms).  Wider is honest but costs: randomised-QMC
    # replicate spreads are conservative on these near-binary integrands (measured 0.73 at
    # R = 4, 0.79 at R = 8), so up to a stderr 25% too wide is accepted (1 / 1.25^2).
    assert 1 / 1.25 ** 2 < np.mean(normal ** 2) < 1 + 4 * math.sqrt(2 / len(t)), \
        np.mean(normal ** 2)


@pytest.mark.slow
def test_bit_identical_for_threads_and_executors():
    a = bake(rays=16, threads=1)
    b = bake(rays=16, threads=2)
    for name in a.channels:
        assert np.array_equal(a.channels[name], b.channels[name]), name
    # worker processes build the source's occluders from the pipeline's scene
    high, low = meshes()
    c = bake_projected(low, high, per="vertices", cage_offset=CAGE, rays=16, threads=1)
    d = bake_projected(low, high, per="vertices", cage_offset=CAGE, rays=16, threads=1,
                       executor="processes", workers=2)
    assert np.array_equal(c.ao, d.ao) and np.array_equal(c.rays, d.rays)


# --------------------------------------------------------------------------- 3. misses, backs


@pytest.mark.slow
def test_a_tight_cage_flags_and_counts_its_misses(caplog):
    high, _ = meshes()
    res = bake(offset=TIGHT, rays=8)
    proj, record = res.projection, res.report["projection"]
    low_points, cage = cage_points_of(res)
    hit, _, _, _ = independent_projection(high, low_points, cage)
    missed = int(np.count_nonzero(~proj.hit))
    assert missed > 20 and abs(missed - int(np.count_nonzero(~hit))) <= 2
    assert record["missed"] == missed and record["hit"] == len(proj.hit) - missed
    # one sample per texel: the missed texels are the samples that missed, and the mask
    # says which
    mask = res.channels["missed"]
    assert set(np.unique(mask)) <= {0.0, 1.0}
    assert record["texels"]["missed_any"] == record["texels"]["missed_all"] == missed \
        == int(mask.sum())
    flat = np.zeros(RESOLUTION * RESOLUTION)
    flat[res.samples.texel[~proj.hit]] = 1
    assert np.array_equal(mask.ravel(), flat)
    # missed texels are not baked (not covered): their values are the gutters' fill
    assert not res.covered[mask > 0].any()
    warning = [w for w in res.report["warnings"] if "missed" in w]
    assert len(warning) == 1 and f"{missed} have samples" in warning[0] \
        and "--cage-offset" in warning[0]
    # the right cage misses nothing and warns of nothing
    good = bake(rays=8)
    assert good.report["projection"]["missed"] == 0 and not good.channels["missed"].any()
    assert not [w for w in good.report["warnings"] if "cage" in w]


@pytest.mark.slow
def test_a_source_inside_out_is_hit_on_its_back():
    _, low = meshes()
    flipped = bumpy_sphere(flip=True)
    res = bake_projected(low, flipped, cage_offset=CAGE, resolution=RESOLUTION,
                         texel_samples=1, rays=8, threads=THREADS)
    record = res.report["projection"]
    assert record["back"] == record["hit"] == record["points"]
    assert res.channels["back_hit"][res.covered].min() == 1.0
    assert any("hit the back" in w for w in res.report["warnings"])


# --------------------------------------------------------------------------- 4. cage meshes


@pytest.mark.slow
def test_the_offset_cage_as_a_mesh_bakes_the_same_bits():
    high, low = meshes()
    cage = make_scene(low.vertices + CAGE * low.vertex_normals, low.faces, fix_normals="off")
    a = bake(rays=16)
    b = bake_projected(low, high, cage=cage, resolution=RESOLUTION, texel_samples=1,
                       padding=0, seams="off", rays=16, seed=0, threads=THREADS)
    for name in a.channels:
        assert np.array_equal(a.channels[name], b.channels[name]), name
    assert b.report["projection"]["cage"]["kind"] == "mesh"


def test_a_cage_of_another_topology_is_refused(tmp_path):
    high, low = meshes()
    other = trimesh.creation.icosphere(subdivisions=3, radius=1.4)
    with pytest.raises(InputError, match="topology: it has 642 vertices"):
        bake_projected(low, high, cage=other, rays=4)
    # the same counts, one triangle rewired
    faces = low.faces.copy()
    faces[7] = faces[8]
    path = tmp_path / "cage.obj"
    trimesh.Trimesh(low.vertices * 1.3, faces, process=False).export(path)
    with pytest.raises(InputError, match="1 of its 320 triangles use other vertices"):
        bake_projected(low, high, cage=path, rays=4)
    with pytest.raises(InputError, match="not both"):
        bake_projected(low, high, cage=path, cage_offset=0.1)
    with pytest.raises(InputError, match="cage offset must be"):
        bake_projected(low, high, cage_offset="-3%")


# --------------------------------------------------------------------------- 5. outputs


@pytest.mark.slow
def test_outputs(tmp_path):
    from readers import read_image, read_ply

    res = bake(offset=TIGHT, rays=8)
    written = aobake.write(res, tmp_path / "ao.exr")
    pixels, names, _ = read_image(written[0])
    for name in CHANNELS:
        assert np.array_equal(pixels[..., names.index(name)], res.channels[name]), name
    assert res.report["scene"]["triangles"] == 5120  # the source
    assert res.report["projection"]["low"]["triangles"] == 320
    high, low = meshes()
    per_vertex = bake_projected(low, high, per="vertices", cage_offset=CAGE, rays=16,
                                threads=THREADS)
    path = aobake.write(per_vertex, tmp_path / "ao.ply")[0]
    vertex, faces, meta = read_ply(path)
    assert len(vertex) == len(low.vertices) and np.array_equal(faces, low.faces)
    assert np.allclose(vertex["ao"], per_vertex.ao, atol=1e-7)


@pytest.mark.slow
def test_cli_from_bakes_high_to_low_and_protects_the_source(tmp_path):
    """`aobake LOW --from HIGH --out ao.ply`: the low mesh's vertices, projected onto the
    source; the report's config carries --from (so it re-bakes); no output may overwrite
    the source."""
    import json

    import trimesh

    from conftest import run_cli

    high, low = tmp_path / "high.ply", tmp_path / "low.obj"
    trimesh.creation.icosphere(4, 1.0).export(high)
    trimesh.creation.icosphere(1, 1.0).export(low)
    report = tmp_path / "r.json"
    result = run_cli(low, "--from", high, "--out", tmp_path / "ao.ply", "--rays", "8",
                     "--report", report, "--quiet")
    assert result.exit_code == 0, result.output
    config = json.loads(report.read_text())["config"]
    assert config["source"] == str(high)
    clash = run_cli(low, "--from", high, "--out", high, "--rays", "8")
    assert clash.exit_code == 1 and "refusing to overwrite the input --from" in clash.output
    alone = run_cli(low, "--cage-offset", "0.1", "--out", tmp_path / "x.ply")
    assert alone.exit_code == 2 and "--from" in alone.output  # settings that cannot go together
