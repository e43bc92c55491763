"""Orthomosaic files: the RGB mosaic and its per-cell source image as Cloud Optimized GeoTIFFs, the seamlines and
source regions as a GeoPackage, a PNG preview.

* ``ortho.tif``: 3 bands uint8 (red, green, blue) with an internal mask (cells no image sees are masked, never a
  black that could be a colour), DEFLATE, internal overviews (averaged colours, masked cells left out), the CRS of
  the mosaic (its heights are the DSM's: the vertical reference is stated in the tags like the DSM's).
* ``ortho_source.tif``: 1 band int16, the index of the image that gives most of each cell's colour (-1 no data:
  outside the DSM; -2 a surface that no image sees);
  the image names in the tag ``SKYRIG_SOURCE_IMAGES`` (JSON list, index order).
* ``seamlines.gpkg``: layer ``regions`` (one polygon per connected region that takes one image, field ``image``)
  and layer ``seamlines`` (the lines where one image's region meets another's, fields ``left``/``right``).

All files are written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.ortho import Orthomosaic
from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike
from skyrig.io.dsm_cog import _atomic_target, cog_problems
from skyrig.geodesy.statement import file_crs


def _tags(mosaic: Orthomosaic) -> dict[str, str]:
    fc = file_crs(mosaic.frame)
    return {"VERTICAL_REFERENCE": fc.kind, "VERTICAL_CRS": fc.vertical_words,
            "SKYRIG_VERTICAL_REFERENCE": mosaic.vertical_reference or fc.vertical_words,
            "SKYRIG_PRODUCT": "true orthomosaic (surface: DSM)",
            "SKYRIG_METADATA": json.dumps(mosaic.stats, default=str, sort_keys=True), "AREA_OR_POINT": "Area"}


def _write_cog(path: PathLike, bands: list[NDArray], dtype: str, mosaic: Orthomosaic, *, mask: NDArray | None,
               nodata: float | None, descriptions: list[str], tags: dict[str, str], resampling: str,
               photometric: str | None) -> None:
    import rasterio
    from affine import Affine
    from rasterio.crs import CRS as RioCRS
    from rasterio.io import MemoryFile
    from rasterio.shutil import copy as rio_copy

    fc = file_crs(mosaic.frame)
    rows, cols = mosaic.grid.shape
    blocksize = 256 if max(rows, cols) < 4096 else 512
    profile: dict[str, Any] = dict(driver="GTiff", width=cols, height=rows, count=len(bands), dtype=dtype,
                                   crs=RioCRS.from_wkt(fc.horizontal.to_wkt()), transform=Affine(*mosaic.grid.transform))
    if nodata is not None:
        profile["nodata"] = nodata
    if photometric:
        profile["photometric"] = photometric
    opts = dict(BLOCKSIZE=str(blocksize), COMPRESS="DEFLATE", PREDICTOR="YES", BIGTIFF="IF_SAFER", OVERVIEWS="AUTO",
                OVERVIEW_RESAMPLING=resampling)
    with _atomic_target(path, ".tif") as tmp:
        with rasterio.Env(GDAL_PAM_ENABLED="NO", GDAL_TIFF_INTERNAL_MASK="YES"), MemoryFile() as mem:
            with mem.open(**profile) as dst:
                for i, b in enumerate(bands, start=1):
                    dst.write(b, i)
                    dst.set_band_description(i, descriptions[i - 1])
                if mask is not None:
                    dst.write_mask(np.where(mask, 255, 0).astype(np.uint8))
                dst.update_tags(**tags)
            with mem.open() as src:
                rio_copy(src, tmp, driver="COG", **opts)
        problems = cog_problems(tmp)
        if problems:
            raise InputFormatError("GDAL wrote an invalid COG: " + "; ".join(problems), path)


def write_ortho_cog(path: PathLike, mosaic: Orthomosaic) -> None:
    """The RGB mosaic as a COG with an internal mask (see the module docstring)."""
    rgb = np.where(mosaic.valid[..., None], mosaic.rgb, 0).astype(np.uint8)
    _write_cog(path, [rgb[..., k] for k in range(3)], "uint8", mosaic, mask=mosaic.valid, nodata=None,
               descriptions=["red", "green", "blue"], tags=_tags(mosaic), resampling="AVERAGE", photometric="RGB")


def write_source_cog(path: PathLike, mosaic: Orthomosaic) -> None:
    """The per-cell source image index (int16; -1 no surface = nodata, -2 surface seen by no image) with the image
    names in a tag."""
    tags = _tags(mosaic)
    tags["SKYRIG_SOURCE_IMAGES"] = json.dumps(list(mosaic.images))
    _write_cog(path, [np.asarray(mosaic.source, np.int16)], "int16", mosaic, mask=None, nodata=-1,
               descriptions=["source_image"], tags=tags, resampling="NEAREST", photometric=None)


def read_ortho_cog(path: PathLike) -> tuple[NDArray[np.uint8], NDArray[np.bool_], Any, Any]:
    """``(rgb (rows, cols, 3), valid (rows, cols), transform, crs)`` of an orthomosaic COG."""
    import rasterio

    with rasterio.open(str(path)) as src:
        if src.count < 3:
            raise InputFormatError(f"expected an RGB raster (3 bands), found {src.count} band(s)", path)
        rgb = np.moveaxis(src.read([1, 2, 3]), 0, -1)
        valid = src.dataset_mask() > 0
        return rgb, valid, src.transform, src.crs


def seamline_layers(mosaic: Orthomosaic) -> dict[str, tuple[list, dict[str, list]]]:
    """The ``regions`` and ``seamlines`` layers (shapely geometries and fields) of a mosaic's region map."""
    import shapely
    from rasterio.features import shapes
    from affine import Affine

    lab = np.asarray(mosaic.label, np.int32)
    tr = Affine(*mosaic.dsm_grid.transform)
    polys, names, idx = [], [], []
    for geom, val in shapes(lab, mask=lab >= 0, transform=tr, connectivity=4):
        polys.append(shapely.geometry.shape(geom))
        names.append(mosaic.images[int(val)])
        idx.append(int(val))
    lines, left, right = [], [], []
    if polys:
        tree = shapely.STRtree(polys)
        for a, pa in enumerate(polys):
            for b in tree.query(pa):
                b = int(b)
                if b <= a or idx[a] == idx[b]:
                    continue
                shared = shapely.line_merge(shapely.intersection(pa.boundary, polys[b].boundary))
                for g in getattr(shared, "geoms", [shared]):
                    if isinstance(g, shapely.LineString) and g.length > 0:
                        lines.append(g)
                        left.append(names[a])
                        right.append(names[b])
    return {"regions": (polys, {"image": names, "image_index": idx}),
            "seamlines": (lines, {"left": left, "right": right})}


