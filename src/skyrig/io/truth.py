"""Truth file of a simulated project (``truth/truth.json``, format ``skyrig-sim-truth`` version 1).

See ``docs/formats/simulated_project.md``.  A JSON object with the keys ``format``, ``version``,
``scenario``, ``size``, ``seed``, ``local_frame`` (lat, lon, h of the ENU origin of the scene), ``crs``,
``errors`` (the :class:`~skyrig.simulate.errors.SensorErrors` configuration), ``injected`` (the drawn
values: per-strip GNSS shifts, tumbling-curve samples...), ``files`` (relative paths of the truth
files) and ``statistics``.
"""

from __future__ import annotations

import json
from typing import Any

from skyrig._plain import plain
from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike, atomic_write, read_text

MAGIC = "skyrig-sim-truth"
VERSION = 1


_plain = plain


def write_truth(path: PathLike, truth: dict[str, Any]) -> None:
    """Write the truth dictionary (numpy values converted) with ``format`` and ``version``."""
    body = {"format": MAGIC, "version": VERSION, **_plain(truth)}
    with atomic_write(path) as fh:
        json.dump(body, fh, indent=1, sort_keys=False)
        fh.write("\n")


def read_truth(path: PathLike) -> dict[str, Any]:
    """Read a truth file; raises :class:`InputFormatError` on a wrong format or version."""
    try:
        d = json.loads(read_text(path))
    except json.JSONDecodeError as e:
        raise InputFormatError(f"invalid JSON: {e.msg}", path, e.lineno) from None
    if not isinstance(d, dict) or d.get("format") != MAGIC:
        raise InputFormatError(f"not a {MAGIC} file", path, 1, "format")
    if d.get("version") != VERSION:
        raise InputFormatError(f"unsupported version {d.get('version')!r}", path, 1, "version")
    return d
