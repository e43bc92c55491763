"""Dense point clouds (:class:`skyrig.dense.grid.DenseCloud`) as LAS 1.4 / LAZ, through :mod:`skyrig.io.laz`.

File content
------------
* LAS 1.4, point format 7 (format 6 + 16-bit RGB; 8-bit colours scaled by 257 so that 255 -> 65535);
  ``.laz`` compressed with lazrs.
* The CRS as an OGC WKT VLR (WKT2, written by pyproj), always three-dimensional so the heights' reference is
  part of the CRS: a compound CRS ``horizontal + vertical`` for orthometric heights (the EPSG vertical CRS
  when PROJ's database ties the geoid grid to one, e.g. EGM96 height EPSG:5773, otherwise a custom vertical
  CRS carrying ``GEOIDMODEL[<grid>]``), a 3D projected (or geographic 3D) CRS for ellipsoidal heights.  See
  :func:`skyrig.io.dsm_cog.file_crs`.  Unlike GeoTIFF GeoKeys, the WKT VLR keeps all three forms.
* Extra dimensions ``support`` (int16), ``sigma`` (float32, metres), ``normal_x``, ``normal_y``,
  ``normal_z`` (float32).
* A ``skyrig`` JSON VLR with ``vertical_reference`` (``ellipsoidal`` / ``orthometric``), ``vertical_crs``
  (words), ``geoid`` (the grid as given) and ``skyrig_vertical_reference``.

Coordinate scale
----------------
Chosen from the CRS's axis units: about a millimetre -- 0.001 for metres, 0.001 ft for feet, 1e-8 degree
(1.1 mm of latitude) for a geographic CRS; heights 0.001 of the vertical unit.  An explicit ``scale`` coarser
than 10 cm on the ground (e.g. 0.001 on degrees, 111 m) is refused.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np
import pyproj
from numpy.typing import ArrayLike, NDArray

from skyrig.dense.grid import DenseCloud
from skyrig.errors import CRSError, InputFormatError
from skyrig.geodesy.statement import FileCRS, file_crs, frame_from_file_crs
from skyrig.geodesy.frame import WorldFrame
from skyrig.io.laz import read_las, write_las, write_las_chunks

if TYPE_CHECKING:
    from pyproj._crs import Axis

__all__ = ["write_dense_cloud", "write_dense_cloud_chunks", "read_dense_cloud", "coordinate_scale", "DENSE_EXTRA_TYPES"]

PathLike = str | os.PathLike[str]

#: Extra dimensions of a dense cloud file and their types.
DENSE_EXTRA_TYPES = {"support": np.int16, "sigma": np.float32, "normal_x": np.float32, "normal_y": np.float32,
                     "normal_z": np.float32}
_EARTH_RADIUS_M = 6_371_000.0
_TARGET_M = 0.001  # coordinate resolution aimed at, metres on the ground
_COARSEST_M = 0.1  # an explicit scale coarser than this on the ground is refused


def _metres_per_unit(axis: Axis) -> float:
    f = float(axis.unit_conversion_factor)
    if "degree" in axis.unit_name.lower() or "radian" in axis.unit_name.lower() or "grad" in axis.unit_name.lower():
        return f * _EARTH_RADIUS_M  # factor is radians per unit
    return f


def coordinate_scale(crs: pyproj.CRS) -> tuple[float, float, float]:
    """LAS coordinate scales ``(sx, sy, sz)`` for a 3D CRS: about 1 mm on the ground, in the axes' units.

    Examples
    --------
    >>> coordinate_scale(pyproj.CRS("EPSG:25832").to_3d())
    (0.001, 0.001, 0.001)
    >>> coordinate_scale(pyproj.CRS("EPSG:4979"))
    (1e-08, 1e-08, 0.001)
    """
    axes = crs.axis_info
    if len(axes) < 3:
        raise CRSError(f"a 3D CRS is needed to choose LAS scales, {crs.name} has {len(axes)} axes")
    out = []
    for ax in axes[:3]:
        m = _metres_per_unit(ax)
        out.append(float(10.0 ** math.floor(math.log10(_TARGET_M / m) + 0.1)))
    return out[0], out[1], out[2]


def write_dense_cloud(path: PathLike, cloud: DenseCloud, *, scale: float | tuple[float, float, float] | None = None) -> None:
    """Write a dense point cloud as LAS 1.4 / LAZ (point format 7, RGB, CRS with vertical reference, extra dims).

    Parameters
    ----------
    path
        ``.laz`` (compressed) or ``.las``; written to a temporary file in the same folder and renamed, so
        that on any error nothing is left at ``path`` and no temporary remains.
    cloud
        The points; ``cloud.frame`` must be a ``map`` frame.
    scale
        Coordinate resolution in CRS units (one value or per axis); default from the CRS units
        (:func:`coordinate_scale`).

    Raises
    ------
    CRSError
        If the frame is not a map frame, or ``scale`` is coarser than 10 cm on the ground (e.g. a
        metre-like scale on a geographic CRS).
    InputFormatError
        On arrays of the wrong shape or non-finite coordinates.
    """
    fc, scales, meta = _dense_las_setup(path, cloud.frame, cloud.vertical_reference, scale)
    try:
        write_las(path, cloud.xyz, fc.full, extra=_dense_extra(path, cloud), extra_types=DENSE_EXTRA_TYPES,
                  scale=scales, rgb=np.asarray(cloud.rgb, np.uint8), metadata=meta)
    except InputFormatError as exc:
        if exc.path is None:
            raise InputFormatError(exc.reason, path, field=exc.field) from None
        raise


def write_dense_cloud_chunks(path: PathLike, chunks: Iterable[DenseCloud], frame: WorldFrame, vertical_reference: str,
                             mins: ArrayLike, maxs: ArrayLike, *, scale: float | tuple[float, float, float] | None = None
                             ) -> int:
    """:func:`write_dense_cloud` of a cloud that comes in pieces (e.g. one per ground tile, read back one at a
    time): the file holds what :func:`write_dense_cloud` of the pieces put together holds, in their order, and
    only one piece is in memory at a time.  Every piece must be in ``frame``; ``mins`` / ``maxs``: the ``(3,)``
    extremes of all pieces' coordinates (the LAS offsets come from them).  Returns the number of points written.

    Raises
    ------
    CRSError, InputFormatError
        As :func:`write_dense_cloud`; a piece in another frame, or outside ``mins`` .. ``maxs``.
    """
    fc, scales, meta = _dense_las_setup(path, frame, vertical_reference, scale)

    def pieces() -> Iterator[tuple[NDArray, NDArray, dict[str, NDArray]]]:
        for c in chunks:
            if c.frame != frame:
                raise InputFormatError(f"a piece of the cloud is in {c.frame.describe()}, not {frame.describe()}", path)
            yield c.xyz, np.asarray(c.rgb, np.uint8), _dense_extra(path, c)

    try:
        return write_las_chunks(path, pieces(), fc.full, mins, maxs, scale=scales, rgb=True,
                                extra_types=DENSE_EXTRA_TYPES, metadata=meta)
    except InputFormatError as exc:
        if exc.path is None:
            raise InputFormatError(exc.reason, path, field=exc.field) from None
        raise


def _dense_las_setup(path: PathLike, frame: WorldFrame, vertical_reference: str,
                     scale: float | tuple[float, float, float] | None) -> tuple[FileCRS, tuple[float, ...], dict]:
    """The file CRS, the coordinate scales (checked) and the metadata VLR of a dense cloud file."""
    fc = file_crs(frame)
    auto = coordinate_scale(fc.full)
    if scale is None:
        scales = auto
    else:
        scales = tuple(float(s) for s in np.broadcast_to(np.asarray(scale, float), (3,)))
        ground = [s * _metres_per_unit(ax) for s, ax in zip(scales, fc.full.axis_info[:3])]
        if max(ground) > _COARSEST_M:
            units = ", ".join(ax.unit_name for ax in fc.full.axis_info[:3])
            raise CRSError(f"{path}: LAS scale {scales} in {fc.full.name} (units {units}) is {max(ground):.3g} m on "
                           f"the ground; use e.g. {auto} (option 'scale')")
    meta = {"vertical_reference": fc.kind, "vertical_crs": fc.vertical_words, "geoid": fc.geoid or "",
            "skyrig_vertical_reference": vertical_reference or fc.vertical_words}
    return fc, scales, meta


def _dense_extra(path: PathLike, cloud: DenseCloud) -> dict[str, NDArray]:
    """The cloud's arrays checked, its extra dimensions by name."""
    n = len(cloud)
    for name, arr, shape in (("xyz", cloud.xyz, (n, 3)), ("rgb", cloud.rgb, (n, 3)), ("normal", cloud.normal, (n, 3)),
                             ("support", cloud.support, (n,)), ("sigma", cloud.sigma, (n,))):
        if np.shape(arr) != shape:
            raise InputFormatError(f"DenseCloud.{name} must be {shape}, got {np.shape(arr)}", path, field=name)
    normal = np.asarray(cloud.normal, np.float32)
    return {"support": np.asarray(cloud.support), "sigma": np.asarray(cloud.sigma),
            "normal_x": normal[:, 0], "normal_y": normal[:, 1], "normal_z": normal[:, 2]}


