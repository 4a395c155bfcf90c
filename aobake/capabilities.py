"""What each method and target can do, declared without importing them, and the one check
of a request against those declarations.

pbrt-v4 refuses an incompatible integrator/camera/film pair when it creates them, not
halfway through a render; aobake does the same: :func:`check` runs before any file is
loaded (``aobake.api.run`` calls it first, and the command line before it plans its
outputs), and each command's ``--method``, ``-q`` and ``--target`` choices are read from
the declarations (:func:`methods_for`), so a command offers only what it can run.

A method *needs* things of the target's points; a target *provides* them:

- ``points``: positions and normals (every target);
- ``triangles``: the triangle and barycentrics under each point (lightmap texels, view
  pixels): what ``--method file`` interpolates on;
- ``gbuffer``: a camera's G-buffer (the view target): what screen-space methods read.

A method serves a target when the target provides everything the method needs.  The
plugins' own ``prepare`` keeps the checks that need the scene (an empty mesh, an EGL
context); everything decidable from names and settings is here.
"""

from __future__ import annotations

from dataclasses import dataclass

from aobake.errors import InputError, UsageError

#: every quantity a ray-traced bake computes (``aobake.quantities.QUANTITIES``' keys; kept
#: here as names so that reading a declaration imports no quantity)
ALL_QUANTITIES = ("ao", "obscurance", "bent_normal", "indirect", "thickness")


@dataclass(frozen=True)
class MethodCapabilities:
    """What a method computes and needs.

    quantities : the quantities it estimates; needs : what it reads of the target's points
    (``points`` | ``triangles`` | ``gbuffer``); error_bars : it reports a per-point stderr
    and interval (``--denoise`` and ``--tolerance`` weigh by them); traces_scene : it casts
    rays through the scene's faces (what ``--alpha-cutout``, ``--receive-only``,
    ``--tolerance`` and ``--keep-distances`` act on); ground_plane : it honours
    ``--ground-plane``; weightings : the AO conventions it computes; max_distance : it
    honours a finite ``--max-distance``; sections : the settings sections it reads beside
    the common ones (what its report records); what : one line for ``--help``.
    """

    quantities: tuple
    needs: tuple = ("points",)
    error_bars: bool = False
    traces_scene: bool = False
    ground_plane: bool = True
    weightings: tuple = ("cosine", "uniform")
    max_distance: bool = True
    sections: tuple = ()
    what: str = ""


@dataclass(frozen=True)
class TargetCapabilities:
    """What a target's points provide, the settings sections it reads, and what it is.

    provides : ``points`` | ``triangles`` | ``gbuffer``; sections : its settings sections
    (what its report records); what : how messages name it.
    """

    provides: tuple
    sections: tuple = ()
    what: str = ""


_SCREEN = dict(quantities=("ao",), needs=("points", "gbuffer"), weightings=("cosine",))

#: method name -> its declaration (the registry ``aobake.methods.METHODS`` names the class)
METHODS = {
    "rays": MethodCapabilities(
        ALL_QUANTITIES, error_bars=True, traces_scene=True, sections=("rays",),
        what="ray-traced, with error bars: the reference"),
    "discs": MethodCapabilities(
        ("ao", "indirect"), ground_plane=False, sections=("discs",),
        what="Bunnell's disc approximation (GPU Gems 2 ch. 14)"),
    "file": MethodCapabilities(
        ("ao", "obscurance"), needs=("points", "triangles"), sections=("file",),
        what="a bake's values (--ao-from): a per-vertex bake interpolated on the triangles, "
             "or a lightmap looked up at their UVs"),
    "hemicube": MethodCapabilities(
        ("ao",), ground_plane=False, sections=("hemicube",),
        what="rasterised hemicubes (OpenGL)"),
    "crytek": MethodCapabilities(**_SCREEN, sections=("ssao", "crytek"),
                                 what="Crytek's screen-space AO"),
    "shanmugam": MethodCapabilities(**_SCREEN, sections=("ssao",),
                                    what="Shanmugam and Arikan's screen-space AO"),
    "gtao": MethodCapabilities(**_SCREEN, sections=("ssao", "gtao"),
                               what="ground-truth-based AO (Jimenez et al. 2016)"),
    "heightfield": MethodCapabilities(
        **_SCREEN, error_bars=True, sections=("rays", "ssao", "heightfield"),
        what="rays against the G-buffer's height field (the screen methods' own truth)"),
    "depthmaps": MethodCapabilities(
        ("ao", "bent_normal"), max_distance=False, sections=("depthmaps",),
        what="K shared orthographic depth maps (OpenGL): the pre-ray-tracing GPU bake"),
}

