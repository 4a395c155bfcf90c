"""The recipe of docs/screen-space.md ("Scoring your own shader") runs as documented: one
``aobake view --truths``, a shader on the G-buffer alone, ``aobake compare`` against each
truth."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_score_my_shader_recipe_runs_and_scores_against_both_truths(tmp_path):
    out = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "score_my_shader.py"), "--mesh",
         str(ROOT / "assets" / "still_life.obj"), "--size", "64x48", "--rays", "16",
         "--out-dir", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert [line.split(" (")[0] for line in lines if line.startswith("against")] == \
        ["against ao", "against ao_unbounded"]
    for region in ("all", "interior", "edges"):
        assert sum(line.strip().startswith(region) for line in lines) == 2
    for name in ("view.exr", "view.camera.json", "my_shader.png"):
        assert (tmp_path / name).exists()
