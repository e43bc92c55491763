"""``skyrig georef``: direct georeferencing, trajectory + events + rig -> EO file."""

from __future__ import annotations

from pathlib import Path

import click

from skyrig.cli._types import CRS_TEXT, GEOID

from skyrig.georef.direct import direct_georeference
from skyrig.georef.eo import WorldFrame


def load_trajectory(path: str, reference: str | None):
    """A trajectory from a skyrig trajectory CSV or an Applanix SBET (``.out`` / ``.sbet``)."""
    if Path(path).suffix.lower() in (".out", ".sbet", ".bin"):
        from skyrig.io.sbet import read_sbet

        return read_sbet(path, reference=reference or "imu")
    from skyrig.io.trajectory_csv import read_trajectory_csv

    traj = read_trajectory_csv(path)
    if reference and reference != traj.reference:
        raise click.UsageError(f"--reference {reference} contradicts the trajectory file's '# reference: {traj.reference}'")
    return traj


@click.command("georef")
@click.option("--trajectory", "traj_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Trajectory: skyrig trajectory CSV or Applanix SBET (.out/.sbet).")
@click.option("--reference", type=click.Choice(["imu", "antenna"]), default=None, help="Point the SBET positions refer to (CSV files say it in their header).")
@click.option("--events", "events_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Camera events CSV (image, time, head, beta).")
@click.option("--rig", "rig_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Rig file (YAML).")
@click.option("--crs", type=CRS_TEXT, required=True, help="Output CRS: EPSG code, WKT, PROJ string, or 'ecef'.")
@click.option("--heights", type=click.Choice(["ellipsoidal", "orthometric"]), default="ellipsoidal", show_default=True)
@click.option("--geoid", type=GEOID, default=None, help="Geoid grid (path or PROJ name) for orthometric heights.")
@click.option("--angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True)
@click.option("--convention", type=click.Choice(["opk", "pok", "ypr"]), default="opk", show_default=True)
@click.option("--position", type=click.Choice(["cubic", "linear"]), default="cubic", show_default=True, help="Position interpolation (attitude: slerp).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output EO CSV.")
def command(traj_path, reference, events_path, rig_path, crs, heights, geoid, angles, convention, position, output) -> None:
    """Exterior orientation of every image from GNSS/IMU, lever arms, boresights and actuator angles."""
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig

    if heights == "orthometric" and not geoid:
        raise click.UsageError("--heights orthometric needs --geoid")
    frame = WorldFrame.ecef() if crs.lower() == "ecef" else WorldFrame.map(crs, geoid if heights == "orthometric" else None)
    traj = load_trajectory(traj_path, reference)
    events = read_events_csv(events_path)
    rig = read_rig(rig_path)
    eo = direct_georeference(traj, rig, events, frame, position=position)
    write_eo_csv(eo, output, unit=angles, convention=convention)
    click.echo(f"georeferenced {len(eo)} images of {len(set(eo.head))} head(s) -> {output} ({frame.describe()})")
