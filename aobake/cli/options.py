"""The command line's options and their help, made from the settings' specs
(``aobake.settings.spec``) and the registries' declarations (``aobake.capabilities``): flag,
default, choices, range, help and check come from each field's one declaration, and each
command offers only the settings, methods and quantities it can run.

Every generated option defaults to the config's own default (``--help`` shows it); a
malformed value is click's usage error (exit 2) with the library's own message.

Help comes in panels (:data:`PANELS`): a command's ``--help`` lists the panels it shows
in full (the common case: one screen) and names the others, each one flag away
(``--help-on discs``); ``--help-on all`` lists everything.
"""

from __future__ import annotations

import math

import click

from aobake import capabilities
from aobake.cli.common import Command
from aobake.settings import SPECS, parse_distance
from aobake.errors import InputError, UsageError
from aobake.executors import EXECUTORS
from aobake.settings.spec import from_text

#: help panel -> its title, in the order panels are listed (a setting's panel is its
#: section's unless its spec names another)
PANELS = {
    "output": "Output",
    "camera": "Camera",
    "common": "What to bake",
    "rays": "Sampling (--method rays)",
    "texels": "Lightmap",
    "indirect": "Indirect light (-q indirect)",
    "studio": "Studio: high-to-low, occluder groups, cut-outs",
    "run": "Where it runs",
    "file": "--method file",
    "discs": "--method discs",
    "hemicube": "--method hemicube",
    "depthmaps": "--method depthmaps",
    "ssao": "Screen-space methods (crytek, shanmugam, gtao, heightfield)",
    "crytek": "--method crytek",
    "gtao": "--method gtao",
    "heightfield": "--method heightfield",
}


#: what the main command and batch bake at (with --from: the projected targets of the same
#: names), and the methods that serve them (``aobake.capabilities``): their --method choices
BAKE_TARGETS = ("vertices", "texels")
BAKE_METHODS = capabilities.methods_for(BAKE_TARGETS)


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
    """A quantity the command's methods compute; ``bent-normal`` is accepted for
    ``bent_normal``."""

    def convert(self, value, param, ctx):
        return super().convert(str(value).replace("-", "_"), param, ctx)


#: the distance and tau types the refit command reuses
DistanceType = ParsedType(parse_distance, "distance")
TauType = ParsedType(SPECS["tau"].parse, "tau")


def click_type(name: str, spec, quantities=None):
    """The click type of one value of setting ``name`` (one element of a repeatable one:
    click collects them into the tuple the setting's parser reads)."""
    if spec.kind == "int":
        return click.IntRange(min=spec.low, max=spec.high)
    if spec.kind == "float":
        return FiniteRange(spec.low, spec.high, min_open=spec.low_open,
                           max_open=spec.high_open)
    if spec.kind == "choice":
        return click.Choice(sorted(spec.choices))
    if name == "quantities":
        return QuantityType(list(quantities or capabilities.ALL_QUANTITIES))
    if spec.multiple:  # one element: the setting's parser reads the tuple click collects
        return ParsedType(lambda text: from_text(name, spec, text), name.replace("_", "-"))
    return ParsedType(spec.parse, name.replace("_", "-"))


def option(name: str, spec, quantities=None) -> click.Option:
    """The click option of setting ``name``, defaulting to the config's default."""
    from aobake.settings import DEFAULTS

    default = DEFAULTS[name]
    flags = list(spec.flags) or [f"--{name.replace('_', '-')}"]
    if spec.kind == "flag":
        made = click.Option(flags + [name], is_flag=True, default=default, help=spec.help)
    elif "/" in flags[0]:  # --unwrap/--no-unwrap: a switch between two of the choices
        made = click.Option(flags + [name], default=None, help=spec.help)
    else:
        shown = True if spec.show_default is None else spec.show_default
        made = click.Option(flags + [name], type=click_type(name, spec, quantities),
                            default=list(default) if spec.multiple else default,
                            show_default=shown, multiple=spec.multiple, help=spec.help)
    made.panel = spec.panel or spec.section
    return made


def sections_for(targets, methods) -> tuple:
    """The settings sections a command running ``methods`` at ``targets`` can use: the
    common ones, the studio's (occluder groups apply to every target), each target's and
    each method's."""
    out = ["common", "studio"]
    for section in ([s for t in targets for s in capabilities.TARGETS[t].sections]
                    + [s for m in methods for s in capabilities.METHODS[m].sections]):
        if section not in out:
            out.append(section)
    return tuple(out)


def settings(targets, methods, exclude=()) -> list:
    """The click options of every setting a command running ``methods`` at ``targets``
    can use, in the config's field order, less the names in ``exclude``; ``-q``'s choices
    are the quantities those methods compute."""
    sections = sections_for(targets, methods)
    quantities = capabilities.quantities_for(methods)
    return [option(name, spec, quantities) for name, spec in SPECS.items()
            if spec.cli and name not in exclude and spec.section in sections]


#: what a switch flag's True / False mean
SWITCHES = {"unwrap": {None: None, True: "always", False: "never"}}


def checked(settings: dict) -> dict:
    """``settings`` (BakeConfig keywords) once BakeConfig accepts them together: a
    combination it refuses (--cage without --from, an odd --hemicube-resolution) is a usage
    error (exit 2), as a bad value of one flag is, before anything is read."""
    from aobake.settings import BakeConfig

    try:
        BakeConfig(**settings)
    except InputError as exc:
        raise click.UsageError(str(exc)) from None
    return settings


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


def named_method(method: str) -> str | None:
    """``--method`` as given on the command line, or None when it was left at its default."""
    source = click.get_current_context().get_parameter_source("method")
    return method if source == click.core.ParameterSource.COMMANDLINE else None


