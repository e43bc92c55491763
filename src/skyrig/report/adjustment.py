"""Report sections of a bundle adjustment / integrated sensor orientation (paper 004's tables and more).

:func:`report_data_from_adjustment` turns an :class:`~skyrig.adjust.AdjustmentResult` into a
:class:`~skyrig.report.model.ReportData`; each section has its own registered builder (``make_section(key,
result, ...)``) so that a caller can assemble a page of its own.  The numbers of the summary, control/check,
orientation and per-camera tables are those of :func:`skyrig.adjust.report.adjustment_report` (the same as
``report.json``); the others are computed here from the result's arrays.

Units: metres for coordinates, lever arms and shifts; angles in degrees and arc-seconds; image residuals in
pixels (and micrometres where the pixel size is known); interior orientation in millimetres and pixels,
distortion coefficients in the units their model states (``param_units``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, is_dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.report import plots
from skyrig.report.model import (
    Column,
    Figure,
    InputFile,
    Note,
    ReportData,
    Section,
    Table,
    flatten,
    key_value_table,
    make_section,
    register_section,
)

__all__ = ["report_data_from_adjustment", "report_data_from_uav", "input_files", "block_file_inputs",
           "ARCSEC_PER_RAD"]

ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0
_AXES = ("X", "Y", "Z")


# --------------------------------------------------------------------------- inputs
def _sha256(path: Path) -> tuple[str | None, int | None]:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        return h.hexdigest(), path.stat().st_size
    except OSError:
        return None, None


def input_files(paths: Iterable[str | os.PathLike[str]]) -> list[InputFile]:
    """SHA-256 and size of each input file (None for a file that cannot be read); duplicates dropped."""
    out, seen = [], set()
    for p in paths:
        if str(p) in seen:
            continue
        seen.add(str(p))
        digest, size = _sha256(Path(p))
        out.append(InputFile(str(p), digest, size))
    return out


def block_file_inputs(block_path: str | os.PathLike[str]) -> list[Path]:
    """A block file (docs/formats/block.md) and the tables its manifest names (paths as found next to it)."""
    p = Path(block_path)
    out = [p]
    try:
        tables = json.loads(p.read_text(encoding="utf-8-sig")).get("tables", {})
    except (OSError, ValueError, AttributeError):
        return out
    if isinstance(tables, dict):
        out += [p.parent / str(t) for t in tables.values()]
    return out


# --------------------------------------------------------------------------- helpers
def _rms(a: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.mean(np.asarray(a, float) ** 2, axis=axis)) if np.size(a) else np.full(
            np.shape(a)[1] if np.ndim(a) > 1 else 1, np.nan)


def _covariance(result: Any, labels: Sequence[tuple[str, str, str]]) -> NDArray[np.float64] | None:
    """A-posteriori covariance ``(k, k)`` of reduced unknowns named by ``labels`` (None if unknown or not estimated)."""
    s0 = float(result.sigma0)
    if result.covariance is not None:
        idx = {lab: i for i, lab in enumerate(result.layout.labels)}
        Q = result.covariance.Qcc
    elif result.selected is not None:
        idx = {lab: i for i, lab in enumerate(result.selected.labels)}
        Q = result.selected.Qcc
    else:
        return None
    if not all(lab in idx for lab in labels) or not math.isfinite(s0):
        return None
    i = np.array([idx[lab] for lab in labels])
    return s0**2 * Q[np.ix_(i, i)]


def _estimated(result: Any, label: tuple[str, str, str]) -> bool:
    return label in set(result.layout.labels)


def _sig(cov: NDArray[np.float64] | None, k: int) -> float:
    return float(np.sqrt(max(cov[k, k], 0.0))) if cov is not None else float("nan")


def _frame_axes(frame_text: str) -> tuple[str, str, str]:
    return ("E", "N", "U") if "local ENU" in frame_text else ("X", "Y", "Z")


def _table_frame(rep: dict[str, Any], b: Any) -> tuple[tuple[str, str, str], str]:
    """Axes and words of the frame of the control / check tables of ``rep`` (the project CRS when the report
    dict states one, else the block frame)."""
    s = rep.get("summary", {})
    if s.get("adjusted_in") and s.get("frame"):
        vert = f"; {s['vertical']}" if s.get("vertical") else ""
        return ("E", "N", "H"), f"project CRS {s['frame']}{vert} (grid east, grid north, height)"
    return _frame_axes(str(b.frame)), f"block frame {b.frame}"


def _frames_of(rep: dict[str, Any], b: Any) -> tuple[Any, Any]:
    """(block frame, project frame) read from the report dict's text forms (None when not known)."""
    try:
        from skyrig.geodesy import WorldFrame
    except ImportError:  # pragma: no cover - an older geodesy package
        return None, None
    s = rep.get("summary", {})
    out = []
    for text in (s.get("adjusted_in") or str(b.frame), s.get("frame") if s.get("adjusted_in") else None):
        try:
            out.append(WorldFrame.from_text(text) if text else None)
        except Exception:  # noqa: BLE001 - free text: no frame
            out.append(None)
    return out[0], out[1]


