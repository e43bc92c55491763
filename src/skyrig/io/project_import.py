"""Another program's whole project folder brought in as a skyrig project folder (``skyrig import project``).

Which program wrote the folder is told by its files (the folder itself and its sub-folders, three levels down):

=============  =============================================================================================
COLMAP         ``cameras.{bin,txt}`` with ``images.*`` and ``points3D.*`` beside it (``sparse/0`` usually)
OpenSfM        ``reconstruction.json`` (and ``tracks.csv`` beside it for the measurements)
Metashape      an exported cameras XML (``<document>`` holding a ``<chunk>``), or a project ``NAME.psx`` with
               its ``NAME.files`` folder (the first chunk; :func:`skyrig.io.metashape.read_metashape_project`)
Pix4D          ``1_initial/params/<project>_calibrated_camera_parameters.txt`` (``_offset.xyz`` and the
               ``_wkt.prj`` beside it give the offset and the CRS)
=============  =============================================================================================

A folder holding more than one of these (or two models of one kind) is refused with the candidates listed; one
holding none is refused with what was looked for.

Written into the output folder (published as a set: a staging folder renamed into place, ``manifest.json``
last, :func:`skyrig.io.stage.stage_folder`):

* ``eo.csv`` with its side-car: the orientations in the program's frame (or the CRS given for a format that
  states none: COLMAP, a Pix4D folder without its ``_wkt.prj``);
* ``cameras.yaml``: the cameras as a skyrig rig file, one head per camera (the EO's ``camera`` column);
* ``points.csv`` with its side-car and ``tie_points.csv``: the model's 3D points and their image measurements
  (formats that hold them: COLMAP, OpenSfM, Metashape), and ``block.json``: the same as a bundle block for
  ``skyrig adjust`` (as ``skyrig import FORMAT``);
* ``import.json``: the source folder, the format found, the files read and what was written.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.errors import InputFormatError

__all__ = ["ProjectSource", "detect_project", "import_project", "PROJECT_FORMATS"]

PROJECT_FORMATS = ("colmap", "opensfm", "metashape-xml", "metashape-psx", "pix4d")
_DEPTH = 3


@dataclass(frozen=True)
class ProjectSource:
    """What :func:`detect_project` found: the format, the model file or folder, extra files."""

    fmt: str
    model: Path
    tracks: Path | None = None
    crs_file: Path | None = None


def _walk(root: Path) -> list[Path]:
    out = []
    stack = [(root, 0)]
    while stack:
        d, depth = stack.pop()
        try:
            entries = sorted(d.iterdir())
        except OSError:
            continue
        for e in entries:
            if e.is_dir() and not e.name.startswith(".") and depth < _DEPTH:
                stack.append((e, depth + 1))
            elif e.is_file():
                out.append(e)
    return out


def _is_metashape(p: Path) -> bool:
    try:
        head = p.read_bytes()[:4096].decode("utf-8", "replace")
    except OSError:
        return False
    return "<document" in head and "<chunk" in head


def detect_project(folder: str | PathLike[str]) -> ProjectSource:
    """The program whose project ``folder`` is (module docstring).

    Raises
    ------
    InputFormatError
        Naming the folder: nothing recognised (with what was looked for), or several candidates (listed).
    """
    root = Path(folder)
    if not root.is_dir():
        raise InputFormatError("not a folder (give the other program's project folder)", root)
    files = _walk(root)
    found: list[ProjectSource] = []
    colmap_dirs = sorted({f.parent for f in files if f.name in ("cameras.bin", "cameras.txt")})
    for d in colmap_dirs:
        names = {f.name for f in files if f.parent == d}
        if names & {"images.bin", "images.txt"} and names & {"points3D.bin", "points3D.txt"}:
            found.append(ProjectSource("colmap", d))
    for f in files:
        if f.name == "reconstruction.json":
            tr = f.parent / "tracks.csv"
            found.append(ProjectSource("opensfm", f, tr if tr.is_file() else None))
        elif f.suffix.lower() == ".xml" and _is_metashape(f):
            found.append(ProjectSource("metashape-xml", f))
        elif f.suffix.lower() == ".psx":
            found.append(ProjectSource("metashape-psx", f))
        elif f.name.endswith("_calibrated_camera_parameters.txt") and "_pix4d_" not in f.name:
            prj = f.with_name(f.name[: -len("_calibrated_camera_parameters.txt")] + "_wkt.prj")
            found.append(ProjectSource("pix4d", f, None, prj if prj.is_file() else None))
    if not found:
        raise InputFormatError("no project of another program found (looked for COLMAP cameras/images/points3D, "
                               "OpenSfM reconstruction.json, a Metashape cameras XML or .psx project, Pix4D "
                               f"*_calibrated_camera_parameters.txt, {_DEPTH} folders down)", root)
    if len(found) > 1:
        listed = "; ".join(f"{s.fmt}: {s.model.relative_to(root)}" for s in found)
        raise InputFormatError(f"{len(found)} projects found ({listed}): give the folder of the one to import",
                               root)
    return found[0]


def _block(src: ProjectSource, sigma_px: float) -> Any:
    if src.fmt == "colmap":
        from skyrig.io.colmap import block_from_colmap
        from skyrig.io.colmap_folder import read_colmap

        return block_from_colmap(read_colmap(src.model), sigma_px=sigma_px)
    if src.fmt == "opensfm":
        if src.tracks is None:
            return None
        from skyrig.io.opensfm import block_from_opensfm, read_opensfm, read_opensfm_tracks

        return block_from_opensfm(read_opensfm_tracks(src.tracks, read_opensfm(src.model)[0]), sigma_px=sigma_px)
    if src.fmt in ("metashape-xml", "metashape-psx"):
        from skyrig.io.metashape import block_from_metashape, read_metashape_cameras, read_metashape_project

        read = read_metashape_cameras if src.fmt == "metashape-xml" else read_metashape_project
        return block_from_metashape(read(src.model), sigma_px=sigma_px)
    return None  # Pix4D's params files hold no tie points


def import_project(folder: str | PathLike[str], outdir: str | PathLike[str], crs: str | None = None,
                   geoid: str | None = None, sigma_px: float = 1.0) -> dict[str, Any]:
    """Import the project in ``folder`` (:func:`detect_project`) into the skyrig project folder ``outdir``
    (module docstring); returns what ``import.json`` says.  ``crs`` / ``geoid``: the frame of a format that
    states none (named ``--crs`` when missing)."""
    from skyrig.georef.observations import GroundPoints, ImageMeasurements
    from skyrig.io.block_file import write_block
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.exchange import read_model_orientations, write_camera_file
    from skyrig.io.points_csv import write_measurements_csv, write_points_csv
    from skyrig.io.stage import describe_inputs, stage_folder

    src = detect_project(folder)
    if crs is None and src.crs_file is not None:
        crs = src.crs_file.read_text(encoding="utf-8-sig").strip()
    eo, cameras = read_model_orientations(src.model, src.fmt, crs, geoid, crs_option="--crs")
    block = _block(src, sigma_px)
    inputs = [p for p in (src.model, src.tracks, src.crs_file) if p is not None]
    summary: dict[str, Any] = {"format": "skyrig-import", "version": 1, "source": str(Path(folder).resolve()),
                               "program": src.fmt, "model": str(src.model), "frame": eo.frame.describe(),
                               "images": len(eo), "cameras": sorted(cameras), "written": []}
    with stage_folder(outdir, stage="import", inputs=describe_inputs(inputs),
                      options={"crs": crs, "geoid": geoid, "sigma_px": sigma_px}) as tmp:
        write_eo_csv(eo, tmp / "eo.csv")
        write_camera_file(tmp / "cameras.yaml", "rig", cameras)
        summary["written"] += ["eo.csv", "cameras.yaml"]
        if block is not None:
            same = block.station_centre.shape == (len(eo), 3) and np.allclose(
                block.station_centre, eo.centre[[list(eo.image).index(n) for n in block.station_name]], atol=1e-6)
            if same and len(block.point_name):  # the points in the orientations' frame: written with it
                write_points_csv(tmp / "points.csv", GroundPoints(block.point_name, block.point_xyz, eo.frame))
                m = ImageMeasurements(block.point_name[block.obs_point], block.image_name[block.obs_image],
                                      block.obs_pixel)
                write_measurements_csv(tmp / "tie_points.csv", m)
                summary["written"] += ["points.csv", "tie_points.csv"]
                summary["points"], summary["measurements"] = int(len(block.point_name)), int(len(block.obs_point))
            elif len(block.point_name):
                summary["note"] = (f"the model's points are in {block.frame}, not in the orientations' frame: "
                                   "they are in block.json only")
            write_block(tmp / "block.json", block)
            summary["written"].append("block.json")
        summary["written"].append("import.json")
        (tmp / "import.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary
