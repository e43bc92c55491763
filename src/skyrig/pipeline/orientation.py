"""The orientation commands as library functions: block file, bundle adjustment, UAV / no-GNSS orientation.

``skyrig block`` / ``adjust`` / ``adjust-uav`` (:mod:`skyrig.cli`) and the project runner's stages of the same names
(:mod:`skyrig.pipeline.run`) both call :func:`make_block`, :func:`make_adjustment` (or :func:`run_adjustment` +
:func:`write_adjustment`) and :func:`make_uav_orientation` with file paths and plain option values, so a project run
writes the files the commands write, and neither layer holds the other's code.  Nothing here parses a command line
or prints: results are returned (with the lines a user should read as ``summary_lines()``), bad input is a
:class:`skyrig.errors.SkyrigError` naming the option as the caller spells it (``spell("gnss_sigma")`` gives
``--gnss-sigma`` on the command line, ``stages.block.gnss_sigma`` in a project), progress goes through logging and
callbacks.  A failed adjustment is not an exception: the outcome's ``failures`` say why (the caller exits 1).
"""

from __future__ import annotations

import json
import logging
import functools
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.errors import InputFormatError, OptionError
from skyrig.georef.eo import WorldFrame
from skyrig.pipeline.products import cli_spelling

logger = logging.getLogger(__name__)

__all__ = ["BLOCK_GROUPS", "DROP_REASONS", "BlockOutcome", "make_block", "dropped_measurements", "AdjustOutcome",
           "run_adjustment", "write_adjustment", "make_adjustment", "adjustment_inputs", "write_outputs",
           "default_project", "adjust_demo_project", "UavOutcome", "make_uav_orientation", "failure_reasons",
           "needs_no_gnss"]

Spell = Callable[[str], str]
PathArg = str | PathLike[str]

#: System-calibration groups of ``--free`` / ``stages.block.free`` -> the field of :class:`skyrig.adjust.config.Unknowns`.
#: ``make_block``'s default share of the tested observations data snooping may reject per round (when more than
#: ``snooping_per_round``): 0, opt-in.  With 0.001 the midas-dsm growth blocks (60 / 240 images, 8 / 24 rejections)
#: keep their rejections and sigma0 and their rounds no longer grow with the block (bench/run.py --grow
#: --snooping-per-round-share 0.001, issue 35); but the demo's 60-image block (~30 per round) rejected 66 instead of
#: 63, and those few rejections moved one roof corner of the demo's orthomosaic to 4 GSD off: a small block's default
#: stays at ``snooping_per_round``.
SNOOPING_PER_ROUND_SHARE = 0.0

BLOCK_GROUPS = {"boresight": "boresight", "lever-arm": "lever_arm", "datum-shift": "datum_shift",
                "strip-shift": "strip_shift", "intrinsics": "intrinsics", "actuator": "actuator",
                "actuator-curve": "actuator_curve"}

#: Why a measurement is left out of a block, in words (keys of :func:`dropped_measurements`).
DROP_REASONS = {
    "single": "of tie points measured in one image only",
    "exposure": "of points whose images all come from one exposure (no base)",
    "gross": "of points more than 100 px from a measurement or behind a camera with the starting orientations",
    "other": "for another reason",
}


def _sigma3(values: Sequence[float] | float, name: str, spell: Spell, names: str,
            positive: bool = True) -> tuple[float, float, float]:
    """Three standard deviations from one or three numbers, each finite and > 0 (>= 0 unless ``positive``)."""
    try:
        v = [float(x) for x in (values if isinstance(values, (list, tuple, np.ndarray)) else [values])]
    except (TypeError, ValueError):
        v = []
    if len(v) == 1:
        v = v * 3
    if len(v) != 3 or not all(math.isfinite(x) and (x > 0 if positive else x >= 0) for x in v):
        raise OptionError(spell(name), f"expected one or three standard deviations ({names}), finite and "
                                       f"{'> 0' if positive else '>= 0'}, got {values!r}")
    return v[0], v[1], v[2]


# ------------------------------------------------------------------------------------------ block
@dataclass
class BlockOutcome:
    """What :func:`make_block` wrote: the block file ``path``, the block (:class:`skyrig.adjust.Block`), its
    tangential ``frame``, the adjustment section ``config``, the project frame ``crs`` recorded in the file (None:
    the UTM zone of the block), the number of measurements read and those left out by reason."""

    path: Path
    block: Any
    frame: WorldFrame
    config: Any
    crs: WorldFrame | None
    n_measurements: int
    dropped: dict[str, int]
    start_values_only: bool
    datum: str

    def summary_lines(self) -> list[str]:
        """What ``skyrig block`` prints."""
        b = self.block
        first = (f"wrote {self.path}: {b.n_stations} stations, {b.n_images} images, {b.n_points} points, "
                 f"{b.n_observations} image observations, {len(b.control_point)} ground points "
                 f"({int(np.sum(b.control_check))} check), {len(b.gnss_station)} GNSS, "
                 f"{len(b.imu_station)} IMU; frame {self.frame.describe()}; results in "
                 + (self.crs.describe() if self.crs is not None else "the UTM zone of the block (no --crs, no map CRS "
                    "in the inputs)")
                 + ("; GNSS/IMU as starting values only" if self.start_values_only else "") + f"; datum {self.datum}")
        total = sum(self.dropped.values())
        if total:
            second = (f"left out {total} of {self.n_measurements} measurements: "
                      + "; ".join(f"{n} {DROP_REASONS[why]}" for why, n in self.dropped.items() if n))
        else:
            second = f"left out 0 of {self.n_measurements} measurements"
        return [first, second]

    def summary(self) -> dict[str, Any]:
        """Counts for a project run's ``run.json``."""
        b = self.block
        return {"stations": b.n_stations, "images": b.n_images, "points": b.n_points,
                "observations": b.n_observations, "ground_points": len(b.control_point), "gnss": len(b.gnss_station),
                "imu": len(b.imu_station), "left_out": sum(self.dropped.values())}


