"""The command line's options, made from the settings' specs (``aobake.options``): flag,
default, choices, range, help and check come from each field's one declaration.

Every generated option defaults to the config's own default (``--help`` shows it); a
malformed value is click's usage error (exit 2) with the library's own message.
"""

from __future__ import annotations

import math

import click

from aobake.config import SPECS, parse_distance
from aobake.executors import EXECUTORS
from aobake.methods import METHODS
from aobake.errors import InputError


class FiniteRange(click.FloatRange):
    """click's FloatRange, refusing NaN and infinity: a NaN passes every comparison click
    makes, and would reach the library as a value (exit 1 instead of a usage error)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


class ParsedType(click.ParamType):
    """A value checked by the library's own parser (``parse(text) -> value``): its
    InputError becomes a usage error."""

    def __init__(self, parse, name: str):
        self.parse, self.name = parse, name

    def convert(self, value, param, ctx):
        try:
            return self.parse(value)
        except (InputError, ValueError) as exc:
            self.fail(str(exc), param, ctx)


class QuantityType(click.Choice):
    """A registry quantity; ``bent-normal`` is accepted for ``bent_normal``."""

    def convert(self, value, param, ctx):
        return super().convert(str(value).replace("-", "_"), param, ctx)


#: the distance and tau types the refit command reuses
DistanceType = ParsedType(parse_distance, "distance")
TauType = ParsedType(SPECS["tau"].parse, "tau")


def _type(name: str, spec):
    if spec.kind == "int":
        return click.IntRange(min=spec.low, max=spec.high)
    if spec.kind == "float":
        return FiniteRange(spec.low, spec.high, min_open=spec.low_open,
                           max_open=spec.high_open)
    if spec.kind == "choice":
        return click.Choice(sorted(spec.choices))
    if name == "quantities":
        from aobake.quantities import QUANTITIES

        return QuantityType(list(QUANTITIES))
    return ParsedType(spec.parse, name.replace("_", "-"))


def option(name: str, spec) -> click.Option:
    """The click option of setting ``name``, defaulting to the config's default."""
    from aobake.config import DEFAULTS

    default = DEFAULTS[name]
    flags = list(spec.flags) or [f"--{name.replace('_', '-')}"]
    if spec.kind == "flag":
        return click.Option(flags + [name], is_flag=True, default=default, help=spec.help)
    if "/" in flags[0]:  # --unwrap/--no-unwrap: a switch between two of the choices
        return click.Option(flags + [name], default=None, help=spec.help)
    shown = True if spec.show_default is None else spec.show_default
    if spec.multiple:
        default = list(default)
    return click.Option(flags + [name], type=_type(name, spec), default=default,
                        show_default=shown, multiple=spec.multiple, help=spec.help)


def settings(skip_sections=(), exclude=()) -> list:
    """The click options of every setting, in the config's field order, but those of
    ``skip_sections`` and the names in ``exclude``."""
    return [option(name, spec) for name, spec in SPECS.items()
            if spec.cli and name not in exclude and spec.section not in skip_sections]


#: what a switch flag's True / False mean
SWITCHES = {"unwrap": {None: None, True: "always", False: "never"}}


def given(values: dict) -> dict:
    """The settings the user gave (None = not given; an empty repeatable option too), as
    BakeConfig keywords."""
    out = {}
    for name, value in values.items():
        if name in SWITCHES:
            value = SWITCHES[name][value]
        if value is None or (isinstance(value, tuple) and not value):
            continue
        out[name] = value
    return out


#: the options of where and how fast a bake runs (never its numbers); ``aobake view`` too
RUN_OPTIONS = [
    click.Option(["--threads"], default=None, type=click.IntRange(min=1),
                 help="Worker threads. Default: all cores."),
    click.Option(["--method"], default="rays", show_default=True,
                 type=click.Choice(sorted(METHODS)),
                 help="How values are estimated: rays (ray-traced, with error bars: the "
                      "reference); discs (Bunnell's disc approximation); hemicube "
                      "(rasterised hemicubes, OpenGL); file (a per-vertex bake's values, "
                      "--ao-from)."),
    click.Option(["--executor"], default="threads", show_default=True,
                 type=click.Choice(sorted(EXECUTORS)),
                 help="Where the points are estimated: threads (this process), processes (a "
                      "local pool of --workers processes) or dask (a Dask cluster: --scheduler, "
                      "or a local one). The same bits every way."),
    click.Option(["--workers"], default=None, type=click.IntRange(min=1),
                 help="--executor processes: worker processes. Default: --threads (all "
                      "cores)."),
    click.Option(["--chunk-points"], default=None, type=click.IntRange(min=1),
                 help="Points per work item (default: a few items per worker). The same bits "
                      "for any value."),
    click.Option(["--scheduler"], default=None, metavar="ADDRESS",
                 help="--executor dask: an existing Dask scheduler (tcp:// or tls://host:port; "
                      "TLS through Dask's configuration, docs/scale.md). Default: a local "
                      "cluster of --workers processes on 127.0.0.1."),
]
