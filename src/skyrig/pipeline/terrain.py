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
                        progress: Any = None, chunk_points: int = 1_000_000) -> dict[str, Any]:
    """Classify the LAS/LAZ ``src`` (CSF ground + the ASPRS rule of :mod:`skyrig.terrain.classify`) into ``dst``.

    Coordinates in feet (or any non-metre unit) are scaled to metres for the filter, whose parameters are metres.
    A cloud that fits in one ``tile_m`` tile is read and classified whole.  A wider one is classified tile by tile
    with a ``buffer_m`` buffer (the tiles of :func:`skyrig.terrain.classify.classify_tiled`, the same classes) and
    never held whole: it is streamed once, ``chunk_points`` at a time, into one piece file per buffered tile in a
    temporary folder next to ``dst`` (:func:`skyrig.io.terrain_files.spill_tiles`); each task reads its tile's pieces
    and writes its core points' classes back there; the classified copy is written chunk by chunk.  The main process
    holds one chunk, one tile's classes and one byte per point.  The tasks run on the
    :class:`skyrig.pipeline.executor.Executor` of ``executor`` (``auto``: local worker processes when there are
    several tiles) / ``workers`` / ``scheduler`` (a cluster's workers must see ``dst``'s folder);
    ``progress(done, total)`` follows the tiles.
    Returns a summary: points, seconds, points per class code (and name), tiles.
    """
    import tempfile

    from skyrig.io.terrain_files import (read_cloud_header, read_terrain_cloud, spill_tiles, write_classified_cloud,
                                         write_classified_stream)
    from skyrig.pipeline.executor import Executor
    from skyrig.terrain.classify import ASPRS_NAMES, ClassRules, GroundFilter, classify_points

    head = read_cloud_header(src, crs)
    ground, rules = ground or GroundFilter(), rules or ClassRules()
    wins = _tile_grid(head, tile_m, buffer_m)
    t0 = time.perf_counter()
    if len(wins) == 1:
        cloud = read_terrain_cloud(src, crs)
        h, v = cloud.metres_per_unit
        code = classify_points(cloud.xyz * np.array([h, h, v]), cloud.rgb, ground=ground, rules=rules,
                               sigma=cloud.sigma).code
        del cloud
        dt = time.perf_counter() - t0
        write_classified_cloud(src, dst, code)
    else:
        kind = "scheduler" if scheduler else executor
        if kind == "auto":
            kind = "local"
        Path(dst).parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=".skyrig-tiles-", dir=Path(dst).parent) as tmp:
            pieces = spill_tiles(src, head, [b for _, b in wins], tmp, chunk_points)
            items = [(k, files, core) for k, ((core, _), files) in enumerate(zip(wins, pieces)) if files]
            job = _TileClassJob(ground, rules, tmp)
            with Executor(kind, workers=workers, scheduler=scheduler) as ex:
                done = ex.map(job, items, desc="classification tiles", progress=progress)
            code = np.full(head.points, 1, np.uint8)
            for f in done:
                r = np.load(f)
                code[r["gid"]] = r["code"]
            dt = time.perf_counter() - t0
            write_classified_stream(src, dst, code, chunk_points)
    u, c = np.unique(code, return_counts=True)
    return {"points": head.points, "seconds": dt, "points_per_second": head.points / max(dt, 1e-9),
            "classes": {f"{k} {ASPRS_NAMES.get(int(k), '')}".strip(): int(n) for k, n in zip(u, c)},
            "tiles": len(wins), "output": str(dst)}


def _tile_grid(head: Any, tile_m: float, buffer_m: float) -> list[tuple[tuple[float, ...], tuple[float, ...]]]:
    """``[(core, buffered)]`` windows ``(x0, y0, x1, y1)`` (metres, half-open) of ``tile_m`` tiles from the cloud's
    lower-left corner, as :func:`skyrig.terrain.classify.tile_windows` lays them (empty ones included)."""
    if not (np.isfinite(tile_m) and tile_m > 0 and np.isfinite(buffer_m) and buffer_m >= 0):
        raise OptionError("--tile / --buffer", f"tile {tile_m!r} m must be positive and buffer {buffer_m!r} m not "
                          "negative")
    (x0, y0), (x1, y1) = head.mins_m, head.maxs_m
    nx, ny = int(np.floor((x1 - x0) / tile_m)) + 1, int(np.floor((y1 - y0) / tile_m)) + 1
    out = []
    for i in range(nx):
        for j in range(ny):
            cx, cy = x0 + i * tile_m, y0 + j * tile_m
            out.append(((cx, cy, cx + tile_m, cy + tile_m),
                        (cx - buffer_m, cy - buffer_m, cx + tile_m + buffer_m, cy + tile_m + buffer_m)))
    return out


