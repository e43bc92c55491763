"""Data snooping on a seeded penta-rig block with injected blunders: one rejection per round (Baarda) next to
several non-adjacent ones per round (``AdjustConfig.reliability.per_round``), in the same run.

Prints per setting the rounds, the seconds, the blunders found / missed / good observations rejected (against
the injected truth), sigma0, and how far the two solutions are apart in units of their sigma.

    nice .venv/bin/python bench/snooping.py --exposures 120 --blunders 40 --per-round 1 10
    nice .venv/bin/python bench/snooping.py --exposures 48 --blunders 40 --per-round 10 --per-round-share 0.001
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import zlib

import numpy as np


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--exposures", type=int, default=120, help="rig exposures (5 images each)")
    ap.add_argument("--points-per-exposure", type=int, default=40)
    ap.add_argument("--blunders", type=int, default=40, help="image observations given a 12-20 sigma blunder")
    ap.add_argument("--per-round", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--per-round-share", type=float, default=0.0,
                    help="reliability.per_round_share of every run (the round's cap: the larger of per_round and "
                    "this share of the tested observations)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--time-statistics", action="store_true",
                    help="also print the seconds spent in the statistics pass (adjust._statistics) and in its "
                    "stats.covariance, summed over the rounds")
    a = ap.parse_args(argv)
    timers = _time_statistics() if a.time_statistics else None

    from skyrig.adjust import AdjustConfig, adjust
    from skyrig.adjust.config import ReliabilityOptions, Unknowns
    from skyrig.rig.presets import midas

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from scale import block_shape
    from scale_sim import penta_block

    n_strips, n_per_strip = block_shape(a.exposures)
    block, _ = penta_block(a.seed, n_strips, n_per_strip, a.points_per_exposure * n_strips * n_per_strip,
                           midas(), height_m=500.0, n_control=9)
    rng = np.random.default_rng(a.seed + 100)
    rays = np.bincount(block.obs_point, minlength=block.n_points)
    pts = rng.choice(np.flatnonzero(rays >= 5), a.blunders, replace=False)  # localisable: rays to spare
    bad = np.array([rng.choice(np.flatnonzero(block.obs_point == p)) for p in pts])
    sig = np.broadcast_to(np.asarray(block.obs_sigma_px, float).reshape(-1, 1) if np.ndim(block.obs_sigma_px) == 1
                          else np.asarray(block.obs_sigma_px, float), (block.n_observations, 2))[bad]
    block.obs_pixel[bad] += rng.choice([-1, 1], (bad.size, 2)) * rng.uniform(12, 20, (bad.size, 2)) * sig
    print(f"{block.n_stations} exposures, {block.n_images} images, {block.n_points} points, "
          f"{block.n_observations} image observations, {bad.size} blunders")
    truth = set(bad.tolist())
    out = {}
    for k in a.per_round:
        stages: list[str] = []
        t = time.perf_counter()
        r = adjust(block, AdjustConfig(unknowns=Unknowns(boresight="free"),
                                       reliability=ReliabilityOptions(snooping=True, per_round=k,
                                                                      per_round_share=a.per_round_share,
                                                                      max_rejections=10 * bad.size)),
                   callback=lambda s, i, c: stages.append(s))
        dt = time.perf_counter() - t
        got = {x.index for x in r.rejected if x.group == "image"}
        other = [x for x in r.rejected if x.group != "image"]
        out[k] = r
        print(f"per_round {k:3d}: rounds {len(dict.fromkeys(stages)):4d}  {dt:7.1f} s  found {len(got & truth)}/"
              f"{len(truth)}  good rejected {len(got - truth)} (+{len(other)} non-image)  sigma0 {r.sigma0:.5f}  "
              f"failures {len(r.failures)}", flush=True)
        if timers is not None:
            rej = sorted((x.group, x.index) for x in r.rejected)
            print(f"    rejected set digest {zlib.crc32(repr(rej).encode()):08x}, sigma0 {r.sigma0:.12f}")
            print(f"    statistics {timers['_statistics']:.1f} s, of which stats.covariance {timers['covariance']:.1f} s "
                  f"({timers['n_covariance']} calls)", flush=True)
            timers.update(_statistics=0.0, covariance=0.0, n_covariance=0)
    ks = list(out)
    base = out[ks[0]]
    for k in ks[1:]:
        r = out[k]
        dc = np.nanmax(np.abs(r.block.station_centre - base.block.station_centre) / base.pose_sigma[:, :3])
        dp = np.nanmax(np.abs(r.block.point_xyz - base.block.point_xyz) / base.point_sigma)
        same = {(x.group, x.index) for x in r.rejected} == {(x.group, x.index) for x in base.rejected}
        print(f"per_round {k} vs {ks[0]}: same rejected set {same}; largest difference / sigma: centres {dc:.4f}, "
              f"points {dp:.4f}")


def _time_statistics() -> dict[str, float]:
    """Wrap ``skyrig.adjust.adjust._statistics`` and its ``covariance`` with timers (same names in every version)."""
    import importlib

    mod = importlib.import_module("skyrig.adjust.adjust")
    timers = {"_statistics": 0.0, "covariance": 0.0, "n_covariance": 0}
    for name in ("_statistics", "covariance"):
        fn = getattr(mod, name)

        def timed(*args, _fn=fn, _name=name, **kw):  # type: ignore[no-untyped-def]
            t = time.perf_counter()
            try:
                return _fn(*args, **kw)
            finally:
                timers[_name] += time.perf_counter() - t
                if _name == "covariance":
                    timers["n_covariance"] += 1

        setattr(mod, name, timed)
    return timers


if __name__ == "__main__":
    main()