# --------------------------------------------------------------------------- sections
@register_section("summary", order=10)
def summary_section(result: Any, rep: dict[str, Any]) -> Section:
    """Paper 004 Tab. 11 quantities (sigma0 in px and um, RMS control/check, photo position / attitude RMS, GPS
    block shift), the adjustment statistics and the variance components per observation group."""
    b = result.block
    s, o = rep["summary"], rep["orientation"]
    act = result.residuals["image"].weight > 0 if "image" in result.residuals else np.zeros(0, bool)
    sig_px = float(np.median(np.asarray(b.obs_sigma_px)[act])) if act.any() else float("nan")
    pix_mm = [getattr(b.cameras[c], "pixel_size_mm", float("nan")) for c in b.image_camera[b.obs_image[act]]]
    pix_um = float(np.median(pix_mm)) * 1000.0 if len(pix_mm) else float("nan")
    s0 = float(result.sigma0)
    ctl, chk = rep["control"]["stats"], rep["check"]["stats"]
    items: list[tuple[str, Any, str]] = [
        ("sigma0 (a-posteriori, unit weight)", s0, ""),
        ("sigma0 of an image observation", s0 * sig_px, "px"),
        ("sigma0 of an image observation", s0 * sig_px * pix_um, "um"),
        ("a-priori image sigma (median)", sig_px, "px"),
    ]
    for name, st in (("control", ctl), ("check", chk)):
        for k, ax in enumerate(_AXES):
            items.append((f"RMS {name} points {ax} (n = {st['n']})", st["rms_m"][k], "m"))
    if "gnss_rms_m" in o:
        for k, ax in enumerate(_AXES):
            items.append((f"RMS photo position vs GNSS {ax}", o["gnss_rms_m"][k], "m"))
    if "imu_rms_deg" in o:
        for k, ax in enumerate(("rx", "ry", "rz")):
            items.append((f"RMS photo attitude vs IMU {ax}", o["imu_rms_deg"][k], "deg"))
    if "gnss_block_shift_m" in o:
        for k, ax in enumerate(_AXES):
            items.append((f"GPS block shift {ax} (mean GNSS - adjusted)", o["gnss_block_shift_m"][k], "m"))
    if _estimated(result, ("datum_shift", "gnss", "X")):
        for k, ax in enumerate(_AXES):
            items.append((f"estimated GNSS datum shift {ax}", o["datum_shift_m"][k], "m"))
    where = _table_frame(rep, b)[1]
    t11 = Table("summary", "Summary (paper 004 Tab. 11)", [Column("quantity"), Column("value", decimals=4),
                                                             Column("unit")], [list(r) for r in items],
                f"Control / check RMS in the {where}; GNSS and shifts in the adjustment frame {b.frame} (X, Y, Z: "
                f"its axes, E, N, up in a local ENU frame).")
    stats = Table("statistics", "Adjustment", [Column("item"), Column("value", decimals=4)], [
        ["converged", bool(s["converged"])], ["optimiser message", s["message"]], ["iterations", s["iterations"]],
        ["observations (scalar)", s["observations"]], ["unknowns", s["unknowns"]], ["redundancy", s["redundancy"]],
        ["images", s["images"]], ["stations", s["stations"]], ["object points", s["points"]],
        ["image observations", s["image_observations"]], ["wall time (s)", s["wall_s"]]])
    groups = Table("groups", "Observation groups (variance components)",
                   [Column("group"), Column("n"), Column("redundancy", decimals=1),
                    Column("variance factor", decimals=3), Column("RMS residual per component", decimals=4),
                    Column("unit")],
                   [[g, st.n_rows, st.redundancy, st.sigma0, st.rms, _group_units(g)]
                    for g, st in result.groups.items()],
                   "Variance factor: a-posteriori sigma of the group (1 when the a-priori sigmas fit).")
    return Section("summary", "Summary", [t11, stats, groups])


def _group_units(group: str) -> str:
    """The unit of a group's residuals, from its observation type (``skyrig.adjust.factors``: a new type's
    module states it; nothing here to edit)."""
    from skyrig.adjust.factors import observation_type

    t = observation_type(group)
    return t.units if t is not None else ""


def _boresight_rows(result: Any) -> list[list[Any]]:
    b, b0 = result.block, result.initial
    rows = []
    for h, head in enumerate(b.head_name):
        if not np.any(b.image_head == h):
            continue
        labs = [("boresight", str(head), c) for c in ("rx", "ry", "rz")]
        est = _estimated(result, labs[0])
        cov = _covariance(result, labs) if est else None
        v, v0 = b.head_boresight[h], b0.head_boresight[h]
        for k, c in enumerate(("about camera x", "about camera y", "about camera z")):
            sg = _sig(cov, k) if est else float("nan")
            rows.append([str(head), c, float(np.degrees(v0[k])), float(np.degrees(v[k])), v[k] * ARCSEC_PER_RAD,
                         float(np.degrees(sg)), sg * ARCSEC_PER_RAD, "estimated" if est else "fixed"])
        imgs = np.flatnonzero(b.image_head == h)
        R = b.image_rotation[imgs[0]]
        actuated = b.head_actuated[h] is not None
        if not actuated and not np.allclose(R, np.eye(3)) and np.allclose(b.image_rotation[imgs], R):
            vb, vb0 = R @ v, R @ v0
            cb = R @ cov @ R.T if cov is not None else None
            for k, c in enumerate(("roll (body x)", "pitch (body y)", "yaw (body z)")):
                sg = _sig(cb, k) if est else float("nan")
                rows.append([str(head), c, float(np.degrees(vb0[k])), float(np.degrees(vb[k])),
                             vb[k] * ARCSEC_PER_RAD, float(np.degrees(sg)), sg * ARCSEC_PER_RAD,
                             "estimated" if est else "fixed"])
    return rows


