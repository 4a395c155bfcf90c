"""``aobake refit`` held to the error contract (docs/reliability.md): everything it reads is
checked against the file's own metadata before anything is computed (a hand-edited NPZ is
one line naming the file, never a traceback or a wrong answer with exit 0), the signal
contract of the main command, and kept distances that hold no inf.

Every file is made here, under tmp_path.
"""

import json
import os
import signal
import time

import numpy as np
import pytest
import trimesh

import aobake
from aobake.outputs.npz import RAY_MISS
from aobake.refit import refit
from conftest import run_cli

OPTIONS = dict(quantities=("ao", "obscurance"), rays=8, max_distance=1.5, tau=1.0, seed=2)


@pytest.fixture(scope="module")
def kept(tmp_path_factory):
    """A sphere over a floor baked keeping its distances (hits and misses), and its NPZ."""
    tmp = tmp_path_factory.mktemp("kept")
    mesh = trimesh.util.concatenate([
        trimesh.creation.icosphere(subdivisions=1).apply_translation([0, 1.2, 0]),
        trimesh.creation.box(extents=[4, 0.2, 4])])
    result = aobake.bake(mesh, keep_distances=True, **OPTIONS)
    aobake.write(result, tmp / "kept.npz")
    return result, tmp / "kept.npz"


def arrays_of(path):
    with np.load(path) as data:
        return {name: data[name] for name in data.files}


def edited(path, arrays, meta=None):
    """Save ``arrays`` (with ``meta`` as the metadata, when given) as an NPZ at ``path``."""
    arrays = dict(arrays)
    if meta is not None:
        arrays["metadata"] = np.array(json.dumps(meta))
    np.savez(path, **arrays)
    return path


def _meta(arrays):
    return json.loads(str(arrays["metadata"]))


def _edit_meta(section, key, value):
    def change(arrays):
        meta = _meta(arrays)
        if key is None:
            meta[section] = value
        else:
            meta[section][key] = value
        return arrays, meta
    return change


def _edit_array(name, function):
    def change(arrays):
        arrays = dict(arrays)
        if function is None:
            del arrays[name]
        else:
            arrays[name] = function(arrays[name])
        return arrays, None
    return change


def _distances(function):
    return _edit_array("ray_distances", function)


