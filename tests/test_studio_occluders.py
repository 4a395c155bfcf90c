"""The low mesh as an occluder of its own high-to-low bake (``--low-occludes``) and the
projection's per-vertex data in the per-vertex outputs.

The source is a floor; the low mesh a floor grid a little above it (the projected points lie
just under the low surface) plus a plate above, facing down, that only the low mesh has.

* with ``low_occludes`` the floor points' AO is 1 - F, F Lambert's form factor of the plate
  (closed form), within a Bonferroni bound of the reported stderr;
* without it nothing is occluded (AO exactly 1), and a low mesh that is only the floor grid
  (above or below the source) changes no bit: the rule (front faces only, beyond the cage
  ray's length) keeps the low surface from shadowing the points it stands for;
* per-vertex outputs (.npz, .ply) hold the projection's hit, back-hit and distance per low
  vertex, finite everywhere (a miss's distance is -1).
"""

from __future__ import annotations

import numpy as np
import pytest

import aobake
from aobake.scene import make_scene
from aobake.api import bake_projected
from analytic import dof_for, polygon_form_factors, z_bound

THREADS = 2
#: the plate (low mesh only): a square of half-width PLATE at height HEIGHT, facing down
PLATE, HEIGHT = 0.6, 0.5
#: the cage offset: rays reach from LIFT + CAGE down to LIFT - CAGE, past the source at 0;
#: the low mesh then does not occlude within 2 CAGE = 0.2 < HEIGHT of a point
CAGE = 0.1


def grid(n, half, z, down=False):
    """(vertices, faces) of an n x n vertex grid over [-half, half]^2 at height z, facing +z
    (or -z with ``down``)."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    vertices = np.stack([x.ravel(), y.ravel(), np.full(n * n, float(z))], axis=1)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + n + 1], 1),
                            np.stack([i, i + n + 1, i + n], 1)])
    return vertices, faces[:, ::-1] if down else faces


def scene_of(*parts):
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return make_scene(np.concatenate(vertices), np.concatenate(faces), normals_mode="angle",
                      fix_normals="off")


def source():
    return scene_of(grid(7, 3.0, 0.0))


def low(lift=0.02, plate=True):
    parts = [grid(5, 1.0, lift)]
    if plate:
        parts.append(grid(2, PLATE, HEIGHT, down=True))
    return scene_of(*parts)


def bake(low_mesh, rays=64, **options):
    return bake_projected(low_mesh, source(), per="vertices", cage_offset=CAGE, rays=rays,
                          threads=THREADS, **options)


def test_the_low_plate_darkens_as_its_form_factor_says():
    rays = 4096
    result = bake(low(), rays=rays, low_occludes=True)
    floor = np.arange(25)
    assert result.projection.hit[floor].all()
    points = result.projection.points[floor]
    corners = np.array([[-PLATE, -PLATE, HEIGHT], [PLATE, -PLATE, HEIGHT],
                        [PLATE, PLATE, HEIGHT], [-PLATE, PLATE, HEIGHT]])
    exact = 1.0 - polygon_form_factors(points, np.tile([0.0, 0.0, 1.0], (25, 1)), corners)
    k = z_bound(25, dof_for("sobol", rays))
    error = np.abs(result.ao[floor] - exact)
    assert (error <= k * result.ao_stderr[floor]).all(), (error / result.ao_stderr[floor]).max()
    assert exact.min() < 0.8  # the plate matters
    extras = result.report["parameters"]["extra_occluders"]
    assert extras[0]["faces"] == 32 + 2 and extras[0]["skip"] == pytest.approx(2 * CAGE)


def test_without_the_flag_nothing_occludes_and_the_low_floor_never_does():
    plain = bake(low())
    assert (plain.ao[:25] == 1.0).all()
    assert "extra_occluders" not in plain.report["parameters"]
    for lift in (0.02, -0.02):  # the projected points just under, then just above, the low floor
        alone = bake(low(lift, plate=False))
        occluding = bake(low(lift, plate=False), low_occludes=True)
        assert "extra_occluders" in occluding.report["parameters"]
        for name in ("ao", "ao_stderr", "ao_ci_low", "ao_ci_high"):
            np.testing.assert_array_equal(getattr(occluding, name), getattr(alone, name))


def test_low_occludes_needs_from():
    with pytest.raises(aobake.InputError, match="--low-occludes"):
        aobake.BakeConfig(low_occludes=True)


def test_per_vertex_outputs_hold_the_projection(tmp_path):
    from readers import read_ply

    # the plate's four vertices miss the source (their cage rays run upwards)
    result = bake(low(lift=0.02), rays=8)
    projection = result.projection
    assert (~projection.hit).sum() == 4
    npz = np.load(aobake.write(result, tmp_path / "ao.npz")[0])
    vertex, _, _ = read_ply(aobake.write(result, tmp_path / "ao.ply")[0])
    for stored in (npz, vertex):
        np.testing.assert_array_equal(stored["missed"], ~projection.hit)
        np.testing.assert_array_equal(stored["back_hit"], projection.back)
        distance = np.asarray(stored["projection_distance"], dtype=np.float64)
        assert np.isfinite(distance).all()
        np.testing.assert_allclose(distance[projection.hit], projection.distance[projection.hit],
                                   rtol=1e-7, atol=0)
        assert (distance[~projection.hit] == 0).all()
        # the floor grid lies 0.02 above the source: each hit 0.02 below the low surface
        np.testing.assert_allclose(distance[:25], -0.02, rtol=1e-6)
    assert npz["missed"].dtype == np.uint8 and npz["projection_distance"].dtype == np.float32
    # a source inside out: every hit is on a back face, and said so per vertex
    flipped = make_scene(source().vertices, source().faces[:, ::-1], normals_mode="angle",
                         fix_normals="off")
    back = bake_projected(low(), flipped, per="vertices", cage_offset=CAGE, rays=8,
                          threads=THREADS)
    assert (back.back_hit[:25] == 1).all() and (back.missed[:25] == 0).all()