#: target name -> its declaration (``aobake.targets.TARGETS`` names the class)
TARGETS = {
    # section "instances": --bake (aobake.instances), read where the points are the scene's
    # vertices or the caller's own
    "vertices": TargetCapabilities(("points",), ("instances",), what="a per-vertex bake"),
    "points": TargetCapabilities(("points",), ("instances",), what="query points"),
    # (a lightmap of a set of instances: one region per baked instance, --bake)
    "texels": TargetCapabilities(("points", "triangles"), ("texels", "instances"),
                                 what="a lightmap"),
    "view": TargetCapabilities(("points", "triangles", "gbuffer"), ("view",),
                               what="a camera view"),
    "projected_texels": TargetCapabilities(("points",), ("texels", "studio"),
                                           what="a high-to-low lightmap"),
    "projected_vertices": TargetCapabilities(("points",), ("studio",),
                                             what="a high-to-low per-vertex bake"),
}

#: what each need is, in a message
_NEEDS = {"triangles": "a triangle under each point (a lightmap or a view)",
          "gbuffer": "a camera's G-buffer (aobake view)"}


#: the method a request runs when it names none and reads no bake: the ray-traced reference
DEFAULT_METHOD = "rays"


def implied_method(method: str | None, config) -> str:
    """The method a request runs: ``method`` as named, or (None: none named) ``file`` when
    ``config`` (a BakeConfig or a dict of its fields) reads a bake (``ao_from``: --ao-from
    FILE means --method file, at every door), else ``DEFAULT_METHOD``.

    UsageError for ``ao_from`` with another method named: its values would never be read.
    """
    ao_from = config.get("ao_from") if isinstance(config, dict) \
        else getattr(config, "ao_from", None)
    if ao_from is None:
        return DEFAULT_METHOD if method is None else method
    if method is not None and method != "file":
        raise UsageError(f"--ao-from reads a bake: it goes with --method file, not "
                         f"--method {method}")
    return "file"


def serves(method: str, target: str) -> bool:
    """Whether ``target`` provides everything ``method`` needs."""
    return set(METHODS[method].needs) <= set(TARGETS[target].provides)


def methods_for(targets) -> tuple:
    """The methods that serve at least one of ``targets``, in registry order."""
    return tuple(m for m in METHODS if any(serves(m, t) for t in targets))


def quantities_for(methods) -> tuple:
    """The quantities at least one of ``methods`` computes, in ``ALL_QUANTITIES`` order."""
    have = {q for m in methods for q in METHODS[m].quantities}
    return tuple(q for q in ALL_QUANTITIES if q in have)


def sections_used(method: str, target: str) -> tuple:
    """The settings sections a bake of ``method`` at ``target`` reads: the common settings,
    the method's and the target's (what its report's config records)."""
    out = ["common"]
    for section in METHODS[method].sections + TARGETS[target].sections:
        if section not in out:
            out.append(section)
    return tuple(out)


