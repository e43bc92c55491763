"""Report sections of the dense stage: DSM hillshade and orthophoto previews, and any figures and tables the
dense stage wants on the page (``make_section("dsm", ...)``, ``make_section("ortho", ...)``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from skyrig.report import plots
from skyrig.report.model import Figure, Note, Section, Table, register_section

__all__ = ["dsm_section", "ortho_section"]

Image = str | Path | bytes | ArrayLike


@register_section("dsm", order=80)
def dsm_section(dsm: ArrayLike | None = None, cell_m: float = 1.0, hillshade_png: Image | None = None,
                figures: Sequence[Figure] = (), tables: Sequence[Table] = (), caption: str = "") -> Section:
    """The DSM: a hillshade preview (computed from the height grid ``dsm`` ``(R, C)`` metres, rows north to south,
    NaN = no data, cell size ``cell_m``; or given as ``hillshade_png``: a PNG path, PNG bytes or an array) plus
    the dense stage's own figures and tables (accuracy against check data, completeness...)."""
    blocks: list[Any] = []
    if hillshade_png is not None:
        png = plots.png_bytes(hillshade_png)
    elif dsm is not None:
        z = np.asarray(dsm, float)
        hs = plots.hillshade(z, cell_m)
        hs[~np.isfinite(z)] = np.nan
        png = plots.array_png(hs)
    else:
        png = None
    if png is not None:
        blocks.append(Figure("dsm-hillshade", caption or "DSM hillshade (sun from the north-west, 45 deg).", png,
                             "DSM hillshade"))
    blocks += [*figures, *tables]
    if not blocks:
        blocks.append(Note("No DSM given."))
    return Section("dsm", "Digital surface model", blocks)


@register_section("ortho", order=85)
def ortho_section(image: Image, caption: str = "Orthophoto preview.", figures: Sequence[Figure] = (),
                  tables: Sequence[Table] = ()) -> Section:
    """An orthophoto preview (PNG path, PNG bytes, or an ``(R, C)`` / ``(R, C, 3|4)`` array)."""
    return Section("ortho", "Orthophoto", [Figure("ortho-preview", caption, plots.png_bytes(image), "orthophoto"),
                                           *figures, *tables])