class _TileClassJob:
    """One tile of :func:`classify_cloud_file`: its pieces read and classified together, its core points' classes
    written to ``folder/classes_{k}.npy`` (``gid``, ``code``); returns that file (picklable)."""

    def __init__(self, ground: Any, rules: Any, folder: str) -> None:
        self.ground, self.rules, self.folder = ground, rules, folder

    def __call__(self, item: tuple) -> str:
        from skyrig.terrain.classify import classify_points

        k, files, (x0, y0, x1, y1) = item
        rec = np.concatenate([np.load(f) for f in files])
        names = rec.dtype.names
        xyz = np.column_stack([rec["x"], rec["y"], rec["z"]])
        rgb = np.column_stack([rec["red"], rec["green"], rec["blue"]]) if "red" in names else None
        cl = classify_points(xyz, rgb, ground=self.ground, rules=self.rules,
                             sigma=rec["sigma"] if "sigma" in names else None)
        core = (xyz[:, 0] >= x0) & (xyz[:, 0] < x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] < y1)
        out = np.empty(int(core.sum()), [("gid", "<i8"), ("code", "u1")])
        out["gid"], out["code"] = rec["gid"][core], cl.code[core]
        path = str(Path(self.folder) / f"classes_{k}.npy")
        np.save(path, out)
        return path


