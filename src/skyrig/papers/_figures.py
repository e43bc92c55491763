"""Figures of the paper reproductions: a matplotlib figure (Agg, no display) and its PNG written atomically."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

__all__ = ["new_figure", "write_png"]


def new_figure(w_in: float = 7.0, h_in: float = 4.0) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w_in, h_in))
    FigureCanvasAgg(fig)
    return fig


def write_png(fig: Any, path: Path, dpi: int = 100) -> None:
    from skyrig.io._text import atomic_write

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())
