"""``skyrig transfer``: oblique (tumbling-head) orientations from adjusted nadir orientations -> EO file."""

from __future__ import annotations

import click


@click.command("transfer")
@click.option("--eo", "eo_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Adjusted orientations of the reference (nadir) images: skyrig EO CSV (e.g. skyrig adjust's eo.csv).")
@click.option("--rig", "rig_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Calibrated rig file (YAML) with the tumbling head and its boresight curve.")
@click.option("--events", "events_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Camera events CSV of both heads (image, time, head, beta).")
@click.option("--trajectory", "traj_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="GNSS/IMU trajectory (CSV or SBET) for obliques not taken with a nadir image: carries the adjusted "
                   "pose over the time difference (default: interpolate between adjusted exposures).")
@click.option("--reference", "traj_reference", type=click.Choice(["imu", "antenna"]), default=None,
              help="Point an SBET's positions refer to (CSV files say it in their header).")
@click.option("--no-curve", is_flag=True, help="Leave out the rig's beta-dependent boresight curve (nominal tumbling angles only).")
@click.option("--reference-head", default="nadir", show_default=True, help="The fixed head whose orientations were adjusted.")
@click.option("--heads", default=None, help="Heads to transfer to (comma list; default: every actuated head).")
@click.option("--max-gap", type=float, default=3.0, show_default=True,
              help="Seconds: largest time between adjusted exposures to interpolate across.")
@click.option("--with-reference", is_flag=True, help="Also write the reference images' orientations into the output.")
@click.option("--crs", default=None, help="Output CRS (default: the EO file's).")
@click.option("--geoid", default=None, help="Geoid grid for orthometric output heights (with --crs).")
@click.option("--angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True)
@click.option("--convention", type=click.Choice(["opk", "pok", "ypr"]), default="opk", show_default=True)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output EO CSV.")
def command(eo_path, rig_path, events_path, traj_path, traj_reference, no_curve, reference_head, heads, max_gap,
            with_reference, crs, geoid, angles, convention, output) -> None:
    """Oblique orientations from adjusted nadir orientations (paper 000): no adjustment of the obliques.

    Each oblique image's orientation is its exposure's body pose (from the adjusted nadir image through the nadir
    head's mounting) times the tumbling head's mounting at the image's actuator angle beta, with the rig's boresight
    correction curve at beta unless --no-curve.
    """
    import numpy as np

    from skyrig.cli._common import project_frame_option
    from skyrig.georef.transfer import METHODS, transfer_orientations, with_transferred
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.pipeline.inputs import load_trajectory

    if max_gap <= 0:
        raise click.BadParameter("must be a positive number of seconds", param_hint="--max-gap")
    frame = project_frame_option(crs, geoid)
    nadir = read_eo_csv(eo_path)
    rig = read_rig(rig_path)
    events = read_events_csv(events_path)
    traj = load_trajectory(traj_path, traj_reference) if traj_path else None
    if reference_head not in rig:
        raise click.BadParameter(f"the rig has no head {reference_head!r}; heads: {', '.join(rig.head_names)}",
                                 param_hint="--reference-head")
    want = None
    if heads:
        want = [h.strip() for h in heads.split(",") if h.strip()]
        for h in want:
            if h not in rig:
                raise click.BadParameter(f"the rig has no head {h!r}; heads: {', '.join(rig.head_names)}",
                                         param_hint="--heads")
    has_curve = any(getattr(h, "curve", None) is not None for h in rig if h.is_actuated)
    if not no_curve and not has_curve:
        click.echo(f"warning: the rig file {rig_path} has no boresight curve for its actuated head(s): nominal "
                   "tumbling angles only", err=True)
    eo = transfer_orientations(nadir, rig, events, curve=None if no_curve else "rig", trajectory=traj,
                               reference_head=reference_head, heads=want, frame=frame, max_gap_s=max_gap)
    out = with_transferred(nadir, eo) if with_reference else eo
    write_eo_csv(out, output, unit=angles, convention=convention)
    m = eo.extra["transfer_method"]
    how = ", ".join(f"{int(np.sum(m == k))} {METHODS[k]}" for k in range(len(METHODS)) if np.any(m == k))
    click.echo(f"transferred {len(eo)} orientations of head(s) {', '.join(sorted(set(eo.head)))} from "
               f"{reference_head} ({how}; {'boresight curve applied' if has_curve and not no_curve else 'no boresight curve'}) -> {output} "
               f"({out.frame.describe()})")