def _vector_rows(result: Any, group: str, owner: str, comps: Sequence[str], value: NDArray, start: NDArray,
                 name: str, unit: str) -> list[list[Any]]:
    labs = [(group, owner, c) for c in comps]
    est = _estimated(result, labs[0])
    cov = _covariance(result, labs) if est else None
    return [[name, c, float(start[k]), float(value[k]), _sig(cov, k), unit, "estimated" if est else "fixed"]
            for k, c in enumerate(comps)]


def _intrinsic_rows(result: Any) -> list[list[Any]]:
    b, b0 = result.block, result.initial
    rows = []
    for k, cam in enumerate(b.cameras):
        if not np.any(b.image_camera == k):
            continue
        names = list(cam.intrinsic_names)
        vals, v0s = np.asarray(cam.intrinsics, float), np.asarray(b0.cameras[k].intrinsics, float)
        pix = getattr(cam, "pixel_size_mm", None)
        dist = getattr(cam, "distortion", None)
        dunits = dict(zip(getattr(dist, "param_names", ()), getattr(dist, "param_units", ())))
        for j, nm in enumerate(names):
            lab = ("intrinsics", cam.name, nm)
            est = _estimated(result, lab)
            cov = _covariance(result, [lab]) if est else None
            sg = _sig(cov, 0)
            if nm.endswith("_mm"):
                unit = "mm"
                px = (vals[j] / pix, sg / pix) if pix else (float("nan"), float("nan"))
            elif nm == "f":  # BAL: pixels
                unit, px = "px", (vals[j], sg)
            else:
                unit, px = dunits.get(nm, "1"), (float("nan"), float("nan"))
            rows.append([cam.name, nm, v0s[j], vals[j], sg, unit, px[0], px[1], "estimated" if est else "fixed"])
    return rows


def _actuator_rows(result: Any) -> list[list[Any]]:
    b = result.block
    rows = []
    for lab in result.layout.labels:
        if lab[0] not in ("actuator", "actuator_curve"):
            continue
        h = list(b.head_name).index(lab[1])
        j = (["beta_offset", "beta_scale"] + [None] * (b.actuator_correction.shape[1] - 2)).index(lab[2]) \
            if lab[2] in ("beta_offset", "beta_scale") else None
        if j is None:
            order = int(result.config.unknowns.actuator_fourier_order)
            names = [f"{cs}{k}_{ax}" for k in range(1, order + 1) for cs in ("c", "s")
                     for ax in ("roll", "pitch", "yaw")]
            j = 2 + names.index(lab[2])
        v = float(b.actuator_correction[h, j])
        sg = _sig(_covariance(result, [lab]), 0)
        if lab[2] == "beta_scale":
            rows.append([lab[1], lab[2], v * 1e6, sg * 1e6, "ppm", float("nan"), float("nan")])
        else:
            rows.append([lab[1], lab[2], float(np.degrees(v)), float(np.degrees(sg)), "deg", v * ARCSEC_PER_RAD,
                         sg * ARCSEC_PER_RAD])
    return rows


@register_section("calibration", order=20)
def calibration_section(result: Any) -> Section:
    """Boresight, lever arm, datum / strip shifts, interior orientation and actuator corrections with units and
    a-posteriori sigmas (sigma0-scaled); "fixed" rows show the value the adjustment held."""
    b, b0 = result.block, result.initial
    blocks: list[Any] = []
    bore = _boresight_rows(result)
    if bore:
        blocks.append(Table("boresight", "Boresight corrections", [
            Column("head"), Column("component"), Column("start", "deg", 6), Column("adjusted", "deg", 6),
            Column("adjusted", "arcsec", 2), Column("sigma", "deg", 6), Column("sigma", "arcsec", 2),
            Column("status")], bore,
            "The correction is a rotation vector in the camera frame (x right, y up, z backwards); for a rig head "
            "it is also given in the IMU body frame (x forward, y right, z down) as roll, pitch, yaw."))
    has_gnss = len(b.gnss_station) > 0
    sysrows: list[list[Any]] = []
    if has_gnss:
        sysrows += _vector_rows(result, "lever_arm", "antenna", ("x", "y", "z"), b.lever_arm, b0.lever_arm,
                                "lever arm (body frame)", "m")
        sysrows += _vector_rows(result, "datum_shift", "gnss", ("X", "Y", "Z"), b.datum_shift, b0.datum_shift,
                                "GNSS datum shift", "m")
        for t in range(b.n_strips):
            for grp, arr, arr0, nm, unit in (("strip_shift", b.strip_shift, b0.strip_shift, "strip shift", "m"),
                                             ("strip_drift", b.strip_drift, b0.strip_drift, "strip drift", "m/s")):
                if _estimated(result, (grp, f"strip{t}", "X")):
                    sysrows += _vector_rows(result, grp, f"strip{t}", ("X", "Y", "Z"), arr[t], arr0[t],
                                            f"{nm} strip {t}", unit)
    if sysrows:
        blocks.append(Table("gnss-imu", "GNSS/IMU system parameters", [
            Column("parameter"), Column("component"), Column("start", decimals=4), Column("adjusted", decimals=4),
            Column("sigma", decimals=4), Column("unit"), Column("status")], sysrows,
            "Lever arm: GNSS antenna in the IMU body frame (x forward, y right, z down).  Shifts in the "
            "adjustment frame's axes."))
    intr = _intrinsic_rows(result)
    if intr:
        blocks.append(Table("interior", "Interior orientation (self-calibration)", [
            Column("camera"), Column("parameter"), Column("start", decimals=4, style="e"),
            Column("adjusted", decimals=6, style="e"), Column("sigma", decimals=2, style="e"), Column("unit"),
            Column("adjusted", "px", 3), Column("sigma", "px", 3), Column("status")], intr,
            "focal_mm: principal distance; ppx_mm / ppy_mm: principal point from the image centre (x right, "
            "y up); the px columns divide by the pixel size.  Distortion coefficients in their model's units."))
    act = _actuator_rows(result)
    if act:
        blocks.append(Table("actuator", "Actuated head corrections", [
            Column("head"), Column("parameter"), Column("value", decimals=6), Column("sigma", decimals=6),
            Column("unit"), Column("value", "arcsec", 2), Column("sigma", "arcsec", 2)], act))
    if not blocks:
        blocks.append(Note("No calibration parameters in this block."))
    return Section("calibration", "Calibration results", blocks)