def write_seamlines_gpkg(path: PathLike, mosaic: Orthomosaic) -> int:
    """Write ``regions`` and ``seamlines`` layers; returns the number of seamline pieces."""
    from skyrig.geodesy.statement import file_crs
    from skyrig.io.gpkg import write_gpkg

    layers = seamline_layers(mosaic)
    write_gpkg(path, layers, file_crs(mosaic.frame).horizontal.to_wkt())
    return len(layers["seamlines"][0])


def write_preview_png(path: PathLike, mosaic: Orthomosaic, max_side: int = 2048) -> None:
    """A downscaled RGBA PNG of the mosaic (transparent where no image sees the surface)."""
    import cv2

    from skyrig.io._text import output_temp, publish
    import os

    rows, cols = mosaic.valid.shape
    s = min(1.0, max_side / max(rows, cols))
    rgba = np.dstack([mosaic.rgb[..., ::-1], np.where(mosaic.valid, 255, 0).astype(np.uint8)])
    if s < 1.0:
        rgba = cv2.resize(rgba, (max(1, int(cols * s)), max(1, int(rows * s))), interpolation=cv2.INTER_AREA)
    fd, tmp = output_temp(path, ".png")
    os.close(fd)
    try:
        if not cv2.imwrite(tmp, rgba):
            raise InputFormatError("could not write the PNG preview", path)
        publish(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
