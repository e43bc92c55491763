"""``skyrig dsm``: dense matching of oriented images -> DSM (COG), dense cloud (LAZ), hillshade, report."""

from __future__ import annotations

import click

from skyrig.cli._types import CRS_TEXT, FINITE, GEOID, NONNEGATIVE, POSITIVE, POSITIVE_INT, POSITIVE_M, Number

from skyrig.cli._common import eo_options


@click.command("dsm")
@eo_options
@click.option("--images", "images", multiple=True, required=True, type=click.Path(exists=True),
              help="Image folder or image file; repeat for several. Only images with an orientation are used.")
@click.option("--heads", default=None, help="Use only these rig heads / name parts (comma list, e.g. 'nadir').")
@click.option("--crs", type=CRS_TEXT, default=None, help="Output CRS (projected, metres); default: the EO file's CRS.")
@click.option("--geoid", type=GEOID, default=None, help="Geoid grid for orthometric output heights (default: the EO file's).")
@click.option("--height-range", nargs=2, type=FINITE, default=None, metavar="MIN MAX",
              help="Expected surface heights in the output heights (m); sets the disparity search.")
@click.option("--points", "points_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Sparse points (e.g. skyrig adjust's points.csv) to derive the height range from.")
@click.option("--area", nargs=4, type=FINITE, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Area to compute in the output CRS (default: where the images see the ground).")
@click.option("--resolution", type=POSITIVE_M, default=None, help="Cell size in metres (default: 1 GSD).")
@click.option("--mode", type=click.Choice(["sgbm", "hh", "3way", "hh4"]), default="sgbm", show_default=True,
              help="OpenCV semi-global matching mode.")
@click.option("--lr-check", type=click.Choice(["banded", "full", "opencv"]), default=None,
              help="Left-right check: 'banded' (default: a second matching from the right image on the row bands "
                   "where the first shows a depth edge), 'full' (that matching on every row) or 'opencv' "
                   "(OpenCV's internal one: half the matching time, rounder building edges, a few more outliers).")
@click.option("--lr-band-cols", type=Number(integer=True, nonnegative=True), default=None, metavar="PX",
              help="Banded check: the second matching runs only on the columns within this many pixels of a depth "
                   "edge (default 8; 0: on the bands' whole rows).")
@click.option("--pairs-per-image", type=POSITIVE_INT, default=6, show_default=True, help="Stereo pairs an image takes part in.")
@click.option("--min-support", type=POSITIVE_INT, default=2, show_default=True,
              help="Stereo pairs that must agree on a cell's height.")
@click.option("--fill", is_flag=True, help="Interpolate small holes (flagged in the 'filled' band).")
@click.option("--no-cloud", is_flag=True, help="Do not write the dense point cloud.")
@click.option("--min-depth", type=POSITIVE_M, default=None,
              help="Nearest depth searched from a camera in metres (default: a quarter of its distance to the scene).")
@click.option("--tile-cells", type=POSITIVE_INT, default=2048, show_default=True, help="Ground tile side in cells (unit of parallel work); with --tile-memory-mb the largest side.")
@click.option("--tile-memory-mb", type=NONNEGATIVE, default=1024.0, show_default=True,
              help="Memory budget of one ground tile's work in MiB (beyond a worker's own, about 250-500 MiB): the "
                   "tiles' side is the largest up to --tile-cells whose predicted points and images fit; 0: tiles "
                   "of --tile-cells.")
@click.option("--window-min-mp", type=NONNEGATIVE, default=60.0, show_default=True,
              help="TIFF images of at least this many megapixels are read window by window (only what each block "
                   "needs: memory bounded by the block, not the image); 0 reads every TIFF so.")
@click.option("--image-scale", type=click.Choice(["auto", "1", "0.5", "0.25", "0.125", "0.0625", "ultra", "high",
                                                  "medium", "low", "lowest"]), default="auto", show_default=True,
              help="Scale of the images dense matching sees (ODM's quality names: ultra 1, high 0.5, medium 0.25, low "
                   "0.125, lowest 0.0625); auto: the smallest whose GSD is no larger than --resolution, without it the "
                   "largest that keeps the images' longer side within 2048 px. The default cell is the GSD at that "
                   "scale.")
@click.option("--orientation-sigma-px", type=POSITIVE, default=None,
              help="Relative error of the orientations as a disparity in full-resolution pixels (e.g. 1.4 x the "
                   "adjustment's reprojection RMS): widens the tolerance within which pairs must agree on a cell.")
@click.option("--executor", type=click.Choice(["auto", "serial", "local"]), default="auto", show_default=True,
              help="Where tiles run: this process, local Dask worker processes, or (with --scheduler) a cluster.")
@click.option("--workers", type=POSITIVE_INT, default=None, help="Local worker processes.")
@click.option("--scheduler", default=None, help="Address of a dask.distributed scheduler (tcp://host:8786).")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, images, heads, crs, geoid, height_range,
            points_path, area, resolution, mode, lr_check, lr_band_cols, pairs_per_image, min_support, fill, no_cloud, min_depth, tile_cells, tile_memory_mb, window_min_mp,
            image_scale, orientation_sigma_px, executor, workers, scheduler, output) -> None:
    """Dense matching: DSM (COG) and dense point cloud (LAZ) from oriented images.

    Pairs are chosen from the orientations, rectified exactly (distortion included), matched by OpenCV's
    semi-global matcher, triangulated and fused over all pairs; a height no second pair (or a confirmed
    neighbour cell within 2 cells at the same height) confirms is left out.
    """
    from skyrig.cli._common import load_cameras, load_eo
    from skyrig.cli.progress import tile_progress
    from skyrig.pipeline.products import make_dsm

    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    cameras = load_cameras(camera_paths)
    with tile_progress("dense tiles") as progress:
        res = make_dsm(eo, cameras, images, output, crs=crs, geoid=geoid, height_range=height_range,
                       points=points_path, heads=heads, area=area, resolution=resolution, mode=mode,
                       pairs_per_image=pairs_per_image, min_support=min_support, fill=fill, cloud=not no_cloud,
                       min_depth=min_depth, tile_cells=tile_cells, executor=executor, workers=workers,
                       scheduler=scheduler, inputs=[eo_path, *camera_paths], progress=progress, echo=click.echo,
                       lr_check=lr_check, lr_band_cols=lr_band_cols, window_min_mp=window_min_mp, image_scale=image_scale,
                       orientation_sigma_px=orientation_sigma_px, tile_memory_mb=tile_memory_mb or None)
    s = res.summary
    click.echo(f"{len(s['pairs'])} stereo pairs, {res.stats.megapixels:.1f} MP matched, {s['cells_valid']} of {s['cells']} "
               f"cells ({res.stats.cell_m:.3f} m), {s['cloud_points']} cloud points -> {res.outdir} "
               f"({s['vertical_reference']})")
