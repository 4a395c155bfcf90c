"""Capabilities declared, checked once (issue 31): every method x target x quantity is either
refused before anything is read, with one line naming both sides, or runs; each command
offers only what it can run; a report records the sections that ran and re-bakes bit for
bit; every method on every executor gives the same bits (fixtures over the registries)."""

from __future__ import annotations

import json

import click
import numpy as np
import pytest
import trimesh

import aobake
from aobake import capabilities
from aobake.settings import SECTIONS, BakeConfig
from aobake.errors import UsageError
from aobake.methods import METHODS
from aobake.targets import TARGETS

from conftest import run_cli

#: the targets a user reaches (the projected ones are the same kinds with --from)
PLAIN_TARGETS = ("vertices", "points", "texels", "view")
QUANTITIES = capabilities.ALL_QUANTITIES


def _target(name: str):
    if name == "points":
        points = np.array([[0.0, 0.05, 0.0], [0.3, 0.05, 0.2]])
        return TARGETS["points"](points, np.tile([0.0, 1.0, 0.0], (2, 1)))
    if name == "view":
        return TARGETS["view"](size=(12, 8))
    return TARGETS[name]()


def _config(method: str, quantity: str, bake=None) -> BakeConfig:
    extra = {"ao_from": str(bake) if bake else "bake.npz"} if method == "file" else {}
    return BakeConfig(quantities=(quantity,), rays=8, resolution=32, **extra)


def test_the_declarations_cover_the_registries():
    assert set(capabilities.METHODS) == set(METHODS)
    assert set(capabilities.TARGETS) == set(TARGETS)
    for name in METHODS:
        assert METHODS[name].casts_rays == capabilities.METHODS[name].error_bars, name
        assert set(capabilities.METHODS[name].quantities) <= set(QUANTITIES)
        for section in capabilities.METHODS[name].sections:
            assert section in set(SECTIONS.values()), (name, section)


@pytest.mark.parametrize("quantity", QUANTITIES)
def test_refused_requests_are_refused_before_anything_is_read(method_name, target_name,
                                                              quantity, tmp_path):
    """A request the declarations refuse raises UsageError naming the method and the
    target's kind, for a mesh that does not even exist: nothing was loaded first."""
    can = capabilities.METHODS[method_name]
    serves = capabilities.serves(method_name, target_name)
    allowed = serves and quantity in can.quantities
    config = _config(method_name, quantity)
    missing = tmp_path / "no such mesh.obj"
    if allowed:
        capabilities.check(method_name, target_name, config)  # no error
        return
    if target_name.startswith("projected"):  # built from a low mesh: the check alone
        with pytest.raises(UsageError, match=f"--method {method_name}"):
            capabilities.check(method_name, target_name, config)
        return
    with pytest.raises(UsageError) as refused:
        aobake.run(config, str(missing), _target(target_name), method=method_name)
    message = str(refused.value)
    assert f"--method {method_name}" in message
    assert "\n" not in message
    if not serves:
        assert f"({target_name})" in message


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("capabilities")
    floor = trimesh.creation.box((3.0, 0.1, 3.0))
    floor.apply_translation((0, -0.05, 0))
    box = trimesh.creation.box((0.8, 0.8, 0.8))
    box.apply_translation((0.2, 0.4, 0))
    mesh = root / "scene.ply"
    trimesh.util.concatenate([floor, box]).export(mesh)
    bake = root / "bake.npz"
    aobake.write(aobake.bake(str(mesh), rays=8, quantities=("ao", "obscurance")), bake)
    return mesh, bake


def _runnable(method: str) -> None:
    """Skip (with the reason) a GL method where no context can be made; CI insists on one."""
    if method in ("hemicube", "depthmaps"):
        import importlib

        ok, why = importlib.import_module(f"aobake.methods.{method}").available()
        if not ok:
            pytest.skip(f"no OpenGL context for --method {method}: {why}")


def _bits(result) -> dict:
    if hasattr(result, "channels"):
        return {k: np.asarray(v) for k, v in result.channels.items()}
    return {**{k: np.asarray(v) for k, v in result.values.items()},
            "rays": np.asarray(result.rays) if result.rays is not None else None}


@pytest.mark.slow
@pytest.mark.parametrize("target", PLAIN_TARGETS)
def test_allowed_requests_run_and_their_report_rebakes_bit_for_bit(method_name, target,
                                                                   scene):
    """Every method at every target it serves runs, its report records the common settings
    and the sections of that method and target only, and ``from_dict`` of that record
    re-bakes the same bits."""
    if not capabilities.serves(method_name, target):
        pytest.skip(f"{method_name} does not serve {target} (refused: tested above)")
    _runnable(method_name)
    mesh, bake = scene
    config = _config(method_name, "ao", bake)
    result = aobake.run(config, str(mesh), _target(target), method=method_name)
    recorded = result.report["config"]
    used = capabilities.sections_used(method_name, target)
    assert {SECTIONS[name] for name in recorded} == set(used) & set(SECTIONS.values())
    assert set(recorded) == {n for n, s in SECTIONS.items() if s in used}
    again = aobake.run(BakeConfig.from_dict(json.loads(json.dumps(recorded))), str(mesh),
                       _target(target), method=method_name)
    a, b = _bits(result), _bits(again)
    assert a.keys() == b.keys()
    for name in a:
        if a[name] is None:
            assert b[name] is None
        else:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.mark.slow
