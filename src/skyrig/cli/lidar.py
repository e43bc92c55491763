"""``skyrig lidar``: georeference raw scans, register clouds, compare clouds (thin shims over skyrig.lidar)."""

from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path

import click
import numpy as np

from skyrig.errors import InputFormatError


def _floats(text: str, n: int, name: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.replace(";", ",").split(",")], dtype=float)
    except ValueError:
        raise click.BadParameter(f"expected {n} comma-separated numbers, got {text!r}", param_hint=name) from None
    if v.size != n:
        raise click.BadParameter(f"expected {n} comma-separated numbers, got {v.size}", param_hint=name)
    return v


def _lever_arm(text: str, option: str) -> np.ndarray:
    """A lever arm option in metres: refused when it is only plausible in millimetres or centimetres."""
    from skyrig.errors import OptionError
    from skyrig.io.plausibility import lever_arm_problem, warn

    v = _floats(text, 3, option)
    problem = lever_arm_problem(v)
    if problem is not None and problem[0] == "refuse":
        raise OptionError(option, problem[1])
    if problem is not None:
        warn(f"{option}: {problem[1]}")
    return v


@contextmanager
def _progress(label: str):
    """A rich progress bar fed by ``callback(done, total)``; plain text when rich is missing."""
    try:
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
    except ImportError:  # pragma: no cover
        yield lambda done, total: None
        return
    with Progress(TextColumn(label), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeRemainingColumn(), transient=True) as prog:
        task = prog.add_task(label, total=None)

        def cb(done: int, total: int) -> None:
            prog.update(task, completed=done, total=total)

        yield cb


def _load_cloud(path: str, crs_required: bool = False):
    from skyrig.io.laz import read_las

    if Path(path).suffix.lower() in (".las", ".laz"):
        return read_las(path, require_crs=crs_required)
    # text: a header line naming X, Y, Z (CloudCompare / PDAL text exports)
    from skyrig.io.laz import LasPoints

    with open(path, encoding="utf-8") as fh:
        head = fh.readline()
    names = [h.strip().strip('"').lower() for h in head.split(",")]
    try:
        cols = [names.index(c) for c in ("x", "y", "z")]
    except ValueError:
        raise InputFormatError("a text cloud needs a header line with X, Y and Z columns", path, 1) from None
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=cols, ndmin=2)
    except ValueError as exc:
        raise InputFormatError(f"unreadable coordinates ({exc})", path) from None
    if crs_required:
        raise InputFormatError("a text cloud has no CRS; give --crs", path, field="crs")
    return LasPoints(data, None, None, None, None)


