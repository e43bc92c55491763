"""Contour lines of a DTM (interval and index contours), smoothed only within the DTM's precision.

The lines are traced by ``contourpy`` (the marching-squares library behind Matplotlib) on the grid of cell
centres; being level sets of one continuous field, two lines of different levels never cross.  Before tracing,
the grid may be smoothed by a Gaussian (``smooth_cells``), but every cell moves by at most ``smooth_sigmas`` times
its predicted precision (``z + clip(G * z - z, -k sigma, +k sigma)``): the lines lose the noise of the DTM, never
its shape beyond what the DTM can tell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import GridSpec
from skyrig.errors import InputFormatError

__all__ = ["Contours", "contour_levels", "smooth_within_precision", "make_contours"]


@dataclass(frozen=True)
class Contours:
    """Contour lines.

    Attributes
    ----------
    lines
        List of ``(M, 2)`` map coordinates (metres), one per line.
    elevation
        ``(L,)`` height of each line (metres, the DTM's vertical reference).
    index
        ``(L,)`` bool: True for index contours (every ``index_every``-th level).
    closed
        ``(L,)`` bool: True where the line is a closed ring.
    interval_m, index_every
        As given.
    """

    lines: list[NDArray[np.float64]]
    elevation: NDArray[np.float64]
    index: NDArray[np.bool_]
    closed: NDArray[np.bool_]
    interval_m: float
    index_every: int

    def __len__(self) -> int:
        return len(self.lines)


def contour_levels(zmin: float, zmax: float, interval_m: float, *, option: str = "interval") -> NDArray[np.float64]:
    """Multiples of ``interval_m`` strictly inside ``[zmin, zmax]``.

    Raises
    ------
    InputFormatError
        When the interval is not positive or no level falls inside the relief (``field`` = ``option``).

    Examples
    --------
    >>> contour_levels(12.3, 17.9, 2.0).tolist()
    [14.0, 16.0]
    """
    if not (np.isfinite(interval_m) and interval_m > 0):
        raise InputFormatError(f"the contour interval must be a positive number of metres, got {interval_m!r}",
                               field=option)
    if not (np.isfinite(zmin) and np.isfinite(zmax)):
        raise InputFormatError("the surface has no valid height", field=option)
    k0 = int(np.floor(zmin / interval_m)) + 1
    k1 = int(np.ceil(zmax / interval_m)) - 1
    if k1 < k0:
        raise InputFormatError(f"an interval of {interval_m:g} m is larger than the relief (heights "
                               f"{zmin:.3f} .. {zmax:.3f} m): no contour line", field=option)
    if k1 - k0 > 100000:
        raise InputFormatError(f"an interval of {interval_m:g} m gives {k1 - k0 + 1} levels over the relief "
                               f"{zmin:.3f} .. {zmax:.3f} m; choose a larger one", field=option)
    return np.arange(k0, k1 + 1) * float(interval_m)


def smooth_within_precision(height: NDArray[np.float64], sigma: NDArray[np.float64] | None, smooth_cells: float,
                            smooth_sigmas: float = 1.0) -> NDArray[np.float64]:
    """Gaussian smoothing (NaN-aware normalised convolution) whose change of each cell is clipped to
    ``smooth_sigmas * sigma`` (no change where ``sigma`` is unknown or None)."""
    from scipy import ndimage

    z = np.asarray(height, np.float64)
    if smooth_cells <= 0 or sigma is None:
        return z.copy()
    ok = np.isfinite(z)
    num = ndimage.gaussian_filter(np.where(ok, z, 0.0), smooth_cells, mode="nearest")
    den = ndimage.gaussian_filter(ok.astype(np.float64), smooth_cells, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        g = num / den
    lim = smooth_sigmas * np.where(np.isfinite(sigma), sigma, 0.0)
    return np.where(ok, z + np.clip(np.nan_to_num(g - z), -lim, lim), np.nan)


def make_contours(height: NDArray[np.float64], grid: GridSpec, interval_m: float, *, index_every: int = 5,
                  sigma: NDArray[np.float64] | None = None, smooth_cells: float = 1.0, smooth_sigmas: float = 1.0,
                  min_vertices: int = 2) -> Contours:
    """Contour lines of a gridded surface.

    Parameters
    ----------
    height
        ``(rows, cols)`` heights (metres, NaN = no data) on ``grid`` (values at cell centres).
    interval_m
        Contour interval (metres); levels are its multiples.
    index_every
        Every this many levels (counted from height 0) is an index contour.
    sigma
        ``(rows, cols)`` predicted precision of the heights; bounds the smoothing (None: no smoothing).
    smooth_cells, smooth_sigmas
        Gaussian width (cells) and the largest change allowed, in sigmas.

    Raises
    ------
    InputFormatError
        On a bad interval (0, negative, or larger than the relief), index spacing or grid shape.
    """
    import contourpy

    h = np.asarray(height, np.float64)
    if h.shape != grid.shape:
        raise InputFormatError(f"heights {h.shape} do not match the grid {grid.shape}", field="height")
    if index_every < 1:
        raise InputFormatError(f"must be at least 1, got {index_every}", field="index_every")
    z = smooth_within_precision(h, sigma, smooth_cells, smooth_sigmas)
    ok = np.isfinite(z)
    if not ok.any():
        raise InputFormatError("the surface has no valid height", field="height")
    levels = contour_levels(float(z[ok].min()), float(z[ok].max()), interval_m)
    xs = grid.x0 + (np.arange(grid.width) + 0.5) * grid.cell_m
    ys = grid.y0 - (np.arange(grid.height) + 0.5) * grid.cell_m
    # contourpy wants increasing y: flip the rows
    gen = contourpy.contour_generator(xs, ys[::-1], np.ma.masked_invalid(z[::-1]), line_type="Separate",
                                      corner_mask=False)
    lines, elev, closed = [], [], []
    for lv in levels:
        for ln in gen.lines(float(lv)):
            ln = np.asarray(ln, np.float64)
            if len(ln) < min_vertices:
                continue
            lines.append(ln)
            elev.append(lv)
            closed.append(bool(len(ln) > 3 and np.allclose(ln[0], ln[-1])))
    elevation = np.asarray(elev, np.float64)
    idx = np.round(elevation / interval_m).astype(np.int64) % index_every == 0
    return Contours(lines, elevation, idx, np.asarray(closed, bool), float(interval_m), int(index_every))
