"""A growing tiled web map on disk: XYZ PNG tiles (``ROOT/<layer>/<z>/<x>/<y>.png``, Web Mercator EPSG:3857, the
OpenStreetMap "slippy map" tile scheme that Leaflet and OpenLayers read) into which georeferenced RGBA rasters are
painted as they arrive, newest on top.

Every tile is written to a temporary file next to it and renamed into place (:func:`skyrig.io._text.atomic_write`),
so a reader (the live page's server) sees a tile whole or not at all, never half-written.  Rasters are reprojected
with rasterio (GDAL's warper, PROJ for the CRS): once per zoom level into a canvas covering the tiles they touch,
which is then cut into tiles and composited over the tiles already there.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from skyrig.errors import OutputPathError
from skyrig.io._text import PathLike, atomic_write

__all__ = ["TILE_PX", "WEB_MERCATOR_HALF", "tile_range", "tile_bounds", "zoom_for_cell", "paint", "paint_tiles",
           "TileCache", "read_tile", "lonlat_bounds"]

TILE_PX = 256
#: half the side of the Web Mercator square (m): pi * 6378137
WEB_MERCATOR_HALF = math.pi * 6378137.0


def tile_bounds(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` of tile ``z/x/y`` in EPSG:3857 metres (y = 0 is the northern row)."""
    size = 2.0 * WEB_MERCATOR_HALF / (1 << z)
    xmin = -WEB_MERCATOR_HALF + x * size
    ymax = WEB_MERCATOR_HALF - y * size
    return xmin, ymax - size, xmin + size, ymax


