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

Without GNSS (``skyrig adjust-uav --no-gps``): :func:`orient_without_gnss` reads the same inputs plus control points,
scale bars (:func:`read_scale_bars`), extra target measurements and an optional camera (:func:`orient_input`), runs
:func:`skyrig.orient.incremental.orient_incremental` and writes the same outputs (in an arbitrary engineering frame,
:data:`MODEL_FRAME_WKT`, when the datum is a scale bar or a free network).
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from skyrig.camera.distortion import NoDistortion
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
def _ties_file(match: str | Path) -> Path:
    """The tie points: ``match`` itself, or ``match/tie_points.csv`` when it is a folder (``skyrig match``'s)."""
    p = Path(match)
    return p / "tie_points.csv" if p.is_dir() else p


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
    sizes = {(m.width, m.height) for m in metas}
    if len(sizes) > 1:
        raise InputFormatError(f"images of different sizes {sorted(sizes)}: one camera per block is supported",
                               metas[0].path)
    cam, isig, prior = camera_and_prior(metas, cfg)
    notes.append(f"camera prior: {prior.source}; focal {prior.focal_px:.1f} +- {prior.focal_sigma_px:.1f} px, "
                 f"principal point ({prior.pp_px[0]:.1f}, {prior.pp_px[1]:.1f}) +- {prior.pp_sigma_px:.1f} px")
    notes.extend(prior.warnings)
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
    times = np.array([np.nan if m.time_s is None else m.time_s for m in metas], float)
    return UavBlockInput(names, cam, gnss, rot, ground, obs_track.astype(np.int64), obs_image,
                         np.asarray(measurements.pixel, float), track_name, frame, notes, isig, prior.source,
                         camera_make=metas[0].make, camera_model=metas[0].model,
                         times_s=times if np.isfinite(times).any() else None)


def _with_extra(meas: Any, extra: Sequence[Any]) -> Any:
    """Tie points plus extra image measurements (ground control targets) as one table."""
    if not extra:
        return meas
    from skyrig.georef.observations import ImageMeasurements

    ms = [meas, *extra]
    return ImageMeasurements(np.concatenate([m.point for m in ms]), np.concatenate([m.image for m in ms]),
                             np.vstack([m.pixel for m in ms]))


def attach_ground_points(inp: UavBlockInput, control: Any, check: Any, sigma_m: Sequence[float],
                         sources: dict[str, str]) -> UavBlockInput:
    """``inp`` with control / check points (GroundPoints in any frame, moved into the block's local frame by PROJ)
    found by name among its tracks; a point measured in no image is an error naming the file."""
    from dataclasses import replace as _replace

    sig = np.asarray(sigma_m, float).reshape(-1)
    if sig.size == 1:
        sig = np.repeat(sig, 3)
    if sig.size != 3 or not np.all(np.isfinite(sig)) or np.any(sig <= 0):
        raise InputFormatError(f"control sigma {list(sigma_m)}: three positive numbers (m) expected", None, None,
                               "control_sigma")
    tidx = {str(n): k for k, n in enumerate(inp.track_name)}
    tr, xyz, chk = [], [], []
    for pts, is_check in ((control, False), (check, True)):
        if pts is None:
            continue
        local = pts.frame.points_to(pts.xyz, inp.frame)
        for nm, x in zip(pts.name, local):
            if str(nm) not in tidx:
                what = "check" if is_check else "control"
                raise InputFormatError(f"{what} point {str(nm)!r} is not measured in any image (no tie point or "
                                       "image measurement of that name)", sources.get(what))
            tr.append(tidx[str(nm)])
            xyz.append(x)
            chk.append(is_check)
    notes = list(inp.notes) + [f"{sum(not c for c in chk)} control and {sum(chk)} check points, control sigma "
                               f"{', '.join(f'{v:g}' for v in sig)} m (x, y, z)"]
    return _replace(inp, control_track=np.array(tr, np.int64), control_xyz=np.array(xyz, float).reshape(-1, 3),
                    control_sigma=np.broadcast_to(sig, (len(tr), 3)).copy(), control_check=np.array(chk, bool),
                    notes=notes)


