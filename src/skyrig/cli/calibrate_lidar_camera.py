"""``skyrig calibrate lidar-camera``: a laser scanner and a camera on one platform calibrated in one adjustment
(a thin shim over :mod:`skyrig.calibrate.lidar_camera`; registered in :mod:`skyrig.cli.calibrate`).

Inputs: a raw scan CSV with strip ids, the recorded trajectory, the scanner's nominal mount, a rig file with the
camera head, the camera events (image, time) and the tie-point measurements (point, image, column, row); or
``--simulate strips-ci|strips`` (paper 002's bridge strip flight with its camera, errors injected).  Output: a rig file
with the camera head (calibrated boresight) and the scanner record (calibrated mount, range correction, sigmas,
correlations, provenance), and a JSON report with the determinability verdicts and the per-strip corrections.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click
import numpy as np

from skyrig.errors import InputFormatError

#: the recipe's control options (:class:`~skyrig.calibrate.lidar_camera.JointOptions`) the command sets
CONTROL_OPTIONS = ("control_sigma_m", "control_plane_sigma_m", "max_control_z")

_UNIT = {"rad": ("deg", float(np.degrees(1.0))), "_m": ("mm", 1000.0), "range_scale": ("ppm", 1e6)}


def _unit(name: str) -> tuple[str, float]:
    for k, v in _UNIT.items():
        if name.endswith(k) or name == k:
            return v
    return "", 1.0


def _inputs_from_files(scan_path: str, traj_path: str, mount_path: str, scanner: str | None, rig_path: str,
                       head: str | None, events_path: str, meas_path: str, sigma_px: float,
                       control_path: str | None = None, gcp_path: str | None = None,
                       gcp_sigma_m: float = 0.01) -> tuple[Any, Any]:
    """The recipe's inputs from files, every bad input named (file, line, field); the laser's inputs and the control
    first."""
    from skyrig.calibrate.lidar_camera import JointInputs
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.pipeline.lidar import read_strip_scan
    from skyrig.io.rig_file import read_calibrated_rig
    from skyrig.io.scanner_record import read_scanner_mount

    scan, traj = read_strip_scan(scan_path, traj_path, "the joint adjustment")
    t0, t1 = traj.span
    mount, _ = read_scanner_mount(mount_path, scanner)  # left-handed frames and lever arms in mm are named there
    lat, lon, hh = (float(np.mean(traj.lat_deg)), float(np.mean(traj.lon_deg)), float(np.mean(traj.h_m)))
    frame = WorldFrame.local(lat, lon, hh)
    control = None
    if control_path is not None:
        from skyrig.pipeline.lidar import read_control_cloud

        control, _ = read_control_cloud(control_path, frame)
    rig, _ = read_calibrated_rig(rig_path)
    if head is None:
        if len(rig) != 1:
            raise click.UsageError(f"--rig has {len(rig)} heads ({', '.join(rig.head_names)}); name one with --head")
        head = rig.head_names[0]
    h = rig.head(head)
    ev = read_events_csv(events_path)
    sel = np.asarray(ev.head) == head if len(set(ev.head)) > 1 else np.ones(len(ev.time_s), bool)
    names = [str(n) for n in np.asarray(ev.image_name)[sel]]
    times = np.asarray(ev.time_s, float)[sel]
    bad = np.flatnonzero((times < t0) | (times > t1))
    if bad.size:
        raise InputFormatError(f"image {names[bad[0]]!r} at {times[bad[0]]!r} s lies outside the trajectory "
                               f"({t0!r} .. {t1!r} s)", events_path, None, "time")
    # each image's strip: the strip whose pulses span its exposure
    ids = np.unique(scan.strip_id[scan.strip_id >= 0])
    spans = np.array([[scan.time_s[scan.strip_id == s].min(), scan.time_s[scan.strip_id == s].max()] for s in ids])
    strip = np.full(len(times), -1, np.int64)
    for s, (a, b) in zip(ids, spans):
        strip[(times >= a) & (times <= b)] = s
    on = strip >= 0
    if not on.any():
        raise InputFormatError("no image was exposed during a laser strip", events_path, None, "time")
    meas = read_measurements_csv(meas_path)
    img_index = {n: i for i, n in enumerate(np.asarray(names)[on])}
    keep = np.array([str(i) in img_index for i in meas.image], bool)
    pts, obs_point = np.unique(np.asarray(meas.point)[keep], return_inverse=True)
    obs_image = np.array([img_index[str(i)] for i in np.asarray(meas.image)[keep]], np.int64)
    gcp: dict[str, Any] = {}
    if gcp_path is not None:  # ground control points: those of the file measured in the block's images
        from skyrig.io.points_csv import read_points_csv

        g = read_points_csv(gcp_path, option="--gcp")
        at = {str(n): i for i, n in enumerate(pts)}
        use = [i for i, n in enumerate(g.name) if str(n) in at]
        if not use:
            raise InputFormatError(f"none of the {len(g)} ground control points is measured in an image of the block "
                                   f"(names {', '.join(map(str, g.name[:5]))}...)", gcp_path, None, "name")
        gcp = {"gcp_point": np.array([at[str(g.name[i])] for i in use], np.int64),
               "gcp_xyz": frame.from_ecef(g.frame.to_ecef(g.xyz[use])), "gcp_sigma_m": np.full((len(use), 3),
                                                                                                  gcp_sigma_m)}
    inputs = JointInputs(scan, traj, mount, frame, h.camera, h.body_from_camera_rotation(),
                         np.asarray(h.lever_arm_m, float), times[on], strip[on], obs_image, obs_point.astype(np.int64),
                         np.asarray(meas.pixel, float)[keep], sigma_px, control, **gcp)
    return inputs, (rig, head)


def run(inputs: Any, rig_head: tuple[Any, str] | None, opts: dict[str, Any], output: str, report_path: str | None,
        truth_of: Any = None) -> dict[str, Any]:
    """Calibrate, write the rig file (camera head + scanner record) and the report; returns the result and paths.
    ``truth_of(calibration)``: the simulation's truth in the result's conventions (for the report), or None."""
    from skyrig import __version__
    from skyrig.adjust.factors.lidar import SCANNER_COMPONENTS
    from skyrig.calibrate.lidar_camera import JointOptions, calibrate_lidar_camera
    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.io._text import atomic_write
    from skyrig.io.rig_file import write_rig
    from skyrig.io.scanner_record import write_scanner_record
    from skyrig.io.truth import _plain
    from skyrig.rig.rig import Head, Rig

    cal = calibrate_lidar_camera(inputs, JointOptions(range_sigma_m=opts["range_sigma_m"],
                                                      **{k: opts[k] for k in CONTROL_OPTIONS if k in opts}))
    truth = None if truth_of is None else truth_of(cal)
    mount = inputs.mount
    if rig_head is None:
        rig, head = Rig("uav", {"camera": Head("camera", inputs.camera, inputs.camera_lever_arm_m,
                                              inputs.body_from_camera)}), "camera"
    else:
        rig, head = rig_head
    h = rig.head(head)
    heads = {n: (Head(n, h.camera, h.lever_arm_m, h.mounting, h.boresight @ matrix_from_rotvec(cal.camera_boresight_rad))
                 if n == head else rig.head(n)) for n in rig.head_names}
    write_rig(Rig(rig.name, heads, rig.antenna_lever_arm_m, rig.description), output)
    res = cal.result
    cov = res.covariance.Qcc if res.covariance is not None else None
    lab = {l_: i for i, l_ in enumerate(res.layout.labels)}
    idx = [lab[("lidar_scanner", "scanner", c)] for c in SCANNER_COMPONENTS]
    corr = np.eye(8)
    if cov is not None:
        c = cov[np.ix_(idx, idx)]
        dd = np.sqrt(np.clip(np.diag(c), 1e-300, None))
        corr = c / np.outer(dd, dd)
    v, s = cal.scanner, cal.scanner_sigma

    def part(sl: slice, names: tuple[str, ...], f: float = 1.0) -> dict[str, Any]:
        return {"parameters": list(names), "values": (v[sl] * f).tolist(), "sigma": (s[sl] * f).tolist(),
                "correlation": corr[sl, sl].tolist()}

    not_det = [n for n, _, _, vd, _ in cal.verdicts if vd != "determined"]
    record = {
        "name": opts["name"],
        "body_from_scanner": (mount.body_from_scanner @ matrix_from_rotvec(v[:3])).tolist(),
        "lever_arm_m": (mount.lever_arm_m + v[3:6]).tolist(),
        "range_offset_m": float(v[6]), "range_scale_ppm": float(v[7] * 1e6), "range_sigma_m": opts["range_sigma_m"],
        "calibration": {
            "boresight_rad": part(slice(0, 3), SCANNER_COMPONENTS[0:3]),
            "lever_arm_m": part(slice(3, 6), SCANNER_COMPONENTS[3:6]),
            "range": {"parameters": ["range_offset_m", "range_scale_ppm"], "values": [float(v[6]), float(v[7] * 1e6)],
                      "sigma": [float(s[6]), float(s[7] * 1e6)], "correlation": corr[6:8, 6:8].tolist()},
            "held": [],
            "nominal": {"body_from_scanner": mount.body_from_scanner.tolist(), "lever_arm_m": mount.lever_arm_m.tolist(),
                        "range_offset_m": 0.0, "range_scale_ppm": 0.0},
            "provenance": {"recipe": "skyrig calibrate lidar-camera (laser and images in one adjustment)",
                           "flight": opts["flight"], "date": opts["date"], "software": f"skyrig {__version__}",
                           "statistics": {"sigma0": cal.sigma0, "patch_planes": cal.n_patch_planes,
                                          "tie_planes": cal.n_tie_planes, "laser_points": cal.n_laser_points,
                                          "images": int(len(inputs.image_time_s)),
                                          "dropped_points": cal.n_dropped_points,
                                          "dropped_planes": cal.n_dropped_planes,
                                          **({} if cal.control is None else {
                                              "control": opts.get("control"),
                                              "control_planes": len(cal.control),
                                              "control_rejected": 0 if cal.control_rejected is None
                                              else len(cal.control_rejected)})},
                           "notes": ["boresight: rotation vector in the scanner frame, body_from_scanner = nominal @ "
                                     "expmap(boresight); lever arm: correction to the nominal, body frame; range: "
                                     "recorded = (1 + scale) true + offset",
                                     f"camera head {head!r}: boresight estimated in the same adjustment "
                                     f"{np.degrees(cal.camera_boresight_rad).round(4).tolist()} deg +- "
                                     f"{np.degrees(cal.camera_boresight_sigma_rad).round(4).tolist()} deg",
                                     *(f"not determinable by this flight: {n}" for n in not_det)]},
        },
    }
    write_scanner_record(output, record, output)
    report: dict[str, Any] = {"output": output, "frame": inputs.frame.describe(), **cal.to_dict()}
    if truth is not None:
        report["truth"] = truth
    report_path = report_path or str(Path(output).with_suffix(".json"))
    with atomic_write(report_path) as fh:
        json.dump(_plain(report), fh, indent=1)
        fh.write("\n")
    return {"calibration": cal, "report": report_path, "output": output, "truth": truth}


def echo_table(out: dict[str, Any]) -> None:
    """The calibration table (with the simulation's truth side by side when there is one)."""
    cal, truth = out["calibration"], out["truth"]
    tv = None if truth is None else np.concatenate([truth["scanner"], truth["camera_boresight_rad"]])
    click.echo(f"{'parameter':<20}{'estimate':>11}{'sigma':>9}{'truth':>10}  unit  verdict")
    for i, (n, val, sg, vd, _) in enumerate(cal.verdicts):
        u, f = _unit(n)
        t = "" if tv is None else f"{tv[i] * f:>10.3f}"
        click.echo(f"{n:<20}{val * f:>11.3f}{sg * f:>9.3f}{t:>10}  {u:<4}  {vd}")
    click.echo(f"{cal.n_patch_planes} patch planes, {cal.n_tie_planes} tie-point planes, {cal.n_laser_points:,} laser "
               f"points, {len(cal.block.image_name)} images, {len(cal.block.obs_image):,} image measurements; sigma0 "
               f"{cal.sigma0:.3f}; dropped {cal.n_dropped_points} points off their plane, {cal.n_dropped_planes} planes")
    c = cal.control
    if c is not None:
        sm = c.summary()
        click.echo(f"control: {sm['planes']} planes ({sm['points']:,} points) against the laser: residual RMS "
                   f"{sm['rms_m'] * 1e3:.1f} mm, mean {sm['mean_m'] * 1e3:+.1f} mm; normalised mean {sm['z_mean']:+.2f}, "
                   f"std {sm['z_std']:.2f}, max |z| {sm['z_max_abs']:.2f}")
        rej = cal.control_rejected
        for i in range(0 if rej is None else len(rej)):
            assert rej is not None
            click.echo(f"control plane at {np.round(rej.centroid[i], 3).tolist()} m (local frame) left out as a "
                       f"blunder: {rej.residual_m[i] * 1e3:+.1f} mm from the laser, z = {rej.z[i]:+.1f}")
    if cal.gcp_residual_m is not None:
        rms = np.sqrt(np.mean(cal.gcp_residual_m**2, axis=0)) * 1e3
        zmax = "" if cal.gcp_normalised is None else f", largest |normalised| {np.nanmax(np.abs(cal.gcp_normalised)):.2f}"
        click.echo(f"ground control: {len(cal.gcp_residual_m)} points in the images, residual RMS x {rms[0]:.1f}, "
                   f"y {rms[1]:.1f}, z {rms[2]:.1f} mm{zmax}")
    b, a = cal.discrepancies_before, cal.discrepancies_after
    if b is not None and a is not None and a["pairs"]:
        click.echo(f"strip-to-strip discrepancies on {a['pairs']} patch/strip pairs: RMS {b['rms_m'] * 1e3:.1f} mm "
                   f"before, {a['rms_m'] * 1e3:.1f} mm after (predicted noise {a['noise_rms_m'] * 1e3:.1f} mm; "
                   f"over their sigma {b['normalised_rms']:.2f} -> {a['normalised_rms']:.2f})")


@click.command("lidar-camera")
@click.option("--scan", "scan_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Raw scan CSV with a 'strip' column.")
@click.option("--trajectory", "traj_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Recorded trajectory (any format skyrig reads).")
@click.option("--scanner-mount", "mount_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Nominal scanner mount (scanner.json or a rig file's scanners section).")
@click.option("--scanner", default=None, help="Scanner record of --scanner-mount (default: the only one).")
@click.option("--rig", "rig_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Rig file with the camera head.")
@click.option("--head", default=None, help="The camera head of --rig (default: the only one).")
@click.option("--events", "events_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Camera events CSV (image, time).")
@click.option("--measurements", "meas_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Tie-point measurements CSV (point, image, column, row).")
@click.option("--image-sigma-px", type=float, default=0.5, show_default=True, help="Sigma of an image coordinate.")
@click.option("--range-sigma-m", type=float, default=0.02, show_default=True, help="Range noise of the scanner.")
@click.option("--control", "control_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Control: a reference cloud (LAS/LAZ with its CRS, e.g. a terrestrial scan registered to the "
                   "survey's control) or a points CSV (name,x,y,z, CRS in its header) on planar surfaces the strips "
                   "see; its points on the laser patches observe them.")
@click.option("--control-sigma-m", type=float, default=0.003, show_default=True,
              help="Noise of one control point across its surface.")
@click.option("--control-plane-sigma-m", type=float, default=0.0, show_default=True,
              help="Error common to a patch's control points (the reference's registration).")
@click.option("--max-control-z", type=float, default=4.0, show_default=True,
              help="A control plane whose normalised residual against the laser exceeds this is a blunder, left out.")
@click.option("--gcp", "gcp_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Ground control points measured in the images: a points CSV (name,x,y,z, CRS in its header) whose "
                   "names are points of --measurements.")
@click.option("--gcp-sigma-m", type=float, default=0.01, show_default=True,
              help="Sigma of a ground control point's coordinates (per axis).")
@click.option("--simulate", type=click.Choice(["strips-ci", "strips"]), default=None,
              help="Instead of files: paper 002's simulated bridge strip flight with its camera (errors injected).")
@click.option("--seed", type=int, default=1, show_default=True, help="Seed of --simulate.")
@click.option("--name", default="lidar", show_default=True, help="Name of the scanner record.")
@click.option("--flight", default="", help="Provenance: flight / data set.")
@click.option("--date", default="", help="Provenance: date of the flight (ISO 8601).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Calibrated rig file (YAML): camera head and scanner record.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="JSON report (default: next to --output).")
def lidar_camera_command(scan_path, traj_path, mount_path, scanner, rig_path, head, events_path, meas_path,
                         image_sigma_px, range_sigma_m, control_path, control_sigma_m, control_plane_sigma_m,
                         max_control_z, gcp_path, gcp_sigma_m, simulate, seed, name, flight, date, output,
                         report_path) -> None:
    """Laser scanner and camera calibrated in one adjustment (laser strips + images + trajectory)."""
    for opt, v_, low in (("--control-sigma-m", control_sigma_m, 0.0), ("--control-plane-sigma-m", control_plane_sigma_m,
                                                                       -1.0), ("--max-control-z", max_control_z, 0.0),
                         ("--gcp-sigma-m", gcp_sigma_m, 0.0)):
        if not (np.isfinite(v_) and v_ > low) or (low < 0 and v_ < 0):
            raise click.BadParameter(f"must be {'>= 0' if low < 0 else 'positive'}, got {v_!r}", param_hint=opt)
    opts = {"name": name, "flight": flight, "date": date, "range_sigma_m": range_sigma_m,
            "control_sigma_m": control_sigma_m, "control_plane_sigma_m": control_plane_sigma_m,
            "max_control_z": max_control_z, "control": control_path}
    if simulate is not None:
        from skyrig.simulate.lidar import strip_truth_vector
        from skyrig.simulate.lidar_camera import build_joint_flight
        from skyrig.calibrate.lidar_camera import joint_inputs_from_flight as joint_inputs

        fl = build_joint_flight(simulate, seed)
        inputs, rig_head = joint_inputs(fl), None
        opts["flight"] = opts["flight"] or f"simulated uav-bridge-lidar {simulate} seed {seed}"
    else:
        missing = [o for o, v_ in (("--scan", scan_path), ("--trajectory", traj_path), ("--scanner-mount", mount_path),
                                   ("--rig", rig_path), ("--events", events_path),
                                   ("--measurements", meas_path)) if v_ is None]
        if missing:
            raise click.UsageError(f"give {', '.join(missing)} (or --simulate)")
        inputs, rig_head = _inputs_from_files(scan_path, traj_path, mount_path, scanner, rig_path, head, events_path,
                                              meas_path, image_sigma_px, control_path, gcp_path, gcp_sigma_m)
    if control_path is not None and simulate is not None:
        from dataclasses import replace

        from skyrig.pipeline.lidar import read_control_cloud

        control, _ = read_control_cloud(control_path, inputs.frame)
        inputs = replace(inputs, control_xyz=control)
    truth_of = None
    if simulate is not None:
        def truth_of(cal: Any) -> dict[str, Any]:
            tv = strip_truth_vector(fl.survey.injected, cal.strip_epoch_s)
            return {"scanner": tv[:8].tolist(), "camera_boresight_rad": fl.camera_boresight_rad.tolist(),
                    "strips": tv[8:].reshape(-1, 12).tolist()}
    try:
        out = run(inputs, rig_head, opts, output, report_path, truth_of)
    except InputFormatError as exc:
        if control_path is not None and exc.field == "control_xyz":  # the control file's fault: name it
            raise InputFormatError(exc.reason, control_path, field="points") from None
        if gcp_path is not None and exc.field in ("gcp_point", "gcp_xyz"):
            raise InputFormatError(exc.reason, gcp_path, field="name") from None
        raise
    echo_table(out)
    click.echo(f"wrote {out['output']} and {out['report']}")
