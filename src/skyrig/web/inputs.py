"""What a measuring session reads: orientations, cameras, image folders, control and check points, and the
measurements file, from a project (``project.yaml`` or a flight folder) or given one by one.

The orientations of a project are the latest a stage has published: ``OUTPUT/adjust-uav/eo.csv``, then
``OUTPUT/adjust/eo.csv`` (adjusted), then ``OUTPUT/georef/eo.csv`` (direct georeferencing), then the project's own
EO file, else direct georeferencing of its trajectory, events and rig computed here (nothing is written).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations
from skyrig.georef.observations import GroundPoints

__all__ = ["MeasureInputs", "project_inputs", "image_files", "merge_points", "point_targets"]

_STAGE_EO = (("adjust-uav", "adjusted (adjust-uav stage)"), ("adjust", "adjusted (adjust stage)"),
             ("georef", "direct georeferencing (georef stage)"))


@dataclass
class MeasureInputs:
    """The files of a session (absolute paths) and, for a project without an EO file, the orientations."""

    eo_path: Path | None = None
    eo: ExteriorOrientations | None = None
    eo_words: str = ""  # where the orientations come from, in words
    cameras: list[Path] = field(default_factory=list)
    images: list[Path] = field(default_factory=list)
    control: Path | None = None
    check: Path | None = None
    output: Path | None = None
    crs: str | None = None
    geoid: str | None = None
    adjusted_control: Path | None = None  # ground_control.csv of the adjustment whose orientations are used


def project_inputs(path: str | Path) -> MeasureInputs:
    """The inputs of a project: a ``project.yaml`` (or a folder holding one), or a flight folder as
    ``skyrig init`` reads it (:func:`skyrig.pipeline.project.detect_inputs`)."""
    from skyrig.pipeline.project import detect_inputs, load_project

    p = Path(path).absolute()
    yaml_file = p if p.is_file() else p / "project.yaml"
    if yaml_file.is_file():
        pr = load_project(yaml_file)
        out = MeasureInputs(cameras=list(pr.cameras) or ([pr.rig] if pr.rig else []), images=list(pr.images),
                            control=pr.control, check=pr.check, crs=pr.crs, geoid=pr.geoid)
        out.output = pr.measurements[0] if pr.measurements else pr.root / "gcp" / "image_measurements.csv"
        if _stage_eo(out, pr.output):
            return out
        if pr.eo is not None:
            out.eo_path, out.eo_words = pr.eo, "the project's EO file"
            return out
        traj, events, rig = pr.trajectory, pr.events, pr.rig
    elif p.is_dir():
        d = detect_inputs(p)
        out = MeasureInputs(cameras=[d.rig] if d.rig else [], images=list(d.images), control=d.control, check=d.check,
                            crs=d.crs)
        out.output = d.measurements[0] if d.measurements else p / "gcp" / "image_measurements.csv"
        if _stage_eo(out, p / "output"):
            return out
        if d.eo is not None:
            out.eo_path, out.eo_words = d.eo, "the folder's EO file"
            return out
        traj, events, rig = d.trajectory, d.events, d.rig
    else:
        raise InputFormatError("no project file or folder", p)
    if traj is None or events is None or rig is None or out.crs is None:
        raise InputFormatError("no orientations: no eo.csv of an adjust / georef stage, no EO file, and not all of "
                               "trajectory, events, rig and a CRS to georeference directly", p)
    out.eo = _direct(traj, events, rig, out.crs, out.geoid)
    out.eo_words = f"direct georeferencing of {traj.name}, {events.name} and {rig.name} (computed now)"
    return out


def _stage_eo(out: MeasureInputs, output: Path) -> bool:
    """Take the latest stage's ``eo.csv`` (and its ``ground_control.csv``) under ``output``; False when none."""
    for stage, words in _STAGE_EO:
        if (output / stage / "eo.csv").is_file():
            out.eo_path, out.eo_words = output / stage / "eo.csv", words
            gc = output / stage / "ground_control.csv"
            out.adjusted_control = gc if gc.is_file() else None
            return True
    return False


