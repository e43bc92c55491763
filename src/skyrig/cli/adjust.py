"""``skyrig adjust BLOCK --preset NAME -o OUTDIR``: bundle adjustment / integrated sensor orientation.

Writes into OUTDIR: the adjusted block (``adjusted.json`` + tables, same format as the input), the
adjusted exterior orientations (``eo.csv``, skyrig EO CSV) and points (``points.csv``) when the block's
frame is a local ENU frame (``local ENU at lat .. lon .. h ..``), and ``report.json`` / ``report.html``
/ ``residuals_*.png``.  Also :func:`adjust_demo_project` for ``make demo``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import click
import numpy as np

from skyrig.adjust import AdjustmentResult, adjust
from skyrig.adjust.presets import PRESETS, apply_preset, merge_preset
from skyrig.adjust.report import adjustment_report
from skyrig.georef.eo import WorldFrame

__all__ = ["command", "adjust_demo_project", "write_outputs"]

_LOCAL = re.compile(r"local ENU at lat ([-\d.eE+]+) lon ([-\d.eE+]+) h ([-\d.eE+]+)")


def _frame(desc: str) -> WorldFrame | None:
    m = _LOCAL.search(desc or "")
    return None if m is None else WorldFrame.local(float(m.group(1)), float(m.group(2)), float(m.group(3)))


def write_outputs(outdir: str | Path, result: AdjustmentResult, config: Any, title: str,
                  gsd_m: float | None = None, frame: WorldFrame | None = None,
                  to: WorldFrame | None = None) -> dict[str, Path]:
    """Adjusted block, EO CSV, points CSV (when the frame is known) and the report; returns the paths."""
    from skyrig.adjust.frames import eo_from_block, points_to_frame
    from skyrig.georef.observations import GroundPoints
    from skyrig.io.block_file import write_block
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.points_csv import write_points_csv
    from skyrig.io.report_html import write_report

    d = Path(outdir)
    d.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    b = result.block
    from skyrig.camera.frame import FrameCamera

    if all(isinstance(c, FrameCamera) for c in b.cameras):
        write_block(d / "adjusted.json", b, config)
        out["block"] = d / "adjusted.json"
    frame = frame or _frame(b.frame)
    if frame is not None:
        eo = eo_from_block(b, frame, to)
        write_eo_csv(eo, d / "eo.csv")
        xyz = b.point_xyz if to is None else points_to_frame(b.point_xyz, frame, to)
        ps = result.point_sigma
        extra = {} if ps is None else {"sx": ps[:, 0], "sy": ps[:, 1], "sz": ps[:, 2]}
        write_points_csv(d / "points.csv", GroundPoints(b.point_name, xyz, to or frame), extra)
        out["eo"], out["points"] = d / "eo.csv", d / "points.csv"
    rep = adjustment_report(result, gsd_m=gsd_m)
    out.update(write_report(d, result, rep, title))
    return out


@click.command("adjust")
@click.argument("block_path", metavar="BLOCK", type=click.Path(exists=True, dir_okay=False))
@click.option("--preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="Paper 004 variant, merged with the block file's 'adjustment' section (groups freed there stay "
                   "free; a field the preset decides overrides the file, with a warning); default: the section alone.")
@click.option("--gsd", type=float, default=None, help="Ground sampling distance (m) for RMS in GSD units.")
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--keep-failed", is_flag=True, default=False,
              help="Write the outputs even when the adjustment failed (no convergence, sigma0 not finite, no "
                   "redundancy, a single image, data snooping at its cap or rejecting most of a GNSS/IMU group); "
                   "the exit status is non-zero either way.")
def command(block_path: str, preset: str | None, gsd: float | None, outdir: str, keep_failed: bool) -> None:
    """Adjust a block file (docs/formats/block.md) and write the adjusted EO, points and report.

    Exits with status 1 and the reasons in words when the adjustment failed; nothing is written then
    unless --keep-failed is given.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from skyrig.io.block_file import read_block

    bf = read_block(block_path)
    block, cfg = bf.block, bf.config
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
    paths = write_outputs(outdir, res, cfg, title, gsd) if res.ok or keep_failed else {}
    click.echo(f"sigma0 {res.sigma0:.3f}, {res.info.iterations} iterations ({res.info.message}), "
               f"{len(res.rejected)} rejected; "
               + (f"wrote {', '.join(str(p) for p in paths.values())}" if paths else "no outputs written"))
    for w in own:
        click.echo(f"warning: {w}")
    if not res.ok:
        raise click.ClickException(
            f"{block_path}: the adjustment failed: " + "; ".join(res.failures)
            + ("" if keep_failed else " (nothing written; --keep-failed writes the outputs anyway)"))


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
