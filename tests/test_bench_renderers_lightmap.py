"""benchmarks/bench_renderers_lightmap.py's pieces (issue 32 point 6, the lightmap half): its
time-to-error interpolation and error measures on made-up numbers, and, where Blender is
(``AOBAKE_BLENDER_PYTHON``: a Python with ``bpy``), that benchmarks/_cycles_bake.py's image
lines up with aobake's lightmap texel for texel on a scene whose AO changes along v (so a
flipped row order would show).  The benchmark itself is timed by hand, never in a test.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks" / "bench_renderers_lightmap.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_renderers_lightmap", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rows(budgets, rmses, seconds, comparable=True):
    return [{"budget": b, "rmse": e, "seconds": s, "cpu_s": 2 * s, "comparable": comparable}
            for b, e, s in zip(budgets, rmses, seconds)]


def test_time_to_interpolates_in_log_log_and_marks_bounds():
    bench = _bench()
    rows = _rows([16, 64, 256], [0.04, 0.02, 0.01], [1.0, 2.0, 5.0])
    # 0.02 -> 0.01 over 64 -> 256 (slope -1/2): 0.0141 at 128 rays, seconds linear: 3.0
    budget, seconds, how, ok = bench.time_to(rows, 0.02 / math.sqrt(2))
    assert how == "=" and ok
    assert budget == pytest.approx(128, rel=1e-9)
    assert seconds == pytest.approx(3.0, rel=1e-9)
    assert bench.time_to(rows, 0.05)[:3] == (16, 1.0, "<=")
    budget, seconds, how, _ = bench.time_to(rows, 0.005)  # past the last: 1/sqrt(rays)
    assert how == "~" and budget == pytest.approx(1024) and seconds == pytest.approx(20.0)
    assert bench.time_to(rows, 0.02 / math.sqrt(2), "cpu_s")[1] == pytest.approx(6.0)
    loaded = rows[:1] + _rows([64, 256], [0.02, 0.01], [2.0, 5.0], comparable=False)
    assert bench.time_to(loaded, 0.015)[3] is False


def test_scores_take_out_the_reference_noise_and_limit_stats_find_the_floor():
    bench = _bench()
    rng = np.random.default_rng(7)
    n = 200_000
    truth = rng.uniform(0.3, 1.0, n)
    ref = {"ao": truth + rng.normal(0, 0.004, n), "ao_stderr": np.full(n, 0.004)}
    mask = np.ones(n, bool)
    estimate = truth + rng.normal(0, 0.01, n)
    s = bench.scores(estimate, ref, mask)
    assert s["rmse"] == pytest.approx(0.01, rel=0.02)
    assert s["rmse_raw"] == pytest.approx(math.hypot(0.01, 0.004), rel=0.02)
    # two noisy bakes of a definition off by 0.003 rms (and +0.001 on average)
    offset = rng.normal(0.001, 0.003, n)
    c1 = truth + offset + rng.normal(0, 0.006, n)
    c2 = truth + offset + rng.normal(0, 0.006, n)
    lim = bench.limit_stats(c1, c2, ref, mask)
    assert lim["noise_cycles"] == pytest.approx(0.006 / math.sqrt(2), rel=0.02)
    assert lim["floor"] == pytest.approx(math.hypot(0.001, 0.003), rel=0.05)
    assert lim["bias"] == pytest.approx(0.001, abs=4 * lim["bias_se"])


CORNER = 16  # quads along each side of the floor and the wall


def _corner_obj(path: Path) -> None:
    """A unit floor (z = 0, normal +z) and a unit wall along y = 0 (normal +y), not
    sharing vertices; UVs: the floor at u = x / 2, v = y, the wall at u = (1 + x) / 2,
    v = z. The floor's AO grows with y, so with v: a flipped row order shows."""
    g = np.linspace(0.0, 1.0, CORNER + 1)
    x, t = np.meshgrid(g, g, indexing="xy")
    x, t = x.ravel(), t.ravel()
    floor = np.stack([x, t, np.zeros_like(x)], 1)
    wall = np.stack([x, np.zeros_like(x), t], 1)
    uv = np.concatenate([np.stack([x / 2, t], 1), np.stack([(1 + x) / 2, t], 1)])
    normals = np.concatenate([np.tile([0, 0, 1.0], (len(x), 1)),
                              np.tile([0, 1.0, 0], (len(x), 1))])
    k = CORNER + 1
    quads = [(i * k + j, i * k + j + 1, (i + 1) * k + j + 1, (i + 1) * k + j)
             for i in range(CORNER) for j in range(CORNER)]
    faces = []
    for base, flip in ((0, False), (k * k, True)):  # the wall wound to face +y
        for a, b, c, d in quads:
            tris = [(a, b, c), (a, c, d)]
            faces += [tuple(base + v for v in (tri[::-1] if flip else tri)) for tri in tris]
    lines = [f"v {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}" for p in np.concatenate([floor, wall])]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += [f"vn {n[0]:g} {n[1]:g} {n[2]:g}" for n in normals]
    lines += ["f " + " ".join(f"{v + 1}/{v + 1}/{v + 1}" for v in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("AOBAKE_BLENDER_PYTHON"),
                    reason="AOBAKE_BLENDER_PYTHON (a Python with bpy) not set")
def test_cycles_bake_lines_up_with_aobake_texel_for_texel(tmp_path):
    import aobake

    bench = _bench()
    mesh = tmp_path / "corner.obj"
    _corner_obj(mesh)
    size = 32
    result = aobake.bake_texels(str(mesh), rays=1024, texel_samples=16, resolution=size,
                                seams="off", unwrap="never", threads=2, seed=11)
    ref = {"ao": np.asarray(result.channels["ao"], float),
           "ao_stderr": np.asarray(result.channels["ao_stderr"], float)}
    covered = np.asarray(result.channels["coverage"]) > 0
    bakes = []
    for seed in (1, 2):
        out = tmp_path / f"cycles_{seed}.npz"
        done = subprocess.run([os.environ["AOBAKE_BLENDER_PYTHON"],
                               str(ROOT / "benchmarks" / "_cycles_bake.py"), str(mesh),
                               "--out", str(out), "--size", str(size), "--samples", "256",
                               "--seed", str(seed), "--threads", "2"],
                              capture_output=True, text=True, timeout=600, cwd=ROOT)
        assert done.returncode == 0, done.stderr[-2000:]
        with np.load(out) as data:
            bakes.append({k: data[k] for k in ("ao", "baked")})
    baked = bakes[0]["baked"]
    assert baked.all() and covered.all()  # the layout leaves no texel empty
    lim = bench.limit_stats(bakes[0]["ao"], bakes[1]["ao"], ref, baked)
    # within the noise: no offset of the mean, no floor beyond a few thousandths
    assert abs(lim["bias"]) <= max(4 * lim["bias_se"], 2e-3), lim
    assert lim["floor"] < 0.01, lim
    # the check can fail: Cycles' image read with its rows as Blender stores them
    flipped = bench.limit_stats(bakes[0]["ao"][::-1], bakes[1]["ao"][::-1], ref, baked)
    assert flipped["floor"] > 0.05, flipped
