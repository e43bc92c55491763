"""``skyrig plan``: strips, stations, footprints, GSD per head, overlaps -> GeoPackage + PNG."""

from __future__ import annotations

import json
from pathlib import Path

import click

from skyrig.cli._types import FLYING_HEIGHT_M, GROUND_HEIGHT_M, GSD_M
import numpy as np


def _read_area(path: str) -> np.ndarray:
    """Polygon vertices from a GeoJSON file (first polygon) or a text file of ``x y`` / ``x,y`` lines."""
    from skyrig.errors import InputFormatError

    text = Path(path).read_text()
    if text.lstrip().startswith("{"):
        d = json.loads(text)
        geom = d["features"][0]["geometry"] if "features" in d else d.get("geometry", d)
        coords = geom["coordinates"][0] if geom["type"] == "Polygon" else geom["coordinates"][0][0]
        return np.asarray(coords, dtype=np.float64)[:, :2]
    pts = []
    for k, line in enumerate(text.splitlines(), 1):
        s = line.split("#")[0].replace(",", " ").split()
        if not s:
            continue
        if len(s) < 2:
            raise InputFormatError("expected 'x y'", path, k, "x")
        try:
            pts.append([float(s[0]), float(s[1])])
        except ValueError:
            raise InputFormatError(f"not a number: {line.strip()!r}", path, k, "x") from None
    return np.asarray(pts)