def method_for(method: str, config: dict) -> str:
    """--ao-from FILE means --method file (the default method otherwise): the library's rule
    (``capabilities.implied_method``), its refusal a usage error here."""
    if config.get("ao_from") is None:
        return method
    try:
        return capabilities.implied_method(named_method(method), config)
    except UsageError as exc:
        raise click.UsageError(str(exc)) from None


def _method_help(methods) -> str:
    return ("How values are estimated: " + "; ".join(
        f"{m} ({capabilities.METHODS[m].what})" for m in methods)
        + ". --help-on METHOD lists a method's own settings.")


def run_options(methods) -> list:
    """The options of how a bake runs: ``--method`` (choices: ``methods``, those the
    command's targets serve), ``--threads``, and where it runs (the executors)."""
    made = [
        click.Option(["--method"], default="rays", show_default=True,
                     type=click.Choice(list(methods)), help=_method_help(methods)),
        click.Option(["--threads"], default=None, type=click.IntRange(min=1),
                     help="Worker threads. Default: all cores."),
        click.Option(["--executor"], default="threads", show_default=True,
                     type=click.Choice(sorted(EXECUTORS)),
                     help="Where the points are estimated: threads (this process), processes "
                          "(a local pool of --workers processes) or dask (a Dask cluster: "
                          "--scheduler, or a local one). The same bits every way."),
        click.Option(["--workers"], default=None, type=click.IntRange(min=1),
                     help="--executor processes/dask: worker processes. Default: --threads "
                          "(all cores)."),
        click.Option(["--chunk-points"], default=None, type=click.IntRange(min=1),
                     help="Points per work item (default: a few items per worker). The same "
                          "bits for any value."),
        click.Option(["--scheduler"], default=None, metavar="ADDRESS",
                     help="--executor dask: an existing Dask scheduler (tcp:// or "
                          "tls://host:port; TLS through Dask's configuration, docs/scale.md). "
                          "Default: a local cluster of --workers processes on 127.0.0.1."),
    ]
    for opt in made:
        opt.panel = "common" if opt.name in ("method", "threads") else "run"
    return made


def in_panel(panel: str, options: list) -> list:
    """``options`` listed in ``panel`` (each keeps its own panel if it has one)."""
    for opt in options:
        if getattr(opt, "panel", None) is None:
            opt.panel = panel
    return options


def _title(panel: str) -> str:
    """A panel's title: :data:`PANELS`', else a method's section named after the method."""
    return PANELS.get(panel, f"--method {panel}")


class PanelCommand(Command):
    """A click command whose help lists its options in panels (:data:`PANELS`): those of
    ``shown`` in full, the others by name with their option counts, each behind
    ``--help-on PANEL``; ``--help-on all`` lists every option."""

    def __init__(self, *args, shown=("output", "common", "rays", "texels"), **kwargs):
        super().__init__(*args, **kwargs)
        self.shown = tuple(shown)
        self.params.append(click.Option(
            ["--help-on"], metavar="PANEL", is_eager=True, expose_value=False,
            type=click.Choice(["all"] + self.panels() + self._method_names()),
            callback=self._help_on,
            help="Show the options of one panel (or a method's own: --help-on discs), or all "
                 "of them, and exit."))
        self.params[-1].panel = "output"

    def _method_names(self) -> list:
        opt = next((p for p in self.params if p.name == "method"), None)
        return [m for m in getattr(getattr(opt, "type", None), "choices", ())
                if m not in PANELS]

    def panels(self) -> list:
        """The panels this command's options fall in, in :data:`PANELS` order, then any
        other (a new method's section is its own panel the day it is added)."""
        have = {getattr(p, "panel", "output") for p in self.params if isinstance(p, click.Option)}
        return [name for name in PANELS if name in have] + sorted(have - set(PANELS))

    def _help_on(self, ctx, param, value):
        if value is None or ctx.resilient_parsing:
            return
        if value in self._method_names():  # a method's own panels: its settings sections
            wanted = [s for s in capabilities.METHODS[value].sections if s in self.panels()]
        else:
            wanted = self.panels() if value == "all" else [value]
        formatter = ctx.make_formatter()
        self.format_usage(ctx, formatter)
        self._format_panels(ctx, formatter, wanted)
        if not wanted:
            formatter.write_paragraph()
            formatter.write_text(f"--method {value} has no settings of its own.")
        click.echo(formatter.getvalue().rstrip("\n"), color=ctx.color)
        ctx.exit()

    def _format_panels(self, ctx, formatter, panels) -> None:
        for panel in panels:
            rows = [p.get_help_record(ctx) for p in self.get_params(ctx)
                    if isinstance(p, click.Option) and getattr(p, "panel", "output") == panel]
            rows = [r for r in rows if r is not None]
            if rows:
                with formatter.section(_title(panel)):
                    formatter.write_dl(rows)

    def format_options(self, ctx, formatter) -> None:
        shown = [p for p in self.panels() if p in self.shown]
        self._format_panels(ctx, formatter, shown)
        rest = [p for p in self.panels() if p not in self.shown]
        if rest:
            counts = {p: sum(getattr(o, "panel", "output") == p for o in self.params
                             if isinstance(o, click.Option)) for p in rest}
            with formatter.section("More options (--help-on PANEL, or --help-on all)"):
                formatter.write_dl([(p, f"{_title(p)}: {counts[p]} option"
                                        f"{'s' if counts[p] != 1 else ''}") for p in rest])

    def shown_options(self) -> list:
        """The options ``--help`` lists in full (what a user sees first)."""
        return [p for p in self.params if isinstance(p, click.Option)
                and getattr(p, "panel", "output") in self.shown]
