"""Every real dataset through the user path, each with an ABSOLUTE check (issue 28): one table.

Usage::

    .venv/bin/python bench/real.py [--data ../shared/data] [--work /tmp/skyrig-real] [--datasets brighton,strecha]
        [--match-size 1600]

brighton (``brighton-uav``, 18 DJI Phantom 3 FC300S nadir images, GNSS only)
    ``skyrig match`` (guided pairs) -> ``skyrig adjust-uav`` with the defaults -> ``skyrig dsm`` on the images
    downscaled to 800 px (bench/ortho_brighton.py's chain).  Absolute checks, with the vertical reference of each
    number stated:

    - focal length against the camera's metadata (EXIF FocalLength 3.61 mm with the FC300S sensor width from the
      sensor database; the 35-mm value 20 mm gives 2,222 px by the 36-mm frame width rule): held or within 3 %;
    - the DSM's median height against the **take-off height** derived from the images: DJI writes EXIF GPSAltitude =
      XMP ``AbsoluteAltitude`` (above the EGM96 geoid) and XMP ``RelativeAltitude`` (above the take-off point), so
      take-off H = AbsoluteAltitude - RelativeAltitude (EGM96, median over the images), h = H + N with N from
      PROJ's EGM96 grid (``../shared/data/geoid/egm96_15.gtx``); the DSM is in ellipsoidal heights.  Goal: within 5 m.
    - also the run with the focal length freed (``focal="self"``; the old default freed it with a 10 % prior:
      3,134.6 px) for comparison.

strecha (``strecha-entry-p10``, 10 images 3072 x 2048 without any EXIF, ground-truth K, R, C)
    ``skyrig match`` (exhaustive) -> ``skyrig adjust-uav --no-gps`` with no camera given (the prior is 1.2 x the
    image width with 50 % sigma: there is no metadata), and pycolmap's own pipeline on the same images in the same
    run.  Absolute checks: the self-calibrated focal length against the ground truth's (fx 2,759.48, fy 2,764.16;
    goal within 0.5 % of 2,759.5) and principal point (goal within 10 px); camera centres against the ground truth
    after a similarity (7 parameters: the block has no datum) for skyrig and pycolmap (goal: skyrig <= 1.5 x
    pycolmap), rotations after the similarity's rotation (goal RMS <= 0.05 deg) and after the rotations' own best
    common rotation (the centres are nearly coplanar: the similarity's rotation carries its own error).

berlin (``opensfm/berlin``: 3 phone images, 10 ground points in an ODM ``gcp_list.txt``)
    ``skyrig match`` (exhaustive) -> ``skyrig adjust-uav --no-gps`` with half the points as control and half as
    check, then the roles swapped: the check points' errors in metres and over their predicted sigma.

lund (``opensfm/lund``: 29 phone images of a walk with EXIF GPS)
    ``skyrig adjust-uav --no-gps --datum gps-similarity --compare-pycolmap``: the only absolute reference is the
    phone's GPS, so the similarity's residuals are judged against the accuracy the EXIF states (GPSDOP).

ign (``ign-aerial-block``: 68 UltraCam images, GSD 5.7 cm)
    the library path of tests/test_adjust_ign.py (IGN's measurements, GNSS/IMU observations, 2 GCPs): the tie
    points against IGN's own adjusted coordinates, in GSD, next to the predicted precision.

Results go to ``WORK/real.json``; nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))


def _skyrig(*args: str) -> None:
    from ortho_brighton import _skyrig as run

    run(*args)


# ------------------------------------------------------------------------------------------------ brighton
def takeoff_height(images: Path, geoid: Path | None) -> dict[str, float]:
    """Take-off height from DJI metadata: EGM96 H (AbsoluteAltitude - RelativeAltitude, median) and ellipsoidal h."""
    from skyrig.geodesy.crs import Geoid
    from skyrig.io.image_read import list_images, read_image_metadata

    metas = [read_image_metadata(p) for p in list_images(images)]
    H = [m.alt_m - m.relative_alt_m for m in metas if m.alt_m is not None and m.relative_alt_m is not None]
    lat = statistics.median(m.lat_deg for m in metas)
    lon = statistics.median(m.lon_deg for m in metas)
    grid = str(geoid) if geoid is not None and geoid.exists() else "us_nga_egm96_15.tif"
    N = float(Geoid(grid).undulation(np.array([lat]), np.array([lon]))[0])
    Hm = float(np.median(H))
    return {"takeoff_egm96_m": Hm, "undulation_egm96_m": N, "takeoff_ellipsoidal_m": Hm + N,
            "spread_of_takeoff_m": float(np.ptp(H)), "images": len(H)}


def dsm_median(path: Path) -> float:
    import rasterio

    with rasterio.open(path) as d:
        a = d.read(1, masked=True)
    return float(np.ma.median(a))


def brighton(data: Path, work: Path, match_size: int) -> dict[str, Any]:
    from ortho_brighton import chain

    images = data / "brighton-uav"
    w = work / "brighton"
    out: dict[str, Any] = {}
    t0 = time.perf_counter()
    paths = chain(w, images, image_scale=0.2, match_size=match_size, match_features=8000)
    rep = json.loads((w / "adjust-uav" / "report.json").read_text())["uav"]
    focal = next(v for v in rep["calibration"] if v["name"] == "focal_mm")
    take = takeoff_height(images, data / "geoid" / "egm96_15.gtx")
    dsm_h = dsm_median(paths["dsm"])
    px = focal["pixel_size_mm"]
    out.update(focal_px=rep["focal_px"], focal_prior_px=focal["prior"] / px, focal_verdict=focal["verdict"],
               focal_held=focal["held"], focal_estimate_refused_px=focal["estimate"] / px,
               focal_z_prior=focal["z_prior"], dsm_median_ellipsoidal_m=dsm_h, **take,
               dsm_minus_takeoff_m=dsm_h - take["takeoff_ellipsoidal_m"], prior_source=rep["camera_prior_source"],
               focal_35mm_px=20.0 / 36.0 * 4000)
    # the old default: the focal length freed whatever the block can tell
    free = w / "adjust-uav-free"
    if not (free / "report.json").exists():
        cfg = w / "free.json"
        cfg.write_text(json.dumps({"focal": "self"}))
        _skyrig("adjust-uav", str(w), "--images", str(images), "--match", str(w / "match"), "--config", str(cfg),
                "-o", str(free))
    pts = np.loadtxt(free / "points.csv", delimiter=",", skiprows=1, usecols=3)
    held_pts = np.loadtxt(w / "adjust-uav" / "points.csv", delimiter=",", skiprows=1, usecols=3)
    rf = json.loads((free / "report.json").read_text())["uav"]
    out.update(free_focal_px=rf["focal_px"], free_ties_median_ellipsoidal_m=float(np.median(pts)),
               held_ties_median_ellipsoidal_m=float(np.median(held_pts)), wall_s=time.perf_counter() - t0)
    return out


# ------------------------------------------------------------------------------------------------ strecha
def read_strecha_cameras(folder: Path) -> dict[str, dict[str, Any]]:
    """Ground truth of strecha-entry-p10: ``name -> {K, R, C}``.

    The file's ``R`` is the camera -> world rotation (its columns are the camera's x right, y down, z forward axes in
    the world), not world -> camera as the folder README says: checked by projecting skyrig's tie points (moved
    into the ground truth's frame by a similarity of the centres) with ``K R^T (X - C)``: median 1.5 px, against
    2,800 px with ``K R (X - C)``."""
    out = {}
    for f in sorted((folder / "gt_dense_cameras").glob("*.camera")):
        v = np.array(f.read_text().split(), float)
        out[f.name.split(".")[0]] = {"K": v[0:9].reshape(3, 3), "R": v[12:21].reshape(3, 3), "C": v[21:24]}
    return out


def pose_similarity(centres: np.ndarray, world_from_cv: np.ndarray, G: np.ndarray, Rgt: np.ndarray,
                    sigma_centre_m: float = 0.01, sigma_rotation_deg: float = 0.05) -> dict[str, float]:
    """Centres and rotations after ONE similarity fitted to both (the poses): the rotation maximises
    ``tr(Rs^T M)`` with ``M = s / sc^2 sum dG dc^T + 1 / (2 sr^2) sum R_gt R^T`` (the weighted centre term of
    Umeyama's fit plus the chordal distance of the rotations: ``|Rs R - R_gt|_F^2 ~ 2 theta^2`` for small angles),
    the scale and translation then from the centres; three rounds.  ``sigma_*``: nominal weights, the same for every
    program compared (1 cm, 0.05 deg)."""
    c0, g0 = centres.mean(axis=0), G.mean(axis=0)
    dc, dg = centres - c0, G - g0
    s = float(np.sqrt(np.sum(dg ** 2) / np.sum(dc ** 2)))
    sr = np.radians(sigma_rotation_deg)
    rot = sum(Rgt[k] @ world_from_cv[k].T for k in range(len(G))) / (2 * sr ** 2)
    for _ in range(3):
        M = s * (dg.T @ dc) / sigma_centre_m ** 2 + rot
        U, _, Vt = np.linalg.svd(M)
        Rs = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        s = float(np.sum(dg * (dc @ Rs.T)) / np.sum(dc ** 2))
    t = g0 - s * Rs @ c0
    dC = np.linalg.norm(s * centres @ Rs.T + t - G, axis=1)
    ang = [np.degrees(np.arccos(np.clip((np.trace(Rgt[k].T @ Rs @ world_from_cv[k]) - 1) / 2, -1, 1)))
           for k in range(len(G))]
    return {"centre_rms_m": float(np.sqrt(np.mean(dC ** 2))), "centre_max_m": float(dC.max()),
            "rotation_rms_deg": float(np.sqrt(np.mean(np.square(ang)))), "rotation_max_deg": float(max(ang)),
            "sigma_centre_m": sigma_centre_m, "sigma_rotation_deg": sigma_rotation_deg}


def compare_with_truth(names: list[str], centres: np.ndarray, world_from_cv: np.ndarray,
                       gt: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Centres and rotations against the ground truth after a similarity (``world_from_cv``: ``(N, 3, 3)`` camera ->
    world rotations with OpenCV camera axes: x right, y down, z forward)."""
    from skyrig.match.colmap_check import similarity_transform

    G = np.array([gt[n]["C"] for n in names])
    s, Rs, t = similarity_transform(centres, G)
    dC = np.linalg.norm(s * centres @ Rs.T + t - G, axis=1)
    ang = []
    for k, n in enumerate(names):
        Rgt = gt[n]["R"]  # the file's R is world_from_cv (see read_strecha_cameras)
        D = Rgt.T @ (Rs @ world_from_cv[k])
        ang.append(np.degrees(np.arccos(np.clip((np.trace(D) - 1) / 2, -1, 1))))
    spread = float(np.sqrt(np.mean(np.sum((G - G.mean(axis=0)) ** 2, axis=1))))
    # the centres' similarity fixes the rotation from 10 nearly coplanar centres (singular values of their spread
    # about 31, 7 and 0.1 m): its own error (a few hundredths of a degree from millimetres of centre error) is
    # common to every image.  The rotations are also compared after their own best common rotation (the chordal
    # mean of R_gt R^T): what is left is the orientation's rotation error alone
    M = sum(gt[n]["R"] @ world_from_cv[k].T for k, n in enumerate(names))
    U, _, Vt = np.linalg.svd(M)
    Ra = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    own = [np.degrees(np.arccos(np.clip((np.trace(gt[n]["R"].T @ Ra @ world_from_cv[k]) - 1) / 2, -1, 1)))
           for k, n in enumerate(names)]
    gap = np.degrees(np.arccos(np.clip((np.trace(Rs.T @ Ra) - 1) / 2, -1, 1)))
    pose = pose_similarity(centres, world_from_cv, G, np.array([gt[n]["R"] for n in names]))
    return {"centre_rms_m": float(np.sqrt(np.mean(dC ** 2))), "centre_max_m": float(dC.max()),
            "pose_similarity": pose,
            "rotation_rms_deg": float(np.sqrt(np.mean(np.square(ang)))), "rotation_max_deg": float(max(ang)),
            "rotation_rms_own_alignment_deg": float(np.sqrt(np.mean(np.square(own)))),
            "alignments_differ_deg": float(gap), "scene_spread_m": spread, "images": len(names)}


def strecha(data: Path, work: Path, match_size: int) -> dict[str, Any]:
    from skyrig.match.colmap_check import reconstruct_with_pycolmap
    from skyrig.pipeline.uav import orient_without_gnss

    folder = data / "strecha-entry-p10"
    images = folder / "images"
    w = work / "strecha"
    gt = read_strecha_cameras(folder)
    if not (w / "match" / "manifest.json").exists():
        _skyrig("match", str(w), "--images", str(images), "--pairs", "exhaustive", "--max-size", str(match_size),
                "--max-features", "8000", "-o", str(w / "match"))
    t0 = time.perf_counter()
    res, rep = orient_without_gnss(images, w / "match", w / "adjust")
    t_sky = time.perf_counter() - t0
    k = np.flatnonzero(res.oriented)
    names = [str(res.names[i]).rsplit(".", 1)[0] for i in k]
    cv = np.diag([1.0, -1.0, -1.0])  # skyrig camera axes (x right, y up, z back) -> OpenCV's
    sky = compare_with_truth(names, res.centre[k], res.rotation[k] @ cv, gt)
    cam = res.camera
    fpx = cam.focal_mm / cam.pixel_size_mm
    pp = cam.principal_point_px
    K = np.mean([g["K"] for g in gt.values()], axis=0)
    out: dict[str, Any] = {"oriented": int(len(k)), "images": int(len(res.names)), "focal_px": fpx,
                           "focal_gt_fx_px": float(K[0, 0]), "focal_gt_fy_px": float(K[1, 1]),
                           "focal_error_pct_vs_2759.5": 100 * (fpx / 2759.5 - 1),
                           "pp_px": list(pp), "pp_gt_px": [float(K[0, 2]), float(K[1, 2])],
                           "pp_error_px": float(np.hypot(pp[0] - K[0, 2], pp[1] - K[1, 2])),
                           "skyrig": sky, "skyrig_wall_s": t_sky}
    t0 = time.perf_counter()
    jpgs = sorted(p.name for p in images.glob("*.jpg"))
    rec, summ = reconstruct_with_pycolmap(images, jpgs, w / "pycolmap", max_image_size=match_size,
                                          max_features=8000)
    t_col = time.perf_counter() - t0
    if rec is not None:
        pn, pc, pr = [], [], []
        for img in rec.images.values():
            if not img.has_pose:
                continue
            pn.append(img.name.rsplit(".", 1)[0])
            pc.append(np.asarray(img.projection_center()))
            pr.append(np.asarray(img.cam_from_world().rotation.matrix()).T)
        col = compare_with_truth(pn, np.array(pc), np.array(pr), gt)
        cams = list(rec.cameras.values())
        out.update(pycolmap=col, pycolmap_focal_px=float(cams[0].params[0]), pycolmap_wall_s=t_col,
                   centre_rms_ratio_skyrig_over_pycolmap=sky["centre_rms_m"] / col["centre_rms_m"])
    return out


# ------------------------------------------------------------------------------------------------ berlin
def berlin(data: Path, work: Path, match_size: int) -> dict[str, Any]:
    """OpenSfM berlin: 3 phone images and 10 ground points (ODM ``gcp_list.txt``, WGS 84 with heights of the
    file's own reference): half of them control, half check, then the roles swapped; the check points' errors in
    metres and against their predicted sigma (``ground_control.csv``: sx, sy, sz)."""
    from pyproj import Transformer

    folder = data / "opensfm" / "berlin"
    images = folder / "images"
    w = work / "berlin"
    w.mkdir(parents=True, exist_ok=True)
    if not (w / "match" / "manifest.json").exists():
        _skyrig("match", str(w), "--images", str(images), "--pairs", "exhaustive", "--max-size", str(match_size),
                "-o", str(w / "match"))
    from skyrig.io.odm import read_gcp_list

    gp, m = read_gcp_list(folder / "gcp_list.txt_from_commit_c7d5152_parent")  # WGS 84: x = longitude
    names = {n: f"g{k + 1:02d}" for k, n in enumerate(gp.name)}
    (w / "measurements.csv").write_text("point,image,column,row\n" + "".join(
        f"{names[p]},{i},{float(c)!r},{float(r)!r}\n" for p, i, (c, r) in zip(m.point, m.image, m.pixel)))
    t = Transformer.from_crs(4326, 32633, always_xy=True)
    rows = [(names[n], *t.transform(x, y), z) for n, (x, y, z) in zip(gp.name, gp.xyz)]
    out: dict[str, Any] = {"ground_points": len(rows), "runs": []}
    errs, zs = [], []
    for run in (0, 1):
        head = "# crs: EPSG:32633\nname,x,y,z\n"
        ctl = [r for k, r in enumerate(rows) if k % 2 == run]
        chk = [r for k, r in enumerate(rows) if k % 2 != run]
        for nm, sel in (("control", ctl), ("check", chk)):
            (w / f"{nm}{run}.csv").write_text(head + "".join(f"{a},{x:.3f},{y:.3f},{z:.3f}\n" for a, x, y, z in sel))
        o = w / f"adjust{run}"
        _skyrig("adjust-uav", str(w), "--images", str(images), "--match", str(w / "match"), "--no-gps", "--control",
                str(w / f"control{run}.csv"), "--check", str(w / f"check{run}.csv"), "--measurements",
                str(w / "measurements.csv"), "--control-sigma", "0.05", "-o", str(o))
        rep = json.loads((o / "report.json").read_text())
        gc = np.genfromtxt(o / "ground_control.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
        c = gc[gc["role"] == "check"]
        v = np.c_[c["vx"], c["vy"], c["vz"]]
        sg = np.c_[c["sx"], c["sy"], c["sz"]]
        errs.append(v)
        zs.append(v / sg)
        out["runs"].append({"control": [r[0] for r in ctl], "check_rms_m": rep["check"]["stats"]["rms_m"],
                            "left_out": rep["uav"].get("control_left_out", {}),
                            "focal_px": rep["uav"]["focal_px"], "focal_px_exif": rep["uav"]["focal_px_exif"]})
    v, z = np.vstack(errs), np.vstack(zs)
    out.update(check_points=int(len(v)), check_rms_m=np.sqrt(np.mean(v ** 2, axis=0)).tolist(),
               check_z_rms=np.sqrt(np.mean(z ** 2, axis=0)).tolist())
    return out


# ------------------------------------------------------------------------------------------------ lund
def lund(data: Path, work: Path, match_size: int) -> dict[str, Any]:
    """OpenSfM lund: 29 phone images of a walk, oriented without GNSS and placed by a similarity onto the EXIF GPS
    (never an observation); the only absolute reference is that GPS: the similarity's residuals against the
    accuracy the EXIF states (GPSDOP), next to pycolmap's own fit to the same GPS."""
    from orient_lund import _gps_precision

    images = data / "opensfm" / "lund" / "images"
    w = work / "lund"
    if not (w / "match" / "manifest.json").exists():
        _skyrig("match", str(w), "--images", str(images), "--pairs", "exhaustive", "--max-size", "1024",
                "--max-features", "4000", "-o", str(w / "match"))
    _skyrig("adjust-uav", str(w), "--images", str(images), "--match", str(w / "match"), "--no-gps", "--datum",
            "gps-similarity", "--compare-pycolmap", "--pycolmap-size", "1024", "-o", str(w / "orient"))
    rep = json.loads((w / "orient" / "report.json").read_text())
    s, d = rep["uav"], rep["uav"]["datum"]
    sig = np.array(list(s["centre_sigma_m"].values()))
    c = rep.get("pycolmap", {}).get("centre_differences", {})
    return {"images": s["images"], "oriented": s["oriented"], "focal_px": s["focal_px"],
            "focal_px_exif": s["focal_px_exif"], "gps_similarity_rms_3d_m": d.get("positions_similarity_rms_3d_m"),
            "pycolmap_gps_rms_3d_m": c.get("other_gnss_fit_rms_3d_m"), "pycolmap_registered": rep.get(
                "pycolmap", {}).get("registered"),
            "gps": _gps_precision(images, d, float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1)))))}


