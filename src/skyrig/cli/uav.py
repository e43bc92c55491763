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

Without GNSS (``--no-gps``; implied by ``--control``, ``--check``, ``--scale-bar``, ``--camera``, ``--measurements`` and
``--datum``): terrestrial, close-range or any image set whose GPS is missing or not to be trusted is oriented from a
two-view relative orientation, resection and bundle adjustment (:func:`skyrig.orient.incremental.orient_incremental`
through :func:`skyrig.pipeline.uav.orient_without_gnss`).  The datum (``--datum``, default ``auto``): control points
(``--control`` ``name,x,y,z`` with a ``# crs:`` header; their image measurements are tie points of the same name or
``--measurements`` files), scale bars (``--scale-bar`` CSV ``from,to,length_m[,sigma_m]``), a similarity onto the
images' EXIF GPS (``gps-similarity``: the GPS places the finished block, it is not an observation), or a free network
(inner constraints, scale of the start base).  ``--camera`` (rig YAML / IGN .txt) replaces the EXIF camera, and
without image files the image names come from the tie points.  Same outputs as with GNSS; with a scale-bar or free
datum ``eo.csv`` / ``points.csv`` are plain tables in an arbitrary frame (``#`` lines say so) and there is no
``adjusted.gpkg``.  A set that cannot be oriented (no start pair, control not measured...) exits 1.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
from pathlib import Path
from typing import Any

import click

from skyrig.cli._common import parse_sigmas, with_old_spellings

__all__ = ["command"]


class _NotPublished(Exception):
    """A failed run without --keep-failed: the staging folder is dropped, the previous outputs stay."""


@click.command("adjust-uav", cls=with_old_spellings({"--out": "--output", "--gcp": "--control",
                                                    "--gcp-sigma": "--control-sigma"}, {"--gnss-sigma": 3}))
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
@click.option("--no-gps", is_flag=True,
              help="Orient without GNSS: two-view relative orientation, resection and bundle adjustment; datum from "
                   "--control, --scale-bar, else a similarity onto the EXIF GPS (not observations), else a free network. "
                   "Implied by --control, --scale-bar, --camera.")
@click.option("--control", "gcp_path", type=click.Path(exists=True, dir_okay=False),
              help="Control points name,x,y,z with a '# crs:' header (their image measurements: tie points of the "
                   "same name, or --measurements).")
@click.option("--control-sigma", "gcp_sigma", default="0.01", show_default=True,
              help="Control point sigma X,Y,Z (m; one value for all).")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False),
              help="Check points name,x,y,z (compared, not used).")
@click.option("--scale-bar", "scale_bar_path", type=click.Path(exists=True, dir_okay=False),
              help="Scale bars: CSV from,to,length_m[,sigma_m] (ends named as tie points / --measurements).")