#: name -> (change of the arrays / metadata, text in the message)
HAND_EDITS = {
    "no normals": (_edit_array("normals", None), "no normals array"),
    "no rays": (_edit_array("rays", None), "no rays array"),
    "no config": (_edit_meta("config", None, None), "no bake configuration"),
    "config a string": (_edit_meta("config", None, "fast"), "no bake configuration"),
    "parameters a list": (_edit_meta("parameters", None, [1, 2]), "no bake configuration"),
    "rays a string": (_edit_meta("config", "rays", "many"), "config"),
    "no trace_scale": (_edit_meta("parameters", "trace_scale", None), "trace_scale"),
    "zero trace_scale": (_edit_meta("parameters", "trace_scale", 0), "trace_scale"),
    "trace_scale text": (_edit_meta("parameters", "trace_scale", "big"), "trace_scale"),
    "NaN diagonal": (_edit_meta("parameters", "diagonal", "nan"), "diagonal"),
    "zero diagonal": (_edit_meta("parameters", "diagonal", 0.0), "diagonal"),
    "NaN max distance": (_edit_meta("parameters", "max_distance", "nan"), "max_distance"),
    "ray_point out of range": (_edit_array("ray_point", lambda a: a + 10 ** 6), "ray_point"),
    "negative ray_point": (_edit_array("ray_point", lambda a: np.where(np.arange(len(a)) == 3,
                                                                       -1, a)), "ray_point"),
    "short ray_point": (_edit_array("ray_point", lambda a: a[:5]), "ray_point 5, the others"),
    "short positions": (_edit_array("positions", lambda a: a[:5]), "positions 5, the others"),
    "short normals": (_edit_array("normals", lambda a: a[:5]), "normals 5, the others"),
    "short ao": (_edit_array("ao", lambda a: a[:5]), "ao 5, the others"),
    "NaN ao": (_edit_array("ao", lambda a: np.full_like(a, np.nan)), "ao must be"),
    "rays changed": (_edit_array("rays", lambda a: a * 0 + 3), "rays per vertex"),
    "short rows": (_distances(lambda d: d[:, :3]), "do not match"),
    "string distances": (_distances(lambda d: d.astype(str)), "distances are floats"),
    "integer distances": (_distances(lambda d: np.where(d > 0, d * 10, 0).astype(np.int32)),
                          "distances are floats"),
    "NaN distances": (_distances(lambda d: np.where(d > 0, np.nan, d)), "NaN or negative"),
    "negative distances": (_distances(lambda d: np.where(d > 0, -d, d)), "NaN or negative"),
    "minus infinity": (_distances(lambda d: np.where(d == RAY_MISS, -np.inf, d)),
                       "NaN or negative"),
    "beyond the max distance": (_distances(lambda d: np.where(d > 0, d * 100, d)),
                                "beyond the baked max distance"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(HAND_EDITS))
def test_a_hand_edited_bake_is_refused_naming_it(kept, tmp_path, case):
    """Each would give a traceback or, worse, a wrong answer with exit 0 (NaN distances:
    AO 1 everywhere; negative ones change obscurance; integers are misread)."""
    change, text = HAND_EDITS[case]
    arrays, meta = change(arrays_of(kept[1]))
    path = edited(tmp_path / "edited.npz", arrays, meta)
    res = run_cli("refit", path, "-o", tmp_path / "out.npz", "--tau", "2")
    assert res.exit_code == 1, res.output
    assert isinstance(res.exception, SystemExit)  # no traceback
    assert res.output.startswith(f"aobake: error: {path}: ") and res.output.count("\n") == 1, \
        res.output
    assert text in res.output, res.output
    assert sorted(os.listdir(tmp_path)) == ["edited.npz"]
    with pytest.raises(aobake.InputError, match=text):
        refit(path, tau=2.0)


def test_unreadable_archives_are_refused_naming_them(kept, tmp_path):
    data = kept[1].read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04" + bytes(40))
    for name in ("cut.npz", "junk.npz"):
        res = run_cli("refit", tmp_path / name, "-o", tmp_path / "out.npz")
        assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
        assert res.output.startswith(f"aobake: error: {tmp_path / name}: not a readable NPZ")


@pytest.mark.parametrize("signum, code, text", [
    (signal.SIGINT, 130, "aobake: error: interrupted (SIGINT): no output written\n"),
    (signal.SIGTERM, 143, "aobake: error: terminated (SIGTERM): no output written\n")])
def test_refit_follows_the_signal_contract(kept, tmp_path, monkeypatch, signum, code, text):
    """A signal half-way through writing the output: the main command's exit status and
    one line, and no output nor temporary file left."""
    from aobake.outputs import npz

    def half_written(handle, arrays):
        handle.write(b"PK\x03\x04 half an archive")
        handle.flush()
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the signal arrives here

    monkeypatch.setattr(npz, "_savez", half_written)
    start = time.perf_counter()
    res = run_cli("refit", kept[1], "-o", tmp_path / "r.npz", "--tau", "2")
    assert time.perf_counter() - start < 4
    assert res.exit_code == code, res.output
    assert res.output == text
    assert os.listdir(tmp_path) == []  # no r.npz, no .r.npz.aobake-unfinished-*


def test_kept_distances_hold_no_inf(kept, tmp_path):
    """A miss is stored as RAY_MISS (-1), not inf; refit reads it, and reads the inf of
    files written before, to the same numbers as the bake in memory."""
    result, path = kept
    memory = result.kept["ray_distances"]
    stored = arrays_of(path)["ray_distances"]
    assert stored.dtype == np.float32 and np.isfinite(stored).all()
    misses = np.isinf(memory)
    assert misses.any() and (~misses).any()  # the fixture has both
    assert np.array_equal(stored == RAY_MISS, misses)
    assert np.array_equal(stored[~misses], memory[~misses]) and (stored[~misses] >= 0).all()
    fresh = refit(result, tau=3.0, max_distance=1.0)
    for source in (path, edited(tmp_path / "old.npz", dict(
            arrays_of(path), ray_distances=np.where(stored == RAY_MISS, np.inf, stored)
            .astype(np.float32)))):
        again = refit(source, tau=3.0, max_distance=1.0)
        for name, array in fresh.fields().items():
            np.testing.assert_array_equal(again.fields()[name], array, err_msg=f"{source} {name}")
    # a refit written again keeps the encoding
    res = run_cli("refit", tmp_path / "old.npz", "-o", tmp_path / "again.npz", "--tau", "3")
    assert res.exit_code == 0, res.output
    assert np.isfinite(arrays_of(tmp_path / "again.npz")["ray_distances"]).all()


def test_refit_over_its_own_bake_is_refused_calling_it_the_bake(kept, tmp_path):
    path = tmp_path / "kept.npz"
    path.write_bytes(kept[1].read_bytes())
    before = path.read_bytes()
    res = run_cli("refit", path, "-o", path, "--tau", "2")
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    assert res.output == (f"aobake: error: {path}: refusing to overwrite the input bake: "
                          "every output needs its own file\n"), res.output
    assert path.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["kept.npz"]
    with pytest.raises(aobake.OutputError, match="refusing to overwrite the input bake"):
        aobake.write(refit(path, tau=2.0), path, mesh=path)
