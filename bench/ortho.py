"""Orthorectification speed and memory: skyrig's true orthomosaic next to a plain ``cv2.remap`` of the same images
onto the same grid, in the same run.

Data: the simulator's ``midas-dsm`` flight (nadir head, 12 images of 640 x 427 px rendered from the true
orientations), the scene's true surface as the DSM on a UTM grid at the images' GSD.

Printed per run:

* ``remap``: the peer - for every image, the grid's surface points projected with the same camera model
  (distortion included) and ``cv2.remap`` (bilinear) onto the grid, last image wins (no occlusion, no
  seamlines, no blending): what a plain orthorectification does;
* ``skyrig tiles``: :func:`skyrig.dense.ortho.run_ortho_tile` over all tiles (occlusion by a depth buffer per image,
  feathered blend, fallback) - the same work per cell as the peer plus visibility;
* ``skyrig total``: planning (per-image views on the DSM grid, regions, gains) + tiles;

as megapixels of input image area per second (sum over images of the grid cells they cover) and the ratio
skyrig / remap (goal of the issue: tiles >= 0.5 x remap).  Peak memory is printed
for two tile sizes (tracemalloc peak of the run in a child process) to show what follows the tile.

Run: ``.venv/bin/python bench/ortho.py [--images N] [--repeat 3]`` (peer and skyrig timed alternately ``--repeat``
times, the fastest of each reported, with the ratio of every pair).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _setup(n_images: int):
    from skyrig.dense.grid import GridSpec
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.geometry.pose import Pose
    from skyrig.simulate.judge import true_dsm
    from skyrig.simulate.render import render_image
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    survey = build_survey(scenario_spec("midas-dsm", "ci", 1))
    eo = survey.eo_true
    eo = eo.subset(np.flatnonzero(["nadir" in str(n) for n in eo.image])[:n_images])
    cams = {str(c): survey.rig_true.head(str(h)).camera for c, h in zip(eo.camera, eo.head)}
    images = [render_image(survey.scene, cams[str(eo.camera[k])], Pose(eo.rotation[k], eo.centre[k], "world", "camera"),
                           noise_dn=1.0, seed=k) for k in range(len(eo))]
    frame = WorldFrame.map("EPSG:25832", None)
    c = frame.from_ecef(eo.frame.to_ecef(eo.centre))
    cell = 0.285
    x0, x1 = c[:, 0].min() - 90, c[:, 0].max() + 90
    y0, y1 = c[:, 1].min() - 60, c[:, 1].max() + 60
    grid = GridSpec(float(np.floor(x0 / cell) * cell), float(np.ceil(y1 / cell) * cell), cell,
                    int((x1 - x0) / cell), int((y1 - y0) / cell))
    return eo, cams, images, true_dsm(survey.scene, grid, frame)


def plain_remap(eo, cams, images, dsm) -> tuple[float, float]:
    """The peer: project the grid's surface points into each image and cv2.remap; returns (seconds, megapixels)."""
    import cv2

    from skyrig.geodesy.frame import local_frame_for

    xx, yy = dsm.grid.cell_centres()
    zz = dsm.height.astype(np.float64)
    local = local_frame_for(dsm.frame.to_ecef(np.array([[xx.mean(), yy.mean(), float(np.nanmean(zz))]])))
    t0 = time.perf_counter()
    p = local.from_ecef(dsm.frame.to_ecef(np.stack([xx.ravel(), yy.ravel(), zz.ravel()], 1)))
    eo_l = eo.to_frame(local)
    out = np.zeros(xx.shape + (3,), np.uint8)
    mp = 0.0
    for i in range(len(eo_l)):
        cam = cams[str(eo_l.camera[i])]
        pc = (p - eo_l.centre[i]) @ eo_l.rotation[i]
        uv = cam.project_pixels(pc).reshape(xx.shape + (2,)).astype(np.float32)
        inside = cam.in_image(uv)
        mp += inside.sum() / 1e6
        col = cv2.remap(images[i], uv[..., 0], uv[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        out[inside] = col[inside]
    return time.perf_counter() - t0, mp


def skyrig_ortho(eo, cams, images, dsm, tile_cells: int) -> dict:
    from skyrig.dense.ortho import OrthoConfig, _OrthoTileJob, assemble_ortho, plan_ortho

    t0 = time.perf_counter()
    plan = plan_ortho(eo, cams, dsm, images.__getitem__, config=OrthoConfig(tile_cells=tile_cells, cell_m=dsm.grid.cell_m))
    t1 = time.perf_counter()
    job = _OrthoTileJob(plan, images.__getitem__)
    tiles = [job(k) for k in range(len(plan.tiles))]
    t2 = time.perf_counter()
    m = assemble_ortho(plan, tiles)
    return {"plan_s": t1 - t0, "tiles_s": t2 - t1, "total_s": t2 - t0, "cells_valid": int(m.valid.sum()),
            "tiles": len(plan.tiles)}


def _child(n: int, tile: int) -> None:
    import tracemalloc

    eo, cams, images, dsm = _setup(n)
    skyrig_ortho(eo, cams, images, dsm, tile)  # compile the kernels outside the measurement
    tracemalloc.start()
    r = skyrig_ortho(eo, cams, images, dsm, tile)
    r["peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    print(json.dumps(r))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--images", type=int, default=12)
    ap.add_argument("--repeat", type=int, default=3,
                    help="interleaved repeats of peer and skyrig; the fastest of each is reported (on a shared "
                         "machine a single pair of timings swings by 2x with the other processes)")
    ap.add_argument("--child", nargs=2, type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        _child(*a.child)
        return
    eo, cams, images, dsm = _setup(a.images)
    print(f"{len(eo)} images 640 x 427, grid {dsm.grid.width} x {dsm.grid.height} cells of {dsm.grid.cell_m} m")
    # warm up the compiled kernels, then time
    skyrig_ortho(eo, cams, images, dsm, 4096)
    runs_r, runs_s = [], []
    for _ in range(max(a.repeat, 1)):  # interleaved, so that both see the same load
        rs, mp = plain_remap(eo, cams, images, dsm)
        runs_r.append(rs)
        runs_s.append(skyrig_ortho(eo, cams, images, dsm, 4096))
    rs = min(runs_r)
    sk = {k: min(r[k] for r in runs_s) for k in ("plan_s", "tiles_s", "total_s")}
    pairs = [rr / r["tiles_s"] for rr, r in zip(runs_r, runs_s)]
    print(f"{len(runs_r)} interleaved runs; fastest of each below; tiles ratio per run "
          + ", ".join(f"{x:.2f}" for x in pairs))
    print(f"remap (peer)   {rs:7.2f} s  {mp / rs:7.2f} MP/s  ({mp:.2f} MP of image area on the grid)")
    print(f"skyrig tiles   {sk['tiles_s']:7.2f} s  {mp / sk['tiles_s']:7.2f} MP/s  ratio {rs / sk['tiles_s']:.2f} x remap")
    print(f"skyrig total   {sk['total_s']:7.2f} s  {mp / sk['total_s']:7.2f} MP/s  ratio {rs / sk['total_s']:.2f} x remap "
          f"(plan {sk['plan_s']:.2f} s)")
    for tile in (256, 4096):
        r = subprocess.run([sys.executable, str(Path(__file__)), "--images", str(a.images), "--child", str(a.images),
                            str(tile)], capture_output=True, text=True, check=True)
        j = json.loads(r.stdout.strip().splitlines()[-1])
        print(f"tile {tile:5d} cells: {j['tiles']:3d} tiles, peak memory of the run {j['peak_mb']:.0f} MB "
              f"(numpy/Python allocations, tracemalloc; the mosaic itself is {dsm.grid.width * dsm.grid.height * 5 / 2**20:.0f} MB)")


if __name__ == "__main__":
    main()