def dtm_folder(cloud_path: PathLike, outdir: PathLike, *, cell_m: float | None = None, dsm: PathLike | None = None,
               crs: str | None = None, max_gap_m: float = 20.0, classify: bool = False, published: bool = True,
               tile_m: float = 500.0, buffer_m: float = 50.0, executor: str = "serial", workers: int | None = None,
               scheduler: str | None = None, progress: Any = None, chunk_points: int = 1_000_000
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
    tile_m, buffer_m, executor, workers, scheduler, progress, chunk_points
        A grid wider than ``tile_m`` is made tile by tile (:func:`_dtm_tiled`): the cloud streamed into tile pieces
        with ``buffer_m`` around each (more than ``max_gap_m`` and the widest building), each tile's DTM made from
        its pieces by a task of the executor, its core cells pasted into the grid; the main process holds the grid,
        one chunk and one tile's cells.

    Raises
    ------
    InputFormatError
        No ground class in the cloud, a cloud in a non-metre CRS, a DSM in another frame.
    """
    from skyrig.dense.grid import GridSpec
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.io.terrain_files import read_cloud_header, read_height_surface, read_terrain_cloud
    from skyrig.terrain.classify import classify_points
    from skyrig.terrain.dtm import make_dtm, same_frame

    head = read_cloud_header(cloud_path, crs)
    if head.metres_per_unit != (1.0, 1.0):
        raise InputFormatError(f"the cloud's CRS is not in metres (axis units {head.metres_per_unit} m): DTM grids "
                               "are written in metre CRSs; reproject the cloud first", cloud_path, field="crs")
    d = None
    grid = None
    if dsm is not None:
        d = read_height_surface(dsm, "--dsm")
        if not same_frame(d.frame, head.frame):
            raise InputFormatError(f"the DSM is in {d.frame.to_text()}, the cloud in {head.frame.to_text()}", dsm,
                                   field="crs")
        if cell_m is None:
            grid = d.grid
    if grid is None and cell_m is None:
        cell_m = 1.0
    if grid is None and max(head.maxs_m[0] - head.mins_m[0], head.maxs_m[1] - head.mins_m[1]) > tile_m:
        grid = GridSpec.covering(*head.mins_m, head.maxs_m[0] + 1e-9, head.maxs_m[1] + 1e-9, float(cell_m))
    vref = head.vertical_reference or (d.vertical_reference if d is not None else "")
    t0 = time.perf_counter()
    if grid is not None and max(grid.width, grid.height) * grid.cell_m > tile_m:
        dtm = _dtm_tiled(cloud_path, head, grid, vref, max_gap_m=max_gap_m, classify=classify, tile_m=tile_m,
                         buffer_m=buffer_m, executor=executor, workers=workers, scheduler=scheduler,
                         progress=progress, chunk_points=chunk_points)
    else:
        cloud = read_terrain_cloud(cloud_path, crs)
        code = cloud.classification
        if classify:
            code = classify_points(cloud.xyz, cloud.rgb, sigma=cloud.sigma).code
        elif not np.any(code == 2):
            raise InputFormatError("no ground point (class 2): classify the cloud first (skyrig terrain classify) or "
                                   "pass --classify", cloud_path, field="classification")
        dtm = make_dtm(cloud.xyz, code, cloud.frame, cell_m=cell_m, grid=grid, sigma=cloud.sigma, max_gap_m=max_gap_m,
                       vertical_reference=vref, metadata={"cloud": str(cloud_path)})
        del cloud
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


def _dtm_tiled(cloud_path: PathLike, head: Any, grid: Any, vref: str, *, max_gap_m: float, classify: bool,
               tile_m: float, buffer_m: float, executor: str, workers: int | None, scheduler: str | None,
               progress: Any, chunk_points: int) -> Any:
    """:func:`skyrig.terrain.dtm.make_dtm` tile by tile on ``grid`` (see :func:`dtm_folder`): tiles of ``tile_m``
    cells' worth, each made on its window of the grid grown by ``buffer_m`` from the points in it (streamed into
    pieces, :func:`skyrig.io.terrain_files.spill_tiles`), its core cells kept.  The DTM's curvature figure (the
    sigma of interpolated cells) is the tile's own; the metadata keeps the median over the tiles."""
    import tempfile

    from skyrig.io.terrain_files import spill_tiles
    from skyrig.pipeline.executor import Executor
    from skyrig.terrain.dtm import DtmGrid

    t, b = max(1, int(np.ceil(tile_m / grid.cell_m))), int(np.ceil(buffer_m / grid.cell_m))
    jobs, spill = [], []
    for r0 in range(0, grid.height, t):
        for c0 in range(0, grid.width, t):
            br0, bc0 = max(0, r0 - b), max(0, c0 - b)
            br1, bc1 = min(grid.height, r0 + t + b), min(grid.width, c0 + t + b)
            win = grid.window(br0, bc0, br1 - br0, bc1 - bc0)
            core = (r0 - br0, c0 - bc0, min(t, grid.height - r0), min(t, grid.width - c0))
            jobs.append(((r0, c0), win, core))
            wx0, wy0, wx1, wy1 = win.bounds  # grown by a cell: the window's edge points are in (half-open pieces)
            spill.append((wx0 - grid.cell_m, wy0 - grid.cell_m, wx1 + grid.cell_m, wy1 + grid.cell_m))
    height = np.full(grid.shape, np.nan, np.float32)
    sigma = np.full(grid.shape, np.nan, np.float32)
    count = np.zeros(grid.shape, np.int32)
    source = np.zeros(grid.shape, np.uint8)
    kappas = []
    kind = "scheduler" if scheduler else ("local" if executor == "auto" else executor)
    with tempfile.TemporaryDirectory(prefix=".skyrig-tiles-", dir=Path(cloud_path).parent) as tmp:
        pieces = spill_tiles(cloud_path, head, spill, tmp, chunk_points)
        items = [(win, core, files) for (_, win, core), files in zip(jobs, pieces) if files]
        corners = [rc for (rc, _, _), files in zip(jobs, pieces) if files]
        job = _TileDtmJob(head.frame, max_gap_m, classify, vref)
        with Executor(kind, workers=workers, scheduler=scheduler) as ex:
            res = ex.map(job, items, desc="DTM tiles", progress=progress)
    for (r0, c0), r in zip(corners, res):
        if r is None:
            continue
        h_, s_, n_, src_, kap = r
        sl = np.s_[r0:r0 + h_.shape[0], c0:c0 + h_.shape[1]]
        height[sl], sigma[sl], count[sl], source[sl] = h_, s_, n_, src_
        kappas.append(kap)
    if not kappas:
        raise InputFormatError("no ground point (class 2): classify the cloud first (skyrig terrain classify) or "
                               "pass --classify", cloud_path, field="classification")
    from skyrig.terrain.dtm import DTM_SOURCE

    meta = {"dtm_source_codes": {str(k): v for k, v in DTM_SOURCE.items()},
            "curvature_nmad_per_m": float(np.median(kappas)), "max_gap_m": max_gap_m, "cloud": str(cloud_path),
            "tiles": len(items), "tile_m": tile_m, "buffer_m": buffer_m}
    return DtmGrid(grid, head.frame, height, sigma, count, source, vref, meta)


class _TileDtmJob:
    """One tile of :func:`_dtm_tiled`: the DTM of its buffered window from its pieces, the core cells returned
    (``None`` for a tile without ground points)."""

    def __init__(self, frame: Any, max_gap_m: float, classify: bool, vref: str) -> None:
        self.frame, self.max_gap_m, self.classify, self.vref = frame, max_gap_m, classify, vref

    def __call__(self, item: tuple) -> tuple | None:
        from skyrig.terrain.classify import classify_points
        from skyrig.terrain.dtm import make_dtm

        win, (r, c, h, w), files = item
        rec = np.concatenate([np.load(f) for f in files])
        names = rec.dtype.names
        xyz = np.column_stack([rec["x"], rec["y"], rec["z"]])
        sig = rec["sigma"] if "sigma" in names else None
        code = rec["code"]
        if self.classify:
            rgb = np.column_stack([rec["red"], rec["green"], rec["blue"]]) if "red" in names else None
            code = classify_points(xyz, rgb, sigma=sig).code
        if not np.any(code == 2):
            return None
        d = make_dtm(xyz, code, self.frame, grid=win, sigma=sig, max_gap_m=self.max_gap_m,
                     vertical_reference=self.vref)
        sl = np.s_[r:r + h, c:c + w]
        return d.height[sl], d.sigma[sl], d.ground_points[sl], d.source[sl], d.metadata["curvature_nmad_per_m"]


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


