"""Terrain benchmark on real airborne laser data: skyrig's ground class against the data provider's, next to a
second published filter, and speed next to the peer libraries run directly on the same cloud.

Usage::

    .venv/bin/python bench/terrain.py [--laz ../shared/data/autzen-lidar/autzen_trim.laz] [--cell 1.0]

Data: ``autzen_trim.laz`` (PDAL's test data, 110k points, Oregon State Plane in international feet; the provider's
classes 1 and 2).  Coordinates are scaled to metres (the filters' parameters are metres).

Rows:

* **skyrig**: :func:`skyrig.terrain.classify_points` (the cloth simulation filter through the
  ``cloth-simulation-filter`` package, then the ASPRS rule), default parameters;
* **CSF direct**: the same package called directly with the same parameters (the peer library alone: the cost of
  skyrig's rule is the difference);
* **Bulldozer**: the second published filter, CNES's DSM-to-DTM extraction (Lallement et al. 2023, PyPI
  ``bulldozer-dtm``), run on a DSM gridded from the cloud (highest point per ``--cell``), a point being ground when
  within CSF's class threshold (0.5 m) of its DTM; skipped with a note when not installed.

Figures against the provider's class: type I (provider ground called non-ground / provider ground), type II
(provider non-ground called ground / provider non-ground), Cohen's kappa; and type II on the provider's
non-ground points more than 1 m above the provider's ground (a TIN of its ground points), and kappa on the
provider's ground plus those points (``k >1 m``): the provider's class 1 holds many points at ground level (its
ground class is thinned: 66 % of its class-1 points lie within 0.3 m of its ground TIN), which every filter calls
ground.  Then the DTM
from skyrig's class against the DTM from the provider's class (both :func:`skyrig.terrain.make_dtm` on one grid):
NMAD and bias over the cells both measure.  Speed: points per second of classification; cells per second of
``make_dtm`` next to scipy's linear TIN interpolation (``griddata``) of the same ground points onto the same grid.
Peak memory (``ru_maxrss``) of the process is printed at the end.

``--memory 1 4 16``: peak memory of the main process of ``skyrig terrain classify`` (tiles of 500 m with a 50 m
buffer on two local Dask worker processes) and ``skyrig terrain dtm`` (1 m cells) on synthetic clouds of 1, 4 and
16 million points (4 points per m^2 over a growing square of sloped ground with box buildings, written as LAZ by a
separate process): each size in a fresh process, ``ru_maxrss`` after each step.

Measured (2026-11-29, 2 shared cores under heavy load, so the seconds are not speeds)::

    .venv/bin/python bench/terrain.py --memory 1 4

                       before (whole cloud read, twice)      after (tiles streamed: terrain3 branch)
    points      classify peak   + dtm peak         classify peak   + dtm peak
    1,000,000         310 MiB      312 MiB               242 MiB      282 MiB   (one 500 m tile: read whole)
    4,000,000         812 MiB      812 MiB               247 MiB      343 MiB   (2 x 2 tiles)

Before, the main process held the cloud (twice: ``read_las`` and ``laspy.read``) and every buffered tile's copy at
once: ~170 MiB more per million points.  After, classification's peak does not grow with the cloud (one chunk, one
tile's result, one byte per point); the DTM's grows with the grid (1 m cells: 4 x the cells at 4 x the points).

Real laser (``autzen_trim.laz``, same run): skyrig type I 6.65 %, type II 67.66 % (4.61 % on the provider's
non-ground > 1 m above its ground), kappa 0.149 (0.885 on ground + those points); CSF direct 6.10 / 67.70 / 4.62 %,
kappa 0.152 / 0.891; Bulldozer 40.23 / 47.93 / 5.08 %, kappa 0.085 / 0.526.  DTM from skyrig's class vs the
provider's on 17,072 cells both measure: NMAD 0.020 m, bias +0.013 m, RMS 0.234 m.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def kappa(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa of two boolean labelings."""
    po = np.mean(a == b)
    pe = np.mean(a) * np.mean(b) + np.mean(~a) * np.mean(~b)
    return float((po - pe) / (1 - pe))


def figures(name: str, ground: np.ndarray, truth: np.ndarray, high: np.ndarray, seconds: float) -> dict:
    t1 = float(np.mean(~ground[truth]))
    t2 = float(np.mean(ground[~truth]))
    t2h = float(np.mean(ground[~truth & high]))
    clear = truth | high
    return {"name": name, "type1": t1, "type2": t2, "type2_high": t2h, "kappa": kappa(ground, truth),
            "kappa_clear": kappa(ground[clear], truth[clear]), "seconds": seconds, "pps": len(ground) / seconds}


def csf_direct(xyz: np.ndarray) -> np.ndarray:
    import CSF

    from skyrig.terrain.classify import GroundFilter, _quiet_stdout

    p = GroundFilter()
    c = CSF.CSF()
    c.params.bSloopSmooth = p.slope_smooth
    c.params.cloth_resolution = p.cloth_resolution_m
    c.params.class_threshold = p.class_threshold_m
    c.params.rigidness = p.rigidness
    c.params.interations = p.iterations
    c.params.time_step = p.time_step
    c.setPointCloud(xyz - xyz.min(axis=0))
    g, ng = CSF.VecInt(), CSF.VecInt()
    with _quiet_stdout():
        c.do_filtering(g, ng, False)
    out = np.zeros(len(xyz), bool)
    out[np.asarray(g, dtype=np.int64)] = True
    return out


