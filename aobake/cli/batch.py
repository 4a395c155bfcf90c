"""``aobake batch INPUTS... --out-dir DIR --format ply``: many assets in one process.

INPUTS are mesh files, folders, glob patterns or manifests (CSV / JSON lines: ``mesh``,
``output``, ``target`` and per-asset settings; see ``aobake.batch``).  Every bake option
of the main command applies to every asset (a manifest's settings override it), on any
executor (``--executor dask`` opens one cluster for the whole batch).  One line per asset
on stderr, one JSON summary (``--summary``, default ``DIR/batch-summary.json``), exit 1
when any asset failed; an asset whose output and matching report exist is skipped unless
``--force``.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import click

from aobake.cli.common import guarded
from aobake.cli.options import (BAKE_METHODS as METHODS, BAKE_TARGETS as TARGETS,
                                PanelCommand, checked, given, in_panel, method_for,
                                named_method, run_options, settings)
from aobake.outputs.registry import suffixes

#: every output extension a batch can write, without its dot
FORMATS = tuple(sorted({s[1:] for target in TARGETS for s in suffixes(target)}))


def _batch_options() -> list:
    output = in_panel("output", [
        click.Option(["--out-dir", "-o", "out_dir"], required=True,
                     type=click.Path(file_okay=False, path_type=Path),
                     help="Folder every output goes into (made if missing); a manifest's "
                          "outputs are paths inside it."),
        click.Option(["--format", "-f", "fmt"], type=click.Choice(FORMATS), default=None,
                     help="Output format of the assets a manifest does not name an output "
                          "for: " + ", ".join(FORMATS) + "."),
        click.Option(["--target"], type=click.Choice(TARGETS), default=None,
                     help="vertices or texels. Default: from each output's extension."),
        click.Option(["--force"], is_flag=True,
                     help="Bake every asset again, even one whose output and matching report "
                          "exist."),
        click.Option(["--summary", "summary_path"], default=None,
                     type=click.Path(dir_okay=False, path_type=Path),
                     help="The JSON summary (per asset: status, seconds, rays, error). "
                          "Default: OUT_DIR/batch-summary.json."),
        click.Option(["--quiet"], is_flag=True,
                     help="Only failed assets and the final line on stderr; no warnings."),
    ])
    formats = in_panel("texels", [
        click.Option(["--half"], is_flag=True, help="EXR: 16-bit half floats."),
        click.Option(["--bit-depth"], default="8", show_default=True,
                     type=click.Choice(["8", "16"]), help="PNG/TIFF integer depth."),
        click.Option(["--r-only"], is_flag=True, help="PNG/TIFF: AO in R only."),
    ])
    return ([click.Argument(["inputs"], nargs=-1, required=True)] + output
            + settings(TARGETS, METHODS) + run_options(METHODS) + formats)


def batch_command() -> click.Command:
    """The ``batch`` sub-command."""
    return PanelCommand(
        "batch", params=_batch_options(), callback=_batch,
        context_settings={"help_option_names": ["-h", "--help"]},
        help="Bake many assets in one process: INPUTS are mesh files, folders (searched "
             "recursively), glob patterns or manifests (.csv with a header row, or .jsonl: "
             "mesh, output, target and any setting by name, per asset). Outputs go inside "
             "--out-dir, each with its report (<output>.report.json); an asset whose output "
             "and matching report exist is skipped (--force bakes it again). One line per "
             "asset on stderr, a JSON summary, exit status 1 if any asset failed.")


def _batch(inputs, out_dir, fmt, target, threads, method, executor, workers, chunk_points,
           half, bit_depth, r_only, force, summary_path, quiet, scheduler=None, **config):
    context = click.get_current_context()
    source = context.get_parameter_source("resolution")
    if source == click.core.ParameterSource.COMMANDLINE and config["texel_density"] is not None:
        raise click.UsageError("give --resolution or --texel-density, not both")
    if scheduler is not None and executor != "dask":
        raise click.UsageError("--scheduler goes with --executor dask")
    # the method named (or --ao-from's); None: each asset's settings imply it (a manifest
    # row's ao_from reads a bake with the file method, as --ao-from does: job.plan)
    method = method_for(method, config) if config.get("ao_from") is not None \
        else named_method(method)
    run = dict(threads=threads, method=method, executor=executor,
               workers=workers, chunk_points=chunk_points)
    write = dict(half=half, bit_depth=int(bit_depth), r_only=r_only)
    guarded(quiet, _run, inputs, out_dir, fmt, target, run, write, force,
            summary_path or out_dir / "batch-summary.json", quiet, scheduler,
            checked(given(config)))


def _run(inputs, out_dir, fmt, target, run, write, force, summary_path, quiet, scheduler,
         config):
    import aobake
    from aobake import batch
    from aobake.outputs.strictjson import write_report

    settings = aobake.BakeConfig(**config)  # checked before anything is read
    if fmt is not None:  # every asset's output is a .<fmt>: its target reads the settings
        from aobake.capabilities import check_settings
        from aobake.outputs.registry import default_target

        check_settings(target or default_target("asset." + fmt.lstrip(".")), settings, config)
    assets = batch.find_assets(inputs, out_dir, fmt, target)
    if fmt is None and assets and all(a.output is None and (a.error or "").endswith(
            batch.NO_FORMAT) for a in assets):
        # nothing names an output: a usage error for the whole batch, not one per asset
        raise click.UsageError("no output format: give --format (or a manifest that names "
                               "each asset's output)")
    batch.check_summary(summary_path, assets, out_dir, config)
    out_dir.mkdir(parents=True, exist_ok=True)
    executor = {"name": run["executor"], "workers": run["workers"],
                "chunk_points": run["chunk_points"], "scheduler": scheduler}
    records, clock = [], time.perf_counter()

    def save(interrupted: bool = False) -> None:
        data = batch.summary(records, out_dir, executor, time.perf_counter() - clock)
        if interrupted:
            data["interrupted"] = True
            data["not_started"] = len(assets) - len(records)
        write_report(summary_path, data)

    def each(record, index, total):
        records.append(record)
        _line(record, index, total, quiet)
        save()

    session = contextlib.nullcontext()
    if run["executor"] == "dask":  # one cluster for every asset, started when first needed
        from aobake.executors.dask import cluster, require

        require()  # Dask missing: one message, not one per asset
        session = cluster(scheduler, run["workers"])
    try:
        with session:
            batch.bake_assets(assets, out_dir, config, run=run, write=write, force=force,
                              on_asset=each)
    except BaseException:  # an interrupt: what is done is in the summary
        save(interrupted=True)
        click.echo(f"aobake: batch stopped after {len(records)} of {len(assets)} assets; "
                   f"summary {summary_path}", err=True)
        raise
    save()
    counts = {s: sum(r["status"] == s for r in records) for s in ("ok", "skipped", "failed")}
    click.echo(f"aobake: batch: {counts['ok']} baked, {counts['skipped']} skipped, "
               f"{counts['failed']} failed in {time.perf_counter() - clock:.1f} s; summary "
               f"{summary_path}", err=True)
    if counts["failed"]:
        raise SystemExit(1)


def _line(record, index, total, quiet) -> None:
    """One stderr line for an asset."""
    status, where = record["status"], f"aobake: [{index + 1}/{total}]"
    name = record["mesh"] or record["source"]
    if status == "failed":
        error = record["error"]
        said = error if error.startswith(str(name)) else f"{name}: {error}"
        click.echo(f"{where} FAILED {said}", err=True)
    elif quiet:
        return
    elif status == "skipped":
        click.echo(f"{where} skipped {name}: {record.get('reason', 'done')}", err=True)
    else:
        rays = f", {record['rays']} rays" if record["rays"] is not None else ""
        click.echo(f"{where} ok {name} -> {record['outputs'][0]}: {record['points']} points"
                   f"{rays} in {record['seconds']:.2f} s", err=True)


def main(args=None) -> None:
    """``python -m aobake.cli.batch``: the same as ``aobake batch``."""
    batch_command().main(args, prog_name="aobake batch")


if __name__ == "__main__":  # pragma: no cover
    main()
