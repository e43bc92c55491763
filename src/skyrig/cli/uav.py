"""``skyrig adjust-uav PROJECT``: GNSS-supported bundle adjustment of a UAV block from ``skyrig match`` tie points
and the images' own EXIF GPS / DJI gimbal metadata (:func:`skyrig.pipeline.uav.adjust_uav`).

Images come from ``PROJECT/images`` if it exists, else PROJECT (or ``--images``); tie points from
``PROJECT/match/tie_points.csv`` (or ``--match``).  Writes ``eo.csv``, ``points.csv`` and ``adjusted.gpkg`` in the
project CRS (``--crs``; default the WGS84 UTM zone of the images' GNSS, ellipsoidal heights; GDAL-readable CSVs with
side-cars, :mod:`skyrig.io.adjust_outputs`), ``report.json``, ``report.html`` and residual plots to
``PROJECT/adjust-uav`` (or ``--out``).

A run whose adjustment cannot be trusted (no convergence, sigma0 not finite, no redundancy, or any other failure
the adjustment states) exits with status 1 (a failed run; 2 is a wrong command line or input, docs/cli.md) and the reason; its outputs are then not published (a previous run's
files stay as they were) unless ``--keep-failed`` is given. The output folder is published as a set
(:func:`skyrig.io.stage.stage_folder`: written in a staging folder next to it, ``manifest.json`` with inputs,
options, version and checksums written last, then swapped into place), so a killed run never leaves a folder
mixing two runs.  Option spellings: ``-o/--output`` (``--out`` deprecated), ``--gnss-sigma E,N,U`` (three
separate numbers deprecated), as every command (docs/cli.md).
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import click

from skyrig.cli._common import parse_sigmas, with_old_spellings

__all__ = ["command"]


class _NotPublished(Exception):
    """A failed run without --keep-failed: the staging folder is dropped, the previous outputs stay."""


@click.command("adjust-uav", cls=with_old_spellings({"--out": "--output"}, {"--gnss-sigma": 3}))
@click.argument("project", type=click.Path(exists=True, file_okay=False))
@click.option("--images", "image_dir", type=click.Path(exists=True, file_okay=False),
              help="Image folder (default PROJECT/images or PROJECT).")
@click.option("--match", "match_dir", type=click.Path(exists=True, file_okay=False),
              help="Output folder of `skyrig match` (default PROJECT/match).")
@click.option("-o", "--output", "--out", "out", type=click.Path(file_okay=False),
              help="Output folder (default PROJECT/adjust-uav), published as a set with manifest.json last "
                   "(--out: deprecated spelling).")
@click.option("--gnss-sigma", default="2,2,4", show_default=True,
              help="GNSS sigma east,north,up (m; one value for all axes); consumer GPS: metres. The old form of "
                   "three separate numbers is deprecated.")
@click.option("--attitude-sigma", type=float, default=5.0, show_default=True,
              help="Sigma of verified gimbal attitudes (deg); 0 = attitudes not observed.")
@click.option("--altitude", type=click.Choice(["egm96", "ellipsoidal"]), default="egm96", show_default=True,
              help="Reference of the EXIF GPS altitude (DJI: EGM96 above mean sea level).")
@click.option("--geoid", help="EGM96 grid (path or PROJ name); default ../shared/data/geoid or PROJ's.")
@click.option("--focal-prior", type=float, default=0.1, show_default=True,
              help="Relative sigma of the EXIF focal length prior.")
@click.option("--no-self-calibration", is_flag=True, help="Keep the EXIF camera fixed.")
@click.option("--compare-pycolmap", is_flag=True,
              help="Also run pycolmap's own pipeline on the images and compare camera centres.")
@click.option("--pycolmap-size", type=int, default=1600, show_default=True,
              help="pycolmap comparison: SIFT on images downscaled to this.")
@click.option("--pycolmap-mapper", type=click.Choice(["incremental", "global"]), default="incremental",
              show_default=True, help="pycolmap comparison: COLMAP incremental or GLOMAP global mapper.")
@click.option("--crs", "crs", default=None,
              help="Project CRS of the outputs (a compound CRS such as EPSG:32630+5773 gives orthometric heights "
                   "through its geoid); default: the UTM zone of the images' GNSS, ellipsoidal heights.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False),
              help="JSON file of UavConfig options (overrides the options above).")
@click.option("--keep-failed", is_flag=True,
              help="Write the outputs even when the adjustment failed (the exit status is still 1).")
def command(project: str, image_dir: str | None, match_dir: str | None, out: str | None,
            gnss_sigma: str, attitude_sigma: float, altitude: str, geoid: str | None,
            focal_prior: float, no_self_calibration: bool, compare_pycolmap: bool, pycolmap_size: int,
            pycolmap_mapper: str, crs: str | None, config_path: str | None, keep_failed: bool) -> None:
    """GNSS-supported adjustment of the UAV images of PROJECT (tie points from `skyrig match`)."""
    from skyrig.pipeline.uav import UavConfig, adjust_uav

    proj = Path(project)
    images = Path(image_dir) if image_dir else (proj / "images" if (proj / "images").is_dir() else proj)
    match = Path(match_dir) if match_dir else proj / "match"
    if not (match / "tie_points.csv").is_file():
        raise click.UsageError(f"no tie points at {match / 'tie_points.csv'}: run `skyrig match` first")
    outdir = Path(out) if out else proj / "adjust-uav"
    old = click.get_current_context().meta.get("skyrig.old_spellings", {})
    out_option = ("-o/--out" if "--out" in old else "-o/--output") if out else None
    kw: dict = dict(gnss_sigma_m=parse_sigmas(gnss_sigma, 3, "--gnss-sigma", "east,north,up"), attitude_sigma_deg=attitude_sigma or None, altitude=altitude,
                    geoid=geoid, focal_prior_rel=focal_prior)
    if no_self_calibration:
        kw["self_calibration"] = ()
    if config_path:
        from skyrig.errors import InputFormatError
        from skyrig.io._text import read_text

        try:
            kw.update(json.loads(read_text(config_path)))
        except json.JSONDecodeError as exc:
            raise InputFormatError(f"not JSON ({exc.msg})", config_path, exc.lineno) from None
    cfg = UavConfig.from_dict(kw, str(config_path or "options"))
    if crs is not None:
        from skyrig.errors import CRSError
        from skyrig.geodesy.statement import project_frame

        try:
            project_frame(crs)
        except CRSError as e:
            raise click.BadParameter(str(e), param_hint="--crs") from None
    from skyrig.errors import OutputPathError
    from skyrig.io.image_read import list_images
    from skyrig.io.stage import describe_inputs, stage_folder

    _staging_dir(outdir, out_option, probe=True)
    inputs = [match / "tie_points.csv", *list_images(images)] + ([Path(config_path)] if config_path else [])
    options = {"project": str(proj), "images": str(images), "match": str(match), "output": str(outdir),
               "gnss_sigma_m": list(kw["gnss_sigma_m"]), "attitude_sigma_deg": attitude_sigma, "altitude": altitude,
               "geoid": geoid, "focal_prior": focal_prior, "self_calibration": not no_self_calibration,
               "compare_pycolmap": compare_pycolmap, "crs": crs, "config": config_path, "keep_failed": keep_failed}
    failures: list[str] = []
    try:
        with stage_folder(outdir, stage="adjust-uav", inputs=describe_inputs(inputs), options=options) as staging:
            res, rep = adjust_uav(images, match, staging, cfg, staging / "pycolmap" if compare_pycolmap else None,
                                  pycolmap_max_image_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper, crs=crs)
            if (staging / "report.html").is_file():  # the pipeline's plain page -> the full report (skyrig.report)
                from skyrig.report import report_data_from_uav, write_report

                write_report(staging / "report.html", report_data_from_uav(
                    res, rep, inputs=[match / "tie_points.csv", *list_images(images)], options=rep["uav"]["config"]))
            failures = failure_reasons(res.adjustment)
            _echo_summary(rep, outdir)
            if failures and not keep_failed:
                raise _NotPublished
    except _NotPublished:
        pass
    except OutputPathError as exc:
        raise (exc.with_option(out_option) if out_option and exc.option is None else exc) from None
    if failures:
        kept = (f"outputs kept in {outdir} (--keep-failed)" if keep_failed
                else "no outputs written (--keep-failed writes them anyway)")
        click.echo("error: the UAV adjustment failed: " + "; ".join(failures) + f"; {kept}", err=True)
        raise SystemExit(1)
    click.echo(f"{rep['uav']['total_wall_s']:.1f} s; written to {outdir}")


def failure_reasons(adj: Any) -> list[str]:
    """Why an adjustment result must not be trusted, in words (empty when it can).

    The adjustment's own ``failures`` when it states them; otherwise no convergence, a sigma0 that is not
    finite, or no redundancy.
    """
    stated = getattr(adj, "failures", None)
    if stated is not None:
        return [str(f) for f in stated]
    out = []
    info = adj.info
    if not info.converged:
        out.append(f"did not converge ({info.message}; {info.iterations} iterations)")
    if not math.isfinite(float(adj.sigma0)):
        out.append(f"sigma0 is {float(adj.sigma0)} (not finite)")
    if int(adj.redundancy) <= 0:
        out.append(f"no redundancy ({int(adj.redundancy)} observations more than unknowns)")
    return out


def _staging_dir(outdir: Path, option: str | None, probe: bool = False) -> Path:
    """An empty folder next to ``outdir`` (same file system, so that publishing is a rename); with ``probe`` only
    check that one can be made (errors name ``option``) and return ``outdir``."""
    from skyrig.io._text import OutputPathError, check_output_dir

    try:
        check_output_dir(outdir, create=False)
        check_output_dir(outdir.parent)
        if probe:
            return outdir
        return Path(tempfile.mkdtemp(prefix=f".{outdir.name}.staging-", dir=outdir.parent))
    except OutputPathError as exc:
        raise (exc.with_option(option) if option else exc) from None
    except OSError as exc:
        err = OutputPathError(f"cannot write next to it ({exc.strerror or exc})", outdir)
        raise (err.with_option(option) if option else err) from None


def _echo_summary(rep: dict[str, Any], outdir: Path) -> None:
    s = rep["uav"]
    click.echo(f"{s['oriented']}/{s['images']} images oriented, {s['tie_points']} tie points, "
               f"reprojection RMS {s['reprojection_rms_px']:.3f} px, sigma0 {s['sigma0']:.3f}, "
               f"GNSS fit RMS (E, N, U) " + ", ".join(f"{v:.2f}" for v in s["gnss_fit_rms_enu_m"]) + " m")
    if s["not_oriented"]:
        click.echo("not oriented: " + ", ".join(s["not_oriented"]))
    bad = {k: v for k, v in s["attitude_check"].items() if str(v.get("metadata", "")).startswith("rejected")}
    for k, v in bad.items():
        dev = v.get("metadata_vs_adjusted_deg", float("nan"))
        click.echo(f"{k}: metadata attitude rejected (differs by {dev:.1f} deg from the adjusted one)")
    if "pycolmap" in rep and "centre_differences" in rep["pycolmap"]:
        c = rep["pycolmap"]["centre_differences"]
        click.echo(f"pycolmap: {rep['pycolmap']['registered']} images, reprojection RMS "
                   f"{rep['pycolmap']['reprojection_rms_px']:.3f} px; centre differences after similarity "
                   f"RMS {c['rms_m']:.3f} m, max {c['max_m']:.3f} m")


if __name__ == "__main__":  # until the lead registers it: python -m skyrig.cli.uav PROJECT ...
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command()
