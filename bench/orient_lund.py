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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
    ap.add_argument("--work", default="/tmp/skyrig-bench-orient-lund")
    ap.add_argument("--max-size", type=int, default=1024)
    ap.add_argument("--max-features", type=int, default=4000)
    ap.add_argument("--mapper", choices=["incremental", "global"], default="incremental")
    ap.add_argument("--fresh", action="store_true")
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
    c = rep.get("pycolmap", {}).get("centre_differences")
    if c:
        out["centre_differences"] = {k: c[k] for k in ("common", "rms_m", "max_m", "rms_enu_m",
                                                       "other_gnss_fit_rms_3d_m", "ours_gnss_similarity_rms_3d_m")}
    print(json.dumps(out, indent=1))
    (work / "bench_orient_lund.json").write_text(json.dumps(out, indent=1))
    print(f"written {work / 'bench_orient_lund.json'}")


if __name__ == "__main__":
    main()
