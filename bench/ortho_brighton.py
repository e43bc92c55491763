"""Issue 11 real-image acceptance: brighton DJI block, orthomosaic from skyrig's orientations vs pycolmap's.

Both mosaics are made by the same code (``skyrig ortho``) on the same DSM (``dsm_small/dsm.tif`` of the
earlier session) and the same camera (``camera_small.yaml``); only the exterior orientations differ:

(a) skyrig ``adjust-uav`` (``adjust-uav-keep/eo.csv``);
(b) pycolmap (COLMAP): SIFT, exhaustive matching, incremental mapping of the same 800 x 450 images with the
    camera FIXED to ``camera_small.yaml`` (COLMAP ``FULL_OPENCV``), brought into the frame of skyrig's eo.csv by a
    similarity transform (``pycolmap.estimate_sim3d``) of its projection centres onto
    ``gps``: the EXIF GPS positions (EXIF altitude as EGM96 height, as skyrig's run took it; h = H + N), i.e.
    pycolmap's own datum; ``aligned``: skyrig's projection centres (a change of datum only; 7 parameters cannot
    change the model's shape).

The offset between the mosaics is measured per tile (masked template matching of grey tiles where both are
valid), in the images' ground sample distance (focal length and median height above the DSM).  pycolmap is
georeferenced only through GPS (metres absolute; with three strips and ~1 m GPS height noise its tilt is
uncertain by a degree or two), so ``gps`` differs from skyrig by a datum: a shift and a tilt.  A tilt of the
orientations over skyrig's DSM is not a constant shift of the mosaic (the height error it implies grows across
the block and moves cells by height error x tan(view angle)), so removing the median shift does not remove it.
The acceptance figure is the ``aligned`` mosaic's raw offset: the relative geometry of the two orientation sets.

``--chain DIR`` makes those inputs with the current tree instead of taking an earlier session's (each step cached
in DIR, rerun when its output is missing): ``skyrig match`` (``--match-size`` / ``--match-features``) and
``skyrig adjust-uav`` on the full-size images (project CRS: the UTM zone of the EXIF GPS; it must converge: a failed adjustment stops the bench), the images
downscaled by ``--image-scale`` (area averaging) with the adjusted camera scaled to them (same focal length and
principal point in mm, pixels ``1 / scale`` larger; OpenCV distortion coefficients are normalised, so they
stay), then ``skyrig dsm`` on the downscaled images with adjust-uav's tie points for the height range.

Run::

    .venv/bin/python bench/ortho_brighton.py            # cache in /tmp/h/F (pycolmap ~1 min, each mosaic ~3 min)
    .venv/bin/python bench/ortho_brighton.py --cache DIR --figures docs/figures
    nice .venv/bin/python bench/ortho_brighton.py --chain /tmp/brighton --cache /tmp/brighton/F --figures DIR --png

Prints the figures and writes ``DIR/result.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "brighton-uav"
PREV = Path(os.environ.get("SKYRIG_BRIGHTON_ACC", "/tmp/skyrig-acc/brighton"))
CACHE = Path("/tmp/h/F")


# ---------------------------------------------------------------------------------------------- inputs
def inputs(prev: Path = PREV) -> dict[str, Path]:
    """Paths of the earlier session's products this bench builds on (raises FileNotFoundError naming the missing)."""
    p = {"images": prev / "small", "camera": prev / "camera_small.yaml", "eo": prev / "adjust-uav-keep" / "eo.csv",
         "dsm": prev / "dsm_small" / "dsm.tif"}
    p["gps_images"] = DATA  # the downscaled copies carry no EXIF: GPS from the originals (same names)
    missing = [str(v) for v in p.values() if not v.exists()]
    if missing:
        raise FileNotFoundError("missing inputs: " + ", ".join(missing))
    return p


def _skyrig(*args: str) -> None:
    exe = ROOT / ".venv" / "bin" / "skyrig"
    # (skyrig.cli has no __main__: without the project's venv, its console-script entry point run directly)
    cmd = [str(exe), *args] if exe.exists() else [sys.executable, "-c", "import sys; from skyrig.cli import main; "
                                                  "sys.exit(main())", *args]
    print("$ skyrig " + " ".join(args), flush=True)
    subprocess.run(cmd, check=True)


