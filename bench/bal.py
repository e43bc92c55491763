"""skyrig's bundle adjuster on BAL problems: final cost and wall time.

    .venv/bin/python bench/bal.py                          # ../shared/data/bal/problem-49-7776-pre.txt
    .venv/bin/python bench/bal.py --generate 1000 200000   # a generated BAL block (cameras, points)

The Ceres side (through pycolmap) is NOT implemented yet: pycolmap 4.2.1 is installed, and the plan is
to build a pycolmap.Reconstruction with RADIAL cameras (f, cx=cy=0, k1, k2; camera frame flipped
diag(1,-1,-1) so that COLMAP's u = X/Z equals BAL's -P_x/P_z and v = -y_BAL) and run
pycolmap.create_default_bundle_adjuster(options, config, reconstruction).solve().
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import factor_cost
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io.bal import read_bal

ROOT = Path(__file__).resolve().parents[1]


def generate(path: Path, n_cam: int, n_pts: int, obs_per_point: int = 5, seed: int = 0) -> None:
    """A BAL file: points in a slab, cameras on a grid above looking down, noisy start."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n_cam)))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n_cam] * 10.0
    C = np.column_stack([g, np.full(n_cam, 30.0)])
    X = np.column_stack([rng.uniform(-5, side * 10 + 5, (n_pts, 2)), rng.uniform(-3, 3, n_pts)])
    # each point seen by the obs_per_point nearest cameras
    from scipy.spatial import cKDTree

    _, cam_idx = cKDTree(C[:, :2]).query(X[:, :2], k=obs_per_point)
    ci = cam_idx.reshape(-1)
    pi = np.repeat(np.arange(n_pts), obs_per_point)
    Rwc = matrix_from_rotvec(rng.normal(0, 0.05, (n_cam, 3)))  # near nadir (camera looks along -z)
    f, k1, k2 = 500.0, -0.02, 0.001
    P = np.einsum("nji,nj->ni", Rwc[ci], X[pi] - C[ci])
    p = -P[:, :2] / P[:, 2:3]
    r2 = (p**2).sum(1)
    uv = f * (1 + k1 * r2 + k2 * r2**2)[:, None] * p + rng.normal(0, 0.5, (len(ci), 2))
    order = np.argsort(ci, kind="stable")
    R = np.swapaxes(Rwc, 1, 2) @ matrix_from_rotvec(rng.normal(0, 0.002, (n_cam, 3)))
    t = -np.einsum("nij,nj->ni", R, C + rng.normal(0, 0.05, (n_cam, 3)))
    cam = np.column_stack([rotvec_from_matrix(R), t, np.full(n_cam, f * 1.01), np.zeros(n_cam), np.zeros(n_cam)])
    with open(path, "w") as fh:
        fh.write(f"{n_cam} {n_pts} {len(ci)}\n")
        np.savetxt(fh, np.column_stack([ci[order], pi[order], uv[order]]), fmt=["%d", "%d", "%.6f", "%.6f"])
        np.savetxt(fh, cam.reshape(-1, 1), fmt="%.12g")
        np.savetxt(fh, (X + rng.normal(0, 0.05, X.shape)).reshape(-1, 1), fmt="%.12g")


def run_skyrig(path: Path) -> dict:
    t0 = time.perf_counter()
    b = read_bal(path)
    t_read = time.perf_counter() - t0
    cfg = AdjustConfig(intrinsics="free", datum="none", max_iterations=100, function_tolerance=1e-6)
    m = Model(b, cfg)
    c0 = factor_cost(m.evaluate(State.from_block(b), jacobians=False))
    t1 = time.perf_counter()
    r = adjust(b, cfg)
    return dict(cameras=b.n_images, points=b.n_points, observations=b.n_observations, read_s=t_read,
                initial_cost=c0, final_cost=r.info.final_cost, iterations=r.info.iterations,
                solve_s=time.perf_counter() - t1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default=str(ROOT / ".." / "shared" / "data" / "bal" / "problem-49-7776-pre.txt"))
    ap.add_argument("--generate", nargs=2, type=int, metavar=("CAMERAS", "POINTS"))
    a = ap.parse_args()
    if a.generate:
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "gen.txt"
            generate(p, *a.generate)
            res = run_skyrig(p)
    else:
        res = run_skyrig(Path(a.problem))
    print("skyrig:", ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in res.items()))
    print("ceres (pycolmap): not run - see the module docstring")


if __name__ == "__main__":
    main()
