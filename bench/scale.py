"""How skyrig's adjustment grows with the block: a penta-rig (MIDAS) block from 100 to 2,000+ exposures.

    .venv/bin/python bench/scale.py                       # 100 200 500 1000 2000 exposures
    .venv/bin/python bench/scale.py --sizes 100 400 --points-per-exposure 30

Each size runs in its own child process (so that the peak memory of one size does not hide the next):
a seeded block of ``bench/scale_sim.py`` (the simulation model of
:func:`skyrig.adjust.synthetic.synthetic_block`, generated in linear time) with the MIDAS rig (5 heads: nadir + 4 obliques
at 45 deg), roughly square blocks (strips ~ sqrt(exposures / 4)), ``--points-per-exposure`` object
points scattered over the area, GNSS and IMU observations and a few control points; then
``adjust(block, AdjustConfig(statistics=False))``.  Reported per size: block size, generation time,
adjustment wall time and iterations, peak resident memory of the adjustment phase (sampled from
/proc/self/statm every 5 ms, minus the resident memory before it) and of the whole child process
(``resource.getrusage``), and the growth exponent ``d log(time) / d log(exposures)`` between sizes and
over the whole range (least squares).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time

import numpy as np

PAGE = os.sysconf("SC_PAGE_SIZE")


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * PAGE


def _mem_available() -> int:
    with open("/proc/meminfo") as fh:
        for line in fh:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return 0


class _PeakRss:
    """Sample the resident set size in a thread; ``peak`` in bytes.  Above ``limit`` bytes the process
    exits at once (status 3): a guard for the shared machine, not a measurement."""

    def __init__(self, period: float = 0.005, limit: float | None = None) -> None:
        self.period, self.peak, self._stop, self.limit = period, _rss(), threading.Event(), limit
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, _rss())
            if self.limit is not None and self.peak > self.limit:
                sys.stderr.write(f"resident memory {self.peak / 2**30:.1f} GiB above the guard "
                                 f"{self.limit / 2**30:.1f} GiB: stopped\n")
                sys.stderr.flush()
                os._exit(3)
            time.sleep(self.period)

    def __enter__(self) -> "_PeakRss":
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss())


def block_shape(n_exposures: int) -> tuple[int, int]:
    """``(strips, exposures per strip)`` of a roughly square block of about ``n_exposures``."""
    n_strips = max(2, int(round(np.sqrt(n_exposures / 4.0))))
    return n_strips, int(np.ceil(n_exposures / n_strips))


def one(n_exposures: int, points_per_exposure: int, seed: int, boresight: str = "free",
        max_gib: float | None = None, linear_solver: str = "auto") -> dict:
    """Generate and adjust one block; a dict of figures."""
    from skyrig.adjust import AdjustConfig, adjust
    from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
    from skyrig.adjust.synthetic import synthetic_block
    from skyrig.rig.presets import midas

    import skyrig.adjust.solver as solver

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from scale_sim import penta_block

    solver.LINEAR_SOLVER = linear_solver  # the reduced system's solver (auto: skyrig.adjust.linalg.choose)

    # load the compiled (numba, cached on disk) kernels once on a tiny block: a one-off per process
    tw = time.perf_counter()
    small, _ = synthetic_block(seed=seed, n_strips=2, n_per_strip=3, n_points=60, rig=midas(), height_m=500.0,
                               n_control=9)
    adjust(small, AdjustConfig(statistics=StatisticsOptions(compute=False), solver=SolverOptions(max_iterations=2)))
    t_warm = time.perf_counter() - tw
    n_strips, n_per_strip = block_shape(n_exposures)
    t0 = time.perf_counter()
    block, true_centre = penta_block(seed, n_strips, n_per_strip, points_per_exposure * n_strips * n_per_strip,
                                     midas(), height_m=500.0, n_control=9)
    t_gen = time.perf_counter() - t0
    base = _rss()
    t1 = time.perf_counter()
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    # the guard: --max-gib, or less when the machine has less available now (others' jobs)
    limit = None if max_gib is None else min(max_gib * 2**30, _rss() + 0.92 * _mem_available())
    with _PeakRss(limit=limit) as mem:
        res = adjust(block, AdjustConfig(statistics=StatisticsOptions(compute=False),
                                         solver=SolverOptions(max_iterations=50),
                                         unknowns=Unknowns(boresight=boresight)))
    t_adj = time.perf_counter() - t1
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    err = np.sqrt(np.mean((res.block.station_centre - true_centre) ** 2))
    return dict(exposures=block.n_stations, images=block.n_images, points=block.n_points,
                observations=block.n_observations, generate_s=t_gen, adjust_s=t_adj, adjust_cpu_s=cpu,
                warmup_s=t_warm, load=os.getloadavg()[0],
                iterations=res.info.iterations, unsuccessful=res.info.unsuccessful, lm_s=res.info.wall_s,
                engine=res.info.engine, converged=bool(res.info.converged), linear_solver=res.info.linear_solver,
                sigma0=res.sigma0, centre_rmse_m=float(err), adjust_peak_mib=(mem.peak - base) / 2**20,
                process_peak_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 500, 1000, 2000])
    ap.add_argument("--points-per-exposure", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--boresight", default="free", help="boresight mode of the adjustment (free, fixed, weighted)")
    ap.add_argument("--max-gib", type=float, default=20.0,
                    help="guard for a shared machine: a size whose projected adjustment peak (from the previous "
                         "sizes) exceeds this or 90 %% of the available memory is not run, and a run whose resident "
                         "memory exceeds it is stopped (default 20)")
    ap.add_argument("--linear-solver", default="auto", help="reduced system: auto (default), cholmod, pcg, splu, dense")
    ap.add_argument("--history", default=os.path.join(os.environ.get("TMPDIR", "/tmp"), "skyrig_bench_scale.json"),
                    help="JSON file of the sizes measured so far (same points per exposure, seed, boresight mode and "
                         "linear solver); each run adds its rows, and a run of one size (e.g. --sizes 10000) prints "
                         "its growth exponents against the recorded smaller sizes (default %(default)s; '' = none)")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.points_per_exposure, a.seed, a.boresight, a.max_gib, a.linear_solver)))
        return
    rows = []
    hdr = (f"{'exposures':>9} {'images':>7} {'points':>8} {'obs':>9} {'gen s':>7} {'adjust s':>9} {'cpu s':>7} {'LM s':>7} "
           f"{'iter':>5} {'s/iter':>7} {'adj MiB':>8} {'proc MiB':>9} {'sigma0':>7} {'exp(t)':>7} {'exp(mem)':>8} "
           f"{'warm s':>7} {'load':>5} {'conv':>4} {'C rmse':>7}  linear solver")
    import numba

    print(f"MIDAS penta rig, GNSS/IMU, boresights {a.boresight}, linear solver {a.linear_solver}, "
          f"{a.points_per_exposure} points per exposure, seed {a.seed}, "
          f"os.cpu_count() = {os.cpu_count()}, numba threads = {numba.get_num_threads()}")
    print("adjust s: the whole adjust() call (datum check, Levenberg-Marquardt, statistics); LM s: the "
          "Levenberg-Marquardt loop alone; iter: successful + unsuccessful steps; each size runs in a fresh "
          "process after a warm-up adjustment of a 6-exposure block (loads the numba kernels from their cache; "
          "warm s); cpu s: user + system CPU seconds of adjust() (all threads: on a loaded shared machine "
          "the wall time depends on the others' load, printed as the 1-minute load average); C rmse: station "
          "centres against the truth (m)")
    print(hdr, flush=True)
    for n in a.sizes:
        if rows:  # project this size's peak from the previous ones (exponent >= 1) before running it
            e = 1.1
            if len(rows) >= 2:
                e = max(1.0, np.log(rows[-1]["adjust_peak_mib"] / rows[-2]["adjust_peak_mib"])
                        / np.log(rows[-1]["exposures"] / rows[-2]["exposures"]))
            q = n / rows[-1]["exposures"]  # the adjustment's rise with the exponent, the rest (block) linearly
            proj = (rows[-1]["adjust_peak_mib"] * q ** e
                    + (rows[-1]["process_peak_mib"] - rows[-1]["adjust_peak_mib"]) * q) / 1024
            avail = _mem_available() / 2**30
            if proj > a.max_gib or proj > 0.9 * avail:
                print(f"size {n} not run: projected peak {proj:.1f} GiB (exponent {e:.2f}) above the guard "
                      f"{a.max_gib:.0f} GiB or 90 % of the {avail:.1f} GiB available")
                break
        out = subprocess.run([sys.executable, __file__, "--one", str(n), "--points-per-exposure",
                              str(a.points_per_exposure), "--seed", str(a.seed), "--boresight", a.boresight,
                              "--max-gib", str(a.max_gib), "--linear-solver", a.linear_solver],
                             capture_output=True, text=True)
        if out.returncode:
            print(f"size {n} failed:\n{out.stderr[-2000:]}")
            break
        r = json.loads(out.stdout.strip().splitlines()[-1])
        ex_t = ex_m = float("nan")
        if rows:
            p = rows[-1]
            lx = np.log(r["exposures"] / p["exposures"])
            ex_t = np.log(r["adjust_s"] / p["adjust_s"]) / lx
            ex_m = np.log(max(r["adjust_peak_mib"], 1e-3) / max(p["adjust_peak_mib"], 1e-3)) / lx
        rows.append(r)
        print(f"{r['exposures']:9d} {r['images']:7d} {r['points']:8d} {r['observations']:9d} {r['generate_s']:7.1f} "
              f"{r['adjust_s']:9.2f} {r['adjust_cpu_s']:7.1f} {r['lm_s']:7.2f} {r['iterations'] + r['unsuccessful']:5d} "
              f"{r['adjust_s'] / max(r['iterations'] + r['unsuccessful'], 1):7.2f} "
              f"{r['adjust_peak_mib']:8.0f} {r['process_peak_mib']:9.0f} {r['sigma0']:7.3f} {ex_t:7.2f} {ex_m:8.2f} "
              f"{r['warmup_s']:7.2f} {r['load']:5.1f} {'yes' if r['converged'] else 'NO':>4} "
              f"{r['centre_rmse_m']:7.3f}  {r['linear_solver']}",
              flush=True)
    key = [a.points_per_exposure, a.seed, a.boresight, a.linear_solver]
    hist = _history(a.history, key, rows)
    fit = rows
    if len(rows) < 2 and hist:  # one size: against the recorded other sizes (latest run of each)
        fit = sorted([h for h in hist if h["exposures"] not in {r["exposures"] for r in rows}] + rows,
                     key=lambda r: r["exposures"])
        if len(fit) >= 2:
            print("growth exponents with the sizes recorded in " + a.history + ": " + ", ".join(
                f"{r['exposures']} ({r['adjust_s']:.1f} s wall, {r['adjust_cpu_s']:.1f} s CPU, "
                f"{r['adjust_peak_mib']:.0f} MiB, load {r['load']:.1f})" for r in fit))
            for r in rows:  # against the next smaller recorded size
                prev = [h for h in fit if h["exposures"] < r["exposures"]]
                if prev:
                    p = prev[-1]
                    lx = np.log(r["exposures"] / p["exposures"])
                    print(f"exponents {p['exposures']} -> {r['exposures']} exposures: wall time "
                          f"{np.log(r['adjust_s'] / p['adjust_s']) / lx:.2f}, CPU time "
                          f"{np.log(r['adjust_cpu_s'] / p['adjust_cpu_s']) / lx:.2f}, adjustment peak memory "
                          f"{np.log(max(r['adjust_peak_mib'], 1e-3) / max(p['adjust_peak_mib'], 1e-3)) / lx:.2f}")
    rows = fit
    if len(rows) >= 2:
        x = np.log([r["exposures"] for r in rows])
        bt = np.polyfit(x, np.log([r["adjust_s"] for r in rows]), 1)[0]
        bi = np.polyfit(x, np.log([r["adjust_s"] / max(r["iterations"] + r["unsuccessful"], 1) for r in rows]), 1)[0]
        bm = np.polyfit(x, np.log([max(r["adjust_peak_mib"], 1e-3) for r in rows]), 1)[0]
        bc = np.polyfit(x, np.log([r["adjust_cpu_s"] for r in rows]), 1)[0]
        print(f"growth exponent over {rows[0]['exposures']}..{rows[-1]['exposures']} exposures (least squares on "
              f"log-log): wall time {bt:.2f}, wall time per iteration {bi:.2f}, CPU time {bc:.2f}, adjustment "
              f"peak memory {bm:.2f}")


def _history(path: str, key: list, rows: list[dict]) -> list[dict]:
    """The recorded rows of ``key`` (latest per size) before this run; this run's rows added to the file
    (written to a temporary file and renamed)."""
    if not path:
        return []
    try:
        with open(path) as fh:
            runs = json.load(fh)
    except (OSError, ValueError):
        runs = []
    before: dict[int, dict] = {}
    for run in runs:
        if run.get("key") == key:
            before[run["row"]["exposures"]] = run["row"]
    runs += [{"key": key, "time": time.strftime("%Y-%m-%dT%H:%M:%S"), "row": r} for r in rows]
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(runs, fh)
    os.replace(tmp, path)
    return sorted(before.values(), key=lambda r: r["exposures"])


if __name__ == "__main__":
    main()
