"""CLI start-up time: `skyrig --help` and `skyrig --version` next to `python -c pass`, in the same run.

Run:  .venv/bin/python bench/cli_startup.py [--runs 15]

Each command runs as a fresh subprocess (the way a user meets it); the median wall time of ``--runs``
runs is printed with its ratio to the interpreter's bare start-up (``python -c pass``) measured alternately
in the same loop, so that machine load affects all three alike. Target (issue 13): ``skyrig --help`` <= 0.5 s.
A subcommand's own ``--help`` (which imports that command's module) is shown for comparison.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _skyrig_argv() -> list[str]:
    exe = Path(sys.executable).with_name("skyrig")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("skyrig")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; from skyrig.cli import main; sys.exit(main())"]


def _wall(argv: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=15, help="runs per command (>= 7)")
    ap.add_argument("--subcommand", default="georef", help="subcommand whose own --help is timed too")
    args = ap.parse_args()
    runs = max(args.runs, 7)
    sky = _skyrig_argv()
    cases = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "skyrig --help": sky + ["--help"],
        "skyrig --version": sky + ["--version"],
        f"skyrig {args.subcommand} --help": sky + [args.subcommand, "--help"],
    }
    for argv in cases.values():  # warm the file cache once
        _wall(argv)
    times: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(runs):  # interleaved, so that load changes hit every case alike
        for name, argv in cases.items():
            times[name].append(_wall(argv))
    base = statistics.median(times["python -c pass"])
    print(f"CLI start-up, median of {runs} subprocess runs (wall time), {os.cpu_count()} CPUs, {sys.executable}")
    print(f"{'command':<28} {'median s':>9} {'min s':>7} {'max s':>7} {'x python':>9}")
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"{name:<28} {med:9.3f} {min(ts):7.3f} {max(ts):7.3f} {med / base:9.1f}")
    help_med = statistics.median(times["skyrig --help"])
    verdict = "meets" if help_med <= 0.5 else "MISSES"
    print(f"skyrig --help median {help_med:.3f} s {verdict} the 0.5 s target; "
          f"{help_med - base:.3f} s above the bare interpreter")


if __name__ == "__main__":
    main()
