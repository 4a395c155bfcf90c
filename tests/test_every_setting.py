"""Every setting reaches every door (issue 31): each setting a command offers is given a
valid non-default value through that command's flag, through the library
(``aobake.bake_file``, which every command uses), through a batch manifest, and read back
from the bake's report, whose config re-makes it (``BakeConfig.from_dict``).

The cases are generated from the settings themselves (``aobake.settings.SPECS``) and from
each command's own options: a new int, float, choice or flag setting is covered the day it
is added; a new parsed setting (a path, a distance, a pattern) must add its example to
``PARSED`` (``test_every_parsed_setting_has_an_example`` fails until it does).  This is the
test ``--exclude`` lacked: it parsed in the library and failed on the command line.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
import numpy as np
import pytest
import trimesh

import aobake
from aobake import capabilities
from aobake.settings import DEFAULTS, SPECS, BakeConfig
from aobake.errors import InputError

from conftest import run_cli

pytestmark = pytest.mark.slow

#: parsed settings: (command-line text, library value); ``{name}`` is a file of the scene
#: fixture (the high mesh, a cage, a bake to read)
PARSED = {
    "quantities": ("obscurance", ("obscurance",)),
    "max_distance": ("50%", "50%"),
    "tau": ("2.5", 2.5),
    "ao_from": ("{bake}", "{bake}"),
    "ssao_radius": ("0.3", "0.3"),
    "heightfield_thickness": ("0.2", "0.2"),
    "resolution": ("40x32", (40, 32)),
    "overlap_mask": ("{mask}", "{mask}"),
    "source": ("{high}", "{high}"),
    "cage_offset": ("2%", "2%"),
    "cage": ("{cage}", "{cage}"),
    "exclude": ("floor", ("floor",)),
    "receive_only": ("floor", ("floor",)),
    "occluder_only": ("box*", ("box*",)),
    "bake": ("box_a", ("box_a",)),
}

#: the settings a setting is used with (checked together by BakeConfig)
NEEDS = {"cage_offset": {"source": "high.obj"}, "cage": {"source": "high.obj"},
         "low_occludes": {"source": "high.obj"}, "overlap_mask": {"uv_overlap": "refuse"}}

#: a section's method, for the settings only one method reads
SECTION_METHOD = {"discs": "discs", "hemicube": "hemicube", "file": "file", "ssao": "crytek",
                  "crytek": "crytek", "gtao": "gtao", "heightfield": "heightfield",
                  "depthmaps": "depthmaps"}


def _candidates(name, spec):
    default = DEFAULTS[name]
    if spec.kind == "flag":
        return [not default]
    if spec.kind == "choice":
        return [c for c in sorted(spec.choices) if c != default]
    if spec.kind == "int":
        return [default + 1, default + 2, default - 1]
    if spec.kind == "float":
        low = spec.low if spec.low is not None else 0.0
        high = spec.high if spec.high is not None else low + 2.0
        out = [] if default is None else [default * 0.5, default * 0.75]
        return out + [low + (high - low) / 4, low + (high - low) / 2]
    raise AssertionError(f"{name}: a parsed setting needs an example in PARSED")


def example(name: str):
    """(command-line text, library value) of a valid non-default value of ``name``: the
    first of a few candidates the library accepts on its own."""
    spec = SPECS[name]
    if spec.kind == "parsed":
        return PARSED[name]
    base = NEEDS.get(name, {})
    for value in _candidates(name, spec):
        try:
            if BakeConfig(**base, **{name: value}).to_dict()[name] != DEFAULTS[name]:
                return (str(value), value)
        except InputError:
            continue
    raise AssertionError(f"{name}: no valid non-default value among the candidates")


def _flag_args(name: str, text: str) -> list:
    """The command-line arguments that give setting ``name`` the value ``text``."""
    spec = SPECS[name]
    flags = list(spec.flags) or [f"--{name.replace('_', '-')}"]
    if "/" in flags[0]:  # a switch: --x / --no-x
        on, off = flags[0].split("/")
        wanted = {"always": on, "never": off, "True": on, "False": off}[text]
        return [wanted]
    if spec.kind == "flag":
        return [flags[0]]
    return [flags[0], text]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A floor and a box as named OBJ objects; a high mesh, a cage and a bake to read."""
    root = tmp_path_factory.mktemp("settings")
    floor = trimesh.creation.box((4.0, 0.1, 4.0))
    floor.apply_translation((0, -0.05, 0))
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    box.apply_translation((0, 0.5, 0))
    lines, offset = [], 0
    for label, part in (("floor", floor), ("box_a", box)):
        lines.append(f"o {label}\n")
        lines += ["v %.9g %.9g %.9g\n" % tuple(v) for v in part.vertices]
        lines += ["f %d %d %d\n" % tuple(f + 1 + offset) for f in part.faces]
        offset += len(part.vertices)
    mesh = root / "scene.obj"
    mesh.write_text("".join(lines))
    low = root / "low.obj"
    trimesh.creation.icosphere(1, 1.0).export(low)
    high = root / "high.obj"
    trimesh.creation.icosphere(3, 1.0).export(high)
    cage = root / "cage.obj"
    big = trimesh.creation.icosphere(1, 1.0)
    big.vertices *= 1.03
    big.export(cage)
    bake = root / "bake.npz"
    aobake.write(aobake.bake(str(mesh), rays=4), bake)
    lightmap = root / "map.exr"  # with its new atlas beside it: map.obj
    run_cli(mesh, "--out", lightmap, "--resolution", "32", "--rays", "4", "--quiet")
    nodes = root / "scene.glb"
    glb = trimesh.Scene()
    glb.add_geometry(floor, node_name="floor", geom_name="floor")
    glb.add_geometry(box, node_name="box_a", geom_name="box")
    glb.export(nodes)
    return {"mesh": mesh, "low": low, "high": high, "cage": cage, "bake": bake,
            "lightmap": lightmap, "atlas": root / "map.obj",
            "mask": root / "mask.png", "root": root, "nodes": nodes}


