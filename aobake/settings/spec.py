"""Option fields: one declaration per setting gives its default, its check, its command-line
flag, its choices and its help, so nothing is typed twice.

An options record (``settings.CommonOptions``, ``settings.rays.RaysOptions``,
``settings.texels.LightmapOptions``, ...) is a frozen dataclass whose fields are made
by :func:`setting`; ``BakeConfig`` composes the records of every section.  :func:`check`
validates and normalises a record's fields from their specs (the library's checks);
``aobake.cli`` makes its click options from the same specs (the command line's checks),
so a limit, a choice or a help text lives in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Callable

import numpy as np

from aobake.errors import InputError


@dataclass(frozen=True)
class Spec:
    """How one setting is checked and offered.

    kind : 'int' | 'float' | 'choice' | 'flag' | 'parsed'; help : the CLI help (and the
    docs' one line); section : 'common' | a method name | a target name (what it belongs
    to); low, high, low_open, high_open : an 'int' / 'float' range (None: unbounded);
    optional : None is allowed (meaning "not given"); choices : a 'choice''s allowed values
    (a registry's keys); parse : a 'parsed' setting's ``value -> normalised value``
    (InputError on nonsense); too_high : the message after a value above ``high``; words :
    what an 'int' must be, in a message (default from ``low``: "a positive integer");
    label : the name in messages (default: the field name with spaces); flags : the CLI's
    flag names (default ``--field-name``); cli : False to leave it off the command line;
    multiple : the flag repeats (a tuple value); show_default : what ``--help`` shows as
    the default (None: the default itself); panel : the ``--help`` panel it is listed in
    (None: its section's).
    """

    kind: str
    help: str
    section: str = "common"
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    optional: bool = False
    choices: tuple = ()
    parse: Callable | None = None
    too_high: str | None = None
    words: str | None = None
    label: str | None = None
    flags: tuple = ()
    cli: bool = True
    multiple: bool = False
    show_default: object = None
    panel: str | None = None


def setting(default, kind: str, help: str, **spec):
    """A dataclass field with its :class:`Spec` in the metadata."""
    return field(default=default, metadata={"spec": Spec(kind, help, **spec)})


def spec_of(f) -> Spec | None:
    return f.metadata.get("spec")


def label(name: str, spec: Spec) -> str:
    return spec.label or name.replace("_", " ")


def _integer_words(low) -> str:
    return {0: "a non-negative integer", 1: "a positive integer"}.get(low, f"an integer >= {low}")


def normalise(name: str, value, spec: Spec):
    """The checked, normalised value of one setting (InputError naming it otherwise)."""
    what = label(name, spec)
    if value is None and spec.optional:
        return None
    if spec.kind == "int":
        if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) \
                or not math.isfinite(float(value)) or int(value) != value \
                or (spec.low is not None and value < spec.low):
            raise InputError(f"{what} must be {spec.words or _integer_words(spec.low)}, "
                             f"got {value}")
        value = int(value)
        if spec.high is not None and value > spec.high:
            raise InputError(f"{what} {value} {spec.too_high}" if spec.too_high else
                             f"{what} must be {spec.words or f'at most {spec.high}'}, "
                             f"got {value}")
        return value
    if spec.kind == "float":
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if isinstance(value, bool) or not math.isfinite(number) or not _in_range(number, spec):
            raise InputError(f"{what} must be {range_text(spec)}, got {value!r}")
        return number
    if spec.kind == "choice":
        if value not in spec.choices:
            raise InputError(f"{name} must be one of {sorted(spec.choices)}, got {value!r}")
        return value
    if spec.kind == "flag":
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise InputError(f"{name} must be True or False, got {value!r}")
    if spec.kind == "parsed":
        return spec.parse(value)
    raise ValueError(f"unknown setting kind {spec.kind!r}")  # pragma: no cover - a bug


def _in_range(x: float, spec: Spec) -> bool:
    if spec.low is not None and (x < spec.low or (spec.low_open and x == spec.low)):
        return False
    if spec.high is not None and (x > spec.high or (spec.high_open and x == spec.high)):
        return False
    return True


def range_text(spec: Spec) -> str:
    """'a number in (0, 0.1)' and the like."""
    if spec.low is None and spec.high is None:
        return "a finite number"
    if spec.high is None:
        return f"a finite number {'>' if spec.low_open else '>='} {spec.low:.15g}"
    if spec.low is None:
        return f"a number {'<' if spec.high_open else '<='} {spec.high:.15g}"
    return (f"a number in {'(' if spec.low_open else '['}{spec.low:.15g}, {spec.high:.15g}"
            f"{')' if spec.high_open else ']'}")


def from_text(name: str, spec: Spec, text: str):
    """The value of setting ``name`` written as ``text`` (a command-line argument, a
    manifest's cell), checked like the library's own: one element of a repeatable setting
    (the caller collects them).  InputError naming the setting otherwise."""
    text = str(text).strip()
    what = label(name, spec)
    if spec.optional and text.lower() in ("", "none"):
        return None
    if spec.kind == "flag":
        words = {"1": True, "true": True, "yes": True, "on": True, "y": True, "t": True,
                 "0": False, "false": False, "no": False, "off": False, "n": False, "f": False}
        if text.lower() not in words:
            raise InputError(f"{what} must be true or false, got {text!r}")
        return words[text.lower()]
    if spec.kind == "int":
        try:
            value = int(text, 10)
        except ValueError:
            raise InputError(f"{what} must be {spec.words or _integer_words(spec.low)}, got "
                             f"{text!r}") from None
        return normalise(name, value, spec)
    if spec.kind == "float":
        return normalise(name, text, spec)
    if spec.kind == "choice":
        return normalise(name, text, spec)
    if spec.multiple:  # one element: the record's parser reads a sequence of them
        return spec.parse((text,))[0]
    return spec.parse(text)


def check(record, names=None) -> None:
    """Validate and normalise the fields of the frozen dataclass ``record`` in place (all, or
    those in ``names``) from their specs."""
    for f in fields(record):
        spec = spec_of(f)
        if spec is None or (names is not None and f.name not in names):
            continue
        object.__setattr__(record, f.name, normalise(f.name, getattr(record, f.name), spec))


def specs(cls) -> dict:
    """field name -> Spec of an options record (class or instance), in field order."""
    return {f.name: spec_of(f) for f in fields(cls) if spec_of(f) is not None}


def record_of(cls, config, default=None):
    """The options record ``cls`` made from ``config``'s fields when it carries them all
    (``BakeConfig`` composes every record), else ``default`` (else the defaults): how a
    method reads its own settings, also from a config made before its record existed."""
    names = [f.name for f in fields(cls)]
    if all(hasattr(config, name) for name in names):
        return cls(**{name: getattr(config, name) for name in names})
    return default if default is not None else cls()
