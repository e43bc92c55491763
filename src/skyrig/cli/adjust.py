"""``skyrig adjust BLOCK --preset NAME -o OUTDIR``: bundle adjustment / integrated sensor orientation.

Writes into OUTDIR: the adjusted block (``adjusted.json`` + tables, same format as the input, in the block's
tangential frame), and in the project CRS (``--crs``; default the block file's ``crs``, the frame of its control
points or EO; else the UTM zone of the block) with the vertical reference stated: the adjusted exterior
orientations (``eo.csv``), points (``points.csv``), control / check points with their residuals
(``ground_control.csv``), all as GDAL-readable CSVs with side-cars, the same as GeoPackage layers
(``adjusted.gpkg``, :mod:`skyrig.io.adjust_outputs`), and ``report.json`` / ``report.html`` (the
self-contained report of :mod:`skyrig.report`; control / check tables in the project CRS).  Also :func:`adjust_demo_project` for ``make demo``.
A thin shim over :func:`skyrig.pipeline.orientation.run_adjustment` / :func:`~skyrig.pipeline.orientation.write_adjustment`
(which the project's ``adjust`` stage calls through :func:`~skyrig.pipeline.orientation.make_adjustment`).

OUTDIR is published as a set (:func:`skyrig.io.stage.stage_folder`): the outputs are written into a staging
folder next to it, ``manifest.json`` (inputs with SHA-256, options, version, every output's checksum) last, then
swapped into place - a killed run leaves the previous OUTDIR as it was (or none), never a mixed one; the staging
folders killed runs left are removed by the next run.  A failed adjustment publishes nothing (exit status 1)
unless ``--keep-failed``.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from skyrig.cli._types import GSD_M

from skyrig.adjust.presets import PRESETS
# the library functions this command calls, importable from here as before
from skyrig.pipeline.orientation import adjust_demo_project, default_project, write_outputs  # noqa: F401

__all__ = ["command", "adjust_demo_project", "write_outputs"]


def _adjust_cmd_class() -> type[click.Command]:
    from skyrig.cli._common import with_old_spellings

    return with_old_spellings({"--outdir": "--output"})


@click.command("adjust", cls=_adjust_cmd_class())
@click.argument("block_path", metavar="BLOCK", type=click.Path(exists=True, dir_okay=False))
@click.option("--preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Paper 004 variant, merged with the block file's 'adjustment' section (groups freed there stay "
                   "free; a field the preset decides overrides the file, with a warning); default: the section alone.")
@click.option("--gsd", type=GSD_M, default=None, help="Ground sampling distance (m) for RMS in GSD units.")
@click.option("-o", "--output", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder, published as a set with manifest.json (--outdir: deprecated spelling).")
@click.option("--crs", "crs", default=None,
              help="Project CRS of the outputs (e.g. EPSG:25832; a compound CRS such as EPSG:25832+5773 gives "
                   "orthometric heights through its geoid). Default: the block file's 'crs' (skyrig block: the "
                   "control points' CRS), else the UTM zone of the block.")
@click.option("--geoid", default=None, help="With --crs: geoid grid (path or PROJ name) for orthometric heights.")
@click.option("--keep-failed", is_flag=True, default=False,
              help="Write the outputs even when the adjustment failed (no convergence, sigma0 not finite, no "
                   "redundancy, a single image, data snooping at its cap or rejecting most of a GNSS/IMU group); "
                   "the exit status is non-zero either way.")
def command(block_path: str, preset: str | None, gsd: float | None, outdir: str, crs: str | None, geoid: str | None,
            keep_failed: bool) -> None:
    """Adjust a block file (docs/formats/block.md) and write the adjusted EO, points and report.

    Exits with status 1 and the reasons in words when the adjustment failed; nothing is written then
    unless --keep-failed is given.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from skyrig.io.stage import clean_stale, describe_inputs, stage_folder
    from skyrig.pipeline.orientation import adjustment_inputs, run_adjustment, write_adjustment

    started = time.time()
    clean_stale(outdir, started)  # what killed runs left next to OUTDIR
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                  TimeElapsedColumn(), transient=False) as prog:
        task = prog.add_task("adjusting", total=None, info="")

        def cb(stage: str, it: int, cost: float) -> None:
            prog.update(task, completed=it, description=stage, info=f"iteration {it} cost {cost:.6g}")

        res = run_adjustment(block_path, preset=preset, gsd=gsd, crs=crs, geoid=geoid, keep_failed=keep_failed,
                             callback=cb)
    for n in res.notices:
        click.echo(f"warning: {n}", err=True)
    paths: dict[str, Path] = {}
    if res.ok or keep_failed:
        inputs = adjustment_inputs(block_path)
        with stage_folder(outdir, stage="adjust", inputs=describe_inputs(inputs),
                          options=dict(res.options, ok=res.ok), started=started) as tmp:
            staged = write_adjustment(res, tmp)
        paths = {k: Path(outdir) / p.relative_to(tmp) for k, p in staged.items()}
        paths["manifest"] = Path(outdir) / "manifest.json"
    res.paths = paths
    click.echo(res.summary_line())
    for w in res.warnings:
        click.echo(f"warning: {w}", err=True)
    if not res.ok:
        raise click.ClickException(
            f"{block_path}: the adjustment failed: " + "; ".join(res.failures)
            + ("" if keep_failed else " (nothing written; --keep-failed writes the outputs anyway)"))