def _map_coordinates(result: Any, xyz: NDArray[np.float64], frame: Any, map_frame: Any
                     ) -> tuple[NDArray[np.float64], tuple[str, str], str, Any]:
    """Points of the block in the map (``map_frame`` when it is a projected CRS, else the block frame)."""
    b = result.block
    if frame is not None and map_frame is not None and getattr(map_frame, "kind", None) == "map":
        try:
            from pyproj import CRS

            crs = CRS.from_user_input(map_frame.crs)
            if crs.is_projected:
                names = [a.abbrev or a.name for a in crs.axis_info[:2]]
                return (map_frame.from_ecef(frame.to_ecef(xyz)), (names[0], names[1]),
                        f"map: {map_frame.describe()}", map_frame)
        except Exception:  # noqa: BLE001 - an exotic CRS: fall back to the block frame
            pass
    ax = _frame_axes(str(b.frame))
    return xyz.copy(), (f"{ax[0]} (block frame)", f"{ax[1]} (block frame)"), f"block frame: {b.frame}", None


def _point_rows(t: dict[str, Any]) -> list[list[Any]]:
    return [[r["point"], r["VX"], r["VY"], r["VZ"], r["VXYZ"]] for r in sorted(t["rows"], key=lambda x: -x["VXYZ"])]


@register_section("control", order=30)
def control_section(result: Any, rep: dict[str, Any], frame: Any = None, map_frame: Any = None,
                    folder: str | os.PathLike[str] | None = None) -> Section:
    """Control and check point residual tables (V = adjusted - given) and the residual map; with ``folder`` (where
    the adjustment's ``ground_control.csv`` is written) the ``skyrig measure`` command that re-measures them."""
    b, b0 = result.block, result.initial
    ax, where = _table_frame(rep, b)
    blocks: list[Any] = []
    cols = [Column("point"), Column(f"V{ax[0]}", "m", 4), Column(f"V{ax[1]}", "m", 4), Column(f"V{ax[2]}", "m", 4),
            Column("|V|", "m", 4)]
    for key, name in (("control", "Control points"), ("check", "Check points")):
        t = rep[key]
        if not t["rows"]:
            continue
        st = t["stats"]
        blocks.append(Table(key, f"{name} (V = adjusted - given)", cols, _point_rows(t), f"In the {where}."))
        srow = [["RMS", *st["rms_m"], st["rms_xyz_m"]], ["mean", *st["mean_m"], float("nan")],
                ["max |V|", *st["max_abs_m"], float("nan")]]
        if "rms_gsd" in st:
            srow.append(["RMS (GSD)", *st["rms_gsd"], float("nan")])
        blocks.append(Table(f"{key}-stats", f"{name}: statistics (n = {st['n']})",
                            [Column("statistic"), *cols[1:]], srow))
    cp = b0.control_point
    if len(cp):
        given = b0.control_xyz
        adj = b.point_xyz[cp]
        g_map, axes, crs_text, mf = _map_coordinates(result, given, frame, map_frame)
        a_map = _map_coordinates(result, adj, frame, map_frame)[0]
        png = plots.residual_map_png(g_map[:, :2], a_map - g_map, b0.control_check, b.point_name[cp], axes,
                                     crs_text)
        blocks.append(Figure("residual-map", f"Control (triangles) and check points (circles): horizontal residual "
                             f"vectors (adjusted - given, scaled; reference arrow bottom right, map scale bar bottom left), vertical residual as "
                             f"colour; {crs_text}.", png, "residual map"))
        if folder is not None:
            from skyrig.io.report_html import measure_command

            blocks.append(Note(measure_command(folder)))
    else:
        blocks.append(Note("No control or check points in this block."))
    return Section("control", "Control and check points", blocks)


