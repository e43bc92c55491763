"""DSM grids as Cloud Optimized GeoTIFF (rasterio / GDAL), a hillshade preview PNG, and the CRS statement
(horizontal CRS + vertical reference) shared with the dense-cloud writer.

What GDAL keeps of the vertical reference
-----------------------------------------
Checked with GDAL 3.10 (rasterio 1.4) by writing and reading back files without their ``.aux.xml``:

* **Compound CRS with a vertical CRS from the EPSG registry** (e.g. ``EPSG:32631+5773``, UTM 31N + EGM96
  height): GDAL's GeoTIFF writer stores it in the GeoKeys (``VerticalGeoKey`` = the EPSG code, GeoTIFF 1.1)
  and reads it back as the same compound CRS (``pyproj.CRS ==``).  QGIS shows it as the compound CRS.
* **3D projected CRS** (projected CRS with an ellipsoidal-height axis, ``pyproj.CRS.to_3d()``): GeoTIFF
  has no GeoKey encoding for "projected CRS + ellipsoidal height" (GeoTIFF 1.1 only knows a geographic
  3D CRS, annex D.3).  GDAL then writes *no* GeoKeys at all and puts the whole CRS into a side-car
  ``.aux.xml`` (PAM) -- the ``.tif`` alone has no CRS.  Unusable for a COG, so it is not done.
* **Custom vertical CRS** (a geoid grid PROJ's database does not tie to a vertical CRS): GDAL writes a
  user-defined vertical CS whose name survives, but WKT2's ``GEOIDMODEL`` is lost.

So the COG carries:

* ellipsoidal heights: the horizontal CRS in the GeoKeys, and dataset tags ``VERTICAL_REFERENCE=ellipsoidal``,
  ``VERTICAL_CRS`` (words naming the geographic 3D CRS whose ellipsoid the heights refer to) and
  ``CRS_3D_WKT`` (the 3D projected CRS as WKT2);
* orthometric heights through a geoid PROJ identifies (its grid is named in PROJ's ``grid_alternatives`` /
  ``grid_transformation`` tables, e.g. ``egm96_15.gtx`` -> EGM96 height EPSG:5773, ``fr_ign_RAF20.tif`` ->
  NGF-IGN69 height EPSG:5720): the compound CRS in the GeoKeys, plus the tags below;
* orthometric heights through any other geoid: the horizontal CRS in the GeoKeys, ``VERTICAL_REFERENCE=
  orthometric``, ``GEOID`` (the grid as given) and ``CRS_3D_WKT`` (a compound CRS with a custom vertical CRS
  carrying ``GEOIDMODEL``).

Tags: ``VERTICAL_REFERENCE``, ``VERTICAL_CRS``, ``CRS_3D_WKT``, ``GEOID`` (only for
orthometric heights: GDAL drops empty tags), ``SKYRIG_VERTICAL_REFERENCE`` (:attr:`DsmGrid.vertical_reference`) and
``SKYRIG_METADATA`` (:attr:`DsmGrid.metadata` as JSON).  Band units are ``metre`` for height, spread and
sigma (GDAL stores band units and descriptions in the file's ``GDAL_METADATA`` TIFF tag, not in a side-car).

The file layout is GDAL's COG driver: tiles of 256 (grids below 4096 cells a side) or 512, DEFLATE with
the floating-point predictor, internal overviews (nearest neighbour, so that counts and flags stay counts
and flags) down to one tile, IFDs before the data.  :func:`cog_problems` checks that layout independently
of GDAL's own claim.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyproj
from numpy.typing import NDArray

from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.errors import CRSError, InputFormatError
from skyrig.geodesy.statement import FileCRS, file_crs, frame_from_file_crs, vertical_crs_of_geoid
from skyrig.io.laz import _publishable

__all__ = [
    "FileCRS",
    "file_crs",
    "frame_from_file_crs",
    "vertical_crs_of_geoid",
    "write_dsm_cog",
    "write_bands_cog",
    "WindowedBands",
    "write_hillshade_png_windows",
    "read_dsm_cog",
    "write_hillshade_png",
    "hillshade",
    "cog_problems",
    "DSM_BANDS",
    "DSM_NODATA",
]

log = logging.getLogger(__name__)

PathLike = str | os.PathLike[str]

#: Band order and names (band descriptions) of a DSM COG.
DSM_BANDS = ("height", "support", "spread", "sigma", "filled")
#: No-data value of the float bands (height, spread, sigma); GeoTIFF has one no-data value per file.
DSM_NODATA = -32767.0
_UNITS = {"height": "metre", "spread": "metre", "sigma": "metre", "support": "", "filled": ""}


# --------------------------------------------------------------------------------------------------
# atomic output
# --------------------------------------------------------------------------------------------------


@contextmanager
def _atomic_target(path: PathLike, suffix: str) -> Iterator[str]:
    """A temporary file name in ``path``'s folder, renamed onto ``path`` when the block succeeds.

    On any error the temporary file (and a GDAL side-car ``.aux.xml`` of it) is removed and ``path`` is
    left as it was.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=p.parent)
    os.close(fd)
    try:
        yield tmp
        _publishable(tmp)
        os.replace(tmp, p)
    finally:
        for leftover in (tmp, tmp + ".aux.xml"):
            Path(leftover).unlink(missing_ok=True)


