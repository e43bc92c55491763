"""Orientation without GNSS on a real image set: the 29 OpenSfM lund phone images (a walk), their EXIF GPS ignored
by the orientation, oriented end to end from the CLI (``skyrig adjust-uav --no-gps --compare-pycolmap``).

Usage::

    .venv/bin/python bench/orient_lund.py [--data ../shared/data] [--work /tmp/skyrig-bench-orient-lund]
        [--max-size 1024] [--max-features 4000] [--mapper incremental] [--fresh]

In one run:

1. ``skyrig match`` with **exhaustive** pairs (no GPS-neighbour pair selection: nothing of the GPS enters) into
   ``WORK/match`` (features and matches cached there; ``--fresh`` redoes them);
2. ``skyrig adjust-uav WORK --images LUND --no-gps --datum gps-similarity --compare-pycolmap``: two-view start,
   resection, bundle adjustment with self-calibration and inner constraints; the EXIF GPS only places the finished
   block by a similarity (never an observation), whose residuals are the check against GPS; pycolmap's own pipeline
   (SIFT, exhaustive matching, COLMAP's incremental mapper, GLOMAP's global mapper when the incremental one
   registers fewer than half of the images) on the same images in the same run, compared by camera centres after a
   similarity.

Then (unless ``--no-same-tracks``) pycolmap's incremental mapper on skyrig's own tie points
(:func:`skyrig.orient.reference.pycolmap_from_tracks`: the same measurements, the same EXIF start camera), compared
with skyrig's EO by centres after a similarity; and the GPS residuals against the EXIF's stated accuracy (GPSDOP).

Printed: images oriented, tie points, reprojection RMS, predicted centre sigma (RMS), similarity onto the EXIF GPS
(RMS / max, m), pycolmap registered images, its mapper, centre differences skyrig - pycolmap after a similarity
(RMS / max, m) and pycolmap's own similarity onto GPS; wall times.  Results in ``WORK/bench_orient_lund.json``.
Nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _gps_precision(images: Path, datum: dict, sigma_ours_m: float) -> dict:
    """The similarity's residuals against what the EXIF says of the GPS: ``GPSDOP`` (read as the stated position
    accuracy in metres, as OpenSfM does: 5 m for most lund images, 10 m for the first two), the altitude's
    resolution (whole metres) and repeated fixes (a phone that kept its last fix).  Our own predicted centre sigma
    (decimetres) is added in quadrature; the EXIF GPS, not the orientation, dominates these residuals."""
    from PIL import Image

    dop, fix = {}, {}
    for p in sorted(images.iterdir()):
        if p.suffix.lower() not in (".jpg", ".jpeg"):
            continue
        with Image.open(p) as im:
            g = im.getexif().get_ifd(0x8825)
        if 11 in g:
            dop[p.name] = float(g[11])
        fix[p.name] = (tuple(g.get(2, ())), tuple(g.get(4, ())), g.get(6))
    per = datum.get("per_image_m", {})
    z = np.array([per[n] / np.hypot(dop[n], sigma_ours_m) for n in per if n in dop])
    same = {}
    for n, f in fix.items():
        same.setdefault(f, []).append(n)
    repeated = sorted(n for v in same.values() if len(v) > 1 for n in v)
    return {"gpsdop_m": sorted(set(dop.values())), "images_with_dop": int(len(z)),
            "residual_over_stated_accuracy_rms": float(np.sqrt(np.mean(z ** 2))) if len(z) else None,
            "residual_over_stated_accuracy_max": float(z.max()) if len(z) else None,
            "share_within_1_stated": float(np.mean(z < 1)) if len(z) else None,
            "share_within_2_stated": float(np.mean(z < 2)) if len(z) else None,
            "repeated_gps_fixes": repeated,
            "note": "EXIF GPS of a phone: GPSDOP 5-10 (m, OpenSfM's reading), altitude in whole metres, repeated "
                    "fixes; our predicted centre sigma is about 20x smaller, so these residuals measure the GPS, "
                    "not the orientation: they can only reveal gross errors (a wrong image, a bent block)"}


def _same_tracks(images: Path, work: Path, rep: dict) -> dict:
    """pycolmap's incremental mapper on skyrig's own tie points (``WORK/match/tie_points.csv``, the measurements
    skyrig oriented), started from the same EXIF camera: the orientations compared by centres after a similarity."""
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.match.colmap_check import similarity_transform
    from skyrig.orient.reference import pycolmap_from_tracks
    from skyrig.pipeline.uav import orient_input

    inp = orient_input(images, read_measurements_csv(work / "match" / "tie_points.csv"), use_gps=False)
    t = time.perf_counter()
    # COLMAP's SIMPLE_RADIAL camera with the principal point kept (its defaults for a phone; a free OPENCV camera
    # diverges from the EXIF focal length, 38 % off, on the first pair); its registration thresholds relaxed for
    # skyrig's thin tracks (2625 tracks, 70 % of them two-view: with COLMAP's defaults 2 of 29 images register)
    relaxed = {"abs_pose_min_num_inliers": 15, "init_min_num_inliers": 50, "abs_pose_min_inlier_ratio": 0.1}
    peer = pycolmap_from_tracks(inp.names, inp.camera, inp.obs_track, inp.obs_image, inp.obs_pixel,
                                work / "pycolmap_tracks", init_min_tri_angle_deg=4.0, camera_model="SIMPLE_RADIAL",
                                refine_principal_point=False, mapper_options=relaxed)
    out: dict = {"wall_s": time.perf_counter() - t}
    if peer is None:
        return dict(out, registered=0)
    eo = read_eo_csv(work / "orient" / "eo.csv")
    ours = {str(n): np.asarray(c, float) for n, c in zip(eo.image, eo.centre)}
    com = [k for k, n in enumerate(peer.names) if n in ours]
    A, B = peer.C[com], np.array([ours[peer.names[k]] for k in com])
    s, Rm, tm = similarity_transform(A, B)
    d = np.linalg.norm(s * A @ Rm.T + tm - B, axis=1)
    sig = np.array([np.linalg.norm(rep["uav"]["centre_sigma_m"][peer.names[k]]) for k in com])
    return dict(out, **{k: v for k, v in peer.summary.items() if k not in ("camera_params",)},
                focal_px=peer.focal_px, common=len(com), rms_m=float(np.sqrt(np.mean(d ** 2))), max_m=float(d.max()),
                difference_over_sqrt2_sigma_rms=float(np.sqrt(np.mean((d / (np.sqrt(2) * sig)) ** 2))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
    ap.add_argument("--work", default="/tmp/skyrig-bench-orient-lund")
    ap.add_argument("--max-size", type=int, default=1024)
    ap.add_argument("--max-features", type=int, default=4000)
    ap.add_argument("--mapper", choices=["incremental", "global"], default="incremental")
    ap.add_argument("--fresh", action="store_true")
    ap.add_argument("--no-same-tracks", action="store_true",
                    help="skip pycolmap's incremental mapper on skyrig's own tie points")
    a = ap.parse_args()
    from click.testing import CliRunner

    from skyrig.cli import main as cli
    from skyrig.match.features import FeatureConfig
    from skyrig.match.matching import MatchConfig
    from skyrig.pipeline.match import match_images

    images = Path(a.data) / "opensfm" / "lund" / "images"
    if not images.is_dir():
        raise SystemExit(f"lund images not found at {images}")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    fc = FeatureConfig(method="pycolmap", max_size=a.max_size, max_features=a.max_features)
    mr = match_images([images], work / "match", fc, MatchConfig(matcher="bruteforce"), pair_mode="exhaustive",
                      overwrite=a.fresh)
    t_match = time.perf_counter() - t
    t = time.perf_counter()
    args = ["adjust-uav", str(work), "--images", str(images), "--match", str(work / "match"), "--no-gps",
            "--datum", "gps-similarity", "--compare-pycolmap", "--pycolmap-size", str(a.max_size),
            "--pycolmap-mapper", a.mapper, "-o", str(work / "orient")]
    r = CliRunner().invoke(cli, args)
    t_orient = time.perf_counter() - t
    print(r.output)
    if r.exit_code != 0:
        raise SystemExit(f"skyrig adjust-uav --no-gps exited {r.exit_code}")
    rep = json.loads((work / "orient" / "report.json").read_text())
    s = rep["uav"]
    d = s["datum"]
    sig = np.array(list(s["centre_sigma_m"].values()))
    out = {
        "command": "skyrig " + " ".join(args), "pairs": len(mr.pairs), "match_s": t_match, "orient_cli_s": t_orient,
        "images": s["images"], "oriented": s["oriented"], "not_oriented": s["not_oriented"],
        "tie_points": s["tie_points"], "reprojection_rms_px": s["reprojection_rms_px"], "sigma0": s["sigma0"],
        "focal_px": s["focal_px"], "focal_px_exif": s["focal_px_exif"], "seed": s["seed"],
        "centre_sigma_rms_3d_m": float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1)))),
        "gps_similarity": {k: d.get(k) for k in ("images_with_positions", "similarity_scale",
                                                 "positions_similarity_rms_3d_m", "positions_similarity_rms_xyz_m",
                                                 "positions_similarity_max_m")},
        "pycolmap": {k: v for k, v in rep.get("pycolmap", {}).items() if k != "centre_differences"},
    }
    out["gps_precision"] = _gps_precision(images, d, out["centre_sigma_rms_3d_m"])
    c = rep.get("pycolmap", {}).get("centre_differences")
    if c:
        out["centre_differences"] = {k: c[k] for k in ("common", "rms_m", "max_m", "rms_enu_m",
                                                       "other_gnss_fit_rms_3d_m", "ours_gnss_similarity_rms_3d_m")}
    if not a.no_same_tracks:
        out["pycolmap_same_tracks"] = _same_tracks(images, work, rep)
    print(json.dumps(out, indent=1))
    (work / "bench_orient_lund.json").write_text(json.dumps(out, indent=1))
    print(f"written {work / 'bench_orient_lund.json'}")


if __name__ == "__main__":
    main()
