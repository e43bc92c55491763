"""Where the EGM96 geoid grid lies on this machine (layer 0: looks for a path, opens nothing).

:func:`find_geoid` was :func:`skyrig.pipeline.simulate.find_geoid` (still importable there); it lives here so that
the layers below ``pipeline`` (the calibration recipes on simulated flights) can use it without importing up.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["find_geoid"]


def find_geoid() -> str | None:
    """An EGM96 grid: ``$SKYRIG_GEOID``, ``../shared/data/geoid/egm96_15.gtx`` next to the repository, or None."""
    env = os.environ.get("SKYRIG_GEOID")
    if env and Path(env).exists():
        return str(Path(env).resolve())
    here = Path(__file__).resolve()
    for parent in here.parents:
        cand = parent.parent / "shared" / "data" / "geoid" / "egm96_15.gtx"
        if cand.exists():
            return str(cand)
    return None
