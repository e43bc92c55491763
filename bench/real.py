"""Every real dataset through the user path, each with an ABSOLUTE check (issue 28): one table.

Usage::

    .venv/bin/python bench/real.py [--data ../shared/data] [--work /tmp/skyrig-real] [--datasets brighton,strecha]
        [--match-size 1600] [--reuse-matches]

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
    common rotation (the centres are nearly coplanar: the similarity's rotation carries its own error), and
    centres and rotations after ONE similarity fitted to the whole poses.  What limits the rotations: the same tie
    points oriented with the camera held at the ground truth's own K (the floor no self-calibration causes), the
    random part of each figure predicted from the adjustment's covariance, and whether the ground-truth poses fit
    the tie points (a delta chi-square against skyrig's poses, in a plain pinhole projection).  ``skyrig match``
    runs again each time unless ``--reuse-matches``.

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
                       gt: dict[str, dict[str, Any]]) -> dict[str, Any]:
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


def predicted_pose_similarity(res: Any, k: np.ndarray, G: np.ndarray, draws: int = 200,
                              seed: int = 1) -> dict[str, float]:
    """What the random error alone would make of :func:`pose_similarity`: poses drawn from the adjustment's own
    a-posteriori covariance of the centres and rotations (``sigma0^2 Qcc``, rotations perturbed on the right as
    skyrig's adjustment does), each compared with the estimate by the same one-similarity metric.  Mean and 90th
    percentile of the rotation and centre RMS over ``draws`` draws (centres scaled to metres by the similarity
    onto the ground truth ``G``)."""
    from skyrig.geometry.rotations import matrix_from_rotvec
    from skyrig.match.colmap_check import similarity_transform

    A = res.adjustment
    b = A.block
    ix = np.concatenate([A.layout.pose[b.image_station[q]] for q in range(b.n_images)])
    cov = A.sigma0 ** 2 * A.covariance.Qcc[np.ix_(ix, ix)]
    w, V = np.linalg.eigh(cov)  # the free network's datum defect: zero eigenvalues
    L = V * np.sqrt(np.clip(w, 0.0, None))
    s, _, _ = similarity_transform(res.centre[k], G)
    Cm = s * res.centre[k]
    cv = np.diag([1.0, -1.0, -1.0])
    Rm = res.rotation[k] @ cv
    rng = np.random.default_rng(seed)
    rot, cen, own = [], [], []
    for _ in range(draws):
        d = (L @ rng.standard_normal(len(ix))).reshape(-1, 6)
        Rp = np.array([res.rotation[k][q] @ matrix_from_rotvec(d[q, 3:]) @ cv for q in range(len(k))])
        ps = pose_similarity(Cm + s * d[:, :3], Rp, Cm, Rm)
        rot.append(ps["rotation_rms_deg"])
        cen.append(ps["centre_rms_m"])
        U, _, Vt = np.linalg.svd(sum(Rm[q] @ Rp[q].T for q in range(len(k))))  # the rotations' own alignment
        Ra = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        own.append(np.sqrt(np.mean([np.arccos(np.clip((np.trace(Rm[q].T @ Ra @ Rp[q]) - 1) / 2, -1, 1)) ** 2
                                    for q in range(len(k))])))
    return {"rotation_rms_deg": float(np.mean(rot)), "rotation_rms_p90_deg": float(np.percentile(rot, 90)),
            "centre_rms_m": float(np.mean(cen)), "rotation_rms_own_alignment_deg": float(np.degrees(np.mean(own))),
            "draws": draws}


def truth_consistency(ties: Path, gt: dict[str, dict[str, Any]], names: list[str], centres: np.ndarray,
                      world_from_cv: np.ndarray, max_px: float = 2.0) -> dict[str, float]:
    """Do the images' tie points agree with the ground-truth poses?  A plain pinhole ``K [R^T | -R^T C]`` (the
    ground truth's own K for every image, no skyrig camera code) triangulates every track with >= 2 views twice:
    with the ground-truth cameras and with the given poses (skyrig's, oriented with that same K).  On the tracks
    whose residuals all stay below ``max_px`` with the given poses, the residual sums of squares are compared:
    ``delta_chi2 = (SSE_gt - SSE) / sigma^2`` with ``sigma^2 = SSE / (2 n - 3 p - (6 I - 7))``.  Were the ground
    truth exact (and the tie points free of systematic error) it would be about ``6 I - 7`` (the pose unknowns
    beyond the similarity), and ``sqrt(delta_chi2 / (6 I - 7))`` says by how many formal sigmas per unknown the
    ground truth misses the images' own best fit."""
    from skyrig.io.points_csv import read_measurements_csv

    m = read_measurements_csv(ties)
    idx = {n: q for q, n in enumerate(names)}
    img = np.array([idx.get(str(x).rsplit(".", 1)[0], -1) for x in m.image])
    keep = img >= 0
    pt, img, uv = np.asarray(m.point)[keep], img[keep], np.asarray(m.pixel, float)[keep]
    order = np.argsort(pt, kind="stable")
    pt, img, uv = pt[order], img[order], uv[order]
    _, start, count = np.unique(pt, return_index=True, return_counts=True)

    def cameras(R: np.ndarray, C: np.ndarray) -> np.ndarray:
        return np.array([gt[n]["K"] @ np.hstack([R[q].T, -R[q].T @ C[q][:, None]]) for q, n in enumerate(names)])

    def residuals(P_all: np.ndarray) -> np.ndarray:
        out = np.full((len(pt), 2), np.nan)
        for s0, c in zip(start, count):
            if c < 2:
                continue
            sl = slice(s0, s0 + c)
            P, x = P_all[img[sl]], uv[sl]
            A = np.concatenate([x[:, :1, None] * P[:, 2:3] - P[:, 0:1], x[:, 1:2, None] * P[:, 2:3] - P[:, 1:2]],
                               axis=1).reshape(-1, 4)
            Xh = np.linalg.svd(A)[2][-1]
            X = Xh[:3] / Xh[3]
            for _ in range(4):  # Gauss-Newton on the reprojection error
                h = P[:, :, :3] @ X + P[:, :, 3]
                r = (x - h[:, :2] / h[:, 2:]).ravel()
                J = ((P[:, :2, :3] * h[:, 2, None, None] - h[:, :2, None] * P[:, 2:3, :3])
                     / h[:, 2, None, None] ** 2).reshape(-1, 3)
                X = X + np.linalg.lstsq(J, r, rcond=None)[0]
            h = P[:, :, :3] @ X + P[:, :, 3]
            out[sl] = x - h[:, :2] / h[:, 2:]
        return out

    r_gt = residuals(cameras(np.array([gt[n]["R"] for n in names]), np.array([gt[n]["C"] for n in names])))
    r_sk = residuals(cameras(world_from_cv, centres))
    track = np.repeat(np.arange(len(start)), count)
    bad = np.zeros(len(start), bool)
    np.logical_or.at(bad, track, ~(np.linalg.norm(r_sk, axis=1) < max_px))
    use = ~bad[track]
    n_obs, n_pts, n_img = int(use.sum()), int((~bad).sum()), len(names)
    sse, sse_gt = float(np.sum(r_sk[use] ** 2)), float(np.sum(r_gt[use] ** 2))
    dof_poses = 6 * n_img - 7
    s2 = sse / (2 * n_obs - 3 * n_pts - dof_poses)
    dchi = (sse_gt - sse) / s2
    return {"observations": n_obs, "tracks": n_pts, "sigma_px": float(np.sqrt(s2)),
            "sigma_with_truth_px": float(np.sqrt(sse_gt / (2 * n_obs - 3 * n_pts))),
            "delta_chi2": float(dchi), "expected_delta_chi2": dof_poses,
            "formal_sigmas_per_unknown": float(np.sqrt(max(dchi, 0.0) / dof_poses))}


def strecha(data: Path, work: Path, match_size: int, reuse_matches: bool = False) -> dict[str, Any]:
    """strecha-entry-p10 through the user path (module docstring).  ``skyrig match`` is rerun unless
    ``reuse_matches`` (a match folder kept from an older tree silently measures that tree's features: the bench's
    0.043 deg of 2026-11-29 came from features made before the row-factor fix of the downscaling).

    Besides the self-calibration from no prior knowledge, the same tie points are oriented with the camera held at
    the ground truth's own K (fx, fy, cx, cy; no distortion): what the rotations can reach when the camera is
    exactly known, i.e. the part of the difference to the ground truth that no self-calibration causes.  For
    both runs the random part of the one-similarity figures is predicted from the adjustment's own covariance
    (:func:`predicted_pose_similarity`), and :func:`truth_consistency` asks whether the ground-truth poses fit the
    tie points as well as skyrig's (known-K) poses do."""
    from skyrig.camera.aspect import camera_from_fx_fy
    from skyrig.match.colmap_check import reconstruct_with_pycolmap
    from skyrig.orient.incremental import OrientConfig
    from skyrig.pipeline.uav import orient_without_gnss

    folder = data / "strecha-entry-p10"
    images = folder / "images"
    w = work / "strecha"
    gt = read_strecha_cameras(folder)
    if reuse_matches is False or not (w / "match" / "manifest.json").exists():
        _skyrig("match", str(w), "--images", str(images), "--pairs", "exhaustive", "--max-size", str(match_size),
                "--max-features", "8000", "--overwrite", "-o", str(w / "match"))
    K = np.mean([g["K"] for g in gt.values()], axis=0)
    cv = np.diag([1.0, -1.0, -1.0])  # skyrig camera axes (x right, y up, z back) -> OpenCV's

    def judged(res: Any) -> tuple[dict[str, Any], list[str], np.ndarray]:
        k = np.flatnonzero(res.oriented)
        names = [str(res.names[i]).rsplit(".", 1)[0] for i in k]
        out = compare_with_truth(names, res.centre[k], res.rotation[k] @ cv, gt)
        out["predicted"] = predicted_pose_similarity(res, k, np.array([gt[n]["C"] for n in names]))
        return out, names, k

    t0 = time.perf_counter()
    res, rep = orient_without_gnss(images, w / "match", w / "adjust")
    t_sky = time.perf_counter() - t0
    sky, names, k = judged(res)
    known = camera_from_fx_fy("strecha-gt", 3072, 2048, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    res_k, _ = orient_without_gnss(images, w / "match", None, cfg=OrientConfig(self_calibration=()), camera=known)
    sky_k, names_k, kk = judged(res_k)
    sky_k["truth_consistency"] = truth_consistency(w / "match" / "tie_points.csv", gt, names_k, res_k.centre[kk],
                                                   res_k.rotation[kk] @ cv)
    cam = res.camera
    fpx = cam.focal_mm / cam.pixel_size_mm
    pp = cam.principal_point_px
    cal = {v["name"]: v for v in rep["uav"].get("calibration", [])}
    px_mm = cam.pixel_size_mm
    out: dict[str, Any] = {"oriented": int(len(k)), "images": int(len(res.names)), "focal_px": fpx,
                           "focal_gt_fx_px": float(K[0, 0]), "focal_gt_fy_px": float(K[1, 1]),
                           "focal_error_pct_vs_2759.5": 100 * (fpx / 2759.5 - 1),
                           "pp_px": list(pp), "pp_gt_px": [float(K[0, 2]), float(K[1, 2])],
                           "pp_error_px": float(np.hypot(pp[0] - K[0, 2], pp[1] - K[1, 2])),
                           "pp_sigma_px": [cal[n]["sigma"] / px_mm if n in cal else float("nan")
                                           for n in ("ppx_mm", "ppy_mm")],
                           "skyrig": sky, "skyrig_wall_s": t_sky, "skyrig_known_k": sky_k}
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
    ap.add_argument("--reuse-matches", action="store_true",
                    help="strecha: keep a match folder from an earlier run (default: match again with this tree)")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    a.work.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {}
    for ds in [d.strip() for d in a.datasets.split(",") if d.strip()]:
        fn: Any = {"brighton": brighton, "strecha": strecha, "berlin": berlin, "lund": lund, "ign": ign}.get(ds)
        if fn is None:
            print(f"unknown dataset {ds!r}: brighton, strecha, berlin, lund, ign", file=sys.stderr)
            return 2
        results[ds] = (fn(a.data, a.work, a.match_size, reuse_matches=a.reuse_matches) if ds == "strecha"
                       else fn(a.data, a.work, a.match_size))
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
        if "predicted" in s["skyrig"]:
            kk, pk, pr = s["skyrig_known_k"], s["skyrig_known_k"]["predicted"], s["skyrig"]["predicted"]
            tc = kk["truth_consistency"]
            rows += [("  principal point sigma x, y (px)", ", ".join(f"{v:.2f}" for v in s["pp_sigma_px"]), "", ""),
                     ("  predicted from the covariance (deg)", f"{pr['rotation_rms_deg']:.4f}",
                      f"p90 {pr['rotation_rms_p90_deg']:.4f}", "random part"),
                     ("camera held at the GT's own K: pose rot. (deg)",
                      f"{kk['pose_similarity']['rotation_rms_deg']:.4f}", f"pred. {pk['rotation_rms_deg']:.4f}",
                      "floor"),
                     ("  and centre RMS (m)", f"{kk['pose_similarity']['centre_rms_m']:.4f}",
                      f"pred. {pk['centre_rms_m']:.4f}", ""),
                     ("GT poses vs tie points (GT K): delta chi2", f"{tc['delta_chi2']:.0f}",
                      f"{tc['expected_delta_chi2']} if exact", ""),
                     ("  sigma per axis: skyrig / GT poses (px)", f"{tc['sigma_px']:.3f}",
                      f"{tc['sigma_with_truth_px']:.3f}", "")]
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