# --------------------------------------------------------------------------------------------------
# COG
# --------------------------------------------------------------------------------------------------


def write_dsm_cog(path: PathLike, dsm: DsmGrid, *, overviews: bool = True, blocksize: int | None = None) -> None:
    """Write a DSM as a Cloud Optimized GeoTIFF, atomically.

    Bands (float32, descriptions set): 1 ``height`` (metres, no-data :data:`DSM_NODATA` where NaN),
    2 ``support`` (count, 0 = no data), 3 ``spread`` (metres), 4 ``sigma`` (metres), 5 ``filled`` (1 where
    the height was interpolated).  The CRS and the vertical reference are stated as the module docstring
    describes (compound CRS when the geoid's vertical CRS is identified, tags otherwise).

    Parameters
    ----------
    path
        Output ``.tif``; written to a temporary file in the same folder and renamed, so that on any
        error nothing is left at ``path`` (an existing file stays as it was) and no temporary remains.
    dsm
        The grid; ``dsm.frame`` must be a ``map`` frame.
    overviews
        Internal overviews (nearest neighbour) down to one tile.
    blocksize
        Tile size (256 or 512); default 256 below 4096 cells a side, else 512.

    Raises
    ------
    CRSError
        If the frame is not a map frame.
    InputFormatError
        On a bad block size.
    """
    bands = {"height": dsm.height, "support": dsm.support, "spread": dsm.spread, "sigma": dsm.sigma,
             "filled": dsm.filled}
    write_bands_cog(path, dsm.grid, dsm.frame, [(n, bands[n], _UNITS[n]) for n in DSM_BANDS],
                    vertical_reference=dsm.vertical_reference, metadata=dsm.metadata, overviews=overviews,
                    blocksize=blocksize)


def write_bands_cog(path: PathLike, grid: GridSpec, frame, bands: list[tuple[str, NDArray, str]], *,
                    vertical_reference: str = "", metadata: dict | None = None, overviews: bool = True,
                    blocksize: int | None = None, extra_tags: dict[str, str] | None = None) -> None:
    """Write float32 bands ``[(description, (rows, cols) array, unit)]`` on ``grid`` as a COG in ``frame``'s CRS
    with the vertical reference stated as the module docstring describes (the layout and tags of
    :func:`write_dsm_cog`, which calls it); no-data :data:`DSM_NODATA` (NaN is written as it)."""
    import rasterio
    from rasterio.io import MemoryFile

    rows, cols = grid.shape
    data = []
    for name, a, _ in bands:
        a = np.asarray(a, np.float32)
        if a.shape != (rows, cols):
            raise InputFormatError(f"band {name!r} is {a.shape}, the grid {(rows, cols)}", path, field=name)
        data.append(_nodata_float32(a))
    profile, tags, blocksize = _cog_profile(grid, frame, vertical_reference, metadata, blocksize, extra_tags)
    profile.update(count=len(bands))
    with _atomic_target(path, ".tif") as tmp:
        # PAM off: everything must be inside the .tif, never in a side-car a COG copy would lose
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), MemoryFile() as mem:
            with mem.open(**profile) as src:
                for i, a in enumerate(data, start=1):
                    src.write(a, i)
                _describe_bands(src, [(n, u) for n, _, u in bands], tags)
            with mem.open() as src:
                _copy_cog(src, tmp, path, blocksize, overviews)


