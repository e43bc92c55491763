"""Flight strips: moved to :mod:`skyrig.trajectory.strips` (layer 1, so that :mod:`skyrig.match` can use them
without importing :mod:`skyrig.orient`); the names stay importable from here."""

from skyrig.trajectory.strips import _renumber_strips, detect_strips

__all__ = ["detect_strips", "_renumber_strips"]
