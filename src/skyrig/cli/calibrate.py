"""``skyrig calibrate RECIPE``: the papers' calibration recipes (:mod:`skyrig.calibrate`).

``skyrig calibrate uncalibrated-gnss-imu``: the system calibration of a flight delivered with uncalibrated
GNSS/IMU data (paper 003, :mod:`skyrig.calibrate.gnss_imu`); writes the calibrated rig file, the corrected
trajectory and EO, and a JSON + HTML report with the paper's tables (printed too).

``skyrig calibrate camera``: test-field (cage) calibration of one camera (paper 004, section 2.5) from the
target coordinates (points CSV ``name,x,y,z``, metres in the test field's Cartesian frame) and the image
measurements (measurements CSV ``point,image,column,row``), with fixed stations (a points CSV of the
projection centres, named by image) or free ones; writes the calibrated camera into a calibrated rig file
and a JSON report.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from skyrig.cli._types import CONTROL_SIGMA_M, GNSS_SIGMA_M, IMU_SIGMA_DEG, PIXEL_SIGMA_PX, PIXEL_SIGMA_UM


@click.group("calibrate")
def command() -> None:
    """Calibration recipes; the result is a calibrated rig file and a report."""


@command.command("camera")
@click.option("--points", "points_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Target coordinates: points CSV name,x,y,z (metres, the test field's Cartesian frame; a CRS header "
                   "is not used). The targets are fixed.")
@click.option("--measurements", "meas_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Image measurements CSV point,image,column,row (pixels).")
@click.option("--stations", "stations_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Projection centres: points CSV name,x,y,z with name = image name; the stations are then fixed "
                   "(only the rotations are estimated). Without it the stations are free.")
@click.option("--rig", "rig_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Rig file holding the camera to calibrate (its size, pixel size and starting values); the output "
                   "rig is this rig with the head's camera calibrated.")
@click.option("--head", default=None, help="Head of --rig to calibrate (default: the only one).")
@click.option("--name", default="camera", show_default=True, help="Camera name (without --rig).")
@click.option("--width-px", type=int, default=None, help="Image width (without --rig).")
@click.option("--height-px", type=int, default=None, help="Image height (without --rig).")
@click.option("--pixel-size-um", type=float, default=None, help="Pixel pitch (without --rig).")
@click.option("--focal-mm", type=float, default=None, help="Starting principal distance (without --rig).")
@click.option("--model", default="brown", show_default=True,
              help="Distortion model to calibrate (brown, forward, opencv, ...).")
@click.option("--r0-mm", type=float, default=None, help="Radius of zero distortion of the forward model.")
@click.option("--parameters", default=None,
              help="Comma-separated intrinsics to estimate (default: all of the model, a forward model's "
                   "distortion centre excepted).")
@click.option("--image-sigma-px", type=PIXEL_SIGMA_PX, default=0.1, show_default=True, help="Sigma of an image coordinate.")
@click.option("--flight", default="", help="Provenance: session / data set.")
@click.option("--date", default="", help="Provenance: date of the images (ISO 8601).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Calibrated rig file (YAML).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="JSON report (default: the output with suffix .json).")
def camera_command(points_path, meas_path, stations_path, rig_path, head, name, width_px, height_px, pixel_size_um,
                   focal_mm, model, r0_mm, parameters, image_sigma_px, flight, date, output, report_path) -> None:
    """Test-field (cage) calibration of one camera: fixed targets, fixed or free stations, self-calibration."""
    from skyrig.calibrate.camera import calibrate_camera
    from skyrig.camera.distortion import distortion_class
    from skyrig.camera.frame import FrameCamera
    from skyrig.georef.eo import WorldFrame
    from skyrig.io._text import atomic_write
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.rig import Head, Rig

    object_frame = WorldFrame.local(0.0, 0.0, 0.0)  # a stand-in: coordinates are used as Cartesian metres
    if rig_path is not None:
        from skyrig.io.rig_file import read_calibrated_rig

        rig, rig_cal = read_calibrated_rig(rig_path)
        if head is None:
            if len(rig) != 1:
                raise click.UsageError(f"--rig has {len(rig)} heads ({', '.join(rig.head_names)}); name one with --head")
            head = rig.head_names[0]
        cam0 = rig.head(head).camera
    else:
        missing = [o for o, v in (("--width-px", width_px), ("--height-px", height_px),
                                  ("--pixel-size-um", pixel_size_um), ("--focal-mm", focal_mm)) if v is None]
        if missing:
            raise click.UsageError(f"without --rig give {', '.join(missing)}")
        cam0 = FrameCamera(name, width_px, height_px, pixel_size_um / 1000.0, focal_mm)
        rig, rig_cal, head = None, None, name
    try:
        cls = distortion_class(model)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--model") from None
    if r0_mm is not None:
        if "r0_mm" not in cls.constant_names:
            raise click.BadParameter(f"model {model!r} has no radius of zero distortion", param_hint="--r0-mm")
        start = cls(r0_mm=r0_mm) if cam0.distortion.name != cls.name else cam0.distortion.__class__(
            **{**cam0.distortion.params_dict(), "r0_mm": r0_mm})
    else:
        start = cam0.distortion if cam0.distortion.name == cls.name else cls()
    targets = read_points_csv(points_path, object_frame)
    meas = read_measurements_csv(meas_path)
    centres = None
    if stations_path is not None:
        st = read_points_csv(stations_path, object_frame)
        centres = {str(n): x for n, x in zip(st.name, st.xyz)}
    params = None if parameters is None else tuple(p.strip() for p in parameters.split(",") if p.strip())
    cal = calibrate_camera(cam0, targets.name, targets.xyz, meas.image, meas.point, meas.pixel, model=start,
                           parameters=params, stations="fixed" if centres is not None else "free",
                           station_centres=centres, image_sigma_px=image_sigma_px)
    new_cal = cal.rig_calibration(head, flight, date)
    if rig is None:
        out_rig = Rig(cal.camera.name, [Head(head, cal.camera)], description="camera calibrated by skyrig calibrate camera")
        out_cal = new_cal
    else:
        from skyrig.calibrate.rig_calibration import HeadCalibration, RigCalibration

        heads = [h.with_(camera=cal.camera) if h.name == head else h for h in rig]
        out_rig = Rig(rig.name, heads, rig.antenna_lever_arm_m, rig.description)
        old = dict(rig_cal.heads) if rig_cal is not None else {}
        prev = old.get(head, HeadCalibration())
        old[head] = HeadCalibration(prev.lever_arm_m, prev.boresight_opk_deg, new_cal.heads[head].interior,
                                    prev.actuator, new_cal.heads[head].provenance)
        out_cal = RigCalibration(old, None if rig_cal is None else rig_cal.antenna_lever_arm_m,
                                 None if rig_cal is None else rig_cal.provenance)
    report = cal.to_dict()
    report["inputs"] = {"points": str(points_path), "measurements": str(meas_path), "stations": stations_path,
                        "rig": rig_path, "head": head}
    report["output"] = str(output)
    write_rig(out_rig, output, out_cal)
    report_path = report_path or str(Path(output).with_suffix(".json"))
    with atomic_write(report_path) as fh:
        json.dump(report, fh, indent=2)
        fh.write("\n")
    names = ", ".join(f"{n} {v:.6g} ± {s:.2g}" for n, v, s in zip(cal.parameters, cal.values, cal.sigma))
    click.echo(f"calibrated {cal.camera.name!r} ({cal.camera.distortion.name}) from {len(cal.image_names)} images, "
               f"{cal.n_observations} observations: sigma0 {cal.sigma0:.3f}, redundancy {cal.redundancy}, residual RMS "
               f"{cal.residual_rms_px[0]:.3f} / {cal.residual_rms_px[1]:.3f} px")
    click.echo(names)
    click.echo(f"-> {output}, {report_path}")


def _read_positions(path: str) -> tuple[list[str], list[str], list[float]]:
    """The positions CSV of ``calibrate tumbling-head``: ``image,circle,beta_deg`` (one row per tumbling image)."""
    import csv

    import numpy as np

    from skyrig.errors import InputFormatError

    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    body = [(i + 1, r) for i, r in enumerate(rows) if r and not r[0].lstrip().startswith("#")]
    if not body:
        raise InputFormatError("no column header row", path)
    hline, header = body[0]
    header = [h.strip() for h in header]
    for col in ("image", "circle", "beta_deg"):
        if col not in header:
            raise InputFormatError("missing column", path, hline, col)
    ix = {c: header.index(c) for c in ("image", "circle", "beta_deg")}
    names, circles, betas = [], [], []
    seen: set[str] = set()
    for line, r in body[1:]:
        if len(r) != len(header):
            raise InputFormatError(f"{len(r)} fields, the header has {len(header)}", path, line)
        name = r[ix["image"]].strip()
        if not name:
            raise InputFormatError("empty image name", path, line, "image")
        if name in seen:
            raise InputFormatError(f"image {name!r} listed twice", path, line, "image")
        seen.add(name)
        try:
            b = float(r[ix["beta_deg"]])
        except ValueError:
            raise InputFormatError(f"not a number: {r[ix['beta_deg']]!r}", path, line, "beta_deg") from None
        if not np.isfinite(b):
            raise InputFormatError("not a finite angle", path, line, "beta_deg")
        names.append(name)
        circles.append(r[ix["circle"]].strip())
        betas.append(b)
    if not names:
        raise InputFormatError("no rows", path)
    return names, circles, betas


@command.command("tumbling-head")
@click.option("--images", "images_dir", required=True, type=click.Path(exists=True, file_okay=False),
              help="Folder of the laboratory images (tumbling camera and the reference camera's image).")
@click.option("--rig", "rig_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Rig file with the tumbling (actuated) head and the static reference camera as a fixed head; "
                   "the tumbling head's curve, if any, is ignored (the recipe measures it).")
@click.option("--positions", "positions_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="CSV image,circle,beta_deg: every tumbling image, its circle and its actuator angle (degrees).")
@click.option("--reference-image", default="reference.png", show_default=True,
              help="The reference camera's image in --images (one: the camera does not move).")
@click.option("--reference-series", default=None,
              help="The reference camera's images of the whole session, a pattern in --images (e.g. "
                   "'*_reference.png'): each is block-matched against --reference-image, and the recipe refuses "
                   "when the camera moved by more than 5 x the matching precision (paper 000: the reference must "
                   "not move).")
@click.option("--head", default=None, help="The tumbling head of --rig (default: the only actuated one).")
@click.option("--reference-head", default="reference", show_default=True, help="The reference camera's head.")
@click.option("--plane-distance-m", type=float, required=True,
              help="Distance of the textured plane below the sensor head origin along body z (metres).")
@click.option("--window-px", type=int, default=32, show_default=True,
              help="Side of the non-overlapping correlation windows (tumbling image pixels).")
@click.option("--max-failed-share", type=float, default=0.10, show_default=True,
              help="An image that cannot be measured is left out with a warning (named in the reports); more than "
                   "this share of failed images stops the recipe (a systematic problem, not a bad image).")
@click.option("--min-circles", type=int, default=2, show_default=True,
              help="Every actuator position must keep at least this many measured circles (>= 2).")
@click.option("--flight", default="", help="Provenance: laboratory session.")
@click.option("--date", default="", help="Provenance: date of the images (ISO 8601).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Calibrated rig file (YAML).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="JSON report (default: the output with suffix .json); an HTML table is written next to it.")
def tumbling_head_command(images_dir, rig_path, positions_path, reference_image, reference_series, head,
                          reference_head, plane_distance_m, window_px, max_failed_share, min_circles, flight, date,
                          output, report_path) -> None:
    """Laboratory calibration of a tumbling head (paper 000): boresight curve, repeatability (Tab. 2)."""
    import html

    import numpy as np

    from skyrig import __version__
    from skyrig.calibrate.tumbling import LabSetup, calibrate_tumbling_head
    from skyrig.errors import SkyrigError
    from skyrig.io._text import atomic_write
    from skyrig.io.image_read import read_image
    from skyrig.io.rig_file import read_calibrated_rig, write_rig

    rig, rig_cal = read_calibrated_rig(rig_path)
    if head is None:
        act = [h.name for h in rig if h.is_actuated]
        if len(act) != 1:
            raise click.UsageError(f"--rig has {len(act)} actuated heads ({', '.join(act) or 'none'}); name one with --head")
        head = act[0]
    try:
        setup = LabSetup(rig, head, reference_head, plane_distance_m)
    except SkyrigError as exc:
        raise click.BadParameter(str(exc)) from None
    names, circles, betas = _read_positions(positions_path)
    folder = Path(images_dir)
    ref = read_image(folder / reference_image, gray=False)

    def load(name: str) -> np.ndarray:
        return read_image(folder / name, gray=False)

    ref_check = _reference_check(folder, reference_image, reference_series, ref, setup) if reference_series else None
    cal = calibrate_tumbling_head(setup, load, names, circles, np.radians(betas), ref, window_px=window_px,
                                  min_circles=min_circles, max_failed_share=max_failed_share)
    out_cal = cal.rig_calibration(flight, date, f"skyrig {__version__}", rig_cal)
    write_rig(cal.calibrated_rig(), output, out_cal)
    report = cal.to_dict()
    report["inputs"] = {"images": str(images_dir), "rig": str(rig_path), "positions": str(positions_path),
                        "reference_image": reference_image}
    report["output"] = str(output)
    if ref_check is not None:
        report["reference_check"] = ref_check
    report_path = report_path or str(Path(output).with_suffix(".json"))
    with atomic_write(report_path) as fh:
        json.dump(report, fh, indent=2)
        fh.write("\n")
    t2 = report["table2_2sigma"]
    p2 = report["table2_paper000_mdeg"]
    rows = "".join(f"<tr><td>{a}</td><td>{v['mean_std_mdeg']:.1f}/1000 deg</td><td>{v['max_std_mdeg']:.1f}/1000 deg "
                   f"at beta {v['beta_at_max_deg']:.1f} deg ({html.escape(v['image_at_max'])})</td>"
                   f"<td>{v['measurement_sigma_mdeg']:.1f}/1000 deg</td><td>{v['mechanism_std_mdeg']:.1f} &plusmn; "
                   f"{v['mechanism_std_se_mdeg']:.1f}/1000 deg</td><td>{p2[a]['mean_std_mdeg']:g} / "
                   f"{p2[a]['max_std_mdeg']:g} (photo {p2[a]['photo_at_max']:03d})</td></tr>" for a, v in t2.items())
    curve = "".join(f"<tr><td>{c['beta_deg']:.2f}</td>" + "".join(
        f"<td>{c[a + '_mdeg']:.2f} &plusmn; {c[a + '_std_mdeg']:.2f}</td>" for a in ("droll", "dpitch", "dyaw"))
        + "</tr>" for c in report["curve"])
    page = (f"<!doctype html><meta charset='utf-8'><title>tumbling-head calibration</title>"
            f"<h1>Tumbling head {html.escape(head)}: laboratory calibration</h1>"
            f"<p>{cal.beta_rad.size} actuator positions x {len(cal.circles)} circles against reference camera "
            f"{html.escape(reference_head)}, plane {plane_distance_m:g} m below the sensor head.</p>"
            "<h2>Repeat accuracies (paper 000 Tab. 2 style)</h2><table border=1><tr><th>axis</th>"
            "<th>mean standard deviation (2&sigma;)</th><th>max standard deviation (2&sigma;)</th>"
            "<th>one image's measurement sigma (2&sigma;)</th>"
            "<th>mechanism repeatability, measurement noise removed (2&sigma; &plusmn; its standard error)</th>"
            "<th>paper 000 Tab. 2: mean / max (2&sigma;, 1/1000 deg; MACS-TumbleCam, 72 x 5)</th></tr>"
            f"{rows}</table><h2>Mean correction curve (1/1000 deg, &plusmn; 1&sigma; repeatability)</h2>"
            "<table border=1><tr><th>beta (deg)</th><th>droll</th><th>dpitch</th><th>dyaw</th></tr>"
            f"{curve}</table>"
            f"<h2>How far the curve may be from the mechanism's</h2><p>{html.escape(_curve_statement_line(report))}</p>"
            + (f"<h2>Reference camera over the session</h2><p>{html.escape(_reference_line(ref_check))}</p>"
               if ref_check else "")
            + (f"<h2>Images left out ({len(cal.failed)} of {cal.images.size})</h2><table border=1><tr><th>image</th>"
               "<th>circle</th><th>beta (deg)</th><th>reason</th></tr>" + "".join(
                   f"<tr><td>{html.escape(f.name)}</td><td>{html.escape(f.circle)}</td>"
                   f"<td>{np.degrees(f.beta_rad):.2f}</td><td>{html.escape(f.reason)}</td></tr>" for f in cal.failed)
               + "</table>" if cal.failed else ""))
    html_path = Path(report_path).with_suffix(".html")
    with atomic_write(html_path) as fh:
        fh.write(page)
    click.echo(f"tumbling head {head!r}: {cal.beta_rad.size} positions x {len(cal.circles)} circles, "
               f"{int(cal.windows.min())}-{int(cal.windows.max())} windows per image")
    click.echo("repeat accuracies (2 sigma, 1/1000 deg): " + "; ".join(
        f"{a} mean {v['mean_std_mdeg']:.1f} max {v['max_std_mdeg']:.1f} at beta {v['beta_at_max_deg']:.1f}"
        for a, v in t2.items()))
    click.echo("mechanism repeatability, measurement noise removed (2 sigma, 1/1000 deg): " + "; ".join(
        f"{a} {v['mechanism_std_mdeg']:.1f} +- {v['mechanism_std_se_mdeg']:.1f} (one image's measurement sigma "
        f"{v['measurement_sigma_mdeg']:.1f})" for a, v in t2.items()))
    click.echo(_curve_statement_line(report))
    if ref_check:
        click.echo(_reference_line(ref_check))
    if cal.failed:
        click.echo(f"WARNING: {len(cal.failed)} of {cal.images.size} images left out (their positions' statistics "
                   f"use the other circles; fewest circles at a position {int(cal.counts.min())}): " + "; ".join(
                       f"{f.name} (circle {f.circle}, beta {np.degrees(f.beta_rad):.2f} deg): {f.reason}"
                       for f in cal.failed))
    click.echo(f"-> {output}, {report_path}, {html_path}")


def _reference_check(folder: Path, reference_image: str, pattern: str, ref: Any, setup: Any) -> dict:
    """Block matching of the reference camera's session images (``pattern`` in ``folder``) against
    ``reference_image``; a moved camera is refused (:class:`~skyrig.errors.ReferenceCameraMoved`)."""
    from skyrig.calibrate.tumbling_reference import reference_stability
    from skyrig.errors import ReferenceCameraMoved, SkyrigError
    from skyrig.io.image_read import read_image

    paths = sorted(p for p in folder.glob(pattern) if p.name != reference_image)
    if not paths:
        raise click.BadParameter(f"no image in {folder} matches {pattern!r}", param_hint="--reference-series")
    cam = setup.rig.head(setup.reference_head).camera
    try:
        check = reference_stability([ref] + [read_image(p, gray=False) for p in paths],
                                    [reference_image] + [p.name for p in paths],
                                    ifov_rad=cam.pixel_size_mm / cam.focal_mm)
        check.require_static()
    except ReferenceCameraMoved as exc:
        raise click.ClickException(f"ReferenceCameraMoved: {exc}") from None
    except SkyrigError as exc:
        raise click.BadParameter(str(exc), param_hint="--reference-series") from None
    return check.to_dict()


def _reference_line(check: dict) -> str:
    """The reference camera's check in one sentence."""
    return (f"reference camera still over the session: {check['images']} images block-matched against "
            f"{check['template']}, largest displacement {check['max_movement_px']:.4f} px "
            f"({check['max_movement_mdeg']:.2f}/1000 deg), threshold {check['threshold_px']:.4f} px "
            f"({check['threshold_mdeg']:.2f}/1000 deg) = {check['k_sigma']:g} x the matching precision "
            f"{check['sigma_px']:.5f} px")