def _nodata_float32(a: NDArray) -> NDArray[np.float32]:
    return np.where(np.isfinite(a), a, np.float32(DSM_NODATA)).astype(np.float32)


def _cog_profile(grid: GridSpec, frame, vertical_reference: str, metadata: dict | None, blocksize: int | None,
                 extra_tags: dict[str, str] | None) -> tuple[dict, dict[str, str], int]:
    """The GeoTIFF profile (without ``count``), the tags and the COG tile size of :func:`write_bands_cog`."""
    from affine import Affine
    from rasterio.crs import CRS as RioCRS

    fc = file_crs(frame)
    rows, cols = grid.shape
    if blocksize is None:
        blocksize = 256 if max(rows, cols) < 4096 else 512
    if blocksize not in (256, 512):
        raise InputFormatError(f"COG tile size must be 256 or 512, got {blocksize}", field="blocksize")
    geokeys_crs = fc.full if fc.vertical_identified else fc.horizontal
    tags = {
        "VERTICAL_REFERENCE": fc.kind,
        "VERTICAL_CRS": fc.vertical_words,
        "CRS_3D_WKT": fc.full.to_wkt(),
        "SKYRIG_VERTICAL_REFERENCE": vertical_reference or fc.vertical_words,
        "SKYRIG_METADATA": json.dumps(metadata or {}, default=str, sort_keys=True),
        "AREA_OR_POINT": "Area",
        **(extra_tags or {}),
    }
    if fc.geoid:
        tags["GEOID"] = fc.geoid
    profile = dict(driver="GTiff", width=cols, height=rows, dtype="float32", nodata=DSM_NODATA,
                   crs=RioCRS.from_wkt(geokeys_crs.to_wkt()), transform=Affine(*grid.transform))
    return profile, tags, blocksize


def _describe_bands(src, bands: list[tuple[str, str]], tags: dict[str, str]) -> None:
    for i, (name, _) in enumerate(bands, start=1):
        src.set_band_description(i, name)
    src.units = tuple(u for _, u in bands)
    src.update_tags(**tags)


def _copy_cog(src, tmp: str, path: PathLike, blocksize: int, overviews: bool) -> None:
    """GDAL's COG copy of an open dataset into ``tmp``, its layout checked (:func:`cog_problems`)."""
    from rasterio.shutil import copy as rio_copy

    rio_copy(src, tmp, driver="COG", BLOCKSIZE=str(blocksize), COMPRESS="DEFLATE", PREDICTOR="YES",
             BIGTIFF="IF_SAFER", OVERVIEWS="AUTO" if overviews else "NONE", OVERVIEW_RESAMPLING="NEAREST")
    problems = cog_problems(tmp, expect_overviews=overviews)
    if problems:
        raise InputFormatError("GDAL wrote an invalid COG: " + "; ".join(problems), path)


#: GDAL's block cache while a grid is written window by window (bytes): the windows, not the grid
WINDOWED_CACHE_BYTES = 64 * 2**20


def _windowed_env():
    """GDAL's settings for window-by-window writing: no side-car files, a block cache of
    :data:`WINDOWED_CACHE_BYTES`."""
    import rasterio

    return rasterio.Env(GDAL_PAM_ENABLED="NO", GDAL_CACHEMAX=WINDOWED_CACHE_BYTES)


