"""``skyrig block``: assemble a block file (docs/formats/block.md) from what a flight recorded.

Two ways in:

* rig mode - ``--trajectory``, ``--events``, ``--rig``: one station per platform exposure (the heads of a
  rig share its pose), GNSS antenna positions through the rig's antenna lever arm and IMU attitudes as
  observations (:func:`skyrig.adjust.rig_block.block_from_trajectory`);
* image mode - ``--eo`` + ``--camera``: one station per image, the given orientations as GNSS/IMU
  observations of the projection centres and attitudes (:func:`skyrig.adjust.frames.block_from_georef`).

Measurements (``--measurements``, repeatable: tie points from ``skyrig match``, control point
measurements) in pixels; ground points (``--control``, ``--check``) with their CRS in the file header.
``--crs`` (default: the control points' CRS, else the EO's) is the project CRS recorded in the block file, in
which ``skyrig adjust`` writes the results.  ``--free`` names the system-calibration groups the block's adjustment section sets free (``skyrig adjust
--preset`` merges its variant with that section: the groups freed here stay free).  The file is written atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import click
import numpy as np

__all__ = ["command"]

_GROUPS = {"boresight": "boresight", "lever-arm": "lever_arm", "datum-shift": "datum_shift",
           "strip-shift": "strip_shift", "intrinsics": "intrinsics"}


def _triple(text: str, what: str) -> tuple[float, float, float]:
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"{what}: numbers separated by commas, not {text!r}") from None
    if len(v) == 1:
        v = v * 3
    if len(v) != 3 or not all(np.isfinite(v)) or min(v) <= 0:
        raise click.BadParameter(f"{what}: one or three positive numbers, not {text!r}")
    return v[0], v[1], v[2]


@click.command("block")
@click.option("--trajectory", type=click.Path(exists=True, dir_okay=False), help="Rig mode: trajectory CSV or SBET.")
@click.option("--events", type=click.Path(exists=True, dir_okay=False), help="Rig mode: camera events CSV.")
@click.option("--rig", "rig_path", type=click.Path(exists=True, dir_okay=False), help="Rig mode: rig file (YAML).")
@click.option("--eo", "eo_path", type=click.Path(exists=True, dir_okay=False), help="Image mode: EO file.")
@click.option("--camera", "camera_paths", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Image mode: camera / rig file(s).")
@click.option("--measurements", "meas_paths", multiple=True, required=True,
              type=click.Path(exists=True, dir_okay=False), help="Image measurements CSV (repeatable).")
@click.option("--control", "control_path", type=click.Path(exists=True, dir_okay=False),
              help="Control points CSV (CRS in its header).")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False),
              help="Check points CSV: compared after the adjustment, not used in it.")
@click.option("--sigma-px", type=float, default=0.5, show_default=True, help="Image measurement sigma (pixels).")
@click.option("--gnss-sigma", default="0.05,0.05,0.08", show_default=True,
              help="GNSS sigma E,N,U (metres; one value for all axes).")
@click.option("--imu-sigma-deg", default="0.005,0.005,0.01", show_default=True,
              help="IMU attitude sigma roll,pitch,yaw (degrees) in rig mode; about the camera axes in image mode.")
@click.option("--control-sigma", default="0.02", show_default=True, help="Control point sigma X,Y,Z (metres).")
@click.option("--free", "free", default="", help=f"Comma-separated groups to estimate: {', '.join(_GROUPS)}.")
@click.option("--crs", "crs", default=None,
              help="Project CRS the adjusted results are written in (recorded in the block file); a compound CRS "
                   "(e.g. EPSG:25832+5773) gives orthometric heights through the geoid PROJ ties to it. Default: the "
                   "control points' CRS and heights, else the EO file's (image mode).")
@click.option("--geoid", default=None, help="With --crs: geoid grid (path or PROJ name) for orthometric heights.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Block file (.json) to write.")
def command(trajectory: str | None, events: str | None, rig_path: str | None, eo_path: str | None,
            camera_paths: tuple[str, ...], meas_paths: tuple[str, ...], control_path: str | None,
            check_path: str | None, sigma_px: float, gnss_sigma: str, imu_sigma_deg: str, control_sigma: str,
            free: str, crs: str | None, geoid: str | None, output: str) -> None:
    """Assemble a block file from a trajectory + events + rig (or EO + cameras), measurements and control."""
    from skyrig.adjust import AdjustConfig
    from skyrig.cli._common import load_measurements
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io.block_file import write_block
    from skyrig.io.points_csv import read_points_csv

    rig_mode = any(x is not None for x in (trajectory, events, rig_path))
    if rig_mode and not all(x is not None for x in (trajectory, events, rig_path)):
        raise click.UsageError("rig mode needs --trajectory, --events and --rig together")
    if rig_mode == (eo_path is not None):
        raise click.UsageError("give either --trajectory/--events/--rig or --eo/--camera")
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        raise click.BadParameter(f"--sigma-px must be positive, not {sigma_px}")
    gs = _triple(gnss_sigma, "--gnss-sigma")
    imu = tuple(np.radians(_triple(imu_sigma_deg, "--imu-sigma-deg")))
    cs = _triple(control_sigma, "--control-sigma")
    from skyrig.cli._common import project_frame_option

    project = project_frame_option(crs, geoid)
    groups = [g.strip() for g in free.split(",") if g.strip()]
    unknown = [g for g in groups if g not in _GROUPS]
    if unknown:
        raise click.BadParameter(f"--free: unknown group {unknown[0]!r}; known: {', '.join(_GROUPS)}")
    ms = [load_measurements(p) for p in meas_paths]
    if rig_mode:
        from skyrig.io.events_csv import read_events_csv

        known, source = set(read_events_csv(events).image_name.tolist()), events
    else:
        from skyrig.cli._common import load_eo

        known, source = set(load_eo(eo_path, None, None, None, None).image.tolist()), eo_path
    for path, x in zip(meas_paths, ms):
        bad = np.flatnonzero(~np.isin(x.image, list(known)))
        if len(bad):
            k = int(bad[0])
            err = click.ClickException(f"{path}: image {str(x.image[k])!r} (point {str(x.point[k])!r}, measurement {k + 1}) is not "
                                       f"in {source}; {len(bad)} measurement(s) name images without an orientation")
            err.exit_code = 2  # wrong input: 2, as every input error (docs/cli.md)
            raise err
    m = ImageMeasurements(np.concatenate([x.point for x in ms]), np.concatenate([x.image for x in ms]),
                          np.vstack([x.pixel for x in ms]))
    pts = [read_points_csv(p) for p in (control_path, check_path) if p is not None]
    checks: tuple[str, ...] = ()
    control = None
    if pts:
        if len(pts) == 2 and pts[0].frame != pts[1].frame:
            pts[1] = GroundPoints(pts[1].name, pts[0].frame.from_ecef(pts[1].frame.to_ecef(pts[1].xyz)), pts[0].frame)
        control = GroundPoints(np.concatenate([p.name for p in pts]), np.vstack([p.xyz for p in pts]), pts[0].frame)
        if check_path is not None:
            checks = tuple(str(n) for n in pts[-1].name)
    if rig_mode:
        from skyrig.adjust.rig_block import block_from_trajectory
        from skyrig.cli.georef import load_trajectory
        from skyrig.io.events_csv import read_events_csv
        from skyrig.io.rig_file import read_rig

        block, frame = block_from_trajectory(load_trajectory(trajectory, None), read_rig(rig_path),
                                             read_events_csv(events), m, control, gnss_sigma_m=gs,
                                             imu_sigma_rad=imu, control_sigma_m=cs, check_points=checks,
                                             sigma_px=sigma_px)
    else:
        from skyrig.adjust.frames import block_from_georef
        from skyrig.cli._common import load_cameras, load_eo

        eo = load_eo(eo_path, None, None, None, None)
        block, frame = block_from_georef(eo, load_cameras(list(camera_paths)), m, control, gnss_sigma_m=gs,
                                         imu_sigma_rad=imu, control_sigma_m=cs, check_points=checks,
                                         sigma_px=sigma_px)
    # the GNSS datum shift is free by default when control can separate it from a block translation;
    # --free datum-shift frees it in any case (one keyword each: the groups override the default)
    modes: dict[str, object] = {"datum_shift": "free" if len(block.gnss_station) and len(block.control_point)
                                else "fixed", "snooping": True}
    modes.update({_GROUPS[g]: "free" for g in groups})
    cfg = AdjustConfig(**modes)  # type: ignore[arg-type]
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    if project is None and control is not None and control.frame.kind == "map":
        project = control.frame
    if project is None and not rig_mode and eo.frame.kind == "map":
        project = eo.frame
    # a rig with actuated (tumbling) heads: the block file names the rig that defines them, relative to itself
    rig_file = os.path.relpath(rig_path, Path(output).parent) if rig_mode else None
    write_block(output, block, cfg, rig_file=rig_file, crs=project)
    click.echo(f"wrote {output}: {block.n_stations} stations, {block.n_images} images, {block.n_points} points, "
               f"{block.n_observations} image observations, {len(block.control_point)} ground points "
               f"({int(np.sum(block.control_check))} check), {len(block.gnss_station)} GNSS, "
               f"{len(block.imu_station)} IMU; frame {frame.describe()}; results in "
               + (project.describe() if project is not None else "the UTM zone of the block (no --crs, no map CRS in "
                  "the inputs)"))
