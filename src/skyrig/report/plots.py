"""Report figures as PNG bytes (matplotlib's Agg canvas directly: no pyplot, no global backend switch).

Every function returns the PNG file's bytes, ready to be embedded as a data URI.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["residual_map_png", "normalised_histogram_png", "image_residual_png", "array_png", "hillshade",
           "nice_length", "png_bytes"]


def _figure(w_in: float, h_in: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w_in, h_in))
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Any, dpi: int = 100) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def nice_length(x: float) -> float:
    """The largest 1, 2 or 5 times a power of ten that is <= ``x`` (``x`` > 0), for scale bars.

    >>> nice_length(0.037), nice_length(730.0)
    (0.02, 500.0)
    """
    if not (x > 0 and math.isfinite(x)):
        return 1.0
    e = math.floor(math.log10(x))
    for m in (5, 2, 1):
        if m * 10.0**e <= x * (1 + 1e-12):
            return float(m * 10.0**e)
    return float(10.0**e)  # pragma: no cover


def _length_text(m: float) -> str:
    if m >= 1000:
        return f"{m / 1000:g} km"
    if m >= 1:
        return f"{m:g} m"
    if m >= 0.01:
        return f"{m * 100:g} cm"
    return f"{m * 1000:g} mm"


def residual_map_png(xy: ArrayLike, v: ArrayLike, check: ArrayLike, names: ArrayLike, axis_names: tuple[str, str],
                     crs_text: str, label_limit: int = 40, kinds: tuple[str, str] = ("control", "check")) -> bytes:
    """Plan view of control and check points with their residual vectors.

    Parameters
    ----------
    xy
        ``(K, 2)`` point positions in the map (easting, northing), metres.
    v
        ``(K, 3)`` residuals (adjusted minus given) in the same axes, metres; the horizontal part is drawn
        as an arrow (scaled, with a reference arrow giving the scale), the vertical part as the marker colour.
    check
        ``(K,)`` True for check points (circles), False for control (triangles); ``kinds`` names the two in
        the legend.
    names
        ``(K,)`` point names (written next to the points when there are at most ``label_limit``).
    axis_names, crs_text
        Axis labels and the CRS line of the caption.
    """
    from matplotlib.colors import TwoSlopeNorm

    p = np.asarray(xy, float).reshape(-1, 2)
    d = np.asarray(v, float).reshape(-1, 3)
    chk = np.asarray(check, bool).reshape(-1)
    fig = _figure(8.0, 7.0)
    ax = fig.add_subplot(111)
    ext = float(max(np.ptp(p[:, 0]), np.ptp(p[:, 1]), 1.0)) if len(p) else 1.0
    hv = np.hypot(d[:, 0], d[:, 1]) if len(d) else np.zeros(0)
    vmax = float(np.nanmax(hv)) if len(hv) and np.isfinite(hv).any() else 0.0
    ref = nice_length(vmax) if vmax > 0 else 0.01
    scale = 0.12 * ext / (vmax if vmax > 0 else ref)  # the longest vector is 12 % of the map extent
    zmax = float(np.nanmax(np.abs(d[:, 2]))) if len(d) and np.isfinite(d[:, 2]).any() else 0.0
    norm = TwoSlopeNorm(0.0, -max(zmax, 1e-6), max(zmax, 1e-6))
    sc = None
    for sel, marker, lab in ((~chk, "^", kinds[0]), (chk, "o", kinds[1])):
        if sel.any():
            sc = ax.scatter(p[sel, 0], p[sel, 1], c=d[sel, 2], cmap="coolwarm", norm=norm, marker=marker, s=70,
                            edgecolors="k", linewidths=0.6, label=lab, zorder=3)
    if len(p):
        q = ax.quiver(p[:, 0], p[:, 1], d[:, 0] * scale, d[:, 1] * scale, angles="xy", scale_units="xy", scale=1,
                      width=0.004, color="k", zorder=4)
        ax.quiverkey(q, 0.70, 0.05, ref * scale, f"residual {_length_text(ref)}", labelpos="E",
                     coordinates="axes", fontproperties={"size": 8})
        if len(p) <= label_limit:
            for (x, y), n in zip(p, np.asarray(names).reshape(-1)):
                ax.annotate(str(n), (x, y), textcoords="offset points", xytext=(5, -10), fontsize=7)
        pad = 0.2 * ext
        ax.set_xlim(p[:, 0].min() - pad, p[:, 0].max() + pad)
        ax.set_ylim(p[:, 1].min() - pad, p[:, 1].max() + pad)
        # map scale bar, lower left
        bar = nice_length(0.25 * ext)
        x0, y0 = p[:, 0].min() - 0.8 * pad, p[:, 1].min() - 0.7 * pad
        ax.plot([x0, x0 + bar], [y0, y0], color="k", linewidth=3, solid_capstyle="butt")
        ax.text(x0 + bar / 2, y0 + 0.03 * ext, f"map {_length_text(bar)}", ha="center", fontsize=8)
        ax.legend(loc="upper left", fontsize=8)
    if sc is not None:
        cb = fig.colorbar(sc, ax=ax, shrink=0.7)
        cb.set_label("vertical residual (m)")
    ax.set_aspect("equal")
    ax.set_xlabel(f"{axis_names[0]} (m)")
    ax.set_ylabel(f"{axis_names[1]} (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(axis="x", labelrotation=30)
    ax.set_title(crs_text, fontsize=9, loc="left")
    return _png(fig)


def normalised_histogram_png(w: ArrayLike, groups: dict[str, NDArray[np.float64]] | None = None,
                             limit: float = 5.0) -> bytes:
    """Histogram (density) of normalised residuals with the N(0, 1) density; values beyond ``limit`` are counted
    in the title.  ``groups`` optionally splits the histogram (stacked) by observation group."""
    x = np.asarray(w, float).reshape(-1)
    x = x[np.isfinite(x)]
    fig = _figure(7.5, 4.2)
    ax = fig.add_subplot(111)
    bins = np.linspace(-limit, limit, 41)
    inside = np.abs(x) <= limit
    if groups:
        data = [np.clip(g[np.isfinite(g)], -limit, limit) for g in groups.values()]
        ax.hist(data, bins=bins, density=False, stacked=True, label=list(groups),
                weights=[np.full(len(g), 1.0 / max(len(x), 1) / (bins[1] - bins[0])) for g in data])
    else:
        ax.hist(np.clip(x, -limit, limit), bins=bins, density=True, color="#7aa6d6", edgecolor="white")
    t = np.linspace(-limit, limit, 400)
    ax.plot(t, np.exp(-0.5 * t**2) / math.sqrt(2 * math.pi), "k-", lw=1.5, label="N(0, 1)")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_xlabel("normalised residual w")
    ax.set_ylabel("density")
    n_out = int((~inside).sum())
    ax.set_title(f"{len(x)} normalised residuals; {n_out} beyond ±{limit:g} (drawn in the end bins)", fontsize=9)
    return _png(fig)


def image_residual_png(pixel: ArrayLike, v: ArrayLike, width: float | None, height: float | None, title: str,
                       grid: int = 12) -> bytes:
    """Image residuals of one camera averaged on a ``grid x grid`` raster, drawn as vectors with a scale arrow."""
    px = np.asarray(pixel, float).reshape(-1, 2)
    r = np.asarray(v, float).reshape(-1, 2)
    w = float(width) if width else (float(np.ptp(px[:, 0])) if len(px) else 1.0)
    h = float(height) if height else (float(np.ptp(px[:, 1])) if len(px) else 1.0)
    x0 = 0.0 if width else (float(px[:, 0].min()) if len(px) else 0.0)
    y0 = 0.0 if height else (float(px[:, 1].min()) if len(px) else 0.0)
    w, h = max(w, 1.0), max(h, 1.0)
    fig = _figure(6.5, max(2.5, min(8.0, 6.5 * h / w)))
    ax = fig.add_subplot(111)
    if len(px):
        gx = np.clip(((px[:, 0] - x0) / w * grid).astype(int), 0, grid - 1)
        gy = np.clip(((px[:, 1] - y0) / h * grid).astype(int), 0, grid - 1)
        cell = gy * grid + gx
        n = np.bincount(cell, minlength=grid * grid)
        mx = np.bincount(cell, r[:, 0], grid * grid) / np.maximum(n, 1)
        my = np.bincount(cell, r[:, 1], grid * grid) / np.maximum(n, 1)
        cx = (np.arange(grid * grid) % grid + 0.5) * w / grid + x0
        cy = (np.arange(grid * grid) // grid + 0.5) * h / grid + y0
        ok = n > 0
        mag = np.hypot(mx[ok], my[ok])
        ref = nice_length(float(mag.max())) if mag.size and mag.max() > 0 else 0.1
        s = 0.5 * w / grid / ref
        q = ax.quiver(cx[ok], cy[ok], mx[ok] * s, my[ok] * s, angles="xy", scale_units="xy", scale=1, width=0.004)
        ax.quiverkey(q, 0.80, 1.03, ref * s, f"{ref:g} px", labelpos="E", coordinates="axes")
    ax.set_xlim(x0, x0 + w)
    ax.set_ylim(y0 + h, y0)
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9, loc="left")
    return _png(fig)


def hillshade(z: ArrayLike, cell_m: float = 1.0, azimuth_deg: float = 315.0, altitude_deg: float = 45.0
              ) -> NDArray[np.float64]:
    """Hillshade ``(R, C)`` in [0, 1] of a height grid ``z`` ``(R, C)`` (rows north to south, metres; NaN = no data
    and gives NaN), sun from ``azimuth_deg`` (clockwise from north) at ``altitude_deg``."""
    a = np.asarray(z, float)
    gy, gx = np.gradient(a, cell_m)  # gy along rows (southwards), gx along columns (eastwards)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)  # direction of steepest descent, clockwise from north
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    hs = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return np.clip(hs, 0.0, 1.0)


def array_png(a: ArrayLike, cmap: str | None = None, max_side: int = 1200) -> bytes:
    """An image array as PNG: ``(R, C)`` grey (scaled to its finite 2-98 % range, NaN transparent) or ``(R, C, 3|4)``
    (uint8, or floats in [0, 1]); subsampled to at most ``max_side`` pixels a side."""
    from matplotlib.image import imsave

    x = np.asarray(a)
    step = max(1, int(math.ceil(max(x.shape[:2]) / max_side)))
    x = x[::step, ::step]
    buf = io.BytesIO()
    if x.ndim == 2:
        f = x.astype(float)
        fin = np.isfinite(f)
        lo, hi = (np.percentile(f[fin], [2, 98]) if fin.any() else (0.0, 1.0))
        g = np.clip((f - lo) / (hi - lo if hi > lo else 1.0), 0, 1)
        rgba = np.zeros(f.shape + (4,))
        if cmap:
            from matplotlib import colormaps

            rgba[:] = colormaps[cmap](np.where(fin, g, 0.0))
        else:
            rgba[..., :3] = np.where(fin, g, 0.0)[..., None]
        rgba[..., 3] = fin
        imsave(buf, rgba, format="png")
    else:
        imsave(buf, x, format="png")
    return buf.getvalue()


def png_bytes(image: str | Path | bytes | ArrayLike, **kw: Any) -> bytes:
    """PNG bytes of ``image``: PNG bytes as they are, a PNG file's contents, or an array (:func:`array_png`)."""
    if isinstance(image, (bytes, bytearray)):
        data = bytes(image)
    elif isinstance(image, (str, Path)):
        data = Path(image).read_bytes()
    else:
        return array_png(image, **kw)
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        from skyrig.errors import InputFormatError

        raise InputFormatError("not a PNG file", image if isinstance(image, (str, Path)) else "<bytes>")
    return data
