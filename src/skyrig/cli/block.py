"""``skyrig block``: assemble a block file (docs/formats/block.md) from what a flight recorded.

Two ways in:

* rig mode - ``--trajectory``, ``--events``, ``--rig``: one station per platform exposure (the heads of a
  rig share its pose), GNSS antenna positions through the rig's antenna lever arm and IMU attitudes as
  observations (:func:`skyrig.adjust.rig_block.block_from_trajectory`);
* image mode - ``--eo`` + ``--camera``: one station per image, the given orientations as GNSS/IMU
  observations of the projection centres and attitudes (:func:`skyrig.adjust.frames.block_from_georef`).
  The EO file in any format the other commands read (skyrig EO CSV, IGN .OPK, ODM geo.txt; ``--eo-format``,
  ``--eo-crs``, ``--eo-geoid``, ``--eo-map-z-ground`` as for ``world-to-image``).

``--start-values-only``: the trajectory / EO gives the starting values only (no GNSS/IMU observations); the
datum then comes from the control points or ``--datum free``.  ``--datum`` (``auto``, ``free``: inner constraints
on the station poses, ``free-points``: on object points - all or ``--datum-points`` - as close-range programs
define it, ``none``) is recorded in the block file's adjustment section (:class:`skyrig.adjust.AdjustConfig`).
A rig with a tumbling head: ``--free actuator`` estimates the actuator's offset and scale, ``--free actuator-curve``
a Fourier boresight curve of order ``--fourier-order`` (paper 000's in-flight alternative to the laboratory curve).

Measurements (``--measurements``, repeatable: skyrig CSV, IGN .mes, ODM gcp_list.txt) in pixels; ground points
(``--control``, ``--check``: skyrig points CSV, IGN .app / _world.mes, ODM gcp_list.txt) in the CRS their file
states, else ``--points-crs`` (default: the EO's CRS).  Measurements the block leaves out are counted by reason
(a tie point measured in one image, a point seen from one exposure only, a gross residual at the start).
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
           "strip-shift": "strip_shift", "intrinsics": "intrinsics", "actuator": "actuator",
           "actuator-curve": "actuator_curve"}


def _block_cmd_class() -> type[click.Command]:
    from skyrig.cli._common import with_old_spellings

    # the sigma options read as in adjust-uav: comma text; three separate numbers accepted with a warning
    return with_old_spellings(renamed={"--sigma-px": "--image-sigma-px"},
                              spaced={"--gnss-sigma": 3, "--imu-sigma-deg": 3, "--control-sigma": 3})


def _sigmas(text: str, option: str, names: str) -> tuple[float, float, float]:
    from skyrig.cli._common import parse_sigmas

    a, b, c = parse_sigmas(text, 3, option, names, positive=True)
    return a, b, c


@click.command("block", cls=_block_cmd_class())
@click.option("--trajectory", type=click.Path(exists=True, dir_okay=False), help="Rig mode: trajectory CSV or SBET.")
@click.option("--reference", type=click.Choice(["imu", "antenna"]), default=None,
              help="Rig mode: point the SBET positions refer to (CSV files say it in their header).")
@click.option("--events", type=click.Path(exists=True, dir_okay=False), help="Rig mode: camera events CSV.")
@click.option("--rig", "rig_path", type=click.Path(exists=True, dir_okay=False), help="Rig mode: rig file (YAML).")
@click.option("--eo", "eo_path", type=click.Path(exists=True, dir_okay=False),
              help="Image mode: EO file (skyrig EO CSV, IGN .OPK, ODM geo.txt).")
@click.option("--eo-format", type=click.Choice(["ign-opk", "odm-geo", "skyrig-csv"]), default=None,
              help="EO file format (default: from the file name).")
@click.option("--eo-crs", default=None, help="CRS of the EO file when it does not say (e.g. EPSG:2154 for IGN .OPK).")
@click.option("--eo-geoid", default=None, help="Geoid grid (path or PROJ name) when EO heights are orthometric.")
@click.option("--eo-map-z-ground", type=float, default=None,
              help="Undo the linear alteration of projection-centre heights from an adjustment in map coordinates, "
                   "with this mean ground height (m).")
@click.option("--start-values-only", is_flag=True,
              help="The trajectory / EO gives starting values only, not GNSS/IMU observations (the datum then comes "
                   "from the control points or --datum free).")
@click.option("--camera", "camera_paths", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Image mode: camera / rig file(s).")
@click.option("--measurements", "meas_paths", multiple=True, required=True,
              type=click.Path(exists=True, dir_okay=False),
              help="Image measurements: skyrig CSV point,image,column,row, IGN .mes or ODM gcp_list.txt (repeatable).")
@click.option("--control", "control_path", type=click.Path(exists=True, dir_okay=False),
              help="Control points: skyrig points CSV, IGN .app / _world.mes or ODM gcp_list.txt.")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False),
              help="Check points (same formats): compared after the adjustment, not used in it.")
@click.option("--points-crs", default=None,
              help="CRS of the control / check points when their file does not state one (a skyrig CSV's header "
                   "or side-car wins and must agree with this; default: the EO's CRS).")
@click.option("--points-heights", type=click.Choice(["ellipsoidal", "orthometric"]), default="ellipsoidal",
              show_default=True, help="Height reference of point files that do not state theirs.")
@click.option("--points-geoid", default=None, help="Geoid grid when the point heights are orthometric.")
@click.option("--image-sigma-px", "sigma_px", type=float, default=0.5, show_default=True, help="Image measurement sigma (pixels).")
@click.option("--gnss-sigma", default="0.05,0.05,0.08", show_default=True,
              help="GNSS sigma east,north,up (m; one value for all axes).")
@click.option("--imu-sigma-deg", default="0.005,0.005,0.01", show_default=True,
              help="IMU attitude sigma roll,pitch,yaw (degrees; one value for all axes) in rig mode; about the "
                   "camera axes in image mode.")
@click.option("--control-sigma", default="0.02", show_default=True,
              help="Control point sigma X,Y,Z (m; one value for all axes).")
@click.option("--free", "free", default="", help=f"Comma-separated groups to estimate: {', '.join(_GROUPS)}.")
@click.option("--fourier-order", type=int, default=None,
              help="Order of the Fourier boresight curve of actuated heads estimated with --free actuator-curve "
                   "(default 2; paper 000's in-flight alternative to the laboratory curve).")
@click.option("--datum", type=click.Choice(["auto", "free", "free-points", "none"]), default="auto", show_default=True,
              help="auto: from the control and/or GNSS the block has; free: inner constraints on the station poses "
                   "(7-parameter similarity, minimum norm); free-points: inner constraints on object points (all, or "
                   "--datum-points), as close-range programs define the datum; none: no datum (the damping picks one "
                   "solution; no covariance).")
@click.option("--datum-points", default=None,
              help="With --datum free-points: comma list of the point names that define the datum (default: all).")
@click.option("--crs", "crs", default=None,
              help="Project CRS the adjusted results are written in (recorded in the block file); a compound CRS "
                   "(e.g. EPSG:25832+5773) gives orthometric heights through the geoid PROJ ties to it. Default: the "
                   "control points' CRS and heights, else the EO file's (image mode).")
@click.option("--geoid", default=None, help="With --crs: geoid grid (path or PROJ name) for orthometric heights.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Block file (.json) to write.")
def command(trajectory: str | None, reference: str | None, events: str | None, rig_path: str | None,
            eo_path: str | None, eo_format: str | None, eo_crs: str | None, eo_geoid: str | None,
            eo_map_z_ground: float | None, start_values_only: bool, camera_paths: tuple[str, ...],
            meas_paths: tuple[str, ...], control_path: str | None, check_path: str | None, points_crs: str | None,
            points_heights: str, points_geoid: str | None, sigma_px: float, gnss_sigma: str, imu_sigma_deg: str,
            control_sigma: str, free: str, fourier_order: int | None, datum: str, datum_points: str | None,
            crs: str | None, geoid: str | None, output: str) -> None:
    """Assemble a block file from a trajectory + events + rig (or EO + cameras), measurements and control."""
    from skyrig.adjust import AdjustConfig
    from skyrig.cli._common import load_eo, load_measurements, load_points
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io.block_file import write_block

    rig_mode = any(x is not None for x in (trajectory, events, rig_path))
    if rig_mode and not all(x is not None for x in (trajectory, events, rig_path)):
        raise click.UsageError("rig mode needs --trajectory, --events and --rig together")
    if rig_mode == (eo_path is not None):
        raise click.UsageError("give either --trajectory/--events/--rig or --eo/--camera")
    if rig_mode and any(x is not None for x in (eo_format, eo_crs, eo_geoid, eo_map_z_ground)):
        raise click.UsageError("--eo-format/--eo-crs/--eo-geoid/--eo-map-z-ground go with --eo (image mode)")
    if not rig_mode and reference is not None:
        raise click.UsageError("--reference goes with --trajectory (rig mode)")
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        raise click.BadParameter(f"must be positive, not {sigma_px}", param_hint="--image-sigma-px")
    gs = _sigmas(gnss_sigma, "--gnss-sigma", "east,north,up")
    imu = tuple(np.radians(_sigmas(imu_sigma_deg, "--imu-sigma-deg", "roll,pitch,yaw")))
    cs = _sigmas(control_sigma, "--control-sigma", "X,Y,Z")
    from skyrig.cli._common import project_frame_option

    project = project_frame_option(crs, geoid)
    groups = [g.strip() for g in free.split(",") if g.strip()]
    unknown = [g for g in groups if g not in _GROUPS]
    if unknown:
        raise click.BadParameter(f"--free: unknown group {unknown[0]!r}; known: {', '.join(_GROUPS)}")
    if fourier_order is not None and "actuator-curve" not in groups:
        raise click.UsageError("--fourier-order goes with --free actuator-curve")
    if fourier_order is not None and not 1 <= fourier_order <= 12:
        raise click.BadParameter("must be a whole number from 1 to 12", param_hint="--fourier-order")
    if datum_points is not None and datum != "free-points":
        raise click.UsageError("--datum-points goes with --datum free-points")
    ms = [load_measurements(p) for p in meas_paths]
    eo = None
    if rig_mode:
        from skyrig.io.events_csv import read_events_csv

        known, source = set(read_events_csv(events).image_name.tolist()), events
    else:
        eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
        known, source = set(eo.image.tolist()), eo_path
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
    default_crs = None
    if eo is not None:
        default_crs = eo_crs or (eo.frame.crs if eo.frame.kind == "map" else None)
    pts = [load_points(p, points_crs, points_heights, points_geoid, default_crs=default_crs)
           for p in (control_path, check_path) if p is not None]
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

        ev = read_events_csv(events)
        block, frame = block_from_trajectory(load_trajectory(trajectory, reference), read_rig(rig_path),
                                             ev, m, control, gnss_sigma_m=None if start_values_only else gs,
                                             imu_sigma_rad=None if start_values_only else imu, control_sigma_m=cs,
                                             check_points=checks, sigma_px=sigma_px)
        exposure = {str(n): int(e) for n, e in zip(ev.image_name, ev.exposure_id)}
    else:
        from skyrig.adjust.frames import block_from_georef
        from skyrig.cli._common import load_cameras

        assert eo is not None
        block, frame = block_from_georef(eo, load_cameras(list(camera_paths)), m, control,
                                         gnss_sigma_m=None if start_values_only else gs,
                                         imu_sigma_rad=None if start_values_only else imu, control_sigma_m=cs,
                                         check_points=checks, sigma_px=sigma_px)
        exposure = None
    n_control = int(np.sum(~block.control_check))
    if {"actuator", "actuator-curve"} & set(groups) and not any(a is not None for a in block.head_actuated):
        raise click.UsageError("--free actuator / actuator-curve: the rig has no actuated (tumbling) head")
    if datum == "auto" and not len(block.gnss_station) and n_control == 0:
        raise click.UsageError("the block has no datum: no GNSS observations (--start-values-only) and no control "
                               "point measured in its images; give --control or --datum free")
    dropped = dropped_measurements(m, block, control, exposure)
    # the GNSS datum shift is free by default when control can separate it from a block translation;
    # --free datum-shift frees it in any case (one keyword each: the groups override the default)
    modes: dict[str, object] = {"datum_shift": "free" if len(block.gnss_station) and len(block.control_point)
                                else "fixed", "snooping": True, "datum": "free" if datum == "free-points" else datum}
    modes.update({_GROUPS[g]: "free" for g in groups})
    if "actuator-curve" in groups:
        modes["actuator_fourier_order"] = fourier_order or 2
    if datum == "free-points":
        modes["inner_constraints"] = "points"
        if datum_points:
            modes["datum_points"] = tuple(p.strip() for p in datum_points.split(",") if p.strip())
    cfg = AdjustConfig(**modes)  # type: ignore[arg-type]
    Path(output).parent.mkdir(parents=True, exist_ok=True)
    if project is None and control is not None and control.frame.kind == "map":
        project = control.frame
    if project is None and eo is not None and eo.frame.kind == "map":
        project = eo.frame
    # a rig with actuated (tumbling) heads: the block file names the rig that defines them, relative to itself
    rig_file = os.path.relpath(rig_path, Path(output).parent) if rig_mode else None
    write_block(output, block, cfg, rig_file=rig_file, crs=project)
    click.echo(f"wrote {output}: {block.n_stations} stations, {block.n_images} images, {block.n_points} points, "
               f"{block.n_observations} image observations, {len(block.control_point)} ground points "
               f"({int(np.sum(block.control_check))} check), {len(block.gnss_station)} GNSS, "
               f"{len(block.imu_station)} IMU; frame {frame.describe()}; results in "
               + (project.describe() if project is not None else "the UTM zone of the block (no --crs, no map CRS in "
                  "the inputs)")
               + ("; GNSS/IMU as starting values only" if start_values_only else "") + f"; datum {datum}")
    total = sum(dropped.values())
    if total:
        click.echo(f"left out {total} of {len(m)} measurements: "
                   + "; ".join(f"{n} {DROP_REASONS[why]}" for why, n in dropped.items() if n))
    else:
        click.echo(f"left out 0 of {len(m)} measurements")


DROP_REASONS = {
    "single": "of tie points measured in one image only",
    "exposure": "of points whose images all come from one exposure (no base)",
    "gross": "of points more than 100 px from a measurement or behind a camera with the starting orientations",
    "other": "for another reason",
}


def dropped_measurements(m, block, control, exposure: dict[str, int] | None) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """How many of the measurements ``m`` the block left out, by reason (keys of :data:`DROP_REASONS`).

    A measurement is left out when its (point, image) pair is not among the block's observations; the reason is
    the first that applies to its point: measured in one image (and not a control point), all its images in one
    rig exposure (``exposure``: image -> exposure id; rig mode), else a gross residual at the start (rig mode
    drops such points)."""
    kept = set(zip(block.image_name[block.obs_image].tolist(), block.point_name[block.obs_point].tolist()))
    pts = m.point.astype(str)
    imgs = m.image.astype(str)
    lost = np.array([(i, p) not in kept for i, p in zip(imgs.tolist(), pts.tolist())], bool)
    out = dict.fromkeys(DROP_REASONS, 0)
    if not lost.any():
        return out
    ctrl = set() if control is None else set(control.name.astype(str).tolist())
    images_of: dict[str, set[str]] = {}
    for p, i in zip(pts.tolist(), imgs.tolist()):
        images_of.setdefault(p, set()).add(i)
    for k in np.flatnonzero(lost):
        p = pts[k]
        seen = images_of[p]
        if len(seen) < 2 and p not in ctrl:
            out["single"] += 1
        elif exposure is not None and len({exposure.get(i) for i in seen}) < 2:
            out["exposure"] += 1
        elif exposure is not None:
            out["gross"] += 1
        else:
            out["other"] += 1
    return out
