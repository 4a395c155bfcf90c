"""The command examples of docs/scale.md, followed as written, lose nothing: no command
writes a file another one wrote (an output, or the mesh a lightmap writes beside it)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

DOC = Path(__file__).resolve().parent.parent / "docs" / "scale.md"
#: lightmap images: their atlas's mesh goes beside them as <stem>.obj, a set's as <stem>.glb
IMAGES = (".png", ".exr", ".tif", ".tiff")


def _commands(text: str) -> list[list[str]]:
    """Every ``aobake ...`` command in the fenced blocks (continuation lines joined,
    comments dropped)."""
    commands = []
    for block in re.findall(r"```[^\n]*\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            if line.startswith("aobake "):
                commands.append(shlex.split(line, comments=True))
    return commands


def _written(words: list[str]) -> set[str]:
    """The files a command writes: --out, a lightmap image's atlas mesh beside it
    (``aobake.outputs``; a set's is a GLB), --mesh-out, a view's camera."""
    if "--out" not in words:
        return set()
    out = Path(words[words.index("--out") + 1])
    files = {str(out)}
    if words[1] == "view":
        files.add(str(out.with_suffix(".camera.json")))
    elif out.suffix.lower() in IMAGES and "--mesh-out" not in words:
        files |= {str(out.with_suffix(".obj")), str(out.with_suffix(".glb"))}
    if "--mesh-out" in words:
        files.add(words[words.index("--mesh-out") + 1])
    return files


def test_no_example_overwrites_another_examples_output():
    seen: dict[str, str] = {}
    for words in _commands(DOC.read_text()):
        command = " ".join(words)
        for name in _written(words):
            assert name not in seen, f"{command!r} overwrites {name} of {seen[name]!r}"
            seen[name] = command
    assert "set_ao.png" in seen  # the set's lightmap examples were read
