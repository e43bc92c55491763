"""``skyrig convert SRC -o DST``: exterior orientations between formats, angle conventions, units and CRS; other
programs' models (COLMAP, OpenSfM, Metashape) in and out; ``skyrig convert --camera FILE -o DST``: a camera between
programs' files and distortion models, exactly where the models are equivalent, else fitted over the frame with the
residual reported in pixels.

``-o/--output`` names the file written, as for every single-file command (docs/cli.md); the older positional form
``skyrig convert SRC DST`` still works and warns that it is deprecated."""

from __future__ import annotations

import click

from skyrig.cli._types import CRS_TEXT, GEOID, MAP_Z, POSITIVE

from skyrig.cli._common import EO_READERS, load_eo
from skyrig.georef.eo import WorldFrame
from skyrig.io.eo_csv import write_eo_csv

MODEL_WRITERS = ("colmap", "colmap-text", "opensfm", "metashape-xml", "micmac", "pix4d")
CAMERA_FORMATS = ("metashape-calibration", "micmac-calibration", "opensfm-cameras", "colmap-cameras", "ign-camera",
                  "rig")


def _write_csv(eo, path, unit, convention):
    write_eo_csv(eo, path, unit=unit, convention=convention)


def _write_geo(eo, path, unit, convention):
    from skyrig.io.odm import write_geo_txt

    write_geo_txt(path, eo)


def _write_opk(eo, path, unit, convention):
    from skyrig.io.ign import write_ign_opk

    write_ign_opk(path, eo)


def _write_pix4d(eo, path, unit, convention):
    from skyrig.io.pix4d import write_pix4d_external

    write_pix4d_external(path, eo)


WRITERS = {"skyrig-csv": _write_csv, "odm-geo": _write_geo, "ign-opk": _write_opk, "pix4d-opk": _write_pix4d}


def _distortion_names() -> list[str]:
    from skyrig.camera.distortion import distortion_models

    return sorted(distortion_models())


def _echo_fits(reports: dict, what: str) -> None:
    for name, rep in reports.items():
        click.echo(f"camera {name!r}: {what} cannot hold its {rep.source_model} distortion exactly; written as its "
                   f"{rep.target_model} fit over the frame: RMS {rep.rms_px:.4f} px, max {rep.max_px:.4f} px")


@click.command("convert")
@click.argument("src", required=False, default=None, type=click.Path(exists=True))
@click.argument("dst", required=False, default=None, metavar="", type=click.Path())
@click.option("-o", "--output", type=click.Path(), default=None,
              help="File to write (a folder for COLMAP models; the positional DST of older versions is deprecated).")
@click.option("--from-format", type=click.Choice(sorted(EO_READERS) + list(CAMERA_FORMATS)), default=None,
              help="Input format (default: from the name; a folder is a COLMAP model). With --camera: the camera "
                   "file's format.")
@click.option("--from-crs", type=CRS_TEXT, default=None, help="CRS of the input when the file does not say.")
@click.option("--from-geoid", type=GEOID, default=None, help="Geoid grid when input heights are orthometric.")
@click.option("--from-map-z-ground", type=MAP_Z, default=None, help="Undo the linear alteration of input heights (map-coordinate adjustment) with this ground height.")
@click.option("--to-format", type=click.Choice(sorted(WRITERS) + list(MODEL_WRITERS) + list(CAMERA_FORMATS)),
              default=None, help="Output format (default skyrig-csv; with --camera: from the output name). colmap "
              "(binary), colmap-text, opensfm, metashape-xml write a model: orientations and cameras (from the "
              "input model, or --camera files).")
