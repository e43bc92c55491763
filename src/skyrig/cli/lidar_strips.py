"""``skyrig lidar strips``: LiDAR strip adjustment -> a calibrated scanner record in a rig file and a report
(a thin shim over :mod:`skyrig.lidar.strips`; registered in :mod:`skyrig.cli.lidar`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import numpy as np

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


def run_strips(scan_path: str, traj_path: str, mount_path: str, scanner: str | None, reference: str | None,
               opts: dict[str, Any], output: str, report_path: str | None, base_rig: str | None,
               cloud: str | None, crs: str | None) -> dict[str, Any]:
    """Read, check, adjust, write (see :func:`skyrig.cli.lidar.strips_cmd`; the work is
    :func:`skyrig.pipeline.lidar.strip_adjustment`)."""
    from skyrig.io.scanner_record import write_scanner_record
    from skyrig.pipeline.lidar import _json, scanner_record, strip_adjustment

    run = strip_adjustment(scan_path, traj_path, mount_path, scanner, reference, opts)
    res = run.result
    record = scanner_record(run, opts["name"], {"flight": opts["flight"], "date": opts["date"]})
    write_scanner_record(output, record, base_rig)
    report = {"inputs": {"scan": scan_path, "trajectory": traj_path, "mount": mount_path, "reference": reference,
                         "rig": base_rig}, "frame": run.frame.describe(), "output": output,
              "discrepancies_before": run.before, "discrepancies_after": run.after, **res.to_dict()}
    report_path = report_path or str(Path(output).with_suffix(".json"))
    _json(Path(report_path), report)
    if cloud is not None:
        from skyrig.georef.eo import WorldFrame
        from skyrig.io.laz import write_las
        from skyrig.lidar.strips import apply_strip_corrections

        from skyrig.geodesy.statement import file_crs

        # --crs, else the reference cloud's own frame (its vertical reference included), else ECEF
        ref = run.reference_frame
        of = (WorldFrame.ecef() if crs == "EPSG:4978" else WorldFrame.map(crs) if crs
              else ref if ref is not None and ref.kind == "map" else WorldFrame.ecef())
        out_crs: object = "EPSG:4978" if of.kind == "ecef" else file_crs(of).full
        xyz = apply_strip_corrections(run.scan, run.trajectory, run.mount, run.frame, res)
        write_las(cloud, of.from_ecef(run.frame.to_ecef(xyz)), out_crs, gps_time=run.scan.time_s,
                  intensity=run.scan.intensity)
    return {"result": res, "before": run.before, "after": run.after, "report": report_path}


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
