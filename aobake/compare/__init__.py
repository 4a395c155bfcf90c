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
- ``excess_rmse = sqrt(max(0, rmse^2 - reference_noise_rms^2))``: the part of the difference
  the reference's own noise does not explain (the candidate's noise is part of it;
  ``candidate_noise_rms`` says how much, when the candidate has a stderr).

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

from aobake.compare.align import align_texels, align_vertices
from aobake.compare.heatmap import check_path, diverging, write_heatmap
from aobake.compare.matching import (POSITION_TOLERANCE, match_vertices, position_tolerance,
                                     tie_features)
from aobake.compare.screen import format_screen, is_view, score_view
from aobake.compare.settings import check_same_quantity
from aobake.compare.values import IMAGE_KINDS, image_kind, kind
from aobake.errors import InputError
from aobake.outputs.values import (TEXEL_SUFFIXES, VERTEX_SUFFIXES, Values, file_path, read,
                                   target_of)
from aobake.quantities import QUANTITIES

__all__ = ["COMPARABLE", "CONVENTIONS", "POSITION_TOLERANCE", "TEXEL_SUFFIXES", "VERTEX_SUFFIXES",
           "Values", "compare", "diverging", "format_table", "main", "match_vertices", "metrics",
           "position_tolerance", "read", "tie_features"]

log = logging.getLogger(__name__)

#: quantities whose value is one number per point (the ones an error in [0, 1] describes)
COMPARABLE = tuple(name for name, q in QUANTITIES.items() if q.value.width == 1)
#: --candidate-convention -> what the candidate's numbers mean
CONVENTIONS = {
    "ao": "as aobake: 1 = fully open, 0 = fully occluded",
    "occlusion": "1 minus that: 1 = fully occluded (libigl's ambient_occlusion); compared as 1 - value",
}


