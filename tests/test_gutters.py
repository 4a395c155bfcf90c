"""Mip-safe gutters: `--padding` rings of exact dilation, push-pull fill beyond them.

The mip chain the tests use is the box filter: level k + 1 is the 2x2 mean of level k.
For odd sizes a 2x2 block that runs past the edge averages the texels it has, weighted by
how many level-0 texels each stands for, so a level-k texel is the plain mean of the
level-0 texels of its footprint, rows i 2^k .. (i + 1) 2^k - 1 and columns likewise,
cropped to the image (what ``aobake.post.push_pull`` pyramids over, too).

"No black bleed" is checked three ways at every level down to 16 x 16 (`_mip_violations`):
(a) where a footprint is fully covered, the mip of the map is the mean of the charts;
(b) where a footprint holds a covered texel, the mip lies within [min, max] of the covered
texels of that footprint grown by `padding` texels (the reach of the exact dilation);
(c) no mip texel falls below the smallest covered value.
Today's maps (black beyond the rings, rebuilt by `_bake(..., fill=False)`) fail (b) and (c).
"""

import contextlib
import functools
import json
from unittest import mock

import numpy as np
import pytest
import scipy.ndimage
import trimesh

from aobake import post
from aobake.api import bake_texels
from aobake.targets.texels import gather
from conftest import run_cli
from readers import read_image

#: channels that are not filled: 0 outside the charts
UNFILLED = ("rays", "coverage")
#: float32 rounding of the fill (its sums are float32): far below any AO difference
TINY = 1e-6
QUANTITIES = ("ao", "obscurance", "bent-normal")


def _mesh():
    """A sphere under a plate: AO varies (0.1..1), on a fresh xatlas atlas of 12 charts."""
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[16, 16])
    plate = trimesh.creation.box(extents=[0.8, 0.8, 0.1])
    plate.apply_translation([0, 0, 1.3])
    return trimesh.util.concatenate([sphere, plate])


@functools.lru_cache(maxsize=None)
def _bake(resolution, padding, fill=True):
    """(result, the stack handed to `dilate`, its channel names) of one bake.

    fill=False replaces push-pull by a pass-through: the maps of the previous release
    (dilated rings, then whatever the splat left: 0 for the values)."""
    seen = {}

    def spy(stack, covered, pad, compiled=None):
        seen["stack"] = np.array(stack, dtype=np.float64)
        return post.dilate(stack, covered, pad, compiled=compiled)

    with contextlib.ExitStack() as patches:
        patches.enter_context(mock.patch.object(gather, "dilate", spy))
        if not fill:
            patches.enter_context(mock.patch.object(gather, "push_pull",
                                                    lambda stack, mask, dtype: stack))
        res = bake_texels(_mesh(), resolution=resolution, padding=padding, texel_samples=1,
                          rays=64, unwrap="always", quantities=QUANTITIES)
    names = [n for n in res.channels if n not in UNFILLED]
    return res, seen["stack"], names


def _rings(covered, padding):
    """(H, W) bool: covered texels and the `padding` rings of exact dilation."""
    return post.dilate(np.zeros(covered.shape + (1,)), covered, padding)[1]