class WindowedBands:
    """Float32 bands on a grid written and read window by window, then published as a COG: the layout, tags and
    values :func:`write_bands_cog` writes from whole arrays, without the grid ever in memory.

    The bands live in an uncompressed tiled GeoTIFF ``scratch`` (GDAL's block cache bounded by
    :data:`WINDOWED_CACHE_BYTES`) until :meth:`publish` copies it into a COG; :meth:`close` (or ``with``) closes it,
    the caller removes ``scratch``.  Cells never written read as no data (NaN)."""

    def __init__(self, scratch: PathLike, grid: GridSpec, frame, bands: list[tuple[str, str]], *,
                 vertical_reference: str = "", metadata: dict | None = None, blocksize: int | None = None,
                 extra_tags: dict[str, str] | None = None) -> None:
        import rasterio

        self.grid = grid
        self.names = [n for n, _ in bands]
        profile, tags, self.blocksize = _cog_profile(grid, frame, vertical_reference, metadata, blocksize, extra_tags)
        with _windowed_env():
            self._ds = rasterio.open(scratch, "w+", **profile, count=len(bands), tiled=True, blockxsize=256,
                                     blockysize=256, BIGTIFF="IF_SAFER")
            _describe_bands(self._ds, bands, tags)

    def write(self, row0: int, col0: int, arrays: list[NDArray]) -> None:
        """Every band's ``(rows, cols)`` values at ``(row0, col0)`` (NaN = no data)."""
        from rasterio.windows import Window

        if len(arrays) != len(self.names):
            raise InputFormatError(f"{len(arrays)} arrays for {len(self.names)} bands", self._ds.name)
        h, w = np.shape(arrays[0])
        with _windowed_env():
            self._ds.write(np.stack([_nodata_float32(np.asarray(a, np.float32)) for a in arrays]),
                           window=Window(col0, row0, w, h))

    def read(self, name: str, row0: int, col0: int, height: int, width: int) -> NDArray[np.float32]:
        """Band ``name`` in a window (clipped to nothing outside the grid: the caller asks for cells inside it),
        no data as NaN."""
        from rasterio.windows import Window

        with _windowed_env():
            a = self._ds.read(self.names.index(name) + 1, window=Window(col0, row0, width, height))
        a[a == np.float32(DSM_NODATA)] = np.nan
        return a

    def publish(self, path: PathLike, *, overviews: bool = True) -> None:
        """Copy the bands into a COG at ``path`` (atomically, layout checked); the bands can be read still, no
        longer written."""
        import rasterio

        with _windowed_env():
            self._ds.close()
            self._ds = rasterio.open(self._ds.name)  # read-only from now on
        with _atomic_target(path, ".tif") as tmp, _windowed_env():
            _copy_cog(self._ds, tmp, path, self.blocksize, overviews)

    def close(self) -> None:
        if not self._ds.closed:
            with _windowed_env():
                self._ds.close()

    def __enter__(self) -> "WindowedBands":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_dsm_cog(path: PathLike) -> DsmGrid:
    """Read a DSM written by :func:`write_dsm_cog` (or any north-up raster with a height band).

    Bands are found by description (``height``, ``support``...); a raster without them is read as heights
    in band 1 with support 1 where valid.

    Raises
    ------
    InputFormatError
        If the file is missing, unreadable, not north-up, or has no CRS.
    """
    import rasterio
    from rasterio.errors import RasterioIOError

    p = Path(path)
    if not p.exists():
        raise InputFormatError("file not found", p)
    try:
        with rasterio.open(p) as ds:
            if ds.crs is None:
                raise InputFormatError("raster has no CRS", p, field="crs")
            t = ds.transform
            if abs(t.b) > 0 or abs(t.d) > 0 or not np.isclose(-t.e, t.a, rtol=1e-12, atol=0):
                raise InputFormatError(f"not a north-up grid with square cells (transform {tuple(t)[:6]})", p)
            tags = ds.tags()
            desc = {d: i + 1 for i, d in enumerate(ds.descriptions) if d}
            nodata = ds.nodata

            def band(name: str) -> NDArray[np.float64] | None:
                i = desc.get(name, 1 if name == "height" and "height" not in desc else None)
                if i is None:
                    return None
                a = ds.read(i).astype(np.float64)
                if nodata is not None and name in ("height", "spread", "sigma"):
                    a[a == nodata] = np.nan
                return a

            h, sup, spr, sig, fil = (band(n) for n in DSM_BANDS)
            crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
            shape = (ds.height, ds.width)
    except RasterioIOError as exc:
        raise InputFormatError(f"cannot read raster: {exc}", p) from None
    grid = GridSpec(float(t.c), float(t.f), float(t.a), shape[1], shape[0])
    valid = np.isfinite(h)
    nan = np.full(shape, np.nan, np.float32)
    kind = tags.get("VERTICAL_REFERENCE") or None
    try:
        frame = frame_from_file_crs(crs, tags.get("GEOID") or None, kind)
    except CRSError as exc:
        raise InputFormatError(str(exc), p, field="crs") from None
    try:
        meta = json.loads(tags.get("SKYRIG_METADATA", "{}"))
    except ValueError:
        meta = {}
    return DsmGrid(
        grid=grid, frame=frame, height=h.astype(np.float32),
        support=(np.where(valid, 1, 0) if sup is None else np.round(sup)).astype(np.int16),
        spread=nan.copy() if spr is None else spr.astype(np.float32),
        sigma=nan.copy() if sig is None else sig.astype(np.float32),
        filled=np.zeros(shape, bool) if fil is None else fil > 0.5,
        vertical_reference=tags.get("SKYRIG_VERTICAL_REFERENCE", tags.get("VERTICAL_CRS", "")),
        metadata=meta if isinstance(meta, dict) else {},
    )


