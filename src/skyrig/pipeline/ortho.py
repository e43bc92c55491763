"""The orthophoto stage over files: oriented images + a DSM in, a true orthomosaic (COG), its source-image layer
(COG), seamlines (GeoPackage), a preview and a summary out, published as a set (manifest last).

``run_ortho`` reads and checks the DSM (:func:`load_dsm_for`: another CRS than the one asked for is reprojected with
rasterio, heights kept in the DSM's vertical reference; a DSM without a CRS is refused), plans the mosaic with
:func:`skyrig.dense.ortho.plan_ortho` (per-image views through the executor), runs the tiles through
:class:`skyrig.pipeline.executor.Executor` and writes the folder with :func:`skyrig.io.stage.stage_folder`.  With
``head_sets`` it adds one mosaic per set of images (e.g. per rig head - the obliques' mosaics per viewing direction).
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.dense.ortho import EmptyMosaicError, OrthoConfig, Orthomosaic, _OrthoTileJob, assemble_ortho, plan_ortho
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.pipeline.dense import ImageFiles

logger = logging.getLogger(__name__)


def load_dsm_for(path: str | Path, crs: str | None = None) -> DsmGrid:
    """Read a DSM COG; with ``crs`` (another projected CRS than the file's) reproject it onto a north-up grid of the
    same cell size in that CRS (bilinear heights, the vertical reference unchanged).

    Raises
    ------
    InputFormatError
        When the file has no CRS, or is not a raster.
    """
    from skyrig.io.dsm_cog import read_dsm_cog

    try:
        dsm = read_dsm_cog(path)
    except SkyrigError:
        raise
    except Exception as exc:  # rasterio's own errors: not a raster, truncated ...
        raise InputFormatError(f"cannot read the DSM ({exc})", path, field="dsm") from None
    if dsm.frame.kind != "map":
        raise InputFormatError("the DSM has no map CRS: the orthophoto cannot be placed", path, field="dsm")
    from skyrig.geodesy.crs import check_metric_projected, resolve_crs

    if crs is None:
        try:
            check_metric_projected(dsm.frame.crs, "an orthomosaic (its DSM); give --crs to reproject it")
        except SkyrigError as exc:
            raise InputFormatError(str(exc), path, field="dsm") from None
        return dsm

    src, dst = resolve_crs(dsm.frame.crs), resolve_crs(crs)
    if src.equals(dst, ignore_axis_order=True) or (src.to_2d().equals(dst.to_2d(), ignore_axis_order=True)):
        return dsm
    if not dst.is_projected:
        raise SkyrigError(f"the orthophoto needs a projected CRS with metre cells, not {dst.name} (option: crs)")
    return reproject_dsm(dsm, crs)


def reproject_dsm(dsm: DsmGrid, crs: str) -> DsmGrid:
    """The DSM warped onto a grid of the same cell size in another projected CRS (rasterio, bilinear)."""
    import rasterio.warp
    from affine import Affine
    from rasterio.crs import CRS as RioCRS

    from skyrig.geodesy.crs import check_metric_projected, resolve_crs
    from skyrig.geodesy.statement import file_crs

    check_metric_projected(crs, "an orthomosaic (--crs)")
    src_crs = RioCRS.from_wkt(file_crs(dsm.frame).horizontal.to_wkt())
    dst_crs = RioCRS.from_wkt(resolve_crs(crs).to_2d().to_wkt())
    rows, cols = dsm.grid.shape
    x0, y0, x1, y1 = dsm.grid.bounds
    tr, w, h = rasterio.warp.calculate_default_transform(src_crs, dst_crs, cols, rows, left=x0, bottom=y0, right=x1,
                                                         top=y1, resolution=dsm.grid.cell_m)
    out = np.full((h, w), np.nan, np.float32)
    rasterio.warp.reproject(np.asarray(dsm.height, np.float32), out, src_transform=Affine(*dsm.grid.transform),
                            src_crs=src_crs, dst_transform=tr, dst_crs=dst_crs, src_nodata=np.nan, dst_nodata=np.nan,
                            resampling=rasterio.warp.Resampling.bilinear)
    grid = GridSpec(tr.c, tr.f, dsm.grid.cell_m, w, h)
    frame = WorldFrame.map(crs, dsm.frame.geoid)
    shp = (h, w)
    return DsmGrid(grid, frame, out, np.where(np.isfinite(out), 1, 0).astype(np.int16), np.full(shp, np.nan, np.float32),
                   np.full(shp, np.nan, np.float32), np.zeros(shp, bool), dsm.vertical_reference,
                   {**dsm.metadata, "reprojected_from": dsm.frame.crs})


@dataclass
class OrthoOutputs:
    """Where :func:`run_ortho` put things."""

    outdir: Path
    ortho: Path
    source: Path
    seamlines: Path
    preview: Path
    summary: dict
    mosaic: Orthomosaic


def _mosaic(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], loader: ImageFiles, dsm: DsmGrid,
            area, config: OrthoConfig, ex, progress) -> Orthomosaic:
    plan = plan_ortho(eo, cameras, dsm, loader, area=area, config=config,
                      map_fn=lambda f, items: ex.map(f, items, desc="ortho views"))
    logger.info("ortho: %d x %d cells (%.3f m), %d tiles, %d images used", plan.grid.width, plan.grid.height,
                plan.grid.cell_m, len(plan.tiles), plan.stats["images_used"])
    tiles = ex.map(_OrthoTileJob(plan, loader), list(range(len(plan.tiles))), desc="ortho tiles", progress=progress)
    return assemble_ortho(plan, tiles)


def _summary(m: Orthomosaic) -> dict:
    valid = m.valid
    used = np.unique(m.source[m.source >= 0])
    return {"grid": {"x0": m.grid.x0, "y0": m.grid.y0, "cell_m": m.grid.cell_m, "width": m.grid.width,
                     "height": m.grid.height},
            "frame": m.frame.to_text(), "vertical_reference": m.vertical_reference,
            "cells_valid": int(valid.sum()), "cells_surface": int(m.surface.sum()), "cells": int(valid.size),
            "surface_without_colour": int((m.surface & ~valid).sum()),
            "images": list(m.images), "images_used": [m.images[i] for i in used],
            "gains": {m.images[i]: [round(float(g), 4) for g in m.gains[i]] for i in range(len(m.images))},
            "stats": m.stats}


def _write_report(path: Path, preview: Path, summary: dict, mosaic: Orthomosaic, inputs: list[str],
                  options: dict) -> None:
    """``report.html``: the preview, the mosaic's figures and the per-image gains (self-contained page)."""
    from datetime import datetime, timezone

    from skyrig import __version__
    from skyrig.report import ReportData, make_section
    from skyrig.report.adjustment import input_files
    from skyrig.report.model import Column, Table

    g = summary["grid"]
    st = summary["stats"]
    rows = [["grid", f"{g['width']} x {g['height']} cells of {g['cell_m']:.4f} m"],
            ["CRS and heights", f"{mosaic.frame.crs}; {summary['vertical_reference']}"],
            ["cells with a colour", f"{summary['cells_valid']} of {summary['cells_surface']} cells of the surface"],
            ["surface seen by no image", str(summary["surface_without_colour"])],
            ["images used", f"{len(summary['images_used'])} of {len(summary['images'])}"],
            ["elevated objects given one image", f"{st.get('objects_one_image')} of {st.get('objects')}"],
            ["seamline pieces", str(summary.get("seamlines"))],
            ["image pairs balanced", str(st.get("balance_pairs"))]]
    figures = Table("ortho-figures", "The mosaic", [Column("item"), Column("value")], rows)
    gains = Table("ortho-gains", "Radiometric gains (applied to each image's red, green, blue)",
                  [Column("image"), Column("red", decimals=4), Column("green", decimals=4), Column("blue", decimals=4)],
                  [[n, *v] for n, v in summary["gains"].items() if n in set(summary["images_used"])])
    data = ReportData(title="skyrig orthomosaic", software=f"skyrig {__version__}",
                      created=datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
                      inputs=input_files(inputs), options=dict(options), accepted="orthomosaic written")
    data.add(make_section("ortho", preview, caption="True orthomosaic (transparent: no image sees the surface).",
                          tables=[figures, gains]))
    from skyrig.report import write_report

    write_report(path, data)


def run_ortho(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], image_paths: Sequence[str], dsm: DsmGrid,
              outdir: str | Path, *, area: tuple[float, float, float, float] | None = None,
              config: OrthoConfig = OrthoConfig(), main_rows: Sequence[int] | None = None, head_sets: Mapping[str, Sequence[int]] | None = None,
              head_config: OrthoConfig | None = None,
              executor: str = "auto", workers: int | None = None, scheduler: str | None = None,
              inputs: Sequence[str] = (), options: dict | None = None,
              progress: Callable[[int, int], None] | None = None) -> OrthoOutputs:
    """Orthomosaic of oriented images on a DSM into ``outdir`` (``ortho.tif``, ``ortho_source.tif``,
    ``seamlines.gpkg``, ``ortho_preview.png``, ``ortho.json``, ``report.html``, ``manifest.json``; with ``head_sets`` (name ->
    rows of ``eo``) also ``heads/ortho_<name>.tif`` + previews, e.g. one mosaic per oblique viewing direction)."""
    from skyrig.io.ortho_cog import write_ortho_cog, write_preview_png, write_seamlines_gpkg, write_source_cog
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.pipeline.executor import Executor

    from skyrig.pipeline.inputs import require_cameras

    require_cameras(eo, cameras)  # before any camera is looked up (plan_ortho says it too, for library callers)
    loader = ImageFiles(image_paths, [(cameras[str(c)].width, cameras[str(c)].height) for c in eo.camera])
    kind = executor
    if kind == "auto":
        kind = "scheduler" if scheduler else "serial"
    heads: dict[str, Orthomosaic] = {}
    with Executor(kind, workers=workers, scheduler=scheduler) as ex:
        if main_rows is None or len(main_rows) == len(eo):
            mosaic = _mosaic(eo, cameras, loader, dsm, area, config, ex, progress)
        else:
            mr = np.asarray(main_rows, int)
            mosaic = _mosaic(eo.subset(mr), cameras, loader.subset(mr),
                             dsm, area, config, ex, progress)
        if head_sets:
            hc = head_config or replace(config, max_off_nadir_deg=max(config.max_off_nadir_deg, 80.0))
            for h, rows in head_sets.items():
                rows = np.asarray(rows, int)
                if len(rows) == 0:
                    raise SkyrigError(f"no image of head {h!r} (option: head-mosaics)")
                sub = eo.subset(rows)
                sub_loader = loader.subset(rows)
                try:
                    heads[str(h)] = _mosaic(sub, cameras, sub_loader, dsm, area, hc, ex, None)
                except SkyrigError as exc:
                    logger.warning("no mosaic of head %s: %s", h, exc)
    if not mosaic.valid.any():
        raise EmptyMosaicError("the orthomosaic is empty: no image sees the DSM's surface")
    summary = _summary(mosaic)
    summary["config"] = json.loads(json.dumps(asdict(config), default=str))
    summary["executor"] = kind
    summary["image_levels_16bit"] = None if loader.levels is None else list(loader.levels)
    summary["heads"] = {h: _summary(m) for h, m in heads.items()}
    out = Path(outdir)
    with stage_folder(out, stage="ortho", inputs=describe_inputs(list(inputs)), options=options or {}) as tmp:
        write_ortho_cog(tmp / "ortho.tif", mosaic)
        write_source_cog(tmp / "ortho_source.tif", mosaic)
        summary["seamlines"] = write_seamlines_gpkg(tmp / "seamlines.gpkg", mosaic)
        write_preview_png(tmp / "ortho_preview.png", mosaic)
        for h, m in heads.items():
            safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in h)
            write_ortho_cog(tmp / "heads" / f"ortho_{safe}.tif", m)
            write_preview_png(tmp / "heads" / f"ortho_{safe}_preview.png", m)
        (tmp / "ortho.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
        _write_report(tmp / "report.html", tmp / "ortho_preview.png", summary, mosaic, list(inputs), options or {})
    return OrthoOutputs(out, out / "ortho.tif", out / "ortho_source.tif", out / "seamlines.gpkg",
                        out / "ortho_preview.png", summary, mosaic)