def _blocks(a, k, fill, reduce):
    """Level-k footprint reduction of (H, W) `a`: pad to multiples of 2^k with `fill`."""
    s = 1 << k
    h, w = a.shape
    hp, wp = -(-h // s) * s, -(-w // s) * s
    padded = np.full((hp, wp), fill, dtype=np.float64)
    padded[:h, :w] = a
    return reduce(padded.reshape(hp // s, s, wp // s, s), axis=(1, 3))


def _mip_violations(image, covered, padding, min_side=16):
    """Texels breaking (a), (b), (c) of the module docstring, summed over the levels
    k >= 1 whose both sides are >= min_side; also the number of levels checked."""
    image = np.asarray(image, dtype=np.float64)
    h, w = image.shape
    ones = np.ones_like(image)
    chart = np.where(covered, image, 0.0)
    size = 2 * padding + 1  # footprint grown by `padding` texels on every side
    low = scipy.ndimage.minimum_filter(np.where(covered, image, np.inf), size=size,
                                       mode="constant", cval=np.inf)
    high = scipy.ndimage.maximum_filter(np.where(covered, image, -np.inf), size=size,
                                        mode="constant", cval=-np.inf)
    floor = image[covered].min()
    bad = {"a": 0, "b": 0, "c": 0, "levels": 0}
    k = 1
    while max(h, w) > 1 << (k - 1) and min(-(-h >> k), -(-w >> k)) >= min_side:
        count = _blocks(ones, k, 0.0, np.sum)
        mip = _blocks(image, k, 0.0, np.sum) / count
        n_cov = _blocks(covered.astype(np.float64), k, 0.0, np.sum)
        full = n_cov == count
        charts = _blocks(chart, k, 0.0, np.sum) / np.maximum(n_cov, 1)
        has = n_cov > 0
        lo, hi = _blocks(low, k, np.inf, np.min), _blocks(high, k, -np.inf, np.max)
        bad["a"] += int(np.count_nonzero(np.abs(mip - charts)[full] > TINY))
        bad["b"] += int(np.count_nonzero((mip < lo - TINY)[has] | (mip > hi + TINY)[has]))
        bad["c"] += int(np.count_nonzero(mip < floor - TINY))
        bad["levels"] += 1
        k += 1
    return bad


SIZES = [pytest.param(128, 2, id="128-pad2"), pytest.param((101, 75), 1, id="101x75-pad1"),
         pytest.param((96, 128), 3, id="96x128-pad3"), pytest.param(64, 0, id="64-pad0")]


@pytest.mark.slow
@pytest.mark.parametrize("resolution, padding", SIZES)
def test_every_filled_channel_is_finite_and_filled_outside_the_charts(resolution, padding):
    res, _, names = _bake(resolution, padding)
    covered = res.covered
    assert 0.2 < covered.mean() < 0.8  # there are gutters to fill
    fill = ~_rings(covered, padding)
    assert fill.any()
    for name in names:
        image = res.channels[name]
        assert np.all(np.isfinite(image)), name
        charts = image[covered]
        if name.startswith("bent_normal."):
            continue  # directions: checked as vectors below
        # The fill is a convex combination of chart values: in their range, so 0 only
        # where the charts reach 0 (ci_low clipped at 0 may).
        assert charts.min() - TINY <= image[fill].min(), name
        assert image[fill].max() <= charts.max() + TINY, name
        if charts.min() > 0:
            assert image[fill].min() > 0, name
    bent = np.stack([res.channels[f"bent_normal.{a}"] for a in "XYZ"], axis=-1)
    np.testing.assert_allclose(np.linalg.norm(bent[fill], axis=-1), 1.0, atol=1e-5)
    low, value, high = (res.channels[f"ao{s}"] for s in ("_ci_low", "", "_ci_high"))
    assert np.all(low[fill] <= value[fill] + TINY) and np.all(value[fill] <= high[fill] + TINY)
    # rays and coverage tell real texels from fill: 0 outside the charts.
    for name in UNFILLED:
        assert np.all(res.channels[name][~covered] == 0), name
    assert np.all(res.channels["rays"][covered] > 0)
    # Today's maps were black there.
    old, _, _ = _bake(resolution, padding, fill=False)
    assert np.all(old.channels["ao"][fill] == 0)


@pytest.mark.slow
@pytest.mark.parametrize("resolution, padding", SIZES)
def test_box_filtered_mips_never_bleed_black_into_the_charts(resolution, padding):
    res, _, _ = _bake(resolution, padding)
    ao, covered = res.channels["ao"], res.covered
    assert ao[covered].min() > 0.05  # a black texel would stand out
    bad = _mip_violations(ao, covered, padding)
    assert bad["levels"] >= 1
    assert bad == {"a": 0, "b": 0, "c": 0, "levels": bad["levels"]}, bad
    for name in ("obscurance", "ao_stderr"):  # every scalar channel obeys the same
        assert _mip_violations(res.channels[name], covered, padding)["b"] == 0, name
    # The criterion has teeth: the previous release's black gutters fail it.
    old, _, _ = _bake(resolution, padding, fill=False)
    assert np.array_equal(old.covered, covered)
    bad_old = _mip_violations(old.channels["ao"], covered, padding)
    assert bad_old["a"] == 0 and bad_old["c"] > 0, bad_old
    if 1 << bad_old["levels"] > padding + 1:  # a footprint reaches beyond the rings
        assert bad_old["b"] > 0, bad_old


@pytest.mark.parametrize("resolution, padding", SIZES)
@pytest.mark.slow
def test_dilation_within_padding_is_unchanged_bit_for_bit(resolution, padding):
    res, stack, names = _bake(resolution, padding)
    old, old_stack, _ = _bake(resolution, padding, fill=False)
    rings = _rings(res.covered, padding)
    expected, filled = post.dilate(stack, res.covered, padding)  # the exact dilation
    np.testing.assert_array_equal(filled, rings)
    assert res.report["texture"]["texels_padded"] == int(np.count_nonzero(rings & ~res.covered))
    np.testing.assert_array_equal(stack, old_stack)  # the same bake up to the gutters
    for i, name in enumerate(names):
        new = res.channels[name][rings]
        want = expected[..., i].astype(np.float32)[rings]
        assert np.array_equal(new.view(np.uint32), want.view(np.uint32)), name
        assert np.array_equal(new.view(np.uint32),
                              old.channels[name][rings].view(np.uint32)), name
    for name in UNFILLED:
        assert np.array_equal(res.channels[name], old.channels[name]), name


@pytest.mark.slow
def test_padding_zero_through_the_cli(tmp_path):
    mesh = tmp_path / "scene.ply"
    _mesh().export(mesh)
    out, rep = tmp_path / "ao.exr", tmp_path / "r.json"
    res = run_cli(mesh, "--out", out, "--resolution", "80x48", "--padding", 0, "--rays", 32,
                  "--texel-samples", 1, "-q", "ao", "-q", "bent-normal", "--report", rep,
                  "--quiet")
    assert res.exit_code == 0, res.output
    pixels, names, _ = read_image(out)
    assert pixels.shape[:2] == (48, 80)
    assert np.all(np.isfinite(pixels))
    channel = dict(zip(names, np.moveaxis(pixels, -1, 0)))
    covered = channel["rays"] > 0
    ao = channel["ao"]
    assert covered.any() and (~covered).any()
    assert np.all(channel["coverage"][~covered] == 0)
    assert ao[~covered].min() >= ao[covered].min() - TINY and ao[~covered].min() > 0
    bad = _mip_violations(ao, covered, 0)
    assert bad == {"a": 0, "b": 0, "c": 0, "levels": 1}, bad
    report = json.loads(rep.read_text())
    assert report["texture"]["padding"] == 0 and report["texture"]["texels_padded"] == 0


# --- push_pull itself ---------------------------------------------------------------------


def _push_pull_brute_force(image, mask):
    """Each unmasked texel: the mean of the masked texels of the smallest aligned 2^k block
    (cropped to the image) around it that has any."""
    out = np.array(image, dtype=np.float64)
    for r, c in zip(*np.nonzero(~mask)):
        k = 0
        while True:
            r0, c0, s = (r >> k) << k, (c >> k) << k, 1 << k
            block = mask[r0:r0 + s, c0:c0 + s]
            if block.any():
                out[r, c] = image[r0:r0 + s, c0:c0 + s][block].mean(axis=0)
                break
            k += 1
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_push_pull_matches_brute_force_at_odd_and_non_square_sizes(seed):
    rng = np.random.default_rng(seed)
    for _ in range(20):
        h, w = rng.integers(1, 40, size=2)
        mask = rng.random((h, w)) < rng.choice([0.01, 0.1, 0.5, 0.95])
        mask[rng.integers(h), rng.integers(w)] = True
        image = rng.random((h, w, int(rng.integers(1, 5))))
        image[~mask] = np.nan  # never read
        out = post.push_pull(image, mask)
        assert out.dtype == np.float64 and out.shape == image.shape
        np.testing.assert_allclose(out, _push_pull_brute_force(image, mask), rtol=1e-12)
        assert np.array_equal(out[mask], image[mask])  # bit for bit
        single = post.push_pull(image, mask, np.float32)
        assert single.dtype == np.float32
        assert np.array_equal(single[mask], image[mask].astype(np.float32))
        np.testing.assert_allclose(single, out, rtol=1e-5)


def test_push_pull_mip_chain_stays_within_each_footprint():
    """Synthetic charts at an odd size: every mip texel with masked texels in its footprint
    lies within their range (the property (b) with padding 0, at every level to 1 x 1)."""
    rng = np.random.default_rng(3)
    h, w = 203, 157
    rr, cc = np.mgrid[:h, :w]
    mask = np.zeros((h, w), bool)
    for _ in range(25):
        r, c, rad = rng.integers(h), rng.integers(w), rng.integers(3, 20)
        mask |= (rr - r) ** 2 + (cc - c) ** 2 < rad ** 2
    image = np.where(mask, 0.2 + 0.8 * rng.random((h, w)), 0.0)
    filled = post.push_pull(image[..., None], mask)[..., 0]
    bad = _mip_violations(filled, mask, 0, min_side=1)
    assert bad["levels"] == 8 and bad["b"] == 0 and bad["c"] == 0, bad
    assert _mip_violations(image, mask, 0, min_side=1)["b"] > 0


def test_push_pull_edge_cases():
    image = np.arange(12.0).reshape(2, 3, 2)
    empty = post.push_pull(image, np.zeros((2, 3), bool))
    assert np.array_equal(empty, image) and empty is not image
    full = post.push_pull(image, np.ones((2, 3), bool))
    assert np.array_equal(full, image)
    one = np.zeros((1, 1, 1))
    assert post.push_pull(one, np.zeros((1, 1), bool)).shape == (1, 1, 1)
    row = post.push_pull(np.array([[[1.0], [0.0], [0.0], [0.0], [3.0]]]),
                         np.array([[True, False, False, False, True]]))
    np.testing.assert_array_equal(row[0, :, 0], [1, 1, 1, 1, 3])  # blocks [0,1], [0..3]
    with pytest.raises(ValueError, match="must be"):
        post.push_pull(image[..., 0], np.ones((2, 3), bool))
    with pytest.raises(ValueError, match="mask must be"):
        post.push_pull(image, np.ones((3, 2), bool))
    with pytest.raises(ValueError, match="float"):
        post.push_pull(image, np.ones((2, 3), bool), np.int32)


@pytest.mark.parametrize("seed", range(40))
def test_compiled_rings_give_the_numpy_bits(seed, kernel):
    """dilate's rings in the kernel (dilate_rings) and in numpy: the same bits and the same
    filled mask, for any shape, channel count, padding and value (-0.0, inf, NaN too)."""
    rng = np.random.default_rng(seed)
    h, w, c = (int(x) for x in rng.integers(1, 30, 3))
    c = 1 + c % 5
    mask = rng.random((h, w)) < rng.random()
    image = rng.normal(size=(h, w, c))
    special = rng.random((h, w, c))
    image[special < 0.05] = -0.0
    image[(special >= 0.05) & (special < 0.07)] = np.nan
    image[(special >= 0.07) & (special < 0.08)] = -np.inf
    image = image.astype(np.float32 if seed % 2 else np.float64)
    padding = int(rng.integers(0, 6))
    fast, fast_filled = post.dilate(image, mask, padding, compiled=True)
    slow, slow_filled = post.dilate(image, mask, padding, compiled=False)
    assert np.array_equal(fast_filled, slow_filled)
    assert fast.dtype == slow.dtype and fast.tobytes() == slow.tobytes()
    assert padding == 0 or fast.dtype == np.float64  # padding 0: the input, unchanged