@click.option("--measurements", "meas_paths", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Extra image measurements point,image,column,row (targets, scale-bar ends); repeatable.")
@click.option("--camera", "camera_path", type=click.Path(exists=True, dir_okay=False),
              help="Start camera (rig YAML with one head, or IGN camera .txt) instead of the EXIF focal length.")
@click.option("--datum", type=click.Choice(["auto", "control", "scale-bar", "gps-similarity", "free"]), default="auto",
              show_default=True, help="Without GNSS: what fixes the datum (auto: control, else scale bars, else "
                                      "a similarity onto EXIF GPS, else a free network).")
def command(project: str, image_dir: str | None, match_dir: str | None, out: str | None,
            gnss_sigma: str, attitude_sigma: float, altitude: str, geoid: str | None,
            focal_prior: float, no_self_calibration: bool, compare_pycolmap: bool, pycolmap_size: int,
            pycolmap_mapper: str, crs: str | None, config_path: str | None, keep_failed: bool, no_gps: bool = False,
            gcp_path: str | None = None, gcp_sigma: str = "0.01", check_path: str | None = None,
            scale_bar_path: str | None = None, meas_paths: tuple[str, ...] = (), camera_path: str | None = None,
            datum: str = "auto") -> None:
    """GNSS-supported adjustment of the UAV images of PROJECT (tie points from `skyrig match`); with --no-gps
    (or --control / --scale-bar / --camera) the orientation of an image set without GNSS."""
    from skyrig.pipeline.uav import UavConfig, adjust_uav

    proj = Path(project)
    images = Path(image_dir) if image_dir else (proj / "images" if (proj / "images").is_dir() else proj)
    match = Path(match_dir) if match_dir else proj / "match"
    if not (match / "tie_points.csv").is_file():
        raise click.UsageError(f"no tie points at {match / 'tie_points.csv'}: run `skyrig match` first")
    outdir = Path(out) if out else proj / "adjust-uav"
    old = click.get_current_context().meta.get("skyrig.old_spellings", {})
    out_option = ("-o/--out" if "--out" in old else "-o/--output") if out else None
    if no_gps or gcp_path or scale_bar_path or camera_path or check_path or meas_paths or datum != "auto":
        _without_gnss(proj, images, match, outdir, out_option, dict(
            altitude=altitude, geoid=geoid, focal_prior=focal_prior, no_self_calibration=no_self_calibration,
            compare_pycolmap=compare_pycolmap, pycolmap_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper,
            crs=crs, config=config_path, keep_failed=keep_failed, gcp=gcp_path, gcp_sigma=gcp_sigma,
            check=check_path, scale_bar=scale_bar_path, measurements=list(meas_paths), camera=camera_path,
            datum=datum))
        return
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


def _without_gnss(proj: Path, images: Path, match: Path, outdir: Path, out_option: str | None,
                  o: dict[str, Any]) -> None:
    """``--no-gps``: :func:`skyrig.pipeline.uav.orient_without_gnss`, published like the GNSS adjustment."""
    from skyrig.errors import InputFormatError, OutputPathError
    from skyrig.io.image_read import list_images
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.orient.incremental import OrientConfig, OrientError
    from skyrig.pipeline.uav import UavConfig, orient_without_gnss, read_scale_bars

    kw: dict[str, Any] = {"pixel_sigma_px": 1.0, "focal_prior_rel": o["focal_prior"],
                          "datum": {"gps-similarity": "positions"}.get(o["datum"], o["datum"])}
    if o["no_self_calibration"]:
        kw["self_calibration"] = ()
    if o["config"]:
        from skyrig.io._text import read_text

        try:
            kw.update(json.loads(read_text(o["config"])))
        except json.JSONDecodeError as exc:
            raise InputFormatError(f"not JSON ({exc.msg})", o["config"], exc.lineno) from None
    try:
        cfg = OrientConfig.from_dict(kw, str(o["config"] or "options"))
    except (ValueError, TypeError) as exc:
        raise click.BadParameter(str(exc), param_hint="--config") from None
    camera = None
    if o["camera"]:
        from skyrig.cli._common import load_cameras

        cams = load_cameras([o["camera"]])
        if len({id(c) for c in cams.values()}) > 1:
            raise click.BadParameter(f"{o['camera']} holds several cameras; give a file with one", param_hint="--camera")
        camera = next(iter(cams.values()))
    control = read_points_csv(o["gcp"]) if o["gcp"] else None
    check = read_points_csv(o["check"], default_frame=control.frame if control else None) if o["check"] else None
    bars = read_scale_bars(o["scale_bar"]) if o["scale_bar"] else None
    extra = [read_measurements_csv(p) for p in o["measurements"]]
    gcp_sigma = parse_sigmas(o["gcp_sigma"], 3, "--control-sigma", "x,y,z")
    have_images = bool(list_images(images)) if images.is_dir() else False
    _staging_dir(outdir, out_option, probe=True)
    inputs = [match / "tie_points.csv", *(list_images(images) if have_images else [])] + [
        Path(p) for p in (o["gcp"], o["check"], o["scale_bar"], o["camera"], o["config"], *o["measurements"]) if p]
    options = {"project": str(proj), "images": str(images), "match": str(match), "output": str(outdir),
               "no_gps": True, **{k: v for k, v in o.items()}}
    failures: list[str] = []
    try:
        with stage_folder(outdir, stage="adjust-uav", inputs=describe_inputs(inputs), options=options) as staging:
            res, rep = orient_without_gnss(
                images if have_images else None, match, staging, cfg, camera, control, gcp_sigma, check, bars, extra,
                use_gps=True, pycolmap_workdir=staging / "pycolmap" if o["compare_pycolmap"] else None,
                pycolmap_max_image_size=o["pycolmap_size"], pycolmap_mapper=o["pycolmap_mapper"], crs=o["crs"],
                altitude_cfg=UavConfig(altitude=o["altitude"], geoid=o["geoid"]),
                sources={"control": o["gcp"], "check": o["check"], "scale_bars": o["scale_bar"]})
            if (staging / "report.html").is_file():
                from skyrig.report import report_data_from_uav, write_report

                write_report(staging / "report.html", report_data_from_uav(
                    res, rep, inputs=inputs, options=rep["uav"]["config"],
                    title="skyrig orientation without GNSS"))
            failures = failure_reasons(res.adjustment)
            s = rep["uav"]
            click.echo(f"{s['oriented']}/{s['images']} images oriented (start pair {', '.join(s['seed']['images'])}), "
                       f"{s['tie_points']} tie points, reprojection RMS {s['reprojection_rms_px']:.3f} px, sigma0 "
                       f"{s['sigma0']:.3f}, datum {s['datum']['kind']}")
            if s["not_oriented"]:
                click.echo("not oriented: " + ", ".join(s["not_oriented"]))
            d = s["datum"]
            if "positions_similarity_rms_3d_m" in d:
                click.echo(f"similarity onto the EXIF GPS: RMS {d['positions_similarity_rms_3d_m']:.2f} m, max "
                           f"{d['positions_similarity_max_m']:.2f} m over {d['images_with_positions']} images")
            if "scale_bar_residuals_m" in s:
                click.echo("scale-bar residuals (m): " + ", ".join(f"{v:.4f}" for v in s["scale_bar_residuals_m"]))
            if "control_fit_rms_xyz_m" in s:
                click.echo("control fit RMS x, y, z (m): " + ", ".join(f"{v:.4f}" for v in s["control_fit_rms_xyz_m"]))
            if "pycolmap" in rep and "centre_differences" in rep["pycolmap"]:
                c = rep["pycolmap"]["centre_differences"]
                click.echo(f"pycolmap ({rep['pycolmap']['mapper']}): {rep['pycolmap']['registered']} images; centre "
                           f"differences after similarity RMS {c['rms_m']:.3f}, max {c['max_m']:.3f}")
            if failures and not o["keep_failed"]:
                raise _NotPublished
    except _NotPublished:
        pass
    except OutputPathError as exc:
        raise (exc.with_option(out_option) if out_option and exc.option is None else exc) from None
    except OrientError as exc:  # the data could not be oriented: a failed run (1), not a wrong input (2)
        click.echo(f"error: the orientation failed: {exc}; no outputs written", err=True)
        raise SystemExit(1) from None
    if failures:
        kept = (f"outputs kept in {outdir} (--keep-failed)" if o["keep_failed"]
                else "no outputs written (--keep-failed writes them anyway)")
        click.echo("error: the orientation failed: " + "; ".join(failures) + f"; {kept}", err=True)
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