@register_section("orientation", order=40)
def orientation_section(result: Any, rep: dict[str, Any], frame: Any = None, map_frame: Any = None) -> Section:
    """Projection centres and attitudes against GNSS / IMU, pose precision and the GNSS residual map."""
    o = rep["orientation"]
    b = result.block
    rows: list[list[Any]] = []
    if "gnss_rms_m" in o:
        rows += [[f"RMS GNSS residual {a}", o["gnss_rms_m"][k], "m"] for k, a in enumerate(_AXES)]
        rows += [[f"GPS block shift {a} (mean GNSS - adjusted)", o["gnss_block_shift_m"][k], "m"]
                 for k, a in enumerate(_AXES)]
        rows.append(["GNSS observations", o["gnss_n"], ""])
    if "imu_rms_deg" in o:
        rows += [[f"RMS IMU residual {a}", o["imu_rms_deg"][k], "deg"] for k, a in enumerate(("rx", "ry", "rz"))]
        rows += [[f"mean IMU residual {a}", o["imu_mean_deg"][k], "deg"] for k, a in enumerate(("rx", "ry", "rz"))]
    if "pose_sigma_rms" in o:
        p = o["pose_sigma_rms"]
        rows += [[f"RMS sigma of projection centre {a}", p["centre_m"][k], "m"] for k, a in enumerate(_AXES)]
        rows += [[f"RMS sigma of attitude {a}", p["rotation_deg"][k], "deg"] for k, a in enumerate(("rx", "ry", "rz"))]
    blocks: list[Any] = []
    if rows:
        blocks.append(Table("orientation", "Orientation against GNSS / IMU",
                            [Column("quantity"), Column("value", decimals=5), Column("unit")], rows,
                            "GNSS residual = adjusted antenna position - GNSS observation; IMU residual: rotation "
                            "vector about the station axes."))
    if "gnss" in result.residuals and len(b.gnss_station):
        g = result.residuals["gnss"]
        st = b.gnss_station
        ant = b.gnss_xyz + g.residual  # adjusted antenna positions
        g_map, axes, crs_text, _ = _map_coordinates(result, b.gnss_xyz, frame, map_frame)
        a_map = _map_coordinates(result, ant, frame, map_frame)[0]
        png = plots.residual_map_png(g_map[:, :2], a_map - g_map, np.zeros(len(st), bool), b.station_name[st],
                                     axes, crs_text, kinds=("GNSS antenna", ""))
        blocks.append(Figure("gnss-map", "GNSS residuals at the antenna positions (adjusted - observed, scaled; "
                             f"vertical as colour); {crs_text}.", png, "GNSS residual map"))
    if not blocks:
        blocks.append(Note("No GNSS or IMU observations in this block."))
    return Section("orientation", "Exterior orientation against GNSS / IMU", blocks)


@register_section("cameras", order=50)
def cameras_section(result: Any, rep: dict[str, Any], max_plots: int = 8) -> Section:
    """Per camera: images, image observations, residual RMS and max (px, um) and the residual vector plots."""
    b = result.block
    img = result.residuals["image"]
    act = img.weight > 0
    cam_of_obs = b.image_camera[b.obs_image]
    rows, figs = [], []
    for k, cam in enumerate(b.cameras):
        sel = (cam_of_obs == k) & act
        n_img = int(np.sum(b.image_camera == k))
        if not n_img:
            continue
        r = img.residual[sel]
        rms = _rms(r) if len(r) else np.full(2, np.nan)
        mx = np.abs(r).max(axis=0) if len(r) else np.full(2, np.nan)
        pix_um = getattr(cam, "pixel_size_mm", float("nan")) * 1000.0
        rows.append([cam.name, n_img, int(sel.sum()), rms[0], rms[1], float(np.sqrt(np.mean((r**2).sum(1))))
                     if len(r) else float("nan"), rms[0] * pix_um, rms[1] * pix_um, mx[0], mx[1]])
        if len(r) and len(figs) < max_plots:
            figs.append(Figure(f"image-residuals-{k}", f"{cam.name}: mean image residual per cell "
                               f"({len(r)} observations), computed - observed.",
                               plots.image_residual_png(b.obs_pixel[sel], r, getattr(cam, "width", None),
                                                        getattr(cam, "height", None), cam.name), cam.name))
    tab = Table("cameras", "Image residuals per camera", [
        Column("camera"), Column("images"), Column("observations"), Column("RMS col", "px", 3),
        Column("RMS row", "px", 3), Column("RMS 2D", "px", 3), Column("RMS col", "um", 2), Column("RMS row", "um", 2),
        Column("max |col|", "px", 2), Column("max |row|", "px", 2)], rows,
        "Residual = computed - observed image position of the observations in use (rejected ones left out).")
    return Section("cameras", "Cameras", [tab, *figs])