# ------------------------------------------------------------------------------------------------ IGN
def ign(data: Path, work: Path, match_size: int) -> dict[str, Any]:
    """The real IGN 68-image block (UltraCam Eagle, GSD 5.7 cm): the library path of tests/test_adjust_ign.py
    (IGN's measurements, orientations 3 m / 0.2 deg off as the start and as GNSS/IMU observations, the 2 GCPs
    as control) and the absolute check against IGN's own adjusted coordinates of 3,004 tie points (Lambert-93,
    ellipsoidal heights), in GSD, next to the adjustment's predicted precision."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_adjust_ign import GSD, _tie_differences, ign_block

    from skyrig.adjust import AdjustConfig, adjust

    t0 = time.perf_counter()
    conv, eo, world, block, frame, _ = ign_block(data / "ign-aerial-block")
    res = adjust(block, AdjustConfig())
    dv, k = _tie_differences(conv, world, frame, res)
    rms = np.sqrt(np.mean(dv ** 2, axis=0))
    pred = np.sqrt(np.mean(res.point_sigma[k] ** 2, axis=0))
    return {"tie_points": int(len(dv)), "images": int(block.n_images), "tie_rms_gsd": (rms / GSD).tolist(),
            "predicted_rms_gsd": (pred / GSD).tolist(), "rms_over_predicted": (rms / pred).tolist(),
            "sigma0": float(res.sigma0), "wall_s": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--work", type=Path, default=Path("/tmp/skyrig-real"))
    ap.add_argument("--datasets", default="brighton,strecha,berlin,lund,ign")
    ap.add_argument("--match-size", type=int, default=1600)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    a.work.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {}
    for ds in [d.strip() for d in a.datasets.split(",") if d.strip()]:
        fn = {"brighton": brighton, "strecha": strecha, "berlin": berlin, "lund": lund, "ign": ign}.get(ds)
        if fn is None:
            print(f"unknown dataset {ds!r}: brighton, strecha, berlin, lund, ign", file=sys.stderr)
            return 2
        results[ds] = fn(a.data, a.work, a.match_size)
    old = a.work / "real.json"  # the datasets not run this time keep their last results
    kept = json.loads(old.read_text()) if old.exists() else {}
    old.write_text(json.dumps({**kept, **results}, indent=1))
    print(f"\n{'dataset':10s} {'check':48s} {'skyrig':>14s} {'reference':>14s} {'goal':>16s}")
    if "brighton" in results:
        b = results["brighton"]
        rows = [("focal length (px)", f"{b['focal_px']:.1f}", f"{b['focal_prior_px']:.1f} (EXIF+DB)",
                 "held or 3 %"),
                ("  focal verdict", b["focal_verdict"] + (" (held)" if b["focal_held"] else ""),
                 f"z {b['focal_z_prior']:+.1f}", ""),
                ("  focal freed (focal: self) (px)", f"{b['free_focal_px']:.1f}", "", "(for comparison)"),
                ("DSM median height (ellipsoidal m)", f"{b['dsm_median_ellipsoidal_m']:.2f}",
                 f"{b['takeoff_ellipsoidal_m']:.2f}", "within 5 m"),
                ("  DSM - take-off (m)", f"{b['dsm_minus_takeoff_m']:+.2f}", "", ""),
                ("  take-off EGM96 H / N (m)", f"{b['takeoff_egm96_m']:.2f}", f"N {b['undulation_egm96_m']:+.2f}", ""),
                ("  tie-point median h: held / freed focal (m)", f"{b['held_ties_median_ellipsoidal_m']:.2f}",
                 f"{b['free_ties_median_ellipsoidal_m']:.2f}", "")]
        for r in rows:
            print(f"{'brighton':10s} {r[0]:48s} {r[1]:>14s} {r[2]:>14s} {r[3]:>16s}")
    if "strecha" in results:
        s = results["strecha"]
        p = s.get("pycolmap", {})
        rows = [("images oriented", f"{s['oriented']}/{s['images']}", f"{p.get('images', '-')}", "all"),
                ("focal length (px)", f"{s['focal_px']:.1f}", f"{s['focal_gt_fx_px']:.1f} (GT fx)",
                 "0.5 % of 2759.5"),
                ("  error vs 2759.5 (%)", f"{s['focal_error_pct_vs_2759.5']:+.3f}", "", ""),
                ("principal point error (px)", f"{s['pp_error_px']:.2f}", "", "<= 10 px"),
                ("centre RMS after similarity (m)", f"{s['skyrig']['centre_rms_m']:.4f}",
                 f"{p.get('centre_rms_m', float('nan')):.4f} (pycolmap)", "<= 1.5 x pycolmap"),
                ("  ratio skyrig / pycolmap", f"{s.get('centre_rms_ratio_skyrig_over_pycolmap', float('nan')):.2f}",
                 "", "<= 1.5"),
                ("rotation RMS after similarity (deg)", f"{s['skyrig']['rotation_rms_deg']:.4f}",
                 f"{p.get('rotation_rms_deg', float('nan')):.4f} (pycolmap)", "<= 0.05 deg"),
                ("  after the rotations' own alignment (deg)", f"{s['skyrig']['rotation_rms_own_alignment_deg']:.4f}",
                 f"{p.get('rotation_rms_own_alignment_deg', float('nan')):.4f} (pycolmap)", "<= 0.05 deg"),
                ("one similarity of the poses: centre RMS (m)",
                 f"{s['skyrig'].get('pose_similarity', {}).get('centre_rms_m', float('nan')):.4f}",
                 f"{p.get('pose_similarity', {}).get('centre_rms_m', float('nan')):.4f} (pycolmap)",
                 "<= 1.5 x pycolmap"),
                ("  and rotation RMS (deg)",
                 f"{s['skyrig'].get('pose_similarity', {}).get('rotation_rms_deg', float('nan')):.4f}",
                 f"{p.get('pose_similarity', {}).get('rotation_rms_deg', float('nan')):.4f} (pycolmap)",
                 "<= 0.05 deg"),
                ("  the two alignments differ by (deg)", f"{s['skyrig']['alignments_differ_deg']:.4f}", "", "")]
        for r in rows:
            print(f"{'strecha':10s} {r[0]:48s} {r[1]:>14s} {r[2]:>14s} {r[3]:>16s}")
    if "berlin" in results:
        b = results["berlin"]
        f3 = ", ".join
        rows = [("check points (2 runs, roles swapped)", str(b["check_points"]), f"{b['ground_points']} GCPs", ""),
                ("check RMS x, y, z (m)", f3(f"{v:.2f}" for v in b["check_rms_m"]), "GCP file", ""),
                ("check error / predicted sigma (RMS)", f3(f"{v:.2f}" for v in b["check_z_rms"]), "", "about 1"),
                ("ground points left out", str(sum(len(r["left_out"]) for r in b["runs"])), "", "0")]
        for r in rows:
            print(f"{'berlin':10s} {r[0]:48s} {r[1]:>14s} {r[2]:>14s} {r[3]:>16s}")
    if "lund" in results:
        x = results["lund"]
        g = x["gps"]
        rows = [("images oriented", f"{x['oriented']}/{x['images']}", f"{x['pycolmap_registered']} (pycolmap)", "all"),
                ("similarity onto EXIF GPS RMS 3D (m)", f"{x['gps_similarity_rms_3d_m']:.2f}",
                 f"{x['pycolmap_gps_rms_3d_m'] or float('nan'):.2f} (pycolmap)", "GPS accuracy"),
                ("  residual / stated GPS accuracy (RMS)", f"{g['residual_over_stated_accuracy_rms']:.2f}",
                 "GPSDOP " + "/".join(f"{v:g}" for v in g["gpsdop_m"]), "<= 1"),
                ("focal length (px)", f"{x['focal_px']:.1f}", f"{x['focal_px_exif']:.1f} (EXIF)", "")]
        for r in rows:
            print(f"{'lund':10s} {r[0]:48s} {r[1]:>14s} {r[2]:>14s} {r[3]:>16s}")
    if "ign" in results:
        x = results["ign"]
        f3 = ", ".join
        rows = [("tie points vs IGN's coordinates", str(x["tie_points"]), f"{x['images']} images", ""),
                ("  RMS x, y, z (GSD 5.7 cm)", f3(f"{v:.2f}" for v in x["tie_rms_gsd"]),
                 f3(f"{v:.2f}" for v in x["predicted_rms_gsd"]) + " pred", "0.3/0.3/0.75"),
                ("  RMS / predicted", f3(f"{v:.2f}" for v in x["rms_over_predicted"]), "", "0.6-1.4")]
        for r in rows:
            print(f"{'ign':10s} {r[0]:48s} {r[1]:>14s} {r[2]:>14s} {r[3]:>16s}")
    print(f"\nwritten {a.work / 'real.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
