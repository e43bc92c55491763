"""skyrig's bundle adjuster against Ceres (through pycolmap) on BAL problems: time, iterations, cost, memory.

    .venv/bin/python bench/bal.py                          # ../shared/data/bal/problem-49-7776-pre.txt
    .venv/bin/python bench/bal.py --generate 1000 200000   # a generated BAL block (cameras, points)
    .venv/bin/python bench/bal.py --series 200,1000,3000,6000   # generated blocks, 200 points per camera
    .venv/bin/python bench/bal.py --ceres auto,sparse_schur,iterative_schur   # the Ceres configurations run
    .venv/bin/python bench/bal.py --skip-skyrig ...        # Ceres only (or --skip-ceres)
    .venv/bin/python bench/bal.py --engine scipy           # skyrig's reference (scipy sparse) path

Solvers: skyrig and, by default, two Ceres configurations: ``ceres-auto`` (what a COLMAP user gets:
COLMAP picks DENSE_SCHUR up to 50 images, SPARSE_SCHUR up to 1,000, ITERATIVE_SCHUR above) and
``ceres-sparse_schur`` (Ceres's best direct configuration for these blocks).  Every run of every solver
is a fresh child process (this script with ``--child``) that reads the block, loads what it needs
(skyrig: the numba kernels from numba's cache, through a one-iteration warm-up; Ceres: pycolmap), and
runs the solver once; the child reports its figures and its peak resident memory (``VmHWM`` of
/proc/self/status at its end) and the resident memory just before the solver.  Each solver runs
``--repeat`` times (default 2) in turns and the best wall time is reported (other work on the machine
disturbs single runs); a run longer than ``--timeout`` is stopped and reported as such.  "iterations"
counts successful and unsuccessful steps for both (Ceres's ``num_successful_steps +
num_unsuccessful_steps``).  The table gives per solver: linear solver used, threads, solve wall time,
iterations, final BAL cost, peak and solve-phase memory, and the ratios skyrig / that solver.

Both solvers start from the same block and stop on the same tolerances (Ceres's definitions:
function 1e-6, parameter 1e-8, gradient 1e-10, at most 100 iterations), both Levenberg-Marquardt with
the points eliminated by the Schur complement, no gauge fixed (as Ceres's own BAL example).

The BAL model on a COLMAP camera
--------------------------------
BAL: ``P = R X + t``, ``p = -P_xy / P_z``, ``uv = f (1 + k1 |p|^2 + k2 |p|^4) p`` (x right, y up).
COLMAP's ``RADIAL`` model with params ``(f, cx, cy, k1, k2)`` projects ``q = Q_xy / Q_z`` to
``f (1 + k1 |q|^2 + k2 |q|^4) q + (cx, cy)``.  With ``cam_from_world = F (R, t)``, ``F = diag(1, -1, -1)``
(180 degrees about x, so that BAL's points in front, ``P_z < 0``, are in front for COLMAP, ``Q_z > 0``):
``Q = F P``, ``q = (-P_x / P_z, P_y / P_z) = (p_x, -p_y)`` and ``|q| = |p|``; so with ``cx = cy = 0`` and the
measured ``v`` negated the two residuals are equal up to the sign of the second component, and the
costs are identical.  One camera (own f, k1, k2) and one trivial rig/frame per BAL camera.

Known difference: COLMAP's reprojection cost gives a zero residual to an observation whose point is
behind the camera (``Q_z <= 0``); BAL's model has no such test (problem-49-7776 has 31 such
observations at the start).  By default the bench therefore drops the observations behind their
camera at the start (and points left with one ray) from the block both solvers get, and re-evaluates
the *BAL* cost (all remaining observations, skyrig's model) at Ceres's solution so that the final
costs compare the same objective; ``--keep-behind`` runs the file as it is.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust.block import BalCamera, Block
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import SERIAL_BELOW, factor_cost, levenberg_marquardt
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from skyrig.io.bal import read_bal

ROOT = Path(__file__).resolve().parents[1]
FLIP = np.diag([1.0, -1.0, -1.0])  # COLMAP camera (x right, y down, z forward) from BAL camera (z back)
TOL = dict(function_tolerance=1e-6, parameter_tolerance=1e-8, gradient_tolerance=1e-10, max_iterations=100)


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


def bal_cost(block: Block) -> float:
    """The BAL cost ``0.5 * sum(r^2)`` of a block, all observations, skyrig's model."""
    m = Model(block, AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none")))
    return factor_cost(m.evaluate(State.from_block(block), jacobians=False))


def drop_behind(block: Block) -> tuple[Block, int, int]:
    """The block without observations whose point is behind the camera at the start (BAL: ``P_z >= 0``),
    and without points left with fewer than two observations.  Returns ``(block, n_obs_dropped,
    n_points_dropped)``."""
    Rwc = block.station_rotation[block.image_station] @ block.image_rotation
    Cs = block.station_centre[block.image_station]
    o = block.obs_image
    z = np.einsum("nj,nj->n", Rwc[o][:, :, 2], block.point_xyz[block.obs_point] - Cs[o])
    keep = z < 0
    n_rays = np.bincount(block.obs_point[keep], minlength=block.n_points)
    pkeep = n_rays >= 2
    keep &= pkeep[block.obs_point]
    new_index = np.cumsum(pkeep) - 1
    out = block.copy()
    out.point_name, out.point_xyz = block.point_name[pkeep], block.point_xyz[pkeep]
    out.obs_image, out.obs_point = block.obs_image[keep], new_index[block.obs_point[keep]]
    out.obs_pixel = block.obs_pixel[keep]
    out.obs_sigma_px = block.obs_sigma_px[keep]  # type: ignore[index]
    return out, int((~keep).sum()), int((~pkeep).sum())


# ----------------------------------------------------------------------------------------- Ceres side
def to_colmap(block: Block):  # type: ignore[no-untyped-def]
    """A ``pycolmap.Reconstruction`` equal to a BAL block (one RADIAL camera, rig and frame per image).

    Returns ``(reconstruction, point3D_ids)``; image and camera ids are ``index + 1``.
    """
    import pycolmap

    if not all(isinstance(c, BalCamera) for c in block.cameras):
        raise ValueError("to_colmap needs a block of BalCamera cameras (read_bal)")
    rec = pycolmap.Reconstruction()
    Rwc = block.station_rotation[block.image_station] @ block.image_rotation
    R = np.swapaxes(Rwc, 1, 2)  # BAL camera_from_world
    t = -np.einsum("nij,nj->ni", R, block.station_centre[block.image_station])
    order = np.argsort(block.obs_image, kind="stable")
    ci, pi = block.obs_image[order], block.obs_point[order]
    uv = block.obs_pixel[order] * np.array([1.0, -1.0])
    starts = np.searchsorted(ci, np.arange(block.n_images + 1))
    kp_index = np.arange(len(ci)) - starts[ci]
    half = int(np.ceil(np.abs(uv).max())) + 1 if len(uv) else 1
    for i in range(block.n_images):
        c = block.cameras[int(block.image_camera[i])]
        cam = pycolmap.Camera.create_from_model_name(i + 1, "RADIAL", c.f, 2 * half, 2 * half)
        cam.params = [c.f, 0.0, 0.0, c.k1, c.k2]
        rec.add_camera_with_trivial_rig(cam)
        img = pycolmap.Image(name=str(block.image_name[i]), keypoints=uv[starts[i]:starts[i + 1]],
                             camera_id=i + 1, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(pycolmap.Rotation3d(FLIP @ R[i]), FLIP @ t[i]))
    po = np.argsort(pi, kind="stable")
    ps = np.searchsorted(pi[po], np.arange(block.n_points + 1))
    img_id = (ci + 1).tolist()
    kp = kp_index.tolist()
    TE = pycolmap.TrackElement
    ids = np.empty(block.n_points, np.int64)
    for k in range(block.n_points):
        track = pycolmap.Track([TE(img_id[j], kp[j]) for j in po[ps[k]:ps[k + 1]].tolist()])
        ids[k] = rec.add_point3D(block.point_xyz[k], track)
    return rec, ids


def from_colmap(block: Block, rec, point_ids: np.ndarray) -> Block:  # type: ignore[no-untyped-def]
    """The block with poses, intrinsics and points taken from a (solved) reconstruction."""
    out = block.copy()
    R = np.empty((block.n_images, 3, 3))
    C = np.empty((block.n_images, 3))
    cams = []
    for i in range(block.n_images):
        im = rec.image(i + 1)
        T = im.cam_from_world()
        Rb = FLIP @ T.rotation.matrix()
        tb = FLIP @ np.asarray(T.translation)
        R[i], C[i] = Rb.T, -Rb.T @ tb
        prm = rec.camera(i + 1).params
        cams.append(BalCamera(block.cameras[i].name, float(prm[0]), float(prm[3]), float(prm[4])))
    # BAL blocks from read_bal: one station, image and camera per BAL camera, identity station_from_camera
    out.station_rotation, out.station_centre, out.cameras = R, C, cams
    out.point_xyz = np.array([rec.point3D(int(p)).xyz for p in point_ids])
    return out


def run_ceres(block: Block, threads: int = -1, linear_solver: str = "auto") -> dict:
    """Ceres (COLMAP's bundle adjuster) on a BAL block; costs as Ceres reports them and the BAL cost."""
    import pycolmap

    t0 = time.perf_counter()
    rec, ids = to_colmap(block)
    t_build = time.perf_counter() - t0
    opt = pycolmap.BundleAdjustmentOptions()
    opt.print_summary = False
    opt.refine_focal_length = True
    opt.refine_extra_params = True
    opt.refine_principal_point = False
    so = opt.ceres.solver_options
    so.function_tolerance = TOL["function_tolerance"]
    so.parameter_tolerance = TOL["parameter_tolerance"]
    so.gradient_tolerance = TOL["gradient_tolerance"]
    so.max_num_iterations = TOL["max_iterations"]
    so.num_threads = threads
    if linear_solver != "auto":
        opt.ceres.auto_select_solver_type = False
        # pycolmap 4.2 exposes the Ceres enums only as the types of the option fields
        # (there is no ``pycolmap.LinearSolverType``)
        so.linear_solver_type = getattr(type(so.linear_solver_type), linear_solver.upper())
        if linear_solver.lower() == "iterative_schur":
            so.preconditioner_type = getattr(type(so.preconditioner_type), "SCHUR_JACOBI")
    cfg = pycolmap.BundleAdjustmentConfig()
    for i in range(block.n_images):
        cfg.add_image(i + 1)
    cfg.fix_gauge(pycolmap.BundleAdjustmentGauge.UNSPECIFIED)
    t1 = time.perf_counter()
    ba = pycolmap.create_default_bundle_adjuster(opt, cfg, rec)
    s = ba.solve()
    t_solve = time.perf_counter() - t1
    cs = s.ceres_summary
    final = from_colmap(block, rec, ids)
    return dict(build_s=t_build, initial_cost=cs.initial_cost, final_cost=cs.final_cost,
                final_bal_cost=bal_cost(final), iterations=cs.num_successful_steps + cs.num_unsuccessful_steps,
                successful=cs.num_successful_steps,
                solve_s=t_solve, ceres_total_s=cs.total_time_in_seconds,
                linear_solver=str(cs.linear_solver_type_used).split(".")[-1], threads=cs.num_threads_used,
                termination=str(cs.termination_type).split(".")[-1])


# ----------------------------------------------------------------------------------------- skyrig side
def run_skyrig(block: Block, engine: str = "auto") -> dict:
    """skyrig's Levenberg-Marquardt (:func:`skyrig.adjust.solver.levenberg_marquardt`) on a BAL block."""
    import numba

    cfg = AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none"),
                       statistics=StatisticsOptions(compute=False))
    c0 = bal_cost(block)
    t1 = time.perf_counter()
    model = Model(block, cfg)
    _, info = levenberg_marquardt(model, State.from_block(block), TOL["max_iterations"], TOL["function_tolerance"],
                                  TOL["parameter_tolerance"], TOL["gradient_tolerance"], engine=engine)
    return dict(initial_cost=c0, final_cost=info.final_cost, iterations=info.iterations + info.unsuccessful,
                successful=info.iterations, solve_s=time.perf_counter() - t1, termination=info.message,
                linear_solver=info.linear_solver.split(" ")[0], linear_solver_reason=info.linear_solver,
                engine=info.engine, threads=(1 if block.n_observations < SERIAL_BELOW else numba.get_num_threads())
                if info.engine == "numba" else 1)