@register_section("images", order=55)
def images_section(result: Any, max_rows: int = 5000) -> Section:
    """Per image: camera, head, observations, residual RMS / max (px) and the station's pose sigmas."""
    b = result.block
    img = result.residuals["image"]
    act = img.weight > 0
    ni = b.n_images
    oi = b.obs_image[act]
    r = img.residual[act]
    n = np.bincount(oi, minlength=ni)
    with np.errstate(invalid="ignore", divide="ignore"):
        rc = np.sqrt(np.bincount(oi, r[:, 0] ** 2, ni) / n)
        rr = np.sqrt(np.bincount(oi, r[:, 1] ** 2, ni) / n)
    mx = np.zeros(ni)
    np.maximum.at(mx, oi, np.hypot(r[:, 0], r[:, 1]))
    mx[n == 0] = np.nan
    ps = result.pose_sigma
    rows = []
    for i in range(min(ni, max_rows)):
        s = b.image_station[i]
        p = ps[s] if ps is not None else np.full(6, np.nan)
        rows.append([str(b.image_name[i]), b.cameras[b.image_camera[i]].name, str(b.head_name[b.image_head[i]]),
                     str(b.station_name[s]), int(n[i]), rc[i], rr[i], mx[i], p[0], p[1], p[2],
                     *(np.degrees(p[3:]) * 3600.0)])
    note = "Pose sigmas are those of the image's station (a rig exposure shares one)."
    if ni > max_rows:
        note += f" First {max_rows} of {ni} images shown; report.json and the adjusted block hold all."
    tab = Table("images", "Per image", [
        Column("image"), Column("camera"), Column("head"), Column("station"), Column("obs"),
        Column("RMS col", "px", 3), Column("RMS row", "px", 3), Column("max |v|", "px", 3),
        Column("sigma X", "m", 4), Column("sigma Y", "m", 4), Column("sigma Z", "m", 4),
        Column("sigma rx", "arcsec", 1), Column("sigma ry", "arcsec", 1), Column("sigma rz", "arcsec", 1)],
        rows, note)
    return Section("images", "Images", [tab])


def _stats_rows(s: NDArray[np.float64]) -> list[list[Any]]:
    s3 = np.sqrt((s**2).sum(1))[:, None]
    a = np.hstack([s, s3])
    return [["mean", *a.mean(0)], ["median", *np.median(a, 0)], ["RMS", *_rms(a)],
            ["95th percentile", *np.percentile(a, 95, axis=0)], ["max", *a.max(0)]]


@register_section("points", order=60)
def points_section(result: Any) -> Section:
    """Statistics of the object points' a-posteriori sigmas (all estimated points, and the control/check ones)."""
    b = result.block
    ps = result.point_sigma
    ax = _frame_axes(str(b.frame))
    cols = [Column("statistic"), Column(f"sigma {ax[0]}", "m", 4), Column(f"sigma {ax[1]}", "m", 4),
            Column(f"sigma {ax[2]}", "m", 4), Column("sigma 3D", "m", 4)]
    if ps is None:
        return Section("points", "Object point precision",
                       [Note("Point sigmas not computed (statistics skipped for the size of the block).", "warning")])
    fin = np.isfinite(ps).all(axis=1)
    blocks: list[Any] = []
    if fin.any():
        blocks.append(Table("points", f"All estimated points (n = {int(fin.sum())} of {b.n_points})", cols,
                            _stats_rows(ps[fin]), "A-posteriori standard deviations (sigma0-scaled); fixed points left "
                            "out."))
    cp = result.initial.control_point
    if len(cp):
        sel = cp[np.isfinite(ps[cp]).all(axis=1)]
        if len(sel):
            blocks.append(Table("points-control", f"Control and check points (n = {len(sel)})", cols,
                                _stats_rows(ps[sel])))
    if not blocks:
        blocks.append(Note("No estimated object points."))
    return Section("points", "Object point precision", blocks)


@register_section("normalised", order=65)
def normalised_section(result: Any) -> Section:
    """Histogram of the normalised residuals (Baarda's w) of every group with the N(0, 1) density, and a table
    per group."""
    groups: dict[str, NDArray[np.float64]] = {}
    for g, r in result.residuals.items():
        if r.normalised is None:
            continue
        sel = (r.weight > 0) & ~r.constant
        w = np.asarray(r.normalised)[sel].reshape(-1)
        if w.size:
            groups[g] = w
    if not groups:
        return Section("normalised", "Normalised residuals",
                       [Note("Normalised residuals not computed (statistics skipped).", "warning")])
    rows = [[g, len(w), float(np.mean(w)), float(np.std(w)), float(np.max(np.abs(w))), int(np.sum(np.abs(w) > 3.0))]
            for g, w in groups.items()]
    allw = np.concatenate(list(groups.values()))
    rows.append(["all", len(allw), float(np.mean(allw)), float(np.std(allw)), float(np.max(np.abs(allw))),
                 int(np.sum(np.abs(allw) > 3.0))])
    tab = Table("normalised", "Normalised residuals per group", [
        Column("group"), Column("n"), Column("mean", decimals=3), Column("std", decimals=3),
        Column("max |w|", decimals=2), Column("|w| > 3")], rows,
        "w = residual / its a-posteriori standard deviation (one per scalar component of the observations in "
        "use); for a correct model and weights w follows N(0, 1).")
    fig = Figure("histogram", "Histogram of the normalised residuals (stacked by group) with the N(0, 1) density.",
                 plots.normalised_histogram_png(allw, groups), "histogram of normalised residuals")
    return Section("normalised", "Normalised residuals", [fig, tab])


@register_section("distances", order=70)
def distances_section(rep: dict[str, Any]) -> Section:
    """Distance observations (scale bars)."""
    d = rep["distances"]
    rows = [[r["point_a"], r["point_b"], r["observed_m"], r["adjusted_m"], r["residual_m"], r["sigma_m"],
             r["normalised"], r["redundancy"], r["used"]] for r in d["rows"]]
    return Section("distances", "Distances (scale bars)", [Table("distances", "Distances", [
        Column("from"), Column("to"), Column("observed", "m", 5), Column("adjusted", "m", 5),
        Column("residual", "m", 5), Column("sigma", "m", 5), Column("w", decimals=2), Column("redundancy", decimals=2),
        Column("used")], rows, f"Residual = adjusted - observed; RMS {d['stats']['rms_m']:.5f} m.")])