def tile_range(z: int, bounds: Sequence[float]) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` inclusive tile indices at zoom ``z`` covering EPSG:3857 ``bounds``."""
    n = 1 << z
    size = 2.0 * WEB_MERCATOR_HALF / n
    xmin, ymin, xmax, ymax = bounds

    def col(v: float) -> int:
        return int(min(max(math.floor((v + WEB_MERCATOR_HALF) / size), 0), n - 1))

    def row(v: float) -> int:
        return int(min(max(math.floor((WEB_MERCATOR_HALF - v) / size), 0), n - 1))

    return col(xmin), row(ymax), col(xmax), row(ymin)


def zoom_for_cell(cell_m: float, lat_deg: float) -> int:
    """The zoom whose tile pixels are nearest (in scale) to ``cell_m`` on the ground at latitude ``lat_deg``: between
    0.71 and 1.41 cells (a Web Mercator pixel is ``2 pi R cos(lat) / (256 * 2^z)`` metres on the ground)."""
    ground = 2.0 * WEB_MERCATOR_HALF * math.cos(math.radians(lat_deg)) / TILE_PX
    return int(min(max(math.floor(math.log2(ground / cell_m) + 0.5), 0), 24))


def lonlat_bounds(crs: str, bounds: Sequence[float]) -> tuple[float, float, float, float]:
    """``(west, south, east, north)`` degrees of ``bounds`` given in ``crs``."""
    from rasterio.warp import transform_bounds

    return tuple(transform_bounds(crs, "EPSG:4326", *bounds, densify_pts=21))  # type: ignore[return-value]


def _path(root: Path, layer: str, z: int, x: int, y: int) -> Path:
    return root / layer / str(z) / str(x) / f"{y}.png"


def read_tile(path: PathLike) -> NDArray[np.uint8] | None:
    """``(256, 256, 4)`` RGBA of a tile file, or None when there is none."""
    if not Path(path).is_file():
        return None
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise OutputPathError("is not a readable PNG tile", path)
    if data.ndim != 3 or data.shape[2] != 4:
        raise OutputPathError("is not an RGBA tile", path)
    return cv2.cvtColor(data, cv2.COLOR_BGRA2RGBA)


def _write_tile(path: Path, rgba: NDArray[np.uint8]) -> None:
    # fast deflate (run lengths only): a live tile is rewritten as exposures overlap it
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA),
                           [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE])
    if not ok:
        raise OutputPathError("PNG encoding failed", path)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.tobytes())


def paint(root: PathLike, layer: str, rgba: NDArray[np.uint8], transform: Sequence[float], crs: str,
          zooms: Sequence[int]) -> list[tuple[int, int, int]]:
    """Paint a georeferenced RGBA raster (alpha 0 = no data) into the tiles of ``layer`` at every zoom of
    ``zooms``, over what they hold; returns the tiles written ``(z, x, y)``.

    ``transform`` is GDAL's ``(a, b, c, d, e, f)`` of ``rgba`` in ``crs`` (a north-up grid: ``b = d = 0``)."""
    from affine import Affine
    from rasterio.warp import Resampling, reproject, transform_bounds

    root = Path(root)
    h, w = rgba.shape[:2]
    a, b, c, d, e, f = (float(v) for v in transform)
    src_t = Affine(a, b, c, d, e, f)
    xs = [c, c + a * w]
    ys = [f, f + e * h]
    merc = transform_bounds(crs, "EPSG:3857", min(xs), min(ys), max(xs), max(ys), densify_pts=21)
    written = []
    for z in zooms:
        x0, y0, x1, y1 = tile_range(z, merc)
        tb0 = tile_bounds(z, x0, y0)
        size = (tb0[2] - tb0[0]) / TILE_PX
        nx, ny = (x1 - x0 + 1) * TILE_PX, (y1 - y0 + 1) * TILE_PX
        dst_t = Affine(size, 0.0, tb0[0], 0.0, -size, tb0[3])
        canvas = np.zeros((4, ny, nx), np.uint8)
        src = np.moveaxis(rgba, 2, 0)
        for band, how in ((0, Resampling.bilinear), (1, Resampling.bilinear), (2, Resampling.bilinear),
                          (3, Resampling.nearest)):
            reproject(src[band], canvas[band], src_transform=src_t, src_crs=crs, dst_transform=dst_t,
                      dst_crs="EPSG:3857", resampling=how)
        canvas = np.moveaxis(canvas, 0, 2)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                r0, c0 = (ty - y0) * TILE_PX, (tx - x0) * TILE_PX
                new = canvas[r0:r0 + TILE_PX, c0:c0 + TILE_PX]
                on = new[..., 3] > 0
                if not on.any():
                    continue
                p = _path(root, layer, z, tx, ty)
                old = read_tile(p)
                out = new.copy() if old is None else np.where(on[..., None], new, old)
                _write_tile(p, np.ascontiguousarray(out))
                written.append((z, tx, ty))
    return written



class TileCache:
    """The tiles written last, in memory (``(layer, z, x, y)`` -> RGBA, at most ``size``: 256 KB each): a tile
    painted again (the overlap of consecutive exposures) is composited without reading it back."""

    def __init__(self, size: int = 256) -> None:
        from collections import OrderedDict

        self.size = size
        self._d: OrderedDict[tuple[str, int, int, int], NDArray[np.uint8]] = OrderedDict()

    def get(self, key: tuple[str, int, int, int]) -> NDArray[np.uint8] | None:
        t = self._d.get(key)
        if t is not None:
            self._d.move_to_end(key)
        return t

    def put(self, key: tuple[str, int, int, int], tile: NDArray[np.uint8]) -> None:
        self._d[key] = tile
        self._d.move_to_end(key)
        while len(self._d) > self.size:
            self._d.popitem(last=False)


def paint_tiles(root: PathLike, layer: str, tiles: dict[tuple[int, int, int], NDArray[np.uint8]],
                under: bool = False, cache: TileCache | None = None) -> list[tuple[int, int, int]]:
    """Paint RGBA tiles already on the tile grid (``(z, x, y)`` -> ``(256, 256, 4)``; alpha 0 = no data) into
    ``layer`` over what the tiles hold (``under``: beneath it, only where they are empty); returns the tiles
    written."""
    root = Path(root)
    written = []
    for (z, x, y), new in tiles.items():
        on = new[..., 3] > 0
        if not on.any():
            continue
        key = (layer, z, x, y)
        p = _path(root, layer, z, x, y)
        old = cache.get(key) if cache is not None else None
        if old is None:
            old = read_tile(p)
        if old is None:
            out = new
        elif under:
            if not (on & (old[..., 3] == 0)).any():
                continue
            out = np.where((old[..., 3] > 0)[..., None], old, new)
        else:
            out = np.where(on[..., None], new, old)
        out = np.ascontiguousarray(out)
        _write_tile(p, out)
        if cache is not None:
            cache.put(key, out)
        written.append((z, x, y))
    return written