def _fill(value, files):
    if isinstance(value, str) and value.startswith("{"):
        return str(files[value.strip("{}")])
    return value


def _commands():
    from aobake.cli import main
    from aobake.cli.batch import batch_command
    from aobake.cli.view import view_command

    return {"main": main, "view": view_command(), "batch": batch_command()}


def _offered(command) -> list:
    return [p.name for p in command.params if isinstance(p, click.Option) and p.name in SPECS]


CASES = [(command, name) for command, cmd in _commands().items() for name in _offered(cmd)]


def _context(command: str, name: str, files) -> tuple:
    """(mesh, output name, extra CLI args, method, plan keywords) in which ``name`` is
    used by ``command``."""
    section = SPECS[name].section
    method = SECTION_METHOD.get(section, "rays")
    mesh, request = files["mesh"], {}
    extra = [] if name == "rays" else ["--rays", "4"]
    if command == "view":
        out, extra = "view.exr", extra + ["--size", "16x12"]
        request["view"] = {"size": (16, 12)}
    elif section == "texels" or method == "file" or name == "uv_set":
        # (--uv-set is common to lightmaps and a view's lightmap look: a per-vertex bake
        # refuses it, capabilities.check_settings)
        out = "map.exr"
        if name not in ("texel_density", "resolution"):
            extra += ["--resolution", "32"]
            request["resolution"] = 32
        if name == "uv_set":
            mesh = files["two_sets"]
    else:
        out = "values.npz"
    if section == "studio" and name in ("source", "cage_offset", "cage", "low_occludes"):
        mesh = files["low"]
        if name != "source":
            extra += ["--from", str(files["high"])]
            request["source"] = str(files["high"])
    if name == "bake":  # glTF nodes: the scene as a glTF file of named nodes
        mesh = files["nodes"]
    if name == "overlap_mask":
        extra += ["--uv-overlap", "refuse"]
        request["uv_overlap"] = "refuse"
    if method == "file" and name != "ao_from":
        extra += ["--ao-from", str(files["bake"])]
        request["ao_from"] = str(files["bake"])
    if name == "lightmap_filter":  # how a view looks a lightmap up: the map's own mesh
        mesh, method = files["atlas"], "file"
        extra += ["--ao-from", str(files["lightmap"])]
        request["ao_from"] = str(files["lightmap"])
    if method != "rays":
        extra += ["--method", method]
    return mesh, out, extra, method, request


def _expected(name, value):
    base = NEEDS.get(name, {})
    return getattr(BakeConfig(**base, **{name: value}), name)


@pytest.fixture(scope="module")
def files(scene, tmp_path_factory):
    from test_uvsets import FACES, POSITIONS, SET0, SET1
    from aobake.outputs import glb, image

    path = scene["root"] / "two_sets.glb"
    png = image.png_bytes(np.ones((2, 2)), np.ones((2, 2)))
    glb.write_textured(path, POSITIONS, FACES, None, SET1, png, {}, base_uv=SET0)
    return dict(scene, two_sets=path)


