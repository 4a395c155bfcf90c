"""Every script in benchmarks/ describes itself in ``--help`` with its docstring's whole first
paragraph, not its first line cut mid-sentence."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))


def _words(text: str) -> list[str]:
    return text.split()


def _descriptions(path: Path):
    """(module docstring, [the description each ArgumentParser(...) in it gets])."""
    tree = ast.parse(path.read_text())
    doc = ast.get_docstring(tree, clean=False) or ""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "ArgumentParser":
            for keyword in node.keywords:
                if keyword.arg == "description":
                    expression = ast.Expression(keyword.value)
                    found.append(eval(compile(expression, str(path), "eval"),  # noqa: S307
                                      {"__doc__": doc}))
    return doc, found


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_description_is_the_docstrings_first_paragraph(path):
    doc, descriptions = _descriptions(path)
    first = _words(doc.split("\n\n")[0])
    for description in descriptions:
        assert _words(description) == first, f"{path.name}: {description!r}"


@pytest.mark.slow
def test_bench_renderers_help_shows_its_whole_first_paragraph():
    doc, _ = _descriptions(ROOT / "benchmarks" / "bench_renderers.py")
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_renderers.py"),
                             "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    help_text = result.stdout.split("\n\n", 2)[1]  # the usage block, then the description
    assert _words(help_text) == _words(doc.split("\n\n")[0])
