"""``aobake compare REFERENCE CANDIDATE``: how far a bake (ours or another tool's) is from a
reference, measured against the reference's own noise.

    from aobake.compare import compare
    metrics = compare("reference.npz", "candidate.ply", quantity="ao")
    metrics["rmse"], metrics["excess_rmse"]

Per vertex (``.npz``, ``.ply``, ``.glb``) the candidate's vertices are matched to the
reference's by position when their order differs; per texel (``.exr``, ``.png``, ``.tif``)
only the texels the reference covers are compared (and, when the candidate has its own
coverage, the texels both cover).  Every metric is over those n points of the error
``e = candidate - reference`` (float64 arithmetic on the stored float32 values):

- ``rmse = sqrt(mean e^2)``, ``bias = mean e``, ``max_error = max |e|``,
  ``mean_abs_error = mean |e|``, ``psnr = 10 log10(1 / mean e^2)`` (peak 1; None when the
  files agree exactly);
- ``reference_noise_rms = sqrt(mean se_ref^2)`` from the reference's ``*_stderr``;
- ``rmse_in_reference_se = rmse / reference_noise_rms``: about 1 for an exact candidate, about
  sqrt(2) for an independent bake as noisy as the reference;
- ``error``: the standard error the next ones use, per point: 'reference' (se = se_ref) or,
  when the candidate carries its own (an ``ao_stderr`` channel, or ``candidate_stderr``),
  'combined' (se = sqrt(se_ref^2 + se_cand^2): two independent estimates); None without a
  reference stderr.  ``noise_rms = sqrt(mean se^2)``;
- ``z_rms = sqrt(mean (e / se)^2)``: about 1 when the two agree within their noise (an
  exact candidate against the reference's, or two independent bakes with 'combined'), and
  ``within_95`` / ``z_over_3`` the shares of points with |e| <= 1.96 se (the 95% interval
  of the difference holds 0) and |e| > 3 se; points with se = 0 (exact by construction)
  are left out of these three;
- ``excess_rmse = sqrt(max(0, rmse^2 - noise_rms^2))``: the part of the difference the noise
  does not explain; ``rmse_without_reference_noise`` the same with the reference's noise
  alone (the candidate's own error against the truth, its noise included).

A camera view (an ``aobake view`` EXR as the reference; the candidate another view of the
same camera or another tool's image of its pixels) is compared per covered pixel, and
``screen`` holds its screen-space scores (``aobake.compare.screen``: interior and depth-edge
band, SSIM, stderr units, raw and after the best gain); None for other files.

Values the metrics cannot have (no stderr in the reference, an infinite PSNR) are None, so
the record is strict JSON.  The library logs and never prints; ``main`` is the command.

The package: each file is read by ``aobake.outputs.read`` (the reader its format registers
beside its writer; ``read`` is re-exported here), ``values`` (how messages name what a file
holds), ``settings`` (same quantity?), ``align`` and ``matching`` (lining the files up),
``heatmap`` (the error as a picture); this module is the library entry point and the
command.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import click
import numpy as np

from aobake.cli.common import Command
from aobake.compare.align import align_texels, align_vertices
from aobake.compare.heatmap import check_path, diverging, write_heatmap
from aobake.compare.matching import (POSITION_TOLERANCE, match_vertices, position_tolerance,
                                     tie_features)
from aobake.compare.screen import format_screen, is_view, score_view
from aobake.compare.settings import check_same_layout, check_same_quantity
from aobake.compare.values import IMAGE_KINDS, image_kind, kind
from aobake.errors import InputError
from aobake.outputs.image import TRANSFERS
from aobake.outputs.values import (ALPHAS, TEXEL_SUFFIXES, VERTEX_SUFFIXES, Values,
                                   divided_by_alpha, file_path, read, target_of)
from aobake.quantities import QUANTITIES

__all__ = ["COMPARABLE", "CONVENTIONS", "POSITION_TOLERANCE", "TEXEL_SUFFIXES", "TRANSFERS",
           "VERTEX_SUFFIXES", "Values", "ALPHAS", "compare", "diverging", "format_table", "main",
           "match_vertices", "metrics", "position_tolerance", "read", "tie_features"]

log = logging.getLogger(__name__)

#: quantities whose value is one number per point (the ones an error in [0, 1] describes)
COMPARABLE = tuple(name for name, q in QUANTITIES.items() if q.value.width == 1)
#: z of the two-sided 95% normal interval (``within_95``)
Z95 = 1.959963984540054
#: --candidate-convention -> what the candidate's numbers mean
CONVENTIONS = {
    "ao": "as aobake: 1 = fully open, 0 = fully occluded",
    "occlusion": "1 minus that: 1 = fully occluded (libigl's ambient_occlusion); compared as 1 - value",
}


def compare(reference_path, candidate_path, quantity: str = "ao", *, candidate_key: str | None = None,
            candidate_convention: str = "ao", heatmap=None,
            reference_key: str | None = None, candidate_transfer: str | None = None,
            reference_transfer: str | None = None, candidate_stderr=None,
            candidate_alpha: str = "auto", candidate_alpha_key: str | None = None,
            reference_alpha: str = "auto", reference_alpha_key: str | None = None) -> dict:
    """Compare ``candidate_path`` against ``reference_path`` for ``quantity`` ('ao' | 'obscurance').

    candidate_key : the candidate's array (NPZ), vertex property (PLY), attribute (GLB) or
      channel (image) holding the quantity, when it is not aobake's name for it (in a
      layered or multi-part image also a pass, ``ViewLayer.AO``); its stderr is
      ``<key>_stderr`` where there is one
    candidate_convention : 'ao' (1 = open) | 'occlusion' (the candidate holds 1 - value)
    heatmap : path of a .ply (per vertex) or .png (per texel) to write the error to
    reference_key : the reference's array / channel when it is not aobake's name for the
      quantity (a view's ``ao_unbounded``); its stderr is ``<key>_stderr`` where there is one
    candidate_transfer, reference_transfer : None (as the file's colour tags say: an
      untagged 8/16-bit PNG or TIFF is refused) | 'linear' | 'srgb': how the file's values
      are encoded (``TRANSFERS``; ``aobake.outputs.read``'s ``transfer``)
    candidate_stderr : a file holding the candidate's standard errors (its one channel or
      array, or the quantity's name), of the candidate's size and order: z and the excess
      RMSE then use the combined error (divided by the candidate's alpha where its values are)
    candidate_alpha, reference_alpha : 'auto' | 'associated' | 'straight' (``ALPHAS``):
      whether an image's values are multiplied by an alpha (a renderer's AO times its
      coverage, OpenEXR's convention) and so divided by it (auto: where another tool's EXR
      has an alpha channel beside the value); *_alpha_key names that channel (default: the
      value's layer's A, Blender's <view layer>.Combined.A for a render pass, a lone A)

    Returns one record, always with the same keys (see the module docstring for the metrics;
    None where a value does not exist).  Raises ``InputError`` naming the file and the
    problem (missing, unreadable, no such key, meshes or images that do not line up,
    different weightings) and ``OutputError`` when the heatmap cannot be written.
    """
    if not isinstance(quantity, str) or quantity not in COMPARABLE:
        raise InputError(f"quantity must be one of {COMPARABLE}, got {quantity!r}")
    if not isinstance(candidate_convention, str) or candidate_convention not in CONVENTIONS:
        raise InputError(f"candidate_convention must be one of {tuple(CONVENTIONS)}, "
                         f"got {candidate_convention!r}")
    reference_path = file_path(reference_path, "reference", "compare")
    candidate_path = file_path(candidate_path, "candidate", "compare")
    target = target_of(reference_path)
    heatmap = None if heatmap is None else Path(heatmap)
    if heatmap is not None:
        check_path(heatmap, target, (reference_path, candidate_path))
    for name, key in (("candidate_key", candidate_key), ("reference_key", reference_key)):
        if key is not None and not isinstance(key, str):
            raise InputError(f"{name} must be a name (str), got {key!r}")
    for name, value in (("candidate_transfer", candidate_transfer),
                        ("reference_transfer", reference_transfer)):
        if value is not None and (not isinstance(value, str) or value not in TRANSFERS):
            raise InputError(f"{name} must be one of {tuple(TRANSFERS)} or None (as the "
                             f"file's tags say), got {value!r}")
    if candidate_stderr is not None:
        candidate_stderr = file_path(candidate_stderr, "candidate's stderr file", "compare")
    reference = read(reference_path, quantity, key=reference_key, transfer=reference_transfer,
                     alpha=reference_alpha, alpha_key=reference_alpha_key)
    candidate = read(candidate_path, quantity, key=candidate_key, role="candidate",
                     transfer=candidate_transfer, alpha=candidate_alpha,
                     alpha_key=candidate_alpha_key)
    if candidate_stderr is not None:
        _stderr_from_file(candidate, candidate_stderr, quantity)
    _partly_covered_note(reference, candidate)
    if candidate.target != reference.target:
        raise InputError(f"{candidate_path}: holds {kind(candidate)}, but the reference "
                         f"{reference_path} holds {kind(reference)}")
    if target == "texels":  # a view's pixels and a lightmap's texels are not the same points
        ref_kind, cand_kind = image_kind(reference), image_kind(candidate)
        if ref_kind and cand_kind and ref_kind != cand_kind:
            raise InputError(f"{candidate_path}: holds {IMAGE_KINDS[cand_kind]}, but the "
                             f"reference {reference_path} holds {IMAGE_KINDS[ref_kind]}: "
                             "their values are not of the same points")
        if ref_kind == cand_kind == "lightmap":
            check_same_layout(reference, candidate)
    warnings = reference.warnings + candidate.warnings
    warnings += check_same_quantity(reference, candidate, quantity)
    if candidate_convention == "occlusion":
        if candidate.metadata:
            raise InputError(f"{candidate_path}: is an aobake output, which holds {quantity} "
                             "(1 = open); --candidate-convention occlusion is for tools that "
                             "write 1 minus it")
        candidate.value = 1.0 - candidate.value

    if not reference.value.size:
        raise InputError(f"{reference_path}: holds no {quantity} values")
    aligned = (align_texels if target == "texels" else align_vertices)(reference, candidate)
    ref, cand, ref_se, cand_se, where, extra = aligned
    cand_se_path = candidate_stderr or candidate_path
    for values, path, what in ((ref, reference_path, quantity), (cand, candidate_path, quantity),
                               (ref_se, reference_path, f"{quantity}_stderr"),
                               (cand_se, cand_se_path, f"{quantity}_stderr")):
        bad = 0 if values is None else int(np.count_nonzero(~np.isfinite(values)))
        if bad:
            raise InputError(f"{path}: {bad} of the {len(values)} compared {what} values "
                             "are not finite")
    for values, path in ((ref_se, reference_path), (cand_se, cand_se_path)):
        bad = 0 if values is None else int(np.count_nonzero(values < 0))
        if bad:
            raise InputError(f"{path}: {bad} of the {len(values)} compared standard errors "
                             "are negative")
    with np.errstate(over="ignore"):
        error = cand - ref
    if not np.isfinite(error).all():  # finite values whose difference leaves float64
        big_ref, big_cand = float(np.max(np.abs(ref))), float(np.max(np.abs(cand)))
        big, path = (big_ref, reference_path) if big_ref > big_cand else (big_cand, candidate_path)
        raise InputError(f"{path}: {quantity} values as large as {big:.3g}: their difference "
                         "from the other file's is beyond float64's range")
    view = target == "texels" and is_view(reference)  # a camera view: its pixels
    result = {"quantity": quantity, "target": "view" if view else target,
              "reference": str(reference_path),
              "candidate": str(candidate_path), "reference_key": reference.key,
              "candidate_key": candidate.key, "candidate_convention": candidate_convention,
              "reference_transfer": reference.transfer, "candidate_transfer": candidate.transfer,
              "candidate_stderr": None if candidate_stderr is None else str(candidate_stderr),
              # how the values relate to an alpha: divided by it (associated) or as read
              "reference_alpha": "straight" if reference.alpha is None else "associated",
              "candidate_alpha": "straight" if candidate.alpha is None else "associated"}
    try:
        result.update(metrics(ref, cand, ref_se, cand_se))
    except ValueError as exc:  # a ratio beyond float64: the reference's stderr is the cause
        raise InputError(f"{reference_path}: {exc}") from None
    warnings += extra.pop("warnings")
    notes = reference.notes + candidate.notes + extra.pop("notes")
    result.update(extra)
    result["screen"] = None
    if view:  # scored as screen-space AO, in units of the error the metrics use
        stderr = reference.stderr
        if result["error"] == "combined":
            stderr = np.hypot(reference.stderr, np.where(where, candidate.stderr, 0.0))
        result["screen"] = score_view(reference, candidate, where, stderr)
        result["matched_by"] = "pixel"
    result["heatmap"], result["heatmap_scale"] = None, None
    result["warnings"] = warnings
    result["notes"] = notes
    if heatmap is not None:
        scale = result["max_error"] or 1.0
        if target == "vertices":  # on every reference vertex: 0 (white) where none compared
            full = np.zeros(len(reference.value))
            full[slice(None) if where is None else where] = error
            error, where = full, None
        write_heatmap(heatmap, reference, error, where, scale, quantity)
        result["heatmap"], result["heatmap_scale"] = str(heatmap), scale
        log.info("wrote %s (full colour at |error| = %.6g)", heatmap, scale)
    log.info("compared %s over %d %s: rmse %.6g, bias %+.6g", quantity, result["n"],
             "pixels" if view else target,
             result["rmse"], result["bias"])
    return result


def metrics(reference: np.ndarray, candidate: np.ndarray, reference_stderr: np.ndarray | None = None,
            candidate_stderr: np.ndarray | None = None) -> dict:
    """The error metrics of ``candidate - reference``.

    reference, candidate : (n,) float, n >= 1, finite; *_stderr : (n,) float, finite, >= 0,
    or None.
    Returns a dict of Python floats / None (n an int): n, rmse, bias, max_error,
    mean_abs_error, psnr (peak 1, None when the error is exactly 0), reference_noise_rms,
    rmse_in_reference_se, candidate_noise_rms (None without the stderr), error ('reference'
    | 'combined' | None: the per-point standard error se the next ones use: the reference's,
    or sqrt(se_ref^2 + se_cand^2) when the candidate has one too; None without the
    reference's), noise_rms (sqrt(mean se^2)), z_rms, within_95, z_over_3 (over the points
    with se > 0; None when there is none), excess_rmse (sqrt(max(0, rmse^2 - noise_rms^2))),
    rmse_without_reference_noise (the same with reference_noise_rms).
    Every number is finite: the means are taken on values scaled by their largest when
    squares would leave float64's range (an error of 1e200 has an rmse of 1e200, not inf).
    Raises ValueError when the error, a difference or a ratio is beyond float64's range.
    """
    with np.errstate(over="ignore"):
        error = np.asarray(candidate, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    if not np.isfinite(error).all():
        raise ValueError("the error candidate - reference is not finite (or beyond float64)")
    n = error.size
    rmse = _rms(error)
    largest = float(np.max(np.abs(error)))
    reference_noise = _rms(reference_stderr)
    kind, se = None, None
    if reference_stderr is not None:
        kind, se = "reference", np.asarray(reference_stderr, dtype=np.float64)
        if candidate_stderr is not None:  # two independent estimates: their variances add
            kind, se = "combined", np.hypot(se, np.asarray(candidate_stderr, dtype=np.float64))
    noise = _rms(se)
    out = {
        "n": int(n),
        "rmse": rmse,
        "bias": _mean(error, largest),
        "max_error": largest,
        "mean_abs_error": _mean(np.abs(error), largest),
        # peak 1 (AO spans [0, 1]): 10 log10(1 / mean e^2) = -20 log10(rmse)
        "psnr": -20.0 * math.log10(rmse) if rmse > 0 else None,
        "reference_noise_rms": reference_noise,
        "rmse_in_reference_se": None,
        "candidate_noise_rms": _rms(candidate_stderr),
        "error": kind,
        "noise_rms": noise,
        "z_rms": None,
        "within_95": None,
        "z_over_3": None,
        "excess_rmse": None if noise is None else _excess(rmse, noise),
        "rmse_without_reference_noise": None if reference_noise is None else
        _excess(rmse, reference_noise),
    }
    if reference_noise:
        ratio = rmse / reference_noise
        if not math.isfinite(ratio):
            raise ValueError(f"its stderr ({reference_noise:.3g} rms) is too small against an "
                             f"error of {rmse:.3g}: their ratio is beyond float64's range")
        out["rmse_in_reference_se"] = ratio
    if se is not None and np.any(se > 0):
        known = se > 0  # a zero error bar claims exactness: no z of its own
        with np.errstate(over="ignore", under="ignore"):
            z = error[known] / se[known]
        if not np.isfinite(z).all():
            raise ValueError(f"its stderr (as small as {float(se[known].min()):.3g}) is too "
                             f"small against errors up to {largest:.3g}: their ratio is beyond "
                             "float64's range")
        out["z_rms"] = _rms(z)
        out["within_95"] = float(np.mean(np.abs(z) <= Z95))
        out["z_over_3"] = float(np.mean(np.abs(z) > 3.0))
    return out


def _excess(rmse: float, noise: float) -> float:
    """sqrt(max(0, rmse^2 - noise^2)): the part of an RMS error a noise of RMS ``noise``
    does not explain (the noise alone gives mean e^2 = noise^2 against an exact value), as
    rmse sqrt((1 - q)(1 + q)), q = noise / rmse, where the squares would overflow."""
    q = noise / rmse if rmse > 0 else math.inf
    if q >= 1:
        return 0.0
    if rmse < 1e150:
        return math.sqrt(max(0.0, rmse * rmse - noise * noise))
    return rmse * math.sqrt((1 - q) * (1 + q))


def _stderr_from_file(candidate: Values, path: Path, quantity: str) -> None:
    """Give ``candidate`` the standard errors held by the file ``path`` (its one channel or
    array, or the quantity's name: ``aobake.outputs.read``), checked against its size."""
    values = read(path, quantity, role="candidate")
    if values.target != candidate.target or values.value.shape != candidate.value.shape:
        what = "x".join(str(d) for d in values.value.shape[::-1])
        want = "x".join(str(d) for d in candidate.value.shape[::-1])
        raise InputError(f"{path}: holds {what} values, the candidate {candidate.path} {want}: "
                         "a stderr file holds one standard error per candidate value, in its "
                         "order")
    if candidate.positions is not None and values.positions is not None and \
            not np.all(np.abs(values.positions - candidate.positions)
                       <= position_tolerance(candidate.positions)):
        raise InputError(f"{path}: its vertices are not the candidate {candidate.path}'s (in "
                         "its order)")
    own = " (in place of the ones it holds)" if candidate.stderr is not None else ""
    candidate.stderr = values.value
    if candidate.alpha is not None:  # the errors of associated values: divided as they are
        candidate.stderr = divided_by_alpha(values.value, candidate.alpha)
    candidate.notes.append(f"{path}: its {values.key!r} is read as the candidate's standard "
                           f"errors{own}")


def _partly_covered_note(reference: Values, candidate: Values) -> None:
    """A note when a view's partly covered pixels are compared with another tool's image
    read as straight: a renderer's value there is usually its AO times its coverage."""
    if not is_view(reference) or candidate.metadata or candidate.alpha is not None \
            or reference.columns is None or "coverage" not in reference.columns:
        return
    coverage = np.asarray(reference.columns["coverage"])
    if coverage.shape != candidate.value.shape:
        return
    partly = (coverage > 0) & (coverage < 1)
    if candidate.mask is not None:
        partly &= candidate.mask
    if partly.any():
        candidate.notes.append(
            f"{candidate.path}: read as straight (not multiplied by coverage) at the "
            f"{int(partly.sum())} pixels the reference covers partly; a renderer's AO there "
            "is usually its AO times its coverage: give its alpha (--candidate-alpha-key "
            "NAME) or compare the pixels every image covers fully")


def _rms(values) -> float | None:
    """sqrt(mean(values^2)) of finite values (None stays None), finite: on the values scaled
    by their largest when the squares would overflow (or underflow to 0)."""
    if values is None:
        return None
    values = np.asarray(values, dtype=np.float64)
    with np.errstate(over="ignore", under="ignore"):
        mean_square = float(np.mean(values * values))
    largest = float(np.max(np.abs(values)))
    if math.isfinite(mean_square) and (mean_square > 0 or largest == 0):
        return math.sqrt(mean_square)
    scaled = values / largest
    return largest * math.sqrt(float(np.mean(scaled * scaled)))


def _mean(values: np.ndarray, largest: float) -> float:
    """mean(values) of finite values, finite (a sum of values near float64's limit would
    overflow: then on the values scaled by ``largest``, their largest magnitude)."""
    with np.errstate(over="ignore"):
        mean = float(np.mean(values))
    if math.isfinite(mean) or largest == 0:
        return mean
    return largest * float(np.mean(values / largest))


def format_table(result: dict) -> str:
    """The short human summary of a ``compare`` record."""
    def num(value, spec=".6f"):
        if value is None:
            return "-"
        return format(value, spec) if abs(value) < 1e6 else format(value, ".6g")

    where = {"order": "vertices (same order)", "position": "vertices (matched by position)",
             "instance": "vertices of the instances baked (by node and vertex index)",
             "source": "vertices baked (by their place in the whole set)",
             "texel": "covered texels", "pixel": "covered pixels of a camera view"}[result["matched_by"]]
    rows = [
        ("rmse", num(result["rmse"])),
        ("bias (candidate - reference)", num(result["bias"], "+.6f")),
        ("max |error|", num(result["max_error"])),
        ("mean |error|", num(result["mean_abs_error"])),
        ("psnr (peak 1)", "inf (identical)" if result["psnr"] is None else f"{result['psnr']:.2f} dB"),
        ("reference noise rms", num(result["reference_noise_rms"])),
        ("rmse / reference noise rms", num(result["rmse_in_reference_se"], ".3f")),
    ]
    if result["candidate_noise_rms"] is not None:
        rows.append(("candidate noise rms", num(result["candidate_noise_rms"])))
    if result["error"] == "combined":
        rows.append(("combined noise rms", num(result["noise_rms"])))
    error = {"combined": "combined stderr", "reference": "reference stderr"}.get(result["error"])
    rows += [
        ("excess rmse" + (f" (beyond the {error})" if error else ""), num(result["excess_rmse"])),
        ("z rms" + (f" (error / {error})" if error else ""), num(result["z_rms"], ".3f")),
        ("within the 95% interval", "-" if result["within_95"] is None else
         f"{100 * result['within_95']:.1f}% of points"),
    ]
    if result["error"] == "combined":
        rows.append(("rmse without the reference noise",
                     num(result["rmse_without_reference_noise"])))
    lines = [f"{result['quantity']}: {result['candidate']} against {result['reference']}, "
             f"{result['n']} {where}"]
    width = max(len(label) for label, _ in rows)
    lines += [f"  {label:<{width}}  {value}" for label, value in rows]
    if result["error"] is not None:
        lines.append("  error: " + ("combined: sqrt(reference stderr^2 + candidate stderr^2)"
                                    if result["error"] == "combined" else
                                    "the reference's stderr (the candidate has none)"))
    for side in ("reference", "candidate"):
        if result[f"{side}_transfer"] != "linear":
            lines.append(f"  {side} values: {result[f'{side}_transfer']}-encoded, linearised")
    if result["n_uncovered_in_candidate"] and result["target"] in ("texels", "view"):
        points = "pixels" if result["target"] == "view" else "texels"
        lines.append(f"  ({result['n_uncovered_in_candidate']} {points} the reference covers are "
                     "not covered by the candidate: left out)")
    lines += [f"  note: {text}" for text in result["notes"]]
    if result.get("screen"):
        lines += format_screen(result["screen"])
    if result["heatmap"]:
        lines.append(f"  heatmap: {result['heatmap']} (full colour at |error| = "
                     f"{result['heatmap_scale']:.4g})")
    return "\n".join(lines)


@click.command(cls=Command, context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("reference", type=click.Path(path_type=Path))
@click.argument("candidate", type=click.Path(path_type=Path))
@click.option("--quantity", "-q", type=click.Choice(COMPARABLE), default="ao", show_default=True,
              help="What to compare.")
@click.option("--candidate-key", metavar="NAME", default=None,
              help="The candidate's NPZ array / PLY property / GLB attribute / image channel "
                   "holding the quantity, when it is not aobake's name for it (in a layered "
                   "or multi-part EXR: the full name, ViewLayer.AO.R, a pass, ViewLayer.AO, or "
                   "a unique end, AO.R).")
@click.option("--reference-key", metavar="NAME", default=None,
              help="The reference's array / channel to compare against, when not aobake's "
                   "name for the quantity (a view's ao_unbounded); NAME_stderr is its stderr.")
@click.option("--candidate-convention", type=click.Choice(tuple(CONVENTIONS)), default="ao",
              show_default=True,
              help="occlusion: the candidate holds 1 - AO (libigl); compared as 1 - value.")
@click.option("--candidate-transfer", type=click.Choice(tuple(TRANSFERS)), default=None,
              help="How the candidate image's values are encoded, whatever its tags say "
                   "(default: as its colour tags say; an 8/16-bit PNG or TIFF without tags "
                   "is refused). srgb: linearised by the sRGB curve.")
@click.option("--reference-transfer", type=click.Choice(tuple(TRANSFERS)), default=None,
              help="The same for the reference.")
@click.option("--candidate-alpha", type=click.Choice(tuple(ALPHAS)), default="auto",
              show_default=True,
              help="Whether the candidate image's values are multiplied by an alpha (a "
                   "renderer's AO times its coverage: divided by it, pixels of alpha 0 not "
                   "compared). auto: associated where another tool's EXR has an alpha beside "
                   "the value (OpenEXR's convention; Blender's passes: the Combined pass's), "
                   "else straight (aobake's files, PNG, TIFF).")
@click.option("--candidate-alpha-key", metavar="NAME", default=None,
              help="The candidate's alpha channel (default: the value's layer's A, "
                   "<view layer>.Combined.A for a Blender pass, a lone A); naming one means "
                   "associated.")
@click.option("--reference-alpha", type=click.Choice(tuple(ALPHAS)), default="auto",
              show_default=True, help="The same for the reference.")
@click.option("--reference-alpha-key", metavar="NAME", default=None,
              help="The same for the reference.")
@click.option("--candidate-stderr", type=click.Path(path_type=Path), default=None,
              metavar="FILE",
              help="A file of the candidate's standard errors (one per value, in its order): "
                   "z and the excess rmse then use sqrt(se_ref^2 + se_cand^2).")
@click.option("--heatmap", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the error (candidate - reference) in a blue-white-red map: "
                   ".ply per vertex, .png per texel.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of the table.")
def main(reference, candidate, quantity, candidate_key, reference_key, candidate_convention,
         candidate_transfer, reference_transfer, candidate_alpha, candidate_alpha_key,
         reference_alpha, reference_alpha_key, candidate_stderr, heatmap, as_json):
    """Compare CANDIDATE against REFERENCE: RMSE, bias, max error, PSNR and how much of the
    difference the noise explains (the reference's, and the candidate's where it has a
    stderr).

    Both are per-vertex files (.npz, .ply, .glb; vertices matched by position) or lightmaps
    (.exr, .png, .tif; the texels the reference covers).  A camera view from aobake view is
    compared per covered pixel and scored as screen-space AO as well: interior and
    depth-edge band, SSIM, stderr units, raw and after the best gain.  The candidate may come
    from another tool (see --candidate-key, --candidate-convention): images are read as
    linear values (EXR; PNG/TIFF as their colour tags say, see --candidate-transfer), a
    multi-part EXR's every part (Blender's AO pass by its name).  When the candidate carries
    standard errors too, z and the excess rmse use both (error: combined).  Uniform- and
    cosine-weighted AO are different quantities and are not compared.
    """
    from aobake.cli.common import guarded  # the CLI's contract: errors, signals, exit codes

    def run():
        result = compare(reference, candidate, quantity, candidate_key=candidate_key,
                         candidate_convention=candidate_convention, heatmap=heatmap,
                         reference_key=reference_key, candidate_transfer=candidate_transfer,
                         reference_transfer=reference_transfer,
                         candidate_stderr=candidate_stderr, candidate_alpha=candidate_alpha,
                         candidate_alpha_key=candidate_alpha_key,
                         reference_alpha=reference_alpha,
                         reference_alpha_key=reference_alpha_key)
        click.echo(json.dumps(result, allow_nan=False) if as_json else format_table(result))

    guarded(False, run)
