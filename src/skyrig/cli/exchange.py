"""``skyrig import FORMAT PATH -o block.json`` and ``skyrig export FORMAT BLOCK -o OUT``: a bundle block from and to
other programs' projects (COLMAP, OpenSfM, Metashape cameras XML or .psx project; MicMac Ori folders out).

``import`` writes a skyrig block file (cameras, oriented images, tie points and their measurements, control where
the format has it) that ``skyrig adjust`` adjusts; ``export`` writes a block file (e.g. the ``adjusted.json`` of
``skyrig adjust``) in the program's format.  Conventions: docs/formats/<format>.md."""

from __future__ import annotations

from pathlib import Path

import click

from skyrig.cli._types import CONTROL_SIGMA_M, CRS_TEXT, GEOID, PIXEL_SIGMA_PX

IMPORT_FORMATS = ("colmap", "opensfm", "metashape-xml", "metashape-psx", "project")
EXPORT_FORMATS = ("colmap", "colmap-text", "opensfm", "metashape-xml", "micmac")


@click.command("import")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(IMPORT_FORMATS))
@click.argument("path", type=click.Path(exists=True))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="Block file to write (.json); for 'project': the skyrig project folder to write.")
@click.option("--crs", type=CRS_TEXT, default=None,
              help="project: the CRS of a model that states none (COLMAP; Pix4D without its _wkt.prj).")
@click.option("--geoid", type=GEOID, default=None, help="project: geoid grid when that CRS's heights are orthometric.")
@click.option("--tracks", type=click.Path(exists=True, dir_okay=False), default=None,
              help="OpenSfM: the tracks.csv with the measurements (default: tracks.csv beside the reconstruction).")
@click.option("--sigma-px", type=PIXEL_SIGMA_PX, default=1.0, show_default=True, help="Sigma of the image measurements (px).")
@click.option("--control-sigma-m", type=CONTROL_SIGMA_M.each, default=0.01, show_default=True,
              help="Metashape: sigma of the markers' enabled references (m, per axis).")
def import_command(fmt, path, output, crs, geoid, tracks, sigma_px, control_sigma_m) -> None:
    """Bring another program's project PATH in as a skyrig block file -o/--output; FORMAT 'project': a whole
    project folder (COLMAP, OpenSfM, Metashape cameras XML or .psx, or Pix4D, told by its files) as a skyrig project folder
    (eo.csv, cameras.yaml, points.csv, tie_points.csv, block.json, import.json)."""
    from skyrig.io.block_file import write_block

    if not sigma_px > 0:
        raise click.BadParameter("must be positive", param_hint="--sigma-px")
    if fmt == "project":
        from skyrig.io.project_import import import_project

        if Path(output).is_file():
            raise click.BadParameter(f"{output} is a file: give the project folder to write", param_hint="-o")
        s = import_project(path, output, crs=crs, geoid=geoid, sigma_px=sigma_px)
        click.echo(f"{s['program']} project in {path}: {s['images']} images, {len(s['cameras'])} camera(s)"
                   + (f", {s['points']} points, {s['measurements']} measurements" if "points" in s else "")
                   + f" ({s['frame']}); wrote {', '.join(s['written'])} to {output}")
        if "note" in s:
            click.echo(f"note: {s['note']}")
        return
    if Path(output).is_dir():
        raise click.BadParameter(f"{output} is a folder: give the block file to write", param_hint="-o")
    if fmt == "colmap":
        from skyrig.io.colmap import block_from_colmap
        from skyrig.io.colmap_folder import read_colmap

        block = block_from_colmap(read_colmap(path), sigma_px=sigma_px)
    elif fmt == "opensfm":
        from skyrig.io.opensfm import block_from_opensfm, read_opensfm, read_opensfm_tracks

        rec = read_opensfm(path)[0]
        tr = Path(tracks) if tracks else Path(path).parent / "tracks.csv"
        if not tr.is_file():
            raise click.BadParameter(f"{tr} not found: give the measurements with --tracks", param_hint="--tracks")
        block = block_from_opensfm(read_opensfm_tracks(tr, rec), sigma_px=sigma_px)
    else:
        from skyrig.io.metashape import block_from_metashape, read_metashape_cameras, read_metashape_project

        read = read_metashape_cameras if fmt == "metashape-xml" else read_metashape_project
        block = block_from_metashape(read(path), sigma_px=sigma_px, control_sigma_m=control_sigma_m)
    block.validate()
    write_block(output, block)
    click.echo(f"wrote {output}: {block.n_images} images, {len(block.cameras)} camera(s), {block.n_points} points, "
               f"{block.n_observations} measurements, {len(block.control_point)} control points ({block.frame})")


@click.command("export")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(EXPORT_FORMATS))
@click.argument("block_path", metavar="BLOCK", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="File or folder to write (a folder for colmap, colmap-text and micmac).")
@click.option("--fit-cameras", is_flag=True, help="Fit a camera the format cannot hold exactly (residual printed).")
@click.option("--max-residual-px", type=float, default=0.01, show_default=True,
              help="Largest RMS (px) of a fitted camera over the frame.")