def _curve_statement_line(report: dict) -> str:
    """The report's ``curve_statement`` in one sentence: the simultaneous bands of the lookup and the series."""
    cs = report.get("curve_statement") or {}
    lk = cs.get("lookup")
    if not lk:
        return ""
    pct = 100 * cs["level"]
    out = (f"curve, {pct:.0f} % simultaneous bands: lookup table {lk['values']} values within "
           f"{lk['simultaneous_z']:.2f} sigma (every value within 2 sigma: probability "
           f"{lk['p_every_value_within_2sigma']:.2g} with exact sigmas)")
    share = lk.get("repeat_share")
    if share:  # the per-position sigma's model: circle scatter / C + the repeating share of the fit variance
        se = lk.get("repeat_share_se") or {}
        out += (f"; per-position sigma = sqrt(pooled^2/C + share x fit^2), the comparison error's repeating share "
                + ", ".join(f"{a} {v:.2f} +- {se.get(a, float('nan')):.2f}" for a, v in share.items())
                + f" (REML, series of order {lk.get('repeat_share_order')}, {lk.get('repeat_share_dof')} dof)")
    f = cs.get("fourier")
    if f:
        out += (f"; Fourier series of order {f['order']} within {f['simultaneous_z']:.2f} sigma (every value within "
                f"2 sigma: probability {f['p_every_value_within_2sigma']:.2f})")
    return out


