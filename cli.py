"""Run aobake from a checkout without installing: ``python cli.py mesh.obj --out ao.ply``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from aobake.cli import entry  # noqa: E402

if __name__ == "__main__":
    entry()
