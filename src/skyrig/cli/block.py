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

A thin shim: the work is :func:`skyrig.pipeline.orientation.make_block` (which the project's ``block`` stage calls).
"""

from __future__ import annotations

import click

from skyrig.cli._types import CONTROL_SIGMA_M, GNSS_SIGMA_M, IMU_SIGMA_DEG, PIXEL_SIGMA_PX

from skyrig.pipeline.orientation import BLOCK_GROUPS as _GROUPS

__all__ = ["command"]


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
@click.option("--image-sigma-px", "sigma_px", type=PIXEL_SIGMA_PX, default=0.5, show_default=True, help="Image measurement sigma (pixels).")
@click.option("--gnss-sigma", type=GNSS_SIGMA_M, default="0.05,0.05,0.08", show_default=True,
              help="GNSS sigma east,north,up (m; one value for all axes).")
@click.option("--imu-sigma-deg", type=IMU_SIGMA_DEG, default="0.005,0.005,0.01", show_default=True,
              help="IMU attitude sigma roll,pitch,yaw (degrees; one value for all axes) in rig mode; about the "
                   "camera axes in image mode.")
@click.option("--control-sigma", type=CONTROL_SIGMA_M, default="0.02", show_default=True,
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
@click.option("--snooping-per-round", type=int, default=10, show_default=True,
              help="Image observations data snooping may reject in one round of the adjustment: the largest "
                   "normalised residual and further ones above the critical value that share neither point nor image "
                   "with a larger one (1: Baarda's one at a time; each round costs one statistics pass).")
@click.option("--snooping-per-round-share", type=float, default=0.0, show_default=True,
              help="... or this share of the tested observations when that is more, so that the rounds do not grow "
                   "with the block (e.g. 0.001 for large blocks; 0: --snooping-per-round alone).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Block file (.json) to write.")
def command(trajectory: str | None, reference: str | None, events: str | None, rig_path: str | None,
            eo_path: str | None, eo_format: str | None, eo_crs: str | None, eo_geoid: str | None,
            eo_map_z_ground: float | None, start_values_only: bool, camera_paths: tuple[str, ...],
            meas_paths: tuple[str, ...], control_path: str | None, check_path: str | None, points_crs: str | None,
            points_heights: str, points_geoid: str | None, sigma_px: float, gnss_sigma: str, imu_sigma_deg: str,
            control_sigma: str, free: str, fourier_order: int | None, datum: str, datum_points: str | None,
            crs: str | None, geoid: str | None, snooping_per_round: int, snooping_per_round_share: float,
            output: str) -> None:
    """Assemble a block file from a trajectory + events + rig (or EO + cameras), measurements and control."""
    from skyrig.pipeline.orientation import make_block

    gs = _sigmas(gnss_sigma, "--gnss-sigma", "east,north,up")
    imu = _sigmas(imu_sigma_deg, "--imu-sigma-deg", "roll,pitch,yaw")
    cs = _sigmas(control_sigma, "--control-sigma", "X,Y,Z")
    groups = [g.strip() for g in free.split(",") if g.strip()]
    points = None if datum_points is None else [p.strip() for p in datum_points.split(",") if p.strip()]
    res = make_block(output, meas_paths, trajectory=trajectory, reference=reference, events=events, rig=rig_path,
                     eo=eo_path, eo_format=eo_format, eo_crs=eo_crs, eo_geoid=eo_geoid,
                     eo_map_z_ground=eo_map_z_ground, start_values_only=start_values_only, cameras=camera_paths,
                     control=control_path, check=check_path, points_crs=points_crs, points_heights=points_heights,
                     points_geoid=points_geoid, sigma_px=sigma_px, gnss_sigma=gs, imu_sigma_deg=imu,
                     control_sigma=cs, free=groups, fourier_order=fourier_order, datum=datum, datum_points=points,
                     crs=crs, geoid=geoid, snooping_per_round=snooping_per_round,
                     snooping_per_round_share=snooping_per_round_share, spell=_spell)
    for line in res.summary_lines():
        click.echo(line)


def _spell(name: str) -> str:
    """How this command names a library option (``sigma_px`` -> ``--image-sigma-px``)."""
    return {"sigma_px": "--image-sigma-px"}.get(name, "--" + name.replace("_", "-"))