def test_every_method_gives_the_same_bits_on_every_executor(method_name, executor_name,
                                                            scene):
    """The split and executor change no bit, for every method (at the first target it
    serves of vertices and view) on every executor, with odd work-item sizes."""
    _runnable(method_name)
    if executor_name == "dask":
        pytest.importorskip("distributed")
    mesh, bake = scene
    target = next(t for t in ("vertices", "view") if capabilities.serves(method_name, t))
    config = _config(method_name, "ao", bake)
    base = aobake.run(config, str(mesh), _target(target), method=method_name, threads=1)
    other = aobake.run(config, str(mesh), _target(target), method=method_name,
                       executor=executor_name, workers=2, chunk_points=7, threads=2)
    a, b = _bits(base), _bits(other)
    assert a.keys() == b.keys()
    for name in a:
        if a[name] is None:
            assert b[name] is None
        else:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def _choices(command, name):
    return [p for p in command.params if p.name == name][0].type.choices


def test_each_command_offers_only_the_methods_and_quantities_it_can_run():
    from aobake.cli import main
    from aobake.cli.batch import batch_command
    from aobake.cli.view import view_command

    for command, targets in ((main, ("vertices", "texels")),
                             (batch_command(), ("vertices", "texels")),
                             (view_command(), ("view",))):
        methods = list(_choices(command, "method"))
        assert methods == [m for m in METHODS if any(capabilities.serves(m, t)
                                                     for t in targets)]
        quantities = set(_choices(command, "quantities"))
        assert quantities == {q for m in methods for q in capabilities.METHODS[m].quantities}
    assert "gtao" not in _choices(main, "method") and "gtao" in _choices(view_command(),
                                                                         "method")
    names = {p.name for p in view_command().params}
    assert "low_occludes" not in names and "resolution" not in names


def test_help_fits_a_screen_and_offers_the_rest_one_flag_away():
    from aobake.cli import main

    shown = main.shown_options()
    assert len(shown) <= 45, [p.name for p in shown]
    text = run_cli("--help").output
    assert "--help-on" in text and "--discs-k" not in text and "--ssao-radius" not in text
    discs = run_cli("--help-on", "discs")
    assert discs.exit_code == 0 and "--discs-k" in discs.output and "--rays " not in \
        discs.output
    everything = run_cli("--help-on", "all").output
    for p in main.params:
        if isinstance(p, click.Option):
            assert p.opts[0] in everything, p.opts[0]


@pytest.mark.parametrize("args, words", [
    (["--method", "discs", "--denoise", "--out", "{tmp}/x.exr"], "--denoise"),
    (["--method", "hemicube", "-q", "obscurance", "--out", "{tmp}/x.npz"], "-q obscurance"),
    (["--method", "discs", "--ground-plane", "--out", "{tmp}/x.npz"], "ground plane"),
    (["--ao-from", "{bake}", "--out", "{tmp}/x.npz"], "(vertices) has none"),
    (["--method", "discs", "--tolerance", "0.1", "--out", "{tmp}/x.npz"], "--tolerance"),
])
def test_the_command_line_refuses_at_once_with_exit_2(args, words, scene, tmp_path,
                                                      monkeypatch):
    """Refused before loading: the loader is never called."""
    import importlib

    mesh, bake = scene

    def never(*a, **k):
        raise AssertionError("the scene was loaded before the refusal")

    monkeypatch.setattr(importlib.import_module("aobake.api"), "load_scene", never)
    args = [a.format(tmp=tmp_path, bake=bake) for a in args]
    result = run_cli(mesh, *args)
    assert result.exit_code == 2, result.output
    assert result.output.startswith("aobake: error:") and words in result.output
    assert list(tmp_path.iterdir()) == []


def test_view_refuses_a_lightmap_method_mismatch_too(scene, tmp_path):
    mesh, _ = scene
    result = run_cli("view", mesh, "--out", tmp_path / "v.exr", "--method", "discs",
                     "-q", "obscurance")
    assert result.exit_code == 2 and "--method discs computes ao, indirect only" in \
        result.output


def test_the_library_bakes_high_to_low_as_the_command_line_does(tmp_path):
    """``bake(low, source=HIGH)`` is ``aobake LOW --from HIGH`` (it once baked LOW alone and
    ignored the source); a missing source is an error; a source where no low mesh is baked
    onto (query points, a view) is refused before anything is read."""
    low, high = tmp_path / "low.obj", tmp_path / "high.obj"
    trimesh.creation.icosphere(1, 1.0).export(low)
    trimesh.creation.icosphere(3, 1.0).export(high)
    library = aobake.bake(str(low), source=str(high), rays=8)
    assert library.report["target"] == "projected_vertices"
    result = run_cli(low, "--from", high, "--out", tmp_path / "cli.npz", "--rays", 8,
                     "--quiet")
    assert result.exit_code == 0, result.output
    with np.load(tmp_path / "cli.npz") as cli:
        np.testing.assert_array_equal(cli["ao"], library.ao.astype(np.float32))
    with pytest.raises(aobake.InputError, match="no such file"):
        aobake.bake(str(low), source=str(tmp_path / "missing.obj"), rays=8)
    with pytest.raises(UsageError, match="query points"):
        aobake.bake_points(str(tmp_path / "missing.obj"), [[0, 0, 2.0]], [[0, 0, 1.0]],
                           source=str(high))
    with pytest.raises(UsageError, match="camera view"):
        aobake.bake_view(str(tmp_path / "missing.obj"), source=str(high), size=(4, 4))


def test_a_screen_space_method_is_refused_a_box_filtered_view_at_once(scene, tmp_path):
    mesh, _ = scene
    result = run_cli("view", mesh, "--out", tmp_path / "v.exr", "--method", "crytek",
                     "--pixel-filter", "box", "--size", "8x8")
    assert result.exit_code == 2, result.output
    assert "--pixel-filter box" in result.output and list(tmp_path.iterdir()) == []