def check_control_measurements(loaded: Sequence[tuple[str, Any, Any]], eo: Any, cameras: Mapping[str, Any],
                               ctrl: Any) -> None:
    """Image measurements of control / check points against where the start orientations put the points: a
    measurement more than a fifth of the image off that fits within 2 % once column and row are exchanged is
    refused (column and row swapped), naming file and line; one more than half an image off is a warning.

    ``loaded``: ``(path, ImageMeasurements, lines)`` per measurement file; ``eo``: the start orientations (GNSS/IMU
    or the EO file); ``cameras`` by the EO's camera names; ``ctrl``: the control and check points.
    """
    import warnings

    from skyrig.errors import PlausibilityWarning
    from skyrig.georef.ground import world_to_image

    known = {str(n): k for k, n in enumerate(ctrl.name)}
    index = eo.index()
    for path, x, lines in loaded:
        sel = np.flatnonzero([str(p) in known and str(i) in index and str(eo.camera[index[str(i)]]) in cameras
                              for p, i in zip(x.point, x.image)])
        if not len(sel):
            continue
        xyz = ctrl.xyz[[known[str(p)] for p in x.point[sel]]]
        with np.errstate(invalid="ignore"):
            pred = world_to_image(eo, cameras, x.image[sel], xyz, ctrl.frame)
        size = np.array([max(cameras[str(eo.camera[index[str(i)]])].width,
                             cameras[str(eo.camera[index[str(i)]])].height) for i in x.image[sel]], float)
        meas = np.asarray(x.pixel, float)[sel]
        d = np.linalg.norm(meas - pred, axis=1)
        ds = np.linalg.norm(meas[:, ::-1] - pred, axis=1)
        swapped = np.flatnonzero((d > 0.2 * size) & (ds < 0.02 * size))
        if len(swapped):
            j = int(swapped[0])
            k = int(sel[j])
            more = f" ({len(swapped)} such measurements)" if len(swapped) > 1 else ""
            raise InputFormatError(
                f"point {str(x.point[k])!r} in image {str(x.image[k])!r} is measured at ({meas[j, 0]:.1f}, "
                f"{meas[j, 1]:.1f}), {d[j]:.0f} px from where the orientation puts it ({pred[j, 0]:.1f}, "
                f"{pred[j, 1]:.1f}) and {ds[j]:.0f} px with column and row exchanged: column and row swapped?{more}",
                path, int(lines[k]), "column")
        far = np.flatnonzero(d > 0.5 * size)
        if len(far):
            j = int(far[0])
            k = int(sel[j])
            warnings.warn(f"{path}, line {int(lines[k])}: point {str(x.point[k])!r} in image {str(x.image[k])!r} is "
                          f"measured {d[j]:.0f} px from where the start orientation puts it (more than half the image; "
                          f"{len(far)} such measurement(s)); the wrong point, image or orientation?",
                          PlausibilityWarning, stacklevel=2)


