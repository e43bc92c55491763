"""Pixels of an image window by window, at any reduction, without loading a large frame whole (GDAL through
rasterio: TIFF / COG with its overviews, JPEG with its DCT-scaled decoding, PNG).

:class:`ImageWindows` is what a tile server or a sub-pixel refinement asks for: ``window(col0, row0, w, h,
out_w, out_h)`` gives the pixels of the full-resolution rectangle ``[col0, col0 + w) x [row0, row0 + h)``
(pixel edges; pixel centres are at integer positions, :mod:`skyrig.camera.frame`), averaged down to
``out_w x out_h``.  Samples are returned as they are stored (8 or 16 bit).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike

__all__ = ["ImageWindows"]


class ImageWindows:
    """An image file opened for window reads (thread-safe: one reader at a time per image).

    Parameters
    ----------
    path
        The image file.

    Raises
    ------
    InputFormatError
        The file is missing or GDAL cannot read it.
    """

    def __init__(self, path: PathLike) -> None:
        import rasterio
        from rasterio.errors import RasterioIOError

        self.path = Path(path)
        if not self.path.is_file():
            raise InputFormatError("image file not found", self.path)
        import warnings

        from rasterio.errors import NotGeoreferencedWarning

        try:
            with rasterio.Env(GDAL_PAM_ENABLED="NO"), warnings.catch_warnings():  # no .aux.xml next to the images
                warnings.simplefilter("ignore", NotGeoreferencedWarning)  # a photo has no geotransform
                self._ds = rasterio.open(self.path)
        except RasterioIOError as exc:
            raise InputFormatError(f"not a readable image ({exc})", self.path) from None
        self.width = int(self._ds.width)
        self.height = int(self._ds.height)
        self.bands = int(self._ds.count)
        self.dtype = np.dtype(self._ds.dtypes[0])
        self.driver = str(self._ds.driver)
        self.tiled = bool(self._ds.profile.get("tiled", False))
        self._lock = threading.Lock()

    def close(self) -> None:
        self._ds.close()

    def window(self, col0: int, row0: int, width: int, height: int, out_width: int | None = None,
               out_height: int | None = None, gray: bool = False) -> NDArray:
        """Pixels of the window (clipped to the image) as ``(h, w)`` (grey or one band) or ``(h, w, 3)`` (RGB).

        ``out_width`` / ``out_height``: the size to average the window down to (default: full resolution).
        """
        from rasterio.enums import Resampling
        from rasterio.windows import Window

        c0, r0 = max(int(col0), 0), max(int(row0), 0)
        c1, r1 = min(int(col0) + int(width), self.width), min(int(row0) + int(height), self.height)
        if c1 <= c0 or r1 <= r0:
            raise ValueError(f"window ({col0}, {row0}, {width} x {height}) lies outside {self.path.name} "
                             f"({self.width} x {self.height} px)")
        ow = int(out_width) if out_width else c1 - c0
        oh = int(out_height) if out_height else r1 - r0
        bands = [1, 2, 3] if self.bands >= 3 else [1]
        with self._lock:
            a = self._ds.read(bands, window=Window(c0, r0, c1 - c0, r1 - r0), out_shape=(len(bands), oh, ow),
                              resampling=Resampling.average)
        a = np.moveaxis(a, 0, -1)
        if gray:
            return a[..., 0] if a.shape[-1] == 1 else (a @ np.array([0.299, 0.587, 0.114])).astype(np.float32)
        return a[..., 0] if a.shape[-1] == 1 else a

    def tiled_copy(self, dest: PathLike, pixels: NDArray | None = None,
                   pause: Callable[[], None] | None = None) -> "ImageWindows":
        """Write a tiled copy (GeoTIFF, 256 px blocks, JPEG-compressed for 8-bit samples, DEFLATE otherwise) to
        ``dest`` and open it.  A JPEG or PNG can only be decoded from its top: every window of it costs a decode
        down to the window; of the copy, only its blocks.

        ``pixels``: the whole image already decoded, as :meth:`window` gives it (``(h, w, 3)`` RGB or ``(h, w)``,
        the file's sample type): written from memory a row of blocks at a time, calling ``pause()`` before each
        (to yield to more urgent work); without it GDAL streams the file (reads it line by line)."""
        import warnings

        import rasterio
        import rasterio.shutil
        from rasterio.errors import NotGeoreferencedWarning
        from rasterio.windows import Window

        nb = self.bands if pixels is None else (pixels.shape[2] if pixels.ndim == 3 else 1)
        opts: dict = {"TILED": "YES", "BLOCKXSIZE": 256, "BLOCKYSIZE": 256, "NUM_THREADS": "ALL_CPUS"}
        if self.dtype == np.uint8:
            opts.update(COMPRESS="JPEG", JPEG_QUALITY=92, **({"PHOTOMETRIC": "YCBCR"} if nb == 3 else {}))
        else:
            opts.update(COMPRESS="DEFLATE", ZLEVEL=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            if pixels is None:
                rasterio.shutil.copy(str(self.path), str(dest), driver="GTiff", **opts)
                return ImageWindows(dest)
            a = pixels if pixels.ndim == 3 else pixels[..., None]
            if a.shape[:2] != (self.height, self.width) or a.dtype != self.dtype:
                raise ValueError(f"pixels {pixels.shape} {pixels.dtype} are not {self.path.name} "
                                 f"({self.height} x {self.width}, {self.dtype})")
            with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(
                    str(dest), "w", driver="GTiff", width=self.width, height=self.height, count=a.shape[2],
                    dtype=a.dtype, **opts) as ds:
                for r0 in range(0, self.height, 256):
                    if pause is not None:
                        pause()
                    r1 = min(r0 + 256, self.height)
                    ds.write(np.moveaxis(a[r0:r1], -1, 0), window=Window(0, r0, self.width, r1 - r0))
        return ImageWindows(dest)

    def around(self, col: float, row: float, half: int, gray: bool = True) -> tuple[NDArray, tuple[int, int]]:
        """Full-resolution pixels within ``half`` pixels of (``col``, ``row``), clipped to the image, and the
        (column, row) of the window's first pixel (add it to window positions to get image positions)."""
        c0 = min(max(int(round(col)) - half, 0), self.width - 1)
        r0 = min(max(int(round(row)) - half, 0), self.height - 1)
        c1 = max(min(int(round(col)) + half + 1, self.width), c0 + 1)
        r1 = max(min(int(round(row)) + half + 1, self.height), r0 + 1)
        return self.window(c0, r0, c1 - c0, r1 - r0, gray=gray), (c0, r0)

    def __enter__(self) -> "ImageWindows":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