def plot_plan(path: Path, plan, fps: dict, area: np.ndarray, title: str) -> None:
    """PNG: area, strip lines, stations and footprints of every head (one colour per head)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 9))
    ax.plot(*np.vstack([area, area[:1]]).T, "k-", lw=1.5, label="area")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (head, fp) in enumerate(fps.items()):
        for q in fp:
            if np.all(np.isfinite(q)):
                ax.plot(*np.vstack([q[:, :2], q[:1, :2]]).T, "-", color=colours[k % len(colours)], lw=0.6, alpha=0.7)
                ax.plot(q[1, 0], q[1, 1], ".", color="red", ms=3)  # upper right corner (paper 000 Fig. 5)
        ax.plot([], [], "-", color=colours[k % len(colours)], label=head)
    ax.plot(plan.position[:, 0], plan.position[:, 1], "b.", ms=3, label="stations")
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


@click.command("plan")
@click.option("--rig", "rig_spec", required=True, help="Rig file (YAML) or preset name (midas, dlr-3k, macs-tumblecam, uav-single).")
@click.option("--area", "area_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Area polygon: GeoJSON or 'x y' lines, in --crs.")
@click.option("--crs", required=True, help="CRS of the area and of the outputs (a projected CRS).")
@click.option("--height", "flying_height", type=FLYING_HEIGHT_M, default=None, help="Flying height above ground (m).")
@click.option("--gsd", type=GSD_M, default=None, help="Target nadir GSD (m) instead of --height.")
@click.option("--ground-height", type=GROUND_HEIGHT_M, default=0.0, show_default=True, help="Mean ground height (m).")
@click.option("--dem", "dem_path", default=None, type=click.Path(exists=True, dir_okay=False), help="DEM GeoTIFF for footprints.")
@click.option("--forward-overlap", type=float, default=0.6, show_default=True)
@click.option("--side-overlap", type=float, default=0.3, show_default=True)
@click.option("--direction", type=float, default=0.0, show_default=True, help="Strip azimuth (deg, clockwise from grid north).")
@click.option("--speed", type=float, default=60.0, show_default=True, help="Ground speed (m/s).")
@click.option("--crab", type=float, default=0.0, show_default=True, help="Crab angle (deg); compensated for tumbling heads.")
@click.option("--frame-rate", type=float, default=None, help="Exposures per second (instead of the forward overlap).")
@click.option("--rotation-speed", type=float, default=0.0, show_default=True, help="Tumbling head rotation speed (deg/s).")
@click.option("--swath", type=click.Choice(["reference", "all"]), default="reference", show_default=True)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output GeoPackage (a PNG plot is written next to it).")
def command(rig_spec, area_path, crs, flying_height, gsd, ground_height, dem_path, forward_overlap, side_overlap, direction,
            speed, crab, frame_rate, rotation_speed, swath, output) -> None:
    """Plan a flight for a rig over an area; write stations, footprints and strips."""
    import shapely

    from skyrig.io.gpkg import write_gpkg
    from skyrig.plan.flight import footprints, gsd_per_head, overlap_stats, plan_flight
    from skyrig.rig.presets import PRESETS, preset

    if Path(rig_spec).exists():
        from skyrig.io.rig_file import read_rig

        rig = read_rig(rig_spec)
    elif rig_spec.lower().replace("_", "-") in PRESETS:
        rig = preset(rig_spec)
    else:
        raise click.UsageError(f"--rig {rig_spec!r} is neither a file nor a preset ({', '.join(PRESETS)})")
    if (flying_height is None) == (gsd is None):
        raise click.UsageError("give exactly one of --height and --gsd")
    area = _read_area(area_path)
    plan = plan_flight(rig, area, flying_height_m=flying_height, gsd_m=gsd, ground_height_m=ground_height,
                       forward_overlap=forward_overlap, side_overlap=side_overlap, direction_deg=direction,
                       speed_mps=speed, crab_deg=crab, frame_rate_hz=frame_rate, rotation_speed_deg_s=rotation_speed,
                       swath=swath)
    surface = None
    if dem_path:
        from skyrig.io.dem import read_dem

        surface = read_dem(dem_path, crs=crs).sample
    fps = {h: footprints(plan, rig, h, surface) for h in rig.head_names}
    geoms, heads, stn, gsd_c, gsd_n, gsd_f = [], [], [], [], [], []
    for h, fp in fps.items():
        g = gsd_per_head(plan, rig, h)
        for i, q in enumerate(fp):
            if np.all(np.isfinite(q)):
                geoms.append(shapely.Polygon(q[:, :2]))
                heads.append(h)
                stn.append(i)
                gsd_c.append(g.centre_m[i])
                gsd_n.append(g.near_m[i])
                gsd_f.append(g.far_m[i])
    layers = {
        "stations": ([shapely.Point(p[0], p[1]) for p in plan.position],
                     {"time_s": plan.time_s, "strip": plan.strip, "height": plan.position[:, 2],
                      "heading_deg": np.degrees(plan.heading_rad), "beta_deg": np.degrees(plan.beta_rad)}),
        "footprints": (geoms, {"head": np.array(heads), "station": np.array(stn), "gsd_centre_m": np.array(gsd_c),
                               "gsd_near_m": np.array(gsd_n), "gsd_far_m": np.array(gsd_f)}),
        "strips": ([shapely.LineString(l[:, :2]) for l in plan.strip_lines], {"strip": np.arange(len(plan.strip_lines))}),
    }
    write_gpkg(output, layers, crs)
    ov = overlap_stats(plan, fps[plan.reference_head], plan.reference_head).summary()
    png = Path(output).with_suffix(".png")
    plot_plan(png, plan, fps, area, f"{rig.name}: {len(plan)} stations, H = {plan.flying_height_m:.0f} m")
    click.echo(f"{len(plan)} stations on {len(plan.strip_lines)} strips, H = {plan.flying_height_m:.1f} m, "
               f"base {plan.base_m:.1f} m, spacing {plan.spacing_m:.1f} m")
    for h in rig.head_names:
        g = gsd_per_head(plan, rig, h)
        click.echo(f"  GSD {h}: centre {np.nanmean(g.centre_m):.3f} m, near {np.nanmean(g.near_m):.3f} m, far {np.nanmean(g.far_m):.3f} m")
    click.echo(f"  overlaps ({plan.reference_head}): forward {ov['forward_mean']:.2f}, side {ov['side_mean']:.2f}")
    click.echo(f"-> {output}, {png}")
