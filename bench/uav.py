"""UAV benchmark: ``skyrig match`` + skyrig's GNSS-supported adjustment (:mod:`skyrig.pipeline.uav`) against
pycolmap's own pipeline (SIFT, exhaustive matching, mapping) on the same images.

Usage::

    .venv/bin/python bench/uav.py [--data ../shared/data] [--work /tmp/skyrig-bench-uav] [--max-size 1600]
        [--max-features 8000] [--datasets brighton,lund] [--fresh] [--variants]

Datasets: ``brighton-uav`` (18 DJI Phantom images in 3 nadir strips, GPS + gimbal attitudes; guided pairs, COLMAP
incremental mapper) and ``opensfm/lund`` (29 phone images of a walk, GPS only; GPS-neighbour pairs, GLOMAP global
mapper for both, as in ``bench/match.py``: COLMAP's incremental mapper cannot initialise on the forward motion).

Per dataset, in one run:

1. ``skyrig match`` into ``WORK/<dataset>/match`` (features and pair matches are cached there by
   :func:`skyrig.cli.match.match_images`, so reruns skip them);
2. pycolmap's own pipeline in ``WORK/<dataset>/pycolmap`` (cached: reused when ``stamp.json`` records the same
   size / features / mapper; ``--fresh`` reruns matching and pycolmap);
3. skyrig's GNSS-supported adjustment (:func:`skyrig.pipeline.uav.adjust_uav_block`, default :class:`UavConfig`).

Printed table: images oriented, tie points (total; min / median / max per image), reprojection RMS (full-resolution
pixels, both), camera-centre differences after a similarity transform (RMS / max, metres), fit of each to GPS
(skyrig: GNSS residuals of the adjustment and a similarity of its centres onto GPS; pycolmap: similarity onto GPS)
and wall times.  ``--variants`` also runs the brighton strip-1 study (focal fixed at EXIF, per-strip GNSS shift,
no attitude prior) and prints per-strip GNSS fit and distances to pycolmap.  Results go to
``WORK/bench_uav.json``.  Nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np


def _per_image(counts: list[int] | np.ndarray) -> str:
    c = np.asarray(counts)
    return f"{int(c.min())} / {int(np.median(c))} / {int(c.max())}" if len(c) else "-"


def run_pycolmap(images: Path, names: list[str], work: Path, max_size: int, max_features: int, mapper: str,
                 focal_px: float, fresh: bool) -> tuple[object | None, float]:
    """pycolmap's own pipeline, cached in ``work`` (``stamp.json``); returns (summary, wall seconds of the run
    that produced it)."""
    import pycolmap

    from skyrig.match.colmap_check import reconstruct_with_pycolmap, summarise

    stamp = work / "stamp.json"
    key = {"max_size": max_size, "max_features": max_features, "mapper": mapper, "images": sorted(names)}
    if not fresh and stamp.is_file():
        st = json.loads(stamp.read_text())
        models = sorted((work / "sparse_colmap").glob("*/images.bin"))
        if st.get("key") == key and models:
            recs = [pycolmap.Reconstruction(str(m.parent)) for m in models]
            rec = max(recs, key=lambda r: r.num_reg_images())
            return summarise(rec), float(st["wall_s"])
    shutil.rmtree(work, ignore_errors=True)
    t = time.perf_counter()
    _, summ = reconstruct_with_pycolmap(images, names, work, max_image_size=max_size, max_features=max_features,
                                        mapper=mapper, focal_px=focal_px)
    wall = time.perf_counter() - t
    if summ is not None:
        # keep only the largest model on disk, so the cache reloads what was measured
        stamp.write_text(json.dumps({"key": key, "wall_s": wall}))
    return summ, wall


def run_dataset(name: str, images: Path, work: Path, max_size: int, max_features: int, pair_mode: str,
                mapper: str, fresh: bool) -> dict:
    from skyrig.cli.match import match_images
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.match.features import FeatureConfig
    from skyrig.pipeline.uav import UavConfig, adjust_uav_block, compare_with_reconstruction, metadata_block_input

    wd = work / name
    wd.mkdir(parents=True, exist_ok=True)
    fc = FeatureConfig(method="pycolmap", max_size=max_size, max_features=max_features)
    t = time.perf_counter()
    from skyrig.errors import InputFormatError

    try:
        mr = match_images([images], wd / "match", fc, pair_mode=pair_mode, overwrite=fresh)
    except InputFormatError:  # cache made with other settings: start it again
        mr = match_images([images], wd / "match", fc, pair_mode=pair_mode, overwrite=True)
    t_match = time.perf_counter() - t
    t = time.perf_counter()
    meas = read_measurements_csv(wd / "match" / "tie_points.csv")
    metas = [read_image_metadata(p) for p in list_images(images)]
    inp = metadata_block_input(metas, meas, UavConfig())
    res = adjust_uav_block(inp, UavConfig())
    t_adj = time.perf_counter() - t
    s = res.summary
    focal = inp.camera.focal_mm / inp.camera.pixel_size_mm
    summ, t_col = run_pycolmap(images, [str(n) for n in inp.names], wd / "pycolmap", max_size, max_features,
                               mapper, focal, fresh)
    gr = res.adjustment.residuals["gnss"].residual
    out: dict = {
        "images": len(inp.names), "pair_mode": mr.pair_mode, "pairs_tried": len(mr.pairs),
        "skyrig": {
            "oriented": s["oriented"], "tie_points": s["tie_points"],
            "tie_points_per_image": _per_image(list(s["tie_points_per_image"].values())),
            "reprojection_rms_px": s["reprojection_rms_px"], "sigma0": s["sigma0"],
            "gnss_residual_rms_3d_m": s["gnss_fit_rms_3d_m"], "gnss_residual_max_3d_m":
                float(np.linalg.norm(gr, axis=1).max()),
            "focal_px": s["focal_px"], "focal_px_exif": s["focal_px_exif"], "focal": s.get("focal"),
            "match_s": t_match, "match_timings_s": {k: round(v, 1) for k, v in mr.timings_s.items()},
            "adjust_s": t_adj,
        },
        "pycolmap": None,
    }
    if summ is not None:
        cmp = compare_with_reconstruction(res, summ.names, summ.centres, inp.gnss)
        out["pycolmap"] = {
            "registered": int(len(summ.names)), "tie_points": int(summ.n_points),
            "tie_points_per_image": _per_image(summ.obs_per_image), "reprojection_rms_px": summ.reprojection_rms_px,
            "components": list(summ.components), "wall_s": t_col,
            "gnss_similarity_rms_3d_m": cmp["other_gnss_fit_rms_3d_m"],
        }
        out["skyrig"]["gnss_similarity_rms_3d_m"] = cmp["ours_gnss_similarity_rms_3d_m"]
        out["centre_differences"] = {k: cmp[k] for k in ("common", "rms_m", "max_m", "rms_enu_m", "per_image_m")}
    return out


def strip_study(work: Path, images: Path) -> list[dict]:
    """Brighton strip-1 study on the cached 1600-px ties: per-strip GNSS fit and distance to pycolmap for the
    default adjustment and the variants of the open question."""
    from skyrig.io.image_read import list_images, read_image_metadata
    from skyrig.io.points_csv import read_measurements_csv
    from skyrig.pipeline.uav import (UavConfig, adjust_uav_block, compare_with_reconstruction, detect_strips,
                                     metadata_block_input)

    import pycolmap

    from skyrig.match.colmap_check import summarise

    wd = work / "brighton"
    meas = read_measurements_csv(wd / "match" / "tie_points.csv")
    metas = [read_image_metadata(p) for p in list_images(images)]
    inp = metadata_block_input(metas, meas, UavConfig())
    models = sorted((wd / "pycolmap" / "sparse_colmap").glob("*/images.bin"))
    rec = max((pycolmap.Reconstruction(str(m.parent)) for m in models), key=lambda r: r.num_reg_images())
    sm = summarise(rec)
    strip = detect_strips(inp.gnss)
    variants = {"default": {}, "focal fixed (EXIF)": {"focal": "exif"}, "focal auto": {"focal": "auto"},
                "strip GNSS shift": {"gnss_strip_shift": "weighted"}, "no attitude prior": {"attitude_sigma_deg": None},
                "strip shift + EXIF focal": {"gnss_strip_shift": "weighted", "focal": "exif"}}
    rows = []
    for label, kw in variants.items():
        t = time.perf_counter()
        r = adjust_uav_block(inp, UavConfig(**kw))
        c = compare_with_reconstruction(r, sm.names, sm.centres, inp.gnss)
        names = r.names[r.block_image]
        d = np.linalg.norm(r.adjustment.residuals["gnss"].residual, axis=1)
        st = strip[r.block_image]
        row = {"variant": label, "focal_px": r.summary["focal_px"], "reprojection_rms_px": r.summary["reprojection_rms_px"],
               "gnss_rms_per_strip_m": [float(np.sqrt(np.mean(d[st == k] ** 2))) for k in np.unique(st[st >= 0])],
               "pycolmap_rms_per_strip_m": [float(np.sqrt(np.mean([c["per_image_m"][n] ** 2 for n in names[st == k]])))
                                            for k in np.unique(st[st >= 0])],
               "pycolmap_rms_m": c["rms_m"], "pycolmap_max_m": c["max_m"], "wall_s": time.perf_counter() - t,
               "focal": r.summary.get("focal"), "strip_shift_m": r.summary.get("strip_shift_m")}
        rows.append(row)
        print(f"{label:26s} f {row['focal_px']:7.1f} px  rms {row['reprojection_rms_px']:.3f} px  GNSS/strip "
              + " ".join(f"{v:.2f}" for v in row["gnss_rms_per_strip_m"]) + "  pycolmap/strip "
              + " ".join(f"{v:.2f}" for v in row["pycolmap_rms_per_strip_m"])
              + f"  (rms {row['pycolmap_rms_m']:.2f} max {row['pycolmap_max_m']:.2f} m)", flush=True)
    return rows


def print_table(results: dict) -> None:
    def f(v: object, fmt: str = "{:.3f}") -> str:
        return "-" if v is None else (fmt.format(v) if isinstance(v, (float, int)) else str(v))

    lines = []
    for name, r in results.items():
        if not isinstance(r, dict) or "skyrig" not in r:
            continue
        s, p, c = r["skyrig"], r["pycolmap"] or {}, r.get("centre_differences", {})
        lines += [f"\n== {name}: {r['images']} images ({r['pair_mode']} pairs: {r['pairs_tried']})",
                  f"{'':34s}{'skyrig (match + GNSS adjustment)':>34s}{'pycolmap (own pipeline)':>28s}",
                  f"{'images oriented':34s}{s['oriented']:>34d}{f(p.get('registered'), '{:d}'):>28s}",
                  f"{'tie points':34s}{s['tie_points']:>34d}{f(p.get('tie_points'), '{:d}'):>28s}",
                  f"{'  per image min / median / max':34s}{s['tie_points_per_image']:>34s}"
                  f"{f(p.get('tie_points_per_image')):>28s}",
                  f"{'reprojection RMS (px, full res)':34s}{s['reprojection_rms_px']:>34.3f}"
                  f"{f(p.get('reprojection_rms_px')):>28s}",
                  f"{'fit to GPS: similarity RMS 3D (m)':34s}{f(s.get('gnss_similarity_rms_3d_m')):>34s}"
                  f"{f(p.get('gnss_similarity_rms_3d_m')):>28s}",
                  f"{'fit to GPS: adj. residual RMS/max':34s}"
                  f"{s['gnss_residual_rms_3d_m']:>27.3f} / {s['gnss_residual_max_3d_m']:.2f}{'-':>28s}",
                  f"{'focal (px; EXIF)':34s}{s['focal_px']:>25.1f} ({s['focal_px_exif']:.0f})"
                  f"{'-':>28s}",
                  f"{'wall time (s)':34s}{'match ' + f(s['match_s'], '{:.1f}') + ' + adjust ' + f(s['adjust_s'], '{:.1f}'):>34s}"
                  f"{f(p.get('wall_s'), '{:.1f}'):>28s}",
                  f"centre differences after similarity: {c.get('common', 0)} common images, RMS "
                  f"{f(c.get('rms_m'))} m, max {f(c.get('max_m'))} m"]
    print("\n".join(lines))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--work", default="/tmp/skyrig-bench-uav")
    ap.add_argument("--max-size", type=int, default=1600)
    ap.add_argument("--max-features", type=int, default=8000)
    ap.add_argument("--datasets", default="brighton,lund")
    ap.add_argument("--fresh", action="store_true", help="rerun matching and pycolmap instead of using the cache")
    ap.add_argument("--variants", action="store_true", help="also the brighton strip-1 study")
    a = ap.parse_args()
    data, work = Path(a.data), Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    sets = {"brighton": (data / "brighton-uav", "guided", "incremental"),
            "lund": (data / "opensfm" / "lund" / "images", "gps", "global")}
    results: dict = {"config": {"max_size": a.max_size, "max_features": a.max_features}}
    for name in a.datasets.split(","):
        folder, mode, mapper = sets[name]
        results[name] = run_dataset(name, folder, work, a.max_size, a.max_features, mode, mapper, a.fresh)
    print_table(results)
    if a.variants and "brighton" in results:
        print("\n== brighton strip study (strips from the flight path; GNSS residual RMS 3D and distance to pycolmap "
              "after similarity, per strip)")
        results["brighton_strip_study"] = strip_study(work, sets["brighton"][0])
    (work / "bench_uav.json").write_text(json.dumps(results, indent=1, default=float))
    print(f"\nwritten {work / 'bench_uav.json'}")


if __name__ == "__main__":
    main()
