"""Fuzzing the mesh readers: whatever bytes a file holds, loading it gives a valid Scene or an
``aobake.InputError`` naming the file, never another exception (hypothesis, a bounded number
of examples so the suite stays fast; the seed is derandomised so CI runs are reproducible)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aobake.errors import InputError
from aobake.scene import load_scene

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])

numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
                    st.integers(-5, 5).map(str), st.sampled_from(["x", "", "1e400", "-0", "nan"]))
index = st.one_of(st.integers(-6, 8).map(str), st.sampled_from(["", "0", "a", "1/", "//"]))
corner = st.tuples(index, st.sampled_from(["", "/"]), index, st.sampled_from(["", "/"]),
                   index).map("".join)
obj_line = st.one_of(
    st.lists(numbers, min_size=0, max_size=5).map(lambda xs: "v " + " ".join(xs)),
    st.lists(numbers, min_size=0, max_size=3).map(lambda xs: "vt " + " ".join(xs)),
    st.lists(numbers, min_size=0, max_size=4).map(lambda xs: "vn " + " ".join(xs)),
    st.lists(corner, min_size=0, max_size=6).map(lambda cs: "f " + " ".join(cs)),
    st.sampled_from(["g a", "o b", "usemtl m", "mtllib missing.mtl", "s off", "l 1 2", "# c",
                     "\\", "", "\x00", "f", "v"]),
)


def check(path):
    """Loading gives a Scene whose arrays are consistent, or an InputError naming the file,
    and no Python or numpy warning on the way."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            scene = load_scene(path)
    except InputError as exc:
        assert str(path) in str(exc)
        return
    assert scene.faces.ndim == 2 and scene.faces.shape[1] == 3 and len(scene.faces)
    assert scene.faces.min() >= 0 and scene.faces.max() < len(scene.vertices)
    assert np.isfinite(scene.vertices).all() and np.isfinite(scene.vertex_normals).all()


@pytest.mark.slow
@SETTINGS
@given(lines=st.lists(obj_line, min_size=0, max_size=25))
def test_obj_text(tmp_path, lines):
    path = tmp_path / "fuzz.obj"
    path.write_text("\n".join(lines), encoding="utf-8", errors="surrogateescape")
    check(path)


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".ply", ".stl", ".off", ".glb", ".obj"])
@SETTINGS
@given(data=st.binary(min_size=0, max_size=400))
def test_arbitrary_bytes(tmp_path, suffix, data):
    path = tmp_path / f"fuzz{suffix}"
    path.write_bytes(data)
    check(path)


HEADERS = {
    ".ply": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
    ".stl": b"solid s\n",
    ".off": b"OFF\n",
}


@pytest.mark.slow
@pytest.mark.parametrize("suffix", sorted(HEADERS))
@SETTINGS
@given(body=st.lists(st.lists(numbers, min_size=0, max_size=5).map(" ".join), max_size=12))
def test_valid_headers_with_fuzzed_bodies(tmp_path, suffix, body):
    path = tmp_path / f"fuzz{suffix}"
    path.write_bytes(HEADERS[suffix] + "\n".join(body).encode())
    check(path)
