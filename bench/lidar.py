"""Benchmark: scanner georeferencing throughput, ICP and cloud-to-cloud on 1 M points, next to raw
Open3D and scipy calls made in the same run.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/lidar.py [--pulses 5000000] [--points 1000000]

Single-threaded by the environment variables above (the target is per core).
"""

from __future__ import annotations

import argparse
import os
import time

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from skyrig.geodesy.local import LocalTangentFrame  # noqa: E402
from skyrig.georef.eo import WorldFrame  # noqa: E402
from skyrig.lidar.compare import cloud_to_cloud  # noqa: E402
from skyrig.lidar.georef import PulseGeoreferencer, ScannerMount, georeference_scan  # noqa: E402
from skyrig.lidar.register import apply_transform, icp  # noqa: E402
from skyrig.lidar.scanner import HOKUYO_UTM_30LX_EW, RawScan  # noqa: E402
from skyrig.trajectory.trajectory import Trajectory  # noqa: E402


def timed(f, *a, repeat=1, **k):
    best = np.inf
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f(*a, **k)
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pulses", type=int, default=5_000_000)
    ap.add_argument("--points", type=int, default=1_000_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    # ---------------------------------------------------------------- georeferencing
    origin = (51.0, 13.7, 150.0)
    sc = HOKUYO_UTM_30LX_EW
    n_lines = int(np.ceil(args.pulses / sc.pulses_per_line))
    dur = n_lines / sc.lines_per_s
    tt = np.arange(-1.0, dur + 1.0, 0.005)  # 200 Hz navigation
    loc = np.c_[2.0 * tt, 0.3 * np.sin(tt), 5 + 0.2 * np.sin(0.3 * tt)]
    lat, lon, h = LocalTangentFrame(*origin).to_geodetic(loc)
    traj = Trajectory.from_rpy(tt, lat, lon, h, 3 * np.sin(tt), 2 * np.cos(0.5 * tt), 90 + 5 * np.sin(0.1 * tt))
    t, alpha = sc.pulse_times_and_angles(np.arange(n_lines) / sc.lines_per_s)
    t, alpha = t[: args.pulses], alpha[: args.pulses]
    scan = RawScan(t, rng.uniform(1, 30, len(t)), alpha)
    mount = ScannerMount(np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]), np.array([0.1, 0.0, 0.15]))
    xs = scan.sensor_xyz()
    geo = PulseGeoreferencer(traj, mount)
    te, _ = timed(geo.ecef, t, xs, repeat=2)
    print(f"georeference {len(t):,} pulses -> ECEF (kernel): {te:.3f} s = {len(t) / te / 1e6:.1f} M points/s")
    tl, _ = timed(georeference_scan, scan, traj, mount, WorldFrame.local(*origin))
    print(f"  raw scan -> local ENU (eq. 1 + kernel + frame): {tl:.3f} s = {len(t) / tl / 1e6:.1f} M points/s")
    m = min(len(t), 1_000_000)
    tm, _ = timed(georeference_scan, scan.subset(slice(0, m)), traj, mount, WorldFrame.map("EPSG:32633"))
    print(f"  raw scan -> UTM 33N via one batched pyproj call ({m:,} pts): {tm:.3f} s = {m / tm / 1e6:.1f} M points/s")
    ti, _ = timed(traj.interpolate, t[:m])
    print(f"  for scale: Trajectory.interpolate (general path, per pulse) on {m:,} times: {ti:.3f} s")

    # ---------------------------------------------------------------- ICP and C2C on 1 M points
    n = args.points
    xy = rng.uniform(0, 200, (n, 2))
    z = 3 * np.sin(xy[:, 0] / 15) + 2 * np.cos(xy[:, 1] / 11)
    target = np.c_[xy, z]
    xy2 = rng.uniform(0, 200, (n, 2))
    src_true = np.c_[xy2, 3 * np.sin(xy2[:, 0] / 15) + 2 * np.cos(xy2[:, 1] / 11) + rng.normal(0, 0.01, n)]
    mt = np.eye(4)
    c, s = np.cos(np.radians(0.5)), np.sin(np.radians(0.5))
    mt[:2, :2] = [[c, -s], [s, c]]
    mt[:3, 3] = [0.3, -0.2, 0.1]
    source = apply_transform(np.linalg.inv(mt), src_true)
    tc = target - target.mean(axis=0)
    sc_ = source - target.mean(axis=0)
    import open3d as o3d

    reg = o3d.pipelines.registration
    ta, ra = timed(icp, sc_, tc, method="point_to_plane", max_correspondence_distance=1.0, max_iterations=30,
                   backend="open3d", tolerance=1e-10)
    print(f"ICP point-to-plane, {n:,} points, skyrig icp (Open3D backend): {ta:.2f} s, RMSE {ra.rmse_m:.4f}, fitness {ra.fitness:.3f}")

    def raw_o3d():
        ps, pt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
        ps.points = o3d.utility.Vector3dVector(sc_)
        pt.points = o3d.utility.Vector3dVector(tc)
        pt.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(16))
        return reg.registration_icp(ps, pt, 1.0, np.eye(4), reg.TransformationEstimationPointToPlane(),
                                    reg.ICPConvergenceCriteria(1e-10, 1e-10, 30))

    tr, rr = timed(raw_o3d)
    print(f"  raw Open3D registration_icp (same settings): {tr:.2f} s, RMSE {rr.inlier_rmse:.4f}")
    tsp, rs = timed(icp, sc_, tc, method="point_to_plane", max_correspondence_distance=1.0, max_iterations=30,
                    backend="scipy", tolerance=1e-10)
    print(f"  skyrig scipy backend: {tsp:.2f} s ({rs.iterations} iterations), RMSE {rs.rmse_m:.4f}")
    truth_c = src_true - target.mean(axis=0)  # where the source points belong (centred frame)
    ea = np.linalg.norm(apply_transform(ra.matrix, sc_) - truth_c, axis=1).max()
    es = np.linalg.norm(apply_transform(rs.matrix, sc_) - truth_c, axis=1).max()
    print(f"  recovered pose: max point error {ea:.4f} m (Open3D), {es:.4f} m (scipy)")

    from scipy.spatial import cKDTree

    tb, tree = timed(cKDTree, tc)
    tq, _ = timed(tree.query, src_true - target.mean(axis=0), k=1)
    print(f"C2C {n:,} vs {n:,}: raw scipy cKDTree build {tb:.2f} s + query {tq:.2f} s")
    tn, _ = timed(cloud_to_cloud, src_true - target.mean(axis=0), tc, model="nearest", tree=tree)
    print(f"  skyrig cloud_to_cloud nearest (tree reused): {tn:.2f} s")
    tp, rp = timed(cloud_to_cloud, src_true - target.mean(axis=0), tc, model="plane", k=8, tree=tree)
    print(f"  skyrig cloud_to_cloud local plane k=8: {tp:.2f} s, RMS {np.sqrt(np.nanmean(rp.distance_m ** 2)):.4f} m "
          "(noise 0.010)")
    ps, pt = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    ps.points = o3d.utility.Vector3dVector(src_true - target.mean(axis=0))
    pt.points = o3d.utility.Vector3dVector(tc)
    to, _ = timed(ps.compute_point_cloud_distance, pt)
    print(f"  raw Open3D compute_point_cloud_distance (nearest, builds its own tree): {to:.2f} s")


if __name__ == "__main__":
    main()