def block_gsd_m(res: UavResult) -> float | None:
    """The block's ground sampling distance (m): median over the oriented images of the height above the median
    object point over the focal length in pixels (for check-point RMS in GSD)."""
    b = res.adjustment.block
    if b.n_points == 0 or len(res.block_image) == 0:
        return None
    zg = float(np.median(b.point_xyz[:, 2]))
    H = np.abs(res.centre[res.block_image, 2] - zg)
    f_px = res.camera.focal_mm / res.camera.pixel_size_mm
    g = float(np.median(H)) / f_px
    return g if np.isfinite(g) and g > 0 else None


def camera_and_prior(metas: Sequence[Any], cfg: UavConfig = UavConfig()) -> tuple[Any, dict[str, float], Any]:
    """The starting camera of a block's images, its intrinsics' prior sigmas (camera units) and the
    :class:`skyrig.io.camera_prior.CameraPrior` it came from (the first image's; every image is checked to be the
    same camera: make, model and EXIF focal length, else a warning names the first that differs)."""
    from skyrig.io.camera_prior import camera_prior
    from skyrig.camera.frame import FrameCamera

    m0 = metas[0]
    prior = camera_prior(m0, focal_sigma_rel=cfg.focal_prior_rel)
    for m in metas[1:]:
        if (m.make, m.model) != (m0.make, m0.model) or (m.focal_mm and m0.focal_mm and
                                                        abs(m.focal_mm / m0.focal_mm - 1) > 0.005):
            logger.warning("%s: camera %s %s, focal %s mm differs from %s (%s %s, %s mm): one camera is adjusted for "
                           "the whole block", m.path, m.make, m.model, m.focal_mm, m0.name, m0.make, m0.model,
                           m0.focal_mm)
            break
    pix = prior.pixel_size_mm or 0.001
    dist = OpenCVDistortion(**prior.distortion) if prior.distortion else OpenCVDistortion()
    cam = FrameCamera.from_pixels(m0.model or "camera", prior.width, prior.height, prior.focal_px, prior.pp_px[0],
                                  prior.pp_px[1], pixel_size_mm=pix, distortion=dist)
    isig = {"focal_mm": prior.focal_sigma_px * pix, "ppx_mm": prior.pp_sigma_px * pix,
            "ppy_mm": prior.pp_sigma_px * pix, **prior.distortion_sigma}
    return cam, isig, prior