def _trajectory_file_frame(path: str):  # type: ignore[no-untyped-def]
    """The CRS a skyrig trajectory CSV states in its ``# crs:`` header line (default EPSG:4979)."""
    from skyrig.georef.eo import WorldFrame

    crs = "EPSG:4979"
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            key, _, value = line[1:].partition(":")
            if key.strip() == "crs" and value.strip():
                crs = value.strip()
    return WorldFrame.map(crs)


@command.command("uncalibrated-gnss-imu")
@click.option("--trajectory", "trajectory_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Recorded GNSS antenna positions + IMU attitudes (skyrig trajectory CSV), uncalibrated.")
@click.option("--events", "events_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Camera events CSV.")
@click.option("--rig", "rig_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The nominal rig file (antenna lever arm as recorded, no boresight).")
@click.option("--measurements", "meas_paths", required=True, multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Image measurements CSV point,image,column,row (tie and ground points; repeatable).")
@click.option("--control", "control_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Ground control points CSV (CRS and geoid in its header): control of the reference sub-block "
                   "and check points of the evaluation.")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="More ground points (same kind of file): check points of the evaluation only.")
@click.option("--reference-strips", default=None,
              help="Strips of the reference sub-block, 1-based in time order, comma-separated (default: the two "
                   "central strips).")