def _interpolated_regions(path: PathLike, xx: np.ndarray, yy: np.ndarray) -> np.ndarray | None:
    """Labels (0: none) of a skyrig DTM's interpolated gaps (source 2-4: across a gap, under a building or
    vegetation) at the points ``xx, yy`` (nearest cell), or None when ``path`` is not a skyrig DTM."""
    import rasterio
    from scipy import ndimage

    from skyrig.io.terrain_files import read_dtm_cog

    with rasterio.open(path) as ds:
        if ds.tags().get("SKYRIG_PRODUCT") != "dtm":
            return None
    d = read_dtm_cog(path)
    lab, _ = ndimage.label(np.isin(d.source, (2, 3, 4)))
    r, c = d.grid.cell_of(xx, yy)
    ok = (r >= 0) & (r < d.grid.height) & (c >= 0) & (c < d.grid.width)
    return np.where(ok, lab[np.clip(r, 0, d.grid.height - 1), np.clip(c, 0, d.grid.width - 1)], 0)


def _sigma_column(text: list[str], path: PathLike) -> np.ndarray:
    """A points file's ``sz`` column as numbers >= 0 (else an error naming file, line and field)."""
    from skyrig.io._text import float_column
    from skyrig.io.points_csv import _header_line

    lines = [_header_line(path) + 1 + k for k in range(len(text))]
    out = float_column(text, path, lines, "sz")
    if np.any(out < 0):
        k = int(np.flatnonzero(out < 0)[0])
        raise InputFormatError(f"height sigma {text[k]!r} is negative", path, lines[k], field="sz")
    return out


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
                correlation_length_m: float | None = None, sigma_sys_m: float = 0.0, base_fit: str = "tin"
                ) -> dict[str, Any]:
    """Cut / fill between the surface ``top`` (a DTM or DSM COG) and one base (another surface, a horizontal
    plane, or a surface through boundary points) inside the polygons of a vector file; written as JSON to ``out``.

    Raises
    ------
    OptionError
        Not exactly one base given.
    InputFormatError
        A base surface in another frame; the polygon's problems (see :func:`read_volume_polygon`).
    """
    from skyrig.io.points_csv import read_point_extras, read_points_csv
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
    bp = regions = None
    if base is not None:
        b = read_height_surface(base, "--base")
        if not same_frame(b.frame, t.frame):
            raise InputFormatError(f"the base surface is in {b.frame.to_text()}, the top in {t.frame.to_text()}",
                                   base, field="crs")
        xx, yy = t.grid.cell_centres()
        bh = sample_surface(b, xx, yy)
        sb = sample_grid(b.grid, b.sigma, xx, yy)
        kind = f"surface {base}"
        regions = _interpolated_regions(base, xx, yy)
        if regions is not None:
            kind += " (a DTM: its interpolated gaps' errors correlated over each gap)"
    elif base_plane is not None:
        bh = plane_base(t.grid, float(base_plane))
        kind = f"plane z = {base_plane}"
    else:
        pts = read_points_csv(base_points, t.frame, option="--base-points")
        if base_fit not in ("tin", "plane"):
            raise OptionError("--base-fit", f"is tin or plane, got {base_fit!r}")
        bh = base_from_points(t.grid, pts.xyz, base_fit)
        kind = f"{'triangulated' if base_fit == 'tin' else 'a plane fitted'} through {len(pts.xyz)} points of " \
            f"{base_points}"
        sz = read_point_extras(base_points).get("sz")
        if sz is not None:  # the points' height precision, propagated to the volume
            bp = (pts.xyz[:, :2], _sigma_column(sz, base_points), base_fit)
            kind += " (height sigmas sz propagated)"
    r = cut_fill(t.height, bh, t.grid, poly, sigma_top=t.sigma, sigma_base=sb,
                 correlation_length_m=correlation_length_m, sigma_sys_m=sigma_sys_m, base_points=bp,
                 base_regions=regions)
    out_d = {**r.as_dict(), "top": str(top), "base": kind, "polygon": str(polygon), "frame": t.frame.to_text(),
             "vertical_reference": t.vertical_reference}
    if out is not None:
        _json(Path(out), out_d)
    return out_d