def adjust_uav(images: str | Path, match_dir: str | Path, out: str | Path | None = None,
               cfg: UavConfig = UavConfig(), pycolmap_workdir: str | Path | None = None,
               pycolmap_max_image_size: int = 1600, pycolmap_max_features: int = 8192,
               pycolmap_mapper: str = "incremental", crs: str | None = None,
               pycolmap_input: str = "images", control: Any = None, check: Any = None,
               control_sigma_m: Sequence[float] = (0.01, 0.01, 0.01), extra_measurements: Sequence[Any] = (),
               sources: dict[str, str] | None = None) -> tuple[UavResult, dict[str, Any]]:
    """Project-level stage: images + ``skyrig match`` output -> adjusted EO, camera and report.

    With ``control`` / ``check`` (:class:`~skyrig.georef.observations.GroundPoints`, measured in the images through
    the tie points or ``extra_measurements``) the GNSS-supported block also uses control points (sigma
    ``control_sigma_m`` per axis: metre-class targets with a loose height are fine) and reports check points in
    metres and GSD; without check points the report says the absolute accuracy is the GNSS's.

    Parameters
    ----------
    images
        Folder of the images (EXIF GPS, DJI XMP).
    match_dir
        Output folder of ``skyrig match`` (``tie_points.csv``), or a tie-point file.
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
        ``pycolmap_mapper`` "incremental" (COLMAP) or "global" (GLOMAP; forward-moving sequences such as lund);
        ``pycolmap_input`` "tracks": pycolmap's mapper on skyrig's own tie points instead
        (:func:`skyrig.orient.reference.compare_on_same_tracks`).

    Returns
    -------
    result, report
    """
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.io.points_csv import read_measurements_csv

    t0 = time.perf_counter()
    meas = _with_extra(read_measurements_csv(_ties_file(match_dir)), extra_measurements)
    metas = [read_image_metadata(p) for p in list_images(images)]  # images without tie points: "not oriented"
    metas, meas = without_gps_left_out(metas, meas)
    inp = metadata_block_input(metas, meas, cfg)
    if control is not None or check is not None:
        inp = attach_ground_points(inp, control, check, control_sigma_m, sources or {})
    res = adjust_uav_block(inp, cfg)
    from skyrig.adjust.report import adjustment_report

    project = uav_project_frame(inp, crs)
    report = adjustment_report(res.adjustment, gsd_m=block_gsd_m(res),
                               frames=None if project is None else (inp.frame, project))
    report["uav"] = dict(res.summary)
    report["uav"]["config"] = asdict(cfg)
    report["uav"]["attitude_check"] = res.attitude_check
    if pycolmap_workdir is not None and pycolmap_input == "tracks":
        from skyrig.orient.reference import compare_on_same_tracks

        report["pycolmap"] = compare_on_same_tracks(res, inp, pycolmap_workdir)
    elif pycolmap_workdir is not None:
        from skyrig.match.colmap_check import reconstruct_with_pycolmap
        from skyrig.orient.reference import centre_differences_in_sigma

        t1 = time.perf_counter()
        _, summ = reconstruct_with_pycolmap(images, [str(n) for n in inp.names], pycolmap_workdir,
                                           max_image_size=pycolmap_max_image_size,
                                           max_features=pycolmap_max_features, mapper=pycolmap_mapper,
                                           focal_px=inp.camera.focal_mm / inp.camera.pixel_size_mm)
        if summ is None:
            report["pycolmap"] = {"registered": 0}
        else:
            cmp = centre_differences_in_sigma(res, compare_with_reconstruction(res, summ.names, summ.centres,
                                                                               inp.gnss))
            report["pycolmap"] = {"input": "images", "registered": int(len(summ.names)), "points": summ.n_points,
                                  "reprojection_rms_px": summ.reprojection_rms_px, "wall_s": time.perf_counter() - t1,
                                  "cameras": list(summ.cameras), "centre_differences": cmp}
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
    cal = res.summary.get("self_calibrated") if isinstance(getattr(res, "summary", None), dict) else None
    how = ("as given (no self-calibration) in skyrig adjust-uav" if cal == [] else
           "self-calibrated by skyrig adjust-uav" + (f" ({', '.join(cal)})" if cal else "")) + \
        ("" if conv in (None, True) else " (NOT converged)")
    write_rig(Rig(f"{res.camera.name}-adjust-uav", {"camera": Head("camera", res.camera)},
                  description=f"{res.camera.name} {how}"), path)
    return path


# ---------------------------------------------------------------------------------------------- without GNSS
#: an arbitrary Cartesian frame (engineering CRS) for blocks whose datum is a scale bar or a free network
MODEL_FRAME_WKT = ('ENGCRS["skyrig model frame (arbitrary origin and orientation)",EDATUM["skyrig relative '
                   'orientation"],CS[Cartesian,3],AXIS["x",east,LENGTHUNIT["metre",1]],AXIS["y",north,'
                   'LENGTHUNIT["metre",1]],AXIS["z",up,LENGTHUNIT["metre",1]]]')


