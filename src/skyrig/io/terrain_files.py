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

__all__ = ["TerrainCloud", "read_terrain_cloud", "write_classified_cloud", "write_dtm_cog", "read_dtm_cog",
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

    from skyrig.geodesy.crs import resolve_crs
    from skyrig.geodesy.statement import frame_from_file_crs
    from skyrig.io.laz import read_las

    pts = read_las(path, require_crs=crs is None)
    given = resolve_crs(crs) if crs else None
    if pts.crs_wkt is not None:
        file_c = pyproj.CRS.from_wkt(pts.crs_wkt)
        same = given is None or file_c == given or (file_c.is_compound and file_c.sub_crs_list[0] == given)
        completes = (given is not None and given.is_compound and len(file_c.axis_info) < 3
                     and given.sub_crs_list[0] == file_c)  # a 2D file CRS completed with its vertical CRS
        if not (same or completes):
            raise InputFormatError(f"the file's CRS is {file_c.name}, not the {given.name} given", path, field="crs")
        c = given if completes else file_c
    else:
        c = given
    try:
        frame = frame_from_file_crs(c, pts.metadata.get("geoid") or None, pts.metadata.get("vertical_reference"))
        mpu = _axis_metres(c)
    except CRSError as exc:
        raise InputFormatError(str(exc), path, field="crs") from None
    las = laspy.read(str(path))
    cls = np.asarray(las.classification, np.uint8)
    sigma = pts.extra.get("sigma")
    words = pts.metadata.get("skyrig_vertical_reference", pts.metadata.get("vertical_crs", ""))
    return TerrainCloud(pts.xyz, pts.rgb, None if sigma is None else np.asarray(sigma, float), cls, frame, mpu, words)


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
    if code.shape != (len(las.points),):
        raise InputFormatError(f"{code.shape} classes for {len(las.points)} points", src, field="classification")
    top = 255 if las.header.point_format.id >= 6 else 31
    if code.size and (code.min() < 0 or code.max() > top):
        raise InputFormatError(f"class codes must be 0..{top} for point format {las.header.point_format.id}",
                               dst, field="classification")
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