# ----------------------------------------------------------------------------------------- driver
def _mib(field: str) -> float:
    """A ``/proc/self/status`` memory field (``VmHWM``, ``VmRSS``) in MiB."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


def load(path: str, keep_behind: bool) -> tuple[Block, int, int]:
    """A BAL file as the block both solvers get (see the module notes on ``drop_behind``)."""
    block = read_bal(path)
    if keep_behind:
        return block, 0, 0
    return drop_behind(block)


def child(solver: str, path: str, keep_behind: bool, threads: int, engine: str) -> dict:
    """One solver on one problem, in this (fresh) process; its figures with the peak resident memory."""
    block, _, _ = load(path, keep_behind)
    if solver == "skyrig":  # load the numba kernels (from numba's disk cache) before the timed run, on a
        # small block (so that the warm-up's memory is not counted in the solver's peak)
        with tempfile.TemporaryDirectory() as d:
            generate(Path(d) / "warm.txt", 16, 800)
            small = read_bal(str(Path(d) / "warm.txt"))
        levenberg_marquardt(Model(small, AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none"))), State.from_block(small), 1,
                            engine=engine)
        del small
    else:
        import pycolmap  # noqa: F401  (its import is not the solver's memory)
    base = _mib("VmRSS")
    if solver == "skyrig":
        r = run_skyrig(block, engine)
        r["final_bal_cost"] = r["final_cost"]
    else:
        r = run_ceres(block, threads, solver.split("-", 1)[1])
    r.update(base_mib=base, peak_mib=_mib("VmHWM"))
    return r


def run_child(solver: str, path: str, a: argparse.Namespace) -> dict:
    """:func:`child` in a subprocess (so that each solver's peak memory is its own); ``{"error": ...}`` on
    failure or timeout."""
    import json
    import subprocess
    import sys

    cmd = [sys.executable, __file__, "--child", solver, "--problem", path, "--threads", str(a.threads),
           "--engine", a.engine] + (["--keep-behind"] if a.keep_behind else [])
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=a.timeout)
    except subprocess.TimeoutExpired:
        return dict(error=f"timeout after {a.timeout:.0f} s")
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    if out.returncode or not lines:
        return dict(error=f"exit {out.returncode}: {(out.stderr.strip().splitlines() or [''])[-1]}")
    return json.loads(lines[-1][7:])


def _fmt(v: object) -> str:
    return f"{v:.7g}" if isinstance(v, float) else str(v)


def bench_problem(name: str, path: str, a: argparse.Namespace, solvers: list[str]) -> list[dict]:
    """All solvers on one problem, each ``--repeat`` times in turns, each run in its own process; the best
    wall time per solver (its peak memory the largest over its runs)."""
    t0 = time.perf_counter()
    block0 = read_bal(path)
    block, n_o, n_p = load(path, a.keep_behind)
    print(f"\n{name}: {block0.n_images} cameras, {block0.n_points} points, {block0.n_observations} observations; "
          + (f"dropped {n_o} observations with the point behind the camera and {n_p} points left with < 2 "
             f"(--keep-behind keeps them): " if not a.keep_behind else "")
          + f"{block.n_points} points, {block.n_observations} observations (read in {time.perf_counter() - t0:.1f} s)",
          flush=True)
    problem = dict(problem=name, cameras=block.n_images, points=block.n_points, observations=block.n_observations)
    best: dict[str, dict] = {}
    failed: set[str] = set()
    for rep in range(a.repeat):  # in turns, so that all solvers see the same machine load
        for s in solvers:
            if s in failed:
                continue
            r = run_child(s, path, a)
            print(f"  {s:20s} run {rep + 1}:", ", ".join(f"{k}={_fmt(v)}" for k, v in r.items()), flush=True)
            if "error" in r:
                failed.add(s)
                best[s] = r
                continue
            if s not in best or r["solve_s"] < best[s]["solve_s"]:
                r["peak_mib"] = max(r["peak_mib"], best.get(s, {}).get("peak_mib", 0.0))
                best[s] = r
            else:
                best[s]["peak_mib"] = max(best[s]["peak_mib"], r["peak_mib"])
    return [dict(problem, solver=s, **best[s]) for s in solvers if s in best]


def print_table(rows: list[dict], repeat: int) -> None:
    """One line per problem and solver; the ratios skyrig / that solver (time, peak memory, final cost)."""
    print(f"\nbest of {repeat} wall times per solver, each run in its own process; peak MiB = the process's VmHWM "
          f"(block read + solver), solve MiB = VmHWM - VmRSS before the solver (for Ceres that includes building "
          f"the COLMAP reconstruction); iterations = successful + unsuccessful steps; cost = the BAL cost at the "
          f"solver's solution (skyrig's model, same observations); sk/x = skyrig / that solver")
    hdr = (f"{'problem':34s} {'solver':20s} {'linear solver':16s} {'thr':>3s} {'time s':>8s} {'iter':>5s} "
           f"{'final cost':>14s} {'peak MiB':>9s} {'solve MiB':>9s} {'t sk/x':>7s} {'peak sk/x':>9s} {'solve sk/x':>10s} {'cost sk/x-1':>12s}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        sk = next((q for q in rows if q["problem"] == r["problem"] and q["solver"] == "skyrig" and "error" not in q),
                  None)
        if "error" in r:
            print(f"{r['problem'][:34]:34s} {r['solver']:20s} {r['error']}")
            continue
        rt = rm = rs = rc = ""
        if sk is not None and r is not sk:
            rt = f"{sk['solve_s'] / r['solve_s']:7.2f}"
            rm = f"{sk['peak_mib'] / r['peak_mib']:9.2f}"
            rs = f"{(sk['peak_mib'] - sk['base_mib']) / (r['peak_mib'] - r['base_mib']):10.2f}"
            rc = f"{sk['final_bal_cost'] / r['final_bal_cost'] - 1:12.2e}"
        print(f"{r['problem'][:34]:34s} {r['solver']:20s} {r['linear_solver']:16s} {r['threads']:3d} "
              f"{r['solve_s']:8.2f} {r['iterations']:5d} {r['final_bal_cost']:14.7e} {r['peak_mib']:9.0f} "
              f"{r['peak_mib'] - r['base_mib']:9.0f} {rt:>7s} {rm:>9s} {rs:>10s} {rc:>12s}")


def main() -> None:
    import json
    import sys

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problem", default=str(ROOT / ".." / "shared" / "data" / "bal" / "problem-49-7776-pre.txt"))
    ap.add_argument("--generate", nargs=2, type=int, metavar=("CAMERAS", "POINTS"))
    ap.add_argument("--series", help="comma-separated camera counts of generated blocks, e.g. 200,1000,3000,6000 "
                                     "(points: --points-per-camera each)")
    ap.add_argument("--points-per-camera", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated blocks")
    ap.add_argument("--threads", type=int, default=-1, help="Ceres threads (-1: all cores)")
    ap.add_argument("--ceres", default="auto,sparse_schur",
                    help="comma-separated Ceres linear solvers, each run: auto (COLMAP's choice by image count), "
                         "dense_schur, sparse_schur, iterative_schur (SCHUR_JACOBI)")
    ap.add_argument("--linear-solver", help="one Ceres linear solver (the same as --ceres with one entry)")
    ap.add_argument("--keep-behind", action="store_true",
                    help="keep observations whose point is behind the camera (COLMAP's cost zeroes them, "
                         "BAL's does not: the two then minimise different objectives)")
    ap.add_argument("--skip-skyrig", action="store_true")
    ap.add_argument("--skip-ceres", action="store_true")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each solver (the best time is reported)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per solver run (then reported as such)")
    ap.add_argument("--engine", default="auto", help="skyrig's engine: auto, numba or scipy (reference path)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print("RESULT " + json.dumps(child(a.child, a.problem, a.keep_behind, a.threads, a.engine)), flush=True)
        return
    solvers = [] if a.skip_skyrig else ["skyrig"]
    if not a.skip_ceres:
        solvers += ["ceres-" + s.strip().lower() for s in (a.linear_solver or a.ceres).split(",") if s.strip()]
    print(f"solvers: {', '.join(solvers)}; os.cpu_count() = {os.cpu_count()}; python {sys.version.split()[0]}")
    rows: list[dict] = []
    if a.series or a.generate:
        sizes = ([(int(c), int(c) * a.points_per_camera) for c in a.series.split(",")] if a.series
                 else [tuple(a.generate)])
        with tempfile.TemporaryDirectory() as d:
            for n_cam, n_pts in sizes:
                p = Path(d) / f"gen-{n_cam}.txt"
                t0 = time.perf_counter()
                generate(p, n_cam, n_pts, seed=a.seed)
                print(f"generated {n_cam} cameras x {n_pts} points (seed {a.seed}) in {time.perf_counter() - t0:.1f} s",
                      flush=True)
                rows += bench_problem(f"generated {n_cam} x {n_pts} s{a.seed}", str(p), a, solvers)
                p.unlink()
                print_table(rows, a.repeat)  # after every size: a long series leaves its figures as it goes
    else:
        rows += bench_problem(Path(a.problem).name, a.problem, a, solvers)
        print_table(rows, a.repeat)


if __name__ == "__main__":
    main()
