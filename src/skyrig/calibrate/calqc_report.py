"""The ``calqc`` report as text tables (steps, calibration, Tab. 11, the grid's effect) and as an HTML page.
"""

from __future__ import annotations

import html
from typing import Any, Mapping

import numpy as np


__all__ = ["format_tables", "report_html"]


# ------------------------------------------------------------------------------------------------ reports
def _f(v: Any, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def format_tables(report: Mapping[str, Any]) -> str:
    """The steps, the calibration, the separability and Tab. 11 as plain text (what the CLI prints)."""
    out = []
    fl = report["flight"]
    out.append(f"flight: heights {[round(h) for h in fl['heights_m']]} m above ground, headings "
               f"{fl['headings_deg']} deg, opposite directions: {'yes' if fl['opposite_directions'] else 'no'}")
    out.append("CalQC steps  IO        datum   ctrl check snoop  sigma[um] rejected  RMS control XYZ [m]   RMS check XYZ [m]")
    for s in report["steps"]:
        out.append(f"  {s['step']:<10} {s['io']:<9} {s['datum_shift']:<7} {s['control']:>4} {s['check']:>5} "
                   f"{'on' if s['blunder_detection'] else 'off':>5} {s['sigma_um']:10.2f} {s['rejected']:>8}  "
                   + " ".join(_f(x, "6.3f") for x in s["rms_control_m"]) + "  "
                   + " ".join(_f(x, "6.3f") for x in s["rms_check_m"]))
    for n in report.get("notes") or []:
        out.append(f"  note: {n}")
    r = report["result"]
    out.append("boresight corrections (rotation vector about the camera axes, 1/1000 deg, +- sigma):")
    for h, b in r["boresight"].items():
        out.append(f"  {h:<10} " + "  ".join(f"{v:8.2f} +- {s:5.2f}" for v, s in zip(b["rotvec_mdeg"], b["sigma_mdeg"])))
    out.append("interior orientation [mm] (start -> adjusted +- sigma):")
    for h, io in r["interior_orientation"].items():
        out.append(f"  {h:<10} " + "  ".join(f"{n} {e['start_mm']:.4f} -> {e['value_mm']:.4f} +- {e['sigma_mm']:.4f}"
                                             for n, e in io.items()))
    out.append("GNSS datum shift (GNSS minus control) [m]: " + ", ".join(
        f"{a} {v:.3f} +- {s:.3f}" for a, v, s in zip("XYZ", r["datum_shift_m"], r["datum_shift_sigma_m"])))
    if report["inseparable"]:
        out.append("INSEPARABLE in this flight:")
        for e in report["inseparable"]:
            out.append(f"  step {e['step']}: {e['text']}; would be separated by {e['separating_flight']}")
    else:
        out.append("all calibration unknowns separable (no correlation above the limit)")
    ds = report.get("inseparable_by_head") or {}
    if ds:
        tried = ", ".join(f"{k} (+{v['images_added']} images)" for k, v in ds["flights_tried"].items()) or "none"
        out.append(f"design study (flights added virtually: {tried}; named: an excess sigma gain >= "
                   f"{ds['excess_limit']} or a multiple correlation > {ds['limit']}):")
        if not ds["by_head"]:
            out.append("  every calibration unknown separable in this flight")
        for h, es in ds["by_head"].items():
            out.append(f"  {h}:")
            for e in es:
                out.append(f"    {'[any flight] ' if e['separating_flight'] is None else ''}{e['text']}")
    t = report["table11"]
    if t.get("variants"):
        blocks = t["blocks"]
        out.append("Tab. 11: bundle adjustment results")
        for v, vd in t["variants"].items():
            out.append(f"  {vd['title']}")
            out.append("    " + f"{'':<22}" + "".join(f"{b:>24}" for b in blocks))
            cols = [vd["columns"][b] for b in blocks]
            out.append("    " + f"{'GSD (cm)':<22}" + "".join(f"{_f(c['gsd_cm'], '.1f'):>24}" for c in cols))
            out.append("    " + f"{'Sigma (um)':<22}" + "".join(f"{_f(c['sigma_um'], '.2f'):>24}" for c in cols))
            for key, lab, fmt in (("rms_control_m", "RMS Control {} (m)", ".3f"), ("rms_check_m", "RMS Check {} (m)", ".3f"),
                                  ("rms_photo_position_m", "RMS Photo Pos. {} (m)", ".3f"),
                                  ("rms_photo_attitude_deg", "RMS Photo Att. {} (d)", ".4f"),
                                  ("gps_block_shift_m", "GPS Block Shift {} (m)", ".3f")):
                for k, a in enumerate("XYZ"):
                    out.append("    " + f"{lab.format(a):<22}" + "".join(
                        f"{_f(None if c[key] is None else c[key][k], fmt):>24}" for c in cols))
    ge = report.get("correction_grid_effect") or {}
    if ge:
        out.append("correction grid (least-squares collocation of the whole flight's residuals, estimated with the IO; "
                   f"its effect on block {ge['block']}):")
        for k, g in report["correction_grid"].items():
            cv = g["covariance"]
            out.append(f"  {k}: {g['residuals']} residuals, signal {np.sqrt(cv['c0_px2']):.3f} px, correlation length "
                       f"{cv['length_px']:.0f} px, noise {np.sqrt(cv['nugget_px2']):.3f} px, max correction "
                       f"{g['max_correction_px']:.3f} px (mean sigma {g['mean_sigma_px']:.3f} px)")
        for lab in ("before", "after"):
            e = ge[lab]
            out.append(f"  {lab:<6}: sigma {e['sigma_um']:.3f} um, RMS check XYZ " + " ".join(_f(x, ".3f") for x in e["rms_check_m"]))
    return "\n".join(out)


def report_html(report: Mapping[str, Any]) -> str:
    """A self-contained HTML page with the tables."""
    return ("<!doctype html><meta charset='utf-8'><title>calqc calibration</title>"
            "<h1>System calibration of a multi-head rig (paper 004 CalQC recipe)</h1>"
            f"<p>frame {html.escape(str(report['frame']))}</p><pre>{html.escape(format_tables(report))}</pre>")
