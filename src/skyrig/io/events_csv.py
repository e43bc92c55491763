"""The skyrig camera events CSV format (``# skyrig-events 1``); layout in ``docs/formats/events_csv.md``.

Example::

    # skyrig-events 1
    # angles: deg
    # time: gps-sow
    image,time,head,beta,exposure
    0001_nadir.jpg,345600.100000,nadir,,1
    0001_oblique.jpg,345600.100000,oblique,-35.0,1

Every error names the file, the line and the field (column or header key).
"""

from __future__ import annotations

import csv
import io
import os

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.geometry.angles import check_plausible, from_radians, normalize_unit, to_radians
from skyrig.io._text import atomic_write
from skyrig.io.trajectory_csv import (
    FORMAT_VERSION,
    SECONDS_PER_WEEK,
    ImplausibleAngleError,
    _angle_unit,
    _check_columns,
    _split_file,
    _time_system,
)
from skyrig.trajectory.events import CameraEvents

__all__ = ["read_events_csv", "write_events_csv"]

PathLike = str | os.PathLike[str]

_KEYS = ("angles", "time")


def read_events_csv(path: PathLike) -> CameraEvents:
    """Read a skyrig camera events CSV file (see ``docs/formats/events_csv.md``).

    Returns
    -------
    CameraEvents
        With ``source`` set to ``path`` and ``source_line`` to each event's line, so that later
        checks (e.g. :func:`skyrig.trajectory.check_events_in_span`) can name the line.

    Raises
    ------
    InputFormatError
        Naming file, line and field for: a missing format line, unknown header keys, missing or
        unknown columns, rows of the wrong length, empty image or head names, times that are not
        finite numbers, a literal NaN actuator angle (leave the cell empty for a fixed head),
        non-integer exposure ids, repeated image names.
    ImplausibleAngleError
        For actuator angles beyond one full turn in the declared unit.
    InputFormatError
        For actuator angles whose steps between consecutive frames of a head agree with a constant gear step in
        another unit than the declared one (gon written, degrees declared;
        :func:`skyrig.io.plausibility.check_actuator_cadence`).
    """
    hdr = _split_file(path, "skyrig-events", _KEYS)
    if not hdr.data:
        raise InputFormatError("no rows after the column header: an events file needs at least one event", path,
                               hdr.header_line, None)
    tsys = _time_system(path, hdr)
    required = ["image", "time", "head"] + (["week"] if tsys == "gps-week-sow" else [])
    _check_columns(path, hdr, required, [], optional=("beta", "exposure"))
    unit = _angle_unit(path, hdr, required="beta" in hdr.columns)
    cols = hdr.columns
    ncol = len(cols)
    m = len(hdr.data)
    time = np.empty(m)
    week = np.zeros(m)
    beta = np.full(m, np.nan)
    exposure = np.zeros(m, dtype=np.int64)
    heads: list[str] = []
    names: list[str] = []
    lines = np.empty(m, dtype=np.int64)
    i_img, i_t, i_head = cols.index("image"), cols.index("time"), cols.index("head")
    i_beta = cols.index("beta") if "beta" in cols else None
    i_exp = cols.index("exposure") if "exposure" in cols else None
    i_week = cols.index("week") if "week" in cols else None

    def number(text: str, no: int, field: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise InputFormatError(f"{text.strip()!r} is not a number", path, no, field) from None
        if not np.isfinite(v):
            raise InputFormatError(f"{text.strip()!r} is not a finite number", path, no, field)
        return v

    for k, (no, text) in enumerate(hdr.data):
        cells = next(csv.reader([text], skipinitialspace=True))
        if len(cells) != ncol:
            raise InputFormatError(f"expected {ncol} values, found {len(cells)}", path, no, None)
        lines[k] = no
        name, head = cells[i_img].strip(), cells[i_head].strip()
        if not name:
            raise InputFormatError("empty image name", path, no, "image")
        if not head:
            raise InputFormatError("empty head name", path, no, "head")
        names.append(name)
        heads.append(head)
        time[k] = number(cells[i_t], no, "time")
        if i_week is not None:
            week[k] = number(cells[i_week], no, "week")
            if week[k] != round(week[k]) or week[k] < 0:
                raise InputFormatError(f"GPS week {week[k]!r} is not a whole non-negative number", path, no, "week")
            if not 0.0 <= time[k] < SECONDS_PER_WEEK:
                raise InputFormatError(f"seconds of week {time[k]!r} outside [0, 604800)", path, no, "time")
        if i_beta is not None and cells[i_beta].strip():
            beta[k] = number(cells[i_beta], no, "beta")
            if unit is not None and check_plausible(beta[k], unit, limit_turns=1.0):
                raise ImplausibleAngleError(
                    f"{check_plausible(beta[k], unit, limit_turns=1.0)} (declared 'angles: {unit}')",
                    path, no, "beta")
        if i_exp is not None:
            cell = cells[i_exp].strip()
            try:
                exposure[k] = int(cell)
            except ValueError:
                raise InputFormatError(f"exposure id {cell!r} is not an integer", path, no, "exposure") from None
            except OverflowError:
                raise InputFormatError(f"exposure id {cell!r} is too large (at most {2**63 - 1})", path, no,
                                       "exposure") from None
    if tsys == "gps-week-sow":
        time = week * SECONDS_PER_WEEK + time
        tsys = "gps"
    if unit is not None and i_beta is not None:
        from skyrig.io.plausibility import check_actuator_cadence

        check_actuator_cadence(beta, unit, heads, time, path, lines,
                               "declare the unit of beta with the header line '# angles: deg|gon|rad'")
    beta_rad = beta if unit is None else to_radians(beta, unit)
    return CameraEvents.create(
        time, np.array(heads, dtype=str), np.array(names, dtype=str), beta_rad,
        exposure if i_exp is not None else None, time_system=tsys, source=str(path), source_line=lines,
    )


def write_events_csv(path: PathLike, events: CameraEvents, *, angles: str = "deg") -> None:
    """Write camera events as skyrig events CSV (temporary file, then renamed into place).

    The ``beta`` column is written when any event has an actuator angle (empty cells for fixed
    heads); ``exposure`` is always written.  Times with 6 decimals (microseconds).
    """
    unit = normalize_unit(angles)
    for name in events.image_name.tolist():
        if name.lstrip().startswith("#"):
            raise InputFormatError(f"image name {name!r} would read back as a comment", path, None, "image")
    has_beta = bool(np.any(np.isfinite(events.beta_rad)))
    buf = io.StringIO()
    buf.write(f"# skyrig-events {FORMAT_VERSION}\n")
    if has_beta:
        buf.write(f"# angles: {unit}\n")
    buf.write(f"# time: {events.time_system}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["image", "time", "head"] + (["beta"] if has_beta else []) + ["exposure"])
    beta = from_radians(np.mod(events.beta_rad, 2.0 * np.pi), unit)  # one turn, [0, 360) deg: what the reader accepts
    for k in range(len(events)):
        row = [str(events.image_name[k]), f"{events.time_s[k]:.6f}", str(events.head[k])]
        if has_beta:
            row.append("" if not np.isfinite(beta[k]) else f"{beta[k]:.10f}")
        row.append(str(int(events.exposure_id[k])))
        w.writerow(row)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())
