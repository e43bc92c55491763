"""``skyrig ortho``: true orthomosaic (COG) of oriented images on a DSM, with its source-image layer, seamlines and
a preview; optionally one mosaic per rig head (the obliques' viewing directions)."""

from __future__ import annotations

import click

from skyrig.cli._common import eo_options


@click.command("ortho")
@eo_options
@click.option("--images", "images", multiple=True, required=True, type=click.Path(exists=True),
              help="Image folder or image file; repeat for several. Only images with an orientation are used.")
@click.option("--dsm", "dsm_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="The surface (skyrig dsm's dsm.tif or any DSM GeoTIFF with a CRS).")
@click.option("--surface", type=click.Choice(["dsm", "dtm"]), default="dsm", show_default=True,
              help="dsm: a true orthophoto on --dsm; dtm: a classic orthophoto on the bare earth of --dtm "
                   "(buildings lean, as in a classic ortho).")
@click.option("--dtm", "dtm_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="The DTM of --surface dtm (skyrig terrain dtm's dtm.tif or any DTM GeoTIFF with a CRS).")
@click.option("--heads", default=None, help="Images of the main mosaic: these rig heads / name parts (comma list, "
                                            "e.g. 'nadir'); default all.")
@click.option("--head-mosaics", default=None,
              help="Also one mosaic per head / name part in this comma list (e.g. 'forward,backward,left,right').")
@click.option("--crs", default=None, help="Output CRS (projected); default: the DSM's (another one reprojects the DSM).")
@click.option("--area", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Area in the output CRS (default: the DSM's extent).")
@click.option("--resolution", type=float, default=None, help="Cell size in metres (default: 1 GSD of the images).")
@click.option("--max-off-nadir", type=float, default=60.0, show_default=True,
              help="Cells seen more obliquely than this (degrees) do not take that image.")
@click.option("--feather", type=float, default=None, help="Blend width across seamlines in metres (default 6 cells).")
@click.option("--no-balance", is_flag=True, help="No radiometric balance between images.")
@click.option("--no-square", is_flag=True,
              help="Project onto the DSM as matched (default: buildings extracted from it get square edges, their "
                   "walls on the roof outline seen in steep images, so roofs do not lean onto the ground).")
@click.option("--tile-cells", type=int, default=2048, show_default=True, help="Tile side in cells (unit of parallel work).")
@click.option("--executor", type=click.Choice(["auto", "serial", "local"]), default="auto", show_default=True,
              help="Where views and tiles run: this process, local Dask worker processes, or (with --scheduler) a cluster.")
@click.option("--workers", type=int, default=None, help="Local worker processes.")
@click.option("--scheduler", default=None, help="Address of a dask.distributed scheduler (tcp://host:8786).")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, images, dsm_path, surface, dtm_path,
            heads, head_mosaics, crs, area, resolution, max_off_nadir, feather, no_balance, no_square, tile_cells, executor,
            workers, scheduler, output) -> None:
    """True orthomosaic: every cell of the DSM's surface coloured by the best image that sees it.

    Occlusion is tested along each ray against the DSM, so buildings stand upright and ground hidden in one image
    comes from another; seamlines run around elevated objects; images are balanced and blended.  With
    ``--surface dtm`` the images are projected onto the DTM instead: a classic orthophoto, next to the true one.
    """
    from skyrig.cli._common import load_cameras, load_eo
    from skyrig.cli.progress import tile_progress
    from skyrig.dense.ortho import EmptyMosaicError
    from skyrig.errors import OptionError
    from skyrig.pipeline.products import make_ortho

    wanted, other = ("--dtm", "--dsm") if surface == "dtm" else ("--dsm", "--dtm")
    path, stray = (dtm_path, dsm_path) if surface == "dtm" else (dsm_path, dtm_path)
    if path is None:
        raise OptionError(wanted, f"--surface {surface} needs the surface file {wanted}")
    if stray is not None:
        raise OptionError(other, f"{other} is not used with --surface {surface} (the surface is {wanted})")
    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    cameras = load_cameras(camera_paths)
    with tile_progress("ortho tiles") as progress:
        try:
            res = make_ortho(eo, cameras, images, path, output, heads=heads, head_mosaics=head_mosaics, crs=crs,
                             area=area, resolution=resolution, max_off_nadir=max_off_nadir, feather=feather,
                             balance=not no_balance, square=not no_square, tile_cells=tile_cells, executor=executor, workers=workers,
                             scheduler=scheduler, inputs=[eo_path, *camera_paths], progress=progress, surface=surface)
        except EmptyMosaicError as exc:
            click.echo(f"error: {exc}", err=True)
            raise SystemExit(1) from None
    s = res.summary
    g = s["grid"]
    kind = "classic orthophoto on the DTM" if surface == "dtm" else "orthomosaic"
    click.echo(f"{kind} {g['width']} x {g['height']} cells ({g['cell_m']:.3f} m) from {len(s['images_used'])} "
               f"images: {s['cells_valid']} cells coloured, {s['surface_without_colour']} of the surface seen by no "
               f"image, {s['seamlines']} seamline pieces; heights: {s['vertical_reference']} -> {res.outdir}")
    for h, hs in s["heads"].items():
        click.echo(f"  head mosaic {h}: {hs['cells_valid']} cells from {len(hs['images_used'])} images")

