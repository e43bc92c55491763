"""Where the DSM loses the cells next to building edges (issue 10: >= 80 % of the cells within 2 GSD of building
outlines).

Usage::

    .venv/bin/python bench/dense_edges.py [--cache /tmp/skyrig-acc] [--sgm "{'edge_erode_px': 0}"]
        [--fusion "{'neighbour_cells': 0}"] [--pairs "{'pairs_per_image': 10}"] [--eo adjusted] [--points]

Data: the simulated ``midas-dsm`` project of ``bench/dense_acceptance.py`` (its cache; run that bench's ``midas``
case once first), nadir images, TRUE orientations (the dense stage alone), the height range of the
acceptance run.  The chain runs as :func:`skyrig.dense.surface.run_tile` does (match every block, triangulate),
keeping the points of every pair, then fuses them with the options given, neighbour confirmation included.

``--eo adjusted`` takes skyrig adjust's ``eo.csv`` of the acceptance run instead (the acceptance's DSM exactly).

Each cell of the planned area within 2 GSD of a building outline (the scene's truth, which skyrig never sees) is
put in one class: valid and within 5 GSD of the truth; valid but off by more; empty with no pair's point in it
(lost in the matcher: left-right check, foreground erosion, speckle filter, occlusion); empty with points of one
pair only (the fusion wants ``min_support`` pairs); empty with two or more pairs (they disagree: the
``min_support_ratio`` rule).  The same for the flat cells, and per cell-pair: the share of pairs whose median
height in an edge cell is within 5 GSD of the truth, too high, too low.

``--points``: every triangulated pixel's ray is also cast into the scene (the renderer's ray caster), giving the
surface the pixel truly shows (terrain, roof, wall) and its true disparity; the points that land in edge cells are
then split by that surface and by whether their disparity is within 1 px of the true one.  On midas-dsm (true
orientations, the DSM defaults) this shows where the wrong heights at building edges come from: of the points more
than 5 GSD above the truth in ground cells next to a building, 69 % are wall pixels and 85 % of those are matched
within 1 px (correct points on the wall, which project onto the outline and so into the cells on either side of
it), 13 % roof pixels (75 % within 1 px: a roof that reaches into a cell whose centre is ground); terrain
pixels given the roof's disparity (foreground fattening) are 17 %.  Of the points more than 5 GSD
below the truth in roof cells at the outline, 90 % are wall pixels.

Where the edge cells went (midas-dsm, ``--eo adjusted``, 4,139 edge cells; before fusion step 5): valid 80.0 %;
empty with no pair's point 8.9 % (ground side 12.9 %), one pair 3.3 %, two or more disagreeing pairs 7.8 % (ground
10.2 %).  Ground cells next to a wall have 3.75 pairs with a height against 14.7 in flat cells (both images of a pair
must be on the cell's side of the wall).  Changes one at a time (edge valid / within 5 GSD / all outliers): all 44
candidate pairs (``pairs_per_image`` 10) 80.6 / 68.1 / 0.45 % - the empty cells stay empty (8.3 % with no point);
no foreground erosion 79.9 / 62.6 / 0.78 % (ground cells with no point 12.9 -> 5.4 %, but what comes back is mostly
fattened roof); no wall test 78.0 / 64.8 / 0.51 %; no speckle filter 79.8 / 68.4 / 0.41 %; incidence limit off
80.3 / 68.5 / 0.42 %; holes taken as background in the erosion 79.3 / 67.7 / 0.47 %; ``min_support_ratio`` 0
82.2 / 69.1 / 0.47 %.  Fusion step 5 (two camps, ``FusionConfig.split_by_neighbours``): 83.0 / 70.4 / 0.45 %,
disagreeing-pair cells 7.8 -> 4.8 %.
"""

from __future__ import annotations

