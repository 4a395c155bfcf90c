"""The near plane chosen for an eye inside the scene's box (far x 1e-4) is documented
(issue 35), and is what ``fit_clip`` does; a hit nearer than it keeps its hardware depth
outside the range, as documented (nothing is clipped)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aobake.camera import fit_clip, hardware_depth, look_at

DOCS = Path(__file__).resolve().parent.parent / "docs" / "conventions.md"


def test_the_inside_near_plane_is_documented():
    text = " ".join(DOCS.read_text().split())
    assert "When the box reaches the eye plane" in text and "`near` = far x 1e-4" in text
    assert "Nothing is clipped" in text


def test_an_eye_inside_the_box_gets_far_times_1e_4():
    cam = fit_clip(look_at([0, 0, 0], [0, 0, -1], [0, 1, 0], 60, size=(8, 8)),
                   np.array([-5.0, -5.0, -5.0]), np.array([5.0, 5.0, 5.0]))
    assert cam.near == cam.far * 1e-4
    inside = hardware_depth(np.array([cam.near / 2]), cam.near, cam.far, "opengl")
    assert inside[0] < -1.0