def bulldozer_ground(xyz: np.ndarray, cell: float, threshold: float) -> np.ndarray | None:
    try:
        from bulldozer.pipeline.bulldozer_pipeline import dsm_to_dtm
    except ImportError:
        print("Bulldozer (pip install bulldozer-dtm) is not installed: its row is left out")
        return None
    import rasterio
    from affine import Affine

    from skyrig.dense.grid import GridSpec
    from skyrig.terrain.dtm import sample_grid

    g = GridSpec.covering(xyz[:, 0].min(), xyz[:, 1].min(), xyz[:, 0].max() + 1e-6, xyz[:, 1].max() + 1e-6, cell)
    r, c = g.cell_of(xyz[:, 0], xyz[:, 1])
    dsm = np.full(g.shape, -32768.0, np.float32)
    np.maximum.at(dsm, (r, c), xyz[:, 2].astype(np.float32))
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "dsm.tif"
        with rasterio.open(p, "w", driver="GTiff", width=g.width, height=g.height, count=1, dtype="float32",
                           nodata=-32768.0, transform=Affine(*g.transform), crs="EPSG:32610") as ds:
            ds.write(dsm, 1)
        dsm_to_dtm(dsm_path=str(p), output_dir=str(Path(tmp) / "out"), nb_max_workers=2)
        with rasterio.open(Path(tmp) / "out" / "dtm.tif") as ds:
            dtm = ds.read(1).astype(np.float64)
            if ds.nodata is not None:
                dtm[dtm == ds.nodata] = np.nan
    z = sample_grid(g, dtm, xyz[:, 0], xyz[:, 1])
    return np.abs(xyz[:, 2] - z) <= threshold


def make_cloud(n: int, path: str, density: float = 4.0, seed: int = 0) -> None:
    """A synthetic LAZ of ``n`` points (EPSG:25832): sloped, undulating ground and box buildings (one per 50 m x 50 m
    block, 10-25 m wide, 6-15 m high) over a square of ``n / density`` m^2."""
    import laspy

    rng = np.random.default_rng(seed)
    side = float(np.sqrt(n / density))
    x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
    z = 100 + 0.02 * x + 2 * np.sin(x / 80.0) * np.cos(y / 120.0) + rng.normal(0, 0.05, n)
    bi, bj = np.floor(x / 50), np.floor(y / 50)
    brng = np.random.default_rng(seed + 1)
    nb = int(np.ceil(side / 50)) + 1
    half = brng.uniform(5, 12.5, (nb, nb))
    height = brng.uniform(6, 15, (nb, nb))
    bi_, bj_ = bi.astype(int), bj.astype(int)
    inb = (np.abs(x - (bi + 0.5) * 50) < half[bi_, bj_]) & (np.abs(y - (bj + 0.5) * 50) < half[bi_, bj_])
    z = np.where(inb, z + height[bi_, bj_], z)
    h = laspy.LasHeader(point_format=3, version="1.4")
    h.offsets = [500000.0, 5800000.0, 0.0]
    h.scales = [0.001, 0.001, 0.001]
    h.add_crs(__import__("pyproj").CRS.from_epsg(25832))
    las = laspy.LasData(h)
    las.x, las.y, las.z = x + 500000.0, y + 5800000.0, z
    las.write(path)


def measure_memory(path: str, out: str) -> dict:
    """Main-process peak memory (``ru_maxrss``, MiB) after ``classify_cloud_file`` and after ``dtm_folder``."""
    import json as _json

    from skyrig.pipeline.terrain import classify_cloud_file, dtm_folder

    def peak() -> float:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    base = peak()
    t = time.perf_counter()
    r = classify_cloud_file(path, Path(out) / "classified.laz", executor="local", workers=2)
    t_c = time.perf_counter() - t
    p_c = peak()
    t = time.perf_counter()
    dtm_folder(Path(out) / "classified.laz", Path(out) / "dtm", cell_m=1.0)
    res = {"points": r["points"], "imports_mib": base, "classify_peak_mib": p_c, "dtm_peak_mib": peak(),
           "classify_s": t_c, "dtm_s": time.perf_counter() - t}
    print(_json.dumps(res), flush=True)
    return res


