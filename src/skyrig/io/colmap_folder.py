"""COLMAP model folders, binary or text: :func:`read_colmap` / :func:`write_colmap` choose the encoding
(:mod:`skyrig.io.colmap_binary`, :mod:`skyrig.io.colmap_text`) of the model in :mod:`skyrig.io.colmap` (kept apart
so that the model module imports neither encoding)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from skyrig.errors import InputFormatError
from skyrig.io.colmap import FIT_TOLERANCE_PX, ColmapModel

__all__ = ["read_colmap", "write_colmap"]


def read_colmap(folder: str | PathLike[str], pixel_size_mm: float = 0.001) -> ColmapModel:
    """Read a COLMAP model folder, binary (``*.bin``) or text (``*.txt``); binary when both are there
    (COLMAP's own choice)."""
    d = Path(folder)
    if all((d / f"{n}.bin").is_file() for n in ("cameras", "images", "points3D")):
        from skyrig.io.colmap_binary import read_colmap_binary

        return read_colmap_binary(d, pixel_size_mm)
    if all((d / f"{n}.txt").is_file() for n in ("cameras", "images", "points3D")):
        from skyrig.io.colmap_text import read_colmap_text

        return read_colmap_text(d, pixel_size_mm)
    raise InputFormatError("not a COLMAP model folder: needs cameras, images and points3D as .bin or .txt", d)


def write_colmap(folder: str | PathLike[str], model: ColmapModel, binary: bool = True, fit_cameras: bool = False,
                 fit_tolerance_px: float = FIT_TOLERANCE_PX) -> list[Path]:
    """Write ``model`` as a COLMAP model into ``folder``: binary (default) or text.  Returns the files written
    (each atomically).  ``fit_cameras``: see :func:`colmap_camera`."""
    if binary:
        from skyrig.io.colmap_binary import write_colmap_binary

        return write_colmap_binary(folder, model, fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
    from skyrig.io.colmap_text import write_colmap_text

    return write_colmap_text(folder, model, fit_cameras=fit_cameras, fit_tolerance_px=fit_tolerance_px)
