"""``skyrig adjust BLOCK --preset NAME -o OUTDIR``: bundle adjustment / integrated sensor orientation.

Writes into OUTDIR: the adjusted block (``adjusted.json`` + tables, same format as the input, in the block's
tangential frame), and in the project CRS (``--crs``; default the block file's ``crs``, the frame of its control
points or EO; else the UTM zone of the block) with the vertical reference stated: the adjusted exterior
orientations (``eo.csv``), points (``points.csv``), control / check points with their residuals
(``ground_control.csv``), all as GDAL-readable CSVs with side-cars, the same as GeoPackage layers
(``adjusted.gpkg``, :mod:`skyrig.io.adjust_outputs`), and ``report.json`` / ``report.html`` (the
self-contained report of :mod:`skyrig.report`; control / check tables in the project CRS).  Also :func:`adjust_demo_project` for ``make demo``.

OUTDIR is published as a set (:func:`skyrig.io.stage.stage_folder`): the outputs are written into a staging
folder next to it, ``manifest.json`` (inputs with SHA-256, options, version, every output's checksum) last, then
swapped into place - a killed run leaves the previous OUTDIR as it was (or none), never a mixed one; the staging
folders killed runs left are removed by the next run.  A failed adjustment publishes nothing (exit status 1)
unless ``--keep-failed``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import click
import numpy as np

from skyrig.adjust import AdjustmentResult, adjust
from skyrig.adjust.presets import PRESETS, apply_preset, merge_preset
from skyrig.adjust.report import adjustment_report
from skyrig.georef.eo import WorldFrame

__all__ = ["command", "adjust_demo_project", "write_outputs"]


def _frame(desc: str) -> WorldFrame | None:
    """The block's frame from its text (None for a free-text description)."""
    from skyrig.errors import CRSError

    try:
        return WorldFrame.from_text(desc or "")
    except (CRSError, ValueError):
        return None


def default_project(frame: WorldFrame) -> WorldFrame:
    """The project frame when none is given: a map frame as it is, else the UTM zone (WGS84, ellipsoidal heights)
    at the frame's origin (local) or at the ellipsoid point under its origin (ECEF: lat 0, lon 0)."""
    from skyrig.geodesy.statement import utm_frame

    if frame.kind == "map":
        return frame
    if frame.kind == "local":
        return utm_frame(frame.origin[0], frame.origin[1])  # type: ignore[index]
    return utm_frame(0.0, 0.0)


def write_outputs(outdir: str | Path, result: AdjustmentResult, config: Any, title: str,
                  gsd_m: float | None = None, frame: WorldFrame | None = None,
                  to: WorldFrame | None = None, inputs: Any = (), options: dict[str, Any] | None = None,
                  rig_file: str | Path | None = None) -> dict[str, Path]:
    """Adjusted block, then in the project frame ``to`` (default :func:`default_project` of the block's frame)
    the EO, points and ground-control CSVs and GeoPackage (:func:`skyrig.io.adjust_outputs.write_adjusted_tables`,
    when the block's frame is known) and the report; returns the paths.

    ``rig_file``: the rig file defining the block's actuated heads (a block with a tumbling head needs it); the
    adjusted block names it by its path relative to ``outdir``'s parent folder joined with ``outdir``'s name
    (the same from a staging folder next to the published one)."""
    from skyrig.camera.frame import FrameCamera
    from skyrig.io.adjust_outputs import write_adjusted_tables
    from skyrig.io.block_file import write_block
    from skyrig.report import write_adjustment_report

    d = Path(outdir)
    d.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    b = result.block
    frame = frame or _frame(b.frame)
    project = None if frame is None else (to or default_project(frame))
    if all(isinstance(c, FrameCamera) for c in b.cameras):
        rel = None if rig_file is None else os.path.relpath(Path(rig_file).resolve(), d.resolve())
        write_block(d / "adjusted.json", b, config, rig_file=rel, crs=project)
        out["block"] = d / "adjusted.json"
    if frame is not None and project is not None:
        out.update(write_adjusted_tables(d, result, frame, project))
    rep = adjustment_report(result, gsd_m=gsd_m, frames=None if project is None else (frame, project))
    out.update(write_adjustment_report(d, result, rep, title, frame=frame, map_frame=project, inputs=inputs,
                                       options=options or {}))
    return out


def _adjust_cmd_class() -> type[click.Command]:
    from skyrig.cli._common import with_old_spellings

    return with_old_spellings({"--outdir": "--output"})


@click.command("adjust", cls=_adjust_cmd_class())
@click.argument("block_path", metavar="BLOCK", type=click.Path(exists=True, dir_okay=False))
@click.option("--preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Paper 004 variant, merged with the block file's 'adjustment' section (groups freed there stay "
                   "free; a field the preset decides overrides the file, with a warning); default: the section alone.")
