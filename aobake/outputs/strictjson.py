"""Strict JSON for every file aobake writes: the report file (``report.json``) and the
metadata every output carries (the report dict itself is built by ``aobake.report``).

Reports and file metadata hold numpy scalars, small arrays, paths and
non-finite floats (an unbounded ``max_distance`` is ``inf``).  Strict JSON has
no ``Infinity`` or ``NaN``, so ``to_jsonable`` writes non-finite floats as the
strings ``"inf"``, ``"-inf"`` and ``"nan"``; every other value keeps its JSON
type.  Readers that need the float back use ``float(value)``, which accepts
those three strings.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

import numpy as np

from aobake.outputs.atomic import atomic_path

log = logging.getLogger(__name__)


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` to plain JSON types (dict, list, str, int, float, bool, None).

    - numpy scalars become Python scalars, numpy arrays nested lists;
    - ``pathlib`` paths become strings;
    - tuples and lists become lists; mappings become dicts with string keys
      (non-string scalar keys are written as JSON would: ``1 -> "1"``);
    - non-finite floats become ``"inf"``, ``"-inf"`` or ``"nan"``.

    Raises ``TypeError`` naming where in ``obj`` an unsupported value sits.
    """
    return _convert(obj, "value")


def _convert(obj: Any, where: str) -> Any:
    # bool before int: bool is a subclass of int and must stay true/false
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.generic):
        # np.bool_, np.int64, np.float32, np.str_ ...: .item() gives the Python scalar
        return _convert(obj.item(), where)
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        if math.isfinite(obj):
            return float(obj)
        if math.isnan(obj):
            return "nan"
        return "inf" if obj > 0 else "-inf"
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biufU":
            raise TypeError(f"{where}: cannot write a {obj.dtype} array as JSON")
        return _convert(obj.tolist(), where)
    if isinstance(obj, Mapping):
        return {_key(k, where): _convert(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_convert(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    raise TypeError(f"{where}: cannot write {type(obj).__name__} as JSON")


def _key(key: Any, where: str) -> str:
    key = _convert(key, f"{where} key {key!r}")
    if isinstance(key, str):
        return key
    if isinstance(key, (int, float, bool)) or key is None:
        # the same spelling json.dumps uses for non-string keys
        return json.dumps(key)
    raise TypeError(f"{where}: key {key!r} cannot be a JSON object key")


def metadata_json(metadata: Mapping | None, compact: bool = False) -> str:
    """File metadata as one line of strict JSON text (no newlines).

    ``compact`` also drops all whitespace, escaping spaces inside strings as
    ``\\u0020`` (still valid JSON), so the text is a single token to formats
    whose headers are split on whitespace (PLY comments).
    """
    data = to_jsonable(check_metadata(metadata))
    if not compact:
        return json.dumps(data, allow_nan=False)
    # json.dumps escapes control characters (\n, \t ...); with these separators
    # the only spaces left are inside strings, where \u0020 means the same
    return json.dumps(data, allow_nan=False, separators=(",", ":")).replace(" ", "\\u0020")


def check_metadata(metadata: Mapping | None) -> dict:
    """File metadata as a dict: None -> {}; ``ValueError`` if it is not a mapping."""
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise ValueError(f"metadata must be a dict, got {type(metadata).__name__}")
    return dict(metadata)


def write_report(path: str | os.PathLike, report: Mapping) -> None:
    """Write ``report`` as indented JSON (keys in the given order), atomically.

    Values go through ``to_jsonable``: the file is strict JSON, with non-finite
    floats as the strings ``"inf"``, ``"-inf"`` and ``"nan"``.
    """
    # convert before opening anything so a bad value leaves no file behind
    text = json.dumps(to_jsonable(report), indent=2, sort_keys=False, allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    log.debug("wrote report %s", path)