def _write_histogram_png(path: str, distances: np.ndarray, title: str, stats) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skyrig.lidar.compare import histogram

    counts, edges = histogram(distances, bins=60)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color="#4477aa")
    ax.axvline(stats.p68_abs_m, color="#cc3311", label=f"68 % below {stats.p68_abs_m:.3f} m")
    ax.axvline(stats.rms_m, color="#222222", ls="--", label=f"RMS {stats.rms_m:.3f} m")
    ax.set_xlabel("absolute distance (m)")
    ax.set_ylabel("points")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    tmp = Path(path).with_name(f".{Path(path).name}.tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)


@click.group("lidar")
def command() -> None:
    """Laser scanning: georeference raw scans, register and compare point clouds."""


@command.command("georef")
@click.option("--scan", "scan_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Raw scan CSV (docs/formats/raw_scan_csv.md).")
@click.option("--trajectory", "traj_path", required=True, type=click.Path(exists=True, dir_okay=False), help="skyrig trajectory CSV or Applanix SBET.")
@click.option("--reference", type=click.Choice(["imu", "antenna"]), default=None, help="Point the SBET positions refer to.")
@click.option("--lever-arm", default="0,0,0", show_default=True, help="Scanner origin in the body frame, x,y,z metres.")
@click.option("--antenna-lever-arm", default="0,0,0", show_default=True, help="GNSS antenna in the body frame (antenna trajectories).")
@click.option("--boresight", default="0,0,0", show_default=True, help="Boresight angles about x,y,z (--angles unit).")
@click.option("--mounting", default=None, help="Nominal body_from_scanner as 9 numbers, row by row (default identity).")
@click.option("--sequence", default="zyx", show_default=True, help="Axis order of the boresight rotation product.")
@click.option("--passive", is_flag=True, help="Boresight angles describe a passive (frame) rotation.")
@click.option("--angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True)
@click.option("--yaw-correction", type=float, default=0.0, show_default=True, help="Heading correction added to the IMU yaw (--angles unit).")
@click.option("--barometric", type=click.Path(exists=True, dir_okay=False), default=None, help="CSV 'time,h' of barometric ellipsoidal heights replacing GNSS heights.")
@click.option("--position", type=click.Choice(["cubic", "linear"]), default="cubic", show_default=True)
@click.option("--crs", required=True, help="Output CRS (EPSG code, WKT, PROJ string) or 'ecef'.")
@click.option("--geoid", default=None, help="Geoid grid for orthometric heights.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output .las/.laz.")
def georef_cmd(scan_path, traj_path, reference, lever_arm, antenna_lever_arm, boresight, mounting, sequence, passive,
               angles, yaw_correction, barometric, position, crs, geoid, output) -> None:
    """Georeference a raw scan: scanner -> body -> NED -> ECEF -> CRS, trajectory interpolated per pulse."""
    from skyrig.georef.eo import WorldFrame
    from skyrig.geometry.angles import to_radians
    from skyrig.io.laz import write_las
    from skyrig.io.raw_scan_csv import read_raw_scan_csv
    from skyrig.lidar.georef import ScannerMount, georeference_scan
    from skyrig.pipeline.inputs import load_trajectory

    scan, _ = read_raw_scan_csv(scan_path)
    traj = load_trajectory(traj_path, reference)
    mnt = None if mounting is None else _floats(mounting, 9, "--mounting").reshape(3, 3)
    arms = {o: _lever_arm(t, o) for o, t in (("--lever-arm", lever_arm), ("--antenna-lever-arm", antenna_lever_arm))}
    mount = ScannerMount.from_angles(arms["--lever-arm"], _floats(boresight, 3, "--boresight"), angles,
                                     sequence, passive, mnt, arms["--antenna-lever-arm"])
    baro = None
    if barometric:
        try:
            b = np.loadtxt(barometric, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise InputFormatError(f"expected a header line and 'time,h' rows ({exc})", barometric) from None
        baro = (b[:, 0], b[:, 1])
    frame = WorldFrame.ecef() if crs.lower() == "ecef" else WorldFrame.map(crs, geoid)
    with _progress("georeferencing") as cb:
        pts = georeference_scan(scan, traj, mount, frame, position=position,
                                yaw_correction_rad=float(to_radians(yaw_correction, angles)), barometric=baro, progress=cb)
    write_las(output, pts.xyz, "EPSG:4978" if frame.kind == "ecef" else crs, gps_time=pts.time_s,
              intensity=pts.intensity, scan_angle_deg=pts.scan_angle_deg)
    click.echo(f"georeferenced {len(pts):,} pulses -> {output} ({frame.describe()})")


@command.command("register")
@click.option("--source", required=True, type=click.Path(exists=True, dir_okay=False), help="Cloud to move (.las/.laz).")
@click.option("--target", required=True, type=click.Path(exists=True, dir_okay=False), help="Fixed reference cloud.")
@click.option("--points", "points_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Homologous points CSV 'sx,sy,sz,tx,ty,tz' (>= 3 rows, header line) for the coarse alignment.")
@click.option("--similarity", is_flag=True, help="Coarse alignment with a scale.")
@click.option("--method", type=click.Choice(["point_to_plane", "point_to_point", "none"]), default="point_to_plane", show_default=True)
@click.option("--max-distance", type=float, default=1.0, show_default=True, help="ICP correspondence distance (m).")
@click.option("--iterations", type=int, default=50, show_default=True)
@click.option("--backend", type=click.Choice(["auto", "open3d", "scipy"]), default="auto", show_default=True)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Registered source (.las/.laz).")
@click.option("--matrix", "matrix_out", type=click.Path(dir_okay=False), default=None, help="Write the 4x4 target_from_source matrix (text).")
def register_cmd(source, target, points_path, similarity, method, max_distance, iterations, backend, output, matrix_out) -> None:
    """Coarse alignment from homologous points, then ICP; reports transform, RMSE and overlap."""
    from skyrig.io.laz import write_las
    from skyrig.lidar.register import apply_transform, fit_transform, icp

    src = _load_cloud(source)
    tgt = _load_cloud(target, crs_required=True)
    m = np.eye(4)
    if points_path:
        try:
            hp = np.loadtxt(points_path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise InputFormatError(f"expected 'sx,sy,sz,tx,ty,tz' rows ({exc})", points_path) from None
        if hp.shape[1] != 6:
            raise InputFormatError(f"expected 6 columns, got {hp.shape[1]}", points_path, 2)
        fit = fit_transform(hp[:, :3], hp[:, 3:], similarity=similarity)
        m = fit.matrix
        click.echo(f"coarse: {len(hp)} points, residual RMS {fit.rms_m:.4f} m, scale {fit.scale:.8f}")
    origin = tgt.xyz.mean(axis=0)  # work near the origin
    shift = np.eye(4)
    shift[:3, 3] = -origin
    if method != "none":
        with _progress("ICP") as cb:
            cb(0, 1)
            init = shift @ m @ np.linalg.inv(shift)
            r = icp(src.xyz - origin, tgt.xyz - origin, init=init, method=method, max_correspondence_distance=max_distance,
                    max_iterations=iterations, backend=backend)
            cb(1, 1)
        m = np.linalg.inv(shift) @ r.matrix @ shift
        click.echo(f"ICP ({r.backend}, {method}): RMSE {r.rmse_m:.4f} m, overlap {100 * r.fitness:.1f} %")
    moved = apply_transform(m, src.xyz)
    write_las(output, moved, tgt.crs_wkt, gps_time=src.gps_time, intensity=src.intensity, scan_angle_deg=src.scan_angle_deg)
    if matrix_out:
        np.savetxt(matrix_out, m, fmt="%.12f")
    click.echo("target_from_source =\n" + np.array2string(m, precision=6, suppress_small=True))


@command.command("compare")
@click.option("--compared", required=True, type=click.Path(exists=True, dir_okay=False), help="Cloud whose distances are computed (M3C2: epoch 2).")
@click.option("--reference", required=True, type=click.Path(exists=True, dir_okay=False), help="Reference cloud (M3C2: epoch 1).")
@click.option("--method", type=click.Choice(["c2c", "c2c-plane", "m3c2"]), default="c2c", show_default=True)
@click.option("--k", type=int, default=8, show_default=True, help="Neighbours of the local plane (c2c-plane).")
@click.option("--max-distance", type=float, default=None, help="C2C: ignore references farther than this (m).")
@click.option("--core", type=click.Path(exists=True, dir_okay=False), default=None, help="M3C2 core points (.las/.laz or text with X,Y,Z header); default: the reference cloud.")
@click.option("--normal-radius", type=float, default=None, help="M3C2 normal radius (m).")
@click.option("--cylinder-radius", type=float, default=None, help="M3C2 cylinder radius (m).")
@click.option("--half-length", type=float, default=None, help="M3C2 cylinder half-length (m).")
@click.option("--registration-error", type=float, default=0.0, show_default=True)
@click.option("--flavour", type=click.Choice(["cloudcompare", "pdal"]), default="cloudcompare", show_default=True, help="M3C2 details (normal compression, minimum points).")
@click.option("--crs", default=None, help="CRS for the output when the input files carry none.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, help="LAS/LAZ with the distance as extra dimension.")
@click.option("--histogram", "hist_png", type=click.Path(dir_okay=False), default=None, help="Histogram PNG of absolute distances.")
@click.option("--stats", "stats_json", type=click.Path(dir_okay=False), default=None, help="Statistics as JSON.")
def compare_cmd(compared, reference, method, k, max_distance, core, normal_radius, cylinder_radius, half_length,
                registration_error, flavour, crs, output, hist_png, stats_json) -> None:
    """Cloud-to-cloud distances or M3C2, with statistics (mean, std, RMS, 68 % / "2/3 below")."""
    from skyrig.io.laz import write_las
    from skyrig.lidar.compare import M3C2Params, cloud_to_cloud, distance_statistics, m3c2

    cmp_cloud = _load_cloud(compared)
    ref_cloud = _load_cloud(reference)
    out_crs = crs or ref_cloud.crs_wkt or cmp_cloud.crs_wkt
    if output and out_crs is None:
        raise InputFormatError("neither input has a CRS and --crs was not given: the output LAS needs one",
                               reference, field="crs")
    extra: dict[str, np.ndarray] = {}
    if method == "m3c2":
        if None in (normal_radius, cylinder_radius, half_length):
            raise click.UsageError("m3c2 needs --normal-radius, --cylinder-radius and --half-length")
        maker = M3C2Params.cloudcompare if flavour == "cloudcompare" else M3C2Params.pdal
        params = maker(normal_radius, cylinder_radius, half_length, registration_error)
        core_pts = _load_cloud(core).xyz if core else ref_cloud.xyz
        origin = ref_cloud.xyz.mean(axis=0)
        with _progress("M3C2") as cb:
            cb(0, 1)
            r = m3c2(ref_cloud.xyz - origin, cmp_cloud.xyz - origin, core_pts - origin, params)
            cb(1, 1)
        dist = r.distance_m
        pts = core_pts
        extra = {"m3c2_distance": dist, "m3c2_uncertainty": r.uncertainty_m, "m3c2_significant": r.significant.astype(float),
                 "m3c2_count1": r.count1.astype(float), "m3c2_count2": r.count2.astype(float)}
        click.echo(f"M3C2 ({flavour}): {int(np.isfinite(dist).sum())} of {len(dist)} core points with a distance, "
                   f"{int(r.significant.sum())} significant")
    else:
        with _progress("C2C") as cb:
            cb(0, 1)
            origin = ref_cloud.xyz.mean(axis=0)
            res = cloud_to_cloud(cmp_cloud.xyz - origin, ref_cloud.xyz - origin, model="plane" if method == "c2c-plane" else "nearest",
                                 k=k, max_distance=max_distance)
            cb(1, 1)
        dist = res.distance_m
        pts = cmp_cloud.xyz
        extra = {"distance": dist}
    st = distance_statistics(dist)
    click.echo(f"n {st.count}  mean {st.mean_m:.4f}  std {st.std_m:.4f}  RMS {st.rms_m:.4f}  "
               f"68 % (2/3) below {st.p68_abs_m:.4f}  95 % below {st.p95_abs_m:.4f} m")
    if output:
        write_las(output, pts, out_crs, extra={kk: np.nan_to_num(v, nan=-9999.0) for kk, v in extra.items()})
    if hist_png:
        _write_histogram_png(hist_png, dist, f"{method}: {Path(compared).name} vs {Path(reference).name}", st)
    if stats_json:
        Path(stats_json).write_text(json.dumps(st.as_dict(), indent=2), encoding="utf-8")


@command.command("strips")
@click.option("--scan", "scan_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Raw scan CSV with a 'strip' column (docs/formats/raw_scan_csv.md).")
@click.option("--trajectory", "traj_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="skyrig trajectory CSV or Applanix SBET (IMU positions).")
@click.option("--mount", "mount_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Nominal scanner mount: a scanner.json (skyrig-scanner-mount) or a rig file with a 'scanners' section.")
@click.option("--scanner", default=None, help="Scanner record of --mount (a rig file with several scanners).")
@click.option("--reference", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Control: a reference cloud (.las/.laz with a CRS, e.g. a terrestrial scan) on the same surfaces.")
@click.option("--range-sigma", type=float, default=0.02, show_default=True, help="Range noise (m).")
@click.option("--angle-sigma-deg", type=float, default=0.0, show_default=True, help="Deflection-angle noise (deg).")
@click.option("--roughness", type=float, default=0.002, show_default=True, help="Surface roughness of a patch (m).")
@click.option("--control-sigma", type=float, default=0.003, show_default=True, help="Noise of a reference point (m).")
@click.option("--position-sigma", default="0.05,0.05,0.08", show_default=True,
              help="Trajectory position accuracy per strip, E,N,U (m): prior of the strip offsets.")
@click.option("--position-drift-sigma", default="0.001", show_default=True, help="... of the strip drifts (m/s).")
@click.option("--attitude-sigma-deg", default="0.03,0.03,0.08", show_default=True,
              help="Trajectory attitude accuracy per strip about E,N,U (deg).")
@click.option("--attitude-drift-sigma-deg", default="0.0003,0.0003,0.0008", show_default=True, help="... per second.")
@click.option("--cell", type=float, default=1.0, show_default=True, help="Patch size (m).")
@click.option("--min-strips", type=int, default=2, show_default=True, help="Strips that must see a patch.")
@click.option("--estimate", default="all", show_default=True,
              help="Calibration unknowns, comma-separated (boresight_x.., lever_x.., range_offset, range_scale) or 'all'.")
@click.option("--name", default="lidar", show_default=True, help="Name of the scanner record written.")
@click.option("--rig", "base_rig", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Rig file to add the scanner record to (its heads and other scanners are kept).")
@click.option("--flight", default="", help="Provenance: flight / data set.")
@click.option("--date", default="", help="Provenance: date of the flight (ISO 8601).")
@click.option("--cloud", type=click.Path(dir_okay=False), default=None, help="Also write the corrected cloud (.las/.laz).")
@click.option("--crs", default=None, help="CRS of --cloud (default: the reference's, else ECEF).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Rig file with the calibrated scanner.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Report JSON (default: next to --output).")
def strips_cmd(scan_path, traj_path, mount_path, scanner, reference, range_sigma, angle_sigma_deg, roughness,
               control_sigma, position_sigma, position_drift_sigma, attitude_sigma_deg, attitude_drift_sigma_deg, cell,
               min_strips, estimate, name, base_rig, flight, date, cloud, crs, output, report_path) -> None:
    """Strip adjustment: scanner boresight, lever arm, range offset/scale and per-strip trajectory corrections from
    planar patches seen by overlapping strips (and a reference cloud) -> a calibrated scanner record + report."""
    from skyrig.cli.lidar_strips import _triple, echo_table, run_strips
    from skyrig.errors import OptionError
    from skyrig.lidar.strips import CALIBRATION_NAMES

    deg = float(np.radians(1.0))
    est = CALIBRATION_NAMES if estimate.strip().lower() == "all" else tuple(e.strip() for e in estimate.split(",") if e.strip())
    bad = [e for e in est if e not in CALIBRATION_NAMES]
    if bad:
        raise OptionError("--estimate", f"unknown parameters {bad}; choose from {', '.join(CALIBRATION_NAMES)}")
    for opt, v in (("--range-sigma", range_sigma), ("--control-sigma", control_sigma), ("--cell", cell)):
        if not (np.isfinite(v) and v > 0):
            raise OptionError(opt, f"must be a positive number, got {v!r}")
    opts = {"name": name, "flight": flight, "date": date, "estimate": est,
            "model": {"range_sigma_m": range_sigma, "scan_angle_sigma_rad": angle_sigma_deg * deg,
                      "roughness_m": roughness, "control_sigma_m": control_sigma,
                      "strip_position_sigma_m": _triple(position_sigma, "--position-sigma"),
                      "strip_position_drift_sigma_mps": _triple(position_drift_sigma, "--position-drift-sigma"),
                      "strip_attitude_sigma_rad": _triple(attitude_sigma_deg, "--attitude-sigma-deg", deg),
                      "strip_attitude_drift_sigma_radps": _triple(attitude_drift_sigma_deg, "--attitude-drift-sigma-deg",
                                                                  deg)},
            "patches": {"cell_m": cell, "min_strips": min_strips}}
    out = run_strips(scan_path, traj_path, mount_path, scanner, reference, opts, output, report_path, base_rig, cloud, crs)
    echo_table(out)
    click.echo(f"-> {output}, {out['report']}" + (f", {cloud}" if cloud else ""))
