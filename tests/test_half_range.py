"""--half EXR of values beyond half float's range (issue 35): a view of a scene far from the
origin held inf in depth, distance and P.  Such channels are written as float32 (named in a
warning and in the ``aobake:float_channels`` attribute); ids stay float32 like ray counts
(half rounds integers above 2048)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest
import trimesh

import aobake
from aobake.outputs.image import HALF_MAX, write_exr


def _read(path):
    image = oiio.ImageInput.open(str(path))
    try:
        spec = image.spec()
        pixels = image.read_image("float")
        formats = [str(f) for f in spec.channelformats] or [str(spec.format)] * spec.nchannels
        return pixels, list(spec.channelnames), formats, spec.getattribute("aobake:float_channels")
    finally:
        image.close()


def test_write_exr_keeps_channels_beyond_half_range_in_float32(tmp_path, caplog):
    path = tmp_path / "h.exr"
    big = np.full((2, 3), 3.0e6)
    ids = np.arange(6, dtype=np.float64).reshape(2, 3) + 70001
    write_exr(path, {"ao": np.full((2, 3), 0.5), "depth": big, "primitive_id": ids,
                     "inf_only": np.full((2, 3), np.inf)}, half=True)
    pixels, names, formats, beyond = _read(path)
    kind = dict(zip(names, formats))
    assert kind["ao"] == "half" and kind["inf_only"] == "half"  # inf is inf in either
    assert kind["depth"] == "float" and kind["primitive_id"] == "float"
    np.testing.assert_array_equal(pixels[..., names.index("depth")], big)
    np.testing.assert_array_equal(pixels[..., names.index("primitive_id")], ids)
    assert json.loads(beyond) == ["depth"]
    assert "depth" in caplog.text and "float32" in caplog.text


@pytest.fixture
def far_mesh(tmp_path):
    mesh = trimesh.creation.icosphere(1)
    mesh.apply_scale(1e5)
    mesh.apply_translation([3e6, 0.0, 0.0])
    path = tmp_path / "far.ply"
    mesh.export(path)
    return path


@pytest.mark.slow
def test_library_view_of_a_far_scene_as_half_has_no_inf(far_mesh, tmp_path):
    view = aobake.bake_view(far_mesh, size=(12, 12), rays=4)
    aobake.write(view, tmp_path / "v.exr", half=True)
    pixels, names, formats, _ = _read(tmp_path / "v.exr")
    covered = pixels[..., names.index("coverage")] > 0
    assert covered.any()
    for name in ("depth", "distance", "P.X"):
        channel = pixels[..., names.index(name)]
        assert np.isfinite(channel[covered]).all(), name
        assert np.abs(channel[covered]).max() > HALF_MAX
    assert dict(zip(names, formats))["ao"] == "half"


@pytest.mark.slow
def test_cli_view_of_a_far_scene_as_half_warns_once(far_mesh, tmp_path):
    out = tmp_path / "v.exr"
    result = subprocess.run([sys.executable, "-m", "aobake", "view", str(far_mesh), "--half",
                             "--size", "12x12", "--rays", "4", "--out", str(out)],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith(f"aobake: warning: {out}: ")
    assert "float32" in warnings[0] and "depth" in warnings[0]
    pixels, names, _, _ = _read(out)
    covered = pixels[..., names.index("coverage")] > 0
    assert np.isfinite(pixels[covered]).all()
