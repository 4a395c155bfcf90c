"""Settings in sections: one declaration per setting drives the library's check and the
command line's flag, default, choices and range, so nothing is typed twice."""

from __future__ import annotations

import click
import pytest

import aobake
from aobake.cli import main
from aobake.cli.view import NOT_FOR_VIEWS, view_command
from aobake.settings import DEFAULTS, SECTIONS, SPECS, BakeConfig, CommonOptions
from aobake.settings.file import FileOptions
from aobake.settings.rays import RaysOptions
from aobake.settings.texels import LightmapOptions

from conftest import run_cli

#: a report's config from the previous release (before the sections), verbatim
PREVIOUS_RELEASE = {
    "quantities": ["ao"], "rays": 8, "max_distance": "inf", "tau": None, "seed": 0,
    "sampler": "sobol", "replicates": 8, "weighting": "cosine", "normals": "file",
    "fix_normals": "warn", "ground_plane": False, "up_axis": "y", "backfaces": "occlude",
    "ray_offset": 1e-05, "backend": "embree", "confidence": 0.95, "tolerance": 0.1,
    "max_rays": 64, "keep_distances": False, "resolution": [64, 64], "texel_density": None,
    "padding": 2, "texel_samples": 4, "unwrap": "auto", "bent_space": "object",
    "seams": "erase", "denoise": False}


def _options(command):
    return {p.name: p for p in command.params if isinstance(p, click.Option)}


def test_every_section_record_lives_in_the_settings_package():
    assert {f for f in DEFAULTS} == set(SPECS)
    for record, section in ((CommonOptions, "common"), (RaysOptions, "rays"),
                            (FileOptions, "file"), (LightmapOptions, "texels")):
        names = set(record.__dataclass_fields__)
        assert names and all(SECTIONS[n] == section for n in names), section
    for record in (CommonOptions, RaysOptions, FileOptions, LightmapOptions):
        assert issubclass(BakeConfig, record)
        assert record.__module__.startswith("aobake.settings"), record


#: the settings sections each command can use (main and batch: a lightmap or vertices, by
#: the methods that serve them; view: a camera, by every method)
COMMAND_SECTIONS = {
    "main": {"common", "studio", "texels", "rays", "discs", "hemicube", "file", "depthmaps",
             "instances"},
    "view": {"common", "studio", "view", "rays", "discs", "hemicube", "file", "ssao", "crytek",
             "gtao", "heightfield", "depthmaps"}}


@pytest.mark.parametrize("command", ["main", "view"])
def test_cli_options_are_made_from_the_specs(command):
    cmd = main if command == "main" else view_command()
    options = _options(cmd)
    for name, spec in SPECS.items():
        wanted = spec.cli and spec.section in COMMAND_SECTIONS[command] and (
            command == "main" or name not in NOT_FOR_VIEWS)
        assert (name in options) == wanted, name
        if not wanted:
            continue
        opt = options[name]
        assert opt.help == spec.help
        if spec.kind == "choice" and not opt.secondary_opts:  # --unwrap/--no-unwrap: a switch
            assert set(opt.type.choices) == set(spec.choices), name
        if spec.kind == "int":
            assert (opt.type.min, opt.type.max) == (spec.low, spec.high), name
        if spec.kind in ("int", "float", "choice") and not opt.secondary_opts:
            assert opt.default == DEFAULTS[name], name


@pytest.mark.parametrize("name, text, value", [
    ("rays", "0", 0), ("rays", str(2**24 + 1), 2**24 + 1), ("replicates", "1", 1),
    ("seed", "-1", -1), ("padding", "-2", -2), ("confidence", "0.4", 0.4),
    ("tolerance", "0.5", 0.5), ("ray_offset", "0.2", 0.2), ("sampler", "halton", "halton"),
    ("tolerance", "nan", float("nan")), ("texel_density", "inf", float("inf")),
])
def test_a_bad_value_is_refused_by_the_library_and_the_command_line(tmp_path, box_ply, name,
                                                                    text, value):
    with pytest.raises(aobake.InputError):
        BakeConfig(**{name: value})
    flag = f"--{name.replace('_', '-')}"
    result = run_cli(box_ply, "--out", tmp_path / "ao.npz", flag, text)
    assert result.exit_code == 2, result.output
    assert not (tmp_path / "ao.npz").exists()


def test_reports_of_the_previous_release_still_rebake():
    config = BakeConfig.from_dict(PREVIOUS_RELEASE)
    # the settings added since (the file and disc methods', indirect light's) take their
    # defaults
    added = {name: DEFAULTS[name] for name in set(DEFAULTS) - set(PREVIOUS_RELEASE)}
    assert set(added) >= {"ao_from", "albedo", "bounces", "discs_kappa"}
    assert config.to_dict() == dict(PREVIOUS_RELEASE, max_distance=float("inf"), **added)
    with pytest.raises(aobake.InputError, match="unknown configuration keys"):
        BakeConfig.from_dict(dict(PREVIOUS_RELEASE, rayz=3))


@pytest.mark.slow
def test_the_command_line_bakes_what_the_library_bakes(tmp_path, box_ply):
    """Every default the CLI passes is the config's: a bake with no options has the
    report config of BakeConfig()."""
    import json

    report = tmp_path / "r.json"
    assert run_cli(box_ply, "--out", tmp_path / "ao.npz", "--rays", "8", "--report",
                   report, "--quiet").exit_code == 0
    config = json.loads(report.read_text())["config"]
    assert BakeConfig.from_dict(config) == BakeConfig(rays=8)


@pytest.mark.parametrize("args, flag", [
    (["--method", "hemicube", "--hemicube-resolution", "65"], "--hemicube-resolution"),
    (["--cage-offset", "0.1"], "--from"),
    (["--low-occludes"], "--from"),
])
def test_settings_that_cannot_go_together_are_a_usage_error_naming_the_flag(tmp_path, box_ply,
                                                                          args, flag):
    """Checked by BakeConfig before anything is read: exit 2 (usage), as a bad value of a
    single flag is, and the message names the flag (issue 35: an odd resolution exited 1
    without naming it)."""
    for command in ([], ["view"]) if "--hemicube-resolution" in args else ([],):
        result = run_cli(*command, box_ply, "--out", tmp_path / ("v.exr" if command else
                                                                  "ao.npz"), *args)
        assert result.exit_code == 2, result.output
        assert flag in result.output and "Traceback" not in result.output
    assert list(tmp_path.iterdir()) == [box_ply]
