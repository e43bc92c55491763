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

With GNSS and ground control: when the images carry EXIF GPS positions (at least 3 and half of them; the others are
left out with a warning) and neither ``--no-gps``, ``--scale-bar``,
``--camera`` nor ``--datum`` is given, ``--control`` / ``--check`` / ``--measurements`` join the GNSS-supported block
(control with ``--control-sigma``: metre-class targets, e.g. ``1.5,1.5,10``, are weighted as such; check points are
reported in metres and GSD; a point seen in fewer than two images is reported and left out).

Without GNSS (``--no-gps``; implied by ``--scale-bar``, ``--camera``, ``--datum``, and by ``--control``, ``--check``,
``--measurements`` when the images have no EXIF GPS): terrestrial, close-range or any image set whose GPS is missing or not to be trusted is oriented from a
two-view relative orientation, resection and bundle adjustment (:func:`skyrig.orient.incremental.orient_incremental`
through :func:`skyrig.pipeline.uav.orient_without_gnss`).  The datum (``--datum``, default ``auto``): control points
(``--control`` ``name,x,y,z`` with a ``# crs:`` header; their image measurements are tie points of the same name or
``--measurements`` files), scale bars (``--scale-bar`` CSV ``from,to,length_m[,sigma_m]``), a similarity onto the
images' EXIF GPS (``gps-similarity``: the GPS places the finished block, it is not an observation), or a free network
(inner constraints, scale of the start base).  ``--camera`` (rig YAML / IGN .txt) replaces the EXIF camera, and
without image files the image names come from the tie points.  Same outputs as with GNSS; with a scale-bar or free
datum ``eo.csv`` / ``points.csv`` are plain tables in an arbitrary frame (``#`` lines say so) and there is no
``adjusted.gpkg``.  A set that cannot be oriented (no start pair, control not measured...) exits 1.

``--compare-pycolmap``: pycolmap orients the set too, on the image files (``--pycolmap-input images``: its own SIFT,
matching and mapper) or on skyrig's tie points (``tracks``: the same measurements; the default without image files),
and ``report.json``'s ``pycolmap`` holds skyrig - pycolmap centres after a similarity (RMS, max, and in units of
skyrig's predicted sigma); docs/cli.md.

A thin shim: the work is :func:`skyrig.pipeline.orientation.make_uav_orientation` (which the project's
``adjust-uav`` stage calls); this module parses the options and publishes the folder as a set.
"""

from __future__ import annotations

import json
import logging
import tempfile
from pathlib import Path
from typing import Any

import click

from skyrig.cli._types import CONTROL_SIGMA_M, CRS_TEXT, GEOID, GNSS_SIGMA_M, NONNEGATIVE, POSITIVE, POSITIVE_INT

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
@click.option("--gnss-sigma", type=GNSS_SIGMA_M, default="2,2,4", show_default=True,
              help="GNSS sigma east,north,up (m; one value for all axes); consumer GPS: metres. The old form of "
                   "three separate numbers is deprecated.")
@click.option("--attitude-sigma", type=NONNEGATIVE, default=5.0, show_default=True,
              help="Sigma of verified gimbal attitudes (deg); 0 = attitudes not observed.")
@click.option("--altitude", type=click.Choice(["egm96", "ellipsoidal"]), default="egm96", show_default=True,
              help="Reference of the EXIF GPS altitude (DJI: EGM96 above mean sea level).")
@click.option("--geoid", type=GEOID, help="EGM96 grid (path or PROJ name); default ../shared/data/geoid or PROJ's.")
@click.option("--focal-prior", type=POSITIVE, default=None,
              help="Relative sigma of the focal length prior (e.g. 0.03). Default: the sigma of the prior's source "
                   "(1 %% vendor XMP calibration, 3 %% EXIF focal with the sensor database, 10 %% 35-mm value, "
                   "50 %% nothing).")
@click.option("--free-intrinsics", default="",
              help="Comma-separated intrinsics (focal_mm, ppx_mm, ppy_mm, k1, k2, p1, p2, k3) left free even when "
                   "the block cannot determine them (default: held at the prior with a warning; the report states "
                   "the choice).")
@click.option("--no-self-calibration", is_flag=True, help="Keep the EXIF camera fixed.")
@click.option("--rolling-shutter", type=click.Choice(["auto", "on", "off"]), default="auto", show_default=True,
              help="Model the rolling shutter (pose change over the readout: velocity per image, readout time with a "
                   "30 +- 20 ms prior). auto: on for cameras known to have one (DJI FC300S/X, FC330, FC220, Mavic "
                   "models, phones), off for others (global or mechanical shutter, e.g. FC6310).")
@click.option("--compare-pycolmap", is_flag=True,
              help="Also orient with pycolmap and compare camera centres after a similarity (RMS, max, in units of "
                   "skyrig's predicted sigma; report.json key pycolmap).")
@click.option("--pycolmap-input", type=click.Choice(["images", "tracks"]), default=None,
              help="pycolmap comparison on: images (its own SIFT, matching and mapper) or tracks (its mapper on "
                   "skyrig's tie points, the same measurements; for sets without image files). Default: images when "
                   "there are image files, else tracks.")
@click.option("--pycolmap-size", type=POSITIVE_INT, default=1600, show_default=True,
              help="pycolmap comparison: SIFT on images downscaled to this.")
@click.option("--pycolmap-mapper", type=click.Choice(["incremental", "global"]), default="incremental",
              show_default=True, help="pycolmap comparison: COLMAP incremental or GLOMAP global mapper.")
@click.option("--crs", "crs", type=CRS_TEXT, default=None,
              help="Project CRS of the outputs (a compound CRS such as EPSG:32630+5773 gives orthometric heights "
                   "through its geoid); default: the UTM zone of the images' GNSS, ellipsoidal heights.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False),
              help="JSON file of UavConfig options (overrides the options above).")
@click.option("--keep-failed", is_flag=True,
              help="Write the outputs even when the adjustment failed (the exit status is still 1).")
@click.option("--no-gps", is_flag=True,
              help="Orient without GNSS: two-view relative orientation, resection and bundle adjustment; datum from "
                   "--control, --scale-bar, else a similarity onto the EXIF GPS (not observations), else a free network. "
                   "Implied by --scale-bar, --camera, --datum (and by --control / --check / --measurements when an image "
                   "has no EXIF GPS; with GPS on the images they join the GNSS-supported block).")
@click.option("--control", "gcp_path", type=click.Path(exists=True, dir_okay=False),
              help="Control points name,x,y,z with a '# crs:' header (their image measurements: tie points of the "
                   "same name, or --measurements).")
@click.option("--control-sigma", "gcp_sigma", type=CONTROL_SIGMA_M, default="0.01", show_default=True,
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
            focal_prior: float | None, free_intrinsics: str, no_self_calibration: bool, compare_pycolmap: bool, pycolmap_input: str | None,
            pycolmap_size: int, pycolmap_mapper: str, crs: str | None, config_path: str | None, keep_failed: bool, no_gps: bool = False,
            gcp_path: str | None = None, gcp_sigma: str = "0.01", check_path: str | None = None,
            scale_bar_path: str | None = None, meas_paths: tuple[str, ...] = (), camera_path: str | None = None,
            datum: str = "auto", rolling_shutter: str = "auto") -> None:
    """GNSS-supported adjustment of the UAV images of PROJECT (tie points from `skyrig match`); with --no-gps
    (or --control / --scale-bar / --camera) the orientation of an image set without GNSS."""
    from skyrig.errors import InputFormatError, OutputPathError
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.orient.incremental import OrientError
    from skyrig.pipeline.orientation import make_uav_orientation, needs_no_gnss

    gs = parse_sigmas(gnss_sigma, 3, "--gnss-sigma", "east,north,up")  # options first: refused before any input
    cs = parse_sigmas(gcp_sigma, 3, "--control-sigma", "x,y,z")
    proj = Path(project)
    images = Path(image_dir) if image_dir else (proj / "images" if (proj / "images").is_dir() else proj)
    match = Path(match_dir) if match_dir else proj / "match"
    if not (match / "tie_points.csv").is_file():
        raise click.UsageError(f"no tie points at {match / 'tie_points.csv'}: run `skyrig match` first")
    outdir = Path(out) if out else proj / "adjust-uav"
    old = click.get_current_context().meta.get("skyrig.old_spellings", {})
    out_option = ("-o/--out" if "--out" in old else "-o/--output") if out else None
    without = needs_no_gnss(no_gps, gcp_path, check_path, scale_bar_path, camera_path, meas_paths, datum, images)
    config = None
    if config_path:
        from skyrig.io._text import read_text

        try:
            config = json.loads(read_text(config_path))
        except json.JSONDecodeError as exc:
            raise InputFormatError(f"not JSON ({exc.msg})", config_path, exc.lineno) from None
    _staging_dir(outdir, out_option, probe=True)
    from skyrig.io.image_read import list_images

    have_images = images.is_dir() and bool(list_images(images))
    inputs = [match / "tie_points.csv", *(list_images(images) if have_images or not without else [])] + [
        Path(p) for p in (gcp_path, check_path, scale_bar_path, camera_path, config_path, *meas_paths) if p]
    options = {"project": str(proj), "images": str(images), "match": str(match), "output": str(outdir)}
    failures: list[str] = []
    res = None
    try:
        with stage_folder(outdir, stage="adjust-uav", inputs=describe_inputs(inputs), options=options) as staging:
            res = make_uav_orientation(
                images if (have_images or not without) else None, match, staging, no_gps=without, gnss_sigma=gs,
                attitude_sigma=attitude_sigma, altitude=altitude, geoid=geoid, focal_prior=focal_prior, free_intrinsics=free_intrinsics,
                self_calibration=not no_self_calibration, config=config, config_source=config_path, crs=crs,
                compare_pycolmap=compare_pycolmap, pycolmap_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper,
                pycolmap_input=pycolmap_input, control=gcp_path, control_sigma=cs, check=check_path, scale_bars=scale_bar_path,
                measurements=meas_paths, camera=camera_path, datum=datum, spell=_spell,
                rolling_shutter=rolling_shutter)
            options.update(res.options, keep_failed=keep_failed)
            for line in res.summary_lines():
                click.echo(line)
            failures = res.failures
            if failures and not keep_failed:
                raise _NotPublished
    except _NotPublished:
        pass
    except OutputPathError as exc:
        raise (exc.with_option(out_option) if out_option and exc.option is None else exc) from None
    except OrientError as exc:  # the data could not be oriented: a failed run (1), not a wrong input (2)
        if not without:
            raise
        click.echo(f"error: the orientation failed: {exc}; no outputs written", err=True)
        raise SystemExit(1) from None
    if failures:
        kept = (f"outputs kept in {outdir} (--keep-failed)" if keep_failed
                else "no outputs written (--keep-failed writes them anyway)")
        what = "orientation" if without else "UAV adjustment"
        hint = ("; a slow but steady solve may need more iterations: max_iterations in a --config JSON file"
                if any("maximum number of iterations" in f for f in failures) else "")
        click.echo(f"error: the {what} failed: " + "; ".join(failures) + f"{hint}; {kept}", err=True)
        raise SystemExit(1)
    if res is not None:
        click.echo(f"{res.report['uav']['total_wall_s']:.1f} s; written to {outdir}")


def _spell(name: str) -> str:
    """How this command names a library option."""
    return {"control_sigma": "--control-sigma", "scale_bars": "--scale-bar", "measurements": "--measurements",
            "self_calibration": "--no-self-calibration"}.get(name, "--" + name.replace("_", "-"))


def failure_reasons(adj: Any) -> list[str]:
    """:func:`skyrig.pipeline.orientation.failure_reasons` (kept importable from here)."""
    from skyrig.pipeline.orientation import failure_reasons as _reasons

    return _reasons(adj)


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


if __name__ == "__main__":  # until the lead registers it: python -m skyrig.cli.uav PROJECT ...
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command()
