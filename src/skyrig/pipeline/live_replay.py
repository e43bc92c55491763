"""Replay of a recorded (or simulated) flight folder into a watched folder at the flight's own rate, for
``skyrig live`` (:mod:`skyrig.pipeline.live`): the way a recording system writes it.

Flight time ``t`` runs at ``speed`` x wall-clock time from the first event.  The trajectory's lines up to ``t``
are appended to ``trajectory.csv`` (``trajectory_lag_s`` behind, as a real-time GNSS/IMU solution is); at each
exposure's time its images are written into ``images/`` (each in two pieces, as a camera or copy tool does) and
then its event lines appended to ``events.csv``; ``flight.end`` is written at the end.

Faults for the bad-input checks: ``truncate`` (image names written half and never finished), ``drop`` (image names
never written: events without an image), ``trajectory_stop_s`` (the trajectory stops at that flight time).
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from skyrig.errors import SkyrigError
from skyrig.pipeline.live import FlightPaths

__all__ = ["ReplayFaults", "replay_flight"]


@dataclass(frozen=True)
class ReplayFaults:
    truncate: Sequence[str] = ()
    drop: Sequence[str] = ()
    trajectory_stop_s: float | None = None


def _table(path: Path) -> tuple[list[str], list[tuple[float, str]]]:
    """Header lines (comments + column names) and the data lines with their time (column ``time``)."""
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    head, rows = [], []
    cols: list[str] | None = None
    for ln in lines:
        if cols is None:
            head.append(ln)
            if not ln.startswith("#") and ln.strip():
                cols = [c.strip() for c in ln.strip().split(",")]
            continue
        if ln.strip():
            rows.append((float(ln.split(",")[cols.index("time")]), ln))
    if cols is None or "time" not in cols:
        raise SkyrigError(f"{path}: no header line with a 'time' column")
    return head, rows


def replay_flight(src: str | os.PathLike[str], dst: str | os.PathLike[str] | FlightPaths, speed: float = 1.0,
                  faults: ReplayFaults = ReplayFaults(), stop: threading.Event | None = None,
                  max_exposures: int | None = None, trajectory_lag_s: float = 0.5) -> dict[str, float]:
    """Write ``src``'s flight (a flight folder) into ``dst`` (a flight folder, given its rig; or the paths a project
    names, whose rig must be there) at ``speed`` x its real rate; returns the flight-time span replayed and the
    wall time it took."""
    src = Path(src)
    if speed <= 0:
        raise SkyrigError(f"replay speed must be > 0, not {speed}")
    if isinstance(dst, FlightPaths):
        out = dst
    else:
        out = FlightPaths.of_folder(dst)
        out.rig.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / "rig.yaml", out.rig)
    out.images.mkdir(parents=True, exist_ok=True)
    out.trajectory.parent.mkdir(parents=True, exist_ok=True)
    out.events.parent.mkdir(parents=True, exist_ok=True)
    th, trows = _table(src / "trajectory.csv")
    eh, erows = _table(src / "events.csv")
    exposures: dict[float, list[str]] = {}
    for t, ln in erows:
        exposures.setdefault(t, []).append(ln)
    times = sorted(exposures)[:max_exposures] if max_exposures else sorted(exposures)
    with open(out.trajectory, "w", encoding="utf-8") as ft, open(out.events, "w", encoding="utf-8") as fe:
        ft.writelines(th)
        fe.writelines(eh)
        ft.flush()
        fe.flush()
        t0, w0 = times[0] - 1.0, time.time()  # one second of trajectory before the first exposure
        ti = 0
        for t in times + [times[-1] + 1.0]:
            while True:  # the trajectory up to t (lagging), in real time
                now_t = t0 + (time.time() - w0) * speed
                upto = min(now_t - trajectory_lag_s, faults.trajectory_stop_s if faults.trajectory_stop_s
                           is not None else float("inf"))
                while ti < len(trows) and trows[ti][0] <= upto:
                    ft.write(trows[ti][1])
                    ti += 1
                ft.flush()
                if now_t >= t or (stop is not None and stop.is_set()):
                    break
                time.sleep(min(0.05, max((t - now_t) / speed, 0.0)))
            if stop is not None and stop.is_set():
                break
            if t not in exposures:
                continue
            for ln in exposures[t]:
                name = ln.split(",")[0].strip()
                if name in faults.drop:
                    continue
                data = (src / "images" / name).read_bytes()
                with open(out.images / name, "wb") as fh:
                    fh.write(data[: len(data) // 2])
                    fh.flush()
                    if name in faults.truncate:
                        continue
                    fh.write(data[len(data) // 2:])
            fe.writelines(exposures[t])
            fe.flush()
        # the rest of the trajectory (unless it stopped)
        while ti < len(trows) and (faults.trajectory_stop_s is None or trows[ti][0] <= faults.trajectory_stop_s):
            ft.write(trows[ti][1])
            ti += 1
    out.end.write_text("end\n", encoding="utf-8")
    return {"flight_s": times[-1] - times[0], "wall_s": time.time() - w0, "exposures": float(len(times))}
