"""A corrupt --orm-from PNG (issue 35): libpng printed its own "libpng error: ..." line on
stderr before aobake's message.  The file is checked before the image library sees it, and
what that library says stays off the terminal: one line, aobake's, exit 1."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest

from aobake.errors import OutputError
from aobake.outputs.orm import check_source

SIZE = 16


def _png() -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.full((SIZE, SIZE, 3), 128, dtype=np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


def _corrupt(kind: str) -> bytes:
    data = bytearray(_png())
    if kind == "crc":
        data[40] ^= 0xFF  # inside the first IDAT: its CRC fails
    elif kind == "garbage":
        data = bytearray(data[:8] + b"x" * 100)
    else:  # truncated
        data = data[:len(data) // 2]
    return bytes(data)


@pytest.fixture
def plane(tmp_path):
    path = tmp_path / "plane.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                    "vn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    return path


@pytest.mark.parametrize("kind", ["crc", "garbage", "truncated"])
def test_check_source_refuses_a_corrupt_png(tmp_path, kind):
    path = tmp_path / "orm.png"
    path.write_bytes(_corrupt(kind))
    with pytest.raises(OutputError, match=f"{path}: cannot read the ORM source"):
        check_source(path, (SIZE, SIZE))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["crc", "garbage"])
def test_cli_corrupt_orm_from_is_one_line(plane, tmp_path, kind):
    source = tmp_path / "orm.png"
    source.write_bytes(_corrupt(kind))
    out = tmp_path / "ao.png"
    result = subprocess.run([sys.executable, "-m", "aobake", str(plane), "--out", str(out),
                             "--resolution", str(SIZE), "--rays", "4", "--orm-from",
                             str(source)], capture_output=True, text=True)
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr  # no "libpng error: ..." before it
    assert lines[0].startswith(f"aobake: error: {source}: cannot read the ORM source")
    assert not out.exists()