def memory_table(millions: list[float]) -> None:
    import json as _json
    import subprocess

    rows = []
    for m in millions:
        with tempfile.TemporaryDirectory() as tmp:
            laz = str(Path(tmp) / "cloud.laz")
            subprocess.run([sys.executable, __file__, "--make-cloud", str(int(m * 1e6)), laz], check=True)
            p = subprocess.run([sys.executable, __file__, "--measure-memory", laz, tmp], check=True,
                               capture_output=True, text=True)
            rows.append(_json.loads(p.stdout.strip().splitlines()[-1]))
            print(rows[-1], flush=True)
    print(f"\n{'points':>10s} {'imports':>9s} {'classify':>9s} {'+ dtm':>9s} {'MiB/Mpt':>8s} {'classify s':>10s} "
          f"{'dtm s':>7s}")
    for r in rows:
        print(f"{r['points']:10d} {r['imports_mib']:8.0f}M {r['classify_peak_mib']:8.0f}M {r['dtm_peak_mib']:8.0f}M "
              f"{(r['dtm_peak_mib'] - r['imports_mib']) / (r['points'] / 1e6):8.0f} {r['classify_s']:10.1f} "
              f"{r['dtm_s']:7.1f}")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--make-cloud":
        return make_cloud(int(sys.argv[2]), sys.argv[3])
    if len(sys.argv) > 1 and sys.argv[1] == "--measure-memory":
        return measure_memory(sys.argv[2], sys.argv[3]) and None
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--memory", type=float, nargs="+", metavar="MILLIONS",
                    help="only the memory table: synthetic clouds of these many million points")
    ap.add_argument("--laz", default=str(ROOT.parent / "shared" / "data" / "autzen-lidar" / "autzen_trim.laz"))
    ap.add_argument("--cell", type=float, default=1.0, help="DTM / Bulldozer DSM cell (m)")
    a = ap.parse_args()
    if a.memory:
        return memory_table(a.memory)

    import laspy
    from scipy.interpolate import LinearNDInterpolator, griddata

    from skyrig.georef.eo import WorldFrame
    from skyrig.terrain import classify_points, make_dtm

    las = laspy.read(a.laz)
    ft = float(las.header.parse_crs().axis_info[0].unit_conversion_factor)
    xyz = np.column_stack([las.x, las.y, las.z]) * ft
    truth = np.asarray(las.classification) == 2
    tin = LinearNDInterpolator(xyz[truth, :2], xyz[truth, 2])
    hag_p = xyz[:, 2] - tin(xyz[:, :2])
    high = np.nan_to_num(hag_p, nan=0.0) > 1.0
    print(f"{a.laz}: {len(xyz)} points, {truth.sum()} provider ground, {np.sum(~truth & high)} provider non-ground "
          f"> 1 m above its ground; units {ft} m")
    rows = []
    t = time.perf_counter()
    cl = classify_points(xyz, None)
    rows.append(figures("skyrig", cl.code == 2, truth, high, time.perf_counter() - t))
    t = time.perf_counter()
    g = csf_direct(xyz)
    rows.append(figures("CSF direct", g, truth, high, time.perf_counter() - t))
    t = time.perf_counter()
    gb = bulldozer_ground(xyz, a.cell, 0.5)
    if gb is not None:
        rows.append(figures("Bulldozer", gb, truth, high, time.perf_counter() - t))
    print(f"\n{'filter':12s} {'type I':>8s} {'type II':>8s} {'II >1 m':>8s} {'kappa':>7s} {'k >1 m':>7s} {'s':>7s} "
          f"{'pts/s':>9s}")
    for r in rows:
        print(f"{r['name']:12s} {r['type1'] * 100:7.2f}% {r['type2'] * 100:7.2f}% {r['type2_high'] * 100:7.2f}% "
              f"{r['kappa']:7.3f} {r['kappa_clear']:7.3f} {r['seconds']:7.2f} {r['pps']:9.0f}")
    # DTMs of the two classes on one grid
    frame = WorldFrame.map("EPSG:32610")  # a metre frame for the arrays (the file's own CRS is in feet)
    from skyrig.dense.grid import GridSpec

    grid = GridSpec.covering(xyz[:, 0].min(), xyz[:, 1].min(), xyz[:, 0].max() + 1e-6, xyz[:, 1].max() + 1e-6, a.cell)
    t = time.perf_counter()
    d_sky = make_dtm(xyz, cl.code, frame, grid=grid)
    t_dtm = time.perf_counter() - t
    d_pro = make_dtm(xyz, np.where(truth, 2, 1), frame, grid=grid)
    both = (d_sky.source == 1) & (d_pro.source == 1)
    e = (d_sky.height - d_pro.height)[both].astype(np.float64)
    nmad = 1.4826 * np.median(np.abs(e - np.median(e)))
    xx, yy = grid.cell_centres()
    t = time.perf_counter()
    griddata(xyz[cl.code == 2, :2], xyz[cl.code == 2, 2], (xx, yy), method="linear")
    t_tin = time.perf_counter() - t
    print(f"\nDTM {grid.width} x {grid.height} cells of {a.cell} m: skyrig's class vs the provider's on {both.sum()} "
          f"cells both measure: NMAD {nmad:.3f} m, bias {np.median(e):+.3f} m, RMS {np.sqrt(np.mean(e ** 2)):.3f} m")
    print(f"make_dtm {grid.width * grid.height / t_dtm:.0f} cells/s vs scipy griddata (linear TIN) "
          f"{grid.width * grid.height / t_tin:.0f} cells/s")
    print(f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
