"""DEM GeoTIFF (any GDAL raster) through rasterio, into :class:`skyrig.georef.ground.Dem`."""

from __future__ import annotations

import numpy as np
import rasterio
from rasterio.errors import RasterioIOError

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.georef.ground import Dem
from skyrig.io._text import PathLike, output_temp, publish


#: Values GIS tools write for "no data" that a raster may hold without declaring them.
NODATA_SENTINELS = (-9999.0, -32767.0, -32768.0, -99999.0, -3.4028234663852886e38)


def read_dem(path: PathLike, geoid: str | None = None, band: int = 1, crs: str | None = None) -> Dem:
    """Read a DEM raster.

    Parameters
    ----------
    path
        Raster file (GeoTIFF / COG or anything GDAL reads).
    geoid
        Geoid grid when the heights are orthometric; None for ellipsoidal heights.
    band
        1-based band holding the heights.
    crs
        CRS to use when the file has none; for a file that states one it must agree (otherwise an error).

    Raises
    ------
    InputFormatError
        Naming the file: not a raster, no such band, no CRS, a CRS other than ``crs``, heights no terrain has
        (all cells: a unit error, the hint gives mm or cm), positions only inside the CRS's area of use when x and y
        are swapped.  Cells holding an undeclared nodata value (-9999, -32767, -32768, -99999, -3.4e38) are left out
        with a :class:`~skyrig.errors.PlausibilityWarning`.
    """
    from skyrig.io.plausibility import _crs_equal, check_coordinates, warn

    try:
        with rasterio.open(path) as ds:
            if not 1 <= band <= ds.count:
                raise InputFormatError(f"band {band} does not exist (the raster has {ds.count})", path, None, "band")
            if ds.crs is None and crs is None:
                raise InputFormatError("raster has no CRS; pass one explicitly", path, field="crs")
            if ds.crs is not None and crs is not None and not _crs_equal(ds.crs.to_wkt(), str(crs)):
                raise InputFormatError(f"the raster is in {ds.crs.to_string()}, not in the CRS given ({crs}); "
                                       "reproject it or give its own CRS", path, None, "crs")
            file_crs = crs or ds.crs.to_wkt()
            data = ds.read(band, masked=True).astype(np.float64)
            t = ds.transform
            width, height = ds.width, ds.height
    except RasterioIOError as exc:
        raise InputFormatError(f"cannot read raster: {exc}", path) from None
    heights = np.ma.filled(data, np.nan)
    frame = WorldFrame.map(file_crs, geoid)
    sentinel = np.isin(heights, NODATA_SENTINELS)
    if sentinel.any():
        values = ", ".join(f"{v:g}" for v in np.unique(heights[sentinel]))
        warn(f"{path}: {int(sentinel.sum())} cells hold {values}, a nodata value the raster does not declare; "
             "left out")
        heights = np.where(sentinel, np.nan, heights)
    valid = heights[np.isfinite(heights)]
    if valid.size:
        cols = np.array([0.5, width - 0.5, 0.5, width - 0.5])
        rows = np.array([0.5, 0.5, height - 0.5, height - 0.5])
        corners = np.stack([t.a * cols + t.b * rows + t.c, t.d * cols + t.e * rows + t.f,
                            np.full(4, float(np.median(valid)))], axis=1)
        lo, hi = float(valid.min()), float(valid.max())
        check_coordinates(np.vstack([corners, [[corners[0, 0], corners[0, 1], lo], [corners[0, 0], corners[0, 1], hi]]]),
                          frame, path, None, "ground", ("x", "y", "height"), lenient=True)
    return Dem(heights, (t.a, t.b, t.c, t.d, t.e, t.f), frame)


def write_dem(path: PathLike, dem: Dem, nodata: float = -32767.0) -> None:
    """Write a DEM as a tiled, compressed GeoTIFF (atomically)."""
    import os
    from pathlib import Path

    from affine import Affine

    from skyrig.geodesy.crs import resolve_crs

    p = Path(path)
    fd, tmp = output_temp(p, ".tif")
    os.close(fd)
    h = np.where(np.isfinite(dem.heights), dem.heights, nodata).astype(np.float32)
    try:
        profile = dict(
            driver="GTiff", width=h.shape[1], height=h.shape[0], count=1, dtype="float32", nodata=nodata,
            crs=resolve_crs(dem.frame.crs).to_wkt(), transform=Affine(*dem.transform), tiled=True,
            blockxsize=256, blockysize=256, compress="deflate",
        )
        if h.shape[0] < 256 or h.shape[1] < 256:
            profile.pop("blockxsize"), profile.pop("blockysize")
            profile["tiled"] = False
        with rasterio.open(tmp, "w", **profile) as ds:
            ds.write(h, 1)
        publish(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
