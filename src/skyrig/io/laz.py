"""LAS / LAZ 1.4 point clouds (laspy, with lazrs for LAZ compression).

Written files are LAS 1.4, point format 6 (GPS time, intensity, scan angle in 0.006 deg steps) or 7 (the
same plus 16-bit RGB) when colours are given, with the CRS as an OGC WKT VLR (global encoding WKT bit set;
pyproj writes WKT2, which can hold a compound or 3D CRS), optional extra dimensions (float64 unless a type is
given; e.g. a comparison distance for colour coding in CloudCompare or QGIS) and optional key/value metadata
in a JSON VLR (user id ``skyrig``).  ``.laz`` compresses with lazrs.  Writes go to a temporary file renamed
into place.  Reading accepts any LAS/LAZ version laspy reads; the
CRS is taken from a WKT or GeoTIFF VLR (``laspy.LasHeader.parse_crs``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from skyrig.errors import CRSError, InputFormatError
from skyrig.geodesy.crs import resolve_crs
from skyrig.io._text import output_temp, publish

__all__ = ["LasPoints", "read_las", "write_las", "write_las_chunks"]

PathLike = str | os.PathLike[str]
SCAN_ANGLE_STEP_DEG = 0.006  # LAS 1.4 point formats 6-10
METADATA_VLR_USER_ID = "skyrig"  # JSON key/value VLR written by write_las(metadata=...)
METADATA_VLR_RECORD_ID = 1


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
    rgb
        ``(N, 3)`` uint16 colours (LAS 16-bit scale), or None when the point format has none.
    metadata
        Key/value metadata from a ``skyrig`` JSON VLR (empty when absent).
    """

    xyz: NDArray[np.float64]
    gps_time: NDArray[np.float64] | None
    intensity: NDArray[np.float64] | None
    scan_angle_deg: NDArray[np.float64] | None
    crs_wkt: str | None
    extra: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    rgb: NDArray[np.uint16] | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    point_source_id: NDArray[np.int64] | None = None  # the flight line of each point (LAS point_source_id)

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
    rgb = None
    if {"red", "green", "blue"} <= dims:
        rgb = np.column_stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)]).astype(np.uint16)
    psid = np.asarray(las.point_source_id, np.int64) if "point_source_id" in dims else None
    return LasPoints(xyz, gps, inten, sa, None if crs is None else crs.to_wkt(), extra, rgb, las_metadata(las.header, p),
                     psid)


def las_metadata(header, path: PathLike) -> dict[str, str]:
    """skyrig's metadata VLR of a laspy header (``{}`` when there is none)."""
    meta: dict[str, str] = {}
    for vlr in header.vlrs:
        if vlr.user_id == METADATA_VLR_USER_ID and vlr.record_id == METADATA_VLR_RECORD_ID:
            try:
                meta = {str(k): str(v) for k, v in json.loads(bytes(vlr.record_data).decode("utf-8")).items()}
            except (ValueError, AttributeError, UnicodeDecodeError):
                raise InputFormatError("unreadable skyrig metadata VLR", path, field="metadata") from None
    return meta


