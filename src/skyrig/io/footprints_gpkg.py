"""Building footprints from a GeoPackage polygon layer (pyogrio), in the frame of a DSM.

``read_footprints(path, frame)`` reads every polygon (multi-polygons give one footprint per part; interior
rings, i.e. courtyards, are left out) of one layer and returns their outer rings in ``frame``: the layer's CRS
is checked against the frame's and the vertices are reprojected with PROJ (pyproj) when they differ, or
refused in words (``reproject=False``).  A layer without a CRS is refused: its coordinates cannot be placed.
Heights are not read (they come from the DSM: :func:`skyrig.dense.buildings.buildings_from_footprints`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.io._text import PathLike


def read_footprints(path: PathLike, frame: WorldFrame, *, layer: str | None = None, reproject: bool = True,
                    height_m: float = 0.0) -> tuple[list[NDArray[np.float64]], list[str]]:
    """Footprint polygons of a GeoPackage layer in ``frame``.

    Parameters
    ----------
    path
        The GeoPackage.
    frame
        Target frame (the DSM's): a projected map CRS or a local ENU frame.
    layer
        Layer name; None: the only polygon layer (refused when there are several).
    reproject
        Reproject a layer in another CRS (True) or refuse it (False).
    height_m
        Ellipsoidal height at which footprints are placed when the frame is a local ENU frame (whose x, y
        depend on the height by about ``height * distance / earth radius``).

    Returns
    -------
    ``(N_i, 2)`` outer rings (x, y in ``frame``; not closed, in the file's order) and a label per footprint
    (``"<layer>:<feature id>[.<part>]"``).

    Raises
    ------
    InputFormatError
        On a missing file or layer, a layer without polygons or without a CRS, a CRS other than the frame's
        with ``reproject=False``, or a polygon of fewer than 3 vertices.
    """
    import pyogrio
    import shapely
    from pyproj import CRS, Transformer

    from skyrig.geodesy.crs import resolve_crs

    p = Path(path)
    if not p.is_file():
        raise InputFormatError("no such GeoPackage", p)
    try:
        layers = pyogrio.list_layers(str(p))
    except Exception as exc:  # noqa: BLE001 - GDAL's reason in words
        raise InputFormatError(f"not a readable GeoPackage ({exc})", p) from exc
    poly = [str(n) for n, g in layers if g is not None and "polygon" in str(g).lower()]
    if layer is None:
        if len(poly) != 1:
            raise InputFormatError(f"{len(poly)} polygon layers ({', '.join(poly) or 'none'}): name the footprint layer",
                                   p, field="layer")
        layer = poly[0]
    elif layer not in [str(n) for n, _ in layers]:
        raise InputFormatError(f"no layer {layer!r} (layers: {', '.join(str(n) for n, _ in layers)})", p, field="layer")
    meta, fids, geoms, _ = pyogrio.raw.read(str(p), layer=layer, return_fids=True)
    wkt = meta.get("crs")
    if not wkt:
        raise InputFormatError(f"layer {layer!r} has no CRS: its coordinates cannot be placed (assign one, e.g. "
                               "ogr2ogr -a_srs EPSG:xxxx)", p, field="crs")
    src = CRS.from_user_input(wkt)
    if frame.kind == "map":
        dst = resolve_crs(frame.crs)
        same = src.equals(dst, ignore_axis_order=True)
        if not same and not reproject:
            raise InputFormatError(f"layer {layer!r} is in {src.name}, the DSM in {dst.name}: reproject it first or "
                                   "allow reprojection", p, field="crs")
        tr = None if same else Transformer.from_crs(src, dst, always_xy=True)

        def to_frame(xy: NDArray) -> NDArray:
            if tr is None:
                return xy
            x, y = tr.transform(xy[:, 0], xy[:, 1])
            return np.column_stack([x, y])
    elif frame.kind == "local":
        if not reproject:
            raise InputFormatError(f"layer {layer!r} is in {src.name}, the DSM in a local frame: allow reprojection",
                                   p, field="crs")
        src_frame = WorldFrame.map(src.to_wkt())

        def to_frame(xy: NDArray) -> NDArray:
            xyz = np.column_stack([xy, np.full(len(xy), float(height_m))])
            return frame.from_ecef(src_frame.to_ecef(xyz))[:, :2]
    else:
        raise InputFormatError(f"footprints need a map or local frame, not {frame.kind}", p)
    out: list[NDArray[np.float64]] = []
    labels: list[str] = []
    for fid, wkb in zip(fids, geoms):
        if wkb is None:
            continue
        g = shapely.from_wkb(wkb)
        if g.is_empty:
            continue
        parts = list(g.geoms) if g.geom_type == "MultiPolygon" else [g]
        for k, part in enumerate(parts):
            if part.geom_type != "Polygon":
                raise InputFormatError(f"feature {fid} is a {part.geom_type}, not a polygon", p, line=int(fid),
                                       field="geometry")
            ring = np.asarray(part.exterior.coords, float)[:, :2]
            if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
                ring = ring[:-1]
            if len(ring) < 3:
                raise InputFormatError(f"feature {fid}: a polygon of {len(ring)} vertices", p, line=int(fid),
                                       field="geometry")
            out.append(to_frame(ring))
            labels.append(f"{layer}:{fid}" + (f".{k}" if len(parts) > 1 else ""))
    if not out:
        raise InputFormatError(f"layer {layer!r} has no polygon", p, field="layer")
    return out, labels
