"""The view target's settings (section "view", ``aobake view``): what a pixel's value is the
estimate of.

``center`` (the default): one primary ray through the pixel's centre, the method's rays at
its hit; the value is the AO of that one surface point.  ``box``: the pixel's primary rays
spread over its area, so the value estimates the *mean over the pixel's area* of the AO
(what a renderer that averages its samples over the pixel, Mitsuba's or Cycles' box filter,
computes), with an error bar for that mean (``aobake.targets.view``; docs/conventions.md,
"Camera views").  ``--box-sampling joint`` (the default, the ray-traced method's:
``aobake.targets.view_box``) draws the positions and their AO rays' directions together;
``positions`` makes each of ``--pixel-samples`` positions a sample point of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

from aobake.settings.spec import setting

#: what a pixel's value estimates (``--pixel-filter``)
PIXEL_FILTERS = ("center", "box")
#: how a box-filtered pixel is sampled (``--box-sampling``)
BOX_SAMPLINGS = ("joint", "positions")
#: the most primary rays per pixel of a box-filtered view (a sample point each)
MAX_PIXEL_SAMPLES = 1 << 16


@dataclass(frozen=True)
class ViewOptions:
    """The view target's settings (each field's help is its documentation)."""

    pixel_filter: str = setting(
        "center", "choice", "What a pixel's value is: center (the AO at the surface point "
        "the pixel's centre sees: one primary ray) or box (the mean AO over the pixel's "
        "area, the estimate a box-filtered renderer makes: --rays per pixel from positions "
        "spread over it (--box-sampling); the covered part's mean with coverage as a "
        "fraction, and a stderr for that mean).", section="view",
        choices=PIXEL_FILTERS, panel="camera")
    box_sampling: str = setting(
        "joint", "choice", "--pixel-filter box: joint (the ray-traced method: --rays AO rays "
        "per pixel, 4 from each of rays/4 positions, fewer where a replicate would get "
        "fewer than 4 positions, one with --sampler random; positions and directions "
        "stratified together in --replicates replicates and traced in bulk, as a renderer "
        "samples a pixel) or positions (--pixel-samples positions, each a sample point with "
        "ceil(rays / pixel-samples) rays of its own: what a method that casts no rays always "
        "uses).",
        section="view", choices=BOX_SAMPLINGS, panel="camera")
    pixel_samples: int = setting(
        16, "int", "--pixel-filter box --box-sampling positions (and the methods that cast "
        "no rays): primary rays per pixel, each at its own jittered position (stratified in "
        "--replicates groups; i.i.d. with --sampler random), each casting ceil(rays / "
        "pixel-samples) rays.", section="view", low=1, high=MAX_PIXEL_SAMPLES,
        panel="camera")
    lightmap_filter: str = setting(
        "bilinear", "choice", "How a view looks a lightmap up (--ao-from a lightmap): "
        "bilinear (the 4 texels around the UV, whatever the pixel's footprint) or trilinear "
        "(a mip chain of 2x2 means, the level log2 of the pixel's footprint in texels, "
        "OpenGL's rho, read bilinearly in the two levels around it and blended: what an "
        "engine samples at a distance). Views with --pixel-filter center only.",
        section="view", choices=("bilinear", "trilinear"))
