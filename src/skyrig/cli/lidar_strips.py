"""``skyrig lidar strips``: LiDAR strip adjustment -> a calibrated scanner record in a rig file and a report
(a thin shim over :mod:`skyrig.lidar.strips`; registered in :mod:`skyrig.cli.lidar`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click
import numpy as np

from skyrig.errors import InputFormatError

#: report units: (label, factor from SI) per calibration parameter
_UNITS = {"boresight": ("deg", float(np.degrees(1.0))), "lever": ("mm", 1000.0), "range_offset": ("mm", 1000.0),
          "range_scale": ("ppm", 1e6)}


def _unit(name: str) -> tuple[str, float]:
    return _UNITS[next(k for k in _UNITS if name.startswith(k))]


def _triple(text: str, option: str, scale: float = 1.0) -> tuple[float, float, float]:
    try:
        v = [float(x) * scale for x in text.replace(";", ",").split(",")]
    except ValueError:
        raise click.BadParameter(f"expected 3 comma-separated numbers, got {text!r}", param_hint=option) from None
    if len(v) == 1:
        v = v * 3
    if len(v) != 3 or not all(np.isfinite(v)) or min(v) <= 0:
        raise click.BadParameter(f"expected 1 or 3 positive numbers, got {text!r}", param_hint=option)
    return (v[0], v[1], v[2])


def _data_line(path: str, k: int) -> int | None:
    """The line number (1-based) of data row ``k`` of a raw scan CSV (comments, blank lines and the header skipped)."""
    seen_header = False
    row = -1
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, ln in enumerate(fh, start=1):
            s = ln.strip()
            if not s or s.startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            row += 1
            if row == k:
                return lineno
    return None


def run_strips(scan_path: str, traj_path: str, mount_path: str, scanner: str | None, reference: str | None,
               opts: dict[str, Any], output: str, report_path: str | None, base_rig: str | None,
               cloud: str | None, crs: str | None) -> dict[str, Any]:
    """Read, check, adjust, write (see :func:`skyrig.cli.lidar.strips_cmd`)."""
    from skyrig import __version__
    from skyrig.cli.georef import load_trajectory
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.raw_scan_csv import read_raw_scan_csv
    from skyrig.io.scanner_record import read_scanner_mount, write_scanner_record
    from skyrig.lidar.scanner import RawScan
    from skyrig.lidar.strips import (CALIBRATION_NAMES, PatchOptions, StripModel, adjust_strips, find_planar_patches,
                                     patch_discrepancies)

    scan, _ = read_raw_scan_csv(scan_path)
    if scan.strip_id is None:
        raise InputFormatError("the raw scan has no 'strip' column: the strip adjustment needs the flight line of "
                               "every pulse", scan_path, None, "strip")
    traj = load_trajectory(traj_path, None)
    t0, t1 = traj.span
    bad = np.flatnonzero((scan.time_s < t0) | (scan.time_s > t1))
    if bad.size:
        k = int(bad[0])
        raise InputFormatError(f"pulse time {scan.time_s[k]!r} is outside the trajectory {traj_path} "
                               f"([{t0!r}, {t1!r}] s, {traj.time_system}); {bad.size} pulse(s) in all",
                               scan_path, _data_line(scan_path, k), "time")
    mount, extra = read_scanner_mount(mount_path, scanner)
    r0n = float(extra.get("range_offset_m", 0.0))
    sn = float(extra.get("range_scale_ppm", 0.0)) * 1e-6
    if r0n or sn:  # the nominal range correction first; the adjustment estimates what is left
        scan = RawScan(scan.time_s, (scan.range_m - r0n) / (1.0 + sn), scan.alpha_rad, scan.beta_rad, scan.intensity,
                       scan.strip_id)
    lat, lon, h = (float(np.mean(traj.lat_deg)), float(np.mean(traj.lon_deg)), float(np.mean(traj.h_m)))
    frame = WorldFrame.local(lat, lon, h)
    control = None
    ref_crs = None
    if reference is not None:
        from skyrig.io.laz import read_las

        ref = read_las(reference, require_crs=True)
        ref_crs = ref.crs_wkt
        control = frame.from_ecef(WorldFrame.map(ref_crs).to_ecef(ref.xyz))
    model = StripModel(**opts["model"])
    patches = find_planar_patches(scan, traj, mount, frame, options=PatchOptions(**opts["patches"]), control=control)
    res = adjust_strips(patches, mount, model=model, estimate=opts["estimate"])
    before = patch_discrepancies(patches, mount, model)
    after = patch_discrepancies(patches, mount, model, res)
    cal, sig = res.calibration, res.calibration_sigma
    r0e, se = float(cal[6]), float(cal[7])
    held = list(res.held)

    def block(idx: slice, names: tuple[str, ...], factor: float = 1.0) -> dict[str, Any]:
        return {"parameters": list(names), "values": (cal[idx] * factor).tolist(), "sigma": (sig[idx] * factor).tolist(),
                "correlation": res.correlation[idx, idx].tolist()}

    stats = {"sigma0": res.sigma0, "redundancy": res.redundancy, "planes": res.n_planes, "laser_points": res.n_points,
             "laser_points_searched": patches.n_points_total, "control_points": res.n_control,
             "rms_before_m": res.rms_before_m, "rms_after_m": res.rms_after_m,
             "discrepancy_rms_before_m": before["rms_m"], "discrepancy_rms_after_m": after["rms_m"],
             "discrepancy_noise_rms_m": after["noise_rms_m"]}
    record = {
        "name": opts["name"],
        "body_from_scanner": res.mount.body_from_scanner.tolist(),
        "lever_arm_m": res.mount.lever_arm_m.tolist(),
        "range_offset_m": r0n + (1.0 + sn) * r0e,
        "range_scale_ppm": ((1.0 + sn) * (1.0 + se) - 1.0) * 1e6,
        "range_sigma_m": model.range_sigma_m,
        "calibration": {
            "boresight_rad": block(slice(0, 3), CALIBRATION_NAMES[0:3]),
            "lever_arm_m": block(slice(3, 6), CALIBRATION_NAMES[3:6]),
            "range": {"parameters": ["range_offset_m", "range_scale_ppm"], "values": [r0e, se * 1e6],
                      "sigma": [float(sig[6]), float(sig[7]) * 1e6], "correlation": res.correlation[6:8, 6:8].tolist()},
            "held": held,
            "nominal": {"body_from_scanner": mount.body_from_scanner.tolist(), "lever_arm_m": mount.lever_arm_m.tolist(),
                        "range_offset_m": r0n, "range_scale_ppm": sn * 1e6},
            "provenance": {"recipe": "skyrig lidar strips (strip adjustment on planar patches)",
                           "flight": opts["flight"], "date": opts["date"], "software": f"skyrig {__version__}",
                           "statistics": stats,
                           "notes": ["boresight: rotation vector in the scanner frame, body_from_scanner = nominal @ "
                                     "expmap(boresight); lever arm: correction to the nominal, body frame; range: "
                                     "recorded = (1 + scale) true + offset (values: corrections to the nominal)",
                                     f"covariance {res.covariance_kind} (sigma0 {res.sigma0:.3f})", res.rule,
                                     *[v.words() for v in res.verdicts if v.verdict != "determined"]]},
        },
    }
    write_scanner_record(output, record, base_rig)
    report = {"inputs": {"scan": scan_path, "trajectory": traj_path, "mount": mount_path, "reference": reference,
                         "rig": base_rig}, "frame": frame.describe(), "output": output,
              "discrepancies_before": before, "discrepancies_after": after, **res.to_dict()}
    report_path = report_path or str(Path(output).with_suffix(".json"))
    from skyrig.io._text import atomic_write
    from skyrig.io.truth import _plain

    with atomic_write(report_path) as fh:
        json.dump(_plain(report), fh, indent=1)
        fh.write("\n")
    if cloud is not None:
        from skyrig.io.laz import write_las
        from skyrig.lidar.strips import apply_strip_corrections

        out_crs = crs or ref_crs or "EPSG:4978"
        xyz = apply_strip_corrections(scan, traj, mount, frame, res)
        of = WorldFrame.ecef() if out_crs == "EPSG:4978" else WorldFrame.map(out_crs)
        write_las(cloud, of.from_ecef(frame.to_ecef(xyz)), out_crs, gps_time=scan.time_s, intensity=scan.intensity)
    return {"result": res, "before": before, "after": after, "report": report_path}


def echo_table(out: dict[str, Any]) -> None:
    """The report table on the terminal."""
    from skyrig.lidar.strips import CALIBRATION_NAMES

    res, before, after = out["result"], out["before"], out["after"]
    click.echo(f"{'parameter':<14}{'estimate':>12}{'sigma':>10}  unit  verdict")
    for v, name in zip(res.verdicts, CALIBRATION_NAMES):
        unit, f = _unit(name)
        click.echo(f"{name:<14}{v.estimate * f:>12.4f}{v.sigma * f:>10.4f}  {unit:<4}  {v.verdict}"
                   + (" (held)" if v.held else ""))
    click.echo(f"strips {len(res.strip_ids)}, planes {res.n_planes}, laser points {res.n_points:,}, control points "
               f"{res.n_control:,}; sigma0 {res.sigma0:.3f} (redundancy {res.redundancy:,}), {res.iterations} iterations")
    click.echo(f"strip-to-strip discrepancies on {after['pairs']:,} patch pairs: RMS {before['rms_m'] * 1000:.1f} mm -> "
               f"{after['rms_m'] * 1000:.1f} mm (noise {after['noise_rms_m'] * 1000:.1f} mm; normalised "
               f"{before['normalised_rms']:.2f} -> {after['normalised_rms']:.2f})")
    for v in res.verdicts:
        if v.held:
            click.echo(f"held: {v.words()}")