# --------------------------------------------------------------------------------------------------
# COG layout check (the checks of GDAL's validate_cloud_optimized_geotiff.py, written from the TIFF spec)
# --------------------------------------------------------------------------------------------------

_TIFF_TYPES = {1: ("B", 1), 3: ("H", 2), 4: ("I", 4), 16: ("Q", 8), 2: ("c", 1), 7: ("B", 1), 12: ("d", 8)}


def _tiff_ifds(f) -> tuple[list[tuple[int, dict[int, tuple]]], bool]:
    """Walk a TIFF's IFD chain: [(ifd_offset, {tag: values})], is_bigtiff."""
    head = f.read(16)
    bo = {b"II": "<", b"MM": ">"}.get(head[:2])
    if bo is None:
        raise ValueError("not a TIFF file")
    magic = struct.unpack(bo + "H", head[2:4])[0]
    big = magic == 43
    if magic not in (42, 43):
        raise ValueError(f"not a TIFF file (magic {magic})")
    off = struct.unpack(bo + ("Q" if big else "I"), head[8:16] if big else head[4:8])[0]
    ifds = []
    seen = set()
    while off and off not in seen and len(ifds) < 64:
        seen.add(off)
        f.seek(off)
        n = struct.unpack(bo + ("Q" if big else "H"), f.read(8 if big else 2))[0]
        esize = 20 if big else 12
        raw = f.read(n * esize)
        nxt = struct.unpack(bo + ("Q" if big else "I"), f.read(8 if big else 4))[0]
        tags: dict[int, tuple] = {}
        for k in range(n):
            e = raw[k * esize:(k + 1) * esize]
            if big:
                tag, typ, cnt = struct.unpack(bo + "HHQ", e[:12])
                val = e[12:20]
            else:
                tag, typ, cnt = struct.unpack(bo + "HHI", e[:8])
                val = e[8:12]
            if typ not in _TIFF_TYPES or tag not in (254, 256, 257, 322, 323, 324, 325):
                continue
            fmt, size = _TIFF_TYPES[typ]
            if cnt * size <= len(val):
                data = val[:cnt * size]
            else:
                pos = f.tell()
                f.seek(struct.unpack(bo + ("Q" if big else "I"), val)[0])
                data = f.read(cnt * size)
                f.seek(pos)
            tags[tag] = struct.unpack(bo + fmt * cnt, data)
        ifds.append((off, tags))
        off = nxt
    return ifds, big


