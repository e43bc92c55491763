"""``skyrig terrain``: ground classification (classify), DTM (dtm), contours (contours), volumes (volume)."""

from __future__ import annotations

import json

import click

from skyrig.cli._types import CRS_TEXT, GROUND_HEIGHT_M, POSITIVE_M


@click.group("terrain")
def command() -> None:
    """Terrain products: ASPRS classes, DTM + nDSM + hillshade, contour lines, cut/fill volumes."""


@command.command("classify")
@click.argument("cloud", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Classified LAS/LAZ to write.")
@click.option("--crs", type=CRS_TEXT, default=None, help="CRS of a cloud whose file states none (e.g. EPSG:25832).")
@click.option("--cloth-resolution", type=float, default=1.0, show_default=True,
              help="Cloth particle spacing of the cloth simulation filter, metres (2-3 x the point spacing).")
@click.option("--class-threshold", type=float, default=0.5, show_default=True,
              help="Points within this distance of the settled cloth are ground, metres.")
@click.option("--rigidness", type=click.IntRange(1, 3), default=2, show_default=True,
              help="Cloth rigidness: 1 steep slopes, 2 relief, 3 flat terrain.")
@click.option("--building-min-height", type=float, default=2.0, show_default=True,
              help="Roofs stand at least this high above the ground, metres.")
@click.option("--tile", "tile_m", type=float, default=500.0, show_default=True,
              help="A wider cloud is classified in tiles of this side (m), each with --buffer around it.")
@click.option("--buffer", "buffer_m", type=float, default=50.0, show_default=True,
              help="Buffer around each tile (m); must hold the largest building.")
@click.option("--executor", type=click.Choice(["serial", "local"]), default="serial", show_default=True,
              help="Where tiles run: this process or local Dask worker processes (or --scheduler).")
@click.option("--workers", type=int, default=None, help="Local worker processes.")
@click.option("--scheduler", default=None, help="Address of a dask.distributed scheduler (tcp://host:8786).")
@click.option("--copc", "copc_path", default=None, type=click.Path(dir_okay=False),
              help="Also write the classified cloud as COPC (cloud-optimised LAZ for web viewers; needs copclib).")
def classify(cloud, output, crs, cloth_resolution, class_threshold, rigidness, building_min_height, tile_m, buffer_m,
             executor, workers, scheduler, copc_path) -> None:
    """Classify CLOUD: ground by the cloth simulation filter (Zhang et al. 2016), then building (6), vegetation
    (3-5, where colour or shape supports it) and noise (7) by height above ground; written as ASPRS classes."""
    from skyrig.cli.progress import tile_progress
    from skyrig.pipeline.terrain import classify_cloud_file
    from skyrig.terrain.classify import ClassRules, GroundFilter

    with tile_progress("classification tiles") as progress:
        s = classify_cloud_file(cloud, output, crs=crs,
                                ground=GroundFilter(cloth_resolution_m=cloth_resolution,
                                                    class_threshold_m=class_threshold, rigidness=rigidness),
                                rules=ClassRules(building_min_height_m=building_min_height), tile_m=tile_m,
                                buffer_m=buffer_m, executor=executor, workers=workers, scheduler=scheduler,
                                progress=progress)
    click.echo(f"{s['points']} points classified in {s['seconds']:.1f} s -> {output}")
    for k, n in s["classes"].items():
        click.echo(f"  class {k}: {n}")
    if copc_path:
        from skyrig.io.copc import copc_from_las

        c = copc_from_las(output, copc_path)
        click.echo(f"COPC: {c['points']} points in {c['nodes']} octree nodes (depth {c['depth']}) -> {copc_path}")


@command.command("dtm")
@click.argument("cloud", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--dsm", default=None, type=click.Path(exists=True, dir_okay=False),
              help="DSM COG: the DTM takes its grid, and the normalised DSM (DSM - DTM) is written.")
@click.option("--resolution", type=POSITIVE_M, default=None, help="Cell size in metres (default: the DSM's, else 1).")
@click.option("--crs", type=CRS_TEXT, default=None, help="CRS of a cloud whose file states none.")
@click.option("--max-gap", type=POSITIVE_M, default=20.0, show_default=True,
              help="Gaps in the cloud farther than this from ground (m) stay without data (gaps under buildings and "
                   "vegetation are always interpolated).")
@click.option("--classify", is_flag=True, help="Classify the cloud first (default parameters).")
def dtm(cloud, output, dsm, resolution, crs, max_gap, classify) -> None:
    """DTM of the ground points (class 2) of CLOUD: dtm.tif (height, sigma, ground_points, source mask),
    dtm_hillshade.png, ndsm.tif with --dsm, dtm.json."""
    from skyrig.pipeline.terrain import dtm_folder

    s = dtm_folder(cloud, output, cell_m=resolution, dsm=dsm, crs=crs, max_gap_m=max_gap, classify=classify)
    c = s["cells_by_source"]
    click.echo(f"DTM {s['grid']['width']} x {s['grid']['height']} cells of {s['cell_m']:.3f} m: {c['measured']} "
               f"measured, interpolated {c['building']} under buildings, {c['vegetation']} under vegetation, "
               f"{c['gap']} across gaps, {c['no_data']} without data -> {output} ({s['vertical_reference']})")


@command.command("contours")
@click.argument("dtm", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="GeoPackage to write.")
@click.option("--interval", type=float, required=True, help="Contour interval, metres.")
@click.option("--index-every", type=int, default=5, show_default=True, help="Every N-th level is an index contour.")
@click.option("--smooth-cells", type=float, default=1.0, show_default=True,
              help="Gaussian smoothing width in cells (0: none); never moves a cell by more than --smooth-sigmas "
                   "times its predicted precision.")
@click.option("--smooth-sigmas", type=float, default=1.0, show_default=True,
              help="Largest change the smoothing may make, in the DTM's sigmas.")
def contours(dtm, output, interval, index_every, smooth_cells, smooth_sigmas) -> None:
    """Contour lines of DTM (a DTM or DSM COG) into a GeoPackage layer 'contours' (elevation, index, closed)."""
    from skyrig.errors import OptionError
    from skyrig.pipeline.terrain import contours_file

    if index_every < 1:
        raise OptionError("--index-every", f"must be at least 1, got {index_every}")
    s = contours_file(dtm, output, interval_m=interval, index_every=index_every, smooth_cells=smooth_cells,
                      smooth_sigmas=smooth_sigmas)
    click.echo(f"{s['lines']} contour lines on {s['levels']} levels ({s['index_lines']} index, {s['closed']} closed) "
               f"-> {output}")


@command.command("volume")
@click.option("--top", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Upper surface: a DTM or DSM COG (its sigma band gives the precision).")
@click.option("--polygon", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Vector file (GeoPackage...) whose polygons bound the volume; reprojected into the top's CRS.")
@click.option("--layer", default=None, help="Polygon layer (default: the only polygon layer).")
@click.option("--base", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Base surface COG (e.g. an earlier epoch).")
@click.option("--base-plane", type=GROUND_HEIGHT_M, default=None, help="Base: the horizontal plane at this height (m).")
@click.option("--base-points", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Base: a surface through these points (name,x,y,z CSV, e.g. the toe of a stockpile; an sz "
                   "column of height sigmas (m) is propagated to the volume's sigma).")
@click.option("--base-fit", type=click.Choice(["tin", "plane"]), default="tin", show_default=True,
              help="With --base-points: triangulated through them, or the least-squares plane (a ring of toe points).")
@click.option("--correlation-length", type=float, default=None,
              help="Length over which height errors are correlated (m; default 3 cells).")
@click.option("--sigma-sys", type=float, default=0.0, show_default=True,
              help="Height error common to the whole surface difference (m), e.g. a datum uncertainty.")
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False), help="JSON file to write.")
def volume(top, polygon, layer, base, base_plane, base_points, base_fit, correlation_length, sigma_sys, output
           ) -> None:
    """Cut and fill between --top and one base inside --polygon, with the predicted uncertainty."""
    from skyrig.pipeline.terrain import volume_file

    r = volume_file(top, polygon, output, base=base, base_plane=base_plane, base_points=base_points,
                    base_fit=base_fit, layer=layer, correlation_length_m=correlation_length, sigma_sys_m=sigma_sys)
    click.echo(f"fill {r['fill_m3']:.3f} +- {r['sigma_fill_m3']:.3f} m3, cut {r['cut_m3']:.3f} +- "
               f"{r['sigma_cut_m3']:.3f}"
               f" m3, net {r['net_m3']:.3f} +- {r['sigma_net_m3']:.3f} m3 over {r['area_m2']:.1f} m2 "
               f"({r['cells_interpolated']} cells without a height interpolated)")
    if output is None:
        click.echo(json.dumps(r, indent=1, default=str))