def chain(work: Path, data: Path = DATA, image_scale: float = 0.2, match_size: int = 640,
          match_features: int = 1500, crs: str | None = None) -> dict[str, Path]:
    """The bench's inputs made with the current tree in ``work`` (module docstring): match -> adjust-uav ->
    downscaled images + camera -> dsm.  Each step is skipped when its output exists.  Returns the paths
    :func:`inputs` returns."""
    import cv2
    import yaml

    work.mkdir(parents=True, exist_ok=True)
    if not (work / "match" / "manifest.json").exists():
        _skyrig("match", str(work), "--images", str(data), "--max-size", str(match_size), "--max-features",
                str(match_features), "-o", str(work / "match"))
    adj = work / "adjust-uav"
    if not (adj / "eo.csv").exists():
        _skyrig("adjust-uav", str(work), "--images", str(data), "--match", str(work / "match"),
                *(("--crs", crs) if crs else ()), "-o", str(adj))  # default: the UTM zone of the images' GNSS
    small = work / f"images_{image_scale:g}"
    names = sorted(p.name for p in data.iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    if not all((small / n).exists() for n in names):
        small.mkdir(exist_ok=True)
        for n in names:
            img = cv2.imread(str(data / n), cv2.IMREAD_COLOR)
            h, w = img.shape[:2]
            out = cv2.resize(img, (int(round(w * image_scale)), int(round(h * image_scale))), interpolation=cv2.INTER_AREA)
            tmp = small / f".{n}.tmp.jpg"
            cv2.imwrite(str(tmp), out, [cv2.IMWRITE_JPEG_QUALITY, 95])
            os.replace(tmp, small / n)
    cam_small = work / f"camera_{image_scale:g}.yaml"
    if not cam_small.exists():
        rig = yaml.safe_load((adj / "camera.yaml").read_text())
        for head in rig["heads"]:
            c = head["camera"]
            w, h = int(c["width_px"]), int(c["height_px"])
            ws, hs = int(round(w * image_scale)), int(round(h * image_scale))
            if abs(ws / w - hs / h) > 1e-9:
                raise RuntimeError(f"image scale {image_scale} gives {ws} x {hs} pixels: not the same factor on both axes")
            c["width_px"], c["height_px"] = ws, hs
            c["pixel_size_um"] = float(c["pixel_size_um"]) * w / ws
        rig["description"] = f"{rig.get('description', '')}; images downscaled by {image_scale:g} ({ws} x {hs})"
        tmp = cam_small.with_suffix(".tmp")
        tmp.write_text(yaml.safe_dump(rig, sort_keys=False))
        os.replace(tmp, cam_small)
    dsm = work / f"dsm_{image_scale:g}"
    if not (dsm / "dsm.tif").exists():
        _skyrig("dsm", "--eo", str(adj / "eo.csv"), "--camera", str(cam_small), "--images", str(small),
                "--points", str(adj / "points.csv"), "--executor", "serial", "--no-cloud", "-o", str(dsm))
    return {"images": small, "camera": cam_small, "eo": adj / "eo.csv", "dsm": dsm / "dsm.tif", "gps_images": data}


def gps_positions(image_dir: Path, names: list[str], frame: Any, geoid: str | None = None) -> NDArray[np.float64]:
    """EXIF GPS positions of ``names`` in ``frame`` (a :class:`skyrig.geodesy.frame.WorldFrame`), ``(N, 3)`` metres.

    EXIF ``GPSAltitude`` is taken as an EGM96 orthometric height (``h = H + N``), as ``skyrig adjust-uav`` did for
    the orientations compared with (``report.json``: ``altitude: egm96``).
    """
    from skyrig.geodesy.crs import Geoid, geodetic_to_ecef
    from skyrig.io.image_read import read_image_metadata
    from skyrig.pipeline.simulate import find_geoid

    metas = [read_image_metadata(image_dir / n) for n in names]
    lat = np.array([m.lat_deg for m in metas], float)
    lon = np.array([m.lon_deg for m in metas], float)
    alt = np.array([m.alt_m for m in metas], float)
    grid = geoid or find_geoid() or "us_nga_egm96_15.tif"
    h = alt + Geoid(grid).undulation(lat, lon)
    return np.asarray(frame.from_ecef(geodetic_to_ecef(lat, lon, h)), dtype=np.float64)


def colmap_full_opencv(cam: Any) -> tuple[int, int, list[float]]:
    """A skyrig :class:`FrameCamera` with ``opencv`` (or no) distortion as COLMAP ``FULL_OPENCV`` parameters.

    COLMAP's pixel origin is the corner of the top-left pixel (skyrig: its centre, +0.5); skyrig's principal point
    is in mm, y up, from the image centre.  The distortion coefficients are OpenCV's (normalised, y down) in both.
    """
    f = cam.focal_mm / cam.pixel_size_mm
    cx = (cam.width - 1) / 2.0 + cam.ppx_mm / cam.pixel_size_mm + 0.5
    cy = (cam.height - 1) / 2.0 - cam.ppy_mm / cam.pixel_size_mm + 0.5
    d = cam.distortion
    if getattr(d, "name", "none") not in ("none", "opencv"):
        raise ValueError(f"camera {cam.name!r}: distortion {d.name!r} has no COLMAP FULL_OPENCV equivalent")
    k = [float(getattr(d, n, 0.0)) for n in ("k1", "k2", "p1", "p2", "k3")]
    return cam.width, cam.height, [f, f, cx, cy, *k, 0.0, 0.0, 0.0]


# ---------------------------------------------------------------------------------------------- pycolmap
def reconstruct(image_dir: Path, names: list[str], cam: Any, work: Path) -> Any:
    """pycolmap SIFT + exhaustive matching + incremental mapping with the camera fixed; the largest model.

    Cached: a model already in ``work/sparse/model`` is loaded.
    """
    import pycolmap

    model_dir = work / "sparse" / "model"
    if (model_dir / "images.bin").exists():
        return pycolmap.Reconstruction(model_dir)
    try:
        pycolmap.logging.minloglevel = 2  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001
        pass
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    if db.exists():
        db.unlink()
    w, h, params = colmap_full_opencv(cam)
    ro = pycolmap.ImageReaderOptions()
    ro.camera_model = "FULL_OPENCV"
    ro.camera_params = ",".join(f"{v:.12g}" for v in params)
    eo = pycolmap.FeatureExtractionOptions()
    eo.use_gpu = False
    eo.num_threads = 2
    eo.max_image_size = max(w, h)
    pycolmap.extract_features(db, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=ro, extraction_options=eo, device=pycolmap.Device.cpu)
    mo = pycolmap.FeatureMatchingOptions()
    mo.use_gpu = False
    mo.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = 2
    opts.random_seed = 0
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    out = work / "sparse"
    out.mkdir(exist_ok=True)
    recs = pycolmap.incremental_mapping(db, image_dir, out, options=opts)
    if not recs:
        raise RuntimeError("pycolmap reconstructed nothing")
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    model_dir.mkdir(parents=True, exist_ok=True)
    rec.write(model_dir)
    return rec


def colmap_poses(rec: Any) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Per registered image: projection centre and ``world_from_camera`` rotation in skyrig's camera axes.

    COLMAP stores ``cam_from_world`` with the camera looking along +z, y down; skyrig's camera frame is x right,
    y up, z backwards (looking along -z): ``skyrig_cam = diag(1, -1, -1) colmap_cam``.
    """
    flip = np.diag([1.0, -1.0, -1.0])
    out = {}
    for img in rec.images.values():
        if not img.has_pose:
            continue
        cfw = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
        R_cw = np.asarray(cfw.rotation.matrix(), dtype=np.float64)
        t = np.asarray(cfw.translation, dtype=np.float64)
        out[img.name] = (-R_cw.T @ t, R_cw.T @ flip)
    return out


def georeference(poses: dict[str, tuple[NDArray, NDArray]], gps: dict[str, NDArray], frame: Any,
                 camera_name: str) -> tuple[Any, dict[str, Any]]:
    """Similarity (``pycolmap.estimate_sim3d``) of COLMAP's centres onto target positions per image name (GPS,
    or another orientation set's centres, in ``frame``); the model's orientations as a skyrig EO in ``frame``.

    Returns the :class:`ExteriorOrientations` and a summary (scale, rotation and translation of the similarity,
    residual RMS per axis at the targets, skyrig's own Umeyama fit as a cross-check of the transform).
    """
    import pycolmap

    from skyrig.georef.eo import ExteriorOrientations
    from skyrig.match.colmap_check import similarity_transform

    names = sorted(n for n in poses if n in gps)
    if len(names) < 3:
        raise RuntimeError(f"only {len(names)} images both registered and with GPS")
    C = np.array([poses[n][0] for n in names])
    G = np.array([gps[n] for n in names])
    o = G.mean(0)  # work relative to the GPS mean: UTM coordinates in float64 but well conditioned
    sim = pycolmap.estimate_sim3d(C, G - o)
    if sim is None:
        raise RuntimeError("pycolmap.estimate_sim3d failed")
    s = float(sim.scale)
    Rs = np.asarray(sim.rotation.matrix(), dtype=np.float64)
    ts = np.asarray(sim.translation, dtype=np.float64) + o
    s2, R2, t2 = similarity_transform(C, G - o)
    centres = s * C @ Rs.T + ts
    rot = np.array([Rs @ poses[n][1] for n in names])
    res = centres - G
    eo = ExteriorOrientations(np.array(names), camera_name, centres, rot, frame)
    info = {"images": len(names), "scale": s, "rotation": Rs.tolist(), "translation": ts.tolist(),
            "target_residual_rms_m": np.sqrt(np.mean(res**2, axis=0)).tolist(),
            "umeyama_check": {"scale_diff": abs(s2 - s), "rotation_diff_deg": float(np.degrees(np.arccos(
                np.clip((np.trace(R2.T @ Rs) - 1) / 2, -1, 1)))),
                "translation_diff_m": float(np.linalg.norm(t2 + o - ts))}}
    return eo, info


def reprojection_check(rec: Any, eo: Any, info: dict[str, Any], cam: Any) -> dict[str, float]:
    """COLMAP's 3D points, moved by the georeferencing similarity, projected with skyrig's camera model into the
    written skyrig orientations, against COLMAP's own keypoint observations (pixels, skyrig origin = COLMAP - 0.5).

    An independent check of the conversion (axes, rotation direction, pixel origin, distortion): a sign or axis
    error gives tens to hundreds of pixels, a right one COLMAP's reprojection error.
    """
    s = float(info["scale"])
    Rs = np.asarray(info["rotation"])
    ts = np.asarray(info["translation"])
    idx = {n: k for k, n in enumerate(eo.image)}
    res = []
    for img in rec.images.values():
        if not img.has_pose or img.name not in idx:
            continue
        obs = [(p2.xy, rec.points3D[p2.point3D_id].xyz) for p2 in img.points2D if p2.has_point3D()]
        if not obs:
            continue
        xy = np.array([o[0] for o in obs], dtype=np.float64) - 0.5
        X = s * np.array([o[1] for o in obs], dtype=np.float64) @ Rs.T + ts
        px = cam.world_to_pixel(eo.subset([idx[img.name]]).pose(), X)
        res.append(np.asarray(px) - xy)
    r = np.concatenate(res)
    return {"observations": int(len(r)), "rms_px": float(np.sqrt(np.mean(r**2))),
            "max_px": float(np.abs(r).max())}


# ---------------------------------------------------------------------------------------------- mosaics
def run_ortho(eo_csv: Path, inp: dict[str, Path], out: Path, resolution: float = 0.1) -> Path:
    """``skyrig ortho`` (the CLI, same options for both mosaics); cached when ``out/ortho.tif`` exists."""
    tif = out / "ortho.tif"
    if tif.exists():
        return tif
    cmd = [str(ROOT / ".venv" / "bin" / "skyrig"), "ortho", "--eo", str(eo_csv), "--camera", str(inp["camera"]),
           "--images", str(inp["images"]), "--dsm", str(inp["dsm"]), "--resolution", str(resolution),
           "-o", str(out)]
    exe = Path(cmd[0])
    if not exe.exists():
        cmd = [sys.executable, "-m", "skyrig.cli", *cmd[1:]]
    subprocess.run(cmd, check=True)
    return tif


def read_mosaic(path: Path) -> tuple[NDArray[np.float64], NDArray[np.bool_], Any, str]:
    """Grey values, valid mask, affine transform and CRS of an RGB orthomosaic GeoTIFF."""
    import rasterio

    with rasterio.open(path) as ds:
        rgb = ds.read().astype(np.float64)
        mask = ds.dataset_mask() > 0
        return rgb.mean(axis=0), mask, ds.transform, ds.crs.to_string()


def tile_offsets(a: NDArray[np.float64], va: NDArray[np.bool_], b: NDArray[np.float64], vb: NDArray[np.bool_],
                 tile: int = 192, search: int = 32, min_valid: float = 0.4, min_std: float = 3.0,
                 min_overlap: float = 0.6) -> NDArray[np.float64]:
    """Shift (dx, dy) in cells that moves ``b`` onto ``a``, per tile of ``tile`` cells (half-overlapping).

    The DSM of this block is sparse, so the mosaics have holes whose outline is nearly the same in both: phase
    correlation of filled tiles locks onto that common outline, and so does a masked template match that counts
    holes of ``a`` as mismatches (a bias towards zero shift).  Here each tile of ``b`` is searched over
    +-``search`` cells of ``a`` by the MEAN squared grey difference over the cells valid in both at each trial
    shift (sums of products by ``cv2.matchTemplate``), trial shifts overlapping less than ``min_overlap`` of the
    template's valid cells excluded; sub-cell by a parabola through the minimum.  Tiles with less than
    ``min_valid`` valid cells, grey std below ``min_std`` (no texture) or the minimum on the border of the
    search window (no reliable match) are dropped.

    Returns
    -------
    ``(K, 4)``: template column, row (top-left cell), dx, dy.
    """
    import cv2

    f32 = np.float32
    A = np.where(va, a, 0.0)
    Ma = va.astype(f32)
    both = va & vb
    H, W = a.shape
    rows = []

    def ccorr(img: NDArray, tpl: NDArray) -> NDArray:
        return cv2.matchTemplate(np.ascontiguousarray(img, f32), np.ascontiguousarray(tpl, f32), cv2.TM_CCORR)

    def vertex(p: float, q: float, r: float) -> float:
        den = p - 2.0 * q + r
        return 0.0 if den <= 0 else 0.5 * (p - r) / den

    for r0 in range(search, H - tile - search + 1, tile // 2):
        for c0 in range(search, W - tile - search + 1, tile // 2):
            mt = vb[r0:r0 + tile, c0:c0 + tile]
            if both[r0:r0 + tile, c0:c0 + tile].mean() < min_valid:
                continue
            t = np.where(mt, b[r0:r0 + tile, c0:c0 + tile], 0.0)
            if t[mt].std() < min_std:
                continue
            win = (slice(r0 - search, r0 + tile + search), slice(c0 - search, c0 + tile + search))
            sA, sM = A[win], Ma[win]
            m = mt.astype(f32)
            n = ccorr(sM, m)
            ssd = ccorr(sM, t * t) - 2.0 * ccorr(sA, t) + ccorr(sA * sA, m)
            res = np.where(n >= min_overlap * m.sum(), ssd / np.maximum(n, 1.0), np.inf)
            y, x = np.unravel_index(int(np.argmin(res)), res.shape)
            if not (0 < x < res.shape[1] - 1 and 0 < y < res.shape[0] - 1):
                continue
            nb = res[y - 1:y + 2, x - 1:x + 2]
            if not np.all(np.isfinite(nb)):
                continue
            fx = vertex(res[y, x - 1], res[y, x], res[y, x + 1])
            fy = vertex(res[y - 1, x], res[y, x], res[y + 1, x])
            rows.append((c0, r0, x + fx - search, y + fy - search))
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def offset_stats(d: NDArray[np.float64], unit: float) -> dict[str, float]:
    """Median / RMS / max of the length of the ``(K, 2)`` shifts ``d`` (cells) times ``unit``."""
    L = np.hypot(d[:, 0], d[:, 1]) * unit
    return {"n": int(len(L)), "median": float(np.median(L)), "rms": float(np.sqrt(np.mean(L**2))),
            "max": float(L.max())}


def image_gsd_m(eo_csv: Path, camera_yaml: Path, dsm_tif: Path) -> float:
    """Ground sample distance of the nadir images: pixel / focal x median (camera height - median DSM height)."""
    import rasterio

    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.rig_file import read_rig

    eo = read_eo_csv(eo_csv)
    cam = next(iter(read_rig(camera_yaml).heads.values())).camera
    with rasterio.open(dsm_tif) as ds:
        z = ds.read(1, masked=True)
    ground = float(np.ma.median(z.compressed())) if z.count() else float("nan")
    return float(cam.pixel_size_mm / cam.focal_mm * np.median(eo.centre[:, 2] - ground))


def preview(tif: Path, jpg: Path, max_side: int = 900, max_bytes: int = 150_000) -> int:
    """A small JPEG preview of an RGB mosaic (cropped to its coloured cells, no-data white), written via
    temp-and-rename; its size in bytes."""
    import cv2
    import rasterio
    import rasterio.windows

    with rasterio.open(tif) as ds:
        rr, cc = np.nonzero(ds.dataset_mask() > 0)  # crop to the coloured cells
        win = rasterio.windows.Window(cc.min(), rr.min(), cc.max() - cc.min() + 1, rr.max() - rr.min() + 1)
        f = max(win.width, win.height) / max_side
        h, w = max(1, int(round(win.height / f))), max(1, int(round(win.width / f)))
        rgb = ds.read(out_shape=(3, h, w), window=win, resampling=rasterio.enums.Resampling.average)
        mask = ds.dataset_mask(out_shape=(h, w), window=win) > 0
    img = np.transpose(rgb, (1, 2, 0))[:, :, ::-1].copy()
    img[~mask] = 255
    jpg.parent.mkdir(parents=True, exist_ok=True)
    if jpg.suffix.lower() == ".png":  # lossless, sized by max_side only
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    else:
        for q in (85, 75, 65, 55, 45):
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, q])
            if ok and len(buf) <= max_bytes:
                break
    tmp = jpg.with_suffix(".tmp" + jpg.suffix)
    tmp.write_bytes(buf.tobytes())
    os.replace(tmp, jpg)
    return len(buf)


def dsm_coverage(dsm_tif: Path, mosaic_tif: Path) -> dict[str, float]:
    """Share of the mosaic's footprint (its valid cells' bounding box) where the DSM has a height, and of the
    DSM's own grid."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    with rasterio.open(mosaic_tif) as m:
        mask = m.dataset_mask() > 0
        T, crs, shape = m.transform, m.crs, mask.shape
    with rasterio.open(dsm_tif) as d:
        z = d.read(1).astype(np.float32)
        if d.nodata is not None:
            z[z == d.nodata] = np.nan
        own = float(np.isfinite(z).mean())
        out = np.full(shape, np.nan, np.float32)
        reproject(z, out, src_transform=d.transform, src_crs=d.crs, dst_transform=T, dst_crs=crs,
                  src_nodata=np.nan, dst_nodata=np.nan, resampling=Resampling.nearest)
    rr, cc = np.nonzero(mask)
    box = (slice(rr.min(), rr.max() + 1), slice(cc.min(), cc.max() + 1))
    return {"mosaic_cells_with_dsm": float(np.isfinite(out[mask]).mean()),
            "mosaic_box_with_dsm": float(np.isfinite(out[box]).mean()), "dsm_grid_measured": own}


# ---------------------------------------------------------------------------------------------- main
def _orientation_diff(eo: Any, ref: Any) -> dict[str, Any]:
    """Centre and rotation differences ``eo - ref`` over common images (rotation vector of
    ``R_eo R_ref^T`` in degrees, world axes): mean and scatter, per axis."""
    from scipy.spatial.transform import Rotation

    idx = {n: k for k, n in enumerate(ref.image)}
    ks = [(k, idx[n]) for k, n in enumerate(eo.image) if n in idx]
    dC = np.array([eo.centre[k] - ref.centre[j] for k, j in ks])
    rv = np.array([Rotation.from_matrix(eo.rotation[k] @ ref.rotation[j].T).as_rotvec(degrees=True) for k, j in ks])
    return {"centre_mean_m": dC.mean(0).tolist(), "centre_rms_m": np.sqrt(np.mean(dC**2, axis=0)).tolist(),
            "rotation_mean_deg": rv.mean(0).tolist(), "rotation_std_deg": rv.std(0).tolist()}


def mosaic_offsets(tif_a: Path, tif_b: Path, gsd: float, tile: int = 192) -> dict[str, Any]:
    """Per-tile offsets of mosaic ``b`` against mosaic ``a`` (same grid): raw, and relative (median removed).

    ``median_shift_m`` is the (east, north) shift in metres that moves ``b``'s content onto ``a``'s.
    """
    ga, va, Ta, crs_a = read_mosaic(tif_a)
    gb, vb, Tb, crs_b = read_mosaic(tif_b)
    if ga.shape != gb.shape or tuple(Ta) != tuple(Tb) or crs_a != crs_b:
        raise RuntimeError(f"the two mosaics are on different grids: {ga.shape} {Ta} vs {gb.shape} {Tb}")
    cell = float(Ta.a)
    off = tile_offsets(ga, va, gb, vb, tile=tile)
    if len(off) == 0:
        raise RuntimeError(f"no tile of {tif_b} matched in {tif_a}")
    d = off[:, 2:4]
    med = np.median(d, axis=0)
    return {"cell_m": cell, "tiles": int(len(off)),
            "valid_cells": {"a": int(va.sum()), "b": int(vb.sum()), "both": int((va & vb).sum())},
            "median_shift_m": [float(med[0] * cell), float(-med[1] * cell)],  # east, north (rows grow southwards)
            "raw_gsd": offset_stats(d, cell / gsd), "relative_gsd": offset_stats(d - med, cell / gsd),
            "offsets_cells": off.tolist()}


def predicted_offsets(off: NDArray[np.float64], tile: int, mosaic_b: Path, dsm_tif: Path, eo_a: Any,
                      geo_b: dict[str, Any], geo_a: dict[str, Any]) -> NDArray[np.float64]:
    """Offsets (dx, dy cells, moving ``b`` onto ``a``) the datum difference of two georeferencings of one model
    predicts per tile, from geometry alone (no image content).

    ``b``'s mosaic colours ground point P (tile centre, DSM height) from the image pixel at which its EO sees P;
    with ``a``'s EO that pixel looks along the ray from the image's centre through ``T^-1(P)`` (T maps ``a``'s
    frame to ``b``'s through the common model: ``geo_a``, ``geo_b`` are the two similarities from the COLMAP
    frame), which meets the tile's DSM height at H: ``a``'s mosaic shows that content at H.  The source image
    is the one giving most of the tile's cells in ``b``'s mosaic (``ortho_source.tif``, ``ortho.json``).
    """
    import rasterio

    sa, Ra, ta = float(geo_a["scale"]), np.asarray(geo_a["rotation"]), np.asarray(geo_a["translation"])
    sb, Rb, tb = float(geo_b["scale"]), np.asarray(geo_b["rotation"]), np.asarray(geo_b["translation"])
    names = json.loads((mosaic_b.parent / "ortho.json").read_text())["images"]
    idx = {n: k for k, n in enumerate(eo_a.image)}
    with rasterio.open(mosaic_b.parent / "ortho_source.tif") as ds:
        src, T = ds.read(1), ds.transform
    with rasterio.open(dsm_tif) as ds:
        dsm, Td, nod = ds.read(1).astype(np.float64), ds.transform, ds.nodata
    if nod is not None:
        dsm[dsm == nod] = np.nan
    out = []
    for c0, r0, _, _ in off:
        c0, r0 = int(c0), int(r0)
        s_tile = src[r0:r0 + tile, c0:c0 + tile]
        k = np.bincount(s_tile[s_tile >= 0].ravel()).argmax()
        rr, cc = np.mgrid[r0:r0 + tile:4, c0:c0 + tile:4]
        xs, ys = rasterio.transform.xy(T, rr.ravel(), cc.ravel())
        dr, dc = rasterio.transform.rowcol(Td, xs, ys)
        dr, dc = np.asarray(dr), np.asarray(dc)
        ok = (dr >= 0) & (dr < dsm.shape[0]) & (dc >= 0) & (dc < dsm.shape[1])
        z = float(np.nanmedian(dsm[dr[ok], dc[ok]]))
        x, y = rasterio.transform.xy(T, r0 + tile / 2 - 0.5, c0 + tile / 2 - 0.5)
        P = np.array([x, y, z])
        Q = sa * Ra @ (Rb.T @ (P - tb) / sb) + ta
        C = eo_a.centre[idx[names[k]]]
        Hh = C + (z - C[2]) / (Q[2] - C[2]) * (Q - C)
        out.append(((Hh[0] - x) / T.a, -(Hh[1] - y) / T.a))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def compare(cache: Path = CACHE, prev: Path = PREV, figures: Path | None = None, tile: int = 192,
            inp: dict[str, Path] | None = None, png: bool = False) -> dict[str, Any]:
    """The whole acceptance: pycolmap model, its EO in skyrig's frame two ways, the mosaics, offsets.

    ``gps``: pycolmap's model georeferenced to the EXIF GPS positions (its own datum).  ``aligned``: the same model
    mapped by a similarity onto skyrig's projection centres (7 parameters, a change of datum only: it cannot
    change the model's shape), so the mosaic offset is what the two orientation sets differ in beyond the datum.
    """
    from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
    from skyrig.io.rig_file import read_rig

    inp = inp or inputs(prev)
    cache.mkdir(parents=True, exist_ok=True)
    eo_sky = read_eo_csv(inp["eo"])
    cam = next(iter(read_rig(inp["camera"]).heads.values())).camera
    names = sorted(p.name for p in inp["images"].iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    rec = reconstruct(inp["images"], names, cam, cache / "pycolmap")
    poses = colmap_poses(rec)
    G = gps_positions(inp["gps_images"], names, eo_sky.frame)
    gsd = image_gsd_m(inp["eo"], inp["camera"], inp["dsm"])
    tif_a = run_ortho(inp["eo"], inp, cache / "ortho_skyrig")
    result: dict[str, Any] = {
        "images": len(names), "pycolmap_registered": len(poses), "pycolmap_points": int(len(rec.points3D)),
        "pycolmap_reprojection_px": float(rec.compute_mean_reprojection_error()),
        "image_gsd_m": gsd, "tile_cells": tile, "mosaics": {"skyrig": str(tif_a)},
    }
    targets = {"gps": dict(zip(names, G)), "aligned": dict(zip(eo_sky.image, eo_sky.centre))}
    for key, tgt in targets.items():
        eo_col, geo = georeference(poses, tgt, eo_sky.frame, str(eo_sky.camera[0]))
        eo_csv_col = cache / f"eo_pycolmap_{key}.csv"
        write_eo_csv(eo_col, eo_csv_col)
        tif_b = run_ortho(eo_csv_col, inp, cache / f"ortho_pycolmap_{key}")
        result[key] = {"georeference": {k: v for k, v in geo.items() if k not in ("rotation", "translation")},
                       "reprojection_skyrig_camera": reprojection_check(rec, eo_col, geo, cam),
                       "orientation_minus_skyrig": _orientation_diff(eo_col, eo_sky),
                       "mosaic": mosaic_offsets(tif_a, tif_b, gsd, tile), "eo": str(eo_csv_col)}
        result["mosaics"][f"pycolmap_{key}"] = str(tif_b)
    # the GPS variant's offsets, predicted from the two datums alone (is the tilt the whole story?)
    geo_g = georeference(poses, targets["gps"], eo_sky.frame, "x")[1]
    geo_s = georeference(poses, targets["aligned"], eo_sky.frame, "x")[1]
    mg = result["gps"]["mosaic"]
    offg = np.asarray(mg["offsets_cells"])
    pred = predicted_offsets(offg, tile, Path(result["mosaics"]["pycolmap_gps"]), inp["dsm"], eo_sky, geo_g, geo_s)
    mg["predicted_from_datum"] = {"residual_gsd": offset_stats(offg[:, 2:4] - pred, mg["cell_m"] / gsd),
                                  "predicted_gsd": offset_stats(pred, mg["cell_m"] / gsd)}
    result["acceptance"] = {"figure": "aligned.mosaic.raw_gsd.rms",
                            "value": result["aligned"]["mosaic"]["raw_gsd"]["rms"], "limit": 1.0}
    result["inputs"] = {k: str(v) for k, v in inp.items()}
    result["dsm_coverage"] = dsm_coverage(inp["dsm"], tif_a)
    if figures is not None:
        ext = "png" if png else "jpg"
        result["previews_bytes"] = {
            "skyrig": preview(tif_a, figures / f"brighton_ortho_skyrig.{ext}"),
            "pycolmap": preview(Path(result["mosaics"]["pycolmap_aligned"]), figures / f"brighton_ortho_pycolmap.{ext}")}
    tmp = cache / "result.json.tmp"
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, cache / "result.json")
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--prev", type=Path, default=PREV, help="folder of the earlier session's brighton products")
    ap.add_argument("--figures", type=Path, default=ROOT / "docs" / "figures")
    ap.add_argument("--tile", type=int, default=192)
    ap.add_argument("--fresh", action="store_true", help="drop the cached pycolmap model and mosaics first")
    ap.add_argument("--chain", type=Path, help="make the inputs with the current tree in this folder (module docstring)")
    ap.add_argument("--image-scale", type=float, default=0.2, help="--chain: image (and camera) scale of dsm / ortho")
    ap.add_argument("--match-size", type=int, default=640, help="--chain: skyrig match --max-size")
    ap.add_argument("--match-features", type=int, default=1500, help="--chain: skyrig match --max-features")
    ap.add_argument("--png", action="store_true", help="previews as PNG (default JPEG)")
    a = ap.parse_args()
    if a.fresh:
        for sub in ("pycolmap", "ortho_skyrig", "ortho_pycolmap_gps", "ortho_pycolmap_aligned"):
            shutil.rmtree(a.cache / sub, ignore_errors=True)
    inp = chain(a.chain, image_scale=a.image_scale, match_size=a.match_size,
                match_features=a.match_features) if a.chain else None
    r = compare(a.cache, a.prev, a.figures, a.tile, inp=inp, png=a.png)
    print(f"DSM coverage: {100 * r['dsm_coverage']['mosaic_box_with_dsm']:.1f} % of the mosaic's box, "
          f"{100 * r['dsm_coverage']['mosaic_cells_with_dsm']:.1f} % of its coloured cells")
    print(f"pycolmap: {r['pycolmap_registered']}/{r['images']} images, {r['pycolmap_points']} points, mean "
          f"reprojection {r['pycolmap_reprojection_px']:.3f} px (camera fixed to skyrig's)")
    print(f"image GSD {r['image_gsd_m']:.4f} m; offsets per tile of {r['tile_cells']} cells (half-overlapping, "
          "masked template matching, where both mosaics are valid)")
    for key, what in (("gps", "georeferenced to EXIF GPS"), ("aligned", "similarity onto skyrig's centres")):
        v = r[key]
        g, o, m = v["georeference"], v["orientation_minus_skyrig"], v["mosaic"]
        print(f"[{key}] pycolmap {what}: sim3 scale {g['scale']:.4f}, residual RMS E/N/U "
              f"{np.round(g['target_residual_rms_m'], 3).tolist()} m")
        print(f"  COLMAP points via the written EO + skyrig camera: {v['reprojection_skyrig_camera']['rms_px']:.3f} px RMS")
        print(f"  minus skyrig: centres mean {np.round(o['centre_mean_m'], 2).tolist()} RMS "
              f"{np.round(o['centre_rms_m'], 2).tolist()} m; rotation mean {np.round(o['rotation_mean_deg'], 3).tolist()}"
              f" std {np.round(o['rotation_std_deg'], 3).tolist()} deg")
        print(f"  mosaic: {m['tiles']} tiles, {m['cell_m']} m cells, median shift {np.round(m['median_shift_m'], 3).tolist()}"
              " m (E, N)")
        for k in ("raw_gsd", "relative_gsd"):
            s = m[k]
            print(f"  {k:13s} median {s['median']:.3f}  RMS {s['rms']:.3f}  max {s['max']:.3f} GSD")
    pr = r["gps"]["mosaic"]["predicted_from_datum"]
    print(f"[gps] offsets predicted from the datum difference alone (shift + tilt through the DSM): predicted RMS "
          f"{pr['predicted_gsd']['rms']:.3f} GSD; measured - predicted: median {pr['residual_gsd']['median']:.3f} "
          f"RMS {pr['residual_gsd']['rms']:.3f} max {pr['residual_gsd']['max']:.3f} GSD")
    acc = r["acceptance"]
    print(f"acceptance ({acc['figure']}): {acc['value']:.3f} GSD <= {acc['limit']}: {acc['value'] <= acc['limit']}")
    if "previews_bytes" in r:
        print(f"previews: {r['previews_bytes']}")


if __name__ == "__main__":
    main()