def cog_problems(path: PathLike, *, expect_overviews: bool = True) -> list[str]:
    """Why a GeoTIFF is not a Cloud Optimized GeoTIFF; an empty list when it is one.

    Checks, from the file's bytes: GDAL's structural-metadata "ghost" header with
    ``LAYOUT=IFDS_BEFORE_DATA``; every image (full resolution and overviews) tiled with square 256 or 512
    tiles; overviews present when the image is larger than one tile (and ``expect_overviews``), each half
    the size of the previous; all IFDs before the first tile; the tiles of smaller overviews before those
    of larger ones and the full-resolution tiles last.  Also that GDAL (rasterio) reports the file as tiled
    with overviews.
    """
    import rasterio

    problems: list[str] = []
    with open(path, "rb") as f:
        try:
            ifds, big = _tiff_ifds(f)
        except (ValueError, struct.error) as exc:
            return [str(exc)]
        f.seek(16 if big else 8)
        ghost = f.read(1024)
    if not ghost.startswith(b"GDAL_STRUCTURAL_METADATA_SIZE="):
        problems.append("no GDAL structural-metadata header after the TIFF header")
    elif b"LAYOUT=IFDS_BEFORE_DATA" not in ghost:
        problems.append("structural metadata lacks LAYOUT=IFDS_BEFORE_DATA")
    images = [(o, t) for o, t in ifds if not (t.get(254, (0,))[0] & 4)]  # drop mask IFDs
    if not images:
        return problems + ["no image IFD"]
    for k, (_, t) in enumerate(images):
        if 322 not in t or 324 not in t:
            problems.append(f"IFD {k} is not tiled")
            continue
        tw, th = t[322][0], t[323][0]
        if tw != th or tw not in (256, 512):
            problems.append(f"IFD {k} tiles are {tw}x{th}, not 256 or 512 square")
    w0, h0 = images[0][1].get(256, (0,))[0], images[0][1].get(257, (0,))[0]
    tile0 = images[0][1].get(322, (0,))[0]
    if expect_overviews and max(w0, h0) > tile0 and len(images) < 2:
        problems.append("no internal overviews")
    for k in range(1, len(images)):
        wp, wk = images[k - 1][1].get(256, (0,))[0], images[k][1].get(256, (0,))[0]
        if not (wk < wp):
            problems.append(f"overview {k} is not smaller than the image before it")
    first_data = min((min((x for x in t.get(324, ()) if x), default=2**63) for _, t in ifds), default=2**63)
    if any(o > first_data for o, _ in ifds):
        problems.append("an IFD lies after tile data (IFDs must come first)")
    if any(ifds[k][0] > ifds[k + 1][0] for k in range(len(ifds) - 1)):
        problems.append("IFDs are not in increasing file order")
    starts = [min((x for x in t.get(324, ()) if x), default=None) for _, t in images]
    for k in range(len(images) - 1):
        if starts[k] is not None and starts[k + 1] is not None and starts[k + 1] > starts[k]:
            problems.append(f"tiles of overview {k + 1} come after those of image {k} (smallest must come first)")
    with rasterio.open(path) as ds:
        if not all(bs[0] == bs[1] == tile0 for bs in ds.block_shapes):
            problems.append(f"GDAL reports blocks {ds.block_shapes}")
        if expect_overviews and max(w0, h0) > tile0 and not ds.overviews(1):
            problems.append("GDAL reports no overviews")
    return problems


# --------------------------------------------------------------------------------------------------
# hillshade
# --------------------------------------------------------------------------------------------------


def hillshade(height: NDArray, cell_m: float, *, azimuth_deg: float = 315.0, altitude_deg: float = 45.0,
              z_factor: float = 1.0) -> NDArray[np.float64]:
    """Shaded relief in [0, 1] by Horn's (1981) gradient and Burrough's illumination formula.

    With the 3x3 window ``a b c / d e f / g h i`` (row 0 north)::

        dz/dx = ((c + 2f + i) - (a + 2d + g)) / (8 cell)
        dz/dy = ((g + 2h + i) - (a + 2b + c)) / (8 cell)
        slope = atan(z_factor * hypot(dz/dx, dz/dy)),  aspect = atan2(dz/dy, -dz/dx)
        shade = cos(zenith) cos(slope) + sin(zenith) sin(slope) cos(azimuth_math - aspect)

    with ``zenith = 90 - altitude`` and ``azimuth_math = 360 - azimuth + 90`` (the ArcGIS / GDAL
    ``gdaldem hillshade`` definition).  Edge cells use replicated borders; cells whose window holds a NaN
    are NaN.

    Parameters
    ----------
    height
        ``(rows, cols)`` heights in metres, NaN = no data.
    cell_m
        Cell size in metres.

    Examples
    --------
    >>> float(hillshade(np.zeros((3, 3)), 1.0)[1, 1])  # flat ground: cos(45 deg)
    0.7071067811865476
    """
    z = np.pad(np.asarray(height, np.float64), 1, mode="edge")
    a, b, c = z[:-2, :-2], z[:-2, 1:-1], z[:-2, 2:]
    d, f = z[1:-1, :-2], z[1:-1, 2:]
    g, h, i = z[2:, :-2], z[2:, 1:-1], z[2:, 2:]
    dzdx = ((c + 2 * f + i) - (a + 2 * d + g)) / (8.0 * cell_m)
    dzdy = ((g + 2 * h + i) - (a + 2 * b + c)) / (8.0 * cell_m)
    slope = np.arctan(z_factor * np.hypot(dzdx, dzdy))
    aspect = np.arctan2(dzdy, -dzdx)
    zen = np.radians(90.0 - altitude_deg)
    az = np.radians((360.0 - azimuth_deg + 90.0) % 360.0)
    shade = np.cos(zen) * np.cos(slope) + np.sin(zen) * np.sin(slope) * np.cos(az - aspect)
    shade = np.clip(shade, 0.0, 1.0)
    shade[~np.isfinite(z[1:-1, 1:-1])] = np.nan
    return shade


