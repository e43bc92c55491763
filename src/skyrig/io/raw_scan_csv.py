"""The skyrig raw scan CSV format (``# skyrig-raw-scan 1``); layout in ``docs/formats/raw_scan_csv.md``.

Example::

    # skyrig-raw-scan 1
    # angles: deg
    # time: gps-sow
    time,range,alpha,intensity
    345600.008350,12.418,-134.875,1893

Columns ``time`` (s), ``range`` (m) and ``alpha`` are required; ``beta`` (3D scanners), ``intensity`` and
``strip`` (integer flight-line id, -1 outside any strip) are optional; column order is free.  Times must not decrease.  Every error names the file, the line and the field.
"""

from __future__ import annotations

import io
import os
import re

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.geometry.angles import from_radians, normalize_unit, to_radians
from skyrig.io._text import atomic_write, parse_float, read_text
from skyrig.lidar.scanner import RawScan

__all__ = ["read_raw_scan_csv", "write_raw_scan_csv", "data_line"]

PathLike = str | os.PathLike[str]
MAGIC = "# skyrig-raw-scan 1"
_DIRECTIVE = re.compile(r"^#\s*([A-Za-z][A-Za-z0-9_-]*)\s*:\s*(.*)$")
_KNOWN = {"angles", "time"}
_COLUMNS = ("time", "range", "alpha", "beta", "intensity", "strip")


def read_raw_scan_csv(path: PathLike) -> tuple[RawScan, dict[str, str]]:
    """Read a raw scan CSV.

    Returns
    -------
    scan
        The pulses (angles converted to radians).
    header
        The header directives (``angles``, ``time``).

    Raises
    ------
    InputFormatError
        Naming file, line and field: missing magic line, unknown directive or column, a bad number,
        a missing required column, or a time smaller than the previous line's.
    """
    text = read_text(path)
    lines = text.splitlines()
    if not lines or lines[0].strip() != MAGIC:
        raise InputFormatError(f"first line must be {MAGIC!r}", path, 1)
    header: dict[str, str] = {"angles": "deg", "time": "gps-sow"}
    i = 1
    while i < len(lines) and lines[i].lstrip().startswith("#"):
        m = _DIRECTIVE.match(lines[i].strip())
        if m:
            key = m.group(1).lower()
            if key not in _KNOWN:
                raise InputFormatError(f"unknown header directive {key!r} (known: {', '.join(sorted(_KNOWN))})",
                                       path, i + 1, key)
            header[key] = m.group(2).strip()
        i += 1
    try:
        unit = normalize_unit(header["angles"])
    except Exception as exc:
        raise InputFormatError(str(exc), path, i, "angles") from None
    if i >= len(lines):
        raise InputFormatError("no column header line", path, i + 1)
    cols = [c.strip().lower() for c in lines[i].split(",")]
    col_line = i + 1
    for c in cols:
        if c not in _COLUMNS:
            raise InputFormatError(f"unknown column {c!r} (known: {', '.join(_COLUMNS)})", path, col_line, c)
    for c in ("time", "range", "alpha"):
        if c not in cols:
            raise InputFormatError(f"required column {c!r} is missing", path, col_line, c)
    body = [(k + 1, ln) for k, ln in enumerate(lines[i + 1:], start=i + 1) if ln.strip() and not ln.lstrip().startswith("#")]
    data = None
    if body:
        try:
            data = np.loadtxt(io.StringIO("\n".join(ln for _, ln in body)), delimiter=",", ndmin=2)
            if data.shape[1] != len(cols) or not np.all(np.isfinite(data)):
                data = None
        except ValueError:
            data = None
        if data is None:  # locate the first bad value for the message
            for lineno, ln in body:
                parts = ln.split(",")
                if len(parts) != len(cols):
                    raise InputFormatError(f"expected {len(cols)} fields, got {len(parts)}", path, lineno)
                for c, v in zip(cols, parts):
                    parse_float(v, path, lineno, c)
            raise InputFormatError("unreadable data", path)  # pragma: no cover
    else:
        data = np.zeros((0, len(cols)))
    col = {c: data[:, j] for j, c in enumerate(cols)}
    t = col["time"]
    dec = np.flatnonzero(np.diff(t) < 0)
    if dec.size:
        k = int(dec[0]) + 1
        raise InputFormatError(f"time {t[k]!r} is smaller than the previous pulse's {t[k - 1]!r}: pulse times must "
                               "not decrease", path, body[k][0], "time")
    neg = np.flatnonzero(col["range"] < 0)
    if neg.size:
        raise InputFormatError(f"negative range {col['range'][neg[0]]!r}", path, body[int(neg[0])][0], "range")
    beta = to_radians(col["beta"], unit) if "beta" in col else None
    strip = None
    if "strip" in col:
        frac = np.flatnonzero(col["strip"] != np.round(col["strip"]))
        if frac.size:
            raise InputFormatError(f"strip id {col['strip'][frac[0]]!r} is not an integer", path,
                                   body[int(frac[0])][0], "strip")
        strip = col["strip"].astype(np.int64)
    scan = RawScan(t, col["range"], to_radians(col["alpha"], unit), beta, col.get("intensity"), strip)
    return scan, header


def data_line(path: PathLike, k: int) -> int | None:
    """The line number (1-based) of data row ``k`` of a raw scan CSV (comments, blank lines and the header skipped)."""
    seen_header = False
    row = -1
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, ln in enumerate(fh, start=1):
            s = ln.strip()
            if not s or s.startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            row += 1
            if row == k:
                return lineno
    return None


def write_raw_scan_csv(path: PathLike, scan: RawScan, unit: str = "deg", time_system: str = "gps-sow") -> None:
    """Write pulses as a raw scan CSV (atomic)."""
    unit = normalize_unit(unit)
    cols = ["time", "range", "alpha"]
    arrs = [scan.time_s, scan.range_m, from_radians(scan.alpha_rad, unit)]
    fmts = ["%.6f", "%.4f", "%.6f"]
    if scan.beta_rad is not None:
        cols.append("beta")
        arrs.append(from_radians(scan.beta_rad, unit))
        fmts.append("%.6f")
    if scan.intensity is not None:
        cols.append("intensity")
        arrs.append(scan.intensity)
        fmts.append("%.6g")
    if scan.strip_id is not None:
        cols.append("strip")
        arrs.append(scan.strip_id)
        fmts.append("%d")
    with atomic_write(path) as fh:
        fh.write(f"{MAGIC}\n# angles: {unit}\n# time: {time_system}\n{','.join(cols)}\n")
        if len(scan):
            np.savetxt(fh, np.column_stack(arrs), fmt=fmts, delimiter=",")