def write_las(
    path: PathLike,
    xyz: ArrayLike,
    crs: object,
    *,
    gps_time: ArrayLike | None = None,
    intensity: ArrayLike | None = None,
    scan_angle_deg: ArrayLike | None = None,
    extra: dict[str, ArrayLike] | None = None,
    scale: float | ArrayLike | None = None,
    rgb: ArrayLike | None = None,
    extra_types: dict[str, DTypeLike] | None = None,
    metadata: dict[str, str] | None = None,
) -> None:
    """Write a LAS 1.4 (``.las``) or LAZ (``.laz``) file, point format 6 (7 with ``rgb``), with the CRS as WKT.

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
        Extra dimensions ``{name: (N,)}``, stored as float64 unless ``extra_types`` names a type.
    scale
        Coordinate resolution in CRS units, one value or ``(sx, sy, sz)`` (offsets are chosen from the data).
        Default: 1 mm, that is 0.001 in metre axes and 1e-8 deg (1.1 mm or less on the ground) in the degree axes
        of a geographic CRS.  A horizontal scale coarser than 1e-6 deg (0.11 m) on a geographic CRS is refused
        (it would move points by up to half of it without a word).
    rgb
        ``(N, 3)`` colours: uint8 (scaled to LAS's 16 bits by 257, so 255 -> 65535) or uint16 (as is);
        selects point format 7.
    extra_types
        numpy type per extra dimension (e.g. ``{"support": np.int16}``); values are cast to it.
    metadata
        Key/value strings stored as JSON in a VLR (user id ``skyrig``, record 1); :func:`read_las` returns them.

    Raises
    ------
    CRSError
        If ``crs`` is not a CRS.
    InputFormatError
        On arrays of the wrong shape.
    """
    p = Path(path)
    pts = _finite_points(xyz)
    n = len(pts)
    colours = _las_colours(rgb, n)
    extra = extra or {}
    for name, v in extra.items():
        if np.asarray(v).shape != (n,):
            raise InputFormatError(f"extra dimension must be ({n},), got {np.asarray(v).shape}", field=name)
    header = _las_header(p, crs, scale, pts.min(axis=0) if n else None, pts.max(axis=0) if n else None,
                         list(extra), extra_types or {}, metadata, colours is not None)
    las = _las_record(header, pts, colours, extra, extra_types or {}, gps_time, intensity, scan_angle_deg)
    fd, tmp = output_temp(p, p.suffix)
    os.close(fd)
    try:
        las.write(tmp, do_compress=p.suffix.lower() == ".laz")
        _publishable(tmp)
        publish(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_las_chunks(path: PathLike, chunks: Iterable[tuple[ArrayLike, ArrayLike | None, dict[str, ArrayLike]]],
                     crs: object, mins: ArrayLike, maxs: ArrayLike, *, scale: float | ArrayLike | None = None,
                     rgb: bool = False, extra_types: dict[str, DTypeLike] | None = None,
                     metadata: dict[str, str] | None = None) -> int:
    """:func:`write_las` of points that come chunk by chunk (one chunk in memory at a time): ``chunks`` yields
    ``(xyz, rgb or None, extra)`` as :func:`write_las` takes them (the same extra names in every chunk, ``rgb``
    in every chunk when ``rgb``); ``mins`` / ``maxs``: the ``(3,)`` extremes of all chunks' coordinates, known
    beforehand (the offsets are chosen from them, as :func:`write_las` chooses them from its points; a chunk
    outside them is refused).  The file holds what :func:`write_las` of the concatenated chunks holds.  Returns
    the number of points written.

    Raises
    ------
    InputFormatError
        As :func:`write_las`, naming ``path``.
    """
    import laspy

    p = Path(path)
    lo = np.asarray(mins, np.float64).reshape(3)
    hi = np.asarray(maxs, np.float64).reshape(3)
    header = None
    n_all = 0
    fd, tmp = output_temp(p, p.suffix)
    os.close(fd)
    try:
        writer = None
        try:
            for xyz, colour, extra in chunks:
                pts = _finite_points(xyz)
                n = len(pts)
                if n and (np.any(pts.min(axis=0) < lo) or np.any(pts.max(axis=0) > hi)):
                    raise InputFormatError(f"a chunk's points lie outside the extremes given ({lo} .. {hi})", p)
                colours = _las_colours(colour, n) if rgb else None
                if rgb and colours is None:
                    raise InputFormatError("a chunk without colours in a cloud with colours", p, field="rgb")
                if header is None:
                    header = _las_header(p, crs, scale, lo, hi, list(extra), extra_types or {}, metadata, rgb)
                    writer = laspy.open(tmp, mode="w", header=header, do_compress=p.suffix.lower() == ".laz")
                for name, v in extra.items():
                    if np.asarray(v).shape != (n,):
                        raise InputFormatError(f"extra dimension must be ({n},), got {np.asarray(v).shape}", p,
                                               field=name)
                if n:
                    assert writer is not None
                    writer.write_points(_las_record(header, pts, colours, extra, extra_types or {}).points)
                    n_all += n
            if writer is None:  # no chunk at all: an empty file
                header = _las_header(p, crs, scale, None, None, [], {}, metadata, rgb)
                writer = laspy.open(tmp, mode="w", header=header, do_compress=p.suffix.lower() == ".laz")
        finally:
            if writer is not None:
                writer.close()
        _publishable(tmp)
        publish(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return n_all


def _finite_points(xyz: ArrayLike) -> NDArray[np.float64]:
    pts = np.asarray(xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise InputFormatError(f"points must be a finite (N, 3) array, got {pts.shape}", field="xyz")
    return pts


def _las_colours(rgb: ArrayLike | None, n: int) -> NDArray[np.uint16] | None:
    """Colours in LAS's 16 bits (uint8 scaled by 257), checked."""
    if rgb is None:
        return None
    colours = np.asarray(rgb)
    if colours.shape != (n, 3):
        raise InputFormatError(f"rgb must be ({n}, 3), got {colours.shape}", field="rgb")
    if colours.dtype == np.uint8:
        return colours.astype(np.uint16) * np.uint16(257)
    if colours.dtype != np.uint16:
        raise InputFormatError(f"rgb must be uint8 or uint16, got {colours.dtype}", field="rgb")
    return colours


def _las_header(p: Path, crs: object, scale: float | ArrayLike | None, mins: NDArray | None, maxs: NDArray | None,
                extra_names: list[str], extra_types: dict[str, DTypeLike], metadata: dict[str, str] | None,
                with_rgb: bool):
    """The LAS 1.4 header of :func:`write_las`: scales, offsets (``floor(mins)``; zero without points), extra
    dimensions, metadata and CRS VLRs."""
    import laspy

    c = resolve_crs(crs)
    geographic = bool((c.sub_crs_list[0] if c.is_compound else c).is_geographic)
    if scale is None:
        scale = (1e-8, 1e-8, 0.001) if geographic else 0.001
    scales = np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,)).copy()
    if not np.all(np.isfinite(scales) & (scales > 0)):
        raise InputFormatError(f"scale must be positive, got {scale!r}", field="scale")
    if geographic and np.any(scales[:2] > 1e-6):
        raise InputFormatError(f"scale {float(scales[:2].max()):g} deg on a geographic CRS is up to "
                               f"{float(scales[:2].max()) * 111_320.0:.3g} m on the ground; use 1e-8 (about 1 mm)",
                               p, None, "scale")
    header = laspy.LasHeader(point_format=7 if with_rgb else 6, version="1.4")
    header.scales = scales
    header.offsets = np.floor(mins) if mins is not None else np.zeros(3)
    if maxs is not None and mins is not None:
        span = (maxs - header.offsets) / scales
        if np.any(span > 2**31 - 1):
            raise InputFormatError(f"coordinates span {maxs - mins} does not fit LAS 32-bit integers at scale "
                                   f"{scales}; use a coarser scale", field="scale")
    for name in extra_names:
        header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=np.dtype(extra_types.get(name, np.float64))))
    if metadata:
        header.vlrs.append(laspy.VLR(METADATA_VLR_USER_ID, METADATA_VLR_RECORD_ID, "skyrig metadata (JSON)",
                                     json.dumps({str(k): str(v) for k, v in metadata.items()}).encode("utf-8")))
    try:
        header.add_crs(c)
    except Exception as exc:
        raise CRSError(f"cannot store the CRS in a LAS header: {exc}") from None
    return header


def _las_record(header, pts: NDArray[np.float64], colours: NDArray[np.uint16] | None, extra: dict[str, ArrayLike],
                extra_types: dict[str, DTypeLike], gps_time: ArrayLike | None = None,
                intensity: ArrayLike | None = None, scan_angle_deg: ArrayLike | None = None):
    """The points as a ``laspy.LasData`` on ``header``."""
    import laspy

    n = len(pts)
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
    if colours is not None:
        las.red, las.green, las.blue = colours[:, 0], colours[:, 1], colours[:, 2]
    for name, v in extra.items():
        las[name] = np.asarray(v).astype(np.dtype(extra_types.get(name, np.float64)))
    return las


def _publishable(tmp: str) -> None:
    """Give a ``mkstemp`` file (mode 0600) the permissions a normally created file gets (0666 & ~umask)."""
    umask = 0o022
    try:  # read the umask without the thread-unsafe os.umask set-and-restore (Linux >= 4.7)
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                umask = int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    os.chmod(tmp, 0o666 & ~umask)
