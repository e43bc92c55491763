"""Issue 35 item 3: the brighton DJI block (4000 x 2250 px, ~40 m above ground) matched at full resolution with the
hierarchical disparity search, next to the same images at x0.25, on the same grid.

Takes an adjust-uav output folder (``eo.csv``, ``camera.yaml``, ``points.csv``: e.g. a ``skyrig run`` of
brighton) and a subset of its images (``--images``: names; default six images of two strips, the shared machine
cannot match all 18 at full resolution in a few minutes).  Per run it prints the seconds, the disparity search's
counts (blocks refined, windows cut), the DSM's completeness (valid cells of the grid; the grid and area are the
same for every run) and its spread (median per-cell spread of the fused heights, and the NMAD of the height
differences between the runs where both are valid).

    nice .venv/bin/python bench/dense_fullres.py /tmp/skyrig-real/brighton/adjust-uav /work/shared/data/brighton-uav \
        --resolution 0.07 --scales 0.25 1
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("adjusted", type=Path, help="adjust-uav output folder (eo.csv, camera.yaml, points.csv)")
    ap.add_argument("images", type=Path, help="image folder")
    ap.add_argument("--images", dest="names", nargs="+",
                    default=["DJI_0020.JPG", "DJI_0021.JPG", "DJI_0022.JPG", "DJI_0025.JPG", "DJI_0026.JPG",
                             "DJI_0027.JPG"])
    ap.add_argument("--resolution", type=float, default=0.07, help="DSM cell (m), the same for every run")
    ap.add_argument("--scales", nargs="+", default=["0.25", "1"])
    ap.add_argument("--orientation-sigma-px", type=float, default=None,
                    help="skyrig dsm --orientation-sigma-px (e.g. 1.4 x adjust-uav's reprojection RMS)")
    ap.add_argument("--area", type=float, nargs=4, default=None, help="XMIN YMIN XMAX YMAX (default: all)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("skyrig.dense.pairs", "numba"):
        logging.getLogger(name).setLevel(logging.WARNING)

    import rasterio

    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.pipeline.inputs import load_cameras
    from skyrig.pipeline.products import make_dsm

    eo = read_eo_csv(a.adjusted / "eo.csv")
    eo = eo.subset(np.flatnonzero(np.isin(eo.image, a.names)))
    cams = load_cameras([a.adjusted / "camera.yaml"], "bench")
    files = [str(a.images / n) for n in eo.image]
    out = a.out or Path(tempfile.mkdtemp(prefix="dense_fullres_"))
    res = {}
    for scale in a.scales:
        tag = f"x{scale}"
        t = time.perf_counter()
        r = make_dsm(eo, cams, files, out / tag, points=a.adjusted / "points.csv", resolution=a.resolution,
                     image_scale=scale, executor="serial", echo=print, area=a.area,
                     orientation_sigma_px=a.orientation_sigma_px)
        dt = time.perf_counter() - t
        with rasterio.open(r.dsm) as ds:
            h = ds.read(1, masked=True).filled(np.nan)
            spread = ds.read(3, masked=True).filled(np.nan)
        res[tag] = h
        s = r.stats
        search = s.summary_line() or "no window wider than the limit"
        print(f"{tag:10s}: {dt:7.1f} s, {s.megapixels:7.1f} MP matched, {search}")
        print(f"{'':10s}  completeness {np.isfinite(h).mean() * 100:.2f} % of {h.size} cells, median spread "
              f"{np.nanmedian(spread):.3f} m", flush=True)
    tags = list(res)
    for t2 in tags[1:]:
        d = res[t2] - res[tags[0]]
        d = d[np.isfinite(d)]
        nmad = 1.4826 * np.median(np.abs(d - np.median(d)))
        print(f"{t2} - {tags[0]}: {d.size} cells in both, median {np.median(d):+.3f} m, NMAD {nmad:.3f} m, "
              f"|d| > 0.5 m {np.mean(np.abs(d) > 0.5) * 100:.2f} %")


if __name__ == "__main__":
    main()