def make_block(output: PathArg, measurements: Sequence[PathArg], *, trajectory: PathArg | None = None,
               reference: str | None = None, events: PathArg | None = None, rig: PathArg | None = None,
               eo: PathArg | None = None, eo_format: str | None = None, eo_crs: str | None = None,
               eo_geoid: str | None = None, eo_map_z_ground: float | None = None, start_values_only: bool = False,
               cameras: Sequence[PathArg] = (), control: PathArg | None = None, check: PathArg | None = None,
               points_crs: str | None = None, points_heights: str = "ellipsoidal", points_geoid: str | None = None,
               sigma_px: float = 0.5, gnss_sigma: Sequence[float] = (0.05, 0.05, 0.08),
               imu_sigma_deg: Sequence[float] = (0.005, 0.005, 0.01), control_sigma: Sequence[float] = (0.02,) * 3,
               free: Sequence[str] = (), fourier_order: int | None = None, datum: str = "auto",
               datum_points: Sequence[str] | None = None, crs: str | None = None, geoid: str | None = None,
               snooping_per_round: int = 10, snooping_per_round_share: float = SNOOPING_PER_ROUND_SHARE,
               spell: Spell = cli_spelling) -> BlockOutcome:
    """Assemble a block file (docs/formats/block.md) and write it (atomically) to ``output``.

    Rig mode (``trajectory`` + ``events`` + ``rig``): one station per platform exposure
    (:func:`skyrig.adjust.rig_block.block_from_trajectory`); image mode (``eo`` + ``cameras``): one station per
    image (:func:`skyrig.adjust.frames.block_from_georef`).  ``measurements``: image measurement files (skyrig
    CSV, IGN .mes, ODM gcp_list.txt); ``control`` / ``check``: ground points in the CRS their file states, else
    ``points_crs`` (default the EO's CRS).  Sigmas: ``sigma_px`` (px), ``gnss_sigma`` E, N, U (m),
    ``imu_sigma_deg`` roll, pitch, yaw (deg), ``control_sigma`` X, Y, Z (m); one value stands for all three.
    ``free``: system-calibration groups (:data:`BLOCK_GROUPS`); ``datum``: auto / free / free-points / none;
    ``crs`` / ``geoid``: the project CRS recorded in the file (default the control points' map CRS, else the EO's).
    ``snooping_per_round``: image observations data snooping may reject per round (``AdjustConfig.reliability.per_round``; 1 = Baarda's
    one at a time), or ``snooping_per_round_share`` of the tested observations when that is more
    (``reliability.per_round_share``: the rounds do not grow with the block; 0 = ``snooping_per_round`` alone).

    Raises
    ------
    OptionError, InputFormatError
        Bad option values or files (named as ``spell`` spells them).
    """
    from skyrig.adjust import AdjustConfig
    from skyrig.adjust.config import ReliabilityOptions, Unknowns
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io.block_file import write_block
    from skyrig.pipeline.inputs import (load_cameras, load_eo, load_measurements_lines, load_points, load_trajectory,
                                        project_frame_of)

    rig_mode = any(x is not None for x in (trajectory, events, rig))
    if rig_mode and not all(x is not None for x in (trajectory, events, rig)):
        raise OptionError(spell("trajectory"), f"rig mode needs {spell('trajectory')}, {spell('events')} and "
                                               f"{spell('rig')} together")
    if rig_mode == (eo is not None):
        raise OptionError(spell("eo"), f"give either {spell('trajectory')}/{spell('events')}/{spell('rig')} or "
                                       f"{spell('eo')}/{spell('camera')}")
    if rig_mode and any(x is not None for x in (eo_format, eo_crs, eo_geoid, eo_map_z_ground)):
        raise OptionError(spell("eo_format"), f"{spell('eo_format')}/{spell('eo_crs')}/{spell('eo_geoid')}/"
                                              f"{spell('eo_map_z_ground')} go with {spell('eo')} (image mode)")
    if not rig_mode and reference is not None:
        raise OptionError(spell("reference"), f"goes with {spell('trajectory')} (rig mode)")
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        raise OptionError(spell("sigma_px"), f"must be positive, not {sigma_px}")
    gs = _sigma3(gnss_sigma, "gnss_sigma", spell, "east,north,up")
    imu = tuple(np.radians(_sigma3(imu_sigma_deg, "imu_sigma_deg", spell, "roll,pitch,yaw")))
    cs = _sigma3(control_sigma, "control_sigma", spell, "X,Y,Z")
    project = project_frame_of(crs, geoid, spell("crs"), spell("geoid"))
    groups = [str(g).strip() for g in free if str(g).strip()]
    unknown = [g for g in groups if g not in BLOCK_GROUPS]
    if unknown:
        raise OptionError(spell("free"), f"unknown group {unknown[0]!r}; known: {', '.join(BLOCK_GROUPS)}")
    if fourier_order is not None and "actuator-curve" not in groups:
        raise OptionError(spell("fourier_order"), f"goes with {spell('free')} actuator-curve")
    if not 1 <= int(snooping_per_round) <= 1000:
        raise OptionError(spell("snooping_per_round"), f"must be a whole number from 1 to 1000, got {snooping_per_round}")
    if not 0.0 <= float(snooping_per_round_share) <= 1.0:
        raise OptionError(spell("snooping_per_round_share"), f"must be a share from 0 to 1, got {snooping_per_round_share}")
    if fourier_order is not None and not 1 <= fourier_order <= 12:
        raise OptionError(spell("fourier_order"), "must be a whole number from 1 to 12")
    if datum not in ("auto", "free", "free-points", "none"):
        raise OptionError(spell("datum"), f"unknown datum {datum!r} (auto, free, free-points, none)")
    if datum_points is not None and datum != "free-points":
        raise OptionError(spell("datum_points"), f"goes with {spell('datum')} free-points")
    if not measurements:
        raise OptionError(spell("measurements"), "no image measurements given")
    loaded = [(str(p), *load_measurements_lines(p)) for p in measurements]
    eo_ = None
    ev = None
    if rig_mode:
        from skyrig.io.events_csv import read_events_csv

        ev = read_events_csv(events)  # type: ignore[arg-type]
        known, source = set(ev.image_name.tolist()), str(events)
    else:
        eo_ = load_eo(eo, eo_format, eo_crs, eo_geoid, eo_map_z_ground, spell("eo_crs"),  # type: ignore[arg-type]
                      spell("eo_format"))
        known, source = set(eo_.image.tolist()), str(eo)
    for path, x, lines in loaded:
        bad = np.flatnonzero(~np.isin(x.image, list(known)))
        if len(bad):
            k = int(bad[0])
            raise InputFormatError(f"image {str(x.image[k])!r} (point {str(x.point[k])!r}, measurement {k + 1}) is "
                                   f"not in {source}; {len(bad)} measurement(s) name images without an orientation",
                                   path, int(lines[k]), "image")
    ms = [x for _, x, _ in loaded]
    m = ImageMeasurements(np.concatenate([x.point for x in ms]), np.concatenate([x.image for x in ms]),
                          np.vstack([x.pixel for x in ms]))
    default_crs = None
    if eo_ is not None:
        default_crs = eo_crs or (eo_.frame.crs if eo_.frame.kind == "map" else None)
    pts = [load_points(p, points_crs, points_heights, points_geoid, default_crs=default_crs,
                       option=spell("points_crs")) for p in (control, check) if p is not None]
    checks: tuple[str, ...] = ()
    ctrl = None
    if pts:
        if len(pts) == 2 and pts[0].frame != pts[1].frame:
            pts[1] = GroundPoints(pts[1].name, pts[0].frame.from_ecef(pts[1].frame.to_ecef(pts[1].xyz)), pts[0].frame)
        ctrl = GroundPoints(np.concatenate([p.name for p in pts]), np.vstack([p.xyz for p in pts]), pts[0].frame)
        if check is not None:
            checks = tuple(str(n) for n in pts[-1].name)
    gnss = None if start_values_only else gs
    imu_s = None if start_values_only else imu
    if rig_mode:
        from skyrig.adjust.rig_block import block_from_trajectory
        from skyrig.georef.direct import direct_georeference
        from skyrig.io.rig_file import read_rig

        traj_, rig_ = load_trajectory(trajectory, reference, spell("reference")), read_rig(rig)  # type: ignore[arg-type]
        if ctrl is not None:
            check_control_measurements(loaded, direct_georeference(traj_, rig_, ev, ctrl.frame),  # type: ignore[arg-type]
                                       {h.camera.name: h.camera for h in rig_.heads.values()}, ctrl)
        block, frame = block_from_trajectory(traj_, rig_, ev, m, ctrl, gnss_sigma_m=gnss,  # type: ignore[arg-type]
                                             imu_sigma_rad=imu_s, control_sigma_m=cs, check_points=checks,
                                             sigma_px=sigma_px)
        exposure = {str(n): int(e) for n, e in zip(ev.image_name, ev.exposure_id)}  # type: ignore[union-attr]
    else:
        from skyrig.adjust.frames import block_from_georef

        cams_ = load_cameras(list(cameras), spell("camera"))
        if ctrl is not None:
            check_control_measurements(loaded, eo_, cams_, ctrl)  # type: ignore[arg-type]
        block, frame = block_from_georef(eo_, cams_, m, ctrl,
                                         gnss_sigma_m=gnss, imu_sigma_rad=imu_s, control_sigma_m=cs,
                                         check_points=checks, sigma_px=sigma_px)
        exposure = None
    n_control = int(np.sum(~block.control_check))
    if {"actuator", "actuator-curve"} & set(groups) and not any(a is not None for a in block.head_actuated):
        raise OptionError(spell("free"), "actuator / actuator-curve: the rig has no actuated (tumbling) head")
    if datum == "auto" and not len(block.gnss_station) and n_control == 0:
        raise OptionError(spell("datum"), "the block has no datum: no GNSS observations (start values only) and no "
                                          f"control point measured in its images; give {spell('control')} or "
                                          f"{spell('datum')} free")
    dropped = dropped_measurements(m, block, ctrl, exposure)
    # the GNSS datum shift is free by default when control can separate it from a block translation;
    # free datum-shift frees it in any case (one keyword each: the groups override the default)
    modes: dict[str, Any] = {"datum_shift": "free" if len(block.gnss_station) and len(block.control_point)
                             else "fixed", "datum": "free" if datum == "free-points" else datum}
    modes.update({BLOCK_GROUPS[g]: "free" for g in groups})
    if "actuator-curve" in groups:
        modes["actuator_fourier_order"] = fourier_order or 2
    if datum == "free-points":
        modes["inner_constraints"] = "points"
        if datum_points:
            modes["datum_points"] = tuple(str(p) for p in datum_points)
    cfg = AdjustConfig(unknowns=Unknowns(**modes),
                       reliability=ReliabilityOptions(snooping=True, per_round=int(snooping_per_round),
                                                      per_round_share=float(snooping_per_round_share)))
    out = Path(output)
    out.parent.mkdir(parents=True, exist_ok=True)
    if project is None and ctrl is not None and ctrl.frame.kind == "map":
        project = ctrl.frame
    if project is None and eo_ is not None and eo_.frame.kind == "map":
        project = eo_.frame
    # a rig with actuated (tumbling) heads: the block file names the rig that defines them, relative to itself
    rig_file = os.path.relpath(rig, out.parent) if rig_mode else None  # type: ignore[arg-type]
    write_block(out, block, cfg, rig_file=rig_file, crs=project)
    outcome = BlockOutcome(out, block, frame, cfg, project, len(m), dropped, start_values_only, datum)
    for line in outcome.summary_lines():
        logger.info("%s", line)
    return outcome


def dropped_measurements(m: Any, block: Any, control: Any, exposure: dict[str, int] | None) -> dict[str, int]:
    """How many of the measurements ``m`` the block left out, by reason (keys of :data:`DROP_REASONS`).

    A measurement is left out when its (point, image) pair is not among the block's observations; the reason is
    the first that applies to its point: measured in one image (and not a control point), all its images in one
    rig exposure (``exposure``: image -> exposure id; rig mode), else a gross residual at the start (rig mode
    drops such points)."""
    kept = set(zip(block.image_name[block.obs_image].tolist(), block.point_name[block.obs_point].tolist()))
    pts = m.point.astype(str)
    imgs = m.image.astype(str)
    lost = np.array([(i, p) not in kept for i, p in zip(imgs.tolist(), pts.tolist())], bool)
    out = dict.fromkeys(DROP_REASONS, 0)
    if not lost.any():
        return out
    ctrl = set() if control is None else set(control.name.astype(str).tolist())
    images_of: dict[str, set[str]] = {}
    for p, i in zip(pts.tolist(), imgs.tolist()):
        images_of.setdefault(p, set()).add(i)
    for k in np.flatnonzero(lost):
        p = pts[k]
        seen = images_of[p]
        if len(seen) < 2 and p not in ctrl:
            out["single"] += 1
        elif exposure is not None and len({exposure.get(i) for i in seen}) < 2:
            out["exposure"] += 1
        elif exposure is not None:
            out["gross"] += 1
        else:
            out["other"] += 1
    return out