@click.option("--head", default=None, help="The camera head (default: the only one).")
@click.option("--image-sigma-um", type=PIXEL_SIGMA_UM, default=5.0, show_default=True,
              help="Sigma of an image coordinate (micrometres).")
@click.option("--gnss-sigma", type=GNSS_SIGMA_M, default="0.3", show_default=True, help="GNSS sigma E,N,U (metres; one or three values).")
@click.option("--imu-sigma-deg", type=IMU_SIGMA_DEG, default="0.00801,0.00801,0.01503", show_default=True,
              help="IMU sigma roll,pitch,yaw (degrees; one or three values; paper 003: 0.0089 / 0.0167 gon).")
@click.option("--imu-sigma-gon", default=None, hidden=True,
              help="Deprecated: the IMU sigma in grads (use --imu-sigma-deg).")
@click.option("--control-sigma", type=CONTROL_SIGMA_M, default="0.6", show_default=True, help="Control point sigma X,Y,Z (metres).")
@click.option("--flight", default="", help="Provenance: flight / data set.")
@click.option("--date", default="", help="Provenance: date of the flight (ISO 8601).")
@click.option("--crs", "out_crs", default=None,
              help="CRS of the corrected EO file (default: the control points' frame, the national system).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Calibrated rig file (YAML).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="JSON report (default: the output with suffix .json); an HTML page is written next to it.")
@click.option("--corrected-trajectory", "traj_out", type=click.Path(dir_okay=False), default=None,
              help="Corrected GNSS/IMU trajectory CSV (datum shift removed; default OUTPUT_trajectory.csv).")
@click.option("--corrected-eo", "eo_out", type=click.Path(dir_okay=False), default=None,
              help="Corrected EO CSV of every image (direct georeferencing with the calibrated rig and the "
                   "corrected trajectory; default OUTPUT_eo.csv).")
def uncalibrated_gnss_imu_command(trajectory_path, events_path, rig_path, meas_paths, control_path, check_path,
                                  reference_strips, head, image_sigma_um, gnss_sigma, imu_sigma_deg, imu_sigma_gon, control_sigma,
                                  flight, date, out_crs, output, report_path, traj_out, eo_out) -> None:
    """GNSS/IMU system calibration of a flight delivered uncalibrated (paper 003): antenna offset from per-strip
    shifts, two-step reference orientation, boresight misalignment and datum shift, corrected GNSS/IMU and EO,
    evaluation (spatial intersection, ISO, check points, y-parallax); prints Tables 2 and 4-8."""
    import numpy as np

    from skyrig import __version__
    from skyrig.calibrate.gnss_imu import (CalibrationFailed, FlightData, calibrate_uncalibrated_gnss_imu,
                                           format_tables, report_html)
    from skyrig.cli._common import parse_sigmas
    from skyrig.errors import SkyrigError
    from skyrig.georef.eo import WorldFrame
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io._text import atomic_write
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_calibrated_rig, write_rig
    from skyrig.io.trajectory_csv import write_trajectory_csv
    from skyrig.io.trajectory_csv import read_trajectory_csv

    def triple(text: str, option: str) -> tuple[float, float, float]:
        v = parse_sigmas(text, 3, option, "x,y,z", positive=True)
        return (float(v[0]), float(v[1]), float(v[2]))

    if imu_sigma_gon is not None:  # the old spelling (the paper's unit): still read, with a warning
        click.echo("warning: --imu-sigma-gon is deprecated; use --imu-sigma-deg (1 gon = 0.9 deg)", err=True)
        imu_gon = triple(imu_sigma_gon, "--imu-sigma-gon")
    else:
        deg = triple(imu_sigma_deg, "--imu-sigma-deg")
        imu_gon = (deg[0] / 0.9, deg[1] / 0.9, deg[2] / 0.9)
    rig, rig_cal = read_calibrated_rig(rig_path)
    traj = read_trajectory_csv(trajectory_path)
    events = read_events_csv(events_path)
    ms = [read_measurements_csv(p) for p in meas_paths]
    meas = ImageMeasurements(np.concatenate([m.point for m in ms]), np.concatenate([m.image for m in ms]),
                             np.concatenate([m.pixel for m in ms]))
    ctrl = read_points_csv(control_path, option="--control")
    names, xyz = [ctrl.name], [ctrl.xyz]
    if check_path is not None:
        chk = read_points_csv(check_path, option="--check")
        names.append(chk.name)
        xyz.append(ctrl.frame.from_ecef(chk.frame.to_ecef(chk.xyz)))
    ground = GroundPoints(np.concatenate(names), np.concatenate(xyz), ctrl.frame)
    dup = [n for n, c in zip(*np.unique(ground.name, return_counts=True)) if c > 1]
    if dup:
        raise click.BadParameter(f"ground point {dup[0]!r} is in --control and --check", param_hint="--check")
    ref = None
    if reference_strips:
        try:
            ref = [int(s) - 1 for s in reference_strips.split(",") if s.strip()]
        except ValueError:
            raise click.BadParameter(f"strip numbers separated by commas, not {reference_strips!r}",
                                     param_hint="--reference-strips") from None
    traj_frame = _trajectory_file_frame(trajectory_path)
    data = FlightData(traj, events, rig, meas, ground, tuple(str(n) for n in ctrl.name), None, traj_frame)
    try:
        cal = calibrate_uncalibrated_gnss_imu(
            data, reference_strips=ref, head=head, image_sigma_um=image_sigma_um,
            gnss_sigma_m=triple(gnss_sigma, "--gnss-sigma"), imu_sigma_gon=imu_gon,
            control_sigma_m=triple(control_sigma, "--control-sigma"))
    except CalibrationFailed as exc:
        raise click.ClickException(f"calibration failed: {exc}") from None
    except SkyrigError as exc:
        raise click.ClickException(str(exc)) from None
    report = cal.to_dict()
    report["inputs"] = {"trajectory": str(trajectory_path), "events": str(events_path), "rig": str(rig_path),
                        "measurements": [str(p) for p in meas_paths], "control": str(control_path),
                        "check": check_path}
    stem = Path(output)
    traj_out = traj_out or str(stem.with_name(stem.stem + "_trajectory.csv"))
    eo_out = eo_out or str(stem.with_name(stem.stem + "_eo.csv"))
    report_path = report_path or str(stem.with_suffix(".json"))
    html_path = str(Path(report_path).with_suffix(".html"))
    report["outputs"] = {"rig": str(output), "trajectory": traj_out, "eo": eo_out, "report": report_path,
                         "html": html_path}
    out_frame = WorldFrame.map(out_crs) if out_crs else ctrl.frame
    write_rig(cal.rig, output, cal.rig_calibration(flight, date, f"skyrig {__version__}", rig_cal))
    write_trajectory_csv(traj_out, cal.trajectory_corrected, crs=traj_frame.crs if traj_frame.kind == "map" else "EPSG:4979")
    write_eo_csv(cal.eo_corrected.to_frame(out_frame), eo_out)
    with atomic_write(report_path) as fh:
        json.dump(report, fh, indent=2, default=float)
        fh.write("\n")
    with atomic_write(html_path) as fh:
        fh.write(report_html(report))
    click.echo(format_tables(report))
    r = report["result"]
    b, sb = r["boresight_misalignment_gon"], r["boresight_sigma_gon"]
    d, sd = r["datum_shift_m"], r["datum_shift_sigma_m"]
    a, sa = r["antenna_offset_m"], r["antenna_offset_sigma_m"]
    click.echo("boresight misalignment [gon]: " + ", ".join(f"{k} {b[k]:.5f} ± {sb[k]:.5f}" for k in b))
    click.echo("datum shift (GNSS minus control) [m]: " + ", ".join(f"{k} {d[k]:.3f} ± {sd[k]:.3f}" for k in d))
    click.echo("antenna offset [m]: " + ", ".join(f"{k} {a[k]:.3f} ± {sa[k]:.3f}" for k in a))
    click.echo(f"-> {output}, {traj_out}, {eo_out}, {report_path}, {html_path}")


@command.command("calqc")
@click.option("--trajectory", "trajectory_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Recorded GNSS antenna positions + IMU attitudes of the boresight flight (skyrig trajectory CSV).")
@click.option("--events", "events_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Camera events CSV (every head's images).")
@click.option("--rig", "rig_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The nominal rig file (lever arms as measured, laboratory interior orientation).")
@click.option("--measurements", "meas_paths", required=True, multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Image measurements CSV point,image,column,row (tie and ground points; repeatable).")
@click.option("--control", "control_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Ground control points CSV (CRS in its header): control in steps 1-3, check points in step 4.")
@click.option("--check", "check_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Check points CSV (never control).")
@click.option("--image-sigma-um", type=PIXEL_SIGMA_UM, default=4.0, show_default=True,
              help="Sigma of an image coordinate (micrometres; paper 004: 4 um).")
@click.option("--gnss-sigma", type=GNSS_SIGMA_M, default="0.05", show_default=True, help="GNSS sigma E,N,U (metres; one or three values).")
@click.option("--imu-sigma-deg", type=IMU_SIGMA_DEG, default="0.003,0.003,0.006", show_default=True,
              help="IMU sigma roll,pitch,yaw (degrees; one or three values).")
@click.option("--control-sigma", type=CONTROL_SIGMA_M, default="0.05", show_default=True, help="Control point sigma X,Y,Z (metres).")
@click.option("--no-grid", is_flag=True, help="Skip the correction grid.")
@click.option("--grid-method", type=click.Choice(["joint", "cycles"]), default="joint", show_default=True,
              help="joint: the grid's node values are unknowns of the joint adjustment with their collocation prior "
                   "(its covariance holds the grid's uncertainty); cycles: grids by collocation of the residuals "
                   "alternating with the adjustment.")
@click.option("--grid-uncertainty", "grid_pairs", type=click.IntRange(min=0), default=0, show_default=True,
              help="With --grid-method cycles: propagate the correction grid's posterior into the calibration "
                   "covariance with this many antithetic Monte-Carlo pairs (each two adjustments of the whole flight; "
                   "0: the grid taken as known).")
@click.option("--grid-fit-draws", type=click.IntRange(min=0), default=16, show_default=True,
              help="With --grid-method joint: the grid's covariance function (signal variance, correlation length) is "
                   "fitted to the residuals; its sampling uncertainty (a parametric bootstrap of this many fits, and "
                   "two more adjustments) is added to the calibration covariance (0: the fitted function taken as "
                   "known, sigmas a few per cent optimistic).")
@click.option("--no-design-study", is_flag=True,
              help="Skip the design study (which unknowns this flight cannot separate, per head, and the flight that "
                   "would: virtual opposite-direction / cross-strip / second-height flights).")
@click.option("--no-variants", is_flag=True, help="Skip the three adjustment variants (and Tab. 11).")
@click.option("--flight", default="", help="Provenance: flight / data set.")
@click.option("--date", default="", help="Provenance: date of the flight (ISO 8601).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Calibrated rig file (YAML).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="JSON report (default: the output with suffix .json); an HTML page is written next to it.")
@click.option("--poseo", "poseo_path", type=click.Path(dir_okay=False), default=None,
              help="Corrected exterior orientations of every image (the paper's POSEO: calibrated rig, GNSS freed of "
                   "the datum shift), an EO CSV with side-car in the control points' CRS (default OUTPUT_poseo.csv).")
def calqc_command(trajectory_path, events_path, rig_path, meas_paths, control_path, check_path, image_sigma_um,
                  gnss_sigma, imu_sigma_deg, control_sigma, no_grid, grid_method, grid_pairs, grid_fit_draws,
                  no_design_study, no_variants, flight,
                  date, output, report_path, poseo_path) -> None:
    """Boresight, datum shift and interior orientation of a multi-head rig (paper 004, CalQC's four steps), the
    three adjustment variants (Tab. 11) and a correction grid by least-squares collocation."""
    if grid_pairs and grid_method == "joint":
        raise click.UsageError("--grid-uncertainty needs --grid-method cycles (the joint adjustment's covariance "
                               "already holds the grid's uncertainty)")
    import numpy as np

    from skyrig import __version__
    from skyrig.calibrate.calqc import CalqcData, CalqcFailed, calibrate_calqc, format_tables, report_html
    from skyrig.cli._common import parse_sigmas
    from skyrig.errors import SkyrigError
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io._text import atomic_write
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_calibrated_rig, write_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv

    def triple(text: str, option: str) -> tuple[float, float, float]:
        v = parse_sigmas(text, 3, option, "x,y,z", positive=True)
        return (float(v[0]), float(v[1]), float(v[2]))

    rig, rig_cal = read_calibrated_rig(rig_path)
    ms = [read_measurements_csv(p) for p in meas_paths]
    meas = ImageMeasurements(np.concatenate([m.point for m in ms]), np.concatenate([m.image for m in ms]),
                             np.concatenate([m.pixel for m in ms]))
    ctrl = read_points_csv(control_path, option="--control")
    names, xyz, check = [ctrl.name], [ctrl.xyz], ()
    if check_path is not None:
        chk = read_points_csv(check_path, option="--check")
        names.append(chk.name)
        xyz.append(ctrl.frame.from_ecef(chk.frame.to_ecef(chk.xyz)))
        check = tuple(str(n) for n in chk.name)
    ground = GroundPoints(np.concatenate(names), np.concatenate(xyz), ctrl.frame)
    data = CalqcData(read_trajectory_csv(trajectory_path), read_events_csv(events_path), rig, meas, ground, check)
    try:
        cal = calibrate_calqc(data, image_sigma_um=image_sigma_um, gnss_sigma_m=triple(gnss_sigma, "--gnss-sigma"),
                              imu_sigma_deg=triple(imu_sigma_deg, "--imu-sigma-deg"),
                              control_sigma_m=triple(control_sigma, "--control-sigma"), grid=not no_grid,
                              variants=not no_variants, grid_uncertainty_draws=grid_pairs,
                              design=not no_design_study, grid_method=grid_method, grid_fit_draws=grid_fit_draws)
    except CalqcFailed as exc:
        raise click.ClickException(f"calibration failed: {exc}") from None
    except SkyrigError as exc:
        raise click.ClickException(str(exc)) from None
    report = cal.to_dict()
    report["inputs"] = {"trajectory": str(trajectory_path), "events": str(events_path), "rig": str(rig_path),
                        "measurements": [str(p) for p in meas_paths], "control": str(control_path), "check": check_path}
    report_path = report_path or str(Path(output).with_suffix(".json"))
    html_path = str(Path(report_path).with_suffix(".html"))
    poseo_path = poseo_path or str(Path(output).with_name(Path(output).stem + "_poseo.csv"))
    report["outputs"] = {"rig": str(output), "report": report_path, "html": html_path, "poseo": poseo_path}
    write_rig(cal.rig, output, cal.rig_calibration(flight, date, f"skyrig {__version__}", rig_cal))
    from skyrig.io.eo_csv import write_eo_csv

    write_eo_csv(cal.poseo.to_frame(ctrl.frame), poseo_path)
    with atomic_write(report_path) as fh:
        json.dump(report, fh, indent=2, default=float)
        fh.write("\n")
    with atomic_write(html_path) as fh:
        fh.write(report_html(report))
    click.echo(format_tables(report))
    click.echo(f"-> {output}, {report_path}, {html_path}, {poseo_path}")


def _lidar_camera() -> None:
    from skyrig.cli.calibrate_lidar_camera import lidar_camera_command

    command.add_command(lidar_camera_command)


_lidar_camera()
