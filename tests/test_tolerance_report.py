"""--tolerance's report states every ray cast (issue 35): ``final_rays`` is the last stage's
count, but a point that needed further stages cast those before it too; the range of rays
cast after the pilot and per point (the ``rays`` channel) are reported beside it."""

from __future__ import annotations

import pytest
import json

import numpy as np

import aobake
from analytic import up
from conftest import run_cli
from test_tolerance import scene


def test_the_report_states_the_rays_cast_beyond_the_pilot(monkeypatch):
    from aobake import adaptive

    monkeypatch.setattr(adaptive, "VARIANCE_BOUND", 0.05)  # pilots that under-estimate
    mesh, points, _ = scene(0.5)
    pilot = 16
    res = aobake.bake_points(mesh, points[:200], up(200), rays=pilot, tolerance=0.05,
                             max_rays=4096, sampler="random")
    t = res.report["tolerance"]
    after = res.rays.astype(np.int64) - pilot
    assert t["rays_after_pilot"] == {"min": int(after.min()), "median": float(np.median(after)),
                                     "max": int(after.max())}
    assert t["rays_per_point"]["max"] == int(res.rays.max())
    assert t["rays_per_point"]["min"] == int(res.rays.min())
    # some point cast stages before its final one: more after the pilot than its final count
    assert t["rays_after_pilot"]["max"] > t["final_rays"]["max"]
    assert int(res.rays.sum()) == t["rays_total"]


@pytest.mark.slow
def test_cli_report_has_the_ranges(box_ply, tmp_path):
    report = tmp_path / "r.json"
    res = run_cli(box_ply, "--out", tmp_path / "x.npz", "--tolerance", "0.05", "--rays", 16,
                  "--report", report)
    assert res.exit_code == 0, res.output
    t = json.loads(report.read_text())["tolerance"]
    assert t["rays_per_point"]["max"] == t["rays_after_pilot"]["max"] + 16
    assert t["rays_after_pilot"]["min"] >= t["final_rays"]["min"]