import argparse
import ast
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", default="/tmp/skyrig-acc")
    ap.add_argument("--sgm", default="{}", help="SgmConfig overrides (Python dict literal)")
    ap.add_argument("--fusion", default="{}", help="FusionConfig overrides (Python dict literal)")
    ap.add_argument("--pairs", default="{}", help="PairConfig overrides (Python dict literal)")
    ap.add_argument("--eo", default="truth", choices=("truth", "adjusted"),
                    help="orientations: the truth (default) or skyrig adjust's eo.csv of the acceptance run")
    ap.add_argument("--points", action="store_true", help="classify the points in edge cells by the surface their "
                    "pixel truly shows (ray cast into the scene) and their disparity error")
    a = ap.parse_args(argv)
    from scipy import ndimage

    from skyrig.cli._common import load_cameras, load_eo, select_heads
    from skyrig.dense.fusion import confirm_by_neighbours, fuse_grid
    from skyrig.dense.stereo import block_points, match_block
    from skyrig.dense.surface import DenseConfig, plan_dense
    from skyrig.georef.eo import WorldFrame
    from skyrig.pipeline.dense import ImageFiles, find_images
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    p = Path(a.cache) / "midas-dsm"
    acc = p / "output" / "dsm_adjusted" / "dense.json"
    if not acc.exists():
        raise SystemExit(f"{acc} missing: run `bench/dense_acceptance.py midas --cache {a.cache}` first")
    hr = tuple(json.loads(acc.read_text())["height_range"])
    eo_file = p / "truth" / "eo_map.csv" if a.eo == "truth" else p / "output" / "adjust" / "eo.csv"
    eo = select_heads(load_eo(str(eo_file), None, None, None, None), "nadir")
    cams = load_cameras([str(p / "truth" / "rig.yaml")])
    paths = find_images(eo, [str(p / "images")])
    frame = WorldFrame.map(eo.frame.crs, eo.frame.geoid)
    base = DenseConfig()
    cfg = replace(base, sgm=replace(base.sgm, **ast.literal_eval(a.sgm)),
                  fusion=replace(base.fusion, **ast.literal_eval(a.fusion)),
                  pairs=replace(base.pairs, **ast.literal_eval(a.pairs)), cloud=False)
    plan = plan_dense(eo, cams, frame, hr, None, cfg)
    loader = ImageFiles(paths, [(cams[str(c)].width, cams[str(c)].height) for c in plan.eo.camera])
    t = time.perf_counter()
    images: dict[int, np.ndarray] = {}
    pid_l, xyz_l, sig_l = [], [], []
    kind_l, derr_l = [], []  # with --points: per point the surface its pixel shows and its disparity error
    sv = build_survey(scenario_spec("midas-dsm", "ci", 1))
    sc = sv.scene
    local = WorldFrame.local(*sc.origin)
    for k, (pair, rect, blocks) in enumerate(zip(plan.pairs, plan.rects, plan.blocks)):
        for i in (pair.left, pair.right):
            if i not in images:
                images[i] = loader(i)
        for blk in blocks:
            disp, colour, _ = match_block(rect, images[pair.left], images[pair.right], blk, cfg.sgm)
            pp = block_points(rect, blk, disp, colour, cfg.sgm)
            pid_l.append(np.full(len(pp), k))
            xyz_l.append(plan.to_map(pp.xyz))
            sig_l.append(pp.sigma_h.astype(np.float64))
            if a.points:
                kind, derr = _pixel_truth(rect, blk, disp, cfg.sgm, plan.eo.frame, local, sc)
                assert len(kind) == len(pp)
                kind_l.append(kind)
                derr_l.append(derr)
    pid, xyz, sig = np.concatenate(pid_l), np.concatenate(xyz_l), np.concatenate(sig_l)
    print(f"{len(plan.pairs)} pairs matched and triangulated in {time.perf_counter() - t:.0f} s, {len(pid)} points; "
          f"sgm {a.sgm} fusion {a.fusion}")
    g = plan.grid
    H, W = g.shape
    h, n, sp, s, ch, cs, cn, ch2, cs2, cn2 = fuse_grid(g, pid, xyz[:, 0], xyz[:, 1], xyz[:, 2], sig, cfg.fusion,
                                                       candidates=True)
    voted = np.isfinite(h)
    kept = confirm_by_neighbours(h, n, s, ch, cs, cn, g.cell_m, cfg.fusion, ch2, cs2, cn2)

    # truth: the scene's surface and building outlines at the cell centres (local frame of the scene)
    xx, yy = g.cell_centres()
    zz = np.where(np.isfinite(h), h, np.nanmedian(h))
    L = local.from_ecef(frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), zz.ravel()], 1)))
    lx, ly = L[:, 0].reshape(H, W), L[:, 1].reshape(H, W)
    ar = sv.spec.flights[0].area
    inside = (lx >= ar[0]) & (lx <= ar[2]) & (ly >= ar[1]) & (ly <= ar[3])
    on = (sc.buildings.top_height(lx.ravel(), ly.ravel())[1] >= 0).reshape(H, W)
    edge = np.where(on, ndimage.distance_transform_edt(on), ndimage.distance_transform_edt(~on)) * g.cell_m <= 2 * plan.gsd_m
    err = (L[:, 2] - sc.surface_height(L[:, 0], L[:, 1])).reshape(H, W)
    err[~np.isfinite(h)] = np.nan
    tol = 5 * plan.gsd_m

    # per (cell, pair): median height of the pair's points in the cell, judged against the truth
    r, c = g.cell_of(xyz[:, 0], xyz[:, 1])
    m = (r >= 0) & (r < H) & (c >= 0) & (c < W) & np.isfinite(sig)  # points with a DSM height (walls have none)
    cell = r[m] * W + c[m]
    key = cell * (int(pid.max()) + 1) + pid[m]
    order = np.lexsort((xyz[m, 2], key))
    key_s, h_s = key[order], xyz[m, 2][order]
    uk, st, cnt = np.unique(key_s, return_index=True, return_counts=True)
    med = 0.5 * (h_s[st + (cnt - 1) // 2] + h_s[st + cnt // 2])
    ucell = uk // (int(pid.max()) + 1)
    tl = sc.surface_height(L[:, 0], L[:, 1])
    truth_map = frame.from_ecef(local.to_ecef(np.stack([L[:, 0], L[:, 1], tl], 1)))[:, 2]  # true height, map frame
    e_cp = med - truth_map[ucell]
    npairs = np.bincount(ucell, minlength=H * W).reshape(H, W)
    print(f"{'class':12s} {'cells':>7s} {'valid':>6s} {'good':>6s} {'>5GSD':>6s} {'by nbr':>6s} {'0 pairs':>7s} "
          f"{'1 pair':>6s} {'split':>6s}  pairs/cell good/high/low of cell-pairs")
    for name, mask in (("flat", inside & ~edge), ("edge", inside & edge), ("edge roof", inside & edge & on),
                       ("edge ground", inside & edge & ~on)):
        N = int(mask.sum())
        v = mask & np.isfinite(h)
        inv = mask & ~np.isfinite(h)
        sel = mask.ravel()[ucell]
        ee = e_cp[sel]
        print(f"{name:12s} {N:7d} {100 * v.sum() / N:5.1f}% {100 * (v & (np.abs(err) <= tol)).sum() / N:5.1f}% "
              f"{100 * (v & (np.abs(err) > tol)).sum() / N:5.1f}% {100 * (mask & kept).sum() / N:5.1f}% "
              f"{100 * (inv & (npairs == 0)).sum() / N:6.1f}% {100 * (inv & (npairs == 1)).sum() / N:5.1f}% "
              f"{100 * (inv & (npairs >= 2)).sum() / N:5.1f}%  {sel.sum() / N:5.2f} "
              f"{np.mean(np.abs(ee) <= tol):.2f}/{np.mean(ee > tol):.2f}/{np.mean(ee < -tol):.2f}")
    if a.points:
        kind, derr = np.concatenate(kind_l), np.concatenate(derr_l)
        rr, cc = g.cell_of(xyz[:, 0], xyz[:, 1])
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        near = ok & (inside & edge)[np.clip(rr, 0, H - 1), np.clip(cc, 0, W - 1)]
        print("points in edge cells left out of the DSM as wall points (SgmConfig.wall_max_nz): " + ", ".join(
            f"{kn} {np.mean(~np.isfinite(sig[near & (kind == kk)])):.2f}" for kk, kn in ((1, "terrain"), (2, "roof"), (3, "wall"))))
        ok &= np.isfinite(sig)
        rr, cc = np.clip(rr, 0, H - 1), np.clip(cc, 0, W - 1)
        e_p = xyz[:, 2] - truth_map.reshape(H, W)[rr, cc]
        names = {1: "terrain", 2: "roof", 3: "wall"}
        print("points with a DSM height in edge cells by the surface their pixel shows (share; in brackets: share of those matched "
              "within 1 px of the true disparity)")
        for name, mask in (("edge ground", inside & edge & ~on), ("edge roof", inside & edge & on)):
            sel = ok & mask[rr, cc]
            for lab, q in (("> 5 GSD high", e_p > tol), ("> 5 GSD low", e_p < -tol), ("within 5 GSD", np.abs(e_p) <= tol)):
                s2 = sel & q
                if not s2.any():
                    continue
                parts = []
                for kk, kn in names.items():
                    s3 = s2 & (kind == kk)
                    parts.append(f"{kn} {s3.sum() / s2.sum():.2f} ({np.mean(np.abs(derr[s3]) <= 1) if s3.any() else 0:.2f})")
                print(f"  {name:12s} {lab:13s} {s2.sum() / sel.sum():5.2f} of {int(sel.sum())} points: " + ", ".join(parts))
    e_all = err[inside & np.isfinite(h)]
    e_edge = err[inside & edge & np.isfinite(h)]
    e_flat = err[inside & ~edge & np.isfinite(h)]
    nm = 1.4826 * np.median(np.abs(e_flat - np.median(e_flat)))
    print(f"flat NMAD {nm / plan.gsd_m:.3f} GSD, bias {np.median(e_flat) / plan.gsd_m:+.3f} GSD; edge RMSE "
          f"{np.sqrt(np.mean(e_edge ** 2)) / plan.gsd_m:.1f} GSD; cells off by > 5 GSD: {100 * np.mean(np.abs(e_all) > tol):.2f} % "
          f"of valid cells in the area (pair vote alone: {int(voted[inside].sum())} cells, neighbour confirmation "
          f"+{int(kept[inside].sum())})")


def _pixel_truth(rect, blk, disp, sgm, frame, scene_frame, scene):  # type: ignore[no-untyped-def]
    """For the points :func:`skyrig.dense.stereo.block_points` makes of ``disp`` (same order): the kind of surface
    each pixel's ray hits first in the scene (1 terrain, 2 roof, 3 wall, 0 sky) and matched minus true disparity."""
    from skyrig.dense._kernels import triangulate_block
    from skyrig.simulate.render import cast_rays

    d = np.nan_to_num(np.ascontiguousarray(disp, np.float32), nan=-1.0)
    rr, cc = triangulate_block(d, float(blk.u0), float(blk.v0), float(rect.focal_px), float(rect.base_m),
                               np.ascontiguousarray(rect.rotation), np.ascontiguousarray(rect.centres[0]),
                               float(sgm.disparity_sigma_px), float(np.cos(np.radians(sgm.max_incidence_deg))),
                               np.zeros(d.shape + (1,), np.uint8))[:2]
    if len(rr) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    C = rect.centres[0]
    dirs = rect.rect_directions(blk.u0 + cc + 0.0, blk.v0 + rr + 0.0) @ rect.rotation.T
    o_s = scene_frame.from_ecef(frame.to_ecef(C[None]))[0]
    hits = cast_rays(scene, o_s, scene_frame.from_ecef(frame.to_ecef(C[None] + dirs)) - o_s)
    X = frame.from_ecef(scene_frame.to_ecef(np.where(np.isfinite(hits.xyz), hits.xyz, 0.0)))
    depth = -((X - C) @ rect.rotation)[:, 2]
    derr = disp[rr, cc] - rect.focal_px * rect.base_m / depth
    derr[~np.isfinite(hits.xyz[:, 0])] = np.nan
    return np.asarray(hits.kind), derr


if __name__ == "__main__":
    main()
