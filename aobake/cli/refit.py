"""``aobake refit BAKE --out OUT``: recompute ao/obscurance of a bake kept with
``--keep-distances`` at another max distance or tau, without tracing."""

from __future__ import annotations

from pathlib import Path

import click

from aobake.cli.common import Command, guarded
from aobake.cli.options import DistanceType, TauType


@click.command(cls=Command, context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("bake", type=click.Path(path_type=Path))
@click.option("--out", "-o", "out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Where to write the refitted bake (any per-vertex format; .npz keeps the "
                   "distances for another refit).")
@click.option("--tau", default=None, type=TauType,
              help="New obscurance decay per scene unit (adds obscurance if it was not baked).")
@click.option("--max-distance", default=None, type=DistanceType,
              help="New max distance (scene units or P%), at most the baked one.")
@click.option("--quantity", "-q", "quantities", multiple=True,
              type=click.Choice(["ao", "obscurance"]),
              help="What to recompute (repeatable). Default: what was baked.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the JSON report here.")
@click.option("--quiet", is_flag=True, help="No summary line.")
def refit_main(bake, out, tau, max_distance, quantities, report_path, quiet):
    """Recompute ao/obscurance of BAKE (an NPZ written with --keep-distances) at another
    --max-distance or --tau, without tracing: the same numbers as a fresh bake of that seed."""
    # The main command's contract: one line and exit 1 for a bad input or output, SIGINT
    # 130, SIGTERM/SIGHUP 128 + the signal, and the outputs a transaction (none left behind).
    guarded(quiet, _refit, bake, out, tau, max_distance, quantities, report_path, quiet)


def _refit(bake, out, tau, max_distance, quantities, report_path, quiet):
    import time

    import aobake
    from aobake.refit import refit

    start = time.perf_counter()
    result = refit(bake, tau=tau, max_distance=max_distance, quantities=list(quantities) or None)
    written = aobake.write(result, out, mesh=bake, report=report_path)
    if not quiet:
        click.echo(f"aobake: refit {len(result.positions)} vertices in "
                   f"{time.perf_counter() - start:.3f} s, no rays traced -> "
                   f"{', '.join(map(str, written))}", err=True)