# ------------------------------------------------------------------------------------------ adjust
def _frame_of_text(desc: str) -> WorldFrame | None:
    """The block's frame from its text (None for a free-text description)."""
    from skyrig.errors import CRSError

    try:
        return WorldFrame.from_text(desc or "")
    except (CRSError, ValueError):
        return None


def default_project(frame: WorldFrame) -> WorldFrame:
    """The project frame when none is given: a map frame as it is, else the UTM zone (WGS84, ellipsoidal heights)
    at the frame's origin (local) or at the ellipsoid point under its origin (ECEF: lat 0, lon 0)."""
    from skyrig.geodesy.statement import utm_frame

    if frame.kind == "map":
        return frame
    if frame.kind == "local":
        return utm_frame(frame.origin[0], frame.origin[1])  # type: ignore[index]
    return utm_frame(0.0, 0.0)


def write_outputs(outdir: PathArg, result: Any, config: Any, title: str, gsd_m: float | None = None,
                  frame: WorldFrame | None = None, to: WorldFrame | None = None, inputs: Any = (),
                  options: dict[str, Any] | None = None, rig_file: PathArg | None = None) -> dict[str, Path]:
    """Adjusted block, then in the project frame ``to`` (default :func:`default_project` of the block's frame)
    the EO, points and ground-control CSVs and GeoPackage (:func:`skyrig.io.adjust_outputs.write_adjusted_tables`,
    when the block's frame is known) and the report; returns the paths.

    ``rig_file``: the rig file defining the block's actuated heads (a block with a tumbling head needs it); the
    adjusted block names it by its path relative to ``outdir``'s parent folder joined with ``outdir``'s name
    (the same from a staging folder next to the published one)."""
    from skyrig.adjust.report import adjustment_report
    from skyrig.camera.frame import FrameCamera
    from skyrig.io.adjust_outputs import write_adjusted_tables
    from skyrig.io.block_file import write_block
    from skyrig.report import write_adjustment_report

    d = Path(outdir)
    d.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    b = result.block
    frame = frame or _frame_of_text(b.frame.text)
    project = None if frame is None else (to or default_project(frame))
    if all(isinstance(c, FrameCamera) for c in b.cameras):
        rel = None if rig_file is None else os.path.relpath(Path(rig_file).resolve(), d.resolve())
        write_block(d / "adjusted.json", b, config, rig_file=rel, crs=project)
        out["block"] = d / "adjusted.json"
    if frame is not None and project is not None:
        out.update(write_adjusted_tables(d, result, frame, project))
    rep = adjustment_report(result, gsd_m=gsd_m, frames=None if project is None else (frame, project))
    out.update(write_adjustment_report(d, result, rep, title, frame=frame, map_frame=project, inputs=inputs,
                                       options=options or {}))
    return out


def _rig_of(block_path: PathArg) -> str | None:
    """The rig file a block file names (key ``rig``: blocks with actuated heads), as a path."""
    try:
        rig = json.loads(Path(block_path).read_text(encoding="utf-8-sig")).get("rig")
    except (OSError, ValueError, AttributeError):
        return None
    return None if not rig else str(Path(block_path).parent / str(rig))


def adjustment_inputs(block_path: PathArg) -> list[Path]:
    """The files an adjustment of ``block_path`` reads: the block file, its tables and the rig it names."""
    from skyrig.report import block_file_inputs

    rig = _rig_of(block_path)
    return list(block_file_inputs(str(block_path))) + ([Path(rig)] if rig else [])


@dataclass
class AdjustOutcome:
    """An adjustment of a block file (:func:`run_adjustment`).

    ``result``: :class:`skyrig.adjust.AdjustmentResult` (its ``warnings`` start with the failures and the preset
    conflicts, as the report states them); ``notices``: what the user should read before the result (an unknown
    frame, preset conflicts); ``warnings``: the adjustment's own warnings; ``failures``: why the result must not be
    trusted (empty when it can); ``options``: the options as the report and manifest record them; ``paths``: the
    files :func:`write_adjustment` wrote (empty before / when not written)."""

    block_path: Path
    result: Any
    config: Any
    title: str
    frame: WorldFrame | None
    project: WorldFrame | None
    gsd: float | None
    rig_file: str | None
    notices: list[str]
    warnings: list[str]
    options: dict[str, Any]
    paths: dict[str, Path] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return bool(self.result.ok)

    @property
    def failures(self) -> list[str]:
        return [str(f) for f in self.result.failures]

    def summary_line(self) -> str:
        """What ``skyrig adjust`` prints (``paths``: as the caller shows them)."""
        r = self.result
        return (f"sigma0 {r.sigma0:.3f}, {r.info.iterations} iterations ({r.info.message}), {len(r.rejected)} "
                f"rejected; " + (f"wrote {', '.join(str(p) for p in self.paths.values())}" if self.paths
                                 else "no outputs written"))

    def summary(self) -> dict[str, Any]:
        """For a project run's ``run.json``: sigma0, images, points, iterations."""
        r = self.result
        return {"sigma0": float(r.sigma0), "images": int(r.block.n_images), "points": int(r.block.n_points),
                "iterations": int(r.info.iterations)}


def run_adjustment(block_path: PathArg, *, preset: str | None = None, gsd: float | None = None,
                   crs: str | None = None, geoid: str | None = None, keep_failed: bool = False,
                   callback: Callable[[str, int, float], None] | None = None,
                   spell: Spell = cli_spelling) -> AdjustOutcome:
    """Adjust a block file (docs/formats/block.md): bundle adjustment / integrated sensor orientation
    (:func:`skyrig.adjust.adjust`), writing nothing (:func:`write_adjustment` writes the outputs).

    ``preset``: a paper-004 variant (:data:`skyrig.adjust.presets.PRESETS`) merged with the block file's
    ``adjustment`` section; ``gsd`` (m): RMS in GSD units in the report; ``crs`` / ``geoid``: the project CRS of the
    outputs (default the block file's ``crs``, else the UTM zone of the block); ``callback(stage, iteration,
    cost)`` follows the iterations.  ``keep_failed`` is only recorded in the options."""
    from skyrig.adjust import adjust
    from skyrig.adjust.presets import PRESETS, apply_preset, merge_preset
    from skyrig.io.block_file import read_block
    from skyrig.pipeline.inputs import project_frame_of

    if preset is not None and preset not in PRESETS:
        raise OptionError(spell("preset"), f"unknown preset {preset!r}; known: {', '.join(sorted(PRESETS))}")
    if gsd is not None and not (math.isfinite(gsd) and gsd > 0):
        raise OptionError(spell("gsd"), f"must be a positive size in metres, got {gsd}")
    given = project_frame_of(crs, geoid, spell("crs"), spell("geoid"))
    bf = read_block(block_path)
    rig_file = _rig_of(block_path)
    block, cfg = bf.block, bf.config
    project = given if given is not None else bf.crs
    notices: list[str] = []
    if bf.frame is None:
        notices.append(f"{block_path}: the block's frame {block.frame.text!r} is not a frame skyrig knows; EO and points "
                       "are not written (only the adjusted block and the report)")
    title = f"skyrig adjust {Path(block_path).name}"
    conflicts: list[str] = []
    if preset:
        # the preset decides the variant; the groups the block file frees (skyrig block --free) stay free
        cfg, conflicts = merge_preset(preset, cfg, bf.adjustment_keys, bool(len(block.gnss_station)))
        block, _ = apply_preset(block, preset)
        title += f" - {PRESETS[preset].title}"
        notices += conflicts
    for n in notices:
        logger.warning("%s", n)
    res = adjust(block, cfg, callback=callback)
    own = list(res.warnings)
    # the report states the preset conflicts and the failure too
    res.warnings[:0] = [f"the adjustment FAILED: {f}" for f in res.failures] + conflicts
    if not res.ok:
        title += " - FAILED"
    opts = dict(block=str(block_path), preset=preset, gsd=gsd, crs=crs, geoid=geoid, keep_failed=keep_failed)
    return AdjustOutcome(Path(block_path), res, cfg, title, bf.frame, project, gsd, rig_file, notices, own, opts)


