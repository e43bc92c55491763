"""What the library-level commands (:mod:`skyrig.pipeline`) read from the user's files and options, without a
command-line layer: cameras from camera / rig files, the images of some rig heads, EO files, ground points, image
measurements and trajectories in any format skyrig reads, and the project frame of ``--crs`` / ``--geoid``.

The CLI (:mod:`skyrig.cli`) and the project runner (:mod:`skyrig.pipeline.run`) both call these, so that a
``skyrig dsm`` and a project's ``dsm`` stage read their inputs the same way.  Errors are
:class:`skyrig.errors.SkyrigError` (bad input, exit status 2) naming the option as the caller spells it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from os import PathLike

import numpy as np

from pathlib import Path
from typing import Any, Callable

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, OptionError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements

__all__ = ["load_cameras", "head_rows", "select_heads", "project_frame_of", "load_eo", "load_points",
           "load_measurements", "load_measurements_lines", "load_trajectory", "EO_FORMATS"]


def load_cameras(paths: Sequence[str | PathLike[str]], option: str = "--camera") -> dict[str, FrameCamera]:
    """Cameras by name from IGN camera ``.txt`` files and/or skyrig rig files (YAML; every head is known by its
    head name and by its camera's name)."""
    out: dict[str, FrameCamera] = {}
    for p in map(str, paths):
        if p.lower().endswith((".yaml", ".yml")):
            from skyrig.io.rig_file import read_rig

            rig = read_rig(p)
            for name, head in rig.heads.items():
                out[name] = head.camera
                out[head.camera.name] = head.camera
        else:
            from skyrig.io.ign import read_ign_camera

            cam = read_ign_camera(p)
            out[cam.name] = cam
    if not out:
        raise OptionError(option, "no camera given")
    return out


def require_cameras(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera] | None,
                    option: str = "camera") -> None:
    """Refuse orientations whose camera names ``cameras`` lacks (a rig head missing for an EO camera), naming the
    first image, the cameras missing and those given, before any camera is looked up."""
    have = cameras or {}
    missing = [i for i, c in enumerate(eo.camera) if str(c) not in have]
    if missing:
        names = sorted({str(eo.camera[i]) for i in missing})
        raise OptionError(option, f"image {str(eo.image[missing[0]])!r}: no camera {', '.join(map(repr, names))} "
                                  f"among those given ({', '.join(sorted(have)) or 'none'}; {len(missing)} image(s) "
                                  "without a camera)")


def head_rows(eo: ExteriorOrientations, spec: str | Sequence[str]) -> tuple[list[str], list[np.ndarray]]:
    """For rig heads / image-name parts (a comma list or a sequence): the names and, per name, the rows of ``eo``
    that match (the image's head is the name, or its file name contains it)."""
    parts = spec.split(",") if isinstance(spec, str) else list(spec)
    want = [h.strip() for h in parts if h.strip()]
    return want, [np.flatnonzero([(eo.head is not None and str(eo.head[i]) == w) or w in str(n)
                                  for i, n in enumerate(eo.image)]) for w in want]


def select_heads(eo: ExteriorOrientations, spec: str | Sequence[str] | None,
                 option: str = "--heads") -> ExteriorOrientations:
    """The orientations of the images of some rig heads (see :func:`head_rows`); all when ``spec`` is empty.  A
    spec that matches no image is an :class:`OptionError` naming ``option``."""
    if not spec:
        return eo
    _, rows = head_rows(eo, spec)
    sel = np.unique(np.concatenate(rows)) if rows else np.zeros(0, int)
    if len(sel) == 0:
        text = spec if isinstance(spec, str) else ",".join(spec)
        raise OptionError(option, f"{text}: no image of the EO file matches")
    return eo.subset(sel)