def write_hillshade_png(path: PathLike, dsm: DsmGrid, *, azimuth_deg: float = 315.0,
                        altitude_deg: float = 45.0, z_factor: float = 1.0) -> None:
    """Write a shaded-relief preview of the DSM's height band as an 8-bit grey + alpha PNG (atomically).

    Computed by :func:`hillshade` (sun azimuth 315 deg, altitude 45 deg by default); no-data cells are
    transparent.  One pixel per cell.

    Raises
    ------
    InputFormatError
        If the grid is empty.
    """
    from PIL import Image

    if dsm.height.size == 0:
        raise InputFormatError("empty DSM grid", path)
    img = Image.fromarray(_hillshade_grey_alpha(dsm.height, dsm.grid.cell_m, azimuth_deg, altitude_deg, z_factor),
                          mode="LA")
    with _atomic_target(path, ".png") as tmp:
        img.save(tmp, format="PNG")


def _hillshade_grey_alpha(height: NDArray, cell_m: float, azimuth_deg: float, altitude_deg: float,
                          z_factor: float) -> NDArray[np.uint8]:
    """The hillshade preview's ``(rows, cols, 2)`` grey and alpha (0 where no data)."""
    s = hillshade(height, cell_m, azimuth_deg=azimuth_deg, altitude_deg=altitude_deg, z_factor=z_factor)
    ok = np.isfinite(s)
    grey = np.where(ok, np.round(np.nan_to_num(s) * 255.0), 0).astype(np.uint8)
    alpha = np.where(ok, 255, 0).astype(np.uint8)
    return np.dstack([grey, alpha])


def write_hillshade_png_windows(path: PathLike, bands: WindowedBands, scratch: PathLike, *, window_cells: int = 2048,
                                azimuth_deg: float = 315.0, altitude_deg: float = 45.0, z_factor: float = 1.0) -> None:
    """:func:`write_hillshade_png` of the ``height`` band of ``bands``, computed window by window (a one-cell halo
    from the neighbouring windows, so the pixels are those of the whole grid) into an uncompressed GeoTIFF
    ``scratch`` that GDAL's PNG driver copies row by row into ``path`` (atomically); the caller removes
    ``scratch``."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.shutil import copy as rio_copy
    from rasterio.windows import Window

    grid = bands.grid
    rows, cols = grid.shape
    if rows * cols == 0:
        raise InputFormatError("empty DSM grid", path)
    with _windowed_env(), warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # a picture: no georeference, as the PNG has none
        with rasterio.open(scratch, "w", driver="GTiff", width=cols, height=rows, count=2, dtype="uint8", tiled=True,
                           blockxsize=256, blockysize=256) as dst:
            for r0, c0, h, w in grid.tiles(window_cells):
                a0, b0 = max(r0 - 1, 0), max(c0 - 1, 0)
                a1, b1 = min(r0 + h + 1, rows), min(c0 + w + 1, cols)
                z = bands.read("height", a0, b0, a1 - a0, b1 - b0)
                la = _hillshade_grey_alpha(z, grid.cell_m, azimuth_deg, altitude_deg, z_factor)
                dst.write(np.moveaxis(la[r0 - a0:r0 - a0 + h, c0 - b0:c0 - b0 + w], -1, 0), window=Window(c0, r0, w, h))
        with _atomic_target(path, ".png") as tmp, rasterio.open(scratch) as src:
            rio_copy(src, tmp, driver="PNG")
