"""LAS / LAZ 1.4 point clouds (laspy, with lazrs for LAZ compression).

Written files are LAS 1.4, point format 6 (GPS time, intensity, scan angle in 0.006 deg steps), with the
CRS as an OGC WKT VLR (global encoding WKT bit set) and optional float extra dimensions (e.g. a
comparison distance for colour coding in CloudCompare or QGIS).  ``.laz`` compresses with lazrs.
Writes go to a temporary file renamed into place.  Reading accepts any LAS/LAZ version laspy reads; the
CRS is taken from a WKT or GeoTIFF VLR (``laspy.LasHeader.parse_crs``).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import CRSError, InputFormatError
from skyrig.geodesy.crs import resolve_crs

__all__ = ["LasPoints", "read_las", "write_las"]

PathLike = str | os.PathLike[str]
SCAN_ANGLE_STEP_DEG = 0.006  # LAS 1.4 point formats 6-10


@dataclass(frozen=True, eq=False)
class LasPoints:
    """Points read from a LAS/LAZ file.

    Attributes
    ----------
    xyz
        ``(N, 3)`` scaled coordinates (CRS units).
    gps_time, intensity, scan_angle_deg
        ``(N,)`` each, or None when the point format lacks them.
    crs_wkt
        The file's CRS as WKT, or None.
    extra
        Extra-byte dimensions by name, ``(N,)`` each.
    """

    xyz: NDArray[np.float64]
    gps_time: NDArray[np.float64] | None
    intensity: NDArray[np.float64] | None
    scan_angle_deg: NDArray[np.float64] | None
    crs_wkt: str | None
    extra: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def read_las(path: PathLike, require_crs: bool = False) -> LasPoints:
    """Read a LAS/LAZ file.

    Raises
    ------
    InputFormatError
        The file is missing or not LAS/LAZ; or ``require_crs`` and the file has no CRS (field ``crs``).
    """
    import laspy

    p = Path(path)
    if not p.exists():
        raise InputFormatError("file not found", p)
    try:
        las = laspy.read(p)
    except Exception as exc:  # laspy raises several types for bad files
        raise InputFormatError(f"not a readable LAS/LAZ file ({exc})", p) from None
    try:
        crs = las.header.parse_crs()
    except Exception as exc:
        raise InputFormatError(f"unreadable CRS VLR ({exc})", p, field="crs") from None
    if crs is None and require_crs:
        raise InputFormatError("the LAS file has no CRS (neither a WKT nor a GeoTIFF VLR); give the CRS explicitly "
                               "(e.g. --crs EPSG:...)", p, field="crs")
    dims = set(las.point_format.dimension_names)
    std = set(las.point_format.standard_dimension_names)
    xyz = np.column_stack([np.asarray(las.x, float), np.asarray(las.y, float), np.asarray(las.z, float)])
    gps = np.asarray(las.gps_time, float) if "gps_time" in dims else None
    inten = np.asarray(las.intensity, float) if "intensity" in dims else None
    if "scan_angle" in dims:
        sa = np.asarray(las.scan_angle, float) * SCAN_ANGLE_STEP_DEG
    elif "scan_angle_rank" in dims:
        sa = np.asarray(las.scan_angle_rank, float)
    else:
        sa = None
    extra = {d: np.asarray(las[d], float) for d in dims - std}
    return LasPoints(xyz, gps, inten, sa, None if crs is None else crs.to_wkt(), extra)


def write_las(
    path: PathLike,
    xyz: ArrayLike,
    crs: object,
    *,
    gps_time: ArrayLike | None = None,
    intensity: ArrayLike | None = None,
    scan_angle_deg: ArrayLike | None = None,
    extra: dict[str, ArrayLike] | None = None,
    scale: float = 0.001,
) -> None:
    """Write a LAS 1.4 (``.las``) or LAZ (``.laz``) file, point format 6, with the CRS as WKT.

    Parameters
    ----------
    path
        Output file; ``.laz`` is compressed.
    xyz
        ``(N, 3)`` coordinates in ``crs``.
    crs
        Anything :func:`skyrig.geodesy.crs.resolve_crs` accepts (EPSG code, WKT, PROJ string); a
        compound CRS carries a vertical datum.
    gps_time, intensity, scan_angle_deg
        ``(N,)`` each, optional (intensity clipped to 0..65535, scan angle to +-180 deg).
    extra
        Extra dimensions ``{name: (N,)}``, stored as float64.
    scale
        Coordinate resolution in CRS units (offsets are chosen from the data).

    Raises
    ------
    CRSError
        If ``crs`` is not a CRS.
    InputFormatError
        On arrays of the wrong shape.
    """
    import laspy

    p = Path(path)
    pts = np.asarray(xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise InputFormatError(f"points must be a finite (N, 3) array, got {pts.shape}", field="xyz")
    n = len(pts)
    c = resolve_crs(crs)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(pts.min(axis=0)) if n else np.zeros(3)
    extra = extra or {}
    for name, v in extra.items():
        if np.asarray(v).shape != (n,):
            raise InputFormatError(f"extra dimension must be ({n},), got {np.asarray(v).shape}", field=name)
        header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=np.float64))
    try:
        header.add_crs(c)
    except Exception as exc:
        raise CRSError(f"cannot store the CRS in a LAS header: {exc}") from None
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    for name, v in (("gps_time", gps_time), ("intensity", intensity), ("scan_angle_deg", scan_angle_deg)):
        if v is not None and np.asarray(v).shape != (n,):
            raise InputFormatError(f"must be ({n},), got {np.asarray(v).shape}", field=name)
    if gps_time is not None:
        las.gps_time = np.asarray(gps_time, float)
    if intensity is not None:
        las.intensity = np.clip(np.round(np.asarray(intensity, float)), 0, 65535).astype(np.uint16)
    if scan_angle_deg is not None:
        raw = np.round(np.clip(np.asarray(scan_angle_deg, float), -180, 180) / SCAN_ANGLE_STEP_DEG)
        las.scan_angle = np.clip(raw, -30000, 30000).astype(np.int16)
    for name, v in extra.items():
        las[name] = np.asarray(v, float)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=p.suffix, dir=p.parent)
    os.close(fd)
    try:
        las.write(tmp, do_compress=p.suffix.lower() == ".laz")
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