def read_dense_cloud(path: PathLike) -> DenseCloud:
    """Read a dense cloud written by :func:`write_dense_cloud` (or any LAS/LAZ with a CRS).

    Missing pieces of a foreign file get neutral values: colour 0, normals 0, support 1, sigma NaN.  A file
    whose CRS is 2D and without skyrig metadata is taken as ellipsoidal heights.

    Raises
    ------
    InputFormatError
        If the file is missing, not LAS/LAZ, or has no (usable) CRS.
    """
    pts = read_las(path, require_crs=True)
    crs = pyproj.CRS.from_wkt(pts.crs_wkt)
    try:
        frame = frame_from_file_crs(crs, pts.metadata.get("geoid") or None, pts.metadata.get("vertical_reference"))
    except CRSError as exc:
        raise InputFormatError(str(exc), path, field="crs") from None
    n = len(pts)
    rgb = (np.zeros((n, 3), np.uint8) if pts.rgb is None
           else np.clip(np.round(pts.rgb / 257.0), 0, 255).astype(np.uint8))
    ex = pts.extra
    normal = np.column_stack([ex.get(k, np.zeros(n)) for k in ("normal_x", "normal_y", "normal_z")]).astype(np.float32)
    support = np.asarray(ex.get("support", np.ones(n)), np.int16)
    sigma = np.asarray(ex.get("sigma", np.full(n, np.nan)), np.float32)
    words = pts.metadata.get("skyrig_vertical_reference", pts.metadata.get("vertical_crs", ""))
    return DenseCloud(pts.xyz, rgb, normal.reshape(n, 3), support, sigma, frame, words)
