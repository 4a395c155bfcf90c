"""Two noisy estimates (issue 32 point 3): when the candidate carries its own standard errors
(an ``ao_stderr`` beside its values, or ``--candidate-stderr FILE``), z, the 95% interval and
the excess RMSE use the combined error sqrt(se_ref^2 + se_cand^2), and the record says so
(``error``: 'reference' | 'combined').

The statistical test's bound: for n independent points whose errors are normal with the
stated standard error, n z_rms^2 is chi-square with n degrees of freedom; its quantiles by
Wilson and Hilferty (1931), chi2_p(n) ~ n (1 - 2/(9n) + z_p sqrt(2/(9n)))^3, at z_p = -+4.5
(a two-sided probability of 7e-6).  The share inside the 95% interval is binomial(n, 0.95)/n:
within 4.5 of its standard deviations of 0.95.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake.compare import Z95, compare, format_table, metrics
from aobake.errors import InputError
from aobake.outputs.image import write_exr
from conftest import run_cli

K = 4.5  # standard normal deviates of the bounds (two-sided probability 7e-6)


def chi2_bounds(n: int, k: float = K) -> tuple[float, float]:
    """(low, high) bounds of z_rms^2 = chi2(n) / n (Wilson-Hilferty quantiles at -+k)."""
    c = 2.0 / (9.0 * n)
    return tuple((1 - c + s * k * math.sqrt(c)) ** 3 for s in (-1, 1))


@pytest.fixture(scope="module")
def two_bakes(tmp_path_factory):
    """Two independent bakes (seeds 1 and 2, 1024 i.i.d. rays) of the inside of an open box:
    every vertex sees some sky and some wall (AO in (0.1, 0.6): no vertex at an extreme,
    where every ray agrees and the error bar is its floor, 1/n); and the second without its
    stderr, and its stderr alone."""
    tmp = tmp_path_factory.mktemp("noise")
    box = trimesh.creation.box(extents=[2, 2, 1])
    open_top = box.face_normals[:, 2] < 0.5
    mesh = trimesh.Trimesh(box.vertices, box.faces[open_top][:, ::-1], process=False)  # inward
    for _ in range(3):
        mesh = mesh.subdivide()
    a, b = (aobake.bake(mesh, rays=1024, seed=seed, sampler="random") for seed in (1, 2))
    assert 0 < a.ao.min() and a.ao.max() < 1
    aobake.write(a, tmp / "a.npz")
    aobake.write(b, tmp / "b.ply")
    np.savez(tmp / "b_values.npz", positions=b.positions, faces=b.faces, ao=b.ao)
    np.savez(tmp / "b_stderr.npz", positions=b.positions, ao=b.ao_stderr)
    return a, b, tmp


@pytest.mark.slow
def test_two_independent_bakes_agree_within_the_combined_error(two_bakes):
    a, b, tmp = two_bakes
    both = compare(tmp / "a.npz", tmp / "b.ply")
    alone = compare(tmp / "a.npz", tmp / "b_values.npz")  # the candidate without its stderr
    n = both["n"]
    assert n == alone["n"] == len(a.ao)
    assert both["error"] == "combined" and alone["error"] == "reference"
    low, high = chi2_bounds(n)
    assert low <= both["z_rms"] ** 2 <= high, (both["z_rms"], low, high)
    # the reference's error alone misses the candidate's variance: z_rms^2 is inflated by
    # mean(e^2 / se_r^2) / mean(e^2 / (se_r^2 + se_c^2)), a weighted mean of the points'
    # (se_r^2 + se_c^2) / se_r^2, about 2 for two bakes of as many rays
    ra, rb = a.ao_stderr.astype(np.float32) ** 2, b.ao_stderr.astype(np.float32) ** 2
    ratio = (ra + rb) / ra
    inflation = alone["z_rms"] ** 2 / both["z_rms"] ** 2
    assert ratio.min() <= inflation <= ratio.max()
    assert inflation == pytest.approx(2.0, rel=0.1)
    assert alone["z_rms"] ** 2 > high  # outside the bound: the reference's error is too small
    spread = K * math.sqrt(0.95 * 0.05 / n)
    assert abs(both["within_95"] - 0.95) <= spread
    assert alone["within_95"] < 0.95 - spread  # too narrow an interval
    # the excess: what the noise does not explain (none, here) against the rmse the
    # reference's noise alone leaves, the candidate's own error included
    noise = math.sqrt(np.mean(ra + rb))
    assert both["noise_rms"] == pytest.approx(noise, rel=1e-6)
    assert both["excess_rmse"] == pytest.approx(math.sqrt(max(0.0, both["rmse"] ** 2 - noise ** 2)),
                                                rel=1e-9, abs=1e-12)
    assert both["excess_rmse"] < 0.2 * both["rmse_without_reference_noise"]
    assert alone["excess_rmse"] == alone["rmse_without_reference_noise"] == \
        both["rmse_without_reference_noise"]


@pytest.mark.slow
def test_the_summary_says_which_error(two_bakes):
    _, _, tmp = two_bakes
    res = run_cli("compare", tmp / "a.npz", tmp / "b.ply", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["error"] == "combined" and m["candidate_stderr"] is None
    text = run_cli("compare", tmp / "a.npz", tmp / "b.ply").output
    assert "error: combined: sqrt(reference stderr^2 + candidate stderr^2)" in text
    assert "z rms (error / combined stderr)" in text and "combined noise rms" in text
    text = run_cli("compare", tmp / "a.npz", tmp / "b_values.npz").output
    assert "error: the reference's stderr (the candidate has none)" in text
    assert "z rms (error / reference stderr)" in text


@pytest.mark.slow
def test_candidate_stderr_from_a_file(two_bakes, tmp_path):
    _, b, tmp = two_bakes
    res = run_cli("compare", tmp / "a.npz", tmp / "b_values.npz", "--candidate-stderr",
                  tmp / "b_stderr.npz", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    same = compare(tmp / "a.npz", tmp / "b.ply")
    assert m["error"] == "combined" and m["candidate_stderr"] == str(tmp / "b_stderr.npz")
    assert m["z_rms"] == pytest.approx(same["z_rms"], rel=1e-6)
    assert any("read as the candidate's standard errors" in note for note in m["notes"])
    short = tmp_path / "short.npz"
    np.savez(short, ao=b.ao_stderr[:-1])
    with pytest.raises(InputError, match=r"short.npz: holds .* values, the candidate .*: a "
                                         "stderr file holds one standard error per candidate"):
        compare(tmp / "a.npz", tmp / "b_values.npz", candidate_stderr=short)
    negative = tmp_path / "negative.npz"
    np.savez(negative, ao=-b.ao_stderr)
    res = run_cli("compare", tmp / "a.npz", tmp / "b_values.npz", "--candidate-stderr", negative)
    assert res.exit_code == 1 and "standard errors are negative" in res.output
    assert str(negative) in res.output


def test_metrics_of_known_errors():
    """e = 3 at every point, se_ref = 3, se_cand = 4: z = 1 against the reference's error,
    3/5 against the combined one; excess sqrt(9 - 9) = 0 and sqrt(max(0, 9 - 25)) = 0."""
    ref, cand = np.zeros(4), np.full(4, 3.0)
    alone = metrics(ref, cand, np.full(4, 3.0))
    both = metrics(ref, cand, np.full(4, 3.0), np.full(4, 4.0))
    assert alone["error"] == "reference" and both["error"] == "combined"
    assert alone["z_rms"] == pytest.approx(1.0) and both["z_rms"] == pytest.approx(0.6)
    assert both["noise_rms"] == pytest.approx(5.0) and alone["noise_rms"] == pytest.approx(3.0)
    assert alone["within_95"] == 1.0 and alone["z_over_3"] == 0.0
    assert metrics(ref, cand, np.full(4, 1.0))["within_95"] == 0.0  # z = 3 > 1.96
    assert metrics(ref, cand, np.full(4, 1.0))["z_over_3"] == 0.0  # z = 3 is not beyond 3
    assert metrics(ref, cand, np.full(4, 0.5))["z_over_3"] == 1.0
    assert both["excess_rmse"] == 0.0 and both["rmse_without_reference_noise"] == 0.0
    one = metrics(ref, cand, np.full(4, 1.0), np.full(4, 2.0))
    assert one["excess_rmse"] == pytest.approx(math.sqrt(9 - 5))
    assert one["rmse_without_reference_noise"] == pytest.approx(math.sqrt(9 - 1))
    none = metrics(ref, cand)  # no reference stderr: no z, whatever the candidate has
    assert none["error"] is None and none["z_rms"] is None and none["excess_rmse"] is None
    assert metrics(ref, cand, None, np.ones(4))["error"] is None
    # a zero error bar (exact by construction) has no z: left out of z and the interval
    some = metrics(ref, cand, np.array([0.0, 3.0, 3.0, 3.0]))
    assert some["z_rms"] == pytest.approx(1.0) and some["within_95"] == 1.0
    assert metrics(ref, cand, np.zeros(4))["z_rms"] is None
    assert Z95 == pytest.approx(1.959963984540054)
    table = format_table(dict(both, quantity="ao", candidate="c", reference="r",
                              matched_by="order", n_uncovered_in_candidate=0, notes=[],
                              heatmap=None, reference_transfer="linear",
                              candidate_transfer="linear"))
    assert "z rms (error / combined stderr)" in table and "0.600" in table


def test_a_view_scores_z_in_the_combined_error(tmp_path):
    """The screen scores of a view use the error the metrics use: two noisy views."""
    size = (12, 9)
    rng = np.random.default_rng(4)
    ao = rng.uniform(0.2, 0.8, size[::-1])
    camera = {"width": size[0], "height": size[1], "eye": [0, 0, 5], "target": [0, 0, 0],
              "up": [0, 1, 0], "fov_y_deg": 40.0, "near": 0.1, "far": 100.0}
    meta = {"config": {"weighting": "cosine"}, "camera": camera}
    ones = np.ones(size[::-1])
    for name, value, se in (("ref", ao, 0.02), ("cand", ao + 0.03, 0.04),
                            ("bare", ao + 0.03, None)):
        channels = {"ao": value, "coverage": ones}
        if se is not None:
            channels["ao_stderr"] = np.full(size[::-1], se)
        write_exr(tmp_path / f"{name}.exr", channels, meta)
    both = compare(tmp_path / "ref.exr", tmp_path / "cand.exr")
    alone = compare(tmp_path / "ref.exr", tmp_path / "bare.exr")
    raw = both["screen"]["regions"]["all"]["raw"]
    assert both["error"] == "combined" and both["target"] == "view"
    assert raw["z_rms"] == pytest.approx(both["z_rms"], rel=1e-6)
    assert raw["z_rms"] == pytest.approx(0.03 / math.hypot(0.02, 0.04), rel=1e-4)
    assert alone["screen"]["regions"]["all"]["raw"]["z_rms"] == pytest.approx(0.03 / 0.02,
                                                                              rel=1e-4)


def test_candidate_stderr_image_beside_another_tools_image(tmp_path):
    """Mitsuba's way: the mean of N renders in one EXR, its standard error in another."""
    rng = np.random.default_rng(7)
    ao = rng.uniform(0.2, 0.8, (5, 7))
    write_exr(tmp_path / "ref.exr", {"ao": ao, "ao_stderr": np.full((5, 7), 0.03),
                                     "coverage": np.ones((5, 7))}, {"config": {}})
    write_exr(tmp_path / "mean.exr", {"Y": ao + 0.05})
    write_exr(tmp_path / "se.exr", {"Y": np.full((5, 7), 0.04)})
    res = run_cli("compare", tmp_path / "ref.exr", tmp_path / "mean.exr", "--candidate-stderr",
                  tmp_path / "se.exr", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["error"] == "combined" and m["candidate_noise_rms"] == pytest.approx(0.04)
    assert m["z_rms"] == pytest.approx(0.05 / 0.05, rel=1e-5)  # 0.05 / hypot(0.03, 0.04)
    write_exr(tmp_path / "small.exr", {"Y": np.full((4, 7), 0.04)})
    res = run_cli("compare", tmp_path / "ref.exr", tmp_path / "mean.exr", "--candidate-stderr",
                  tmp_path / "small.exr")
    assert res.exit_code == 1 and "holds 7x4 values, the candidate" in res.output
