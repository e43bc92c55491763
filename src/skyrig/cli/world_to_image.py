"""``skyrig world-to-image``: project ground points into images."""

from __future__ import annotations

import click
import numpy as np

from skyrig.cli._common import check_cameras, eo_options, load_cameras, load_eo, load_measurements, load_points
from skyrig.georef.ground import world_to_image
from skyrig.georef.observations import ImageMeasurements
from skyrig.io.points_csv import write_measurements_csv


def residual_summary(d: np.ndarray) -> str:
    """RMS per axis, percentiles and maximum of pixel residuals ``(N, 2)``."""
    a = np.abs(d)
    rms = np.sqrt(np.mean(d**2, axis=0))
    p50, p90, p99 = (np.percentile(np.hypot(d[:, 0], d[:, 1]), q) for q in (50, 90, 99))
    return (
        f"n={len(d)}  RMS column {rms[0]:.3f} px, row {rms[1]:.3f} px  |  "
        f"|residual| median {p50:.3f}, 90% {p90:.3f}, 99% {p99:.3f}  |  max column {a[:, 0].max():.3f}, row {a[:, 1].max():.3f} px"
    )


def _positions(names: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Row in ``names`` of every entry of ``wanted`` (all present), vectorised by sorting."""
    order = np.argsort(names, kind="stable")
    return order[np.searchsorted(names[order], wanted)]


def _nothing_seen(pts, eo, points_path: str) -> None:
    """No point falls in any image: say how far the points are from the projection centres (a CRS or axis-order
    mistake puts them kilometres away) instead of writing an empty file with exit 0."""
    from skyrig.errors import InputFormatError

    try:
        d = np.linalg.norm(pts.frame.to_ecef(pts.xyz).mean(axis=0) - eo.frame.to_ecef(eo.centre).mean(axis=0))
        far = f"; the points' centre is {d / 1000.0:.3g} km from the projection centres' (CRS or axis order?)"
    except Exception:  # noqa: BLE001 - the distance is only a hint
        far = ""
    raise InputFormatError(f"none of the {len(pts)} points falls in any of the {len(eo)} images{far}", points_path)


@click.command("world-to-image")
@eo_options
@click.option("--points", "points_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Ground points (IGN .app or _world.mes, ODM gcp_list.txt, or CSV name,x,y,z).")
@click.option("--points-crs", default=None, help="CRS of the points when the file does not state one (a skyrig CSV's header or side-car wins and must "
                   "agree with this; default: the EO CRS).")
@click.option("--points-heights", type=click.Choice(["ellipsoidal", "orthometric"]), default="ellipsoidal", show_default=True, help="Height reference of the point file.")
@click.option("--points-geoid", default=None, help="Geoid grid when the point heights are orthometric.")
@click.option("--measurements", "mes_path", default=None, type=click.Path(exists=True, dir_okay=False), help="Only project the measured (point, image) pairs of this file and report residuals.")
@click.option("--image", "images", multiple=True, help="Restrict to these images.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output CSV: point,image,column,row.")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, points_path, points_crs,
            points_heights, points_geoid, mes_path, images, output) -> None:
    """Project ground points into every image that sees them (or into measured pairs) and write a CSV."""
    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    if images:
        eo = eo.subset(np.isin(eo.image, list(images)))
    cams = load_cameras(camera_paths)
    check_cameras(eo, cams, eo_path)
    # the points file's own frame (header or side-car) wins; the EO's CRS only stands in for a file that states none
    pts = load_points(points_path, points_crs, points_heights, points_geoid,
                      default_crs=eo_crs or (eo.frame.crs if eo.frame.kind == "map" else None))
    idx = pts.index()
    if mes_path:
        m = load_measurements(mes_path)
        keep = np.array([p in idx for p in m.point]) & np.isin(m.image, eo.image)
        skipped = int((~keep).sum())
        m = ImageMeasurements(m.point[keep], m.image[keep], m.pixel[keep])
        pairs_p, pairs_i = m.point, m.image
    else:
        pairs_p = np.repeat(pts.name, len(eo))
        pairs_i = np.tile(eo.image, len(pts))
        skipped = 0
    rows = _positions(pts.name, pairs_p)
    px = world_to_image(eo, cams, pairs_i, pts.xyz[rows], pts.frame)
    inside = np.ones(len(px), bool)
    if not mes_path:
        pair_cam = eo.camera[_positions(eo.image, pairs_i)]
        for name in np.unique(pair_cam):
            sel = pair_cam == name
            inside[sel] = cams[name].in_image(px[sel])
    if not mes_path and len(pts) and len(eo) and not inside.any():
        _nothing_seen(pts, eo, points_path)
    out = ImageMeasurements(pairs_p[inside], pairs_i[inside], px[inside])
    header = [f"skyrig world-to-image; EO {eo_path}; points {points_path}; frame {pts.frame.describe()}",
              "pixels: column right, row down, origin at the centre of the top-left pixel"]
    write_measurements_csv(output, out, m.pixel if mes_path else None, header)
    click.echo(f"wrote {len(out)} image positions to {output}")
    if mes_path:
        if skipped:
            click.echo(f"skipped {skipped} measurements without ground coordinates or orientation")
        click.echo(residual_summary(px - m.pixel))