@click.option("--to-crs", type=CRS_TEXT, default=None, help="Output CRS: EPSG code, WKT, PROJ string, 'ecef' (default: the input's).")
@click.option("--to-heights", type=click.Choice(["ellipsoidal", "orthometric"]), default=None, help="Output height reference (default: the input's).")
@click.option("--to-geoid", type=GEOID, default=None, help="Geoid grid for orthometric output heights.")
@click.option("--to-angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True)
@click.option("--to-convention", type=click.Choice(["opk", "pok", "ypr"]), default="opk", show_default=True)
@click.option("--camera", "camera_paths", multiple=True, type=click.Path(exists=True),
              help="Camera file (Metashape or MicMac calibration .xml, OpenSfM .json, COLMAP cameras.txt/.bin, IGN "
                   ".txt, rig .yaml). Without SRC: the camera to convert. With SRC: cameras for a model output; repeat for "
                   "several.")
@click.option("--to-model", type=click.Choice(_distortion_names()), default=None,
              help="With --camera: the distortion model to convert to (exact when equivalent, else fitted over "
                   "the frame with the residual printed).")
@click.option("--camera-name", default=None, help="With --camera: the camera of a file that holds several.")
@click.option("--fit-cameras", is_flag=True, help="A camera the output format cannot hold exactly is fitted over "
              "the frame (refused above --max-residual-px RMS); without it such a camera is an error.")
@click.option("--max-residual-px", type=POSITIVE, default=0.01, show_default=True,
              help="Largest RMS (px) of a fitted camera over the frame.")
def command(src, dst, output, from_format, from_crs, from_geoid, from_map_z_ground, to_format, to_crs, to_heights,
            to_geoid, to_angles, to_convention, camera_paths, to_model, camera_name, fit_cameras,
            max_residual_px) -> None:
    """Convert an exterior-orientation file or model SRC into -o/--output, or (without SRC) the camera of --camera."""
    from skyrig.cli._common import output_or_positional

    dst = output_or_positional(output, dst, "DST")
    if src is None:
        if not camera_paths:
            raise click.UsageError("give SRC (orientations) or --camera (a camera to convert)")
        _convert_camera(camera_paths, dst, from_format, to_format, to_model, camera_name, max_residual_px)
        return
    if to_model or camera_name:
        raise click.UsageError("--to-model and --camera-name go with --camera and no SRC (a camera conversion)")
    if from_format in CAMERA_FORMATS:
        raise click.UsageError(f"--from-format {from_format} is a camera format: give the file with --camera")
    to_format = to_format or "skyrig-csv"
    if to_format in CAMERA_FORMATS:
        raise click.UsageError(f"--to-format {to_format} is a camera format: use --camera FILE without SRC")
    cameras = {}
    from skyrig.pipeline.inputs import _guess_eo_format

    fmt = from_format or _guess_eo_format(src)
    if fmt in ("colmap", "opensfm", "metashape-xml", "metashape-psx", "micmac", "pix4d"):
        from skyrig.io.exchange import read_model_orientations

        eo, cameras = read_model_orientations(src, fmt, from_crs, from_geoid, "--from-crs")
        if from_map_z_ground is not None:
            eo = eo.with_map_heights_reduced(from_map_z_ground)
    else:
        eo = load_eo(src, from_format, from_crs, from_geoid, from_map_z_ground, crs_option="--from-crs")
    if to_crs or to_heights or to_geoid:
        if to_crs and to_crs.lower() == "ecef":
            frame = WorldFrame.ecef()
        else:
            crs = to_crs or eo.frame.crs
            heights = to_heights or ("orthometric" if (to_geoid or eo.frame.geoid) else "ellipsoidal")
            geoid = (to_geoid or eo.frame.geoid) if heights == "orthometric" else None
            if heights == "orthometric" and not geoid:
                raise click.UsageError("orthometric output heights need --to-geoid")
            if crs is None:
                raise click.UsageError(f"the input is in {eo.frame.describe()}: give --to-crs")
            frame = WorldFrame.map(crs, geoid)
        eo = eo.to_frame(frame)
    if to_format in MODEL_WRITERS:
        from skyrig.io.exchange import read_camera_file, write_model_orientations

        for p in camera_paths:
            cameras.update(read_camera_file(p))
        from skyrig.errors import OptionError

        try:
            reports = write_model_orientations(dst, to_format, eo, cameras, fit_cameras, max_residual_px)
        except OptionError as e:
            cli = {"fit_cameras": "--fit-cameras", "fit_tolerance_px": "--max-residual-px"}.get(e.option)
            if cli is None:
                raise
            raise OptionError(cli, e.reason) from None
        _echo_fits(reports, to_format)
        click.echo(f"wrote {len(eo)} orientations and {len(set(eo.camera))} camera(s) as {to_format} to {dst}")
        return
    WRITERS[to_format](eo, dst, to_angles, to_convention)
    click.echo(f"wrote {len(eo)} orientations ({eo.frame.describe()}, {to_convention} in {to_angles}) to {dst}")


def _convert_camera(paths, dst, from_format, to_format, to_model, camera_name, max_residual_px) -> None:
    from skyrig.camera.convert import compare_cameras, convert_camera, exact_conversion
    from skyrig.io.exchange import guess_camera_format, read_camera_file, write_camera_file

    if len(paths) != 1:
        raise click.UsageError("a camera conversion takes one --camera file")
    if from_format is not None and from_format not in CAMERA_FORMATS:
        raise click.UsageError(f"--from-format {from_format} is not a camera format ({', '.join(CAMERA_FORMATS)})")
    cams = read_camera_file(paths[0], from_format)
    if camera_name is not None:
        if camera_name not in cams:
            raise click.BadParameter(f"{camera_name!r} is not in {paths[0]} (cameras: {', '.join(cams)})",
                                     param_hint="--camera-name")
        cams = {camera_name: cams[camera_name]}
    to_format = to_format or guess_camera_format(dst)
    if to_format not in CAMERA_FORMATS or to_format == "ign-camera":
        raise click.UsageError(f"--to-format {to_format} is not a writable camera format (metashape-calibration, "
                               "micmac-calibration, opensfm-cameras, colmap-cameras, rig)")
    out = {}
    for name, cam in cams.items():
        if to_model is None:
            out[name] = cam
            continue
        ex = exact_conversion(cam, to_model)
        if ex is not None:
            rep = compare_cameras(cam, ex)
            click.echo(f"camera {name!r}: {cam.distortion.name} -> {to_model} exact (max {rep.max_px:.2e} px over "
                       "the frame)")
            out[name] = ex
            continue
        new, rep = convert_camera(cam, to_model)
        regions = ", ".join(f"{r.name} {r.rms_px:.4f}" for r in rep.regions)
        click.echo(f"camera {name!r}: {cam.distortion.name} -> {to_model} fitted over the frame: RMS {rep.rms_px:.4f} "
                   f"px, max {rep.max_px:.4f} px (RMS by region: {regions})")
        if not rep.rms_px <= max_residual_px:
            raise click.ClickException(f"camera {name!r}: the {to_model} fit departs from the camera by "
                                       f"{rep.rms_px:.4f} px RMS, more than --max-residual-px {max_residual_px}")
        out[name] = new
    write_camera_file(dst, to_format, out)
    click.echo(f"wrote {len(out)} camera(s) as {to_format} to {dst}")
