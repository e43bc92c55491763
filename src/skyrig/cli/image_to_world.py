"""``skyrig image-to-world``: ground coordinates of image points (height surface, DEM, or intersection)."""

from __future__ import annotations

import click

from skyrig.cli._types import GROUND_HEIGHT_M
import numpy as np

from skyrig.cli._common import check_measurements, eo_options, load_cameras, load_eo, load_measurements_lines
from skyrig.errors import GeometryError
from skyrig.georef.eo import WorldFrame
from skyrig.georef.ground import forward_intersection, image_to_world_dem, image_to_world_height
from skyrig.georef.observations import GroundPoints
from skyrig.io.points_csv import write_points_csv


@click.command("image-to-world")
@eo_options
@click.option("--measurements", "mes_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Image points: CSV point,image,column,row (or IGN .mes, ODM gcp_list.txt).")
@click.option("--height", type=GROUND_HEIGHT_M, default=None, help="Intersect with the surface of this constant height in the output frame.")
@click.option("--dem", "dem_path", default=None, type=click.Path(exists=True, dir_okay=False), help="Intersect with this DEM GeoTIFF.")
@click.option("--dem-geoid", default=None, help="Geoid grid when the DEM heights are orthometric.")
@click.option("--intersect", is_flag=True, help="Forward-intersect the rays of each point measured in two or more images.")
@click.option("--crs", "out_crs", default=None, help="Output CRS (default: the EO's, or the DEM's).")
@click.option("--heights", "out_heights", type=click.Choice(["ellipsoidal", "orthometric"]), default="ellipsoidal", show_default=True)
@click.option("--geoid", "out_geoid", default=None, help="Geoid grid for orthometric output heights.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output CSV name,x,y,z (+ residuals).")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, mes_path, height, dem_path, dem_geoid,
            intersect, out_crs, out_heights, out_geoid, output) -> None:
    """Ground coordinates of measured image points."""
    modes = [height is not None, dem_path is not None, intersect]
    if sum(modes) != 1:
        raise click.UsageError("give exactly one of --height, --dem, --intersect")
    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    cams = load_cameras(camera_paths)
    m, lines = load_measurements_lines(mes_path)
    check_measurements(m, lines, mes_path, eo, cams)
    if dem_path:
        from skyrig.io.dem import read_dem

        dem = read_dem(dem_path, dem_geoid)
        xyz = image_to_world_dem(eo, cams, m.image, m.pixel, dem)
        pts = GroundPoints(m.point, xyz, dem.frame)
        if out_crs:
            frame = WorldFrame.map(out_crs, out_geoid if out_heights == "orthometric" else None)
            ok = np.all(np.isfinite(xyz), axis=1)
            conv = np.full_like(xyz, np.nan)
            conv[ok] = frame.from_ecef(dem.frame.to_ecef(xyz[ok]))
            pts = GroundPoints(m.point, conv, frame)
        write_points_csv(output, pts, {"image_column": m.pixel[:, 0], "image_row": m.pixel[:, 1]})
        click.echo(f"wrote {len(pts)} points ({int(np.isnan(xyz[:, 0]).sum())} missed the DEM) to {output}")
        return
    crs = out_crs or (eo.frame.crs if eo.frame.kind == "map" else None)
    frame = WorldFrame.map(crs, out_geoid if out_heights == "orthometric" else None) if crs else eo.frame
    if height is not None:
        xyz = image_to_world_height(eo, cams, m.image, m.pixel, height, frame)
        write_points_csv(output, GroundPoints(m.point, xyz, frame), {"image_column": m.pixel[:, 0], "image_row": m.pixel[:, 1]})
        click.echo(f"wrote {len(xyz)} points to {output}")
        return
    res = forward_intersection(eo, cams, m.point, m.image, m.pixel, frame)
    if not res.valid.any():
        why = "; ".join(f"{str(n)!r}: {t}" for n, t in list(zip(res.point, res.note))[:5])
        raise GeometryError(f"{mes_path}: no point could be intersected ({why})")
    xyz = np.where(res.valid[:, None], res.xyz, np.nan)  # an invalid point is not written as if it were one
    write_points_csv(output, GroundPoints(res.point, xyz, frame), {"n_rays": res.n_rays, "rms_px": res.rms_px})
    for name, note in zip(res.point[~res.valid], res.note[~res.valid]):
        click.echo(f"warning: point {str(name)!r}: {note}", err=True)
    obs_ok = res.used & res.valid[np.unique(m.point, return_inverse=True)[1]]
    if obs_ok.any():
        rms = f"{np.sqrt(np.mean(res.residual_px[obs_ok] ** 2)):.3f} px over {int(obs_ok.sum())} measurements"
    else:
        rms = "n/a (no valid point)"
    click.echo(f"intersected {int(res.valid.sum())} of {len(res.point)} points; image residual RMS {rms}; "
               f"wrote {output}")
