"""Dense-stage benchmark: the whole chain against raw StereoSGBM on the same pairs, and growth with the block.

Usage::

    .venv/bin/python bench/dense.py [--quick] [--sizes 4,8,16,32,64] [--cache /tmp/skyrig-bench-dense]
        [--profile N] [--workers 2] [--cv-threads 1] [--tile-cells N] [--cold] [--lr-check banded|full|opencv]
        [--lr-band-cols PX] [--no-cloud]

Data: the simulator's ``midas-dsm`` scenario (MIDAS rig, 150 m, 80 % forward / 60 % side overlap, 640 x 427
images) with two changes made through :func:`dataclasses.replace` on its spec: only the nadir head is flown
(obliques are not rendered: the dense chain matches nadir with nadir), and the block has 4 strips of 16
exposures (area 100 x 400 m) so that 4..64-image blocks are rectangular sub-blocks of one flight
(``s`` strips x ``m`` exposures: 4 = 2x2, 8 = 2x4, 16 = 4x4, 32 = 4x8, 64 = 4x16).  The 64 images are rendered
once (~1 min on 2 cores) into ``--cache`` and reused; orientations are the true ones (``survey.eo_true``,
local frame), the output frame EPSG:25832, the height range the scene's ``terrain_range[0] .. top`` (+-2 m).

Per size, in a fresh subprocess (so ``ru_maxrss`` is that size's peak), after the chain's one-time start-up
(numba loading its compiled kernels from the cache, LLVM set-up: the chain run once on a 10 x 10 m area,
reported as ``start s``; ``--cold`` leaves it inside the chain's time instead):

* **chain**: :func:`skyrig.dense.surface.plan_dense`, :func:`run_tile` for every tile, :func:`assemble`, with
  image reading from PNG (rectify, match, triangulate, fuse, cloud) -- the default :class:`DenseConfig`
  (its left-right check is the second, right-based matching on the row bands with depth edges,
  ``SgmConfig.lr_check="banded"``; ``--lr-check full`` runs it on every row, ``--lr-check opencv`` measures OpenCV's
  internal check instead; ``--no-cloud`` leaves the dense cloud out, as ``skyrig dsm --no-cloud``
  does: the DSM chain alone);
* **raw**: for every pair the plan selected, ``cv2.StereoSGBM_create(...).compute`` once on the pair's
  whole rectified overlap (the left image's rectified bounds plus the search width on the left, the right
  image shifted by the window start), grey, with the same disparity window (the union of the pair's block
  windows, via the same multiple-of-16 rounding) and the same block size / penalties / filters as
  ``SgmConfig``.  Rectification and image reading are *not* timed for raw (they are for the chain).

With the full check (``--lr-check full``) raw is also timed on the mirrored pair (the chain's second, right-based matching,
with ``SgmConfig.lr_mode``), and the ratio against raw plus that pass is printed too: the chain's overhead beyond
the two SGM passes it runs (issue 10's goal is against raw alone).

Both run with the same ``cv2.setNumThreads`` (``--cv-threads``, default 1; OpenCV's MODE_SGBM is single-threaded
anyway, the setting reaches remap and colour conversion), and both are timed in wall and in CPU seconds of the
process (the CPU figures hold on a shared machine; the wall ones do not).  A second raw reference runs
StereoSGBM on the columns only whose search window reaches the right image (``raw ov``: what the chain itself
matches, about 2/3 of the pixels of these pairs); the ratio against it is printed as well.

The chain's time is split by phase (:mod:`skyrig.dense._phases`: read, rectify, sgm left, sgm right (the
right-based pass of the full left-right check), lr check, filters, triangulate, to map, fuse grid, fuse cloud,
plan, assemble; CPU seconds).

Megapixels are the pairs' rectified left pixels (each pair once), the same count for both; MP/s = that count /
seconds, and ``ratio = MP/s chain / MP/s raw`` (issue 10 goal: >= 0.6).  ``matched MP`` is what the chain
actually ran SGM on (blocks with their context and search-width margins are counted by their interior only;
a block reaching several ground tiles is matched once per tile).

Quality, in the same run: every size's DSM is judged against the scene's truth (:func:`judge`: cells within 2 GSD
of building outlines valid / off by more than 5 GSD / RMSE, flat cells valid / outliers / NMAD), so a faster path
shows its edge quality next to its speed.

``--profile N`` runs the chain for the N-image block under cProfile in this process and prints the functions
with the most own time and cumulative time.  Nothing is written into the repository.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

N_STRIPS, N_PER_STRIP = 4, 16
#: metres by which the judged area exceeds the rectangle of the sub-block's projection centres
JUDGE_MARGIN_M = 60.0
LAYOUT = {4: (2, 2), 8: (2, 4), 16: (4, 4), 32: (4, 8), 64: (4, 16)}


def bench_spec():  # type: ignore[no-untyped-def]
    """The midas-dsm spec flown with the nadir head only, 4 strips x 16 exposures."""
    from skyrig.simulate.scenarios import scenario_spec

    s = scenario_spec("midas-dsm", "ci", 1)
    rig = replace(s.rig, heads={"nadir": s.rig.heads["nadir"]})
    fl = replace(s.flights[0], n_strips=N_STRIPS, area=(-50.0, -200.0, 50.0, 200.0))
    return replace(s, name="midas-dsm-nadir-bench", rig=rig, flights=(fl,))


def ensure_block(cache: Path, workers: int | None):  # type: ignore[no-untyped-def]
    """The survey (rebuilt: deterministic, < 1 s) and its rendered images in ``cache/images`` (rendered once)."""
    from skyrig.pipeline.simulate import render_images
    from skyrig.simulate.scenarios import build_survey

    survey = build_survey(bench_spec())
    names = [str(n) for n in survey.eo_true.image]
    if len(names) != N_STRIPS * N_PER_STRIP:
        raise SystemExit(f"bench block has {len(names)} images, expected {N_STRIPS * N_PER_STRIP}")
    stamp = cache / "block.json"
    want = {"spec": repr(bench_spec().flights) + repr(sorted(bench_spec().rig.heads)), "images": names}
    ok = stamp.exists() and json.loads(stamp.read_text()) == want and all((cache / "images" / n).exists() for n in names)
    if not ok:
        cache.mkdir(parents=True, exist_ok=True)
        print(f"rendering {len(names)} nadir images into {cache} (once) ...", flush=True)
        mp, secs = render_images(survey, cache, workers)
        print(f"  {mp:.1f} MP in {secs:.0f} s", flush=True)
        stamp.write_text(json.dumps(want))
    return survey


def subset_rows(names: list[str], along: np.ndarray, n: int) -> np.ndarray:
    """Rows of a rectangular sub-block of ``n`` images: the first strips, in each the exposures furthest
    south (``along``: the projection centres' northing; strips are flown back and forth)."""
    s, m = LAYOUT[n]
    by_strip: dict[int, list[tuple[float, int]]] = {}
    for i, name in enumerate(names):
        g = re.match(r"s(\d+)_e(\d+)_", name)
        if g is None:
            raise SystemExit(f"unexpected image name {name}")
        by_strip.setdefault(int(g.group(1)), []).append((float(along[i]), i))
    out: list[int] = []
    for strip in sorted(by_strip)[:s]:
        out += [i for _, i in sorted(by_strip[strip])[:m]]
    return np.array(sorted(out))


def setup(cache: Path, n: int, workers: int | None = None):  # type: ignore[no-untyped-def]
    """Orientations, cameras, loader, output frame and height range of the n-image sub-block."""
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.images import read_image

    survey = ensure_block(cache, workers)
    eo = survey.eo_true.subset(subset_rows([str(x) for x in survey.eo_true.image], survey.eo_true.centre[:, 1], n))
    cameras = {h.camera.name: h.camera for h in survey.rig_true.heads.values()}
    paths = [cache / "images" / str(x) for x in eo.image]

    def loader(i: int) -> np.ndarray:
        return read_image(paths[i])

    sc = survey.scene
    hr = (float(sc.terrain_range[0]) - 2.0, float(sc.top) + 2.0)
    return eo, cameras, loader, WorldFrame.map(survey.spec.crs), hr


def run_chain(eo, cameras, loader, out_frame, hr, tile_cells: int | None = None,  # type: ignore[no-untyped-def]
              lr_check: str | None = None, with_cloud: bool = True, lr_band_cols: int | None = None):
    from skyrig.dense.surface import DenseConfig, assemble, plan_dense, run_tile

    from skyrig.dense import _phases

    cfg = DenseConfig() if tile_cells is None else DenseConfig(tile_cells=tile_cells)
    if lr_check is not None:
        cfg = replace(cfg, sgm=replace(cfg.sgm, lr_check=lr_check))
    if lr_band_cols is not None:
        cfg = replace(cfg, sgm=replace(cfg.sgm, lr_band_cols_px=lr_band_cols))
    cfg = replace(cfg, cloud=with_cloud)
    _phases.reset()
    c0 = time.process_time()
    t0 = time.perf_counter()
    with _phases.phase("plan"):
        plan = plan_dense(eo, cameras, out_frame, hr, None, cfg)
    t1 = time.perf_counter()
    results = [run_tile(plan, k, loader) for k in range(len(plan.tiles))]
    t2 = time.perf_counter()
    with _phases.phase("assemble"):
        dsm, cloud, stats = assemble(plan, results)
    t3 = time.perf_counter()
    return plan, dsm, cloud, stats, {"plan_s": t1 - t0, "tiles_s": t2 - t1, "assemble_s": t3 - t2, "chain_s": t3 - t0,
                                     "chain_cpu_s": time.process_time() - c0, "phases": _phases.totals()}


def warm_up(eo, cameras, loader, out_frame, hr, lr_check: str | None = None,  # type: ignore[no-untyped-def]
            with_cloud: bool = True, lr_band_cols: int | None = None) -> dict:
    """The chain's one-time start-up in a fresh process (numba loading its compiled kernels from the cache, LLVM
    set-up, first OpenCV calls), paid once per process whatever the block: the whole chain on a 10 x 10 m area
    in the block's middle with 64-pixel blocks (every kernel runs once, on the same types and options as the timed
    run: a kernel variant the warm-up does not run would be compiled inside the chain's time)."""
    from skyrig.dense.surface import DenseConfig, assemble, plan_dense, run_tile

    c0, t0 = time.process_time(), time.perf_counter()
    m = eo.to_frame(out_frame).centre[:, :2].mean(axis=0)
    cfg = DenseConfig(block_px=64, cloud=with_cloud)
    if lr_check is not None:
        cfg = replace(cfg, sgm=replace(cfg.sgm, lr_check=lr_check))
    if lr_band_cols is not None:
        cfg = replace(cfg, sgm=replace(cfg.sgm, lr_band_cols_px=lr_band_cols))
    plan = plan_dense(eo, cameras, out_frame, hr, (m[0] - 5, m[1] - 5, m[0] + 5, m[1] + 5), cfg)
    assemble(plan, [run_tile(plan, k, loader) for k in range(len(plan.tiles))])
    return {"startup_s": time.perf_counter() - t0, "startup_cpu_s": time.process_time() - c0}


def run_raw(plan, loader) -> dict:  # type: ignore[no-untyped-def]
    """Raw StereoSGBM on each planned pair's whole rectified overlap (only ``compute`` is timed)."""
    import cv2

    from skyrig.dense.sgm import disparity_window

    cfg = plan.config.sgm
    mode = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
            "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}[cfg.mode]
    bs2 = cfg.block_size ** 2
    secs, cpu, mp, valid, cpu_mirror = 0.0, 0.0, 0.0, 0, 0.0
    secs_ov, cpu_ov, mp_ov = 0.0, 0.0, 0.0
    images: dict[int, np.ndarray] = {}
    for pair, rect, blocks in zip(plan.pairs, plan.rects, plan.blocks):
        for i in (pair.left, pair.right):
            if i not in images:
                images[i] = loader(i)
        u0 = min(b.u0 for b in blocks)
        u1 = max(b.u1 for b in blocks)
        v0 = min(b.v0 for b in blocks)
        v1 = max(b.v1 for b in blocks)
        shift, n = disparity_window(min(b.d_min for b in blocks), max(b.d_max for b in blocks), cfg)
        w, h = (u1 - u0) + n, v1 - v0
        lc, _ = rect.remap(0, images[pair.left], u0 - n, v0, w, h)
        rc, _ = rect.remap(1, images[pair.right], u0 - n - shift, v0, w, h)
        lg = cv2.cvtColor(lc, cv2.COLOR_RGB2GRAY) if lc.ndim == 3 else lc
        rg = cv2.cvtColor(rc, cv2.COLOR_RGB2GRAY) if rc.ndim == 3 else rc
        m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n, blockSize=cfg.block_size,
                                  P1=cfg.p1 * bs2, P2=cfg.p2 * bs2, disp12MaxDiff=cfg.lr_max_diff,
                                  preFilterCap=cfg.pre_filter_cap, uniquenessRatio=cfg.uniqueness,
                                  speckleWindowSize=cfg.speckle_window, speckleRange=cfg.speckle_range, mode=mode)
        t, c = time.perf_counter(), time.process_time()
        d16 = m.compute(lg, rg)
        secs += time.perf_counter() - t
        cpu += time.process_time() - c
        if cfg.lr_check == "full":  # the chain's full check: the same matching on the mirrored pair (its lr_mode)
            rmode = cfg.lr_mode or cfg.mode
            mr = m if rmode == cfg.mode else cv2.StereoSGBM_create(
                minDisparity=0, numDisparities=n, blockSize=cfg.block_size, P1=cfg.p1 * bs2, P2=cfg.p2 * bs2,
                disp12MaxDiff=cfg.lr_max_diff, preFilterCap=cfg.pre_filter_cap, uniquenessRatio=cfg.uniqueness,
                speckleWindowSize=cfg.speckle_window, speckleRange=cfg.speckle_range,
                mode={"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
                      "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}[rmode])
            lm, rm_ = np.ascontiguousarray(rg[:, ::-1]), np.ascontiguousarray(lg[:, ::-1])
            c = time.process_time()
            mr.compute(lm, rm_)
            cpu_mirror += time.process_time() - c
        mp += (u1 - u0) * (v1 - v0) / 1e6
        valid += int((d16[:, n:] >= 0).sum())
        # the same, on the columns only whose search window reaches the right image (what the chain matches)
        a = max(u0, int(rect.bounds[1][0]) + shift)
        b = min(u1, int(rect.bounds[1][1]) + shift + n - 1)
        if b > a:
            lo, ro = np.ascontiguousarray(lg[:, a - u0:b - u0 + n]), np.ascontiguousarray(rg[:, a - u0:b - u0 + n])
            t, c = time.perf_counter(), time.process_time()
            m.compute(lo, ro)
            secs_ov += time.perf_counter() - t
            cpu_ov += time.process_time() - c
            mp_ov += (b - a) * (v1 - v0) / 1e6
    return {"raw_s": secs, "raw_cpu_s": cpu, "pair_mp": mp, "raw_valid": valid, "raw_ov_s": secs_ov,
            "raw_ov_cpu_s": cpu_ov, "overlap_mp": mp_ov, "raw_mirror_cpu_s": cpu_mirror}


def worker(cache: Path, n: int, tile_cells: int | None, cv_threads: int = 1, cold: bool = False,
           lr_check: str | None = None, with_cloud: bool = True, lr_band_cols: int | None = None) -> dict:
    """One size, in this (fresh) process: start-up (unless ``cold``), chain, then raw; peak memory of each phase."""
    import cv2

    eo, cameras, loader, out_frame, hr = setup(cache, n)
    cv2.setNumThreads(cv_threads)  # the same for the chain and raw (OpenCV's MODE_SGBM itself is single-threaded)
    start = ({"startup_s": 0.0, "startup_cpu_s": 0.0} if cold else
             warm_up(eo, cameras, loader, out_frame, hr, lr_check, with_cloud, lr_band_cols))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    plan, dsm, cloud, stats, t = run_chain(eo, cameras, loader, out_frame, hr, tile_cells, lr_check, with_cloud,
                                           lr_band_cols)
    rss_chain = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    raw = run_raw(plan, loader)
    h = dsm.height
    q = judge(dsm, eo, plan.gsd_m)
    return {"judge": q, "n": n, "pairs": stats.pairs, "tiles": stats.tiles, "blocks": stats.blocks, "points": stats.points,
            "matched_mp": stats.megapixels, "cells": int(h.size), "valid_cells": float(np.isfinite(h).mean()),
            "rss0_mb": rss0 / 1024, "rss_chain_mb": rss_chain / 1024, **t, **raw, **start}


def judge(dsm, eo, gsd_m: float) -> dict:  # type: ignore[no-untyped-def]
    """The DSM against the scene's truth (:func:`skyrig.simulate.judge.judge_dsm`) inside the rectangle of the
    sub-block's projection centres grown by :data:`JUDGE_MARGIN_M` (a third of an image's ground footprint: the
    scene's buildings are sparse, the centres' rectangle of the small blocks holds next to none): completeness,
    outliers (> 5 GSD), RMSE and NMAD of the cells within 2 GSD of building outlines (edge) and of the others
    (flat)."""
    from skyrig.simulate.judge import judge_dsm
    from skyrig.simulate.scenarios import build_survey

    c = eo.centre
    g = JUDGE_MARGIN_M
    r = judge_dsm(dsm, build_survey(bench_spec()).scene, gsd_m, (float(c[:, 0].min()) - g, float(c[:, 1].min()) - g,
                                                                 float(c[:, 0].max()) + g, float(c[:, 1].max()) + g))
    return {k: {f: r[k][f] for f in ("n", "completeness", "outliers", "rmse_gsd", "nmad_gsd", "bias_gsd")}
            for k in ("edge", "flat")}


def profile(cache: Path, n: int, top: int = 25) -> None:
    import cProfile
    import pstats

    eo, cameras, loader, out_frame, hr = setup(cache, n)
    pr = cProfile.Profile()
    pr.enable()
    run_chain(eo, cameras, loader, out_frame, hr)
    pr.disable()
    st = pstats.Stats(pr)
    print(f"\n--- cProfile of the chain, {n} images: by own time ---")
    st.sort_stats("tottime").print_stats(top)
    print("--- by cumulative time ---")
    st.sort_stats("cumulative").print_stats(top)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="sizes 4, 8, 16 only")
    ap.add_argument("--sizes", default=None, help="comma-separated block sizes out of 4,8,16,32,64")
    ap.add_argument("--cache", default=os.environ.get("SKYRIG_BENCH_DENSE_CACHE", "/tmp/skyrig-bench-dense"))
    ap.add_argument("--workers", type=int, default=None, help="render processes (default: all cores)")
    ap.add_argument("--profile", type=int, default=None, metavar="N", help="cProfile the chain on N images")
    ap.add_argument("--tile-cells", type=int, default=None,
                    help="DenseConfig.tile_cells (default: its default, one tile for these blocks); smaller tiles "
                         "show memory bounded by the tile (blocks reaching several tiles are matched again)")
    ap.add_argument("--cv-threads", type=int, default=1,
                    help="cv2.setNumThreads for both the chain and raw (default 1: per-core throughput; the machine "
                         "may be shared)")
    ap.add_argument("--cold", action="store_true",
                    help="time the chain from a cold process (its one-time start-up - numba loading the compiled "
                         "kernels, LLVM set-up - inside the chain's time); default: the start-up is run first on a "
                         "10 x 10 m area and reported on its own (like raw's OpenCV import, it is paid once per "
                         "process)")
    ap.add_argument("--lr-check", choices=("banded", "full", "opencv"), default=None,
                    help="SgmConfig.lr_check of the chain (default: DenseConfig's, the banded check); raw "
                         "StereoSGBM always runs OpenCV's internal check (disp12MaxDiff)")
    ap.add_argument("--lr-band-cols", type=int, default=None, metavar="PX",
                    help="SgmConfig.lr_band_cols_px of the chain (default: DenseConfig's; skyrig dsm --lr-band-cols)")
    ap.add_argument("--no-cloud", action="store_true",
                    help="the chain without the dense point cloud (DenseConfig.cloud=False, skyrig dsm --no-cloud)")
    ap.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    cache = Path(a.cache)
    if a.worker is not None:
        print("RESULT " + json.dumps(worker(cache, a.worker, a.tile_cells, a.cv_threads, a.cold, a.lr_check,
                                                 not a.no_cloud, a.lr_band_cols)))
        return
    if a.profile is not None:
        profile(cache, a.profile)
        return
    sizes = [int(x) for x in a.sizes.split(",")] if a.sizes else ([4, 8, 16] if a.quick else [4, 8, 16, 32, 64])
    bad = [s for s in sizes if s not in LAYOUT]
    if bad:
        raise SystemExit(f"sizes must be among {sorted(LAYOUT)}, not {bad}")
    ensure_block(cache, a.workers)
    import cv2

    print(f"{'cold start (start-up in the chain)' if a.cold else 'start-up timed apart (column start s)'}; "
          f"tile_cells {a.tile_cells or 'default'}; lr_check {a.lr_check or 'default'}; "
          f"lr_band_cols {'default' if a.lr_band_cols is None else a.lr_band_cols}; "
          f"{'no cloud' if a.no_cloud else 'with cloud'}; OpenCV {cv2.__version__}, "
          f"cv2.setNumThreads({a.cv_threads}) in chain "
          f"and raw, {os.cpu_count()} cores (load average {os.getloadavg()[0]:.1f}); cache {cache}")
    rows = []
    for n in sizes:
        cmd = [sys.executable, __file__, "--worker", str(n), "--cache", str(cache), "--cv-threads", str(a.cv_threads)]
        if a.cold:
            cmd.append("--cold")
        if a.tile_cells is not None:
            cmd += ["--tile-cells", str(a.tile_cells)]
        if a.lr_check is not None:
            cmd += ["--lr-check", a.lr_check]
        if a.no_cloud:
            cmd.append("--no-cloud")
        if a.lr_band_cols is not None:
            cmd += ["--lr-band-cols", str(a.lr_band_cols)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
        if p.returncode != 0 or not line:
            print(p.stdout[-3000:], p.stderr[-3000:])
            raise SystemExit(f"worker for {n} images failed")
        rows.append(json.loads(line[0][7:]))
    hdr = (f"{'images':>6} {'pairs':>5} {'blocks':>6} {'pair MP':>7} {'matched MP':>10} {'chain s':>7} "
           f"{'(plan/tiles/asm)':>18} {'raw s':>6} {'chain MP/s':>10} {'raw MP/s':>8} {'ratio':>5} "
           f"{'tiles':>5} {'s/image':>7} {'peak MB':>7} {'+MB':>5} {'valid %':>7} {'start s':>7}")
    print(hdr)
    for r in rows:
        mps_c = r["pair_mp"] / r["chain_s"]
        mps_r = r["pair_mp"] / r["raw_s"]
        print(f"{r['n']:>6} {r['pairs']:>5} {r['blocks']:>6} {r['pair_mp']:>7.2f} {r['matched_mp']:>10.2f} "
              f"{r['chain_s']:>7.2f} {r['plan_s']:>5.2f}/{r['tiles_s']:>5.2f}/{r['assemble_s']:>5.2f} "
              f"{r['raw_s']:>6.2f} {mps_c:>10.2f} {mps_r:>8.2f} {mps_c / mps_r:>5.2f} "
              f"{r['tiles']:>5} {r['chain_s'] / r['n']:>7.3f} {r['rss_chain_mb']:>7.0f} {r['rss_chain_mb'] - r['rss0_mb']:>5.0f} "
              f"{100 * r['valid_cells']:>7.1f} {r['startup_s']:>7.2f}")
    if len(rows) >= 2:
        a0, a1 = rows[0], rows[-1]
        k = a1["n"] / a0["n"]
        print(f"growth {a0['n']} -> {a1['n']} images (x{k:g}): chain time x{a1['chain_s'] / a0['chain_s']:.2f}, "
              f"pairs x{a1['pairs'] / max(a0['pairs'], 1):.2f}, peak RSS x{a1['rss_chain_mb'] / a0['rss_chain_mb']:.2f} "
              f"(+MB over the process after imports x{(a1['rss_chain_mb'] - a1['rss0_mb']) / max(a0['rss_chain_mb'] - a0['rss0_mb'], 1):.2f})")
    print("\nCPU seconds (this process; robust on a shared machine) and the chain's phases (CPU s):")
    names = sorted({k for r in rows for k in r["phases"]}, key=lambda k: -sum(r["phases"].get(k, (0, 0))[1] for r in rows))
    print(f"{'images':>6} {'chain':>7} {'raw':>6} {'ratio':>5} {'raw ov':>6} {'ratio ov':>8}  " + " ".join(f"{k:>11}" for k in names))
    for r in rows:
        print(f"{r['n']:>6} {r['chain_cpu_s']:>7.2f} {r['raw_cpu_s']:>6.2f} {r['raw_cpu_s'] / r['chain_cpu_s']:>5.2f} "
              f"{r['raw_ov_cpu_s']:>6.2f} {r['raw_ov_cpu_s'] / r['chain_cpu_s']:>8.2f}  "
              + " ".join(f"{r['phases'].get(k, (0, 0))[1]:>11.2f}" for k in names))
    print("\nDSM against the scene's truth inside the projection centres' rectangle + JUDGE_MARGIN_M (edge: cells within 2 GSD of "
          "building outlines; outliers: valid cells off by > 5 GSD):")
    print(f"{'images':>6} {'edge cells':>10} {'edge valid %':>12} {'edge outl %':>11} {'edge RMSE':>9} "
          f"{'flat valid %':>12} {'flat outl %':>11} {'flat NMAD':>9}  (RMSE, NMAD in GSD)")
    for r in rows:
        e, f = r["judge"]["edge"], r["judge"]["flat"]
        print(f"{r['n']:>6} {e['n']:>10} {100 * e['completeness']:>12.2f} {100 * e['outliers']:>11.2f} "
              f"{e['rmse_gsd']:>9.2f} {100 * f['completeness']:>12.2f} {100 * f['outliers']:>11.2f} "
              f"{f['nmad_gsd']:>9.3f}")
    tot_c = sum(r["chain_s"] for r in rows)
    tot_r = sum(r["raw_s"] for r in rows)
    cpu_c = sum(r["chain_cpu_s"] for r in rows)
    cpu_r = sum(r["raw_cpu_s"] for r in rows)
    cpu_o = sum(r["raw_ov_cpu_s"] for r in rows)
    print(f"overall: chain / raw SGBM throughput ratio {tot_r / tot_c:.2f} wall, {cpu_r / cpu_c:.2f} CPU (goal >= 0.6); "
          f"against raw SGBM on the overlap columns only ({sum(r['overlap_mp'] for r in rows) / sum(r['pair_mp'] for r in rows):.0%} "
          f"of the pixels): {cpu_o / cpu_c:.2f} CPU")
    cpu_m = sum(r.get("raw_mirror_cpu_s", 0.0) for r in rows)
    if cpu_m > 0:
        print(f"against raw SGBM plus the same matching of the mirrored pair (the chain's full left-right check, "
              f"{cpu_m:.2f} CPU s): {(cpu_r + cpu_m) / cpu_c:.2f} CPU -- what the chain costs beyond its two SGM passes")


if __name__ == "__main__":
    main()
