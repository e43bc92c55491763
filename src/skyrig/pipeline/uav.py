"""GNSS-supported bundle adjustment of a UAV image block: ``skyrig match`` tie points + image metadata ->
adjusted exterior orientations, self-calibrated camera and a report.

Stages (:func:`skyrig.orient.adjust_uav_block` on arrays, :func:`adjust_uav` on a project folder)
-----------------------------------------------------------------------------------------------
1. **Metadata to a local ENU frame.**  EXIF GPS latitude / longitude / altitude of every image.  The
   altitude is taken as **orthometric above the EGM96 geoid** (DJI writes ``GPSAltitude`` =
   ``drone-dji:AbsoluteAltitude`` above mean sea level) and turned into a WGS84 ellipsoidal height with
   PROJ's EGM96 grid (``h = H + N``; :class:`skyrig.geodesy.crs.Geoid`), unless
   ``UavConfig.altitude == "ellipsoidal"``.  Geodetic -> ECEF -> local ENU at the block centre all go through
   PROJ / :class:`skyrig.geodesy.local.LocalTangentFrame` (:class:`skyrig.georef.eo.WorldFrame`).  DJI XMP
   gimbal yaw / pitch / roll give approximate ``world_from_camera`` rotations.
2. **Which attitudes to trust.**  The metadata attitudes are *checked, not trusted*: the tie points of
   every image are intersected with a horizontal plane at the take-off height (DJI ``RelativeAltitude``)
   using the metadata pose; two overlapping images *agree* when their common tie points land within
   ``agree_fraction`` x flying height of each other (median).  A yaw wrong by 180 deg moves the points by
   twice the base and more.  The largest connected set of agreeing images is the seed.
3. **Growing the block.**  Tie points seen by >= 2 oriented images are triangulated (multi-view midpoint,
   depth and intersection-angle checks), the oriented images are bundle adjusted with GNSS, and every
   remaining image is oriented by space resection (``cv2.solvePnPRansac``) on the triangulated points;
   repeat until no image is left or none can be added.  The attitude found by resection is compared with
   the metadata (a 180 deg yaw error is reported, not silently used).  Without any usable attitude metadata
   (phones), or for a part of the block the tie points do not connect to the rest, the seed is a two-view
   relative orientation (essential matrix), grown by resection in its own frame and then put onto the GNSS
   positions by a similarity transform; GNSS positions that lie on a line leave the roll about that line
   undetermined, which is reported (:class:`UavAdjustError`), not guessed.
4. **Final adjustment.**  GNSS positions (antenna = projection centre, no lever arm known) with a consumer
   GPS sigma (default 2 m horizontal, 4 m vertical), verified gimbal attitudes as weak observations
   (default 5 deg), image observations with Huber weights, self-calibration of focal length (EXIF focal as a
   weighted prior), principal point and OpenCV distortion k1 k2 p1 p2 k3; then residuals above
   ``reject_k`` x robust RMS are removed and the block re-adjusted with full statistics.

   Options (defaults keep the behaviour above): ``focal="exif"`` fixes the focal length at its EXIF value;
   ``focal="auto"`` self-calibrates it but fixes it at EXIF when its formal sigma is not below
   ``focal_determinable`` x the prior sigma (the decision is reported in words in ``summary["focal"]``);
   ``gnss_strip_shift="weighted"`` estimates a GNSS shift per flight strip (:func:`detect_strips`).  On brighton
   (1600-px ties) none of them, nor dropping the attitude prior, changes the 1 m misfit of strip DJI_0018-0023
   (see ``bench/uav.py --variants``), so they stay off by default.

Everything is in the local ENU frame (metres); pixels follow skyrig's convention (origin at the centre of
the top-left pixel).

The algorithms (layer 2b, arrays in / out) live in :mod:`skyrig.orient`; this module is the file-level wrapper
(image metadata and ``skyrig match`` tie points in, EO / points / report files out) and keeps every name it had
importable from here.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError
from skyrig.orient.gnss_block import (  # noqa: F401  (re-exported: the names this module always had)
    UavAdjustError, UavBlockInput, UavConfig, UavResult, _build_block, _seed_component, _summary, _two_view_seed,
    adjust_uav_block, attitude_agreement,
)
from skyrig.orient.similarity import _MIN_COMMON, _robust_similarity, compare_with_reconstruction  # noqa: F401
from skyrig.orient.strips import _renumber_strips, detect_strips  # noqa: F401
from skyrig.orient.triangulation import (  # noqa: F401
    _SKYRIG_FROM_CV, _k_matrix, _rays_world, _reproject, _rotation_angle_deg, _spread_ok, _track_pairs, resect,
    triangulate_tracks,
)

logger = logging.getLogger(__name__)

__all__ = ["UavConfig", "UavBlockInput", "UavResult", "metadata_block_input", "adjust_uav_block", "adjust_uav",
           "compare_with_reconstruction", "triangulate_tracks", "detect_strips"]


# ---------------------------------------------------------------------------------------------- I/O side
def _geoid_grid(cfg: UavConfig) -> str:
    if cfg.geoid:
        return cfg.geoid
    from skyrig.pipeline.simulate import find_geoid

    g = find_geoid()
    return g if g is not None else "us_nga_egm96_15.tif"


def metadata_block_input(metas: Sequence[Any], measurements: Any, cfg: UavConfig = UavConfig()) -> UavBlockInput:
    """Build a :class:`UavBlockInput` from image metadata (:func:`skyrig.io.image_read.read_image_metadata`) and
    tie points (:class:`skyrig.georef.observations.ImageMeasurements`, e.g. ``tie_points.csv`` of ``skyrig match``).

    Raises
    ------
    InputFormatError
        An image lacks GPS or a focal length (naming the image and the field); a tie point names an unknown
        image.
    """
    from skyrig.geodesy.crs import Geoid, geodetic_to_ecef
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.image_read import camera_from_metadata
    from skyrig.io.odm import rotation_from_gimbal_ypr

    metas = list(metas)
    for m in metas:
        if not m.has_gps or m.alt_m is None:
            raise InputFormatError("no EXIF GPS position with altitude", m.path, None,
                                   "GPSLatitude" if not m.has_gps else "GPSAltitude")
    notes = []
    lat = np.array([m.lat_deg for m in metas], float)
    lon = np.array([m.lon_deg for m in metas], float)
    alt = np.array([m.alt_m for m in metas], float)
    if cfg.altitude == "egm96":
        grid = _geoid_grid(cfg)
        N = Geoid(grid).undulation(lat, lon)
        h = alt + N
        notes.append(f"EXIF GPSAltitude taken as EGM96 orthometric height; h = H + N with N = {N.mean():.2f} m "
                     f"(grid {Path(grid).name})")
    else:
        h = alt
        notes.append("EXIF GPSAltitude taken as WGS84 ellipsoidal height")
    ecef = geodetic_to_ecef(lat, lon, h)
    frame = WorldFrame.local(float(lat.mean()), float(lon.mean()), float(h.mean()))
    gnss = frame.from_ecef(ecef)
    rot = np.full((len(metas), 3, 3), np.nan)
    have = np.array([m.gimbal_ypr_deg is not None for m in metas])
    if have.any():
        ypr = np.array([m.gimbal_ypr_deg for m in metas if m.gimbal_ypr_deg is not None], float)
        rot[have] = rotation_from_gimbal_ypr(frame, gnss[have], ypr)
    rel = [g[2] - m.relative_alt_m for g, m in zip(gnss, metas) if m.relative_alt_m is not None]
    ground = float(np.median(rel)) if rel else None
    cam = camera_from_metadata(metas[0], metas[0].model or "camera")
    sizes = {(m.width, m.height) for m in metas}
    if len(sizes) > 1:
        raise InputFormatError(f"images of different sizes {sorted(sizes)}: one camera per block is supported",
                               metas[0].path)
    cam = cam.with_(distortion=OpenCVDistortion())
    names = np.array([m.name for m in metas], dtype=str)
    meas_image = np.asarray(measurements.image, dtype=str)
    by_name = np.argsort(names, kind="stable")
    pos = np.minimum(np.searchsorted(names[by_name], meas_image), len(names) - 1)
    known = names[by_name][pos] == meas_image
    if not known.all():
        unknown = sorted(set(meas_image[~known].tolist()))
        raise InputFormatError(f"tie points name {len(unknown)} image(s) without metadata, e.g. {unknown[0]!r}")
    track_name, obs_track = np.unique(measurements.point, return_inverse=True)
    obs_image = by_name[pos].astype(np.int64)
    return UavBlockInput(names, cam, gnss, rot, ground, obs_track.astype(np.int64), obs_image,
                         np.asarray(measurements.pixel, float), track_name, frame, notes)


def adjust_uav(images: str | Path, match_dir: str | Path, out: str | Path | None = None,
               cfg: UavConfig = UavConfig(), pycolmap_workdir: str | Path | None = None,
               pycolmap_max_image_size: int = 1600, pycolmap_max_features: int = 8192,
               pycolmap_mapper: str = "incremental", crs: str | None = None) -> tuple[UavResult, dict[str, Any]]:
    """Project-level stage: images + ``skyrig match`` output -> adjusted EO, camera and report.

    Parameters
    ----------
    images
        Folder of the images (EXIF GPS, DJI XMP).
    match_dir
        Output folder of ``skyrig match`` (``tie_points.csv``).
    out
        If given: ``eo.csv``, ``points.csv`` and ``adjusted.gpkg`` in the project CRS
        (:mod:`skyrig.io.adjust_outputs`), ``report.json``, ``report.html`` and residual plots are written there.
    crs
        Project CRS of the outputs (a compound CRS gives orthometric heights through its geoid); default the
        WGS84 UTM zone of the images' GNSS positions, ellipsoidal heights.
    pycolmap_workdir
        If given, pycolmap's own pipeline (SIFT, exhaustive matching, incremental mapping) runs there on the
        same images and its camera centres / reprojection RMS are compared (needs ``pycolmap``), with SIFT on
        images downscaled to ``pycolmap_max_image_size`` and at most ``pycolmap_max_features`` per image, and
        ``pycolmap_mapper`` "incremental" (COLMAP) or "global" (GLOMAP; forward-moving sequences such as lund).

    Returns
    -------
    result, report
    """
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.io.points_csv import read_measurements_csv

    t0 = time.perf_counter()
    meas = read_measurements_csv(Path(match_dir) / "tie_points.csv")
    metas = [read_image_metadata(p) for p in list_images(images)]  # images without tie points: "not oriented"
    inp = metadata_block_input(metas, meas, cfg)
    res = adjust_uav_block(inp, cfg)
    from skyrig.adjust.report import adjustment_report

    project = uav_project_frame(inp, crs)
    report = adjustment_report(res.adjustment, frames=None if project is None else (inp.frame, project))
    report["uav"] = dict(res.summary)
    report["uav"]["config"] = asdict(cfg)
    report["uav"]["attitude_check"] = res.attitude_check
    if pycolmap_workdir is not None:
        from skyrig.match.colmap_check import reconstruct_with_pycolmap

        t1 = time.perf_counter()
        _, summ = reconstruct_with_pycolmap(images, [str(n) for n in inp.names], pycolmap_workdir,
                                           max_image_size=pycolmap_max_image_size,
                                           max_features=pycolmap_max_features, mapper=pycolmap_mapper,
                                           focal_px=inp.camera.focal_mm / inp.camera.pixel_size_mm)
        if summ is None:
            report["pycolmap"] = {"registered": 0}
        else:
            cmp = compare_with_reconstruction(res, summ.names, summ.centres, inp.gnss)
            report["pycolmap"] = {"registered": int(len(summ.names)), "points": summ.n_points,
                                  "reprojection_rms_px": summ.reprojection_rms_px, "wall_s": time.perf_counter() - t1,
                                  "centre_differences": cmp}
    report["uav"]["total_wall_s"] = time.perf_counter() - t0
    if out is not None:
        _write_outputs(Path(out), res, report, inp, project)
    return res, report


def uav_project_frame(inp: UavBlockInput, crs: str | None = None) -> Any:
    """The project frame of a UAV block's outputs: ``crs`` (:func:`skyrig.geodesy.statement.project_frame`), else
    the WGS84 UTM zone of the GNSS positions (ellipsoidal heights); None when the block has no frame."""
    from skyrig.geodesy.statement import project_frame, utm_frame

    if crs is not None:
        return project_frame(crs)
    if inp.frame is None:
        return None
    from skyrig.geodesy.crs import ecef_to_geodetic

    lat, lon, _ = ecef_to_geodetic(inp.frame.to_ecef(np.nanmean(inp.gnss, axis=0, keepdims=True)))
    return utm_frame(lat, lon)


def _write_outputs(out: Path, res: UavResult, report: dict[str, Any], inp: UavBlockInput,
                   project: Any = None) -> dict[str, Path]:
    """``eo.csv``, ``points.csv`` (tie points with sigmas) and ``adjusted.gpkg`` in the project frame (default
    :func:`uav_project_frame`), ``report.json``, ``report.html``, residual plots and ``camera.yaml`` (the
    self-calibrated camera as a rig file) in ``out``."""
    from skyrig.georef.eo import ExteriorOrientations
    from skyrig.io.adjust_outputs import write_adjusted_tables
    from skyrig.io.report_html import write_report

    out.mkdir(parents=True, exist_ok=True)
    k = res.block_image
    paths: dict[str, Path] = {}
    project = project or uav_project_frame(inp)
    if inp.frame is not None and project is not None:
        eo = ExteriorOrientations(res.names[k], np.array([res.camera.name] * len(k)), res.centre[k], res.rotation[k],
                                  inp.frame)
        paths.update(write_adjusted_tables(out, res.adjustment, inp.frame, project, eo_local=eo))
    paths.update(write_report(out, res.adjustment, report, title="skyrig UAV GNSS-supported adjustment"))
    paths["camera"] = _write_camera(out / "camera.yaml", res)
    return paths


def _write_camera(path: Path, res: UavResult) -> Path:
    """The self-calibrated camera as a one-head rig file (what ``skyrig dsm`` / ``ortho`` / ``facades`` take with
    ``--camera``); its name is the EO file's camera column."""
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.rig import Head, Rig

    conv = getattr(getattr(res.adjustment, "info", None), "converged", None)
    how = "self-calibrated by skyrig adjust-uav" + ("" if conv in (None, True) else " (NOT converged)")
    write_rig(Rig(f"{res.camera.name}-adjust-uav", {"camera": Head("camera", res.camera)},
                  description=f"{res.camera.name} {how}"), path)
    return path