def write_adjustment(outcome: AdjustOutcome, outdir: PathArg) -> dict[str, Path]:
    """The outputs of an adjustment into ``outdir`` (:func:`write_outputs`: adjusted block, EO / points / ground
    control CSVs and GeoPackage in the project CRS, report); sets and returns ``outcome.paths``."""
    o = outcome
    inputs = adjustment_inputs(o.block_path)
    o.paths = write_outputs(outdir, o.result, o.config, o.title, o.gsd, o.frame, o.project, inputs=inputs,
                            options=o.options, rig_file=o.rig_file)
    return o.paths


def make_adjustment(block_path: PathArg, outdir: PathArg, *, preset: str | None = None, gsd: float | None = None,
                    crs: str | None = None, geoid: str | None = None, keep_failed: bool = False,
                    callback: Callable[[str, int, float], None] | None = None,
                    spell: Spell = cli_spelling) -> AdjustOutcome:
    """:func:`run_adjustment`, then :func:`write_adjustment` into ``outdir`` when the adjustment can be trusted
    or ``keep_failed``; a failed adjustment is not an exception (``outcome.ok`` / ``failures``)."""
    o = run_adjustment(block_path, preset=preset, gsd=gsd, crs=crs, geoid=geoid, keep_failed=keep_failed,
                       callback=callback, spell=spell)
    if o.ok or keep_failed:
        write_adjustment(o, outdir)
    return o


def adjust_demo_project(paths: Any, outdir: PathArg, preset: str = "ba-eo-control", seed: int = 0,
                        sigma_px: float = 0.5, gnss_sigma_m: float = 0.05, imu_sigma_deg: float = 0.005,
                        start_perturb_m: float = 1.0, start_perturb_deg: float = 0.05) -> dict[str, Path]:
    """Adjust the demo flight after ``skyrig georef`` and ``skyrig world-to-image`` have run.

    Builds a block from the demo's EO (``paths.eo``, entering as GNSS/IMU observations with noise of
    ``gnss_sigma_m`` / ``imu_sigma_deg``), the check points' image positions (``paths.image_points``,
    with Gaussian noise ``sigma_px``) and the check points (every other one is control, the rest
    check), starts from orientations perturbed by ``start_perturb_m`` / ``start_perturb_deg``, adjusts
    it with ``preset`` and writes the outputs of :func:`write_outputs` into ``outdir`` (EO and points
    in the demo's map CRS).  Seeded: the same call gives the same report.
    """
    from dataclasses import replace

    from skyrig.adjust import adjust
    from skyrig.adjust.frames import block_from_georef
    from skyrig.adjust.presets import PRESETS, apply_preset
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_rig

    rng = np.random.default_rng(seed)
    eo = read_eo_csv(paths.eo)
    rig = read_rig(paths.rig)
    cams = {h.camera.name: h.camera for h in rig.heads.values()}
    m = read_measurements_csv(paths.image_points)
    m = ImageMeasurements(m.point, m.image, m.pixel + rng.normal(0, sigma_px, m.pixel.shape))
    gp = read_points_csv(paths.check_points)
    n = len(eo)
    obs = replace(eo, centre=eo.centre + rng.normal(0, gnss_sigma_m, (n, 3)),
                  rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(imu_sigma_deg), (n, 3))))
    start = replace(eo, centre=eo.centre + rng.normal(0, start_perturb_m, (n, 3)),
                    rotation=eo.rotation @ matrix_from_rotvec(rng.normal(0, np.radians(start_perturb_deg), (n, 3))))
    checks = tuple(str(x) for x in gp.name[1::2])
    block, frame = block_from_georef(obs, cams, m, GroundPoints(gp.name, gp.xyz, gp.frame), start_eo=start,
                                     gnss_sigma_m=gnss_sigma_m, imu_sigma_rad=np.radians(imu_sigma_deg),
                                     control_sigma_m=0.02, check_points=checks, sigma_px=sigma_px)
    block, cfg = apply_preset(block, preset)
    res = adjust(block, cfg)
    gsd = float(np.median([c.gsd(np.median(eo.centre[:, 2] - gp.xyz[:, 2].mean())) for c in cams.values()]))
    return write_outputs(outdir, res, cfg, f"skyrig demo - {PRESETS[preset].title}", gsd, frame, eo.frame)


# ------------------------------------------------------------------------------------------ UAV / no GNSS
def failure_reasons(adj: Any) -> list[str]:
    """Why an adjustment result must not be trusted, in words (empty when it can).

    The adjustment's own ``failures`` when it states them; otherwise no convergence, a sigma0 that is not
    finite, or no redundancy.
    """
    stated = getattr(adj, "failures", None)
    if stated is not None:
        return [str(f) for f in stated]
    out = []
    info = adj.info
    if not info.converged:
        out.append(f"did not converge ({info.message}; {info.iterations} iterations)")
    if not math.isfinite(float(adj.sigma0)):
        out.append(f"sigma0 is {float(adj.sigma0)} (not finite)")
    if int(adj.redundancy) <= 0:
        out.append(f"no redundancy ({int(adj.redundancy)} observations more than unknowns)")
    return out


def _images_have_gps(images: PathArg | None) -> bool:
    """Whether ``images`` is a folder of images that carry EXIF GPS positions with altitude: all of them, or all but
    a few (at least 3 and half of them; the GNSS block leaves the others out with a warning,
    :func:`skyrig.pipeline.uav.without_gps_left_out`).  The answer is kept per folder state (the CLI and the stage
    ask the same question), so the EXIF headers are read once."""
    if images is None or not Path(images).is_dir():
        return False
    from skyrig.io.image_read import list_images

    files = list_images(Path(images))
    return bool(files) and _gps_share(tuple((str(f), f.stat().st_mtime_ns) for f in files))


@functools.lru_cache(maxsize=8)
def _gps_share(files: tuple[tuple[str, int], ...]) -> bool:
    from skyrig.io.image_read import read_image_metadata

    n = sum(1 for f, _ in files if (m := read_image_metadata(f)).has_gps and m.alt_m is not None)
    return n >= 3 and 2 * n >= len(files)


