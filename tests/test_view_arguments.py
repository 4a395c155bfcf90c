"""The library's view arguments are checked at the door (issue 35): a malformed ``look``,
``camera`` or ``gltf`` raised KeyError, TypeError, AttributeError or ValueError from deep in
the bake; an eye 1e300 from the scene leaked numpy's overflow warning; ``--camera`` on an
OBJ said "invalid glTF JSON".  Each is now an ``InputError`` naming the argument or file."""

from __future__ import annotations

import subprocess
import sys
import warnings

import pytest
import trimesh

import aobake
from aobake.camera import look_at

SIZE = (8, 6)


@pytest.fixture(scope="module")
def mesh(tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "sphere.obj"
    trimesh.creation.icosphere(1).export(path)
    return path


BAD = {
    "look an int": (dict(look=5), "look must be a dict"),
    "look a list": (dict(look=[[3, 3, 3], [0, 0, 0]]), "look must be a dict"),
    "look empty": (dict(look={}), "look needs look_from and look_at"),
    "look without look_at": (dict(look={"look_from": [3, 3, 3]}), "look needs look_at"),
    "look misspelt": (dict(look={"look_from": [3, 3, 3], "look_at": [0, 0, 0], "fovy": 30}),
                      "unknown key(s) fovy"),
    "look bad point": (dict(look={"look_from": "x", "look_at": [0, 0, 0]}),
                       "look-from must be 3 numbers"),
    "camera a dict": (dict(camera={"eye": [3, 3, 3]}), "camera must be an aobake.camera.Camera"),
    "camera a str": (dict(camera="front"), "camera must be an aobake.camera.Camera"),
    "gltf an int": (dict(gltf=5), "gltf must be a pair"),
    "gltf a bare path": (dict(gltf="scene.gltf"), "gltf must be a pair"),
    "gltf one item": (dict(gltf=("scene.gltf",)), "gltf must be a pair"),
    "gltf path None": (dict(gltf=(None, None)), "gltf's path must be a file path"),
    "gltf name an int": (dict(gltf=("scene.gltf", 0)), "camera name must be text"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_view_arguments_are_input_errors(mesh, case):
    kwargs, words = BAD[case]
    with pytest.raises(aobake.InputError) as info:
        aobake.bake_view(mesh, size=SIZE, rays=2, **kwargs)
    assert words in str(info.value)


def test_a_camera_still_works(mesh):
    cam = look_at([3, 2, 3], [0, 0, 0], [0, 1, 0], 40, size=SIZE)
    assert aobake.bake_view(mesh, camera=cam, rays=2).channels["coverage"].any()
    view = aobake.bake_view(mesh, look={"look_from": [3, 2, 3], "look_at": [0, 0, 0]},
                            size=SIZE, rays=2)
    assert view.channels["coverage"].any()


def test_gltf_camera_of_an_obj_says_it_needs_a_gltf(mesh):
    with pytest.raises(aobake.InputError) as info:
        aobake.bake_view(mesh, gltf=(mesh, None), size=SIZE, rays=2)
    message = str(info.value)
    assert message.startswith(f"{mesh}: ") and "needs a glTF" in message
    assert "JSON" not in message


@pytest.mark.parametrize("distance", [1e30, 1e200, 1e300])
def test_a_far_eye_is_an_input_error_without_numpy_warnings(mesh, distance):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy overflow warning fails the test
        with pytest.raises(aobake.InputError, match="from the scene"):
            aobake.bake_view(mesh, look={"look_from": [distance, 0, 0], "look_at": [0, 0, 0]},
                             size=SIZE, rays=2)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "aobake", "view", *map(str, args)],
                          capture_output=True, text=True)


@pytest.mark.slow
def test_cli_far_eye_is_one_error_line(mesh, tmp_path):
    result = _cli(mesh, "--look-from", "1e300,0,0", "--look-at", "0,0,0", "--size", "8x6",
                  "--out", tmp_path / "v.exr")
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"aobake: error: {mesh}: the camera's eye")


@pytest.mark.slow
def test_cli_camera_on_an_obj_says_it_needs_a_gltf(mesh, tmp_path):
    result = _cli(mesh, "--camera", "first", "--size", "8x6", "--out", tmp_path / "v.exr")
    assert result.returncode in (1, 2), result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs a glTF" in lines[-1], result.stderr
    assert "invalid glTF JSON" not in result.stderr