@register_section("rejected", order=75)
def rejected_section(result: Any) -> Section:
    """Observations rejected by data snooping."""
    rows = [[r.group, r.label, r.normalised_residual] for r in result.rejected]
    return Section("rejected", f"Rejected observations ({len(rows)})", [Table("rejected", "Data snooping", [
        Column("group"), Column("observation"), Column("normalised residual", decimals=2)], rows)])


@register_section("key-value", order=90)
def extra_section(key: str, title: str, mapping: dict[str, Any], note: str = "") -> Section:
    """A key/value section (nested mappings flattened with dots), for stage-specific summaries."""
    flat = {k: v for k, v in flatten(mapping).items() if not isinstance(v, (list, tuple)) or len(v) <= 8}
    return Section(key, title, [key_value_table(key, title, flat, 4, note)])


# --------------------------------------------------------------------------- the page
def _config_options(config: Any) -> dict[str, Any]:
    if config is None:
        return {}
    if is_dataclass(config):
        return {f"adjustment.{k}": v for k, v in flatten(asdict(config)).items()}
    return {}


def _software() -> str:
    from skyrig import __version__

    return f"skyrig {__version__}"


def report_data_from_adjustment(result: Any, *, title: str = "skyrig adjustment", rep: dict[str, Any] | None = None,
                                gsd_m: float | None = None, limits_m: tuple[float, float, float] | None = None,
                                inputs: Iterable[str | os.PathLike[str]] | Sequence[InputFile] = (),
                                options: dict[str, Any] | None = None, frame: Any = None, map_frame: Any = None,
                                created: str | None = None, max_image_rows: int = 5000,
                                folder: str | os.PathLike[str] | None = None) -> ReportData:
    """The report of one adjustment.

    Parameters
    ----------
    result
        The :class:`~skyrig.adjust.AdjustmentResult`.
    rep
        Its :func:`~skyrig.adjust.report.adjustment_report` tables (computed with ``gsd_m`` / ``limits_m`` when
        not given), so that the page and ``report.json`` show the same numbers.
    inputs
        Input file paths (hashed here) or :class:`InputFile` records.
    options
        The run's options (command-line values...); the adjustment configuration is added.
    frame, map_frame
        The block's world frame and the user's map frame (objects with ``to_ecef`` / ``from_ecef``, e.g.
        :class:`~skyrig.georef.WorldFrame`): the residual maps are drawn in ``map_frame`` when it is a projected
        CRS, else in the block frame.
    created
        Date of the run (ISO 8601); default now (UTC).
    folder
        Where the report and the adjustment's ``ground_control.csv`` are written: the control section then names
        the ``skyrig measure`` command for its points.
    """
    from skyrig.adjust.report import adjustment_report

    if rep is None:
        rep = adjustment_report(result, gsd_m=gsd_m, limits_m=limits_m)
    if frame is None or map_frame is None:
        f0, p0 = _frames_of(rep, result.block)
        frame = frame if frame is not None else f0
        map_frame = map_frame if map_frame is not None else p0
    inputs_rec = [i if isinstance(i, InputFile) else input_files([i])[0] for i in inputs]
    opts = dict(options or {})
    opts.update(_config_options(getattr(result, "config", None)))
    data = ReportData(title=title, software=_software(),
                      created=created or datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
                      inputs=inputs_rec, options=opts, failures=list(getattr(result, "failures", [])),
                      warnings=[w for w in result.warnings if not w.startswith("the adjustment FAILED")])
    data.add(make_section("summary", result, rep))
    data.add(make_section("calibration", result))
    data.add(make_section("control", result, rep, frame, map_frame, folder))
    data.add(make_section("orientation", result, rep, frame, map_frame))
    data.add(make_section("cameras", result, rep))
    data.add(make_section("images", result, max_image_rows))
    data.add(make_section("points", result))
    data.add(make_section("normalised", result))
    if rep.get("distances"):
        data.add(make_section("distances", rep))
    if result.rejected:
        data.add(make_section("rejected", result))
    return data


