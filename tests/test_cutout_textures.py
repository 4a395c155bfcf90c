"""--alpha-cutout refuses a MASK material whose base-colour texture cannot be read (issue 35).

trimesh drops an image it cannot load without a word; a MASK material left without its alpha
would occlude everywhere, a wrong bake that looks like a right one.  A missing, undecodable or
truncated texture of such a material is an input error naming the file, the material and
the texture, through the library and the command line; without --alpha-cutout the alpha is
not used and the bake goes on.
"""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

import aobake
from conftest import run_cli
from gltf_scenes import png
from test_cutout import checker, scene_file


def _with_image(tmp_path, name, image: dict, files: dict = ()):
    """The cut-out test scene with its plate's texture replaced by ``image`` (a glTF image
    object), and ``files`` (name -> bytes) written beside it."""
    good = json.loads(open(scene_file(tmp_path, alpha=checker(), name="good.gltf")).read())
    good["images"][0] = image
    path = tmp_path / name
    path.write_text(json.dumps(good))
    for file, data in dict(files).items():
        (tmp_path / file).write_bytes(data)
    return path


CASES = {
    "missing": ({"uri": "plate.png"}, {}, "texture plate.png: no such file"),
    "garbage": ({"uri": "plate.png"}, {"plate.png": b"\x89PNG\r\n\x1a\nnot a png"},
                "texture plate.png: not an image"),
    "embedded": ({"uri": "data:image/png;base64," + base64.b64encode(b"junk").decode()}, {},
                 "texture images[0] (embedded): not an image"),
    "truncated": ({"uri": "plate.png"}, {"plate.png": png(checker())[:60]}, "truncated"),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.slow
def test_library_refuses_an_unreadable_mask_texture(tmp_path, case):
    image, files, words = CASES[case]
    path = _with_image(tmp_path, f"{case}.gltf", image, files)
    with pytest.raises(aobake.InputError) as info:
        aobake.bake(path, alpha_cutout=True, rays=8)
    message = str(info.value)
    assert str(path) in message and words in message
    if case != "truncated":  # a truncated image is a corrupt file to trimesh itself
        assert "material1" in message and "MASK" in message
        # without the option the alpha is not used: the bake goes on
        assert np.isfinite(aobake.bake(path, rays=8).ao).all()


@pytest.mark.parametrize("case", ["missing", "garbage"])
@pytest.mark.slow
def test_cli_refuses_an_unreadable_mask_texture(tmp_path, case):
    image, files, words = CASES[case]
    path = _with_image(tmp_path, f"{case}.gltf", image, files)
    result = run_cli(path, "--alpha-cutout", "--rays", 8, "--out", tmp_path / "ao.ply")
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"aobake: error: {path}: --alpha-cutout")
    assert words in lines[0] and "Traceback" not in result.output
    assert not (tmp_path / "ao.ply").exists()


@pytest.mark.slow
def test_a_readable_mask_texture_still_bakes(tmp_path):
    path = scene_file(tmp_path, alpha=checker())
    assert np.isfinite(aobake.bake(path, alpha_cutout=True, rays=8).ao).all()
