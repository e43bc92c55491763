"""``skyrig measure``: measure control and check points in the images, in a local web page (or ``--auto``)."""

from __future__ import annotations

from pathlib import Path

import click

from skyrig.cli._types import CONTROL_SIGMA_M, GNSS_SIGMA_M, IMU_SIGMA_DEG, PIXEL_SIGMA_PX


@click.command("measure")
@click.argument("project", required=False, type=click.Path(exists=True))
@click.option("--eo", "eo_path", type=click.Path(exists=True, dir_okay=False), help="Orientations (skyrig EO CSV, IGN .OPK, ODM geo.txt) instead of a project's.")
@click.option("--eo-format", default=None, help="EO file format (default: from the file name).")
@click.option("--eo-crs", default=None, help="CRS of the EO file when it does not say.")
@click.option("--eo-geoid", default=None, help="Geoid grid when EO heights are orthometric.")
@click.option("--camera", "camera_paths", multiple=True, type=click.Path(exists=True, dir_okay=False), help="Camera file (IGN camera .txt or skyrig rig YAML); repeat for several.")
@click.option("--images", "image_dirs", multiple=True, type=click.Path(exists=True, file_okay=False), help="Image folder; repeat for several.")
@click.option("--points", "points_path", type=click.Path(exists=True, dir_okay=False), help="Control points (skyrig CSV name,x,y,z, IGN .app, ODM gcp_list.txt).")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False), help="Check points (same formats).")
@click.option("--points-crs", default=None, help="CRS of point files that state none (default: the EO's).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="Measurements CSV to continue and write (default: the project's gcp/image_measurements.csv).")
@click.option("--adjustment", type=click.Path(exists=True), help="An adjustment's ground_control.csv, or its folder (the one of its report.html): its control / check residuals are shown with the points (default: the project's, next to the orientations used).")
@click.option("--eo-sigma", type=GNSS_SIGMA_M.each, default=0.10, show_default=True, help="Standard deviation of the projection centres (m, each axis) the prediction ellipses assume.")
@click.option("--attitude-sigma", type=IMU_SIGMA_DEG.each, default=0.01, show_default=True, help="Standard deviation of the orientation angles (deg).")
@click.option("--points-sigma", type=CONTROL_SIGMA_M.each, default=0.02, show_default=True, help="Standard deviation of the ground points (m, each axis).")
@click.option("--pixel-sigma", type=PIXEL_SIGMA_PX, default=0.5, show_default=True, help="Standard deviation of an unrefined click (px).")
@click.option("--operator", default=None, help="Who measures (default: the login name); written with every measurement.")
@click.option("--port", type=int, default=0, show_default=True, help="Port on 127.0.0.1 (0: any free port).")
@click.option("--no-browser", is_flag=True, help="Do not open a browser; only print the page's address.")
@click.option("--targets", default="aruco,coded,chequer,disc", show_default=True, help="Target kinds the refinement and --auto look for, in this order: aruco (ArUco / AprilTag markers), coded (circular ring-coded targets), chequer (2 x 2 checkerboard corners), disc; 'none' for none.")
@click.option("--target-radius", type=click.FloatRange(min=0.0, min_open=True), default=None, help="Radius of the targets in metres (a coded target's centre dot), for points whose file has no target_radius_m: where a coded point's dot is predicted under 2.5 px its code cannot be read and no target fit is made (the page says why, --auto skips the image).")
@click.option("--auto", is_flag=True, help="No page: detect the targets around every prediction, store them as 'detected' and exit.")
def command(project, eo_path, eo_format, eo_crs, eo_geoid, camera_paths, image_dirs, points_path, check_path, points_crs,
            output, adjustment, eo_sigma, attitude_sigma, points_sigma, pixel_sigma, operator, port, no_browser, targets, target_radius,
            auto) -> None:
    """Measure ground control and check points in the images of PROJECT (a project.yaml or a flight folder), or of
    --eo/--camera/--images/--points: a local page (127.0.0.1, a random token in its address) lists the points and
    the images predicted to see them, refines each click to the target's centre and saves every change to the
    measurements CSV."""
    from skyrig.cli._common import load_cameras, load_eo, load_points
    from skyrig.web.inputs import (MeasureInputs, adjustment_residuals, image_files, merge_points, point_targets,
                                   project_inputs)
    from skyrig.web.measure import MeasureSession, PointTarget, Sigmas

    if project is None and not eo_path:
        raise click.UsageError("give a PROJECT or --eo with --camera, --images and --points")
    inp = project_inputs(project) if project else MeasureInputs()
    if eo_path:
        inp.eo_path, inp.eo, inp.eo_words, inp.adjusted_control = Path(eo_path).absolute(), None, "--eo", None
    if adjustment:
        inp.adjusted_control = _ground_control(Path(adjustment))
    inp.cameras = [Path(c) for c in camera_paths] or inp.cameras
    inp.images = [Path(d) for d in image_dirs] or inp.images
    inp.control = Path(points_path) if points_path else inp.control
    inp.check = Path(check_path) if check_path else inp.check
    inp.output = Path(output) if output else inp.output
    for what, have in (("--camera", inp.cameras), ("--images", inp.images), ("-o/--output", inp.output)):
        if not have:
            raise click.UsageError(f"missing option {what}")
    eo = inp.eo if inp.eo is not None else load_eo(inp.eo_path, eo_format, eo_crs or inp.crs, eo_geoid or inp.geoid)
    cams = load_cameras([str(c) for c in inp.cameras])
    default = points_crs or eo_crs or (eo.frame.crs if eo.frame.kind == "map" else None)
    ctl = load_points(inp.control, points_crs, default_crs=default) if inp.control else None
    chk = load_points(inp.check, points_crs, default_crs=default) if inp.check else None
    pts, roles = merge_points(ctl, chk, str(inp.check or ""))
    files = image_files(inp.images, eo.image)
    click.echo(f"orientations: {inp.eo_words or inp.eo_path} ({len(eo)} images, {len(files)} found in "
               f"{', '.join(map(str, inp.images))})")
    if not files:
        raise click.UsageError(f"none of the {len(eo)} images of the orientations is in "
                               f"{', '.join(map(str, inp.images))}")
    sig = Sigmas(eo_sigma, attitude_sigma, points_sigma, pixel_sigma)
    kinds = _target_kinds(targets)
    given = point_targets([inp.control, inp.check])
    default_r = float("nan") if target_radius is None else float(target_radius)
    tgt = {}
    for n in map(str, pts.name):
        code, r = given.get(n, (None, float("nan")))
        tgt[n] = PointTarget(code, r if r == r else default_r)  # the file's radius, else --target-radius
    session = MeasureSession(eo, cams, pts, roles, files, inp.output, sig, operator,
                             {"eo": str(inp.eo_path or inp.eo_words),
                              "points": [str(p) for p in (inp.control, inp.check) if p]},
                             adjustment=adjustment_residuals(inp.adjusted_control) if inp.adjusted_control else None,
                             target_kinds=kinds, point_targets=tgt)
    if inp.adjusted_control:
        click.echo(f"adjustment residuals: {inp.adjusted_control}")
    try:
        click.echo(f"{len(pts)} ground points ({sum(r == 'check' for r in roles.values())} check); "
                   f"{len(session.records)} measurements already in {inp.output}")
        if auto:
            _auto(session)
            return
        _serve(session, port, no_browser)
    finally:
        session.close()


def _ground_control(path: Path) -> Path:
    """``--adjustment``: a ground_control.csv, or the adjustment folder that holds one."""
    if path.is_dir():
        if not (path / "ground_control.csv").is_file():
            raise click.BadParameter(f"no ground_control.csv in the folder {path} (an adjustment's output folder "
                                     "with control or check points?)", param_hint="--adjustment")
        return path / "ground_control.csv"
    return path


def _target_kinds(text: str) -> tuple[str, ...]:
    from skyrig.web.measure import TARGET_KINDS

    kinds = tuple(k.strip() for k in text.split(",") if k.strip() and k.strip() != "none")
    bad = [k for k in kinds if k not in TARGET_KINDS]
    if bad:
        raise click.BadParameter(f"unknown target kind {bad[0]!r} (known: {', '.join(TARGET_KINDS)}, none)",
                                 param_hint="--targets")
    return kinds


def _auto(session) -> None:
    n = n_skip = 0
    for p in session.points.name:
        got = session.detect(str(p), accept=True)
        n += len(got["found"])
        n_skip += len(got["skipped"])
        click.echo(f"{p}: {len(got['found'])} target(s) detected" +
                   (f", {len(got['skipped'])} image(s) passed over:" if got["skipped"] else ""))
        for s in got["skipped"]:
            click.echo(f"  {s['image']}: {s['reason']}")
    click.echo(f"wrote {len(session.records)} measurements ({n} detected now"
               + (f", {n_skip} passed over with the reason above" if n_skip else "") + f") to {session.output}")


def _serve(session, port: int, no_browser: bool) -> None:
    import time
    import webbrowser

    from skyrig.web.server import MeasureServer

    srv = MeasureServer(session, port=port, title=f"skyrig measure - {session.output.name}").start()
    click.echo(f"measuring page (this machine only): {srv.url}")
    click.echo("every accepted measurement is saved at once; Ctrl-C ends the session")
    if not no_browser:
        webbrowser.open(srv.url)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        click.echo("session ended")
    finally:
        srv.stop()