def _skip_unrunnable(method: str) -> None:
    if method in ("hemicube", "depthmaps"):
        import importlib

        ok, why = importlib.import_module(f"aobake.methods.{method}").available()
        if not ok:
            pytest.skip(f"no OpenGL context for --method {method}: {why}")


@pytest.mark.parametrize("command, name", CASES, ids=[f"{c}-{n}" for c, n in CASES])
def test_every_setting_through_the_command_line_and_its_report(command, name, files,
                                                               tmp_path):
    text, value = example(name)
    text, value = _fill(text, files), _fill(value, files)
    mesh, out, extra, method, _ = _context(command, name, files)
    _skip_unrunnable(method)
    args = _flag_args(name, text) + extra
    if command == "batch":
        out_dir = tmp_path / "out"
        result = run_cli("batch", mesh, "--out-dir", out_dir, "--format",
                         Path(out).suffix[1:], *args)
        report = out_dir / (Path(mesh).stem + Path(out).suffix + ".report.json")
    else:
        report = tmp_path / "report.json"
        prefix = ["view"] if command == "view" else []
        result = run_cli(*prefix, mesh, "--out", tmp_path / out, "--report", report, *args)
    assert result.exit_code == 0, result.output
    recorded = json.loads(report.read_text())["config"]
    assert name in recorded, f"{name} was given but the report does not record it"
    assert getattr(BakeConfig.from_dict(recorded), name) == _expected(name, value)


LIBRARY = sorted({name for _, name in CASES})


@pytest.mark.parametrize("name", LIBRARY)
def test_every_setting_through_the_library(name, files, tmp_path):
    _, value = example(name)
    value = _fill(value, files)
    mesh, out, _, method, request = _context("main", name, files)
    if SPECS[name].section in ("view", "ssao", "crytek", "gtao", "heightfield"):
        mesh, out, _, method, request = _context("view", name, files)
    _skip_unrunnable(method)
    config = {k: v for k, v in request.items() if k != "view" and v is not None}
    config[name] = value
    result, written = aobake.bake_file(str(mesh), tmp_path / out, config, method=method,
                                       view=request.get("view"), report=tmp_path / "r.json")
    recorded = result.report["config"]
    assert getattr(BakeConfig.from_dict(recorded), name) == _expected(name, value)
    assert json.loads((tmp_path / "r.json").read_text())["config"][name] is not None \
        or _expected(name, value) is None


@pytest.mark.parametrize("context", ["vertices", "texels", "discs", "file", "studio"])
def test_every_setting_through_a_batch_manifest(context, files, tmp_path):
    """One manifest per context, one row per setting (its value as a manifest's text)."""
    from aobake.cli.batch import batch_command

    offered = _offered(batch_command())
    rows, expected = [], {}
    for name in offered:
        section = SPECS[name].section
        mesh, out, extra, method, request = _context("main", name, files)
        kind = ("file" if method == "file" else "discs" if method == "discs" else
                "studio" if section == "studio" else
                "texels" if out.endswith(".exr") else
                "vertices" if method == "rays" else None)
        if kind != context:
            continue
        text, value = example(name)
        row = {"mesh": str(mesh), "output": f"{name}{Path(out).suffix}", "rays": "4",
               name: _fill(text, files)}
        row.update({k: str(v) for k, v in request.items() if k != "view" and v is not None
                    and k != name})
        rows.append(row)
        expected[name] = _expected(name, _fill(value, files))
    manifest = tmp_path / "assets.jsonl"
    manifest.write_text("".join(json.dumps(r) + "\n" for r in rows))
    method = {"discs": ["--method", "discs"], "file": ["--method", "file"]}.get(context, [])
    result = run_cli("batch", manifest, "--out-dir", tmp_path / "out", *method)
    assert result.exit_code == 0, result.output
    assert expected, context
    for name, want in expected.items():
        report = tmp_path / "out" / f"{name}{Path(rows[0]['output']).suffix}.report.json"
        report = next((tmp_path / "out").glob(f"{name}.*.report.json"))
        recorded = json.loads(report.read_text())["config"]
        assert getattr(BakeConfig.from_dict(recorded), name) == want, name


def test_every_parsed_setting_has_an_example():
    parsed = {name for name, spec in SPECS.items() if spec.kind == "parsed" and spec.cli}
    assert parsed <= set(PARSED), sorted(parsed - set(PARSED))


def test_the_examples_are_not_the_defaults():
    for name, spec in SPECS.items():
        if spec.cli and spec.kind != "parsed":
            _, value = example(name)
            assert value != DEFAULTS[name] or (isinstance(value, float) and math.isnan(value))