def read_scale_bars(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scale bars from a CSV ``from,to,length_m[,sigma_m]`` (``#`` comment lines allowed; sigma default 1 mm).

    Returns ``(D, 2)`` end names, ``(D,)`` lengths and sigmas (m).  Raises :class:`InputFormatError` naming the
    file, line and field of a malformed row, a non-positive length or sigma, or a bar from a point to itself.
    """
    import csv
    import io

    from skyrig.io._text import parse_float, read_text

    lines = read_text(path).splitlines()
    start = 0
    while start < len(lines) and (not lines[start].strip() or lines[start].lstrip().startswith("#")):
        start += 1
    if start >= len(lines):
        raise InputFormatError("no column header row (expected from,to,length_m[,sigma_m])", path, len(lines))
    rd = csv.reader(io.StringIO("\n".join(lines[start:])))
    header = [h.strip().lower() for h in next(rd)]
    for c in ("from", "to", "length_m"):
        if c not in header:
            raise InputFormatError("missing column (expected from,to,length_m[,sigma_m])", path, start + 1, c)
    for c in header:
        if c not in ("from", "to", "length_m", "sigma_m"):
            raise InputFormatError(f"unknown column {c!r}", path, start + 1, c)
    ends, length, sigma = [], [], []
    for k, row in enumerate(rd):
        line = start + 2 + k
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        if len(row) != len(header):
            raise InputFormatError(f"expected {len(header)} fields, found {len(row)}", path, line)
        r = {h: v.strip() for h, v in zip(header, row)}
        if not r["from"] or not r["to"]:
            raise InputFormatError("empty point name", path, line, "from" if not r["from"] else "to")
        if r["from"] == r["to"]:
            raise InputFormatError(f"scale bar from {r['from']!r} to itself", path, line, "to")
        d = parse_float(r["length_m"], path, line, "length_m")
        s = parse_float(r["sigma_m"], path, line, "sigma_m") if r.get("sigma_m") else 0.001
        if not d > 0:
            raise InputFormatError(f"length must be > 0, got {d}", path, line, "length_m")
        if not s > 0:
            raise InputFormatError(f"sigma must be > 0, got {s}", path, line, "sigma_m")
        ends.append((r["from"], r["to"]))
        length.append(d)
        sigma.append(s)
    if not ends:
        raise InputFormatError("no scale bar in the file", path, len(lines))
    return np.array(ends, dtype=str).reshape(-1, 2), np.array(length), np.array(sigma)



def orient_input(images: str | Path | None, measurements: Any, camera: Any = None, control: Any = None,
                 control_sigma_m: Sequence[float] = (0.01, 0.01, 0.01), check: Any = None,
                 scale_bars: tuple | None = None, use_gps: bool = True, cfg: UavConfig = UavConfig(),
                 sources: dict[str, str] | None = None) -> Any:
    """An :class:`skyrig.orient.incremental.OrientInput` from images (EXIF: focal length, GPS), tie points
    (:class:`~skyrig.georef.observations.ImageMeasurements`; control targets and scale-bar ends are points like any
    other, by name), an optional camera (replaces the EXIF one), control / check points
    (:class:`~skyrig.georef.observations.GroundPoints`) and scale bars (:func:`read_scale_bars`).

    Control points in a map CRS or ECEF are used in a local ENU frame at their centroid (``inp.frame``); the EXIF GPS
    positions (``use_gps`` and every image has one) become approximate positions in a local ENU frame (used only
    for ``datum="positions"``: a similarity, never as observations).

    Raises
    ------
    InputFormatError
        No image and no camera; images of different sizes; a tie point naming an unknown image; a control point or
        scale-bar end not measured in any image (naming the file).
    """
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.orient.incremental import OrientInput

    src = sources or {}
    focal_rel: float | None = None
    metas = [read_image_metadata(p) for p in list_images(images)] if images is not None else []
    meas_image = np.asarray(measurements.image, dtype=str)
    notes: list[str] = []
    frame = None
    positions = None
    if metas:
        names = np.array([m.name for m in metas], dtype=str)
        sizes = {(m.width, m.height) for m in metas}
        if len(sizes) > 1:
            raise InputFormatError(f"images of different sizes {sorted(sizes)}: one camera per block is supported",
                                   metas[0].path)
        if camera is None:
            camera, _, prior = camera_and_prior(metas, UavConfig(focal_prior_rel=cfg.focal_prior_rel))
            focal_rel = prior.focal_rel_sigma
            notes.append(f"camera prior from the images' metadata: {prior.source}; focal {prior.focal_px:.1f} +- "
                         f"{prior.focal_sigma_px:.1f} px")
            notes.extend(prior.warnings)
        elif (camera.width, camera.height) != (metas[0].width, metas[0].height):
            raise InputFormatError(f"the given camera {camera.name!r} is {camera.width} x {camera.height} px but the "
                                   f"images are {metas[0].width} x {metas[0].height} px: a camera of other images (or "
                                   "of downscaled / rotated ones)", src.get("camera"), None, "width_px / height_px")
        gps_ok = all(m.has_gps and m.alt_m is not None for m in metas)
        if use_gps and gps_ok and control is None:
            blk = metadata_block_input(metas, measurements, cfg)
            positions, frame = blk.gnss, blk.frame
            notes += blk.notes + ["EXIF GPS used only as approximate positions (similarity), not as observations"]
    else:
        if camera is None:
            raise InputFormatError("no images (with EXIF) found and no camera given: give --camera", str(images))
        names = np.unique(meas_image)
        notes.append("image names from the tie points (no image files read)")
    if isinstance(camera.distortion, NoDistortion):  # a given model (Brown...) is kept as it is
        camera = camera.with_(distortion=OpenCVDistortion())
    by_name = np.argsort(names, kind="stable")
    pos = np.minimum(np.searchsorted(names[by_name], meas_image), len(names) - 1)
    known = names[by_name][pos] == meas_image
    if not known.all():
        unknown = sorted(set(meas_image[~known].tolist()))
        raise InputFormatError(f"tie points name {len(unknown)} image(s) that are not in the image folder, e.g. "
                               f"{unknown[0]!r}", src.get("measurements"))
    track_name, obs_track = np.unique(np.asarray(measurements.point, dtype=str), return_inverse=True)
    tidx = {str(n): k for k, n in enumerate(track_name)}
    kw: dict[str, Any] = {}
    gp = [(p, False) for p in ([control] if control is not None else [])] + \
         [(p, True) for p in ([check] if check is not None else [])]
    if gp:
        from skyrig.georef.eo import WorldFrame

        cf = gp[0][0].frame
        xyz_all = np.vstack([p.frame.points_to(p.xyz, cf) for p, _ in gp])
        if cf.kind in ("map", "ecef") and not _is_engineering(cf):
            from skyrig.geodesy.crs import ecef_to_geodetic

            ecef = cf.points_to(xyz_all.mean(axis=0, keepdims=True), WorldFrame.ecef())
            lat, lon, h = ecef_to_geodetic(ecef)
            frame = WorldFrame.local(float(np.ravel(lat)[0]), float(np.ravel(lon)[0]), float(np.ravel(h)[0]))
            xyz_all = cf.points_to(xyz_all, frame)
            notes.append(f"control points ({cf.describe()}) used in a local ENU frame at their centroid")
        else:
            frame = cf
        ctrack, cxyz, ccheck = [], [], []
        row = 0
        for p, is_check in gp:
            for nm in p.name:
                if str(nm) not in tidx:
                    what = "check" if is_check else "control"
                    raise InputFormatError(f"{what} point {str(nm)!r} is not measured in any image (no tie point / "
                                           "measurement of that name)", src.get("check" if is_check else "control"))
                ctrack.append(tidx[str(nm)])
                cxyz.append(xyz_all[row])
                ccheck.append(is_check)
                row += 1
        kw.update(control_track=np.array(ctrack), control_xyz=np.array(cxyz),
                  control_sigma=np.broadcast_to(np.asarray(control_sigma_m, float), (len(ctrack), 3)),
                  control_check=np.array(ccheck))
    if scale_bars is not None:
        ends, length, sigma = scale_bars
        for a in ends.ravel():
            if str(a) not in tidx:
                raise InputFormatError(f"scale-bar end {str(a)!r} is not measured in any image (no tie point / "
                                       "measurement of that name)", src.get("scale_bars"))
        kw.update(distance_track=np.array([[tidx[str(a)], tidx[str(b)]] for a, b in ends]), distance_m=length,
                  distance_sigma_m=sigma)
    if metas:
        times = np.array([np.nan if m.time_s is None else m.time_s for m in metas], float)
        kw.update(camera_make=metas[0].make or "", camera_model=metas[0].model or "",
                  times_s=times if np.isfinite(times).any() else None)
    return OrientInput(names, camera, obs_track.astype(np.int64), by_name[pos].astype(np.int64),
                       np.asarray(measurements.pixel, float), track_name, positions=positions, frame=frame,
                       notes=notes, focal_prior_rel=focal_rel, **kw)


def _is_engineering(frame: Any) -> bool:
    if frame is None or frame.kind != "map":
        return False
    import pyproj

    try:
        return bool(pyproj.CRS(frame.crs).is_engineering)
    except Exception:  # noqa: BLE001  (a CRS PROJ reads as something else)
        return False


def orient_without_gnss(images: str | Path | None, match_dir: str | Path, out: str | Path | None = None,
                        cfg: Any = None, camera: Any = None, control: Any = None,
                        control_sigma_m: Sequence[float] = (0.01, 0.01, 0.01), check: Any = None,
                        scale_bars: tuple | None = None, extra_measurements: Sequence[Any] = (),
                        use_gps: bool = True, pycolmap_workdir: str | Path | None = None,
                        pycolmap_max_image_size: int = 1600, pycolmap_max_features: int = 8192,
                        pycolmap_mapper: str = "incremental", crs: str | None = None,
                        altitude_cfg: UavConfig = UavConfig(), sources: dict[str, str] | None = None,
                        pycolmap_input: str = "images") -> tuple[UavResult, dict[str, Any]]:
    """Project-level stage of the orientation without GNSS (:func:`skyrig.orient.incremental.orient_incremental`):
    images + ``skyrig match`` tie points (+ target measurements, control, scale bars) -> EO, points, camera,
    report (the same files as :func:`adjust_uav`).

    The output frame: the control points' CRS (datum "control"); the ``crs`` or the UTM zone of the EXIF GPS
    (datum "positions"); else :data:`MODEL_FRAME_WKT`, an engineering CRS in metres (scale bars) or in the units
    of the relative orientation's base (free network).  ``pycolmap_workdir``: pycolmap's own reconstruction of the
    same images, compared by camera centres after a similarity (``mapper`` "incremental", falling back to
    "global" when the incremental mapper registers fewer than half of the images); with ``pycolmap_input``
    "tracks" (or no ``images``) pycolmap's mapper on the same tie points instead
    (:func:`skyrig.orient.reference.compare_on_same_tracks`).
    """
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.orient.incremental import OrientConfig, orient_incremental

    t0 = time.perf_counter()
    cfg = cfg or OrientConfig()
    meas = read_measurements_csv(_ties_file(match_dir))
    if extra_measurements:
        ms = [meas, *extra_measurements]
        meas = ImageMeasurements(np.concatenate([m.point for m in ms]), np.concatenate([m.image for m in ms]),
                                 np.vstack([m.pixel for m in ms]))
    src = {"measurements": str(_ties_file(match_dir)), **(sources or {})}
    inp = orient_input(images, meas, camera, control, control_sigma_m, check, scale_bars, use_gps, altitude_cfg, src)
    res = orient_incremental(inp, cfg)
    from skyrig.adjust.report import adjustment_report
    from skyrig.georef.eo import WorldFrame

    datum = res.summary["datum"]["kind"]
    if datum == "control":
        project = control.frame
        frame = inp.frame
    elif datum == "positions":
        frame = inp.frame
        project = uav_project_frame(UavBlockInput(inp.names, inp.camera, inp.positions, np.zeros((0, 3, 3)), None,
                                                  inp.obs_track, inp.obs_image, inp.obs_pixel, inp.track_name,
                                                  inp.frame), crs)
    else:
        frame = project = WorldFrame.map(MODEL_FRAME_WKT)
    report = adjustment_report(res.adjustment, frames=(frame, project) if frame is not None else None)
    report["uav"] = dict(res.summary)
    report["uav"]["config"] = asdict(cfg)
    report["uav"]["attitude_check"] = res.attitude_check
    report["uav"]["mode"] = "orientation without GNSS (relative orientation, resection, bundle adjustment)"
    if pycolmap_workdir is not None and (pycolmap_input == "tracks" or images is None):
        from skyrig.orient.reference import compare_on_same_tracks

        report["pycolmap"] = compare_on_same_tracks(res, inp, pycolmap_workdir)
    elif pycolmap_workdir is not None:
        report["pycolmap"] = compare_pycolmap(res, images, inp, pycolmap_workdir, pycolmap_max_image_size,
                                              pycolmap_max_features, pycolmap_mapper)
    report["uav"]["total_wall_s"] = time.perf_counter() - t0
    if out is not None:
        if project is not None and project.kind == "map" and _is_engineering(project):
            # skyrig's EO / points writers need a georeferenced frame: plain tables in the model frame, then the
            # report and camera as for any block
            _write_model_frame_tables(Path(out), res, datum)
            shim = UavBlockInput(inp.names, inp.camera, np.zeros((len(inp.names), 3)), np.zeros((0, 3, 3)), None,
                                 inp.obs_track, inp.obs_image, inp.obs_pixel, inp.track_name, None)
        else:
            shim = UavBlockInput(inp.names, inp.camera, np.zeros((len(inp.names), 3)), np.zeros((0, 3, 3)), None,
                                 inp.obs_track, inp.obs_image, inp.obs_pixel, inp.track_name, frame)
        _write_outputs(Path(out), res, report, shim, project)
    return res, report


def _write_model_frame_tables(out: Path, res: UavResult, datum: str) -> None:
    """``eo.csv`` (image, camera, x, y, z, omega, phi, kappa in degrees, centre sigmas) and ``points.csv`` (name,
    x, y, z, sigmas, role) in the arbitrary frame of a block without georeference (scale bars: metres; free
    network: the relative orientation's units), with ``#`` lines saying so; written atomically."""
    from skyrig.geometry.rotations import opk_from_matrix
    from skyrig.io._text import atomic_write

    out.mkdir(parents=True, exist_ok=True)
    units = "metres (scale from the scale bars)" if datum == "scale-bar" else \
        "units of the relative orientation (start base = 1; no scale given)"
    head = (f"# frame: skyrig model frame, arbitrary origin and orientation (datum: inner constraints), {units}\n"
            "# rotation: world_from_camera as omega, phi, kappa (deg); camera x right, y up, z back\n")
    adj = res.adjustment
    b = adj.block
    ps = adj.pose_sigma if adj.pose_sigma is not None else np.full((b.n_images, 6), np.nan)
    o, p, k = opk_from_matrix(b.station_rotation, unit="deg")
    with atomic_write(out / "eo.csv", newline="") as fh:
        fh.write(head + "image,camera,x,y,z,omega,phi,kappa,sx,sy,sz\n")
        for i in range(b.n_images):
            c = b.station_centre[i]
            fh.write(f"{b.image_name[i]},{res.camera.name},{c[0]:.6f},{c[1]:.6f},{c[2]:.6f},{o[i]:.8f},{p[i]:.8f},"
                     f"{k[i]:.8f},{ps[i, 0]:.6f},{ps[i, 1]:.6f},{ps[i, 2]:.6f}\n")
    sig = adj.point_sigma if adj.point_sigma is not None else np.full((b.n_points, 3), np.nan)
    role = np.full(b.n_points, "tie", dtype=object)
    if len(b.distance_point):
        role[np.unique(b.distance_point)] = "scale-bar end"
    with atomic_write(out / "points.csv", newline="") as fh:
        fh.write(head.splitlines()[0] + "\nname,x,y,z,sx,sy,sz,role\n")
        for q in range(b.n_points):
            x = b.point_xyz[q]
            fh.write(f"{b.point_name[q]},{x[0]:.6f},{x[1]:.6f},{x[2]:.6f},{sig[q, 0]:.6f},{sig[q, 1]:.6f},"
                     f"{sig[q, 2]:.6f},{role[q]}\n")


def compare_pycolmap(res: UavResult, images: str | Path | None, inp: Any, workdir: str | Path, max_image_size: int,
                     max_features: int, mapper: str) -> dict[str, Any]:
    """pycolmap's own pipeline on the same images; camera centres compared after a similarity (and, when the images
    have GPS, both fitted onto it).  ``mapper`` "incremental" falls back to "global" (GLOMAP) when COLMAP's
    incremental mapper registers fewer than half of the images (it cannot initialise on forward motion)."""
    from skyrig.match.colmap_check import reconstruct_with_pycolmap

    t1 = time.perf_counter()
    names = [str(n) for n in inp.names]
    focal = inp.camera.focal_mm / inp.camera.pixel_size_mm
    out: dict[str, Any] = {"mapper": mapper}
    _, summ = reconstruct_with_pycolmap(images, names, Path(workdir) / mapper, max_image_size=max_image_size,
                                        max_features=max_features, mapper=mapper, focal_px=focal)
    if mapper == "incremental" and (summ is None or len(summ.names) < 0.5 * len(names)):
        out["incremental_registered"] = 0 if summ is None else int(len(summ.names))
        out["mapper"] = "global (the incremental mapper registered fewer than half of the images)"
        _, summ = reconstruct_with_pycolmap(images, names, Path(workdir) / "global", max_image_size=max_image_size,
                                            max_features=max_features, mapper="global", focal_px=focal)
    if summ is None:
        out["registered"] = 0
        return out
    gnss = inp.positions
    from skyrig.orient.reference import centre_differences_in_sigma

    cmp = centre_differences_in_sigma(res, compare_with_reconstruction(res, summ.names, summ.centres, gnss))
    out.update(input="images", registered=int(len(summ.names)), points=summ.n_points, reprojection_rms_px=summ.reprojection_rms_px,
               wall_s=time.perf_counter() - t1, centre_differences=cmp)
    return out


def without_gps_left_out(metas: Sequence[Any], measurements: Any) -> tuple[list[Any], Any]:
    """Images without an EXIF GPS position (the first shots before a fix) left out of a GNSS-supported block, each
    named in a :class:`~skyrig.errors.PlausibilityWarning`, with their tie-point measurements; all of them when no
    image has one (then :func:`metadata_block_input` refuses, naming the first)."""
    import warnings

    from skyrig.errors import PlausibilityWarning
    from skyrig.georef.observations import ImageMeasurements

    ok = [bool(m.has_gps and m.alt_m is not None) for m in metas]
    if all(ok) or not any(ok):
        return list(metas), measurements
    for m, good in zip(metas, ok):
        if not good:
            warnings.warn(f"{m.path}: no EXIF GPS position with altitude: left out of the GNSS-supported adjustment",
                          PlausibilityWarning, stacklevel=2)
    kept = [m for m, good in zip(metas, ok) if good]
    names = np.array([m.name for m in kept], dtype=str)
    keep = np.isin(np.asarray(measurements.image, dtype=str), names)
    return kept, ImageMeasurements(np.asarray(measurements.point)[keep], np.asarray(measurements.image)[keep],
                                   np.asarray(measurements.pixel)[keep])
