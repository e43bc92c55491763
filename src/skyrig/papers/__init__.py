"""Each paper's tables and figures reproduced by a command (``skyrig paper 000|001|002|003|004``).

Layer 3 (it runs scenarios through the lower layers and writes files).  One module per paper,
``skyrig.papers.pNNN``, each with ``run(out_dir, size) -> PaperResult`` (see :mod:`skyrig.papers.base`);
modules are imported lazily so that ``skyrig paper 004`` never imports paper 000's machinery.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path
from typing import Callable, cast

from skyrig.papers.base import Comparison, Figure, PaperResult, PaperTable, Size

__all__ = ["PAPERS", "Comparison", "Figure", "PaperResult", "PaperTable", "Size", "runner"]

#: paper number -> (module, one line: the system)
PAPERS: dict[str, tuple[str, str]] = {
    "000": ("skyrig.papers.p000", "MACS-TumbleCam: nadir + tumbling oblique camera, actuator-dependent boresight"),
    "001": ("skyrig.papers.p001", "DLR 3K camera: near-real-time DSM chain for disaster monitoring"),
    "002": ("skyrig.papers.p002", "ADFEX UAV: 2D laser scanner vs SfM against a TLS reference"),
    "003": ("skyrig.papers.p003", "Uncalibrated GNSS/IMU data: datum, antenna offset, boresight recovery"),
    "004": ("skyrig.papers.p004", "MIDAS penta camera: CalQC calibration and Tab. 11"),
}


def runner(paper: str) -> Callable[[Path, Size], PaperResult]:
    """The ``run(out_dir, size)`` function of ``paper`` ('000'..'004')."""
    if paper not in PAPERS:
        raise KeyError(f"no paper {paper!r}; known: {', '.join(PAPERS)}")
    return cast(Callable[[Path, Size], PaperResult], import_module(PAPERS[paper][0]).run)
