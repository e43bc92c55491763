"""Where the time and memory of the penta-rig adjustment go: one size of ``bench/scale.py``, per phase.

    nice .venv/bin/python bench/scale_profile.py --exposures 500

The functions of the adjustment are wrapped from outside (nothing in ``skyrig.adjust`` changes): per phase,
the number of calls, the wall time, the resident memory on entry (relative to the start of ``adjust()``), the process CPU time (all threads)
and the largest rise of the resident set above that entry (sampled every 2 ms).  Phases nest: the time of
``check_datum`` includes its ``assemble`` and ``schur_matrix``; ``lm`` includes ``evaluate``, ``engine_init``,
``linearize``, ``reduced_system`` and ``factor+solve``.  Before the adjustment it reports what the
simulated block itself holds (the sum of its arrays) and what the bench's generation cost.
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import sys
import threading
import time
from collections import defaultdict

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from scale import _rss, block_shape  # noqa: E402
from scale_sim import penta_block  # noqa: E402


class _Sampler:
    def __init__(self, period: float = 0.002) -> None:
        self.period = period
        self.active: list[list[float]] = []  # [start rss, peak rss] of the open phases
        self.stop = threading.Event()
        self.t = threading.Thread(target=self._run, daemon=True)
        self.t.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            r = _rss()
            for fr in list(self.active):
                if r > fr[1]:
                    fr[1] = r
            time.sleep(self.period)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--exposures", type=int, default=500)
    ap.add_argument("--points-per-exposure", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--boresight", default="free")
    a = ap.parse_args()

    import importlib

    A = importlib.import_module("skyrig.adjust.adjust")  # the module (the package re-exports the function)
    import skyrig.adjust.linalg as L
    import skyrig.adjust.model as M
    import skyrig.adjust.solver as S
    from skyrig.adjust import AdjustConfig
    from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
    from skyrig.adjust.synthetic import synthetic_block
    from skyrig.rig.presets import midas

    small, _ = synthetic_block(seed=a.seed, n_strips=2, n_per_strip=3, n_points=60, rig=midas(), height_m=500.0,
                               n_control=9)
    A.adjust(small, AdjustConfig(statistics=StatisticsOptions(compute=False),
                                 solver=SolverOptions(max_iterations=2)))

    smp = _Sampler()
    stats: dict[str, list[float]] = defaultdict(lambda: [0, 0.0, 0.0, 0.0, 0.0])  # calls, s, entry, rise, cpu s
    base = [0]

    def wrap(owner, name: str, label: str) -> None:
        f = getattr(owner, name)

        @functools.wraps(f)
        def g(*args, **kw):
            fr = [float(_rss()), float(_rss())]
            smp.active.append(fr)
            t = time.perf_counter()
            c = time.process_time()
            try:
                return f(*args, **kw)
            finally:
                dt = time.perf_counter() - t
                dc = time.process_time() - c
                smp.active = [x for x in smp.active if x is not fr]
                fr[1] = max(fr[1], _rss())
                s = stats[label]
                if s[0] == 0:
                    s[2] = (fr[0] - base[0]) / 2**20
                s[0] += 1
                s[1] += dt
                s[3] = max(s[3], (fr[1] - fr[0]) / 2**20)
                s[4] += dc

        setattr(owner, name, g)

    wrap(A, "check_datum", "check_datum")
    wrap(A, "assemble", "  assemble (scipy, datum check)")
    wrap(A, "schur_matrix", "  schur_matrix (scipy, datum check)")
    wrap(A, "solve_reduced", "  solve_reduced (datum check)")
    wrap(A, "levenberg_marquardt", "lm")
    wrap(M.Model, "evaluate", "  Model.evaluate (residuals+Jacobians)")
    wrap(S.SchurEngine, "__init__", "  SchurEngine.__init__ (pattern)")
    wrap(S.SchurEngine, "linearize", "  SchurEngine.linearize (U, W, V)")
    wrap(S.SchurEngine, "reduced_system", "  SchurEngine.reduced_system (Schur)")
    wrap(S.SchurEngine, "_solve_csr", "  SchurEngine._solve_csr (factor+solve)")
    wrap(L.ReducedSolver, "analyse", "    ReducedSolver.analyse (METIS+symbolic)")
    wrap(A, "_drop_lost_points", "_drop_lost_points")
    wrap(A, "_statistics", "_statistics")
    wrap(A, "_block_from_state", "_block_from_state")
    wrap(A.Block, "validate", "Block.validate")
    wrap(A.Model, "__init__", "Model.__init__")

    r0 = _rss()
    n_strips, n_per_strip = block_shape(a.exposures)
    t0 = time.perf_counter()
    block, truth = penta_block(a.seed, n_strips, n_per_strip, a.points_per_exposure * n_strips * n_per_strip,
                               midas(), height_m=500.0, n_control=9)
    t_gen = time.perf_counter() - t0
    peak_gen = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    held = sum(v.nbytes for v in vars(block).values() if isinstance(v, np.ndarray))
    big = sorted(((v.nbytes, k, v.dtype, v.shape) for k, v in vars(block).items() if isinstance(v, np.ndarray)),
                 reverse=True)[:8]
    tr = truth.nbytes
    print(f"block: {block.n_stations} exposures, {block.n_images} images, {block.n_points} points, "
          f"{block.n_observations} image observations")
    print(f"generation {t_gen:.1f} s; RSS after it +{(_rss() - r0) / 2**20:.0f} MiB (process peak so far "
          f"{peak_gen:.0f} MiB); the block's arrays {held / 2**20:.0f} MiB ({held / block.n_observations:.0f} B/obs), "
          f"truth {tr / 2**20:.1f} MiB")
    print("largest block arrays: " + ", ".join(f"{k} {n / 2**20:.0f} MiB {dt}{list(sh)}" for n, k, dt, sh in big))
    base[0] = _rss()
    t1 = time.perf_counter()
    c1 = time.process_time()
    fr = [float(base[0]), float(base[0])]
    smp.active.append(fr)
    res = A.adjust(block, AdjustConfig(statistics=StatisticsOptions(compute=False),
                                       solver=SolverOptions(max_iterations=50),
                                       unknowns=Unknowns(boresight=a.boresight)))
    smp.active = [x for x in smp.active if x is not fr]
    t_adj = time.perf_counter() - t1
    nobs = block.n_observations
    print(f"adjust(): {t_adj:.1f} s wall, {time.process_time() - c1:.1f} s CPU (all threads; load average "
          f"{os.getloadavg()[0]:.1f}), {res.info.iterations} + {res.info.unsuccessful} iterations, "
          f"solver {res.info.linear_solver}; peak rise {(fr[1] - base[0]) / 2**20:.0f} MiB "
          f"({(fr[1] - base[0]) / nobs:.0f} B per image observation); process peak "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    print(f"{'phase':46s} {'calls':>5s} {'wall s':>8s} {'cpu s':>8s} {'entry MiB':>10s} {'rise MiB':>9s} "
          f"{'rise B/obs':>10s}")
    for k, (n, s, e, rise, c) in stats.items():
        print(f"{k:46s} {int(n):5d} {s:8.2f} {c:8.2f} {e:10.0f} {rise:9.0f} {rise * 2**20 / nobs:10.0f}")


if __name__ == "__main__":
    main()
