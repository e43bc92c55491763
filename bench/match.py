"""Tie-point benchmark: guided vs exhaustive matching as the block grows, and skyrig vs pycolmap's own pipeline.

Usage::

    .venv/bin/python bench/match.py [--data ../shared/data] [--max-size 1600] [--max-features 8000]
        [--work /tmp/skyrig-bench-match] [--skip-growth] [--datasets brighton,lund]

For each dataset (brighton-uav: DJI nadir strips with gimbal attitudes -> guided footprint pairs; opensfm/lund:
phone walk with GPS only -> GPS-neighbour pairs):

1. skyrig matching (features + pairs + verified matches), time and pair counts;
2. pycolmap incremental mapping on a database holding skyrig's keypoints and verified matches;
3. pycolmap's own extraction + exhaustive matching + mapping on the same images;
4. camera-centre differences after a similarity transform, reprojection RMS side by side.

Penta-rig precision (``--penta-only`` runs just this, no data needed): tie precision per head-pair class on the
simulator's MIDAS block against its truth, oblique rectification off vs on (:func:`penta_rig_precision`).

Speed side by side (``--speed``, issue 35: skyrig <= 1.0 x pycolmap's extraction + matching): on the first
``--images`` images of brighton-uav, in one process one after the other, skyrig's :func:`match_images` (features,
footprint-guided pairs from the DJI metadata, verified matches, tracks) and pycolmap's ``extract_features`` +
``match_exhaustive`` (COLMAP's SIFT and its matching with geometric verification), both at ``--max-size`` (0: full
resolution), ``--max-features``, 2 threads each; wall seconds and CPU seconds of the process (all threads; the CPU
figure holds on a shared machine) (:func:`speed_side_by_side`).  COLMAP's ``max_num_features`` bounds the detected
keypoints, each of which may get two orientations (descriptors), so it ends with up to twice the budget.

Growth: pair counts and matching times of guided vs exhaustive on the first n images (n = 6, 12, 18).
Nothing is written into the repository; everything goes under --work.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from skyrig.cli.match import match_images
from skyrig.match.colmap_check import compare_centres, reconstruct_from_matches, reconstruct_with_pycolmap
from skyrig.match.features import FeatureConfig, extract_features


def run_dataset(name: str, images: Path, work: Path, fc: FeatureConfig, mode: str, mapper: str) -> dict:
    from skyrig.io.image_read import orientations_from_metadata, read_image_metadata

    out = work / name
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    r = match_images([images], out / "skyrig", fc, pair_mode=mode)
    t_match = time.perf_counter() - t
    metas = [read_image_metadata(images / n) for n in r.names]
    focal = metas[0].focal_px
    t = time.perf_counter()
    rec_s, sum_s = reconstruct_from_matches(images, r.names, r.features, r.pair_matches, out / "colmap_skyrig",
                                            focal_px=focal, mapper=mapper)
    t_map_s = time.perf_counter() - t
    t = time.perf_counter()
    rec_c, sum_c = reconstruct_with_pycolmap(images, r.names, out / "colmap_own", max_image_size=fc.max_size or 10000,
                                             max_features=fc.max_features, focal_px=focal, mapper=mapper)
    t_colmap = time.perf_counter() - t
    gps = dict(zip(r.names, orientations_from_metadata(metas).eo.centre))
    n = len(r.names)
    res = {
        "images": n, "pair_mode": r.pair_mode, "pairs_tried": len(r.pairs), "pairs_exhaustive": n * (n - 1) // 2,
        "pairs_matched": r.report["pairs_matched"], "tie_points": r.report["n_tracks"],
        "tie_points_per_image": r.report["per_image"], "images_without_ties": r.report["images_without_ties"],
        "mean_multiplicity": r.report["mean_multiplicity"],
        "skyrig_time_s": {**{k: round(v, 1) for k, v in r.timings_s.items()}, "mapping": round(t_map_s, 1),
                          "total_with_mapping": round(t_match + t_map_s, 1)},
        "pycolmap_own_time_s": round(t_colmap, 1), "mapper": mapper,
    }
    for key, s in (("skyrig_matches_in_pycolmap", sum_s), ("pycolmap_own", sum_c)):
        res[key] = None if s is None else {
            "registered": int(len(s.names)), "points": s.n_points, "reprojection_rms_px": round(s.reprojection_rms_px, 3),
            "mean_track_length": round(s.mean_track_length, 2), "components": list(s.components),
            "unregistered_in_largest": sorted(set(r.names) - set(s.names)),
        }
    if sum_s is not None and sum_c is not None and len(set(sum_s.names) & set(sum_c.names)) >= 3:
        names, diff, scale = compare_centres(sum_s, sum_c)
        # express in metres: scale pycolmap's frame by the GPS distance spread where possible
        d = np.linalg.norm(diff, axis=1)
        extent = float(np.ptp(sum_c.centres, axis=0).max())
        # metric scale: similarity of pycolmap's own centres onto the EXIF GPS centres (local ENU, metres)
        from skyrig.match.colmap_check import similarity_transform

        m_per_unit = similarity_transform(sum_c.centres, np.array([gps[n] for n in sum_c.names]))[0]
        res["centre_differences"] = {
            "rms_m_via_gps_scale": float(np.sqrt(np.mean(d**2)) * m_per_unit),
            "max_m_via_gps_scale": float(d.max() * m_per_unit),
            "common_images": int(len(names)), "rms_colmap_units": float(np.sqrt(np.mean(d**2))),
            "max_colmap_units": float(d.max()), "block_extent_colmap_units": extent,
            "rms_relative_to_extent": float(np.sqrt(np.mean(d**2)) / extent),
        }
    return res


def speed_side_by_side(images: Path, work: Path, fc: FeatureConfig, n_images: int) -> dict:
    """skyrig's matching and pycolmap's extraction + exhaustive matching on the first ``n_images`` images, timed in
    wall and process CPU seconds (see the module docstring)."""
    import resource

    import pycolmap

    from skyrig.io.image_read import list_images

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    sub = work / f"speed_{n_images}"
    shutil.rmtree(sub, ignore_errors=True)
    (sub / "images").mkdir(parents=True)
    for p in list_images(images)[:n_images]:
        (sub / "images" / p.name).symlink_to(p.resolve())
    t, c = time.perf_counter(), cpu()
    r = match_images([sub / "images"], sub / "skyrig", fc, pair_mode="guided")
    sk = {"wall_s": time.perf_counter() - t, "cpu_s": cpu() - c, "pairs": len(r.pairs),
          "pairs_matched": r.report["pairs_matched"], "features_wall_s": r.timings_s["features"],
          "matching_wall_s": r.timings_s["matching"],
          "features_per_image": float(np.mean([len(f) for f in r.features]))}
    db = sub / "colmap.db"
    t, c = time.perf_counter(), cpu()
    eo = pycolmap.FeatureExtractionOptions()
    eo.max_image_size = int(fc.max_size or 100000)
    eo.sift.max_num_features = int(fc.max_features)
    eo.use_gpu = False
    eo.num_threads = 2
    pycolmap.extract_features(db, sub / "images", image_names=list(r.names), camera_mode=pycolmap.CameraMode.SINGLE,
                              extraction_options=eo, device=pycolmap.Device.cpu)
    t_ex, c_ex = time.perf_counter() - t, cpu() - c
    mo = pycolmap.FeatureMatchingOptions()
    mo.use_gpu = False
    mo.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    pc = {"wall_s": time.perf_counter() - t, "cpu_s": cpu() - c, "extraction_wall_s": t_ex, "extraction_cpu_s": c_ex,
          "pairs": len(r.names) * (len(r.names) - 1) // 2}
    with pycolmap.Database.open(db) as d:
        pc["features_per_image"] = float(np.mean([d.read_keypoints(im.image_id).shape[0] for im in d.read_all_images()]))
    return {"images": len(r.names), "max_size": fc.max_size, "max_features": fc.max_features, "skyrig": sk,
            "pycolmap": pc, "ratio_wall": sk["wall_s"] / pc["wall_s"], "ratio_cpu": sk["cpu_s"] / pc["cpu_s"],
            "load_average": os.getloadavg()}


def growth(images: Path, work: Path, fc: FeatureConfig, sizes: list[int]) -> list[dict]:
    """Guided vs exhaustive pair counts and matching times on the first n images (features cached per run)."""
    from skyrig.io.image_read import list_images

    all_imgs = list_images(images)
    rows = []
    for n in sizes:
        sub = work / f"growth_{n}" / "images"
        shutil.rmtree(sub.parent, ignore_errors=True)
        sub.mkdir(parents=True)
        for p in all_imgs[:n]:
            (sub / p.name).symlink_to(p.resolve())
        row = {"images": n}
        for mode in ("guided", "exhaustive"):
            if mode == "exhaustive":  # same features, extracted once: time the matching alone fairly
                shutil.copytree(sub.parent / "guided" / "features", sub.parent / mode / "features")
                shutil.copy(sub.parent / "guided" / "config.json", sub.parent / mode / "config.json")
            t = time.perf_counter()
            r = match_images([sub], sub.parent / mode, fc, pair_mode=mode)
            row[mode] = {"pairs": int(len(r.pairs)), "pairs_matched": r.report["pairs_matched"],
                         "tie_points": r.report["n_tracks"], "matching_s": round(r.timings_s["matching"], 1),
                         "total_s": round(time.perf_counter() - t, 1)}
        rows.append(row)
        print(json.dumps(row))
    return rows


def pair_growth_synthetic(strips: list[int], per_strip: int = 20) -> list[dict]:
    """Pair counts and selection time, footprint-guided vs exhaustive, for simulated nadir blocks
    (60 % forward, 30 % side overlap) of growing size: linear vs quadratic."""
    from skyrig.camera.frame import FrameCamera
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.match.pairs import footprint_pairs

    cam = FrameCamera.from_pixels("c", 4000, 3000, 4000.0, 1999.5, 1499.5)
    rows = []
    for ns in strips:
        foot_w, foot_h = 300.0, 225.0  # at 300 m: 4000 px * 300 / 4000
        xs, ys = np.meshgrid(np.arange(per_strip) * foot_w * 0.4, np.arange(ns) * foot_h * 0.7)
        c = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 300.0)])
        eo = ExteriorOrientations(np.array([f"i{k}" for k in range(len(c))]), "c", c,
                                  np.broadcast_to(np.eye(3), (len(c), 3, 3)), WorldFrame.local(0, 0, 0))
        t = time.perf_counter()
        p, _ = footprint_pairs(eo, {"c": cam}, 0.0, min_overlap=0.1)
        rows.append({"images": len(c), "guided_pairs": int(len(p)), "exhaustive_pairs": len(c) * (len(c) - 1) // 2,
                     "selection_s": round(time.perf_counter() - t, 2)})
        print(json.dumps(rows[-1]))
    return rows


def penta_rig_precision(size: str = "ci", seed: int = 1, method: str = "opencv") -> dict:
    """Tie precision per head-pair class on the simulator's MIDAS penta-rig block (``midas-demo``; ``size="full"``
    keeps the scenario's flight but not the CI camera width), with the oblique-image rectification off and on.

    Matching is guided by the recorded (noisy) orientations; each verified tie is judged by its transfer error
    against the simulator's truth (true orientations, ray-cast surface).  Figures: RMS per image coordinate of all
    verified ties, share above 3 px, RMS without those, LSM RMS (cross-head and nadir pairs)."""
    import cv2

    from skyrig.match.lsm import local_affine, lsm_refine
    from skyrig.match.matching import MatchConfig, match_pair
    from skyrig.match.pairs import footprint_pairs
    from skyrig.simulate.render import ray_hits_at_pixels, render_image
    from skyrig.simulate.scenarios import build_survey, georeference_recorded, scenario_spec

    s = build_survey(scenario_spec("midas-demo", size, seed))
    eo, n = s.eo_true, len(s.eo_true)
    P = eo.pose()
    cam = [s.rig_true.head(str(eo.head[k])).camera for k in range(n)]
    imgs = [cv2.cvtColor(render_image(s.scene, cam[k], P[k], noise_dn=s.spec.image_noise_dn, seed=k),
                         cv2.COLOR_RGB2GRAY) for k in range(n)]
    eo_rec = georeference_recorded(s)
    Pr = eo_rec.pose()
    cams = {str(eo_rec.camera[k]): s.rig_recorded.head(str(eo_rec.head[k])).camera for k in range(n)}
    cam_rec = [cams[str(c)] for c in eo_rec.camera]
    z0 = float(s.spec.base_height_m)
    pairs, _ = footprint_pairs(eo_rec, cams, z0, min_overlap=0.05)
    out: dict = {"images": n, "pairs_proposed": len(pairs)}
    for rectify in ("off", "oblique"):
        t = time.perf_counter()
        fc = FeatureConfig(method=method, max_size=None, max_features=4000, rectify=rectify)  # type: ignore[arg-type]
        feats = [extract_features(imgs[k], fc, cam_rec[k], Pr[k], z0) for k in range(n)]
        acc: dict = {}
        for a, b in pairs:
            r = match_pair(feats[a], feats[b], MatchConfig(matcher="bruteforce"), cam_rec[a], Pr[a], cam_rec[b], Pr[b])
            ha, hb = str(eo.head[a]), str(eo.head[b])
            key = "nadir-nadir" if ha == hb == "nadir" else ("nadir-oblique" if "nadir" in (ha, hb) else "oblique-oblique")
            d = acc.setdefault(key, {"pairs": 0, "matched": 0, "e": [], "lsm": []})
            d["pairs"] += 1
            if not r.ok:
                continue
            d["matched"] += 1
            x1, x2 = feats[a].xy[r.matches[:, 0]], feats[b].xy[r.matches[:, 1]]
            t2 = cam[b].world_to_pixel(P[b], ray_hits_at_pixels(s.scene, cam[a], P[a], x1).xyz)
            d["e"].append(x2 - t2)
            lr = lsm_refine(imgs[a], imgs[b], x1, x2, local_affine(x1, x2), half_size=7)
            d["lsm"].append(lr.xy2[lr.ok] - t2[lr.ok])
        res = {}
        for key, d in sorted(acc.items()):
            e = np.concatenate(d["e"]) if d["e"] else np.zeros((0, 2))
            el = np.concatenate(d["lsm"]) if d["lsm"] else np.zeros((0, 2))
            rad = np.linalg.norm(e, axis=1)
            res[key] = {"pairs_proposed": d["pairs"], "pairs_matched": d["matched"], "ties": len(e),
                        "rms_all_px": round(float(np.sqrt(np.mean(e**2))), 3) if len(e) else None,
                        "share_above_3px": round(float(np.mean(rad > 3)), 4) if len(e) else None,
                        "rms_without_gross_px": round(float(np.sqrt(np.mean(e[rad <= 3] ** 2))), 3) if len(e) else None,
                        "lsm_rms_px": round(float(np.sqrt(np.mean(el**2))), 3) if len(el) else None}
        out[f"rectify_{rectify}"] = {"classes": res, "seconds": round(time.perf_counter() - t, 1)}
        print(f"rectify={rectify}:", json.dumps(res, indent=1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--work", default="/tmp/skyrig-bench-match")
    ap.add_argument("--max-size", type=int, default=1600)
    ap.add_argument("--max-features", type=int, default=8000)
    ap.add_argument("--method", default="pycolmap")
    ap.add_argument("--datasets", default="brighton,lund")
    ap.add_argument("--skip-growth", action="store_true")
    ap.add_argument("--speed", action="store_true",
                    help="only skyrig vs pycolmap extraction + matching time on brighton's first --images images")
    ap.add_argument("--images", type=int, default=6, help="images of the --speed comparison")
    ap.add_argument("--penta-only", action="store_true",
                    help="only the simulated penta-rig precision table (no shared data needed)")
    a = ap.parse_args()
    if a.penta_only:
        print(json.dumps(penta_rig_precision(), indent=1))
        return
    data, work = Path(a.data), Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    fc = FeatureConfig(method=a.method, max_size=a.max_size or None, max_features=a.max_features)
    if a.speed:
        print(json.dumps(speed_side_by_side(data / "brighton-uav", work, fc, a.images), indent=1))
        return
    results = {"config": {"max_size": a.max_size, "max_features": a.max_features, "method": a.method}}
    # lund is a forward-moving phone walk: COLMAP's incremental mapper cannot initialise on it (with its own
    # matches either), so both pipelines use the global mapper there
    sets = {"brighton": (data / "brighton-uav", "guided", "incremental"),
            "lund": (data / "opensfm" / "lund" / "images", "gps", "global")}
    results["pair_growth_synthetic"] = pair_growth_synthetic([2, 4, 8, 16, 32])
    results["penta_rig_precision"] = penta_rig_precision()
    for name in a.datasets.split(","):
        folder, mode, mapper = sets[name]
        results[name] = run_dataset(name, folder, work, fc, mode, mapper)
        print(name, json.dumps(results[name], indent=1))
    if not a.skip_growth:
        results["growth_brighton"] = growth(data / "brighton-uav", work, fc, [6, 12, 18])
    (work / "bench_match.json").write_text(json.dumps(results, indent=1))
    print(f"written {work / 'bench_match.json'}")


if __name__ == "__main__":
    main()
