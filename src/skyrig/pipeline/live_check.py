"""Checks of a live run (:mod:`skyrig.pipeline.live`) against the batch answer, for the acceptance figures of
issue 35 (``bench/live.py``), the slow test and the demo step.

* :func:`simulate_3k_flight` - paper 001's 3K triple rig (scenario ``3k``, CI size: 640-pixel sensors) flown as two
  strips of a chosen length, with boresight misalignments injected (the scenario has none) so that the online
  estimate has something to find;
* :func:`batch_boresight` - the batch calibration of the same flight: one rig adjustment of every exposure
  (tie points of all the images, GNSS/IMU, and the reference DEM's heights as in the live run, or the surveyed
  control points and their measurements), boresights free;
* :func:`batch_ortho` - the orthomosaic of all images (:func:`skyrig.dense.ortho.orthomosaic`) with the batch
  calibrated rig's direct georeferencing, onto the same reference plane as the live run;
* :func:`mosaic_offsets` - the live XYZ mosaic (finest zoom) against the batch ortho: phase-correlation offsets
  (OpenCV) of textured patches, in metres.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from skyrig.calibrate import online_boresight as ob
from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.dense.ortho import OrthoConfig, Orthomosaic, orthomosaic
from skyrig.georef.direct import direct_georeference
from skyrig.georef.eo import WorldFrame
from skyrig.georef.observations import ImageMeasurements
from skyrig.io import xyz_tiles
from skyrig.io.events_csv import read_events_csv
from skyrig.io.images import read_image
from skyrig.io.rig_file import read_rig
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.match.features import FeatureConfig

__all__ = ["INJECTED_BORESIGHT_DEG", "simulate_3k_flight", "true_corrections", "batch_boresight", "batch_ortho",
           "mosaic_offsets", "shared_observations", "difference_sigma"]

#: boresight misalignments injected into the 3K heads (roll, pitch, yaw in degrees; body axes of each head)
INJECTED_BORESIGHT_DEG = {"nadir": (0.02, -0.03, 0.05), "left": (-0.03, 0.02, -0.04), "right": (0.025, 0.015, 0.03)}


def simulate_3k_flight(outdir: str | Path, half_length_m: float = 2450.0, seed: int = 1, workers: int | None = None
                       ) -> dict[str, Any]:
    """Write a 3K flight folder (two strips of ``2 * half_length_m``; 2,450 m: 52 exposures, 156 images)."""
    from skyrig.pipeline.simulate import write_project
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    s = scenario_spec("3k", "ci", seed)
    fl = replace(s.flights[0], area=(-200.0, -half_length_m, 200.0, half_length_m))
    err = replace(s.errors, boresight_rpy_rad={h: tuple(np.radians(v)) for h, v in INJECTED_BORESIGHT_DEG.items()})
    ext = (-1800.0, -half_length_m - 1500.0, 1800.0, half_length_m + 1500.0)
    s = replace(s, flights=(fl,), errors=err, scene_extent=ext)
    survey = build_survey(s)
    info = write_project(survey, outdir, workers=workers)
    reference_dem(Path(outdir), "EPSG:25832")
    return {"exposures": int(len(set(survey.events_recorded.exposure_id.tolist()))),
            "images": int(len(survey.events_recorded)), "base_height_m": float(s.base_height_m), "info": info}


def reference_dem(folder: Path, crs: str, cell_m: float = 30.0, name: str = "reference_dem.tif") -> Path:
    """``folder/<name>``: the scene's surface (``scene/dsm.tif``, local ENU) resampled onto a ``cell_m``
    grid of ``crs`` with ellipsoidal heights (what a public 30 m DEM gives a real flight: coarse, buildings smeared
    over their cells)."""
    import json

    import rasterio

    from skyrig.georef.ground import Dem
    from skyrig.io.dem import write_dem

    local = WorldFrame.local(*json.loads((folder / "scene" / "scene.json").read_text())["frame"]["origin"])
    frame = WorldFrame.map(crs)
    with rasterio.open(folder / "scene" / "dsm.tif") as ds:
        z, t = ds.read(1).astype(np.float64), ds.transform
    ext = (t.c, t.f + t.e * z.shape[0], t.c + t.a * z.shape[1], t.f)
    corners = local.points_to(np.array([[ext[0], ext[1], 0.0], [ext[2], ext[3], 0.0], [ext[0], ext[3], 0.0],
                                        [ext[2], ext[1], 0.0]]), frame)
    x0, y0 = corners[:, 0].min() + cell_m, corners[:, 1].min() + cell_m
    x1, y1 = corners[:, 0].max() - cell_m, corners[:, 1].max() - cell_m
    cols, rows = int((x1 - x0) // cell_m), int((y1 - y0) // cell_m)
    xx, yy = np.meshgrid(x0 + (np.arange(cols) + 0.5) * cell_m, y1 - (np.arange(rows) + 0.5) * cell_m)
    # local positions of the cell centres, the scene's height there (mean over the cell), back to the map frame
    p = frame.points_to(np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 80.0)]), local)
    k = max(int(round(cell_m / t.a)), 1)
    zs = cv2_box(z, k)
    c = np.clip(((p[:, 0] - t.c) / t.a).astype(int), 0, z.shape[1] - 1)
    r = np.clip(((p[:, 1] - t.f) / t.e).astype(int), 0, z.shape[0] - 1)
    p[:, 2] = zs[r, c]
    h = local.points_to(p, frame)[:, 2].reshape(rows, cols)
    out = folder / name
    write_dem(out, Dem(h, (cell_m, 0.0, x0, 0.0, -cell_m, y1), frame))
    return out


def cv2_box(z: np.ndarray, k: int) -> np.ndarray:
    """Mean of ``z`` over ``k x k`` windows (OpenCV's box filter)."""
    import cv2

    return cv2.blur(z.astype(np.float32), (k, k)).astype(np.float64)


def true_corrections(folder: str | Path) -> dict[str, np.ndarray]:
    """The boresight corrections (rotation vectors, rad, camera axes) that turn the recorded rig into the true one
    (``truth/rig.yaml``): what the online and batch estimates should find."""
    from skyrig.geometry.rotations import rotvec_from_matrix

    folder = Path(folder)
    rec, tru = read_rig(folder / "rig.yaml"), read_rig(folder / "truth" / "rig.yaml")
    return {h.name: rotvec_from_matrix(h.boresight.T @ tru.heads[h.name].boresight) for h in rec}


def _flight(folder: Path, crs: str):
    traj = read_trajectory_csv(folder / "trajectory.csv")
    ev = read_events_csv(folder / "events.csv")
    rig = read_rig(folder / "rig.yaml")
    return traj, ev, rig, WorldFrame.map(crs)


def batch_boresight(folder: str | Path, crs: str, max_exposures: int | None = None,
                    dem_path: str | Path | None = None, dem_sigma_m: float = 2.0, n_features: int = 1500,
                    variance_components: bool | str = "image") -> ob.WindowEstimate:
    """The batch calibration: every exposure (or the first ``max_exposures``) in one rig adjustment with the tie
    points of all images (``n_features`` SIFT features per image) and either the reference heights of
    ``dem_path`` (the live run's observations, in one adjustment) or, without a DEM, the surveyed control points
    (``gcp/``) and their image measurements."""
    from skyrig.io.dem import read_dem
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv

    folder = Path(folder)
    traj, ev, rig, frame = _flight(folder, crs)
    if max_exposures is not None:
        keep = np.isin(ev.exposure_id, sorted(set(ev.exposure_id.tolist()))[:max_exposures])
        ev = ev.subset(np.flatnonzero(keep))
    eo = direct_georeference(traj, rig, ev, frame)
    cams = {h.camera.name: h.camera for h in rig}
    feats = {}

    def features(i: int):
        n = str(eo.image[i])
        if n not in feats:
            feats[n] = ob.features_of(read_image(folder / "images" / n),
                                      FeatureConfig(max_size=None, max_features=n_features))
        return feats[n]

    cross = [("nadir", h) for h in rig.heads if h != "nadir"]
    if dem_path is not None:
        dem = read_dem(dem_path)

        def height_at(x, y):
            return dem.sample(x, y)

        return ob.estimate_window(eo, cams, features, traj, rig, ev, height_at, dem_sigma_m, cross=cross, prefix="t",
                                  variance_components=variance_components)
    ties = ob.window_tie_points(eo, cams, features, ob.window_pairs(eo.exposure, eo.head, max_lag=1, cross=cross),
                                per_cell=2)
    gm = read_measurements_csv(folder / "gcp" / "image_measurements.csv")
    names = set(eo.image.tolist())
    sel = np.array([str(i) in names for i in gm.image])
    m = ImageMeasurements(np.concatenate([ties.point, gm.point[sel]]), np.concatenate([ties.image, gm.image[sel]]),
                          np.vstack([ties.pixel, gm.pixel[sel]]))
    gcp = read_points_csv(folder / "gcp" / "ground_points.csv", default_frame=frame)
    return ob.adjust_window(traj, rig, ev, m, None, height_sigma_m=1.0, control=gcp, control_sigma_m=0.02)


def shared_observations(online: Sequence[ImageMeasurements], batch: ImageMeasurements) -> float:
    """The share of the online windows' tie observations (image, pixel) that the batch adjustment also holds."""
    def keys(m: ImageMeasurements) -> set[tuple[str, float, float]]:
        return {(str(i), round(float(p[0]), 2), round(float(p[1]), 2)) for i, p in zip(m.image, m.pixel)}

    on = set().union(*(keys(m) for m in online)) if online else set()
    return len(on & keys(batch)) / len(on) if on else 0.0


def difference_sigma(sigma_online: np.ndarray, sigma_batch: np.ndarray, shared: float) -> np.ndarray:
    """Sigma of ``online - batch`` per angle when the online estimate shares the fraction ``shared`` of its
    observations' information with the batch (both least squares of one model):
    ``Var(d) = s_on^2 + s_b^2 - 2 Cov`` with ``Cov = C_on I_S C_b`` (``I_S``: information of the shared
    observations), ``I_S = shared * I_on`` gives ``s_on^2 + (1 - 2 shared) s_b^2``; ``shared`` = 1 is the nested
    case ``s_on^2 - s_b^2``, 0 the independent one ``s_on^2 + s_b^2``.  Never below ``|s_on - s_b|`` (``|Cov| <=
    s_on s_b``)."""
    so, sb = np.asarray(sigma_online, float), np.asarray(sigma_batch, float)
    return np.sqrt(np.maximum(so**2 + (1.0 - 2.0 * shared) * sb**2, (so - sb) ** 2))


def batch_ortho(folder: str | Path, crs: str, height_m: float, correction: dict[str, np.ndarray],
                cell_m: float, max_exposures: int | None = None, dem_path: str | Path | None = None) -> Orthomosaic:
    """The orthomosaic of every nadir image with the direct georeferencing of the rig corrected by ``correction``,
    onto the reference DEM ``dem_path`` (the plane at ``height_m`` outside it or without one)."""
    folder = Path(folder)
    traj, ev, rig, frame = _flight(folder, crs)
    if max_exposures is not None:
        keep = np.isin(ev.exposure_id, sorted(set(ev.exposure_id.tolist()))[:max_exposures])
        ev = ev.subset(np.flatnonzero(keep))
    eo = direct_georeference(traj, ob.rig_with_corrections(rig, correction), ev, frame)
    cams = {h.camera.name: h.camera for h in rig}
    c = eo.centre[:, :2]
    pad = 1500.0
    xmin, ymin = c.min(axis=0) - pad
    xmax, ymax = c.max(axis=0) + pad
    cs = 20.0
    w, h = int(np.ceil((xmax - xmin) / cs)), int(np.ceil((ymax - ymin) / cs))
    g = GridSpec(float(xmin), float(ymax), cs, w, h)
    xx, yy = np.meshgrid(xmin + (np.arange(w) + 0.5) * cs, ymax - (np.arange(h) + 0.5) * cs)
    hz = np.full((h, w), height_m)
    if dem_path is not None:
        from skyrig.io.dem import read_dem

        d = read_dem(dem_path).sample(xx, yy)
        hz = np.where(np.isfinite(d), d, hz)
    surf = DsmGrid(g, frame, hz.astype(np.float32), np.ones((h, w), np.int16),
                   np.full((h, w), np.nan, np.float32), np.ones((h, w), np.float32), np.zeros((h, w), bool),
                   "reference surface")
    sel = np.flatnonzero(eo.head == "nadir")
    eo_n = eo.subset(sel)
    c = eo_n.centre[:, :2]
    area = (float(c[:, 0].min() - 300), float(c[:, 1].min() - 200), float(c[:, 0].max() + 300),
            float(c[:, 1].max() + 200))
    return orthomosaic(eo_n, cams, surf, lambda i: read_image(folder / "images" / str(eo_n.image[i])), area=area,
                       config=OrthoConfig(cell_m=cell_m, square_buildings=False, balance=False))


def mosaic_offsets(tiles_root: str | Path, zoom: int, ortho: Orthomosaic, patch_px: int = 96,
                   min_valid: float = 0.98, min_std: float = 8.0) -> dict[str, Any]:
    """Offsets between the live mosaic (``tiles_root/ortho/<zoom>``) and ``ortho`` (reprojected onto the tiles'
    grid with rasterio): per textured patch of ``patch_px`` the phase-correlation shift (OpenCV), in metres on the
    ground (EPSG:3857 metres times the cosine of the latitude)."""
    import cv2
    from affine import Affine
    from rasterio.warp import Resampling, reproject

    root = Path(tiles_root) / "ortho" / str(zoom)
    xs = sorted(int(p.name) for p in root.iterdir())
    ys = sorted({int(p.stem) for d in root.iterdir() for p in d.glob("*.png")})
    x0, x1, y0, y1 = xs[0], xs[-1], ys[0], ys[-1]
    T = xyz_tiles.TILE_PX
    live = np.zeros(((y1 - y0 + 1) * T, (x1 - x0 + 1) * T, 4), np.uint8)
    for x in range(x0, x1 + 1):
        for y in range(y0, y1 + 1):
            t = xyz_tiles.read_tile(root / str(x) / f"{y}.png")
            if t is not None:
                live[(y - y0) * T:(y - y0 + 1) * T, (x - x0) * T:(x - x0 + 1) * T] = t
    b = xyz_tiles.tile_bounds(zoom, x0, y0)
    px = (b[2] - b[0]) / T
    dst_t = Affine(px, 0, b[0], 0, -px, b[3])
    grey = cv2.cvtColor(ortho.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    valid = ortho.valid.astype(np.float32)
    bat = np.zeros(live.shape[:2], np.float32)
    bval = np.zeros(live.shape[:2], np.float32)
    a, bb, c, d, e, f = ortho.grid.transform
    src_t = Affine(a, bb, c, d, e, f)
    reproject(grey, bat, src_transform=src_t, src_crs=ortho.frame.crs, dst_transform=dst_t, dst_crs="EPSG:3857",
              resampling=Resampling.bilinear)
    reproject(valid, bval, src_transform=src_t, src_crs=ortho.frame.crs, dst_transform=dst_t, dst_crs="EPSG:3857",
              resampling=Resampling.nearest)
    lg = cv2.cvtColor(live[..., :3], cv2.COLOR_RGB2GRAY).astype(np.float32)
    lv = live[..., 3] > 0
    lat = float(np.degrees(2 * np.arctan(np.exp((b[3]) / 6378137.0)) - np.pi / 2))
    ground = px * np.cos(np.radians(lat))
    win = cv2.createHanningWindow((patch_px, patch_px), cv2.CV_32F)
    shifts = []
    for r in range(0, live.shape[0] - patch_px, patch_px):
        for cc in range(0, live.shape[1] - patch_px, patch_px):
            sl = (slice(r, r + patch_px), slice(cc, cc + patch_px))
            if lv[sl].mean() < min_valid or (bval[sl] > 0.5).mean() < min_valid:
                continue
            p1, p2 = lg[sl], bat[sl]
            if p1.std() < min_std or p2.std() < min_std:
                continue
            (dx, dy), resp = cv2.phaseCorrelate(p2, p1, win)
            if resp < 0.2:
                continue
            shifts.append((dx, dy))
    s = np.asarray(shifts, dtype=np.float64).reshape(-1, 2) * ground
    n = np.linalg.norm(s, axis=1)
    return {"patches": int(len(s)), "tile_pixel_m": float(ground),
            "median_offset_m": float(np.median(n)) if len(n) else float("nan"),
            "p90_offset_m": float(np.percentile(n, 90)) if len(n) else float("nan"),
            "mean_shift_m": s.mean(axis=0).tolist() if len(s) else [float("nan")] * 2}
