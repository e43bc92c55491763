"""Laser scanner records: the mount of a scanner (``scanner.json`` of a simulated project) and calibrated scanner
records in a rig file's ``scanners`` section (``docs/formats/rig_file.md``, section "Laser scanners").

A rig file's ``scanners`` section is a list of records::

    scanners:
    - name: lidar
      body_from_scanner: [[0, 0, 1], [1, 0, 0], [0, 1, 0]]   # rotation, calibrated (boresight included)
      lever_arm_m: [0.10, -0.02, 0.15]                     # scanner origin in the body (IMU) frame
      range_offset_m: 0.0                                  # recorded = (1 + scale) true + offset
      range_scale_ppm: 0.0
      calibration:                                         # optional: what a calibration found
        boresight_rad: {parameters: [...], values: [...], sigma: [...], correlation: [[...]]}
        lever_arm_m: {...}
        range: {...}
        held: [lever_z]
        provenance: {recipe: ..., flight: ..., date: ..., software: ..., statistics: {...}, notes: [...]}

Every error names the file, the line (YAML) and the key path.  A ``body_from_scanner`` that is not a rotation, or a
left-handed axis set (determinant -1), and a lever arm only plausible in millimetres or centimetres are refused.
Writing replaces the ``scanners`` section of a rig file (or writes a scanner-only rig file) by temp-and-rename.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np
import yaml

from skyrig.errors import InputFormatError
from skyrig.io._text import atomic_write, read_text
from skyrig.io.plausibility import check_lever_arm
from skyrig.lidar.georef import ScannerMount

__all__ = ["check_rotation", "read_rig_scanners", "read_scanner_mount", "scanner_from_record", "write_scanner_record"]

PathLike = str | os.PathLike[str]
_SCANNER_KEYS = {"name", "body_from_scanner", "lever_arm_m", "range_offset_m", "range_scale_ppm", "range_sigma_m",
                 "description", "calibration"}
_CAL_KEYS = {"boresight_rad", "lever_arm_m", "range", "held", "provenance", "nominal", "strips"}


def check_rotation(m: Any, path: PathLike, line: int | None, field: str) -> np.ndarray:
    """``m`` as a ``(3, 3)`` right-handed rotation; an :class:`InputFormatError` naming ``path``, ``line`` and
    ``field`` otherwise (a left-handed axis set, determinant -1, is named as such)."""
    try:
        r = np.array(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputFormatError(f"expected 3 x 3 numbers, got {m!r}", path, line, field) from None
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise InputFormatError(f"expected 3 rows of 3 finite numbers, got shape {r.shape}", path, line, field)
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
        raise InputFormatError("not a rotation matrix: its rows are not orthonormal (max |R R^T - I| = "
                               f"{np.abs(r @ r.T - np.eye(3)).max():.3g})", path, line, field)
    if np.linalg.det(r) < 0:
        raise InputFormatError("a left-handed axis set (determinant -1): the scanner frame's x, y, z must be "
                               "right-handed (swap or negate one axis of the maker's description)", path, line, field)
    return r


def read_scanner_mount(path: PathLike, name: str | None = None) -> tuple[ScannerMount, dict[str, Any]]:
    """A scanner mount from a ``skyrig-scanner-mount`` JSON file (``scanner.json``) or from the ``scanners`` section
    of a rig file (YAML; ``name`` picks a record, default the only one).

    Returns the mount and the record's other fields (``range_offset_m``, ``range_scale_ppm``, ...).
    """
    p = os.fspath(path)
    text = read_text(p)
    if text.lstrip().startswith("{"):
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputFormatError(f"not valid JSON: {exc.msg}", p, exc.lineno) from None
        if not isinstance(doc, dict) or doc.get("format") != "skyrig-scanner-mount":
            raise InputFormatError("expected a skyrig-scanner-mount JSON file (\"format\": \"skyrig-scanner-mount\")",
                                   p, 1, "format")
        for key in ("body_from_scanner", "lever_arm_m"):
            if key not in doc:
                raise InputFormatError(f"missing key {key!r}", p, None, key)
        return scanner_from_record(doc, p, {}), {k: v for k, v in doc.items() if k not in ("body_from_scanner",
                                                                                           "lever_arm_m")}
    scanners = read_rig_scanners(p)
    if not scanners:
        raise InputFormatError("the rig file has no 'scanners' section", p, None, "scanners")
    if name is None:
        if len(scanners) != 1:
            raise InputFormatError(f"the rig file has {len(scanners)} scanners ({', '.join(scanners)}); name one", p,
                                   None, "scanners")
        name = next(iter(scanners))
    if name not in scanners:
        raise InputFormatError(f"no scanner named {name!r} (scanners: {', '.join(scanners)})", p, None, "scanners")
    rec = scanners[name]
    return rec["mount"], {k: v for k, v in rec.items() if k != "mount"}


def scanner_from_record(rec: Any, path: PathLike, lines: dict[str, int], key_path: str = "") -> ScannerMount:
    """The mount of one record (a mapping with ``body_from_scanner`` and ``lever_arm_m``), checked."""
    kp = (key_path + ".") if key_path else ""
    r = check_rotation(rec["body_from_scanner"], path, lines.get("body_from_scanner"), kp + "body_from_scanner")
    try:
        lever = np.array(rec["lever_arm_m"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputFormatError(f"expected 3 numbers, got {rec['lever_arm_m']!r}", path, lines.get("lever_arm_m"),
                               kp + "lever_arm_m") from None
    if lever.shape != (3,) or not np.all(np.isfinite(lever)):
        raise InputFormatError(f"expected 3 finite numbers, got {rec['lever_arm_m']!r}", path, lines.get("lever_arm_m"),
                               kp + "lever_arm_m")
    check_lever_arm(lever, path, lines.get("lever_arm_m"), kp + "lever_arm_m")
    antenna = np.array(rec.get("antenna_lever_arm_m", (0.0, 0.0, 0.0)), dtype=np.float64)
    return ScannerMount(r, lever, antenna)


def read_rig_scanners(path: PathLike) -> dict[str, dict[str, Any]]:
    """The ``scanners`` section of a rig file: ``{name: {"mount": ScannerMount, "range_offset_m": ..., ...}}``
    (empty when the file has none).  Checks every record (names, keys, rotation, lever arm, numbers)."""
    from skyrig.io._yaml_lines import _Map, _Seq, load_yaml_lines

    p = os.fspath(path)
    doc = load_yaml_lines(read_text(p), p)
    if not isinstance(doc, _Map) or doc.get("scanners") is None:
        return {}
    return parse_scanners(doc["scanners"], doc, p, _Map, _Seq)


def parse_scanners(value: Any, parent: Any, p: str, map_type: type, seq_type: type) -> dict[str, dict[str, Any]]:
    """Check and read a ``scanners`` list (YAML nodes with line numbers, :func:`skyrig.io.rig_file.load_yaml_lines`)."""
    line = getattr(parent, "key_lines", {}).get("scanners", getattr(parent, "line", None))
    if not isinstance(value, seq_type):
        raise InputFormatError("expected a list of scanner records", p, line, "scanners")
    out: dict[str, dict[str, Any]] = {}
    for i, rec in enumerate(value):
        kp = f"scanners[{i}]"
        if not isinstance(rec, map_type):
            raise InputFormatError("expected a mapping", p, getattr(rec, "line", line), kp)
        lines = rec.key_lines
        for k in rec:
            if k not in _SCANNER_KEYS:
                raise InputFormatError(f"unknown key {k!r} (allowed: {', '.join(sorted(_SCANNER_KEYS))})", p,
                                       lines.get(k), f"{kp}.{k}")
        for k in ("name", "body_from_scanner", "lever_arm_m"):
            if k not in rec:
                raise InputFormatError(f"missing key {k!r}", p, rec.line, f"{kp}.{k}")
        name = rec["name"]
        if not isinstance(name, str) or not name.strip():
            raise InputFormatError(f"expected non-empty text, got {name!r}", p, lines.get("name"), f"{kp}.name")
        if name in out:
            raise InputFormatError(f"duplicate scanner name {name!r}", p, lines.get("name"), f"{kp}.name")
        entry: dict[str, Any] = {"mount": scanner_from_record(rec, p, lines, kp)}
        for k in ("range_offset_m", "range_scale_ppm", "range_sigma_m"):
            if k in rec:
                v = rec[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                    raise InputFormatError(f"expected a finite number, got {v!r}", p, lines.get(k), f"{kp}.{k}")
                entry[k] = float(v)
        if abs(entry.get("range_offset_m", 0.0)) > 10.0:
            raise InputFormatError(f"a range offset of {entry['range_offset_m']:g} m is not plausible (metres meant?)",
                                   p, lines.get("range_offset_m"), f"{kp}.range_offset_m")
        cal = rec.get("calibration")
        if cal is not None:
            if not isinstance(cal, map_type):
                raise InputFormatError("expected a mapping", p, lines.get("calibration"), f"{kp}.calibration")
            for k in cal:
                if k not in _CAL_KEYS:
                    raise InputFormatError(f"unknown key {k!r} (allowed: {', '.join(sorted(_CAL_KEYS))})", p,
                                           cal.key_lines.get(k), f"{kp}.calibration.{k}")
            entry["calibration"] = _plain(cal)
        out[name] = entry
    return out


def _plain(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    return v


def write_scanner_record(path: PathLike, record: dict[str, Any], base_rig: PathLike | None = None) -> None:
    """Write ``record`` (a scanner record as in the module docstring) into the rig file ``path``: the rig of
    ``base_rig`` (its other scanners kept, one of the same name replaced) or a scanner-only rig file."""
    if base_rig is not None:
        read_rig_scanners(base_rig)  # checks the scanners it has
        doc = yaml.safe_load(read_text(os.fspath(base_rig))) or {}
    else:
        doc = {"format": "skyrig-rig", "version": 1, "name": str(record["name"]),
               "description": "laser scanner calibrated by skyrig"}
    scanners = [s for s in (doc.get("scanners") or []) if s.get("name") != record["name"]]
    scanners.append(_plain(record))
    doc["scanners"] = scanners
    text = yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, width=120, default_flow_style=None)
    with atomic_write(path) as fh:
        fh.write("# skyrig rig file; format described in docs/formats/rig_file.md\n")
        fh.write(text)
    read_rig_scanners(path)  # what was written reads back
