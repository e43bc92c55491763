"""Terrain stages over files: classify a cloud, grid a DTM folder, contour a DTM, compute a volume.

Each is the library function ``skyrig terrain <step>`` and the project runner call; the arrays work is in
:mod:`skyrig.terrain`, the formats in :mod:`skyrig.io.terrain_files`.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.errors import InputFormatError, OptionError
from skyrig.io._text import PathLike

__all__ = ["classify_cloud_file", "dtm_folder", "contours_file", "volume_file"]

log = logging.getLogger(__name__)


def classify_cloud_file(src: PathLike, dst: PathLike, *, crs: str | None = None, ground: Any = None,
                        rules: Any = None, tile_m: float = 500.0, buffer_m: float = 50.0, executor: str = "serial",
                        workers: int | None = None, scheduler: str | None = None,
                        progress: Any = None) -> dict[str, Any]:
    """Classify the LAS/LAZ ``src`` (CSF ground + the ASPRS rule of :mod:`skyrig.terrain.classify`) into ``dst``.

    Coordinates in feet (or any non-metre unit) are scaled to metres for the filter, whose parameters are metres.
    A cloud wider than ``tile_m`` is classified in tiles with a ``buffer_m`` buffer
    (:func:`skyrig.terrain.classify.classify_tiled`), run by the :class:`skyrig.pipeline.executor.Executor` of
    ``executor`` (``auto``: local worker processes when there are several tiles) / ``workers`` / ``scheduler``;
    ``progress(done, total)`` follows the tiles.
    Returns a summary: points, seconds, points per class code (and name).
    """
    from skyrig.io.terrain_files import read_terrain_cloud, write_classified_cloud
    from skyrig.pipeline.executor import Executor
    from skyrig.terrain.classify import ASPRS_NAMES, ClassRules, GroundFilter, classify_tiled, tile_windows

    cloud = read_terrain_cloud(src, crs)
    h, v = cloud.metres_per_unit
    xyz_m = cloud.xyz * np.array([h, h, v])
    t0 = time.perf_counter()
    kind = "scheduler" if scheduler else executor
    if kind == "auto":  # worker processes only for several tiles
        kind = "local" if len(tile_windows(xyz_m[:, :2], tile_m, buffer_m)) > 1 else "serial"
    with Executor(kind, workers=workers, scheduler=scheduler) as ex:
        cl = classify_tiled(xyz_m, cloud.rgb, ground=ground or GroundFilter(), rules=rules or ClassRules(),
                            sigma=cloud.sigma, tile_m=tile_m, buffer_m=buffer_m,
                            map_fn=lambda f, items: ex.map(f, items, desc="classification tiles", progress=progress))
    dt = time.perf_counter() - t0
    write_classified_cloud(src, dst, cl.code)
    return {"points": len(cloud), "seconds": dt, "points_per_second": len(cloud) / max(dt, 1e-9),
            "classes": {f"{k} {ASPRS_NAMES.get(k, '')}".strip(): n for k, n in sorted(cl.counts.items())},
            "output": str(dst)}


def dtm_folder(cloud_path: PathLike, outdir: PathLike, *, cell_m: float | None = None, dsm: PathLike | None = None,
               crs: str | None = None, max_gap_m: float = 20.0, classify: bool = False, published: bool = True
               ) -> dict[str, Any]:
    """DTM (``dtm.tif``), hillshade (``dtm_hillshade.png``), with ``dsm`` the normalised DSM (``ndsm.tif``) on the
    DSM's grid, and ``dtm.json`` (figures), published as one folder with a manifest.

    Parameters
    ----------
    cloud_path
        A classified LAS/LAZ (class 2 = ground); with ``classify`` an unclassified one is classified first.
    cell_m
        DTM cell size (metres); default the DSM's grid when ``dsm`` is given, else 1 m.
    dsm
        A DSM COG: its grid is the DTM's, and the nDSM is written.
    published
        Publish ``outdir`` as a stage folder with a manifest (False: write the files into the existing folder
        ``outdir``, e.g. the project runner's staging folder).

    Raises
    ------
    InputFormatError
        No ground class in the cloud, a cloud in a non-metre CRS, a DSM in another frame.
    """
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.io.terrain_files import read_height_surface, read_terrain_cloud
    from skyrig.terrain.classify import classify_points
    from skyrig.terrain.dtm import make_dtm, same_frame

    cloud = read_terrain_cloud(cloud_path, crs)
    if cloud.metres_per_unit != (1.0, 1.0):
        raise InputFormatError(f"the cloud's CRS is not in metres (axis units {cloud.metres_per_unit} m): DTM grids "
                               "are written in metre CRSs; reproject the cloud first", cloud_path, field="crs")
    code = cloud.classification
    if classify:
        code = classify_points(cloud.xyz, cloud.rgb, sigma=cloud.sigma).code
    elif not np.any(code == 2):
        raise InputFormatError("no ground point (class 2): classify the cloud first (skyrig terrain classify) or "
                               "pass --classify", cloud_path, field="classification")
    d = None
    grid = None
    if dsm is not None:
        d = read_height_surface(dsm, "--dsm")
        if not same_frame(d.frame, cloud.frame):
            raise InputFormatError(f"the DSM is in {d.frame.to_text()}, the cloud in {cloud.frame.to_text()}", dsm,
                                   field="crs")
        if cell_m is None:
            grid = d.grid
    if grid is None and cell_m is None:
        cell_m = 1.0
    t0 = time.perf_counter()
    dtm = make_dtm(cloud.xyz, code, cloud.frame, cell_m=cell_m, grid=grid, sigma=cloud.sigma, max_gap_m=max_gap_m,
                   vertical_reference=cloud.vertical_reference or (d.vertical_reference if d is not None else ""),
                   metadata={"cloud": str(cloud_path)})
    dt = time.perf_counter() - t0
    src = dtm.source
    summary: dict[str, Any] = {
        "cells": int(src.size), "cells_per_second": src.size / max(dt, 1e-9), "cell_m": dtm.grid.cell_m,
        "grid": {"x0": dtm.grid.x0, "y0": dtm.grid.y0, "cell_m": dtm.grid.cell_m, "width": dtm.grid.width,
                 "height": dtm.grid.height},
        "frame": dtm.frame.to_text(), "vertical_reference": dtm.vertical_reference,
        "cells_by_source": {k: int(np.sum(src == c)) for c, k in
                            ((0, "no_data"), (1, "measured"), (2, "gap"), (3, "building"), (4, "vegetation"))},
        "sigma_median_m": {k: float(np.nanmedian(dtm.sigma[src == c])) if np.any(src == c) else None
                           for c, k in ((1, "measured"), (2, "gap"), (3, "building"), (4, "vegetation"))},
    }
    if not published:
        _write_dtm_products(Path(outdir), dtm, d, summary)
        return summary
    inputs = [cloud_path] + ([dsm] if dsm is not None else [])
    with stage_folder(outdir, stage="dtm", inputs=describe_inputs(inputs),
                      options={"cell_m": cell_m, "max_gap_m": max_gap_m, "classify": classify}) as tmp:
        _write_dtm_products(tmp, dtm, d, summary)
    summary["outdir"] = str(outdir)
    return summary


def _write_dtm_products(folder: Path, dtm: Any, dsm: Any, summary: dict[str, Any]) -> None:
    from skyrig.io.dsm_cog import write_hillshade_png
    from skyrig.io.terrain_files import write_dtm_cog, write_ndsm_cog
    from skyrig.terrain.dtm import normalised_dsm

    write_dtm_cog(folder / "dtm.tif", dtm)
    write_hillshade_png(folder / "dtm_hillshade.png", dtm)
    if dsm is not None:
        nd = normalised_dsm(dsm, dtm)
        write_ndsm_cog(folder / "ndsm.tif", dsm, nd)
        summary["ndsm_above_2m_cells"] = int(np.sum(nd > 2.0))
    _json(folder / "dtm.json", summary)


def _json(path: Path, obj: dict) -> None:
    import json

    from skyrig.io._text import atomic_write

    with atomic_write(path) as fh:
        json.dump(obj, fh, indent=1, default=str)
        fh.write("\n")


def contours_file(dtm_path: PathLike, out: PathLike, *, interval_m: float, index_every: int = 5,
                  smooth_cells: float = 1.0, smooth_sigmas: float = 1.0) -> dict[str, Any]:
    """Contour lines of a DTM (or any height COG) into a GeoPackage; returns a summary."""
    from skyrig.io.terrain_files import read_height_surface, write_contours_gpkg
    from skyrig.terrain.contours import make_contours

    d = read_height_surface(dtm_path, "DTM")
    sig = d.sigma if np.isfinite(d.sigma).any() else None
    try:
        c = make_contours(d.height, d.grid, interval_m, index_every=index_every, sigma=sig,
                          smooth_cells=smooth_cells, smooth_sigmas=smooth_sigmas)
    except InputFormatError as exc:
        if exc.field == "interval":
            raise OptionError("--interval", f"{exc.reason} ({dtm_path})") from None
        raise InputFormatError(exc.reason, dtm_path, field=exc.field) from None
    write_contours_gpkg(out, c, d.frame)
    return {"lines": len(c), "index_lines": int(c.index.sum()), "closed": int(c.closed.sum()),
            "levels": int(len(np.unique(c.elevation))), "interval_m": interval_m, "output": str(out),
            "smoothed_within_sigmas": smooth_sigmas if sig is not None else 0.0}


def volume_file(top: PathLike, polygon: PathLike, out: PathLike | None = None, *, base: PathLike | None = None,
                base_plane: float | None = None, base_points: PathLike | None = None, layer: str | None = None,
                correlation_length_m: float | None = None, sigma_sys_m: float = 0.0) -> dict[str, Any]:
    """Cut / fill between the surface ``top`` (a DTM or DSM COG) and one base (another surface, a horizontal
    plane, or a surface through boundary points) inside the polygons of a vector file; written as JSON to ``out``.

    Raises
    ------
    OptionError
        Not exactly one base given.
    InputFormatError
        A base surface in another frame; the polygon's problems (see :func:`read_volume_polygon`).
    """
    from skyrig.io.points_csv import read_points_csv
    from skyrig.io.terrain_files import read_height_surface, read_volume_polygon
    from skyrig.terrain.dtm import same_frame, sample_grid, sample_surface
    from skyrig.terrain.volume import base_from_points, cut_fill, plane_base

    given = [k for k, v in (("--base", base), ("--base-plane", base_plane), ("--base-points", base_points))
             if v is not None]
    if len(given) != 1:
        raise OptionError("--base / --base-plane / --base-points",
                          f"give exactly one base surface ({', '.join(given) or 'none'} given)")
    t = read_height_surface(top, "--top")
    poly = read_volume_polygon(polygon, t.frame, layer)
    sb: Any = 0.0
    if base is not None:
        b = read_height_surface(base, "--base")
        if not same_frame(b.frame, t.frame):
            raise InputFormatError(f"the base surface is in {b.frame.to_text()}, the top in {t.frame.to_text()}",
                                   base, field="crs")
        xx, yy = t.grid.cell_centres()
        bh = sample_surface(b, xx, yy)
        sb = sample_grid(b.grid, b.sigma, xx, yy)
        kind = f"surface {base}"
    elif base_plane is not None:
        bh = plane_base(t.grid, float(base_plane))
        kind = f"plane z = {base_plane}"
    else:
        pts = read_points_csv(base_points, t.frame, option="--base-points")
        bh = base_from_points(t.grid, pts.xyz)
        kind = f"through {len(pts.xyz)} points of {base_points}"
    r = cut_fill(t.height, bh, t.grid, poly, sigma_top=t.sigma, sigma_base=sb,
                 correlation_length_m=correlation_length_m, sigma_sys_m=sigma_sys_m)
    out_d = {**r.as_dict(), "top": str(top), "base": kind, "polygon": str(polygon), "frame": t.frame.to_text(),
             "vertical_reference": t.vertical_reference}
    if out is not None:
        _json(Path(out), out_d)
    return out_d
