"""--denoise: denoised channels beside the raw ones (never instead), a filter that does not
cross creases, charts or value steps the noise cannot explain, an honest noise channel,
seams erased in the denoised channels too, and less error than the raw map against a
high-ray reference."""

from __future__ import annotations

import functools
import math
import subprocess
import sys

import numpy as np
import pytest

from aobake.api import bake_texels
from aobake.targets.texels.denoise import CREASE_ANGLE, Guide, denoise
from tests.test_seams import differences, lookup_noise, random_seam_points, seam_mesh, torus_obj

OPTIONS = dict(resolution=40, rays=32, texel_samples=2, padding=2,
               quantities=("ao", "obscurance"), unwrap="never")


@pytest.fixture(scope="module")
def torus(tmp_path_factory):
    return torus_obj(tmp_path_factory.mktemp("denoise") / "torus.obj")


@functools.lru_cache(maxsize=None)
def _bake(path, denoised, seed=0, **extra):
    return bake_texels(path, denoise=denoised, seed=seed, **{**OPTIONS, **extra})


# --- the filter on synthetic guides ----------------------------------------------------


def strip(height=24, width=48, fold=None, chart_split=False):
    """A flat (H, W) grid of texels 1 unit apart; right of column ``fold`` the surface turns
    (normal +x instead of +z, positions continuing along -z) when fold is set, or belongs to
    another chart when chart_split.  Returns a Guide (every texel covered, 64 rays each)."""
    r, c = np.mgrid[0:height, 0:width].astype(np.float64)
    position = np.stack([c, r, np.zeros_like(c)], -1)
    normal = np.broadcast_to([0.0, 0.0, 1.0], position.shape).copy()
    chart = np.zeros((height, width), np.int64)
    if fold is not None:
        right = c >= fold
        position[right] = np.stack([np.full(right.sum(), fold - 0.5), r[right],
                                    -(c[right] - fold + 0.5)], -1)
        normal[right] = [1.0, 0.0, 0.0]
    if chart_split:
        chart[:, width // 2:] = 1
    return Guide(position, normal, chart, np.full((height, width), 64.0),
                 np.ones((height, width), bool), 1.0)


def test_never_mixes_across_a_crease_or_a_chart():
    # Exact values, 0.3 left and 0.9 right, with stderrs as large as the step: only the
    # normals (90 degrees > CREASE_ANGLE) or the chart ids keep the halves apart, exactly.
    assert CREASE_ANGLE < 90
    for guide in (strip(fold=24), strip(chart_split=True)):
        value = np.where(np.arange(48) < 24, 0.3, 0.9)[None, :].repeat(24, 0)
        out, se = denoise(value, np.full(value.shape, 0.6), guide)
        np.testing.assert_allclose(out, value, rtol=0, atol=1e-15)
        assert (se > 0).all() and (se < 0.6).all()


def test_keeps_a_step_the_noise_cannot_explain():
    # A contact-shadow-like step 0.2 -> 0.8 on one flat chart, noise sd 0.02: next to the
    # step the denoised values stay at their side's truth within 4 standard errors of
    # their mean over the texels (the range kernel gives the far side ~e^-56 weight).
    rng = np.random.default_rng(3)
    guide = strip()
    truth = np.where(np.arange(48) < 24, 0.2, 0.8)[None, :].repeat(24, 0)
    se = np.full(truth.shape, 0.02)
    out, out_se = denoise(truth + rng.normal(0, 0.02, truth.shape), se, guide)
    for col in (23, 24):
        err = out[:, col] - truth[:, col]
        assert abs(err.mean()) < 4 * 0.02 / math.sqrt(len(err))
        assert (np.abs(err) < 0.1).all()


@pytest.mark.slow
def test_no_bias_and_the_noise_channel_predicts_the_spread():
    # Constant truth 0.6, Gaussian noise of a known sd per texel (two levels), over seeds:
    # the denoised value's mean is the truth within 4 SE of the seeds' mean, and its
    # spread over seeds matches the denoised stderr (treats the weights as given; the
    # range kernel makes them depend on the data a little: measured 1.00-1.03 at k = 4 over
    # 2000 seeds, SE ~0.015, so 4 SE also catches k = 2's 1.10-1.13).
    guide = strip(height=16, width=16)
    sd = np.where(np.arange(16) % 2 == 0, 0.03, 0.06)[None, :].repeat(16, 0)
    outs, preds = [], []
    for seed in range(2000):
        rng = np.random.default_rng(seed)
        out, out_se = denoise(0.6 + rng.normal(0, 1, sd.shape) * sd, sd, guide)
        outs.append(out[4:12, 4:12].ravel())  # the interior: full windows
        preds.append(out_se[4:12, 4:12].ravel())
    outs, preds = np.array(outs), np.array(preds)
    per_seed = (outs - 0.6).mean(axis=1)
    assert abs(per_seed.mean()) < 4 * per_seed.std(ddof=1) / math.sqrt(len(per_seed))
    z2 = (((outs - 0.6) / preds) ** 2).mean(axis=1)  # one value per seed, mean 1 if honest
    assert abs(z2.mean() - 1) < 4 * z2.std(ddof=1) / math.sqrt(len(z2))
    assert preds.mean() < sd.mean() / 3  # and it does reduce the noise


# --- in a bake ---------------------------------------------------------------------------


def test_raw_channels_are_untouched_and_denoised_ones_are_beside_them(torus):
    raw, both = _bake(str(torus), False), _bake(str(torus), True)
    for name, image in raw.channels.items():
        np.testing.assert_array_equal(both.channels[name], image)
    covered = both.covered
    for q in OPTIONS["quantities"]:
        d, se = both.channels[q + "_denoised"], both.channels[q + "_denoised_stderr"]
        assert d.dtype == np.float32 and d.shape == covered.shape
        assert np.isfinite(d).all() and (d >= 0).all() and (d <= 1).all()
        assert (se[covered] > 0).all()
        assert se[covered].mean() < both.channels[q + "_stderr"][covered].mean()
        stats = both.report["texture"]["denoise"][q]
        assert stats["noise_reduction"] == pytest.approx(
            stats["stderr_mean"] / stats["denoised_stderr_mean"])
    assert raw.report["texture"]["denoise"] is None
    assert "denoise_s" in both.report["timings"]
    # the seams' report is the baked channels' solves, the same with or without denoising
    assert both.report["texture"]["seams"] == raw.report["texture"]["seams"]


def test_denoised_channels_are_seam_erased(torus):
    result = _bake(str(torus), True)
    points = random_seam_points(seam_mesh(result))
    for q in OPTIONS["quantities"]:
        d = differences(result, q + "_denoised", points)
        noise = lookup_noise(result, q + "_denoised", points)
        # the same criterion as the raw channels' erasure (tests/test_seams.py)
        assert np.sqrt(np.mean((d / noise) ** 2)) < 0.02


def test_closer_to_a_reference_than_the_raw_map(torus):
    # At 16 rays per texel the raw map is noise-dominated; against a 1024-ray reference of
    # another seed (its own noise taken out), the denoised map's mean squared error is
    # smaller than the raw one's.
    ref = _bake(str(torus), False, seed=7, rays=1024)
    low = _bake(str(torus), True, seed=0, rays=16)
    mask = ref.covered & low.covered
    noise = np.mean(ref.channels["ao_stderr"][mask].astype(np.float64) ** 2)
    mse = {name: np.mean((low.channels[name][mask] - ref.channels["ao"][mask]) ** 2) - noise
           for name in ("ao", "ao_denoised")}
    assert mse["ao_denoised"] < mse["ao"]


# --- the command line ----------------------------------------------------------------


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "aobake", *map(str, args)],
                          capture_output=True, text=True)