def needs_no_gnss(no_gps: bool = False, control: Any = None, check: Any = None, scale_bars: Any = None,
                  camera: Any = None, measurements: Sequence[Any] = (), datum: str = "auto",
                  images: PathArg | None = None) -> bool:
    """Whether a UAV orientation runs without GNSS: asked for, or implied by scale bars, a start camera or a datum
    other than ``auto``; control / check points and extra measurements imply it only when ``images`` do not carry
    EXIF GPS (with GPS they join the GNSS-supported block: :func:`ground_with_gnss`)."""
    if no_gps or scale_bars or camera or datum != "auto":
        return True
    if control or check or list(measurements):
        return not ground_with_gnss(no_gps, control, check, scale_bars, camera, measurements, datum, images)
    return False


def ground_with_gnss(no_gps: bool, control: Any, check: Any, scale_bars: Any, camera: Any,
                     measurements: Sequence[Any], datum: str, images: PathArg | None) -> bool:
    """Whether control / check points (or extra measurements) join the GNSS-supported block: given, with images that
    carry EXIF GPS (:func:`_images_have_gps`), and nothing that asks for the orientation without GNSS."""
    return (not no_gps and bool(control or check or list(measurements)) and not scale_bars and not camera
            and datum == "auto" and _images_have_gps(images))


@dataclass
class UavOutcome:
    """A UAV orientation (:func:`make_uav_orientation`): the :class:`skyrig.orient.UavResult`, the report dict
    (``report.json``), why it must not be trusted (``failures``; empty when it can), and whether it ran without
    GNSS; ``options`` as the manifest records them and ``inputs`` the files read."""

    result: Any
    report: dict[str, Any]
    failures: list[str]
    without_gnss: bool
    options: dict[str, Any]
    inputs: list[Path]

    @property
    def ok(self) -> bool:
        return not self.failures

    def summary_lines(self) -> list[str]:
        """What ``skyrig adjust-uav`` prints about the result."""
        rep = self.report
        s = rep["uav"]
        out: list[str] = []
        if self.without_gnss:
            out.append(f"{s['oriented']}/{s['images']} images oriented (start pair {', '.join(s['seed']['images'])}), "
                       f"{s['tie_points']} tie points, reprojection RMS {s['reprojection_rms_px']:.3f} px, sigma0 "
                       f"{s['sigma0']:.3f}, datum {s['datum']['kind']}")
            if s["not_oriented"]:
                out.append("not oriented: " + ", ".join(s["not_oriented"]))
            d = s["datum"]
            if "positions_similarity_rms_3d_m" in d:
                out.append(f"similarity onto the EXIF GPS: RMS {d['positions_similarity_rms_3d_m']:.2f} m, max "
                           f"{d['positions_similarity_max_m']:.2f} m over {d['images_with_positions']} images")
            if "scale_bar_residuals_m" in s:
                out.append("scale-bar residuals (m): " + ", ".join(f"{v:.4f}" for v in s["scale_bar_residuals_m"]))
            if "control_fit_rms_xyz_m" in s:
                out.append("control fit RMS x, y, z (m): " + ", ".join(f"{v:.4f}" for v in s["control_fit_rms_xyz_m"]))
            out.extend(_shutter_lines(s))
            out.extend(_check_lines(rep))
            out.extend(_pycolmap_lines(rep))
            return out
        out.append(f"{s['oriented']}/{s['images']} images oriented, {s['tie_points']} tie points, "
                   f"reprojection RMS {s['reprojection_rms_px']:.3f} px, sigma0 {s['sigma0']:.3f}, "
                   f"GNSS fit RMS (E, N, U) " + ", ".join(f"{v:.2f}" for v in s["gnss_fit_rms_enu_m"]) + " m")
        if s["not_oriented"]:
            out.append("not oriented: " + ", ".join(s["not_oriented"]))
        bad = {k: v for k, v in s["attitude_check"].items() if str(v.get("metadata", "")).startswith("rejected")}
        for k, v in bad.items():
            dev = v.get("metadata_vs_adjusted_deg", float("nan"))
            out.append(f"{k}: metadata attitude rejected (differs by {dev:.1f} deg from the adjusted one)")
        out.extend(_shutter_lines(s))
        out.extend(_check_lines(rep))
        out.extend(_pycolmap_lines(rep))
        return out

    def summary(self) -> dict[str, Any]:
        """For a project run's ``run.json``."""
        s = self.report["uav"]
        out = {k: s.get(k) for k in ("images", "oriented", "tie_points", "reprojection_rms_px", "sigma0")}
        if self.without_gnss:
            out["datum"] = s["datum"]["kind"]
        return out


def _shutter_lines(s: Mapping[str, Any]) -> list[str]:
    """The rolling shutter in words: modelled or not and why, and the readout time (estimated or held)."""
    rs = s.get("rolling_shutter")
    if not rs:
        return []
    if not rs.get("modelled"):
        return [str(rs.get("why", "rolling shutter not modelled"))]
    ro = rs.get("readout_s", float("nan")) * 1e3
    if rs.get("readout_held"):
        how = f"readout time {ro:.1f} ms held at its prior"
    else:
        how = f"readout time {ro:.1f} +- {rs.get('readout_sigma_s', float('nan')) * 1e3:.1f} ms estimated"
    return [f"{rs['why']}; {how}; velocity priors for {rs.get('velocity_priors', 0)} images"
            + (f" ({rs['note']})" if rs.get("note") else "")]


def _check_lines(rep: Mapping[str, Any]) -> list[str]:
    """The check points' RMS (the absolute accuracy of the block) and the ground points left out, in words."""
    out = []
    st = (rep.get("check") or {}).get("stats") or {}
    if st.get("n"):
        out.append("check points: RMS x, y, z " + ", ".join(f"{v:.4f}" for v in st["rms_m"]) + f" m over {st['n']}"
                   + (" (" + ", ".join(f"{v:.2f}" for v in st["rms_gsd"]) + " GSD)" if st.get("rms_gsd") else ""))
    for nm, why in (rep.get("uav", {}).get("control_left_out") or {}).items():
        out.append(f"ground point {nm}: {why}")
    return out


def _pycolmap_lines(rep: Mapping[str, Any]) -> list[str]:
    """What ``skyrig adjust-uav --compare-pycolmap`` prints about the comparison (report key ``pycolmap``)."""
    p = rep.get("pycolmap")
    if p is None:
        return []
    what = ("incremental mapper on skyrig's tie points" if p.get("input") == "tracks"
            else f"on the images, mapper: {p.get('mapper', '?')}")
    n = rep["uav"].get("images", "?")
    if "centre_differences" not in p:
        return [f"pycolmap ({what}): {p.get('registered', 0)} images registered; no comparison"]
    c = p["centre_differences"]
    err = p.get("reprojection_rms_px")
    err_text = (f"reprojection RMS {err:.3f} px" if err is not None else
                f"mean reprojection error {p.get('mean_reprojection_error_px', float('nan')):.3f} px")
    line = (f"pycolmap ({what}): {p['registered']}/{n} images, {err_text}; skyrig - pycolmap "
            f"centres after a similarity: RMS {c['rms_m']:.4g}, max {c['max_m']:.4g} over {c['common']} images")
    if "normalised_rms" in c:
        line += (f" = RMS {c['normalised_rms']:.2f}, max {c['normalised_max']:.2f} predicted sigma (sigma RMS "
                 f"{c['sigma_rms_m']:.4g})")
    return [line]


def _ties_file(ties: PathArg) -> Path:
    p = Path(ties)
    return p / "tie_points.csv" if p.is_dir() else p


