"""Flight strips from a sequence of GNSS positions (layer 1, with the trajectory: arrays in, arrays out)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["detect_strips"]


def _renumber_strips(strip: NDArray[np.int64]) -> NDArray[np.int64]:
    """Strip labels of a subset renumbered 0..T-1 (-1 kept)."""
    out = np.full(len(strip), -1, np.int64)
    ok = strip >= 0
    if ok.any():
        out[ok] = np.unique(strip[ok], return_inverse=True)[1]
    return out


def detect_strips(gnss: NDArray, max_turn_deg: float = 45.0, min_images: int = 3) -> NDArray[np.int64]:
    """Flight strips from GNSS positions in capture order.

    A strip is a run of consecutive images whose horizontal displacement keeps its direction (within
    ``max_turn_deg`` of the strip's first leg).

    Parameters
    ----------
    gnss
        ``(I, 3)`` positions (m) in capture order.
    max_turn_deg
        Direction change that starts a new strip (deg).
    min_images
        Runs shorter than this get no strip.

    Returns
    -------
    ``(I,)`` strip index per image (0..T-1), -1 for images in no strip.
    """
    g = np.asarray(gnss, float)
    n = len(g)
    lab = np.full(n, -1, np.int64)
    if n < 2:
        return lab
    leg = np.diff(g[:, :2], axis=0)
    ang = np.arctan2(leg[:, 1], leg[:, 0])
    start, k = 0, 0
    runs = []
    ref = ang[0]
    for j in range(1, n - 1):  # leg j joins image j and j+1
        d = np.degrees(abs((ang[j] - ref + np.pi) % (2 * np.pi) - np.pi))
        if d > max_turn_deg:
            runs.append((start, j + 1))  # images start..j
            start, ref = j + 1, ang[j + 1] if j + 1 < n - 1 else ang[j]
    runs.append((start, n))
    for a, b in runs:
        if b - a >= min_images:
            lab[a:b] = k
            k += 1
    return lab
