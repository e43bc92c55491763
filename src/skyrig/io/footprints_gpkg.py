"""Building footprints from a GeoPackage (any OGR vector file) polygon layer, in the frame of a DSM.

:func:`read_footprint_layer` is the one reader: every polygon of one layer (multi-polygons give one footprint per
part with the feature's attributes; inner rings, i.e. courtyards, are left out with a warning) as its outer ring
in the target frame, with the values of named height fields (metres).  The layer's CRS is checked against the
frame's and the vertices are reprojected with PROJ (pyproj) when they differ (a compound CRS: its horizontal
part), or refused in words (``reproject=False``); a local ENU frame is reached through ECEF at a given height.
A layer without a CRS is refused: its coordinates cannot be placed.  Every refusal names the file, the layer and,
where it applies, the feature id (``InputFormatError.line``) and the field.

:func:`read_footprints` is the same without attributes: ``(rings, labels)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.io._text import PathLike

logger = logging.getLogger(__name__)

__all__ = ["FootprintLayer", "read_footprint_layer", "read_footprints"]


@dataclass
class FootprintLayer:
    """Footprints read by :func:`read_footprint_layer`.

    Attributes
    ----------
    rings
        ``(K, 2)`` exterior rings (no closing vertex) in the target frame, one per polygon part.
    labels
        ``"<layer>:<feature id>[.<part>]"`` per ring.
    heights
        Per ring the values of the height fields asked for (``{field: (N,) float}``; NaN: none given).
    path, layer
        Where they came from.
    """

    rings: list[NDArray[np.float64]]
    labels: list[str]
    heights: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    path: Path = Path()
    layer: str = ""


def read_footprint_layer(path: PathLike, frame: WorldFrame, layer: str | None = None,
                         height_fields: Sequence[str] = (), *, max_height_m: float | None = None,
                         reproject: bool = True, height_m: float = 0.0) -> FootprintLayer:
    """Footprint polygons of a vector layer in ``frame`` (a projected map CRS or a local ENU frame), with the
    values of ``height_fields`` (metres) per footprint.

    Parameters
    ----------
    path
        The GeoPackage (any vector file OGR reads).
    frame
        Target frame (the DSM's).
    layer
        Layer name; None: the layer named ``buildings`` if there is one, else the only polygon layer.
    height_fields
        Attribute fields to read as metres: each value must be a finite number, with ``max_height_m`` at most
        that in absolute value (a height in centimetres or millimetres is refused); NULL gives NaN (its height
        must then come from elsewhere, e.g. the DSM).
    reproject
        Reproject a layer in another CRS (True) or refuse it (False).
    height_m
        Ellipsoidal height at which footprints are placed when the frame is a local ENU frame (whose x, y depend
        on the height by about ``height * distance / earth radius``).

    Raises
    ------
    InputFormatError
        Missing or unreadable file, no such layer / several polygon layers, no CRS, a CRS other than the frame's
        with ``reproject=False``, no polygons, an empty, invalid or degenerate polygon (feature id named), a
        missing height field (the fields there listed), a height that is not a number or implausible (feature id
        and field named), a frame that is neither a map CRS nor a local frame.
    """
    import pyogrio
    import shapely
    from pyogrio.errors import DataLayerError, DataSourceError
    from pyogrio.raw import read
    from pyproj import CRS, Transformer

    from skyrig.geodesy.crs import resolve_crs

    p = Path(path)
    if not p.is_file():
        raise InputFormatError("no such file", p, field="footprints")
    try:
        layers = [(str(n), str(t)) for n, t in pyogrio.list_layers(str(p))]
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise InputFormatError(f"cannot read the footprints: {exc}", p) from None
    names = [n for n, _ in layers]
    if layer is None:
        poly = [n for n, t in layers if "polygon" in t.lower()]
        if "buildings" in names:
            layer = "buildings"
        elif len(poly) == 1:
            layer = poly[0]
        else:
            raise InputFormatError(f"{len(poly)} polygon layers ({', '.join(poly) or 'none'}): name the footprint "
                                   "layer", p, field="layer")
    elif layer not in names:
        raise InputFormatError(f"no layer {layer!r} (layers: {', '.join(names)})", p, field="layer")
    try:
        meta, fids, geoms, data = read(str(p), layer=layer, read_geometry=True, return_fids=True)
    except (DataSourceError, DataLayerError, OSError) as exc:
        raise InputFormatError(f"cannot read layer {layer!r}: {exc}", p, field="layer") from None
    where = f"layer {layer!r}"
    if not meta.get("crs"):
        raise InputFormatError(f"{where} states no CRS: its coordinates cannot be placed (assign one, e.g. ogr2ogr "
                               "-a_srs EPSG:xxxx)", p, field="crs")
    if geoms is None or len(geoms) == 0:
        raise InputFormatError(f"no footprint polygons in {where}", p, field="layer")
    fields = [str(f) for f in meta.get("fields", [])]
    values: dict[str, NDArray[np.float64]] = {}
    for name in height_fields:
        if name not in fields:
            raise InputFormatError(f"{where} has no field {name!r} (fields: {', '.join(fields) or 'none'})", p,
                                   field=name)
        col = data[fields.index(name)]
        vals = np.full(len(col), np.nan)
        for k, v in enumerate(col):
            if v is None or (isinstance(v, float) and np.isnan(v)):
                continue  # NULL: no height given for this feature
            try:
                vals[k] = float(v)
            except (TypeError, ValueError):
                raise InputFormatError(f"{where} feature {fids[k]}: {name} = {v!r} is not a number of metres", p,
                                       line=int(fids[k]), field=name) from None
            if not np.isfinite(vals[k]) or (max_height_m is not None and abs(vals[k]) > max_height_m):
                raise InputFormatError(f"{where} feature {fids[k]}: {name} = {v!r} is not a plausible height in metres"
                                       + (f" (at most {max_height_m:g})" if max_height_m is not None else ""), p,
                                       line=int(fids[k]), field=name)
        values[name] = vals
    src = CRS.from_user_input(meta["crs"])
    h_src = src.sub_crs_list[0] if src.is_compound else src
    if frame.kind == "map":
        dst = resolve_crs(frame.crs)
        dst_h = dst.sub_crs_list[0] if dst.is_compound else dst
        same = h_src.equals(dst_h, ignore_axis_order=True)
        if not same and not reproject:
            raise InputFormatError(f"{where} is in {h_src.name}, the DSM in {dst_h.name}: reproject it first or "
                                   "allow reprojection", p, field="crs")
        tr = None if same else Transformer.from_crs(h_src, dst_h, always_xy=True)

        def to_frame(xy: NDArray) -> NDArray:
            if tr is None:
                return xy
            x, y = tr.transform(xy[:, 0], xy[:, 1])
            return np.column_stack([x, y])
    elif frame.kind == "local":
        if not reproject:
            raise InputFormatError(f"{where} is in {h_src.name}, the DSM in a local frame: allow reprojection", p,
                                   field="crs")
        src_frame = WorldFrame.map(h_src.to_wkt())

        def to_frame(xy: NDArray) -> NDArray:
            xyz = np.column_stack([xy, np.full(len(xy), float(height_m))])
            return frame.from_ecef(src_frame.to_ecef(xyz))[:, :2]
    else:
        raise InputFormatError(f"footprints need a DSM in a map CRS or a local frame, not a {frame.kind} frame", p,
                               field="crs")
    rings, labels, per = [], [], []
    for k, wkb in enumerate(geoms):
        fid = int(fids[k])
        g = shapely.from_wkb(wkb) if wkb is not None else None
        if g is None or g.is_empty:
            raise InputFormatError(f"{where} feature {fid}: empty geometry", p, line=fid, field="geometry")
        polys = list(g.geoms) if g.geom_type == "MultiPolygon" else [g]
        for q, poly in enumerate(polys):
            if poly.geom_type != "Polygon":
                raise InputFormatError(f"{where} feature {fid}: a {poly.geom_type}, not a polygon", p, line=fid,
                                       field="geometry")
            if not poly.is_valid:
                raise InputFormatError(f"{where} feature {fid}: invalid polygon ({shapely.is_valid_reason(poly)})",
                                       p, line=fid, field="geometry")
            if len(poly.interiors):
                logger.warning("%s %s feature %d: %d inner ring(s) (courtyards) left out: the building is modelled as "
                               "its outer footprint", p, where, fid, len(poly.interiors))
            xy = np.asarray(poly.exterior.coords, float)[:-1, :2]  # shapely closes every ring: drop the repeat
            if len(xy) < 3:
                raise InputFormatError(f"{where} feature {fid}: a polygon of {len(xy)} vertices", p, line=fid,
                                       field="geometry")
            rings.append(to_frame(xy))
            labels.append(f"{layer}:{fid}" + (f".{q}" if len(polys) > 1 else ""))
            per.append(k)
    idx = np.asarray(per, int)
    return FootprintLayer(rings, labels, {n: v[idx] for n, v in values.items()}, p, layer)


def read_footprints(path: PathLike, frame: WorldFrame, *, layer: str | None = None, reproject: bool = True,
                    height_m: float = 0.0) -> tuple[list[NDArray[np.float64]], list[str]]:
    """Footprint rings of a layer in ``frame`` and a label per footprint (``"<layer>:<feature id>[.<part>]"``):
    :func:`read_footprint_layer` without attributes."""
    fl = read_footprint_layer(path, frame, layer, reproject=reproject, height_m=height_m)
    return fl.rings, fl.labels
