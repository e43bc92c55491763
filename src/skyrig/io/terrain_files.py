"""Files of the terrain products (:mod:`skyrig.terrain`): classified clouds, DTM / nDSM COGs, contour and polygon
GeoPackages.

* **Classified cloud**: the input LAS/LAZ read by laspy and written back whole with its ASPRS ``classification``
  replaced (every other dimension, VLR and the CRS kept); atomically.
* **DTM COG**: bands ``height``, ``sigma`` (metres), ``ground_points`` (count) and ``source`` (the
  :data:`skyrig.terrain.dtm.DTM_SOURCE` code: 1 measured, 2 interpolated across a gap, 3 under a building,
  4 under vegetation), with the CRS and vertical reference stated exactly as the DSM's
  (:func:`skyrig.io.dsm_cog.write_bands_cog`) and the tag ``SKYRIG_PRODUCT=dtm``.  The nDSM: one band
  ``height_above_ground``, tag ``SKYRIG_PRODUCT=ndsm``.
* **Contours**: one GeoPackage layer ``contours`` of line strings, fields ``elevation`` (metres, the DTM's
  vertical reference), ``index`` (1 for index contours), ``closed`` (1 for rings); the CRS is the DTM's full 3D
  statement (a compound CRS for orthometric heights).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
from numpy.typing import NDArray

from skyrig.errors import CRSError, InputFormatError
from skyrig.io._text import PathLike, output_temp, publish

__all__ = ["TerrainCloud", "read_terrain_cloud", "CloudHeader", "read_cloud_header", "spill_tiles",
           "write_classified_stream", "write_classified_cloud", "write_dtm_cog", "read_dtm_cog",
           "write_ndsm_cog", "read_height_surface", "write_contours_gpkg", "read_volume_polygon", "DTM_BANDS"]

#: Band order of a DTM COG.
DTM_BANDS = ("height", "sigma", "ground_points", "source")
_DTM_UNITS = {"height": "metre", "sigma": "metre", "ground_points": "", "source": ""}


@dataclass(frozen=True)
class TerrainCloud:
    """A cloud read for classification.

    Attributes
    ----------
    xyz
        ``(N, 3)`` coordinates in the file's CRS units.
    rgb
        ``(N, 3)`` uint16 colours or None.
    sigma
        ``(N,)`` predicted precision (metres; a skyrig dense cloud's ``sigma`` dimension) or None.
    classification
        ``(N,)`` the file's ASPRS classes.
    frame
        The map frame (CRS and height reference).
    metres_per_unit
        Horizontal and vertical axis units in metres ``(h, v)`` (0.3048 for international feet).
    vertical_reference
        Words for the heights' reference.
    """

    xyz: NDArray[np.float64]
    rgb: NDArray[np.uint16] | None
    sigma: NDArray[np.float64] | None
    classification: NDArray[np.uint8]
    frame: object
    metres_per_unit: tuple[float, float]
    vertical_reference: str

    def __len__(self) -> int:
        return len(self.xyz)


def _axis_metres(crs: pyproj.CRS) -> tuple[float, float]:
    axes = crs.axis_info
    h = float(axes[0].unit_conversion_factor) if axes else 1.0
    if crs.is_geographic or (crs.is_compound and crs.sub_crs_list[0].is_geographic):
        raise CRSError(f"{crs.name} is geographic (degrees): terrain products need a projected CRS")
    v = float(axes[2].unit_conversion_factor) if len(axes) >= 3 else h
    return h, v


def read_terrain_cloud(path: PathLike, crs: str | None = None) -> TerrainCloud:
    """Read a LAS/LAZ cloud for :func:`skyrig.terrain.classify_points`.

    Parameters
    ----------
    crs
        The CRS when the file has none (anything PROJ reads); refused when the file has another one.

    Raises
    ------
    InputFormatError
        Missing / unreadable file, no CRS in the file and none given (field ``crs``), a given CRS that differs
        from the file's, a geographic CRS.
    """
    import laspy

    from skyrig.io.laz import read_las

    pts = read_las(path, require_crs=crs is None)
    frame, mpu, words = _cloud_frame(path, pts.crs_wkt, crs, pts.metadata)
    las = laspy.read(str(path))
    cls = np.asarray(las.classification, np.uint8)
    sigma = pts.extra.get("sigma")
    return TerrainCloud(pts.xyz, pts.rgb, None if sigma is None else np.asarray(sigma, float), cls, frame, mpu, words)


def _cloud_frame(path: PathLike, crs_wkt: str | None, crs: str | None, metadata: dict[str, str]):
    """``(frame, metres_per_unit, vertical words)`` of a cloud from its file CRS and the CRS given (see
    :func:`read_terrain_cloud`)."""
    from skyrig.geodesy.crs import resolve_crs
    from skyrig.geodesy.statement import frame_from_file_crs

    given = resolve_crs(crs) if crs else None
    if crs_wkt is not None:
        file_c = pyproj.CRS.from_wkt(crs_wkt)
        same = given is None or file_c == given or (file_c.is_compound and file_c.sub_crs_list[0] == given)
        completes = (given is not None and given.is_compound and len(file_c.axis_info) < 3
                     and given.sub_crs_list[0] == file_c)  # a 2D file CRS completed with its vertical CRS
        if not (same or completes):
            raise InputFormatError(f"the file's CRS is {file_c.name}, not the {given.name} given", path, field="crs")
        c = given if completes else file_c
    elif given is None:
        raise InputFormatError("the LAS file has no CRS (neither a WKT nor a GeoTIFF VLR); give the CRS explicitly "
                               "(e.g. --crs EPSG:...)", path, field="crs")
    else:
        c = given
    try:
        frame = frame_from_file_crs(c, metadata.get("geoid") or None, metadata.get("vertical_reference"))
        mpu = _axis_metres(c)
    except CRSError as exc:
        raise InputFormatError(str(exc), path, field="crs") from None
    return frame, mpu, metadata.get("skyrig_vertical_reference", metadata.get("vertical_crs", ""))


@dataclass(frozen=True)
class CloudHeader:
    """What a LAS/LAZ header says of a cloud read tile by tile (:func:`spill_tiles`): the frame as
    :func:`read_terrain_cloud` gives it, the point count and the bounds (metres: the file's units scaled by
    ``metres_per_unit``)."""

    frame: object
    metres_per_unit: tuple[float, float]
    vertical_reference: str
    points: int
    mins_m: tuple[float, float]
    maxs_m: tuple[float, float]
    rgb: bool
    sigma: bool


def read_cloud_header(path: PathLike, crs: str | None = None) -> CloudHeader:
    """The header of a LAS/LAZ cloud (no point is read); the errors of :func:`read_terrain_cloud`."""
    import laspy

    from skyrig.io.laz import las_metadata

    p = Path(path)
    if not p.exists():
        raise InputFormatError("file not found", p)
    try:
        with laspy.open(str(p)) as rd:
            h = rd.header
    except Exception as exc:  # laspy raises several types for bad files
        raise InputFormatError(f"not a readable LAS/LAZ file ({exc})", p) from None
    try:
        file_crs = h.parse_crs()
    except Exception as exc:
        raise InputFormatError(f"unreadable CRS VLR ({exc})", p, field="crs") from None
    frame, mpu, words = _cloud_frame(p, None if file_crs is None else file_crs.to_wkt(), crs, las_metadata(h, p))
    dims = set(h.point_format.dimension_names)
    return CloudHeader(frame, mpu, words, int(h.point_count), (float(h.mins[0]) * mpu[0], float(h.mins[1]) * mpu[0]),
                       (float(h.maxs[0]) * mpu[0], float(h.maxs[1]) * mpu[0]), {"red", "green", "blue"} <= dims,
                       "sigma" in dims)


def spill_tiles(path: PathLike, head: CloudHeader, windows: list[tuple[float, float, float, float]], folder: PathLike,
                chunk_points: int = 1_000_000) -> list[list[Path]]:
    """Stream a cloud once, ``chunk_points`` at a time, into ``.npy`` pieces per window: every point whose metre
    coordinates lie in window ``k`` (``(x0, y0, x1, y1)``, half-open) goes into ``folder/w{k}_c{chunk}.npy`` with
    its index in the file (``gid``), ``x, y, z`` in metres, its class (``code``), ``sigma`` and ``red, green, blue``
    when the cloud has them.  Returns the pieces of each window (in file order); the caller holds one chunk at a time."""
    import laspy

    h, v = head.metres_per_unit
    fields = [("gid", "<i8"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("code", "u1")]
    fields += [("sigma", "<f8")] if head.sigma else []
    fields += [(c, "<u2") for c in ("red", "green", "blue")] if head.rgb else []
    out: list[list[Path]] = [[] for _ in windows]
    off = 0
    with laspy.open(str(path)) as rd:
        for c, pts in enumerate(rd.chunk_iterator(chunk_points)):
            x, y = np.asarray(pts.x, float) * h, np.asarray(pts.y, float) * h
            rec = np.empty(len(x), fields)
            rec["gid"] = off + np.arange(len(x))
            rec["x"], rec["y"], rec["z"] = x, y, np.asarray(pts.z, float) * v
            rec["code"] = np.asarray(pts.classification)
            if head.sigma:
                rec["sigma"] = np.asarray(pts["sigma"], float)
            for col in ("red", "green", "blue") if head.rgb else ():
                rec[col] = np.asarray(pts[col])
            for k, (x0, y0, x1, y1) in enumerate(windows):
                m = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
                if m.any():
                    f = Path(folder) / f"w{k}_c{c}.npy"
                    np.save(f, rec[m])
                    out[k].append(f)
            off += len(x)
    return out


def write_classified_stream(src: PathLike, dst: PathLike, code: NDArray[np.integer],
                            chunk_points: int = 1_000_000) -> None:
    """:func:`write_classified_cloud` chunk by chunk (the cloud is never whole in memory)."""
    import laspy

    code = np.asarray(code)
    with laspy.open(str(src)) as rd:
        n, fmt = int(rd.header.point_count), rd.header.point_format.id
    _check_codes(code, n, fmt, src, dst)
    p = Path(dst)
    fd, tmp = output_temp(p, p.suffix)
    os.close(fd)
    try:
        with laspy.open(str(src)) as rd, laspy.open(tmp, mode="w", header=rd.header,
                                                     do_compress=p.suffix.lower() == ".laz") as wr:
            off = 0
            for pts in rd.chunk_iterator(chunk_points):
                pts.classification = code[off:off + len(pts)].astype(np.uint8)
                wr.write_points(pts)
                off += len(pts)
        publish(tmp, p)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _check_codes(code: NDArray, n: int, fmt: int, src: PathLike, dst: PathLike) -> None:
    if code.shape != (n,):
        raise InputFormatError(f"{code.shape} classes for {n} points", src, field="classification")
    top = 255 if fmt >= 6 else 31
    if code.size and (code.min() < 0 or code.max() > top):
        raise InputFormatError(f"class codes must be 0..{top} for point format {fmt}", dst, field="classification")


def write_classified_cloud(src: PathLike, dst: PathLike, code: NDArray[np.integer]) -> None:
    """Copy the LAS/LAZ ``src`` to ``dst`` (``.laz`` compressed) with its classification set to ``code``.

    Raises
    ------
    InputFormatError
        When ``code`` does not have one value per point or holds a code the point format cannot store.
    """
    import laspy

    las = laspy.read(str(src))
    code = np.asarray(code)
    _check_codes(code, len(las.points), las.header.point_format.id, src, dst)
    las.classification = code.astype(np.uint8)
    p = Path(dst)
    fd, tmp = output_temp(p, p.suffix)
    os.close(fd)
    try:
        las.write(tmp, do_compress=p.suffix.lower() == ".laz")
        publish(tmp, p)
    finally:
        Path(tmp).unlink(missing_ok=True)


def write_dtm_cog(path: PathLike, dtm) -> None:
    """Write a :class:`skyrig.terrain.dtm.DtmGrid` as a COG (module docstring), atomically."""
    from skyrig.io.dsm_cog import write_bands_cog

    bands = [(n, getattr(dtm, n), _DTM_UNITS[n]) for n in DTM_BANDS]
    write_bands_cog(path, dtm.grid, dtm.frame, bands, vertical_reference=dtm.vertical_reference,
                    metadata=dtm.metadata, extra_tags={"SKYRIG_PRODUCT": "dtm"})


def read_dtm_cog(path: PathLike):
    """Read a DTM written by :func:`write_dtm_cog` as a :class:`skyrig.terrain.dtm.DtmGrid`.

    Raises
    ------
    InputFormatError
        If the file is missing, unreadable, has no CRS or is not a skyrig DTM (no ``source`` band).
    """
    import rasterio

    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.terrain.dtm import DtmGrid

    d = read_dsm_cog(path)  # the checks, the grid and the frame
    with rasterio.open(path) as ds:
        desc = {n: i + 1 for i, n in enumerate(ds.descriptions) if n}
        if "source" not in desc:
            raise InputFormatError("not a skyrig DTM (no 'source' band)", path, field="source")

        def band(name: str) -> NDArray[np.float64]:
            a = ds.read(desc[name]).astype(np.float64)
            return np.where(a == ds.nodata, np.nan, a) if ds.nodata is not None else a

        sig, gp, src = band("sigma"), band("ground_points"), band("source")
    return DtmGrid(d.grid, d.frame, d.height, sig.astype(np.float32), np.nan_to_num(gp).astype(np.int32),
                   np.nan_to_num(src).astype(np.uint8), d.vertical_reference, d.metadata)


def read_height_surface(path: PathLike, option: str):
    """A height raster (DSM or DTM COG, any north-up GeoTIFF with a CRS) as a
    :class:`skyrig.dense.grid.DsmGrid`, refused when it states no vertical reference (a 2D CRS without skyrig's
    ``VERTICAL_REFERENCE`` tag): the heights of two such surfaces could differ by a geoid undulation unseen.

    Raises
    ------
    InputFormatError
        As :func:`skyrig.io.dsm_cog.read_dsm_cog`, and naming ``option`` when the vertical reference is missing.
    """
    import rasterio

    from skyrig.io.dsm_cog import read_dsm_cog

    d = read_dsm_cog(path)
    with rasterio.open(path) as ds:
        tags = ds.tags()
        three_d = ds.crs is not None and len(pyproj.CRS.from_wkt(ds.crs.to_wkt()).axis_info) >= 3
    if not tags.get("VERTICAL_REFERENCE") and not three_d:
        raise InputFormatError(f"the raster states no vertical reference (a 2D CRS and no VERTICAL_REFERENCE tag): "
                               f"its heights cannot be placed; write it with a compound CRS (option {option})",
                               path, field="crs")
    return d


def write_ndsm_cog(path: PathLike, dsm, ndsm: NDArray[np.float32]) -> None:
    """Write a normalised DSM (heights above ground on the DSM's grid) as a one-band COG, atomically."""
    from skyrig.io.dsm_cog import write_bands_cog

    write_bands_cog(path, dsm.grid, dsm.frame, [("height_above_ground", ndsm, "metre")],
                    vertical_reference="heights above the DTM (metres)",
                    metadata={"product": "ndsm", "dsm_vertical_reference": dsm.vertical_reference},
                    extra_tags={"SKYRIG_PRODUCT": "ndsm"})


def write_contours_gpkg(path: PathLike, contours, frame) -> None:
    """Write :class:`skyrig.terrain.contours.Contours` as a GeoPackage layer ``contours`` (module docstring).

    Raises
    ------
    InputFormatError
        When there is no line to write.
    """
    import shapely

    from skyrig.geodesy.statement import file_crs
    from skyrig.io.gpkg import write_gpkg

    if len(contours) == 0:
        raise InputFormatError("no contour line to write", path)
    geoms = [shapely.LineString(ln) for ln in contours.lines]
    fields = {"elevation": np.asarray(contours.elevation, np.float64),
              "index": np.asarray(contours.index, np.int32), "closed": np.asarray(contours.closed, np.int32)}
    write_gpkg(path, {"contours": (geoms, fields)}, file_crs(frame).full.to_wkt())


def read_volume_polygon(path: PathLike, frame, layer: str | None = None):
    """The polygon of a volume computation from a vector file: the union of a layer's polygons, reprojected into
    ``frame`` (a layer in another CRS is reprojected; one without a CRS, an empty or invalid polygon are refused in
    words by :func:`skyrig.io.footprints_gpkg.read_footprints`).  Inner rings are not kept."""
    import shapely

    from skyrig.io.footprints_gpkg import read_footprints

    try:
        rings, _ = read_footprints(path, frame, layer=layer)
    except InputFormatError as exc:
        raise InputFormatError(exc.reason.replace("footprint", "polygon"), path, exc.line,
                               "polygon" if exc.field == "footprints" else exc.field) from None
    polys = [shapely.Polygon(r) for r in rings]
    u = shapely.union_all(polys)
    if u.is_empty or u.area <= 0:
        raise InputFormatError("the polygons have no area", path, field="polygon")
    return u