def compare(reference_path, candidate_path, quantity: str = "ao", *, candidate_key: str | None = None,
            candidate_convention: str = "ao", heatmap=None,
            reference_key: str | None = None) -> dict:
    """Compare ``candidate_path`` against ``reference_path`` for ``quantity`` ('ao' | 'obscurance').

    candidate_key : the candidate's array (NPZ), vertex property (PLY), attribute (GLB) or
      channel (image) holding the quantity, when it is not aobake's name for it
    candidate_convention : 'ao' (1 = open) | 'occlusion' (the candidate holds 1 - value)
    heatmap : path of a .ply (per vertex) or .png (per texel) to write the error to
    reference_key : the reference's array / channel when it is not aobake's name for the
      quantity (a view's ``ao_unbounded``); its stderr is ``<key>_stderr`` where there is one

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
    reference = read(reference_path, quantity, key=reference_key)
    candidate = read(candidate_path, quantity, key=candidate_key, role="candidate")
    if candidate.target != reference.target:
        raise InputError(f"{candidate_path}: holds {kind(candidate.target)}, but the reference "
                         f"{reference_path} holds {kind(reference.target)}")
    if target == "texels":  # a view's pixels and a lightmap's texels are not the same points
        ref_kind, cand_kind = image_kind(reference), image_kind(candidate)
        if ref_kind and cand_kind and ref_kind != cand_kind:
            raise InputError(f"{candidate_path}: holds {IMAGE_KINDS[cand_kind]}, but the "
                             f"reference {reference_path} holds {IMAGE_KINDS[ref_kind]}: "
                             "their values are not of the same points")
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
    for values, path, what in ((ref, reference_path, quantity), (cand, candidate_path, quantity),
                               (ref_se, reference_path, f"{quantity}_stderr"),
                               (cand_se, candidate_path, f"{quantity}_stderr")):
        bad = 0 if values is None else int(np.count_nonzero(~np.isfinite(values)))
        if bad:
            raise InputError(f"{path}: {bad} of the {len(values)} compared {what} values "
                             "are not finite")
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
              "candidate_key": candidate.key, "candidate_convention": candidate_convention}
    try:
        result.update(metrics(ref, cand, ref_se, cand_se))
    except ValueError as exc:  # a ratio beyond float64: the reference's stderr is the cause
        raise InputError(f"{reference_path}: {exc}") from None
    warnings += extra.pop("warnings")
    notes = reference.notes + candidate.notes + extra.pop("notes")
    result.update(extra)
    result["screen"] = None
    if view:  # scored as screen-space AO
        result["screen"] = score_view(reference, candidate, where)
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

    reference, candidate : (n,) float, n >= 1, finite; *_stderr : (n,) float, finite, or None.
    Returns a dict of Python floats / None (n an int): n, rmse, bias, max_error,
    mean_abs_error, psnr (peak 1, None when the error is exactly 0), reference_noise_rms,
    rmse_in_reference_se, excess_rmse, candidate_noise_rms (None without the stderr).
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
    noise = _rms(reference_stderr)
    out = {
        "n": int(n),
        "rmse": rmse,
        "bias": _mean(error, largest),
        "max_error": largest,
        "mean_abs_error": _mean(np.abs(error), largest),
        # peak 1 (AO spans [0, 1]): 10 log10(1 / mean e^2) = -20 log10(rmse)
        "psnr": -20.0 * math.log10(rmse) if rmse > 0 else None,
        "reference_noise_rms": noise,
        "rmse_in_reference_se": None,
        "excess_rmse": None,
        "candidate_noise_rms": _rms(candidate_stderr),
    }
    if noise is not None:
        # the reference's noise alone gives mean e^2 = noise^2 against an exact candidate:
        # sqrt(max(0, rmse^2 - noise^2)), as rmse sqrt((1 - q)(1 + q)), q = noise / rmse
        q = noise / rmse if rmse > 0 else math.inf
        out["excess_rmse"] = 0.0 if q >= 1 else (math.sqrt(max(0.0, rmse * rmse - noise * noise))
                                                 if rmse < 1e150 else
                                                 rmse * math.sqrt((1 - q) * (1 + q)))
        if noise > 0:
            ratio = rmse / noise
            if not math.isfinite(ratio):
                raise ValueError(f"its stderr ({noise:.3g} rms) is too small against an error of "
                                 f"{rmse:.3g}: their ratio is beyond float64's range")
            out["rmse_in_reference_se"] = ratio
    return out


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
             "texel": "covered texels", "pixel": "covered pixels of a camera view"}[result["matched_by"]]
    rows = [
        ("rmse", num(result["rmse"])),
        ("bias (candidate - reference)", num(result["bias"], "+.6f")),
        ("max |error|", num(result["max_error"])),
        ("mean |error|", num(result["mean_abs_error"])),
        ("psnr (peak 1)", "inf (identical)" if result["psnr"] is None else f"{result['psnr']:.2f} dB"),
        ("reference noise rms", num(result["reference_noise_rms"])),
        ("rmse / reference noise rms", num(result["rmse_in_reference_se"], ".3f")),
        ("excess rmse", num(result["excess_rmse"])),
    ]
    if result["candidate_noise_rms"] is not None:
        rows.append(("candidate noise rms", num(result["candidate_noise_rms"])))
    lines = [f"{result['quantity']}: {result['candidate']} against {result['reference']}, "
             f"{result['n']} {where}"]
    width = max(len(label) for label, _ in rows)
    lines += [f"  {label:<{width}}  {value}" for label, value in rows]
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


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("reference", type=click.Path(path_type=Path))
@click.argument("candidate", type=click.Path(path_type=Path))
@click.option("--quantity", "-q", type=click.Choice(COMPARABLE), default="ao", show_default=True,
              help="What to compare.")
@click.option("--candidate-key", metavar="NAME", default=None,
              help="The candidate's NPZ array / PLY property / GLB attribute / image channel "
                   "holding the quantity, when it is not aobake's name for it.")
@click.option("--reference-key", metavar="NAME", default=None,
              help="The reference's array / channel to compare against, when not aobake's "
                   "name for the quantity (a view's ao_unbounded); NAME_stderr is its stderr.")
@click.option("--candidate-convention", type=click.Choice(tuple(CONVENTIONS)), default="ao",
              show_default=True,
              help="occlusion: the candidate holds 1 - AO (libigl); compared as 1 - value.")
@click.option("--heatmap", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the error (candidate - reference) in a blue-white-red map: "
                   ".ply per vertex, .png per texel.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of the table.")
def main(reference, candidate, quantity, candidate_key, reference_key, candidate_convention,
         heatmap, as_json):
    """Compare CANDIDATE against REFERENCE: RMSE, bias, max error, PSNR and how much of the
    difference the reference's own noise explains.

    Both are per-vertex files (.npz, .ply, .glb; vertices matched by position) or lightmaps
    (.exr, .png, .tif; the texels the reference covers).  A camera view from aobake view is
    compared per covered pixel and scored as screen-space AO as well: interior and
    depth-edge band, SSIM, stderr units, raw and after the best gain.  The candidate may come
    from another tool (see --candidate-key, --candidate-convention).  Uniform- and
    cosine-weighted AO are different quantities and are not compared.
    """
    from aobake.cli.common import guarded  # the CLI's contract: errors, signals, exit codes

    def run():
        result = compare(reference, candidate, quantity, candidate_key=candidate_key,
                         candidate_convention=candidate_convention, heatmap=heatmap,
                         reference_key=reference_key)
        click.echo(json.dumps(result, allow_nan=False) if as_json else format_table(result))

    guarded(False, run)
