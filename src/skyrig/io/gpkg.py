"""GeoPackage vector output (points, line strings, polygons) through pyogrio (GDAL's OGR driver).

``write_gpkg(path, layers, crs)`` writes every layer into one new GeoPackage (temporary file, then
renamed), readable by QGIS and GDAL.  A layer is ``(geometries, fields)``: shapely geometries of one
type and a dict of equally long columns (numbers or strings); 3D geometries give a ``... Z`` layer.  ``crs``: anything
PROJ reads, a compound or 3D CRS included (the heights' vertical reference).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from skyrig.errors import SkyrigError
from skyrig.io._text import PathLike, output_temp, publish


def write_gpkg(path: PathLike, layers: Mapping[str, tuple[Sequence[Any], Mapping[str, Any]]], crs: str | None) -> None:
    """Write layers ``{name: (geometries, {field: values})}`` to a GeoPackage in ``crs`` (None: no CRS)."""
    import shapely
    from pyogrio.raw import write

    from skyrig.geodesy.crs import resolve_crs

    p = Path(path)
    fd, tmp = output_temp(p, ".gpkg")
    os.close(fd)
    os.unlink(tmp)  # GDAL creates the file
    wkt = resolve_crs(crs).to_wkt() if crs else None
    try:
        first = True
        for name, (geoms, fields) in layers.items():
            g = np.asarray(geoms, dtype=object)
            if g.size == 0:
                continue
            types = {shapely.get_type_id(x) for x in g}
            if len(types) != 1:
                raise SkyrigError(f"GeoPackage layer {name!r}: geometries of mixed types")
            gtype = {0: "Point", 1: "LineString", 3: "Polygon"}[types.pop()]
            if bool(np.all(shapely.has_z(g))):
                gtype += " Z"  # 3D geometries (heights in the CRS's vertical reference)
            keys = list(fields)
            data = []
            for k in keys:
                v = np.asarray(fields[k])
                if v.shape[0] != g.size:
                    raise SkyrigError(f"GeoPackage layer {name!r}: field {k!r} has {v.shape[0]} values for {g.size} features")
                data.append(v.astype(object) if v.dtype.kind in "US" else v)
            write(tmp, geometry=shapely.to_wkb(g), field_data=data, fields=keys, layer=name, driver="GPKG",
                  geometry_type=gtype, crs=wkt, append=not first)
            first = False
        if first:
            raise SkyrigError("GeoPackage: nothing to write (all layers empty)")
        publish(tmp, p)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def read_gpkg_layers(path: PathLike) -> list[str]:
    """Names of the layers of a GeoPackage."""
    from pyogrio import list_layers

    return [str(x[0]) for x in list_layers(str(path))]