def export_command(fmt, block_path, output, fit_cameras, max_residual_px) -> None:
    """Write the block file BLOCK (e.g. skyrig adjust's adjusted.json) in another program's format."""
    from skyrig.errors import OptionError
    from skyrig.io.block_file import read_block

    bf = read_block(block_path)
    b = bf.block
    reports: dict = {}
    try:
        if fmt in ("colmap", "colmap-text"):
            from skyrig.io.colmap import colmap_from_block
            from skyrig.io.colmap_folder import write_colmap

            m = colmap_from_block(b)
            write_colmap(output, m, binary=fmt == "colmap", fit_cameras=fit_cameras, fit_tolerance_px=max_residual_px)
            reports = {b.cameras[k - 1].name: r for k, r in m.fit_reports.items()}
        elif fmt == "opensfm":
            from skyrig.io.opensfm import opensfm_from_block, write_opensfm, write_opensfm_tracks

            frame = bf.frame if bf.frame is not None and bf.frame.kind == "local" else None
            rec = opensfm_from_block(b, frame)
            write_opensfm(output, rec, fit_cameras=fit_cameras, fit_tolerance_px=max_residual_px)
            write_opensfm_tracks(Path(output).parent / "tracks.csv", rec)
            reports = rec.fit_reports
        elif fmt == "metashape-xml":
            from skyrig.io.metashape import metashape_from_block, write_metashape_cameras

            ch = metashape_from_block(b)
            write_metashape_cameras(output, ch, fit_cameras=fit_cameras, fit_tolerance_px=max_residual_px)
            reports = {ch.cameras[k].name: r for k, r in ch.fit_reports.items()}
        else:
            from skyrig.io.colmap import block_camera_poses
            from skyrig.io.micmac import MicmacOrientations, write_micmac_ori

            ids = [c.name for c in b.cameras]
            write_micmac_ori(output, MicmacOrientations(dict(zip(ids, b.cameras)), b.image_name,
                                                        [ids[c] for c in b.image_camera], block_camera_poses(b)),
                             fit_cameras=fit_cameras, fit_tolerance_px=max_residual_px, reports=reports)
    except OptionError as e:
        cli = {"fit_cameras": "--fit-cameras", "fit_tolerance_px": "--max-residual-px"}.get(e.option)
        if cli is None:
            raise
        raise OptionError(cli, e.reason) from None
    for name, rep in reports.items():
        click.echo(f"camera {name!r}: written as its {rep.target_model} fit over the frame: RMS {rep.rms_px:.4f} px, "
                   f"max {rep.max_px:.4f} px")
    click.echo(f"wrote {b.n_images} images, {b.n_points} points and {b.n_observations} measurements as {fmt} to "
               f"{output} (coordinates in the block's frame: {b.frame})")


@click.command("export-gcp")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(["pix4d"]))
@click.option("--points", "points_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Control points (skyrig CSV with its CRS, IGN .app, ODM gcp_list.txt).")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False),
              help="Check points (written to checkpoints.txt; Pix4D's file has no type column).")
@click.option("--measurements", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Image measurements of the points (skyrig CSV, IGN .mes, ODM gcp_list.txt); repeat for several.")
@click.option("--points-crs", type=CRS_TEXT, default=None, help="CRS of point files that state none.")
@click.option("--accuracy", "accuracy_m", type=CONTROL_SIGMA_M, default="0.02,0.02", show_default=True,
              help="Horizontal, vertical accuracy written with every point (m).")
@click.option("--mark-accuracy", "mark_px", type=PIXEL_SIGMA_PX, default=0.5, show_default=True,
              help="Accuracy of a mark (px) where the measurements file gives no sigma_px.")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Folder to write: gcp.txt (+ side-car with the CRS), checkpoints.txt, marks.txt.")
def export_gcp_command(fmt, points_path, check_path, measurements, points_crs, accuracy_m, mark_px, output) -> None:
    """Write ground control / check points and their image measurements as Pix4D's GCP and marks files
    (docs/cli.md: the columns, axis order and pixel origin)."""
    import numpy as np

    from skyrig.cli._common import load_points, parse_sigmas
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.pix4d_gcp import write_pix4d_gcps, write_pix4d_marks
    from skyrig.pipeline.inputs import load_measurements

    acc = parse_sigmas(accuracy_m, 2, "--accuracy", "horizontal,vertical", positive=True)
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    ctl = load_points(points_path, points_crs)
    sets = [("gcp.txt", ctl)]
    if check_path:
        sets.append(("checkpoints.txt", load_points(check_path, points_crs, default_crs=ctl.frame.crs
                                                    if ctl.frame.kind == "map" else None)))
    names = set()
    for fname, pts in sets:
        write_pix4d_gcps(out / fname, pts, acc)
        names |= set(map(str, pts.name))
        click.echo(f"wrote {out / fname}: {len(pts.name)} points ({pts.frame.describe()})")
    if measurements:
        parts = [load_measurements(m) for m in measurements]
        m = ImageMeasurements(np.concatenate([p.point for p in parts]), np.concatenate([p.image for p in parts]),
                              np.concatenate([p.pixel for p in parts]))
        keep = np.array([str(p) in names for p in m.point], dtype=bool)
        if not keep.any():
            raise click.BadParameter("none of the measured points is among the points written", param_hint="--measurements")
        m = ImageMeasurements(m.point[keep], m.image[keep], m.pixel[keep])
        write_pix4d_marks(out / "marks.txt", m, mark_px)
        click.echo(f"wrote {out / 'marks.txt'}: {int(keep.sum())} marks ({int((~keep).sum())} of points not written "
                   f"left out; x, y from the image's top-left corner)")
