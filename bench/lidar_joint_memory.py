"""Where the joint LiDAR-camera adjustment's memory goes, and how it scales with the laser points (issue 34).

Builds the simulated strip flight and its joint block (:func:`skyrig.calibrate.lidar_camera.build_joint_block`),
then for each fraction of the laser points -- kept at random in every plane, the planes all kept (at least 4 points
on a patch plane, 3 on a tie plane) -- runs :func:`skyrig.adjust.adjust` once and reports

* per phase the peak resident memory it added over its start (a 5 ms sampler; phases nest: the Levenberg-Marquardt
  loop holds the engine's linearisations, the statistics hold assemble, covariance and row cofactors) and its time;
* the peak traced (``tracemalloc``) memory of one evaluation of the laser factor with its Jacobians and of its
  normal equations by :func:`~skyrig.adjust.solver.assemble` and by the compiled engine (the resident figures
  also hold what the allocator kept).

Run: ``PYTHONPATH=src python bench/lidar_joint_memory.py [--size strips-ci|strips] [--seed 1]
[--fractions 0.25 0.5 1] [--json out.json]``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import threading
import time
import tracemalloc
from dataclasses import replace

import numpy as np

from skyrig.adjust import adjust as adjust_block
from skyrig.adjust.factors import lidar as lidar_mod
from skyrig.adjust.model import Model
from skyrig.adjust.solver import SchurEngine, assemble
from skyrig.calibrate.lidar_camera import JointOptions, build_joint_block, joint_inputs_from_flight
from skyrig.simulate.lidar_camera import build_joint_flight

_PAGE = os.sysconf("SC_PAGE_SIZE")


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * _PAGE


class PhasePeaks:
    """Peak resident memory added and time per wrapped function (``wrap(obj, name, label)``)."""

    def __init__(self) -> None:
        self.active: list[list] = []
        self.stats: dict[str, list] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._sample, daemon=True).start()

    def _sample(self) -> None:
        while True:
            time.sleep(0.005)
            r = _rss()
            with self._lock:
                for fr in self.active:
                    fr[1] = max(fr[1], r)

    def wrap(self, obj: object, name: str, label: str) -> None:
        f = getattr(obj, name)

        @functools.wraps(f)
        def g(*a, **k):
            r0 = _rss()
            fr = [label, r0]
            with self._lock:
                self.active.append(fr)
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                with self._lock:
                    self.active.remove(fr)
                s = self.stats.setdefault(label, [0, 0.0, 0])
                s[0] += 1
                s[1] += time.perf_counter() - t
                s[2] = max(s[2], max(fr[1], _rss()) - r0)

        setattr(obj, name, g)


def subsample(block, frac: float, seed: int = 0):
    """``block`` with about ``frac`` of its laser points (at random), every plane kept."""
    lp = block.observations["lidar"]
    if frac >= 1.0:
        return block
    drop = np.random.default_rng(seed).random(len(lp)) > frac
    need = np.where(lp.plane_point >= 0, 3, 4)
    order = np.argsort(lp.plane, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(lp.plane, minlength=lp.n_planes))])
    for p in range(lp.n_planes):
        idx = order[ptr[p]:ptr[p + 1]]
        if (~drop[idx]).sum() < need[p]:
            drop[idx[:need[p]]] = False
    return replace(block, observations={**block.observations, "lidar": lp.without(drop)})


def traced(block, cfg) -> dict[str, float]:
    """Peak traced MB of the laser factor's evaluation and of its normals (assemble, engine), each run once before."""
    m = Model(block, cfg)
    s = m.initial.copy()
    f = lidar_mod.LIDAR.evaluate(m, s, True)[0]
    out = {"factor_rows": len(f)}
    for name, fn in (("evaluate", lambda: lidar_mod.LIDAR.evaluate(m, s, True)),
                     ("assemble", lambda: assemble([f], m.layout, None)),
                     ("engine", lambda: SchurEngine([f], m.layout, m.block.obs_image).linearize([f]))):
        fn()
        tracemalloc.start()
        fn()
        out[f"{name}_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="strips-ci", choices=("strips-ci", "strips"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.25, 0.5, 1.0])
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    adj = sys.modules["skyrig.adjust.adjust"]
    eng = sys.modules["skyrig.adjust.schur_engine"]
    pp = PhasePeaks()
    for obj, name, label in ((lidar_mod.Lidar, "evaluate", "laser factor + Jacobians"),
                             (eng.SchurEngine, "__init__", "engine pattern"),
                             (eng.SchurEngine, "linearize", "engine normals"),
                             (eng.SchurEngine, "reduced_system", "engine reduction"),
                             (eng.SchurEngine, "solve", "engine solve"),
                             (adj, "check_datum", "datum check"),
                             (adj, "levenberg_marquardt", "Levenberg-Marquardt"),
                             (adj, "assemble", "statistics: assemble"),
                             (adj, "covariance", "statistics: covariance"),
                             (adj, "row_cofactors", "statistics: row cofactors"),
                             (adj, "_statistics", "statistics (all)")):
        pp.wrap(obj, name, label)
    fl = build_joint_flight(a.size, a.seed)
    block0, cfg, info = build_joint_block(joint_inputs_from_flight(fl), JointOptions())
    lp0 = block0.observations["lidar"]
    print(f"{a.size} seed {a.seed}: {len(lp0)} laser points on {lp0.n_planes} planes, {fl.n_images} images")
    out = []
    for frac in a.fractions:
        block = subsample(block0, frac)
        pp.stats.clear()
        r0, t0 = _rss(), time.perf_counter()
        fr = ["total", r0]
        pp.active.append(fr)
        res = adjust_block(block, cfg)
        pp.active.remove(fr)
        row = {"fraction": frac, "laser_points": len(block.observations["lidar"]), "planes": lp0.n_planes,
               "wall_s": time.perf_counter() - t0, "rss_start_mb": r0 / 1e6, "rss_added_mb": (fr[1] - r0) / 1e6,
               "sigma0": res.sigma0, "phases": {k: {"calls": v[0], "time_s": v[1], "rss_added_mb": v[2] / 1e6}
                                               for k, v in pp.stats.items()},
               "traced": traced(block, cfg)}
        out.append(row)
        print(f"\n{row['laser_points']} laser points ({frac:g}): adjust {row['wall_s']:.1f} s, peak RSS added "
              f"{row['rss_added_mb']:.0f} MB (start {row['rss_start_mb']:.0f} MB), sigma0 {res.sigma0:.4f}")
        for k, v in row["phases"].items():
            print(f"  {k:<28} calls {v['calls']:>3} {v['time_s']:7.2f} s  peak RSS added {v['rss_added_mb']:8.1f} MB")
        t = row["traced"]
        print(f"  traced: laser factor {t['evaluate_mb']:.1f} MB ({t['factor_rows']} rows), its normals by "
              f"assemble {t['assemble_mb']:.1f} MB, by the engine {t['engine_mb']:.1f} MB")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