@pytest.mark.slow
def test_cli_writes_the_channels_to_exr(torus, tmp_path):
    import OpenImageIO as oiio

    out = tmp_path / "ao.exr"
    done = _cli(torus, "--out", out, "--denoise", "--rays", 16, "--resolution", 32,
                "--quiet")
    assert done.returncode == 0, done.stderr
    image = oiio.ImageInput.open(str(out))
    names = set(image.spec().channelnames)
    image.close()
    assert {"ao", "ao_stderr", "ao_ci_low", "ao_ci_high", "ao_denoised",
            "ao_denoised_stderr"} <= names


def test_uv_soup_still_has_its_charts():
    # One vt per corner (no shared UV indices): charts come from UVs at the same place, so
    # a plane of 2 x 8 x 8 triangles is one chart, not 128.
    from aobake.targets.texels.charts import uv_islands

    n = 8
    g = np.linspace(0, 1, n + 1)
    uv, faces = [], []
    for i in range(n):
        for j in range(n):
            for tri in (((i, j), (i + 1, j), (i + 1, j + 1)), ((i, j), (i + 1, j + 1), (i, j + 1))):
                faces.append([len(uv), len(uv) + 1, len(uv) + 2])
                uv += [(g[a], g[b]) for a, b in tri]
    labels = uv_islands(np.array(uv), np.array(faces))
    assert len(np.unique(labels)) == 1


def test_refused_without_a_scalar_quantity(torus):
    from aobake.errors import InputError

    with pytest.raises(InputError, match="denoise"):
        bake_texels(str(torus), denoise=True, quantities=("bent_normal",), resolution=16, rays=4)


@pytest.mark.slow
@pytest.mark.parametrize("out", ["ao.png", "ao.npz", "ao.glb"])
def test_cli_refuses_denoise_without_exr(torus, tmp_path, out):
    done = _cli(torus, "--out", tmp_path / out, "--denoise", "--rays", 4, "--resolution", 16)
    assert done.returncode == 2
    assert "--denoise" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / out).exists()
