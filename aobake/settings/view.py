"""The view target's settings (section "view", ``aobake view``): what a pixel's value is the
estimate of.

``center`` (the default): one primary ray through the pixel's centre, the method's rays at
its hit; the value is the AO of that one surface point.  ``box``: the pixel's primary rays
spread over its area, ``--rays`` split over them, so the value estimates the *mean over the
pixel's area* of the AO (what a renderer that averages its samples over the pixel, Mitsuba's
or Cycles' box filter, computes), with an error bar for that mean
(``aobake.targets.view``; docs/conventions.md, "Camera views").
"""

from __future__ import annotations

from dataclasses import dataclass

from aobake.settings.spec import setting

#: what a pixel's value estimates (``--pixel-filter``)
PIXEL_FILTERS = ("center", "box")
#: the most primary rays per pixel of a box-filtered view (a sample point each)
MAX_PIXEL_SAMPLES = 1 << 16


@dataclass(frozen=True)
class ViewOptions:
    """The view target's settings (each field's help is its documentation)."""

    pixel_filter: str = setting(
        "center", "choice", "What a pixel's value is: center (the AO at the surface point "
        "the pixel's centre sees: one primary ray) or box (the mean AO over the pixel's "
        "area, the estimate a box-filtered renderer makes: --pixel-samples primary rays at "
        "stratified positions in the pixel, --rays split over them; the covered part's mean "
        "with coverage as a fraction, and a stderr for that mean).", section="view",
        choices=PIXEL_FILTERS, panel="camera")
    pixel_samples: int = setting(
        16, "int", "--pixel-filter box: primary rays per pixel, each at its own jittered "
        "position (stratified in --replicates groups; i.i.d. with --sampler random), each "
        "casting ceil(rays / pixel-samples) rays. Equal to --rays: every AO ray has its own "
        "primary ray.", section="view", low=1, high=MAX_PIXEL_SAMPLES, panel="camera")
