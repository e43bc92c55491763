"""Direct-georeferencing and world-to-image throughput, next to pyproj's raw transform rate.

Run:  .venv/bin/python bench/georef.py [--events 1000000] [--points 10000000]

Prints, in one process on one core (numpy single-threaded work):
* direct georeferencing of N events (MIDAS penta rig) into ECEF and into a UTM map frame,
* world-to-image projection of M points (Cartesian frame, one camera, Brown distortion and without),
* pyproj's raw rate for geodetic -> ECEF and geodetic -> UTM on the same number of points.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pyproj  # noqa: E402

from skyrig.camera import FrameCamera  # noqa: E402
from skyrig.camera.brown import BrownDistortion  # noqa: E402
from skyrig.georef.direct import direct_georeference  # noqa: E402
from skyrig.georef.eo import WorldFrame  # noqa: E402
from skyrig.georef.ground import project_points  # noqa: E402
from skyrig.geometry import Pose, matrix_from_opk  # noqa: E402
from skyrig.rig.presets import midas  # noqa: E402
from skyrig.trajectory import CameraEvents, Trajectory  # noqa: E402


def timed(fn, *a, **k):
    t = time.perf_counter()
    out = fn(*a, **k)
    return out, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--events", type=int, default=1_000_000)
    ap.add_argument("--points", type=int, default=10_000_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    # ---- trajectory: 2 h at 200 Hz
    t = np.arange(0.0, 7200.0, 0.005)
    lat = 52.0 + 1e-5 * t
    lon = 9.5 + 0.02 * np.sin(t / 600.0)
    traj = Trajectory.from_rpy(t, lat, lon, 1000 + 5 * np.sin(t / 50), np.sin(t), 2 + np.cos(t / 3), (t * 0.1) % 360 - 180)
    rig = midas()
    heads = np.array(list(rig.heads))
    n = args.events
    te = np.sort(rng.uniform(1.0, 7199.0, n // len(heads))).repeat(len(heads))[:n]
    hd = np.tile(heads, n // len(heads) + 1)[:n]
    ev = CameraEvents(te, hd, np.array([f"i{k}" for k in range(n)]), np.full(n, np.nan), np.arange(n) // len(heads))

    _, dt_ecef = timed(direct_georeference, traj, rig, ev, WorldFrame.ecef())
    _, dt_map = timed(direct_georeference, traj, rig, ev, WorldFrame.map("EPSG:25832"))
    print(f"direct georeferencing, {n:,} events x MIDAS heads:")
    print(f"  ECEF frame       {dt_ecef:7.2f} s   {n / dt_ecef / 1e6:6.2f} M events/s")
    print(f"  UTM 32N (grid)   {dt_map:7.2f} s   {n / dt_map / 1e6:6.2f} M events/s")

    # ---- world to image
    m = args.points
    pose = Pose(matrix_from_opk(1.0, -2.0, 30.0, unit="deg"), np.array([0.0, 0.0, 1000.0]), "world", "camera")
    pts = np.column_stack([rng.uniform(-300, 300, m), rng.uniform(-200, 200, m), rng.uniform(0, 50, m)])
    cam = FrameCamera("c", 5616, 3744, 0.0064, 28.0)
    cam_b = cam.with_(distortion=BrownDistortion(k1=-1e-4, k2=2e-7, p1=1e-6, p2=-2e-6))
    _, dt_w2i = timed(project_points, cam, pose, pts)
    _, dt_w2i_b = timed(project_points, cam_b, pose, pts)
    print(f"world-to-image, {m:,} points (one core):")
    print(f"  pinhole          {dt_w2i:7.2f} s   {m / dt_w2i / 1e6:6.2f} M points/s   (target >= 5)")
    print(f"  Brown distortion {dt_w2i_b:7.2f} s   {m / dt_w2i_b / 1e6:6.2f} M points/s")

    # ---- pyproj raw rates on the same number of points
    lon_p = rng.uniform(9, 10, m)
    lat_p = rng.uniform(52, 53, m)
    h_p = rng.uniform(0, 100, m)
    t_ecef = pyproj.Transformer.from_crs(4979, 4978, always_xy=True)
    t_utm = pyproj.Transformer.from_crs(4326, 25832, always_xy=True)
    _, dt_pe = timed(t_ecef.transform, lon_p, lat_p, h_p)
    _, dt_pu = timed(t_utm.transform, lon_p, lat_p)
    print(f"pyproj raw transform, {m:,} points:")
    print(f"  geodetic -> ECEF {dt_pe:7.2f} s   {m / dt_pe / 1e6:6.2f} M points/s")
    print(f"  geodetic -> UTM  {dt_pu:7.2f} s   {m / dt_pu / 1e6:6.2f} M points/s")
    print(f"ratio world-to-image (pinhole) / pyproj geodetic->UTM: {dt_pu / dt_w2i:.1f}x")


if __name__ == "__main__":
    main()