# ------------------------------------------------------------------------------------------ frames, EO, points
def project_frame_of(crs: str | None, geoid: str | None, crs_option: str = "--crs",
                     geoid_option: str = "--geoid") -> WorldFrame | None:
    """The project frame of a CRS and an optional geoid (a compound CRS brings its geoid); None without ``crs``.
    Errors name the options as the caller spells them."""
    if crs is None:
        if geoid is not None:
            raise OptionError(geoid_option, f"goes with {crs_option}")
        return None
    from skyrig.errors import CRSError
    from skyrig.geodesy.statement import project_frame

    try:
        return project_frame(crs, geoid)
    except CRSError as e:
        raise OptionError(crs_option, str(e)) from None


def _map_frame(crs: str | None, geoid: str | None, what: str, option: str, path: str) -> WorldFrame:
    """The map frame of a file that states none, from the caller's ``option`` (named in the message)."""
    if not crs:
        raise InputFormatError(f"{what} needs {option} (the file does not say which CRS it is in)", path)
    return WorldFrame.map(crs, geoid)


def _eo_ign(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
            option: str) -> ExteriorOrientations:
    from skyrig.io.ign import read_ign_opk

    eo = read_ign_opk(path, _map_frame(crs, geoid, "an IGN OPK file", option, path))
    return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)


def _eo_csv(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
            option: str) -> ExteriorOrientations:
    from skyrig.io.eo_csv import read_eo_csv

    eo = read_eo_csv(path)
    return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)


def _eo_geo_txt(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
                option: str) -> ExteriorOrientations:
    from skyrig.io.odm import read_geo_txt, rotation_from_gimbal_ypr

    g = read_geo_txt(path, geoid)
    if g.ypr_deg is None:
        raise InputFormatError("geo.txt has no camera angles; it cannot give exterior orientations", path)
    rot = rotation_from_gimbal_ypr(g.frame, g.xyz, g.ypr_deg)
    return ExteriorOrientations(g.image, np.full(len(g.image), "camera"), g.xyz, rot, g.frame)


def _eo_pix4d_opk(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
                  option: str) -> ExteriorOrientations:
    from skyrig.io.pix4d import read_pix4d_external

    eo = read_pix4d_external(path, _map_frame(crs, geoid, "a Pix4D external parameters file", option, path))
    return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)


def _eo_model(fmt: str) -> Callable[..., ExteriorOrientations]:
    """The reader of another program's model (:mod:`skyrig.io.exchange`): its orientations."""

    def read(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
             option: str) -> ExteriorOrientations:
        from skyrig.io.exchange import read_model_orientations

        eo = read_model_orientations(path, fmt, crs, geoid, option)[0]
        return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)

    return read


#: EO file formats by name (``--eo-format``): reader(path, crs, geoid, z_ground, crs_option).
EO_FORMATS: dict[str, Callable[..., ExteriorOrientations]] = {
    "skyrig-csv": _eo_csv,
    "ign-opk": _eo_ign,
    "odm-geo": _eo_geo_txt,
    "colmap": _eo_model("colmap"),  # a model folder, binary or text
    "opensfm": _eo_model("opensfm"),
    "metashape-xml": _eo_model("metashape-xml"),
    "metashape-psx": _eo_model("metashape-psx"),  # a project NAME.psx (+ NAME.files), its first chunk
    "micmac": _eo_model("micmac"),  # an Ori-* folder
    "pix4d": _eo_model("pix4d"),  # ..._calibrated_camera_parameters.txt (+ ..._offset.xyz beside it)
    "pix4d-opk": _eo_pix4d_opk,  # ..._calibrated_external_camera_parameters.txt
}


def _guess_eo_format(path: str) -> str:
    name = Path(path).name.lower()
    if Path(path).is_dir():
        return "micmac" if any(Path(path).glob("Orientation-*.xml")) else "colmap"
    if name.endswith(".json"):
        return "opensfm"
    if name.endswith(".xml"):
        return "metashape-xml"
    if name.endswith(".psx"):
        return "metashape-psx"
    if name.endswith("_calibrated_external_camera_parameters.txt"):
        return "pix4d-opk"
    if name.endswith("_calibrated_camera_parameters.txt"):
        return "pix4d"
    if name.endswith(".opk"):
        return "ign-opk"
    if name.startswith("geo") and name.endswith(".txt"):
        return "odm-geo"
    return "skyrig-csv"


