"""Laser strips over files: the strip adjustment of a raw scan (``skyrig lidar strips`` and the project runner's
``lidar`` stage), per-line offsets of a georeferenced LAS/LAZ, and the adjusted cloud written in the output CRS with
its vertical reference stated.

The arrays work is in :mod:`skyrig.lidar.strips`; the formats in :mod:`skyrig.io` (raw scan CSV, scanner records,
LAS/LAZ).  Nothing here imports :mod:`skyrig.cli`.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike

__all__ = ["read_strip_scan", "StripRun", "strip_adjustment", "scanner_record", "write_laser_cloud", "laser_folder"]

log = logging.getLogger(__name__)


def read_strip_scan(scan_path: PathLike, traj_path: PathLike, purpose: str) -> tuple[Any, Any]:
    """A raw scan with strip ids and its trajectory, every pulse inside the trajectory's span.

    Raises
    ------
    InputFormatError
        No ``strip`` column (``purpose`` says what needs it); a pulse outside the trajectory (file, line, field
        ``time``)."""
    from skyrig.io.raw_scan_csv import data_line, read_raw_scan_csv
    from skyrig.pipeline.inputs import load_trajectory

    scan, _ = read_raw_scan_csv(scan_path)
    if scan.strip_id is None:
        raise InputFormatError(f"the raw scan has no 'strip' column: {purpose} needs the flight line of every pulse",
                               scan_path, None, "strip")
    traj = load_trajectory(traj_path, None)
    t0, t1 = traj.span
    bad = np.flatnonzero((scan.time_s < t0) | (scan.time_s > t1))
    if bad.size:
        k = int(bad[0])
        raise InputFormatError(f"pulse time {scan.time_s[k]!r} s is outside the trajectory {traj_path} "
                               f"([{t0!r}, {t1!r}] s, {traj.time_system}); {bad.size} pulse(s) in all",
                               scan_path, data_line(scan_path, k), "time")
    return scan, traj


@dataclass(frozen=True, eq=False)
class StripRun:
    """A strip adjustment of a raw scan with everything its outputs need."""

    scan: Any  # RawScan (nominal range correction applied)
    trajectory: Any
    mount: Any  # nominal ScannerMount
    frame: Any  # the local tangent frame of the adjustment
    patches: Any
    model: Any
    result: Any  # StripAdjustmentResult
    before: dict[str, float]
    after: dict[str, float]
    nominal_range: tuple[float, float]  # (offset m, scale) of the scanner record
    reference_frame: Any  # the reference cloud's own frame (WorldFrame: CRS and vertical reference), or None


def read_control_cloud(path: PathLike, frame: Any) -> tuple[np.ndarray, Any]:
    """Control points for a laser adjustment (a reference cloud: a terrestrial scan registered to the survey's
    control, a surveyor's points on planar surfaces): a LAS/LAZ file with its CRS, or a points CSV (``name,x,y,z``
    with the CRS stated in its header, :func:`skyrig.io.points_csv.read_points_csv`), in the local ``frame`` of the
    adjustment; and the file's own frame (:class:`~skyrig.georef.eo.WorldFrame`: its CRS and vertical reference).

    Raises
    ------
    InputFormatError
        Naming the file (and line and field where there is one): not found, unreadable, no CRS, malformed rows, no
        point.
    """
    from skyrig.georef.eo import WorldFrame

    if Path(path).suffix.lower() in (".csv", ".txt"):
        from skyrig.io.points_csv import read_points_csv

        pts = read_points_csv(path, option="--control")
        own = pts.frame
        xyz = frame.from_ecef(own.to_ecef(np.asarray(pts.xyz, float)))
    else:
        from skyrig.io.laz import read_las

        ref = read_las(path, require_crs=True)
        own = WorldFrame.map(str(ref.crs_wkt))  # (required: never None here)
        xyz = frame.from_ecef(own.to_ecef(ref.xyz))
    xyz = np.asarray(xyz, float)
    if len(xyz) == 0:
        raise InputFormatError("the control file holds no point", path, field="points")
    return xyz, own


def strip_adjustment(scan_path: PathLike, traj_path: PathLike, mount_path: PathLike, scanner: str | None,
                     reference: PathLike | None, opts: dict[str, Any]) -> StripRun:
    """Read a raw scan (with strip ids), a trajectory and a scanner mount, find planar patches and adjust.

    ``opts``: ``model`` (:class:`skyrig.lidar.strips.StripModel` keywords), ``patches``
    (:class:`~skyrig.lidar.strips.PatchOptions` keywords), ``estimate`` (calibration names).

    Raises
    ------
    InputFormatError
        No strip column; a pulse outside the trajectory (file, line, field ``time``); a bad scanner record.
    """
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.scanner_record import read_scanner_mount
    from skyrig.lidar.scanner import RawScan
    from skyrig.lidar.strips import PatchOptions, StripModel, adjust_strips, find_planar_patches, patch_discrepancies

    scan, traj = read_strip_scan(scan_path, traj_path, "the strip adjustment")
    mount, extra = read_scanner_mount(mount_path, scanner)
    r0n = float(extra.get("range_offset_m", 0.0))
    sn = float(extra.get("range_scale_ppm", 0.0)) * 1e-6
    if r0n or sn:  # the nominal range correction first; the adjustment estimates what is left
        scan = RawScan(scan.time_s, (scan.range_m - r0n) / (1.0 + sn), scan.alpha_rad, scan.beta_rad, scan.intensity,
                       scan.strip_id)
    frame = WorldFrame.local(float(np.mean(traj.lat_deg)), float(np.mean(traj.lon_deg)), float(np.mean(traj.h_m)))
    control = None
    ref_frame = None
    if reference is not None:
        control, ref_frame = read_control_cloud(reference, frame)
    model = StripModel(**opts.get("model", {}))
    patches = find_planar_patches(scan, traj, mount, frame, options=PatchOptions(**opts.get("patches", {})),
                                  control=control)
    res = adjust_strips(patches, mount, model=model, **({"estimate": opts["estimate"]} if "estimate" in opts else {}))
    before = patch_discrepancies(patches, mount, model)
    after = patch_discrepancies(patches, mount, model, res)
    return StripRun(scan, traj, mount, frame, patches, model, res, before, after, (r0n, sn), ref_frame)


def scanner_record(run: StripRun, name: str, provenance: dict[str, Any]) -> dict[str, Any]:
    """The calibrated scanner record (rig file ``scanners`` section, :mod:`skyrig.io.scanner_record`) of ``run``."""
    from skyrig import __version__
    from skyrig.lidar.strips import CALIBRATION_NAMES

    res, mount = run.result, run.mount
    r0n, sn = run.nominal_range
    cal, sig = res.calibration, res.calibration_sigma
    r0e, se = float(cal[6]), float(cal[7])

    def block(idx: slice, names: tuple[str, ...]) -> dict[str, Any]:
        return {"parameters": list(names), "values": cal[idx].tolist(), "sigma": sig[idx].tolist(),
                "correlation": res.correlation[idx, idx].tolist()}

    stats = {"sigma0": res.sigma0, "redundancy": res.redundancy, "planes": res.n_planes, "laser_points": res.n_points,
             "laser_points_searched": run.patches.n_points_total, "control_points": res.n_control,
             "rms_before_m": res.rms_before_m, "rms_after_m": res.rms_after_m,
             "discrepancy_rms_before_m": run.before["rms_m"], "discrepancy_rms_after_m": run.after["rms_m"],
             "discrepancy_noise_rms_m": run.after["noise_rms_m"]}
    return {
        "name": name,
        "body_from_scanner": res.mount.body_from_scanner.tolist(),
        "lever_arm_m": res.mount.lever_arm_m.tolist(),
        "range_offset_m": r0n + (1.0 + sn) * r0e,
        "range_scale_ppm": ((1.0 + sn) * (1.0 + se) - 1.0) * 1e6,
        "range_sigma_m": run.model.range_sigma_m,
        "calibration": {
            "boresight_rad": block(slice(0, 3), CALIBRATION_NAMES[0:3]),
            "lever_arm_m": block(slice(3, 6), CALIBRATION_NAMES[3:6]),
            "range": {"parameters": ["range_offset_m", "range_scale_ppm"], "values": [r0e, se * 1e6],
                      "sigma": [float(sig[6]), float(sig[7]) * 1e6], "correlation": res.correlation[6:8, 6:8].tolist()},
            "held": list(res.held),
            "nominal": {"body_from_scanner": mount.body_from_scanner.tolist(), "lever_arm_m": mount.lever_arm_m.tolist(),
                        "range_offset_m": r0n, "range_scale_ppm": sn * 1e6},
            "provenance": {"recipe": "skyrig lidar strips (strip adjustment on planar patches)",
                           **provenance, "software": f"skyrig {__version__}", "statistics": stats,
                           "notes": ["boresight: rotation vector in the scanner frame, body_from_scanner = nominal @ "
                                     "expmap(boresight); lever arm: correction to the nominal, body frame; range: "
                                     "recorded = (1 + scale) true + offset (values: corrections to the nominal)",
                                     f"covariance {res.covariance_kind} (sigma0 {res.sigma0:.3f})", res.rule,
                                     *[v.words() for v in res.verdicts if v.verdict != "determined"]]},
        },
    }


def write_laser_cloud(path: PathLike, xyz: np.ndarray, source_frame: Any, out_frame: Any, *,
                      gps_time: np.ndarray | None = None, intensity: np.ndarray | None = None,
                      point_source_id: np.ndarray | None = None, note: str = "") -> dict[str, str]:
    """Write ``xyz`` (in ``source_frame``) to a LAS/LAZ in ``out_frame``: a map frame's CRS with the vertical
    reference as a compound (orthometric, with a geoid) or 3D (ellipsoidal) CRS and in words in the metadata VLR,
    or ECEF.  Returns the CRS statement (``crs``, ``vertical_reference``)."""
    from skyrig.geodesy.statement import file_crs
    from skyrig.io.laz import write_las

    pts = out_frame.from_ecef(source_frame.to_ecef(xyz))
    crs: Any
    if out_frame.kind == "ecef":
        crs, words, kind = "EPSG:4978", "ECEF (geocentric, no height)", "ecef"
    else:
        fc = file_crs(out_frame)
        crs, words, kind = fc.full, fc.vertical_words, fc.kind
    meta = {"vertical_reference": kind, "vertical_crs": words, "skyrig_vertical_reference": words,
            "geoid": str(getattr(out_frame, "geoid", "") or "")}
    if note:
        meta["skyrig_note"] = note
    extra: dict[str, Any] | None = {"line": np.asarray(point_source_id)} if point_source_id is not None else None
    write_las(path, pts, crs, gps_time=gps_time, intensity=intensity, extra=extra,
              extra_types={"line": np.int32} if extra else None, metadata=meta)
    return {"crs": crs if isinstance(crs, str) else crs.name, "vertical_reference": words}


def _json(path: Path, obj: dict[str, Any]) -> None:
    from skyrig.io._text import atomic_write
    from skyrig.io.truth import _plain

    with atomic_write(path) as fh:
        json.dump(_plain(obj), fh, indent=1, default=str)
        fh.write("\n")


def laser_folder(laser: tuple[Path, ...], out: Path, out_frame: Any, *, trajectory: Path | None = None,
                 rig: Path | None = None, opts: dict[str, Any],
                 progress: Callable[[int, int], None] = lambda done, total: None) -> dict[str, Any]:
    """The project runner's ``lidar`` stage: write ``laser.laz`` (the adjusted cloud in ``out_frame``) and
    ``strips.json`` (strip-to-strip discrepancies before and after, the estimates) into ``out``; with a raw scan
    also ``scanner.yaml`` (the calibrated scanner record).

    ``laser``: one raw scan CSV (with a ``strip`` column; needs ``trajectory`` and ``rig`` with a ``scanners``
    record) or georeferenced LAS/LAZ files (flight lines from ``point_source_id``; per-line offsets only).

    Raises
    ------
    InputFormatError
        Mixed or missing inputs (named), and what the readers refuse.
    """
    from skyrig.io.stage import MANIFEST  # noqa: F401 - the runner writes the manifest

    raw = [p for p in laser if p.suffix.lower() == ".csv"]
    clouds = [p for p in laser if p.suffix.lower() in (".las", ".laz")]
    other = [p for p in laser if p not in raw and p not in clouds]
    if other:
        raise InputFormatError("a laser input is a raw scan CSV or a LAS/LAZ file", other[0], field="inputs.laser")
    if raw and clouds:
        raise InputFormatError("give raw scans or georeferenced clouds, not both", raw[0], field="inputs.laser")
    t0 = time.perf_counter()
    progress(0, 3)
    if raw:
        if len(raw) != 1:
            raise InputFormatError(f"{len(raw)} raw scans: give one file with all strips (column 'strip')", raw[1],
                                   field="inputs.laser")
        if trajectory is None or rig is None:
            raise InputFormatError("a raw scan needs inputs.trajectory and inputs.rig (with a 'scanners' record)",
                                   raw[0], field="inputs.trajectory" if trajectory is None else "inputs.rig")
        from skyrig.io.scanner_record import write_scanner_record
        from skyrig.lidar.strips import apply_strip_corrections

        run = strip_adjustment(raw[0], trajectory, rig, opts.get("scanner"), opts.get("reference"), opts)
        progress(1, 3)
        rec = scanner_record(run, opts.get("name") or "lidar", {"flight": str(raw[0].name), "date": ""})
        write_scanner_record(out / "scanner.yaml", rec)
        xyz = apply_strip_corrections(run.scan, run.trajectory, run.mount, run.frame, run.result)
        progress(2, 3)
        stated = write_laser_cloud(out / "laser.laz", xyz, run.frame, out_frame, gps_time=run.scan.time_s,
                                   intensity=run.scan.intensity, point_source_id=run.scan.strip_id,
                                   note="strip-adjusted laser cloud (skyrig lidar stage)")
        summary = {"mode": "strip adjustment (raw scan + trajectory)", "points": len(run.scan),
                   "strips": len(run.result.strip_ids), "planes": run.result.n_planes, "sigma0": run.result.sigma0,
                   "held": list(run.result.held), "discrepancies_before": run.before, "discrepancies_after": run.after,
                   **stated}
        report = {**summary, "inputs": {"scan": str(raw[0]), "trajectory": str(trajectory), "rig": str(rig),
                                        "reference": opts.get("reference")},
                  "adjustment_frame": run.frame.describe(), **run.result.to_dict()}
    else:
        from skyrig.lidar.strips import adjust_line_offsets

        xyz, line, gps, inten, own = _read_clouds(clouds, out_frame)
        progress(1, 3)
        r = adjust_line_offsets(xyz, line, cell_m=opts.get("cell_lines", 4.0), mode=opts.get("offsets", "vertical"))
        k = np.searchsorted(r.line_ids, line)
        adjusted = xyz + np.nan_to_num(r.offset)[k]
        progress(2, 3)
        note = "per-line offsets (skyrig lidar stage)"
        if own is None:
            stated = write_laser_cloud(out / "laser.laz", adjusted, out_frame, out_frame, gps_time=gps,
                                       intensity=inten, point_source_id=line, note=note)
        else:  # the project's horizontal CRS: the files' own CRS and heights kept (in their units)
            from skyrig.io.laz import write_las

            crs, fac = own
            words = (f"as delivered: {crs.sub_crs_list[1].name}" if crs.is_compound else
                     "ellipsoidal heights" if len(crs.axis_info) >= 3 else "heights as delivered (CRS without a "
                     "vertical part)")
            write_las(out / "laser.laz", adjusted / fac, crs, gps_time=gps, intensity=inten, extra={"line": line},
                      extra_types={"line": np.int32}, metadata={"skyrig_vertical_reference": words, "skyrig_note": note})
            stated = {"crs": crs.name, "vertical_reference": words}
        summary = {"mode": f"per-line {r.mode} offsets (georeferenced clouds, no trajectory)", "points": len(xyz),
                   "lines": len(r.line_ids), "patches": r.patches, "sigma0": r.sigma0,
                   "discrepancies_before": r.before, "discrepancies_after": r.after, **stated}
        report = {**summary, "inputs": {"clouds": [str(c) for c in clouds]}, **r.to_dict()}
    summary["seconds"] = time.perf_counter() - t0
    _json(out / "strips.json", report)
    progress(3, 3)
    return summary


def _read_clouds(paths: list[Path], out_frame: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Any]:
    """Points of LAS/LAZ files in metres, their line ids, GPS times, intensities, and how to write them back:
    ``None`` (``xyz`` is in ``out_frame``) or ``(crs, factors)`` -- files in the project's horizontal CRS keep their
    own CRS and heights (no datum change: a vertical datum needs its geoid grid), ``xyz`` scaled to metres by
    ``factors`` (e.g. heights in US survey feet)."""
    import pyproj

    from skyrig.geodesy.crs import horizontal_crs, resolve_crs
    from skyrig.geodesy.statement import frame_from_file_crs
    from skyrig.io.laz import read_las

    clouds = [read_las(p, require_crs=True) for p in paths]
    for p, c in zip(paths, clouds):
        if c.point_source_id is None:
            raise InputFormatError("no point_source_id (flight line) dimension", p, field="point_source_id")
    crss = [pyproj.CRS.from_wkt(str(c.crs_wkt)) for c in clouds]
    line = np.concatenate([np.asarray(c.point_source_id, np.int64) for c in clouds])
    gps = np.concatenate([c.gps_time if c.gps_time is not None else np.zeros(len(c)) for c in clouds])
    inten = np.concatenate([c.intensity if c.intensity is not None else np.zeros(len(c)) for c in clouds])
    same = all(c == crss[0] for c in crss) and horizontal_crs(crss[0]) == horizontal_crs(resolve_crs(out_frame.crs))
    if same:
        axes = crss[0].axis_info
        f = np.array([float(axes[0].unit_conversion_factor), float(axes[1].unit_conversion_factor),
                      float(axes[-1].unit_conversion_factor) if len(axes) >= 3 else 1.0])
        return np.concatenate([c.xyz for c in clouds]) * f, line, gps, inten, (crss[0], f)
    xyz = []
    for p, c, crs in zip(paths, clouds, crss):
        fr = frame_from_file_crs(crs, c.metadata.get("geoid") or None, c.metadata.get("vertical_reference"))
        xyz.append(out_frame.from_ecef(fr.to_ecef(c.xyz)))
    return np.concatenate(xyz), line, gps, inten, None


def simulate_laser_project(folder: PathLike, seed: int = 2, step_deg: float = 1.0,
                           pass_u_m: tuple[float, float] = (26.0, 12.0)) -> Any:
    """A tiny laser project of the uav-bridge-lidar strip flight in ``folder``: ``scan.csv`` (raw scan with strip ids),
    ``trajectory.csv`` (recorded), ``rig.yaml`` (the nominal scanner record), ``tls_reference.laz`` (the terrestrial
    reference, EPSG:32633, ellipsoidal heights) and ``project.yaml`` (stages ``lidar`` with the flight's stated
    accuracies, ``dtm``).  Returns the simulated survey (its truth judges the outputs)."""
    from dataclasses import replace

    from skyrig.geodesy.frame import WorldFrame
    from skyrig.io.laz import write_las
    from skyrig.io.raw_scan_csv import write_raw_scan_csv
    from skyrig.io.scanner_record import write_scanner_record
    from skyrig.io.trajectory_csv import write_trajectory_csv
    from skyrig.lidar.scanner import Scanner2D
    from skyrig.simulate.lidar import build_lidar_survey, lidar_scenario_spec

    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    spec = replace(lidar_scenario_spec("strips-ci", seed), scanner=Scanner2D(step_deg=step_deg), pass_u_m=pass_u_m,
                   reference_density_per_m2=40.0, reference_ground_density_per_m2=10.0)
    sv = build_lidar_survey(spec)
    write_raw_scan_csv(root / "scan.csv", sv.scan)
    write_trajectory_csv(root / "trajectory.csv", sv.trajectory_recorded, crs="EPSG:4979")
    m = sv.mount_recorded
    write_scanner_record(root / "rig.yaml", {"name": "lidar", "body_from_scanner": m.body_from_scanner.tolist(),
                                             "lever_arm_m": m.lever_arm_m.tolist()})
    write_las(root / "tls_reference.laz", WorldFrame.map("EPSG:32633").from_ecef(sv.frame.to_ecef(sv.reference_xyz)),
              "EPSG:32633")
    e = spec.errors
    deg = float(np.degrees(1.0))
    (root / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\nname: laser-strips\ncrs: EPSG:32633\noutput: output\n"
        "inputs: {laser: [scan.csv], trajectory: trajectory.csv, rig: rig.yaml}\n"
        f"stages:\n  lidar: {{reference: tls_reference.laz, range_sigma: {e.range_sigma_m}, "
        f"position_sigma: [{', '.join('%g' % v for v in e.strip_position_sigma_m)}], "
        f"attitude_sigma_deg: [{', '.join('%.6g' % (v * deg) for v in e.strip_attitude_sigma_rad)}]}}\n"
        "  dtm: {resolution: 1.0, cloth_resolution: 0.5}\n")
    return sv
