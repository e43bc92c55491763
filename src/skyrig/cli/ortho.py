"""``skyrig ortho``: true orthomosaic (COG) of oriented images on a DSM, with its source-image layer, seamlines and
a preview; optionally one mosaic per rig head (the obliques' viewing directions)."""

from __future__ import annotations

import click

from skyrig.cli._common import eo_options


@click.command("ortho")
@eo_options
@click.option("--images", "images", multiple=True, required=True, type=click.Path(exists=True),
              help="Image folder or image file; repeat for several. Only images with an orientation are used.")
@click.option("--dsm", "dsm_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The surface (skyrig dsm's dsm.tif or any DSM GeoTIFF with a CRS).")
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
@click.option("--tile-cells", type=int, default=2048, show_default=True, help="Tile side in cells (unit of parallel work).")
@click.option("--executor", type=click.Choice(["auto", "serial", "local"]), default="auto", show_default=True,
              help="Where views and tiles run: this process, local Dask worker processes, or (with --scheduler) a cluster.")
@click.option("--workers", type=int, default=None, help="Local worker processes.")
@click.option("--scheduler", default=None, help="Address of a dask.distributed scheduler (tcp://host:8786).")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, images, dsm_path, heads, head_mosaics,
            crs, area, resolution, max_off_nadir, feather, no_balance, tile_cells, executor, workers, scheduler,
            output) -> None:
    """True orthomosaic: every cell of the DSM's surface coloured by the best image that sees it.

    Occlusion is tested along each ray against the DSM, so buildings stand upright and ground hidden in one image
    comes from another; seamlines run around elevated objects; images are balanced and blended.
    """
    import numpy as np

    from skyrig.cli._common import head_rows, load_cameras, load_eo
    from skyrig.dense.ortho import EmptyMosaicError, OrthoConfig
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.ortho import load_dsm_for, run_ortho

    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    main = np.arange(len(eo))
    if heads:
        _, rows = head_rows(eo, heads)
        main = np.unique(np.concatenate(rows))
        if len(main) == 0:
            raise click.UsageError(f"--heads {heads}: no image of the EO file matches")
    sets: dict[str, np.ndarray] = {}
    if head_mosaics:
        names, rows = head_rows(eo, head_mosaics)
        empty = [n for n, r in zip(names, rows) if len(r) == 0]
        if empty:
            raise click.UsageError(f"--head-mosaics: no image matches {', '.join(empty)}")
        sets = dict(zip(names, rows))
    for name, val in (("--resolution", resolution), ("--feather", feather)):
        if val is not None and not val > 0:
            raise click.BadParameter("must be positive (metres)", param_hint=name)
    if not 0 < max_off_nadir < 89:
        raise click.BadParameter("must be between 0 and 89 degrees", param_hint="--max-off-nadir")
    # one orientation list: the main mosaic's images first, then those only the head mosaics use
    used = np.unique(np.concatenate([main, *sets.values()])) if sets else main
    order = np.concatenate([main, np.setdiff1d(used, main)])
    pos = {int(r): k for k, r in enumerate(order)}
    eo_all = eo.subset(order)
    cameras = load_cameras(camera_paths)
    dsm = load_dsm_for(dsm_path, crs)
    paths = find_images(eo_all, images)
    cfg = OrthoConfig(cell_m=resolution, max_off_nadir_deg=max_off_nadir, feather_m=feather, balance=not no_balance,
                      tile_cells=tile_cells)
    options = {"dsm": dsm_path, "crs": dsm.frame.crs, "heads": heads, "head_mosaics": head_mosaics, "area": area,
               "resolution": resolution, "max_off_nadir": max_off_nadir, "feather": feather, "balance": not no_balance,
               "tile_cells": tile_cells}
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task("ortho tiles", total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        try:
            res = run_ortho(eo_all, cameras, paths, dsm, output, area=tuple(area) if area else None, config=cfg,
                            main_rows=np.arange(len(main)),
                            head_sets={h: [pos[int(r)] for r in rows] for h, rows in sets.items()} or None,
                            executor=executor, workers=workers, scheduler=scheduler,
                            inputs=[eo_path, *camera_paths, dsm_path], options=options, progress=progress)
        except EmptyMosaicError as exc:
            click.echo(f"error: {exc}", err=True)
            raise SystemExit(1) from None
    s = res.summary
    g = s["grid"]
    click.echo(f"orthomosaic {g['width']} x {g['height']} cells ({g['cell_m']:.3f} m) from {len(s['images_used'])} "
               f"images: {s['cells_valid']} cells coloured, {s['surface_without_colour']} of the surface seen by no "
               f"image, {s['seamlines']} seamline pieces; heights: {s['vertical_reference']} -> {res.outdir}")
    for h, hs in s["heads"].items():
        click.echo(f"  head mosaic {h}: {hs['cells_valid']} cells from {len(hs['images_used'])} images")