def check(method: str, target: str, config, given=()) -> None:
    """Refuse a request the declarations say cannot run, before any work.

    method : a ``METHODS`` name; target : a ``TARGETS`` name; config : a ``BakeConfig``;
    given : the names of the settings the caller gave one by one (flags, keywords, a
    manifest's or a dict's keys), of which a setting only another target reads is refused
    (a whole ``BakeConfig`` passed as one record is not: it carries every section).
    Raises UsageError (an InputError) with one line naming both sides.
    """
    if method not in METHODS:
        raise UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    from aobake.backends import unavailable  # its optional extra (warp) missing: say so now

    missing = unavailable(config.backend)
    if missing:
        raise InputError(missing)
    if target not in TARGETS:
        raise UsageError(f"unknown target {target!r}; choose from {', '.join(TARGETS)}")
    can, where = METHODS[method], TARGETS[target]
    for need in can.needs:
        if need not in where.provides:
            hint = (" (methods for it: " + ", ".join(methods_for([target])) + ")")
            raise UsageError(f"--method {method} needs {_NEEDS[need]}; {where.what} "
                             f"({target}) has none{hint}")
    quantities = tuple(config.quantities)
    missing = [q for q in quantities if q not in can.quantities]
    if missing:
        raise UsageError(f"--method {method} computes {', '.join(can.quantities)} only; it "
                         f"cannot bake -q {', '.join(missing)}")
    if config.weighting not in can.weightings:
        raise UsageError(f"--method {method} computes {' or '.join(can.weightings)}-weighted "
                         f"AO, not --weighting {config.weighting}")
    if config.ground_plane and not can.ground_plane:
        raise UsageError(f"--method {method} has no ground plane (it builds from the mesh's "
                         "faces only): drop --ground-plane or use --method rays")
    distance = config.max_distance
    if not can.max_distance and (isinstance(distance, str) or distance != float("inf")):
        raise UsageError(f"--max-distance {distance}: --method {method} has no finite max "
                         "distance (it sees the whole scene): drop it or use --method rays")
    rays_only = [(config.tolerance is not None, "--tolerance sets a per-point ray count"),
                 (config.keep_distances, "--keep-distances keeps every ray's distance"),
                 (config.alpha_cutout, "--alpha-cutout lets rays through cut-out texels"),
                 (bool(config.receive_only), "--receive-only needs rays that pass the faces "
                                             "it names")]
    for asked, what in rays_only:
        if asked and not can.traces_scene:
            raise UsageError(f"{what}: --method {method} casts no rays through the scene")
    if config.tolerance is not None and method != "rays":
        raise UsageError(f"--tolerance adapts the ray-traced method's counts: not with "
                         f"--method {method}")
    if config.keep_distances and method != "rays":
        raise UsageError(f"--keep-distances keeps the ray-traced method's distances: not "
                         f"with --method {method}")
    if config.denoise:
        if not can.error_bars:
            raise UsageError(f"--denoise filters by each texel's stderr: --method {method} "
                             "reports none")
        if target not in ("texels", "projected_texels"):
            raise UsageError(f"--denoise filters a lightmap: {where.what} ({target}) is not one")
    # (a projected target may also be handed its source as the scene: bake_projected)
    if config.source is not None and not target.startswith("projected_"):
        raise UsageError(f"--from (source) bakes a high mesh onto a low mesh's vertices or "
                         f"lightmap: {where.what} ({target}) is not one")
    if getattr(config, "pixel_filter", "center") == "box" and "gbuffer" in can.needs:
        raise UsageError(f"--method {method} reads one G-buffer sample per pixel centre: not "
                         "with --pixel-filter box (which averages over the pixel's area)")
    if getattr(config, "lightmap_filter", "bilinear") != "bilinear":
        flag = f"--lightmap-filter {config.lightmap_filter}"
        if method != "file":
            raise UsageError(f"{flag} is how --method file looks a lightmap up: not with "
                             f"--method {method}")
        if target != "view":
            raise UsageError(f"{flag} picks a mip level by a camera pixel's footprint: "
                             f"{where.what} ({target}) has no pixels (aobake view has)")
        if getattr(config, "pixel_filter", "center") == "box":
            raise UsageError(f"{flag}: --pixel-filter box averages 16 lookups over each pixel, "
                             "which is what a mip level stands in for: one or the other")
    if method == "file" and config.ao_from is None:
        raise UsageError("--method file needs --ao-from FILE (a per-vertex bake of the mesh)")
    check_settings(target, config, given)
    from aobake import instances  # --bake: the methods and targets that can honour it

    instances.check(method, target, config)


#: the settings sections that belong to a target, and what asks for one that reads them
_TARGET_SECTIONS = {"texels": "a lightmap (an .exr/.png/.tif output, or --target texels)",
                    "view": "aobake view"}


def check_settings(target: str, config, given=()) -> None:
    """Refuse a target's setting given where another target runs: a per-vertex bake does
    not read ``--resolution`` or ``--uv-set``, and saying nothing would leave the user
    believing it did.  ``given`` : the names the caller set one by one; of those, only
    values other than the default count."""
    from aobake.settings import DEFAULTS, SECTIONS, SPECS

    reads = TARGETS[target].sections
    given = set(given)
    if "uv_set" in given and getattr(config, "uv_set", 0) \
            and target in ("vertices", "points", "projected_vertices"):
        raise UsageError(f"--uv-set {config.uv_set} picks the UV set a lightmap bakes into (or "
                         f"a view looks a lightmap up by): {TARGETS[target].what} ({target}) "
                         "does not read it")
    for name, section in SECTIONS.items():
        if name not in given or section not in _TARGET_SECTIONS or section in reads:
            continue
        value = getattr(config, name, DEFAULTS[name])
        if value == DEFAULTS[name]:
            continue
        spec = SPECS[name]
        flag = spec.flags[0] if spec.flags else "--" + name.replace("_", "-")
        raise UsageError(f"{flag} is a setting of {_TARGET_SECTIONS[section]}: "
                         f"{TARGETS[target].what} ({target}) does not read it")