def load_eo(path: str | PathLike[str], fmt: str | None = None, crs: str | None = None, geoid: str | None = None,
            z_ground: float | None = None, crs_option: str = "--eo-crs",
            format_option: str = "--eo-format") -> ExteriorOrientations:
    """An EO file in any format of :data:`EO_FORMATS` (``fmt`` None: from the file name); ``crs`` / ``geoid``
    for a file that states no CRS (named ``crs_option`` when missing); ``z_ground``: undo the linear alteration of
    projection-centre heights of an adjustment in map coordinates."""
    path = str(path)
    fmt = fmt or _guess_eo_format(path)
    if fmt not in EO_FORMATS:
        raise OptionError(format_option, f"unknown EO format {fmt!r}; known: {', '.join(EO_FORMATS)}")
    return EO_FORMATS[fmt](path, crs, geoid, z_ground, crs_option)


def load_points(path: str | PathLike[str], crs: str | None = None, heights: str = "ellipsoidal",
                geoid: str | None = None, default_crs: str | None = None,
                option: str = "--points-crs") -> GroundPoints:
    """Ground points from IGN .app / _world.mes, ODM gcp_list.txt, or a skyrig points CSV.

    ``crs`` (with ``heights`` / ``geoid``) is the frame the caller gives (named ``option``): a skyrig CSV that
    states its own frame must agree with it.  ``default_crs`` (ellipsoidal heights unless ``heights`` says
    orthometric) is used only for a file that states no frame (e.g. the EO's CRS); the file's statement wins.
    """
    path = str(path)
    name = Path(path).name.lower()
    g = geoid if heights == "orthometric" else None
    frame = None if crs is None else WorldFrame.map(crs, g)
    default = None if default_crs is None else WorldFrame.map(default_crs, g)
    if name.endswith((".app", ".mes")):
        from skyrig.io.ign import read_ign_ground_points

        use = frame or default
        return read_ign_ground_points(path, use if use else _map_frame(crs, None, "an IGN point file", option, path))
    if name.startswith("gcp_list"):
        from skyrig.io.odm import read_gcp_list

        return read_gcp_list(path, g)[0]
    from skyrig.io.points_csv import read_points_csv

    return read_points_csv(path, frame, default, option)


def load_measurements(path: str | PathLike[str]) -> ImageMeasurements:
    """Image measurements from a skyrig CSV, an IGN .mes or an ODM gcp_list.txt."""
    return load_measurements_lines(path)[0]


def load_measurements_lines(path: str | PathLike[str]) -> tuple[ImageMeasurements, np.ndarray]:
    """:func:`load_measurements` and the ``(N,)`` 1-based line of each measurement in its file."""
    path = str(path)
    name = Path(path).name.lower()
    if name.endswith(".mes"):
        from skyrig.io.ign import read_ign_measurements_lines

        return read_ign_measurements_lines(path)
    if name.startswith("gcp_list"):
        from skyrig.io.odm import read_gcp_list_lines

        _, m, lines = read_gcp_list_lines(path)
        return m, lines
    from skyrig.io.points_csv import read_measurements_csv_lines

    return read_measurements_csv_lines(path)


def load_trajectory(path: str | PathLike[str], reference: str | None = None,
                    option: str = "--reference") -> Any:
    """A trajectory from a skyrig trajectory CSV or an Applanix SBET (``.out`` / ``.sbet`` / ``.bin``);
    ``reference`` (``imu`` / ``antenna``): the point an SBET's positions refer to (a CSV states it; a
    contradicting ``reference`` is an error naming ``option``)."""
    path = str(path)
    if Path(path).suffix.lower() in (".out", ".sbet", ".bin"):
        from skyrig.io.sbet import read_sbet

        return read_sbet(path, reference=reference or "imu")
    from skyrig.io.trajectory_csv import read_trajectory_csv

    traj = read_trajectory_csv(path)
    if reference and reference != traj.reference:
        raise OptionError(option, f"{reference} contradicts the trajectory file's '# reference: {traj.reference}'")
    return traj