def adjustment_residuals(path: Path) -> dict[str, dict]:
    """``{point: {"role", "v_m": [vx, vy, vz], "v3d_m", "sigma_m": [sx, sy, sz]}}`` from an adjustment's
    ``ground_control.csv`` (adjusted minus given, metres, along the project CRS's axes)."""
    from skyrig.io.points_csv import read_point_extras

    cols = read_point_extras(path)
    out = {}
    for k, name in enumerate(cols["name"]):
        try:
            v = [float(cols[c][k]) for c in ("vx", "vy", "vz")]
            sig = [float(cols[c][k]) for c in ("sx", "sy", "sz")] if "sx" in cols else [float("nan")] * 3
        except (KeyError, ValueError):
            raise InputFormatError("no residual columns vx, vy, vz (an adjustment's ground_control.csv?)", path,
                                   None, "vx") from None
        out[name] = {"role": cols.get("role", ["control"] * len(cols["name"]))[k], "v_m": v,
                     "v3d_m": float(np.linalg.norm(v)), "sigma_m": sig}
    return out


def _direct(traj: Path, events: Path, rig: Path, crs: str, geoid: str | None) -> ExteriorOrientations:
    from skyrig.georef.direct import direct_georeference
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig

    if traj.suffix.lower() in (".out", ".sbet", ".bin"):
        from skyrig.io.sbet import read_sbet

        tr = read_sbet(traj)
    else:
        from skyrig.io.trajectory_csv import read_trajectory_csv

        tr = read_trajectory_csv(traj)
    return direct_georeference(tr, read_rig(rig), read_events_csv(events), WorldFrame.map(crs, geoid))


def image_files(folders: list[Path], names: np.ndarray) -> dict[str, Path]:
    """``{image name: file}`` for the orientations' image names found in the folders (a name may hold a
    sub-folder); names without a file are left out."""
    from skyrig.io.image_read import IMAGE_SUFFIXES

    out: dict[str, Path] = {}
    for f in folders:
        f = Path(f)
        if not f.is_dir():
            raise InputFormatError("image folder not found", f)
        for q in f.iterdir():
            if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES:
                out.setdefault(q.name, q)
    found = {}
    for n in map(str, names):
        if n in out:
            found[n] = out[n]
        else:
            for f in folders:
                q = Path(f) / n
                if q.is_file():
                    found[n] = q
                    break
    return found


def merge_points(control: GroundPoints | None, check: GroundPoints | None, check_path: str = ""
                 ) -> tuple[GroundPoints, dict[str, str]]:
    """Control and check points in one set (the check points brought into the control points' frame) and their
    roles; a name in both is an error naming the check file."""
    parts = [(g, r) for g, r in ((control, "control"), (check, "check")) if g is not None]
    if not parts:
        raise InputFormatError("no ground points (give --points and/or --check, or a project with control points)")
    frame = parts[0][0].frame
    names, xyz, roles = [], [], {}
    for g, role in parts:
        xy = g.xyz if g.frame == frame else frame.from_ecef(g.frame.to_ecef(g.xyz))
        for n, v in zip(g.name, xy):
            if str(n) in roles:
                raise InputFormatError(f"point {str(n)!r} is both a control and a check point", check_path, None, "name")
            names.append(str(n))
            xyz.append(v)
            roles[str(n)] = role
    return GroundPoints(np.array(names), np.array(xyz).reshape(-1, 3), frame), roles


def point_targets(paths: list[Path | None]) -> dict[str, tuple[int | None, float]]:
    """``{point: (code, target_radius_m)}`` from the ``code`` / ``target_radius_m`` columns of the skyrig points
    CSVs among ``paths`` (:func:`skyrig.io.points_csv.read_point_targets`; IGN and ODM point files have no such
    columns)."""
    from skyrig.io.points_csv import read_point_targets
    from skyrig.match.targets import CODE_BITS

    out: dict[str, tuple[int | None, float]] = {}
    for p in paths:
        if p is None or p.name.lower().endswith((".app", ".mes")) or p.name.lower().startswith("gcp_list"):
            continue
        out.update(read_point_targets(p, CODE_BITS))
    return out