def make_uav_orientation(images: PathArg | None, ties: PathArg, outdir: PathArg, *, no_gps: bool = False,
                         gnss_sigma: Sequence[float] = (2.0, 2.0, 4.0), attitude_sigma: float = 5.0,
                         altitude: str = "egm96", geoid: str | None = None, focal_prior: float | None = None,
                         free_intrinsics: str | Sequence[str] = (),
                         self_calibration: bool = True, config: Mapping[str, Any] | None = None,
                         config_source: str | None = None, crs: str | None = None, compare_pycolmap: bool = False,
                         pycolmap_size: int = 1600, pycolmap_mapper: str = "incremental",
                         pycolmap_input: str | None = None, control: PathArg | None = None, control_sigma: Sequence[float] = (0.01,) * 3,
                         check: PathArg | None = None, scale_bars: PathArg | None = None,
                         measurements: Sequence[PathArg] = (), camera: PathArg | None = None, datum: str = "auto",
                         spell: Spell = cli_spelling, rolling_shutter: str = "auto") -> UavOutcome:
    """Orient a UAV / terrestrial image set into ``outdir``: ``eo.csv``, ``points.csv`` (+ ``adjusted.gpkg`` when
    georeferenced), ``camera.yaml``, ``report.json``, ``report.html`` (the full report of :mod:`skyrig.report`).

    With GNSS (default): :func:`skyrig.pipeline.uav.adjust_uav` on the images' EXIF GPS / DJI gimbal metadata and the
    tie points (``ties``: a ``tie_points.csv`` or the folder of ``skyrig match`` holding one), ``gnss_sigma`` E, N,
    U (m), ``attitude_sigma`` (deg; 0 = attitudes not observed), ``altitude`` (``egm96`` / ``ellipsoidal``),
    ``focal_prior`` (relative sigma of the EXIF focal length), ``self_calibration``.

    Without GNSS (``no_gps``, implied by :func:`needs_no_gnss`): :func:`skyrig.pipeline.uav.orient_without_gnss`,
    a two-view start, resection and bundle adjustment; datum (``datum``: auto, control, scale-bar, gps-similarity,
    free) from ``control`` points (``control_sigma`` X, Y, Z in m; ``check`` points compared), ``scale_bars`` (CSV
    from,to,length_m[,sigma_m]), a similarity onto the EXIF GPS or a free network; ``measurements``: extra image
    measurements (targets, scale-bar ends); ``camera``: the start camera (rig YAML with one head or IGN .txt);
    ``images`` may then be None (names from the tie points).

    ``config``: options of :class:`skyrig.pipeline.uav.UavConfig` / :class:`skyrig.orient.incremental.OrientConfig`
    overriding the above (``config_source`` names their file in errors); ``compare_pycolmap``: pycolmap's
    reconstruction in ``outdir/pycolmap``, compared by camera centres after a similarity (RMS, max, and in units of
    skyrig's predicted sigma: report key ``pycolmap``), from ``pycolmap_input`` "images" (its own SIFT, matching and
    mapper on the image files) or "tracks" (its mapper on skyrig's tie points: the same measurements,
    :func:`skyrig.orient.reference.compare_on_same_tracks`; for sets without image files); None: "images" when
    ``images`` holds image files, else "tracks".

    Raises
    ------
    OptionError, InputFormatError
        Bad options or input files.
    skyrig.orient.incremental.OrientError
        The set could not be oriented (a failed run, not bad input).
    skyrig.orient.gnss_block.UavAdjustError
        The GNSS block could not be adjusted.
    """
    from skyrig.io.image_read import list_images
    from skyrig.pipeline.uav import UavConfig

    out = Path(outdir)
    tie_file = _ties_file(ties)
    if not tie_file.is_file():
        raise OptionError(spell("match"), f"no tie points at {tie_file}: run `skyrig match` first")
    if altitude not in ("egm96", "ellipsoidal"):
        raise OptionError(spell("altitude"), f"expected egm96 or ellipsoidal, got {altitude!r}")
    if pycolmap_mapper not in ("incremental", "global"):
        raise OptionError(spell("pycolmap_mapper"), f"expected incremental or global, got {pycolmap_mapper!r}")
    pycolmap_input = _pycolmap_input(images, pycolmap_input, compare_pycolmap, spell)
    if focal_prior is not None and not (math.isfinite(focal_prior) and focal_prior > 0):
        raise OptionError(spell("focal_prior"), f"must be a positive relative sigma (e.g. 0.03), got {focal_prior}")
    free = _intrinsic_names(free_intrinsics, spell)
    if crs is not None:
        from skyrig.errors import CRSError
        from skyrig.geodesy.statement import project_frame

        try:
            project_frame(crs)
        except CRSError as e:
            raise OptionError(spell("crs"), str(e)) from None
    with_ground = ground_with_gnss(no_gps, control, check, scale_bars, camera, measurements, datum, images)
    if not with_ground and needs_no_gnss(no_gps, control, check, scale_bars, camera, measurements, datum):
        return _without_gnss(images, tie_file, out, altitude=altitude, geoid=geoid,
                             focal_prior=focal_prior,
                             self_calibration=self_calibration, config=config, config_source=config_source, crs=crs,
                             compare_pycolmap=compare_pycolmap, pycolmap_size=pycolmap_size,
                             pycolmap_mapper=pycolmap_mapper, pycolmap_input=pycolmap_input, control=control,
                             control_sigma=control_sigma,
                             check=check, scale_bars=scale_bars, measurements=measurements, camera=camera,
                             datum=datum, spell=spell, rolling_shutter=rolling_shutter)
    if images is None:
        raise OptionError(spell("images"), "the GNSS-supported adjustment needs the image folder (EXIF GPS)")
    if not (math.isfinite(attitude_sigma) and attitude_sigma >= 0):
        raise OptionError(spell("attitude_sigma"), f"must be >= 0, got {attitude_sigma}")
    gs = _sigma3(gnss_sigma, "gnss_sigma", spell, "east,north,up")
    kw: dict[str, Any] = dict(gnss_sigma_m=gs, attitude_sigma_deg=attitude_sigma or None, altitude=altitude,
                              geoid=geoid, focal_prior_rel=focal_prior, free_anyway=free,
                              rolling_shutter=rolling_shutter)
    if not self_calibration:
        kw["self_calibration"] = ()
    kw.update(config or {})
    cfg = UavConfig.from_dict(kw, str(config_source or "options"))
    from skyrig.pipeline.uav import adjust_uav

    imgs = Path(images)
    inputs = [tie_file, *list_images(imgs)] + ([Path(config_source)] if config_source else []) + [
        Path(p) for p in (control, check, *measurements) if p]
    gkw: dict[str, Any] = {}
    if with_ground:  # GNSS-supported block with ground control / check points measured in the images
        from skyrig.io.points_csv import read_measurements_csv, read_points_csv

        ctrl = read_points_csv(control) if control else None
        gkw = dict(control=ctrl, check=read_points_csv(check, default_frame=ctrl.frame if ctrl else None)
                   if check else None, control_sigma_m=_sigma3(control_sigma, "control_sigma", spell, "x,y,z"),
                   extra_measurements=[read_measurements_csv(p) for p in measurements],
                   sources={"control": str(control) if control else None, "check": str(check) if check else None})
    res, rep = adjust_uav(imgs, tie_file, out, cfg, out / "pycolmap" if compare_pycolmap else None,
                          pycolmap_max_image_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper, crs=crs,
                          pycolmap_input=pycolmap_input, **gkw)
    if (out / "report.html").is_file():  # the pipeline's plain page -> the full report (skyrig.report)
        from skyrig.report import report_data_from_uav, write_report

        write_report(out / "report.html", report_data_from_uav(
            res, rep, inputs=[tie_file, *list_images(imgs)], options=rep["uav"]["config"], folder=out))
    options = {"images": str(imgs), "ties": str(tie_file), "gnss_sigma_m": list(kw["gnss_sigma_m"]),
               "attitude_sigma_deg": attitude_sigma, "altitude": altitude, "geoid": geoid,
               "focal_prior": focal_prior, "free_intrinsics": list(free), "self_calibration": self_calibration,
               "rolling_shutter": rolling_shutter, "compare_pycolmap": compare_pycolmap, "pycolmap_input": pycolmap_input if compare_pycolmap else None,
               "crs": crs, "config": config_source}
    outcome = UavOutcome(res, rep, failure_reasons(res.adjustment), False, options, inputs)
    for line in outcome.summary_lines():
        logger.info("%s", line)
    return outcome


_INTRINSICS = ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "p1", "p2", "k3")


def _intrinsic_names(value: str | Sequence[str], spell: Spell) -> tuple[str, ...]:
    """``free_intrinsics`` as a tuple of known intrinsic names (comma-separated text or a list); unknown names are an
    error naming the option."""
    names = [x.strip() for x in value.split(",")] if isinstance(value, str) else [str(x).strip() for x in value]
    names = [x for x in names if x]
    bad = [x for x in names if x not in _INTRINSICS]
    if bad:
        raise OptionError(spell("free_intrinsics"), f"unknown intrinsic(s) {bad}; known: {', '.join(_INTRINSICS)}")
    return tuple(names)


def _pycolmap_input(images: PathArg | None, choice: str | None, compare: bool, spell: Spell) -> str:
    """What pycolmap's comparison runs on: ``choice`` (``images`` / ``tracks``), None = images when ``images``
    holds image files, else tracks; images asked for where there are none is an error naming the option."""
    from skyrig.io.image_read import list_images

    if choice not in (None, "images", "tracks"):
        raise OptionError(spell("pycolmap_input"), f"expected images or tracks, got {choice!r}")
    have = images is not None and Path(images).is_dir() and bool(list_images(Path(images)))
    if choice == "images" and compare and not have:
        where = "no image folder" if images is None else f"no image files in {images}"
        raise OptionError(spell("pycolmap_input"), f"images: {where}; give the images or use tracks (pycolmap on "
                                                   "skyrig's tie points)")
    return choice or ("images" if have else "tracks")


def _without_gnss(images: PathArg | None, tie_file: Path, out: Path, *, altitude: str, geoid: str | None,
                  focal_prior: float | None, self_calibration: bool, config: Mapping[str, Any] | None,
                  config_source: str | None, crs: str | None, compare_pycolmap: bool, pycolmap_size: int,
                  pycolmap_mapper: str, pycolmap_input: str, control: PathArg | None, control_sigma: Sequence[float],
                  check: PathArg | None, scale_bars: PathArg | None, measurements: Sequence[PathArg],
                  camera: PathArg | None, datum: str, spell: Spell, rolling_shutter: str = "auto") -> UavOutcome:
    from skyrig.io.image_read import list_images
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.orient.incremental import OrientConfig
    from skyrig.pipeline.uav import UavConfig, orient_without_gnss, read_scale_bars

    if datum not in ("auto", "control", "scale-bar", "gps-similarity", "free"):
        raise OptionError(spell("datum"), f"unknown datum {datum!r} (auto, control, scale-bar, gps-similarity, free)")
    kw: dict[str, Any] = {"pixel_sigma_px": 1.0, "focal_prior_rel": focal_prior,
                          "datum": {"gps-similarity": "positions"}.get(datum, datum),
                          "rolling_shutter": rolling_shutter}
    if not self_calibration:
        kw["self_calibration"] = ()
    kw.update(config or {})
    try:
        cfg = OrientConfig.from_dict(kw, str(config_source or "options"))
    except (ValueError, TypeError) as exc:
        raise OptionError(spell("config"), str(exc)) from None
    cam = None
    if camera:
        from skyrig.pipeline.inputs import load_cameras

        cams = load_cameras([camera], spell("camera"))
        if len({id(c) for c in cams.values()}) > 1:
            raise OptionError(spell("camera"), f"{camera} holds several cameras; give a file with one")
        cam = next(iter(cams.values()))
    ctrl = read_points_csv(control) if control else None
    chk = read_points_csv(check, default_frame=ctrl.frame if ctrl else None) if check else None
    bars = read_scale_bars(scale_bars) if scale_bars else None
    extra = [read_measurements_csv(p) for p in measurements]
    cs = _sigma3(control_sigma, "control_sigma", spell, "x,y,z", positive=False)
    imgs = Path(images) if images is not None else None
    have_images = bool(imgs is not None and imgs.is_dir() and list_images(imgs))
    inputs = [tie_file, *(list_images(imgs) if have_images else [])] + [  # type: ignore[arg-type]
        Path(p) for p in (control, check, scale_bars, camera, config_source, *measurements) if p]
    sources = {k: (str(v) if v else None) for k, v in (("control", control), ("check", check),
                                                       ("scale_bars", scale_bars), ("camera", camera))}
    res, rep = orient_without_gnss(
        imgs if have_images else None, tie_file, out, cfg, cam, ctrl, cs, chk, bars, extra,
        use_gps=True, pycolmap_workdir=out / "pycolmap" if compare_pycolmap else None,
        pycolmap_max_image_size=pycolmap_size, pycolmap_mapper=pycolmap_mapper, crs=crs,
        altitude_cfg=UavConfig(altitude=altitude, geoid=geoid), sources=sources,  # type: ignore[arg-type]
        pycolmap_input=pycolmap_input)
    if (out / "report.html").is_file():
        from skyrig.report import report_data_from_uav, write_report

        write_report(out / "report.html", report_data_from_uav(
            res, rep, inputs=inputs, options=rep["uav"]["config"], title="skyrig orientation without GNSS",
            folder=out))
    options = {"images": None if imgs is None else str(imgs), "ties": str(tie_file), "no_gps": True,
               "altitude": altitude, "geoid": geoid, "focal_prior": focal_prior,
               "self_calibration": self_calibration, "compare_pycolmap": compare_pycolmap,
               "pycolmap_size": pycolmap_size, "pycolmap_mapper": pycolmap_mapper,
               "pycolmap_input": pycolmap_input if compare_pycolmap else None, "crs": crs,
               "config": config_source, "control": sources["control"], "control_sigma": list(cs),
               "check": sources["check"], "scale_bars": sources["scale_bars"],
               "measurements": [str(p) for p in measurements], "camera": None if camera is None else str(camera),
               "datum": datum, "rolling_shutter": cfg.rolling_shutter}
    outcome = UavOutcome(res, rep, failure_reasons(res.adjustment), True, options, inputs)
    for line in outcome.summary_lines():
        logger.info("%s", line)
    return outcome

