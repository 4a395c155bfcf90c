"""A signal while the command starts (issue 35): SIGINT exits 130 and SIGTERM 143, each with
one ``aobake: error:`` line and no traceback, also while the command is still importing
click, numpy and the library (the first ~0.2-0.5 s of every run).

``aobake.cli.entry`` installs its handlers before it imports anything heavy; the test
watches the child's imports (``python -X importtime`` prints each as it completes) and
signals it right after the handlers' module was imported, then a little later, so the
signal lands inside the imports that follow.  What is left before that point is the
interpreter's own start-up, which no program can handle (docs/reliability.md).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import trimesh

pytestmark = pytest.mark.slow

#: the module whose import means the handlers are (about to be) installed
READY = "aobake.cli.signals"


def _start(args):
    return subprocess.Popen([sys.executable, "-X", "importtime", "-m", "aobake", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_import(child, module: str) -> list:
    """Read the child's stderr until ``module``'s import line; the lines read."""
    lines = []
    for line in child.stderr:
        lines.append(line)
        if line.rstrip().endswith(f"| {module}") or line.rstrip().endswith(f"|   {module}"):
            return lines
        if line.strip().split("|")[-1].strip() == module:
            return lines
    raise AssertionError("the child ended before importing " + module + ":\n" + "".join(lines))


@pytest.mark.parametrize("name, code", [("SIGINT", 130), ("SIGTERM", 143)])
@pytest.mark.parametrize("later", [0.0, 0.05, 0.15])
def test_a_signal_while_the_command_imports_exits_with_one_line(name, code, later, tmp_path):
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    out = tmp_path / "ao.npz"
    child = _start([mesh, "--out", out, "--rays", 65536])
    try:
        seen = _wait_for_import(child, READY)
        time.sleep(later)
        child.send_signal(getattr(signal, name))
        rest = child.stderr.read()
        child.wait(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    text = "".join(seen) + rest
    messages = [line for line in text.splitlines() if not line.startswith("import time:")]
    assert child.returncode == code, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text
    assert messages == [f"aobake: error: {'interrupted' if name == 'SIGINT' else 'terminated'}"
                        f" ({name}): no output written"], messages
    assert not out.exists()
