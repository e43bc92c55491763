"""DEM GeoTIFF (any GDAL raster) through rasterio, into :class:`skyrig.georef.ground.Dem`."""

from __future__ import annotations

import numpy as np
import rasterio
from rasterio.errors import RasterioIOError

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.georef.ground import Dem
from skyrig.io._text import PathLike, output_temp, publish


def read_dem(path: PathLike, geoid: str | None = None, band: int = 1, crs: str | None = None) -> Dem:
    """Read a DEM raster.

    Parameters
    ----------
    path
        Raster file (GeoTIFF / COG or anything GDAL reads).
    geoid
        Geoid grid when the heights are orthometric; None for ellipsoidal heights.
    crs
        CRS to use when the file has none (otherwise a file without CRS is an error).
    """
    try:
        with rasterio.open(path) as ds:
            if ds.crs is None and crs is None:
                raise InputFormatError("raster has no CRS; pass one explicitly", path, field="crs")
            file_crs = crs or ds.crs.to_wkt()
            data = ds.read(band, masked=True).astype(np.float64)
            t = ds.transform
    except RasterioIOError as exc:
        raise InputFormatError(f"cannot read raster: {exc}", path) from None
    heights = np.ma.filled(data, np.nan)
    return Dem(heights, (t.a, t.b, t.c, t.d, t.e, t.f), WorldFrame.map(file_crs, geoid))


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
