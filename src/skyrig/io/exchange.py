"""Other programs' projects by format name: the registry behind ``skyrig convert``'s exchange formats.

Two kinds of files:

* **models** (cameras and oriented images; COLMAP, OpenSfM, Metashape cameras XML):
  :func:`read_model_orientations` gives :class:`~skyrig.georef.eo.ExteriorOrientations` and the cameras,
  :func:`write_model_orientations` writes orientations and cameras in a program's format (no tie points: those
  go through the format modules' block functions).
* **camera files** (one or more interior orientations: Metashape calibration XML, OpenSfM camera JSON, COLMAP
  cameras, IGN camera text, skyrig rig YAML): :func:`read_camera_file`, :func:`write_camera_file`.

World frames: COLMAP files state none (the reader needs the CRS from the caller); OpenSfM's is the topocentric
frame at ``reference_lla`` (or, without it, the caller's CRS); Metashape's is ECEF when the chunk is
georeferenced.  Writers convert the orientations into the frame the program expects: COLMAP the orientations'
own frame, OpenSfM a topocentric frame (at ``reference_lla``, or at the block's centre), Metashape ECEF.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any, Callable

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, OptionError
from skyrig.geodesy.frame import WorldFrame, local_frame_for
from skyrig.georef.eo import ExteriorOrientations
from skyrig.geometry.pose import Pose
from skyrig.io._camera_fit import FIT_TOLERANCE_PX

__all__ = ["MODEL_FORMATS", "CAMERA_FORMATS", "read_model_orientations", "write_model_orientations",
           "read_camera_file", "write_camera_file", "guess_camera_format"]

#: model formats (``--from-format`` / ``--to-format`` of ``skyrig convert``)
MODEL_FORMATS = ("colmap", "colmap-text", "opensfm", "metashape-xml", "metashape-psx", "micmac", "pix4d")
#: camera file formats (``skyrig convert --camera``)
CAMERA_FORMATS = ("metashape-calibration", "micmac-calibration", "opensfm-cameras", "colmap-cameras", "ign-camera",
                  "rig")


def _frame(crs: str | None, geoid: str | None, what: str, option: str, path: Path) -> WorldFrame:
    if not crs:
        raise InputFormatError(f"{what} states no CRS: give {option} (the CRS its coordinates are in)", path)
    if str(crs).strip().lower() in ("ecef", "epsg:4978"):
        return WorldFrame.ecef()
    return WorldFrame.map(crs, geoid)


def _eo(names: Any, cams: list[str], pose: Pose, frame: WorldFrame) -> ExteriorOrientations:
    return ExteriorOrientations(np.asarray(names, dtype=str), np.asarray(cams, dtype=str), pose.translation,
                                pose.rotation, frame)


def read_model_orientations(path: str | PathLike[str], fmt: str, crs: str | None = None, geoid: str | None = None,
                            crs_option: str = "--from-crs") -> tuple[ExteriorOrientations, dict[str, FrameCamera]]:
    """``(orientations, {camera name: camera})`` of a model (``fmt`` in :data:`MODEL_FORMATS`).  ``crs`` /
    ``geoid``: the CRS of a model that states none (named ``crs_option`` when it is needed and missing)."""
    p = Path(path)
    if fmt in ("colmap", "colmap-text"):
        from skyrig.io.colmap_folder import read_colmap

        m = read_colmap(p)
        cams = {c.name: c for c in m.cameras.values()}
        frame = _frame(crs, geoid, "a COLMAP model", crs_option, p)
        return _eo(m.image_name, [m.cameras[int(c)].name for c in m.image_camera_id], m.world_from_camera,
                   frame), cams
    if fmt == "opensfm":
        from skyrig.io.opensfm import read_opensfm

        recs = read_opensfm(p)
        if not recs:
            raise InputFormatError("the file holds no reconstruction", p)
        r = recs[0]
        frame = r.frame if r.frame is not None else _frame(crs, geoid, "an OpenSfM reconstruction without "
                                                           "reference_lla", crs_option, p)
        return _eo(r.image_name, [r.cameras[c].name for c in r.image_camera_id], r.world_from_camera, frame), \
            {c.name: c for c in r.cameras.values()}
    if fmt in ("metashape-xml", "metashape-psx"):
        from skyrig.io.metashape import read_metashape_cameras, read_metashape_project

        ch = read_metashape_cameras(p) if fmt == "metashape-xml" else read_metashape_project(p)
        frame = ch.frame if ch.frame is not None else _frame(crs, geoid, "a Metashape chunk in local coordinates",
                                                             crs_option, p)
        return _eo(ch.image_name, [ch.cameras[c].name for c in ch.image_camera_id], ch.world_from_camera, frame), \
            {c.name: c for c in ch.cameras.values()}
    if fmt == "micmac":
        from skyrig.io.micmac import read_micmac_ori

        o = read_micmac_ori(p)
        frame = _frame(crs, geoid, "a MicMac Ori folder", crs_option, p)
        return _eo(o.image_name, [o.cameras[c].name for c in o.image_camera_id], o.world_from_camera, frame), \
            {c.name: c for c in o.cameras.values()}
    if fmt == "pix4d":
        from skyrig.io.pix4d import read_pix4d_calibrated_cameras, read_pix4d_offset

        suffix = "_calibrated_camera_parameters.txt"
        off_path = p.with_name(p.name[: -len(suffix)] + "_offset.xyz") if p.name.endswith(suffix) else None
        off = read_pix4d_offset(off_path) if off_path is not None and off_path.is_file() else np.zeros(3)
        c = read_pix4d_calibrated_cameras(p, off)
        frame = _frame(crs, geoid, "Pix4D's calibrated camera parameters", crs_option, p)
        return _eo(c.image_name, [c.cameras[k].name for k in c.image_camera_id], c.world_from_camera, frame), \
            {k.name: k for k in c.cameras.values()}
    raise OptionError("--from-format", f"unknown model format {fmt!r}; known: {', '.join(MODEL_FORMATS)}")


def _cameras_of(eo: ExteriorOrientations, cameras: dict[str, FrameCamera]) -> list[str]:
    names = list(dict.fromkeys(str(c) for c in eo.camera))
    missing = [c for c in names if c not in cameras]
    if missing:
        raise OptionError("--camera", f"no camera file defines {', '.join(repr(c) for c in missing)} (known: "
                          f"{', '.join(sorted(cameras)) or 'none'})")
    return names


def write_model_orientations(path: str | PathLike[str], fmt: str, eo: ExteriorOrientations,
                             cameras: dict[str, FrameCamera], fit_cameras: bool = False,
                             fit_tolerance_px: float = FIT_TOLERANCE_PX) -> dict[str, Any]:
    """Write orientations and their cameras as a model (``fmt`` in :data:`MODEL_FORMATS`; COLMAP: ``path`` is a
    folder, binary for ``colmap``, text for ``colmap-text``).  Returns the fit reports of cameras the format
    could not hold exactly (``fit_cameras``)."""
    names = _cameras_of(eo, cameras)
    pose = Pose(eo.rotation, eo.centre, "world", "camera")
    if fmt in ("colmap", "colmap-text"):
        from skyrig.io.colmap import ColmapModel
        from skyrig.io.colmap_folder import write_colmap

        ids = {c: k + 1 for k, c in enumerate(names)}
        m = ColmapModel({ids[c]: cameras[c] for c in names}, np.arange(1, len(eo) + 1), eo.image,
                        np.array([ids[str(c)] for c in eo.camera]), pose, np.zeros(0, np.int64), np.zeros((0, 3)),
                        np.zeros((0, 3), np.uint8), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros((0, 2)))
        write_colmap(path, m, binary=fmt == "colmap", fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
        return {names[k - 1]: r for k, r in m.fit_reports.items()}
    if fmt == "opensfm":
        from skyrig.io.opensfm import OpenSfMReconstruction, write_opensfm

        frame = eo.frame if eo.frame.kind == "local" else local_frame_for(eo.frame.to_ecef(eo.centre))
        e = eo.to_frame(frame)
        r = OpenSfMReconstruction({c: cameras[c] for c in names}, e.image, e.camera,
                                  Pose(e.rotation, e.centre, "world", "camera"), np.zeros(0, dtype=str),
                                  np.zeros((0, 3)), np.zeros((0, 3)), frame)
        write_opensfm(path, r, fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
        return r.fit_reports
    if fmt == "metashape-xml":
        from skyrig.io.metashape import MetashapeChunk, write_metashape_cameras

        e = eo.to_frame(WorldFrame.ecef())
        wkt = None
        if eo.frame.kind == "map":
            from skyrig.geodesy.crs import resolve_crs

            wkt = resolve_crs(eo.frame.crs).to_wkt("WKT1_GDAL")
        ch = MetashapeChunk({c: cameras[c] for c in names}, e.image, e.camera,
                            Pose(e.rotation, e.centre, "world", "camera"), WorldFrame.ecef(), wkt)
        write_metashape_cameras(path, ch, fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
        return ch.fit_reports
    if fmt == "pix4d":
        from skyrig.io.pix4d import Pix4dCameras, write_pix4d_calibrated_cameras

        write_pix4d_calibrated_cameras(path, Pix4dCameras({c: cameras[c] for c in names}, eo.image, eo.camera, pose))
        return {}
    if fmt == "micmac":
        from skyrig.io.micmac import MicmacOrientations, write_micmac_ori

        write_micmac_ori(path, MicmacOrientations({c: cameras[c] for c in names}, eo.image, eo.camera, pose),
                         fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
        return {}
    raise OptionError("--to-format", f"unknown model format {fmt!r}; known: {', '.join(MODEL_FORMATS)}")


# ---------------------------------------------------------------------------------------------- camera files
def guess_camera_format(path: str | PathLike[str]) -> str:
    """The camera file format from the name: ``*.xml`` Metashape, ``*.json`` OpenSfM, ``cameras.txt`` /
    ``cameras.bin`` COLMAP, ``*.yaml`` rig, other ``*.txt`` IGN."""
    n = Path(path).name.lower()
    if n.endswith(".xml"):
        try:
            head = Path(path).read_bytes()[:2000]
        except OSError:
            head = b""
        return "micmac-calibration" if b"<ExportAPERO" in head else "metashape-calibration"
    if n.endswith(".json"):
        return "opensfm-cameras"
    if n in ("cameras.txt", "cameras.bin"):
        return "colmap-cameras"
    if n.endswith((".yaml", ".yml")):
        return "rig"
    return "ign-camera"


def read_camera_file(path: str | PathLike[str], fmt: str | None = None) -> dict[str, FrameCamera]:
    """``{camera name: camera}`` of a camera file (``fmt`` in :data:`CAMERA_FORMATS`, None: from the name)."""
    p = Path(path)
    fmt = fmt or guess_camera_format(p)
    readers: dict[str, Callable[[Path], dict[str, FrameCamera]]] = {
        "metashape-calibration": _read_metashape_cal, "micmac-calibration": _read_micmac_cal,
        "opensfm-cameras": _read_opensfm_cams,
        "colmap-cameras": _read_colmap_cams, "ign-camera": _read_ign_cam, "rig": _read_rig_cams}
    if fmt not in readers:
        raise OptionError("--from-format", f"unknown camera format {fmt!r}; known: {', '.join(CAMERA_FORMATS)}")
    return readers[fmt](p)


def _read_metashape_cal(p: Path) -> dict[str, FrameCamera]:
    from skyrig.io.metashape import read_metashape_calibration

    c = read_metashape_calibration(p)
    return {c.name: c}


def _read_micmac_cal(p: Path) -> dict[str, FrameCamera]:
    from skyrig.io.micmac import read_micmac_calibration

    c = read_micmac_calibration(p)
    return {c.name: c}


def _read_opensfm_cams(p: Path) -> dict[str, FrameCamera]:
    from skyrig.io.opensfm import read_opensfm_cameras

    return read_opensfm_cameras(p)


def _read_colmap_cams(p: Path) -> dict[str, FrameCamera]:
    if p.suffix.lower() == ".bin":
        from skyrig.io.colmap_binary import read_colmap_cameras_binary

        cams = read_colmap_cameras_binary(p)
    else:
        from skyrig.io.colmap_text import read_colmap_cameras

        cams = read_colmap_cameras(p)
    return {c.name: c for c in cams.values()}


def _read_ign_cam(p: Path) -> dict[str, FrameCamera]:
    from skyrig.io.ign import read_ign_camera

    c = read_ign_camera(p)
    return {c.name: c}


def _read_rig_cams(p: Path) -> dict[str, FrameCamera]:
    from skyrig.io.rig_file import read_rig

    return {name: h.camera for name, h in read_rig(p).heads.items()}


def write_camera_file(path: str | PathLike[str], fmt: str, cameras: dict[str, FrameCamera],
                      fit_cameras: bool = False) -> dict[str, Any]:
    """Write cameras in a camera file format (Metashape calibration: exactly one camera; COLMAP: ``cameras.txt``
    or ``cameras.bin`` by the name).  Returns fit reports (``fit_cameras``)."""
    p = Path(path)
    if fmt == "metashape-calibration":
        from skyrig.io.metashape import write_metashape_calibration

        if len(cameras) != 1:
            raise OptionError("--camera-name", f"a Metashape calibration file holds one camera; there are "
                              f"{len(cameras)} ({', '.join(cameras)}): choose one")
        (name, cam), = cameras.items()
        rep = write_metashape_calibration(p, cam, fit_cameras=fit_cameras)
        return {name: rep} if rep is not None else {}
    if fmt == "micmac-calibration":
        from skyrig.io.micmac import write_micmac_calibration

        if len(cameras) != 1:
            raise OptionError("--camera-name", f"a MicMac calibration file holds one camera; there are "
                              f"{len(cameras)} ({', '.join(cameras)}): choose one")
        write_micmac_calibration(p, next(iter(cameras.values())), fit_cameras=fit_cameras)
        return {}
    if fmt == "opensfm-cameras":
        from skyrig.io.opensfm import write_opensfm_cameras

        return write_opensfm_cameras(p, cameras, fit_cameras=fit_cameras)
    if fmt == "colmap-cameras":
        from skyrig.io.colmap import camera_records

        reports: dict[Any, Any] = {}
        by_id = {k: c for k, c in enumerate(cameras.values(), start=1)}
        recs = camera_records(by_id, fit_cameras, reports=reports)
        if p.suffix.lower() == ".bin":
            from skyrig.io.colmap_binary import write_camera_records_binary

            write_camera_records_binary(p, recs)
        else:
            from skyrig.io.colmap_text import write_camera_records_text

            write_camera_records_text(p, recs)
        names = list(cameras)
        return {names[k - 1]: r for k, r in reports.items()}
    if fmt == "rig":
        from skyrig.io.rig_file import write_rig
        from skyrig.rig.rig import Head, Rig

        write_rig(Rig("cameras", [Head(n, c) for n, c in cameras.items()],
                      description="cameras written by skyrig convert --camera"), p)
        return {}
    raise OptionError("--to-format", f"cannot write camera format {fmt!r}; writable: metashape-calibration, "
                      "micmac-calibration, opensfm-cameras, colmap-cameras, rig")
