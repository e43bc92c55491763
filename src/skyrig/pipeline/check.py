"""``skyrig check PROJECT``: open and validate every input of a project without running any stage.

The project file is read as ``skyrig run`` reads it (keys, options, the output CRS and its geoid grid, the stage
order); then every input file is opened with its reader (trajectory, events, rig, EO, cameras, control and check
points, measurements, scale bars, tie points), every image is checked for truncation, and the inputs are checked
against each other (the events' heads in the rig, the EO's cameras among the camera files, measured points among
the control and check points).  Every problem is collected, so that one run names all of them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from skyrig.errors import SkyrigError

__all__ = ["CheckReport", "check_project", "eo_heads_problems"]


@dataclass
class CheckReport:
    """What :func:`check_project` found: ``errors`` and ``warnings`` in words, and the files it read."""

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    read: list[Path] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors


def _attempt(report: CheckReport, fn: Callable[[], Any], path: Path | None = None) -> Any:
    """``fn()`` with its SkyrigError and warnings recorded in ``report``; None when it failed."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            out = fn()
        except SkyrigError as exc:
            report.errors.append(str(exc))
            out = None
        except Exception as exc:  # a reader's bug must not hide the other problems: said in words
            report.errors.append(f"{path or ''}: {type(exc).__name__}: {exc}".lstrip(": "))
            out = None
        else:
            if path is not None:
                report.read.append(path)
    for w in caught:
        text = " ".join(str(w.message).split())
        if text not in report.warnings:
            report.warnings.append(text)
    return out


def check_project(path: str | Path) -> CheckReport:
    """Validate a project and all its inputs (module docstring); never raises for a problem of the inputs."""
    from skyrig.io.image_read import check_image_complete, list_images
    from skyrig.pipeline import inputs as load
    from skyrig.pipeline.project import load_project
    from skyrig.pipeline.run import plan_run

    report = CheckReport()
    proj = _attempt(report, lambda: load_project(path))
    if proj is None:
        return report
    _attempt(report, lambda: plan_run(proj))
    got: dict[str, Any] = {}
    single = {"trajectory": load.load_trajectory, "rig": _read_rig, "events": _read_events,
              "eo": lambda p: load.load_eo(p, crs=proj.crs, geoid=proj.geoid, crs_option="crs"),
              "control": lambda p: load.load_points(p, default_crs=proj.crs),
              "check": lambda p: load.load_points(p, default_crs=proj.crs),
              "scale_bars": _read_scale_bars, "ties": load.load_measurements}
    for key, reader in single.items():
        p = getattr(proj, key)
        if p is not None:
            got[key] = _attempt(report, lambda r=reader, q=p: r(q), p)
    if proj.cameras:
        got["cameras"] = _attempt(report, lambda: load.load_cameras(list(proj.cameras), "inputs.cameras"),
                                  proj.cameras[0])
    got["measurements"] = [_attempt(report, lambda q=q: load.load_measurements(q), q) for q in proj.measurements]
    for folder in proj.images:
        files = _attempt(report, lambda f=folder: list_images(f))
        for f in files or []:
            _attempt(report, lambda f=f: check_image_complete(f), f)
    _cross_checks(report, proj, got)
    return report


def _read_rig(p: Path) -> Any:
    from skyrig.io.rig_file import read_rig

    return read_rig(p)


def _read_events(p: Path) -> Any:
    from skyrig.io.events_csv import read_events_csv

    return read_events_csv(p)


def _read_scale_bars(p: Path) -> Any:
    from skyrig.pipeline.uav import read_scale_bars

    return read_scale_bars(p)


#: An EO camera whose median off-nadir angle differs more than this (deg) from its rig head's mounting is named.
HEAD_TILT_TOLERANCE_DEG = 20.0


def _quiet_rig(path: Path) -> Any:
    """The rig file among the camera files (None for another camera format or one that does not read: said by its
    own reader above)."""
    if path.suffix.lower() not in (".yaml", ".yml"):
        return None
    try:
        return _read_rig(path)
    except (SkyrigError, OSError, ValueError):
        return None


def eo_heads_problems(eo: Any, rig: Any, path: Path | None) -> list[str]:
    """Each EO camera that is a head of ``rig`` (by the head's or its camera's name) whose images look another way
    than the head is mounted: the median angle of their optical axes from straight down differs from the head's
    (in the body frame) by more than :data:`HEAD_TILT_TOLERANCE_DEG` -- angles read in another convention or
    unit (omega-phi-kappa as yaw-pitch-roll), or the images of another head.  Map frames only (z up); heads with
    an actuator are left out."""
    import numpy as np

    if eo.frame.kind != "map":
        return []
    heads = {}
    for h in rig.heads.values():
        if not h.is_actuated:
            heads[h.name] = heads[h.camera.name] = h
    down = np.degrees(np.arccos(np.clip(np.asarray(eo.rotation)[:, 2, 2], -1.0, 1.0)))  # optical axis -z
    out = []
    for cam in sorted(set(map(str, eo.camera))):
        h = heads.get(cam)
        if h is None:
            continue
        b = h.body_from_camera_rotation()
        mount = float(np.degrees(np.arccos(np.clip(-b[2, 2], -1.0, 1.0))))  # body z is down
        sel = np.asarray(eo.camera).astype(str) == cam
        got = float(np.median(down[sel]))
        if abs(got - mount) > HEAD_TILT_TOLERANCE_DEG:
            out.append(f"{path}: the {int(sel.sum())} images of camera {cam!r} look {got:.0f} deg from straight down "
                       f"(median); the rig {rig.name!r} mounts head {h.name!r} {mount:.0f} deg from it: angles in "
                       f"another convention (omega-phi-kappa / yaw-pitch-roll) or unit, or another head's images?")
    return out


def _cross_checks(report: CheckReport, proj: Any, got: dict[str, Any]) -> None:
    """The inputs against each other (only those that were read)."""
    rig, events = got.get("rig"), got.get("events")
    if rig is not None and events is not None:
        missing = sorted(set(map(str, events.head)) - set(rig.heads))
        if missing:
            report.errors.append(f"{proj.events}: head(s) {', '.join(missing)} of the events are not in the rig file "
                                 f"{proj.rig.name} (heads: {', '.join(rig.heads)})")
    eo, cams = got.get("eo"), got.get("cameras")
    if eo is not None and cams is not None:
        from skyrig.pipeline.inputs import require_cameras

        _attempt(report, lambda: require_cameras(eo, cams, "inputs.cameras"))
    if eo is not None:
        rigs = [rig] if rig is not None else [r for r in (_quiet_rig(q) for q in proj.cameras) if r is not None]
        for r in rigs:
            report.errors += eo_heads_problems(eo, r, proj.eo)
    names = set()
    for key in ("control", "check"):
        if getattr(proj, key) is not None and got.get(key) is None:
            return  # a point file that did not read (said above): its names are unknown, not absent
        pts = got.get(key)
        if pts is not None:
            names |= set(map(str, pts.name))
    for q, m in zip(proj.measurements, got.get("measurements") or []):
        if m is None:
            continue
        unknown = sorted(set(map(str, m.point)) - names)
        if unknown:
            report.errors.append(f"{q}: {len(unknown)} measured point(s) are neither control nor check points, e.g. "
                                 f"{unknown[0]!r}")
