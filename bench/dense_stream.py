"""Peak memory of the dense stage's assembly and writing against the block size: the tile-by-tile writer
(``skyrig.pipeline.dense_stream.StreamedDsm``) next to the whole-array path (``assemble`` + ``write_dsm_cog`` +
``write_hillshade_png`` + ``write_dense_cloud``) on synthetic tile results (no matching: a smooth surface with
noise, every tile the same size and the same number of cloud points), each run in a child process (``VmHWM``).

    .venv/bin/python bench/dense_stream.py                           # 2 x 2, 3 x 3, 4 x 4 tiles of 512 cells
    .venv/bin/python bench/dense_stream.py --tiles 2 4 6 --points 300000 --paths streamed

The whole-array path's peak grows with the number of tiles (it holds every tile's result, the grids and the
concatenated cloud); the streamed path's stays at one tile's.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile

CHILD = r"""
import json, sys, time
from pathlib import Path
from types import SimpleNamespace
import numpy as np
from skyrig.dense.grid import GridSpec
from skyrig.dense.surface import DenseConfig, TileResult
from skyrig.georef.eo import WorldFrame

path, n, cells, points, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), Path(sys.argv[5])
grid = GridSpec(500000.0, 5800000.0, 0.25, n * cells, n * cells)
plan = SimpleNamespace(grid=grid, tiles=grid.tiles(cells), config=DenseConfig(tile_cells=cells),
                       out_frame=WorldFrame.map("EPSG:25832"), pairs=(), gsd_m=0.25, image_level=0)

def tile(k):
    rng = np.random.default_rng(k)
    r0, c0, h, w = plan.tiles[k]
    y, x = np.mgrid[r0:r0 + h, c0:c0 + w]
    z = (60 + 5 * np.sin(x / 300) * np.cos(y / 200) + rng.normal(0, 0.05, (h, w))).astype(np.float32)
    z[rng.random((h, w)) < 0.1] = np.nan
    cand = np.where(np.isnan(z), z[::-1], np.nan).astype(np.float32)
    xyz = np.column_stack([grid.x0 + (c0 + rng.random(points) * w) * grid.cell_m,
                           grid.y0 - (r0 + rng.random(points) * h) * grid.cell_m, 60 + rng.random(points)])
    cloud = (xyz, rng.integers(0, 255, (points, 3), dtype=np.uint8), rng.normal(0, 1, (points, 3)).astype(np.float32),
             rng.integers(2, 9, points).astype(np.int16), rng.random(points).astype(np.float32))
    sup = np.where(np.isnan(z), 0, 3).astype(np.int16)
    sg = np.where(np.isnan(z), np.nan, 0.05).astype(np.float32)
    return TileResult((r0, c0, h, w), z, sup, sg.copy(), sg, cloud, points, 1, 1.0, 0.0, cand, sg + 0.01,
                      np.where(np.isnan(cand), 0, 1).astype(np.int16))

t0 = time.perf_counter()
if path == "streamed":
    from skyrig.pipeline.dense_stream import StreamedDsm
    (out / "scratch").mkdir()
    with StreamedDsm(plan, out / "scratch") as s:
        for k in range(len(plan.tiles)):
            s.add(k, tile(k))
        s.finish()
        s.publish(out / "dsm.tif", out / "dsm_hillshade.png", out / "cloud.laz")
else:
    from skyrig.dense.surface import assemble
    from skyrig.io.dense_laz import write_dense_cloud
    from skyrig.io.dsm_cog import write_dsm_cog, write_hillshade_png
    dsm, cloud, _ = assemble(plan, [tile(k) for k in range(len(plan.tiles))])
    write_dsm_cog(out / "dsm.tif", dsm)
    write_hillshade_png(out / "dsm_hillshade.png", dsm)
    write_dense_cloud(out / "cloud.laz", cloud)
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")) / 1024
print("BENCH " + json.dumps({"path": path, "tiles": len(plan.tiles), "cells": grid.width * grid.height,
                             "points": points * len(plan.tiles), "seconds": time.perf_counter() - t0,
                             "peak_mib": hwm}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tiles", type=int, nargs="+", default=[2, 3, 4], help="tiles per side of the grid")
    ap.add_argument("--cells", type=int, default=512, help="tile side in cells")
    ap.add_argument("--points", type=int, default=250_000, help="cloud points per tile")
    ap.add_argument("--paths", nargs="+", default=["whole", "streamed"], choices=["whole", "streamed"])
    a = ap.parse_args()
    rows = []
    print(f"{'path':9s} {'tiles':>5s} {'cells':>10s} {'points':>10s} {'seconds':>8s} {'peak MiB':>9s}")
    for n in a.tiles:
        for path in a.paths:
            with tempfile.TemporaryDirectory(prefix="skyrig-dense-stream-") as d:
                r = subprocess.run([sys.executable, "-c", CHILD, path, str(n), str(a.cells), str(a.points), d],
                                   capture_output=True, text=True)
            line = next((x for x in r.stdout.splitlines() if x.startswith("BENCH ")), None)
            if line is None:
                raise SystemExit(f"{path} with {n} x {n} tiles failed:\n{r.stderr[-2000:]}")
            row = json.loads(line[6:])
            rows.append(row)
            print(f"{path:9s} {row['tiles']:5d} {row['cells']:10d} {row['points']:10d} {row['seconds']:8.1f} "
                  f"{row['peak_mib']:9.0f}", flush=True)


if __name__ == "__main__":
    main()
