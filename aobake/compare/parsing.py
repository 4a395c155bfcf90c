"""Moved: the byte-level readers of bake files live beside their writers in
``aobake.outputs`` (``npz.read_npz``, ``ply.parse_ply``, ``gltf`` for the glTF container,
``image.read_pixels``; ``table.Unreadable`` and ``table.parse_json``).

Kept only so that ``aobake.refit`` (``Unreadable``, ``parse_json``, ``read_npz``) reads on
until it imports them from there; nothing else should import this module.
"""

from __future__ import annotations

from aobake.outputs.image import check_png, quiet_stderr, read_pixels, read_size
from aobake.outputs.npz import npz_names, read_npz
from aobake.outputs.ply import PLY_TYPES, Ply, parse_ply
from aobake.outputs.table import Unreadable, parse_json

__all__ = ["PLY_TYPES", "Ply", "Unreadable", "check_png", "npz_names", "parse_json",
           "parse_ply", "quiet_stderr", "read_npz", "read_pixels", "read_size"]