def absolute_accuracy_statement(u: dict[str, Any], check: dict[str, Any] | None = None) -> str:
    """What a UAV block can claim about its absolute accuracy, in words: its check points' RMS (metres and GSD), or
    without check points the GNSS's, no more."""
    st = (check or {}).get("stats") or {}
    datum = (u.get("datum") or {}).get("kind")
    lead = ""
    if datum == "control" or u.get("control_used"):
        n = len(u.get("control_used") or []) or (u.get("datum") or {}).get("control_points") or ""
        lead = (f"The datum rests on the {n} control points{'' if datum == 'control' else ' and the GNSS'}: the "
                "absolute accuracy of these orientations is that of the targets as declared (their sigmas), no better. ")
    if st.get("n"):
        rms = ", ".join(f"{float(x):.3f}" for x in st["rms_m"])
        gsd = st.get("rms_gsd")
        return lead + (f"Absolute accuracy from {st['n']} check points (not used in the adjustment): RMS x, y, z {rms} m"
                       + (f" ({', '.join(f'{float(x):.2f}' for x in gsd)} GSD)" if gsd else "") + ".")
    if lead:
        return lead + "No check points: measure some to state the absolute accuracy reached."
    if datum == "positions":
        rms = (u.get("datum") or {}).get("positions_similarity_rms_3d_m")
        return ("No control and no check points: the block is placed by a similarity onto the images' EXIF GPS "
                "positions (not observations), so its absolute accuracy is that of those positions"
                + (f" (the similarity leaves {float(rms):.2f} m RMS)" if rms is not None else "") + ", no better.")
    if datum in ("scale-bar", "free"):
        return ("No control and no check points: the block's frame is not an absolute one (datum: "
                f"{datum}); its absolute accuracy is undefined.")
    sig = (u.get("config") or {}).get("gnss_sigma_m")
    fit = u.get("gnss_fit_rms_enu_m")
    s = ("No check points: the absolute accuracy of these orientations and of every product made from them is that "
         "of the GNSS positions")
    if sig is not None:
        s += f" (stated sigma east, north, up {', '.join(f'{float(x):g}' for x in sig)} m"
        if fit:
            s += f"; the adjustment fits them with RMS {', '.join(f'{float(x):.2f}' for x in fit)} m"
        s += ")"
    return s + (", and no better; the reprojection and point sigmas describe the block's internal (relative) "
                "accuracy only. Measure check points to state an absolute accuracy.")


def uav_calibration_section(u: dict[str, Any]) -> Section | None:
    """The self-calibration's determinability (issue 28): per parameter prior, estimate, sigmas, the prior test, the
    correlation with the ground height and with the other intrinsics above 0.7, and the verdict; held parameters and
    parameters left free on request are said in words.  None when nothing was self-calibrated."""
    rows = u.get("calibration") or []
    if not rows:
        return None

    def scale(r: dict[str, Any]) -> tuple[float, str]:
        px = r.get("pixel_size_mm")
        if px and r["name"] == "focal_mm":
            return 1.0 / px, "px"
        return (1.0 / px, "px from the image centre, y up") if px and r["name"] in ("ppx_mm", "ppy_mm") else (1.0, "")

    table = []
    for r in rows:
        k, unit = scale(r)
        corr = ", ".join(f"{n} {c:+.2f}" for n, c in r.get("correlations", {}).items()) or "-"
        verdict = r["verdict"] + ("; HELD at the prior" if r["held"] else "") + (
            "; left free on request" if r.get("freed_on_request") else "")
        table.append([r["name"] + (f" ({unit})" if unit else ""), r["prior"] * k, r["prior_sigma"] * k,
                      r["estimate"] * k, r["sigma"] * k, r["ratio"], r["z_prior"], r["corr_ground_height"], corr,
                      verdict])
    blocks: list[Any] = [Table("calibration-determinability", "Self-calibration: prior, estimate and verdict", [
        Column("parameter"), Column("prior", "", 4, "e"), Column("prior sigma", "", 3, "e"),
        Column("estimate (refused when held)", "", 4, "e"), Column("sigma", "", 3, "e"),
        Column("formal sigma / prior sigma", "", 2), Column("prior test z", "", 1),
        Column("corr. with ground height", "", 2), Column("correlations > 0.7"), Column("verdict")], table,
        note=str(u.get("calibration_rule", "")))]
    src = u.get("camera_prior_source")
    if src:
        blocks.append(Note(f"Camera prior: {src}."))
    for r in rows:
        if r["held"] or r.get("freed_on_request"):
            blocks.append(Note(r["words"], "warning"))
    sec = Section("calibration-determinability", "Self-calibration: what the block determines", blocks)
    sec.order = 44
    return sec


def report_data_from_uav(result: Any, rep: dict[str, Any], **kw: Any) -> ReportData:
    """The report of ``skyrig adjust-uav`` (:func:`skyrig.pipeline.uav.adjust_uav`'s result and report dict): the
    adjustment report (the camera's self-calibration in the calibration section) plus the UAV block summary and
    the metadata attitude checks."""
    kw.setdefault("title", "skyrig UAV GNSS-supported adjustment")
    data = report_data_from_adjustment(result.adjustment, rep=rep, **kw)
    u = {k: v for k, v in rep.get("uav", {}).items() if k not in ("attitude_check", "config", "calibration")}
    s = extra_section("uav", "UAV block", u, "Summary of the UAV pipeline (orientation of the images from their "
                      "EXIF GPS / gimbal metadata and the tie points).")
    s.order = 45
    s.blocks.insert(0, Note(absolute_accuracy_statement(rep.get("uav", {}), rep.get("check")), "warning"))
    checks = rep.get("uav", {}).get("attitude_check", {})
    if checks:
        s.blocks.append(Table("attitude-check", "Gimbal attitude metadata", [
            Column("image"), Column("metadata"), Column("metadata vs adjusted", "deg", 2)],
            [[k, str(v.get("metadata", "")), v.get("metadata_vs_adjusted_deg", float("nan"))]
             for k, v in checks.items()]))
    data.add(s)
    cal = uav_calibration_section(rep.get("uav", {}))
    if cal is not None:
        data.add(cal)
    if "pycolmap" in rep:
        p = extra_section("pycolmap", "Comparison with pycolmap", rep["pycolmap"])
        p.order = 46
        data.add(p)
    return data
