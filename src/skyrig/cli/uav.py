"""``skyrig adjust-uav PROJECT``: GNSS-supported bundle adjustment of a UAV block from ``skyrig match`` tie points
and the images' own EXIF GPS / DJI gimbal metadata (:func:`skyrig.pipeline.uav.adjust_uav`).

Images come from ``PROJECT/images`` if it exists, else PROJECT (or ``--images``); tie points from
``PROJECT/match/tie_points.csv`` (or ``--match``).  Writes ``eo.csv`` (local ENU frame of the block),
``points.csv``, ``report.json``, ``report.html`` and residual plots to ``PROJECT/adjust-uav`` (or ``--out``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

__all__ = ["command"]


@click.command("adjust-uav")
@click.argument("project", type=click.Path(exists=True, file_okay=False))
@click.option("--images", "image_dir", type=click.Path(exists=True, file_okay=False),
              help="Image folder (default PROJECT/images or PROJECT).")
@click.option("--match", "match_dir", type=click.Path(exists=True, file_okay=False),
              help="Output folder of `skyrig match` (default PROJECT/match).")
@click.option("-o", "--out", type=click.Path(file_okay=False), help="Output folder (default PROJECT/adjust-uav).")
@click.option("--gnss-sigma", nargs=3, type=float, default=(2.0, 2.0, 4.0), show_default=True,
              help="GNSS sigma east north up (m); consumer GPS: metres.")
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
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False),
              help="JSON file of UavConfig options (overrides the options above).")
def command(project: str, image_dir: str | None, match_dir: str | None, out: str | None,
            gnss_sigma: tuple[float, float, float], attitude_sigma: float, altitude: str, geoid: str | None,
            focal_prior: float, no_self_calibration: bool, compare_pycolmap: bool, pycolmap_size: int,
            pycolmap_mapper: str, config_path: str | None) -> None:
    """GNSS-supported adjustment of the UAV images of PROJECT (tie points from `skyrig match`)."""
    from skyrig.pipeline.uav import UavConfig, adjust_uav

    proj = Path(project)
    images = Path(image_dir) if image_dir else (proj / "images" if (proj / "images").is_dir() else proj)
    match = Path(match_dir) if match_dir else proj / "match"
    if not (match / "tie_points.csv").is_file():
        raise click.UsageError(f"no tie points at {match / 'tie_points.csv'}: run `skyrig match` first")
    outdir = Path(out) if out else proj / "adjust-uav"
    kw: dict = dict(gnss_sigma_m=tuple(gnss_sigma), attitude_sigma_deg=attitude_sigma or None, altitude=altitude,
                    geoid=geoid, focal_prior_rel=focal_prior)
    if no_self_calibration:
        kw["self_calibration"] = ()
    if config_path:
        kw.update(json.loads(Path(config_path).read_text()))
    cfg = UavConfig.from_dict(kw, str(config_path or "options"))
    res, rep = adjust_uav(images, match, outdir, cfg, outdir / "pycolmap" if compare_pycolmap else None,
                          pycolmap_max_image_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper)
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
    click.echo(f"{s['total_wall_s']:.1f} s; written to {outdir}")


if __name__ == "__main__":  # until the lead registers it: python -m skyrig.cli.uav PROJECT ...
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command()