@click.option("--gsd", type=float, default=None, help="Ground sampling distance (m) for RMS in GSD units.")
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

    from skyrig.io.block_file import read_block
    from skyrig.io.stage import clean_stale

    started = time.time()
    clean_stale(outdir, started)  # what killed runs left next to OUTDIR
    bf = read_block(block_path)
    rig_file = _rig_of(block_path)
    block, cfg = bf.block, bf.config
    from skyrig.cli._common import project_frame_option

    given = project_frame_option(crs, geoid)
    project = given if given is not None else bf.crs
    if bf.frame is None:
        click.echo(f"warning: {block_path}: the block's frame {block.frame!r} is not a frame skyrig knows; EO and "
                   "points are not written (only the adjusted block and the report)", err=True)
    title = f"skyrig adjust {Path(block_path).name}"
    conflicts: list[str] = []
    if preset:
        # the preset decides the variant; the groups the block file frees (skyrig block --free) stay free
        cfg, conflicts = merge_preset(preset, cfg, bf.adjustment_keys, bool(len(block.gnss_station)))
        block, _ = apply_preset(block, preset)
        title += f" - {PRESETS[preset].title}"
        for c in conflicts:
            click.echo(f"warning: {c}", err=True)
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[info]}"),
                  TimeElapsedColumn(), transient=False) as prog:
        task = prog.add_task("adjusting", total=cfg.max_iterations, info="")

        def cb(stage: str, it: int, cost: float) -> None:
            prog.update(task, completed=it, description=stage, info=f"iteration {it} cost {cost:.6g}")

        res = adjust(block, cfg, callback=cb)
        prog.update(task, completed=cfg.max_iterations)
    own = list(res.warnings)
    # the report states the preset conflicts and the failure too
    res.warnings[:0] = [f"the adjustment FAILED: {f}" for f in res.failures] + conflicts
    if not res.ok:
        title += " - FAILED"
    from skyrig.report import block_file_inputs

    opts = dict(block=block_path, preset=preset, gsd=gsd, crs=crs, geoid=geoid, keep_failed=keep_failed)
    paths: dict[str, Path] = {}
    if res.ok or keep_failed:
        from skyrig.io.stage import describe_inputs, stage_folder

        inputs = block_file_inputs(block_path) + ([Path(rig_file)] if rig_file else [])
        with stage_folder(outdir, stage="adjust", inputs=describe_inputs(inputs),
                          options=dict(opts, ok=res.ok), started=started) as tmp:
            staged = write_outputs(tmp, res, cfg, title, gsd, bf.frame, project, inputs=inputs, options=opts,
                                   rig_file=rig_file)
        paths = {k: Path(outdir) / p.relative_to(tmp) for k, p in staged.items()}
        paths["manifest"] = Path(outdir) / "manifest.json"
    click.echo(f"sigma0 {res.sigma0:.3f}, {res.info.iterations} iterations ({res.info.message}), "
               f"{len(res.rejected)} rejected; "
               + (f"wrote {', '.join(str(p) for p in paths.values())}" if paths else "no outputs written"))
    for w in own:
        click.echo(f"warning: {w}", err=True)
    if not res.ok:
        raise click.ClickException(
            f"{block_path}: the adjustment failed: " + "; ".join(res.failures)
            + ("" if keep_failed else " (nothing written; --keep-failed writes the outputs anyway)"))


def _rig_of(block_path: str) -> str | None:
    """The rig file a block file's manifest names (key ``rig``: blocks with actuated heads), as a path."""
    import json

    try:
        rig = json.loads(Path(block_path).read_text(encoding="utf-8-sig")).get("rig")
    except (OSError, ValueError, AttributeError):
        return None
    return None if not rig else str(Path(block_path).parent / str(rig))


def adjust_demo_project(paths: Any, outdir: str | Path, preset: str = "ba-eo-control", seed: int = 0,
                        sigma_px: float = 0.5, gnss_sigma_m: float = 0.05, imu_sigma_deg: float = 0.005,
                        start_perturb_m: float = 1.0, start_perturb_deg: float = 0.05) -> dict[str, Path]:
    """Adjust the demo flight after ``skyrig georef`` and ``skyrig world-to-image`` have run.

    Builds a block from the demo's EO (``paths.eo``, entering as GNSS/IMU observations with noise of
    ``gnss_sigma_m`` / ``imu_sigma_deg``), the check points' image positions (``paths.image_points``,
    with Gaussian noise ``sigma_px``) and the check points (every other one is control, the rest
    check), starts from orientations perturbed by ``start_perturb_m`` / ``start_perturb_deg``, adjusts
    it with ``preset`` and writes the outputs of :func:`write_outputs` into ``outdir`` (EO and points
    in the demo's map CRS).  Seeded: the same call gives the same report.
    """
    from dataclasses import replace

    from skyrig.adjust.frames import block_from_georef
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_rig

    rng = np.random.default_rng(seed)
    eo = read_eo_csv(paths.eo)
    rig = read_rig(paths.rig)
    cams = {h.camera.name: h.camera for h in rig.heads.values()}
    m = read_measurements_csv(paths.image_points)
    m = ImageMeasurements(m.point, m.image, m.pixel + rng.normal(0, sigma_px, m.pixel.shape))
    gp = read_points_csv(paths.check_points)
    n = len(eo)
    obs = replace(eo, centre=eo.centre + rng.normal(0, gnss_sigma_m, (n, 3)),
                  rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(imu_sigma_deg), (n, 3))))
    start = replace(eo, centre=eo.centre + rng.normal(0, start_perturb_m, (n, 3)),
                    rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(start_perturb_deg), (n, 3))))
    checks = tuple(str(x) for x in gp.name[1::2])
    block, frame = block_from_georef(obs, cams, m, GroundPoints(gp.name, gp.xyz, gp.frame), start_eo=start,
                                     gnss_sigma_m=gnss_sigma_m, imu_sigma_rad=np.radians(imu_sigma_deg),
                                     control_sigma_m=0.02, check_points=checks, sigma_px=sigma_px)
    block, cfg = apply_preset(block, preset)
    res = adjust(block, cfg)
    gsd = float(np.median([c.gsd(np.median(eo.centre[:, 2] - gp.xyz[:, 2].mean())) for c in cams.values()]))
    return write_outputs(outdir, res, cfg, f"skyrig demo - {PRESETS[preset].title}", gsd, frame, eo.frame)
