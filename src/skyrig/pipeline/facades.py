"""The façades / 3D model stage over files: a DSM, oriented images (and optionally footprints and an orthophoto)
in, building blocks, façade textures and a textured 3D model out.

``run_facades`` reads the DSM (:func:`skyrig.io.dsm_cog.read_dsm_cog`), takes the buildings from given footprints
(GeoPackage polygons, reprojected to the DSM's CRS: :func:`skyrig.io.footprints_gpkg.read_footprint_layer`; heights from the DSM where it
measured the roof, else from a height attribute: :func:`skyrig.dense.buildings.buildings_from_footprints`; the
footprints alone, or completing the DSM's buildings) or extracts them from the DSM
(:func:`skyrig.dense.buildings.extract_buildings`), textures every façade from the images that see it best
(:func:`skyrig.dense.facades.texture_facades`, occlusion against the DSM), builds the model
(:func:`skyrig.dense.model.build_model`; roofs textured from ``--ortho`` when given) and publishes the folder as
a set (:func:`skyrig.io.stage.stage_folder`, manifest last):

=====================  =================================================================================
``model.glb``          binary glTF 2.0, local ENU frame (y-up), origin and CRS in ``asset.extras`` (+ side-car
                       ``model.glb.json``)
``model.obj``          the same as OBJ + ``model.mtl`` + ``model_textures/*.png``
``facades/*.png``      each façade's rectified texture (RGBA, alpha 0 where no image saw the texel), named
                       ``b<building>_f<edge>.png``
``buildings.gpkg``     layer ``buildings``: footprints with ground / eave / ridge heights, in the DSM's CRS
                       (its vertical reference as a compound CRS); layer ``roofs``: roof polygons (3D)
``viewer.html``        a static viewer with the model inlined (opens from the file system)
``facades.json``       per façade: size, texel, images used (best first), coverage; the frame statement; with
                       footprints, ``footprints``: file, mode, footprints given / used, buildings with heights
                       from the attributes, occlusion cells burnt in
=====================  =================================================================================
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.dense.buildings import BuildingBlock, FacadeTexture
from skyrig.dense.grid import DsmGrid
from skyrig.dense.model import Model3D, OrthoRaster
from skyrig.errors import InputFormatError, NoBuildingsError, SkyrigError  # noqa: F401 - NoBuildingsError re-exported
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.io.footprints_gpkg import FootprintLayer, read_footprint_layer

logger = logging.getLogger(__name__)

__all__ = ["FacadesOutputs", "FootprintLayer", "NoBuildingsError", "read_footprint_layer", "read_footprints_gpkg",
           "read_ortho_raster", "run_facades"]


@dataclass
class FacadesOutputs:
    """Where :func:`run_facades` put things, and its counts."""

    outdir: Path
    glb: Path
    viewer: Path
    buildings: list[BuildingBlock]
    textures: list[FacadeTexture]
    model: Model3D
    summary: dict


def read_footprints_gpkg(path: str | Path, frame: WorldFrame, layer: str | None = None) -> list[np.ndarray]:
    """Footprint polygons ``(K, 2)`` of a GeoPackage layer in ``frame`` (:func:`read_footprint_layer`'s rings)."""
    return read_footprint_layer(path, frame, layer).rings


def read_ortho_raster(path: str | Path, frame: WorldFrame | None = None) -> OrthoRaster:
    """An RGB orthophoto (GeoTIFF / COG, bands 1-3, uint8; its mask or alpha band gives the valid cells).

    ``frame``: the frame to use when the raster's horizontal CRS is the same (e.g. the DSM's, so no conversion is
    needed); otherwise the raster's own CRS (heights are not used).

    Raises
    ------
    InputFormatError
        Missing or unreadable file, fewer than 3 bands, not 8-bit, not north-up, no CRS.
    """
    import pyproj
    import rasterio
    from rasterio.errors import RasterioIOError

    p = Path(path)
    if not p.is_file():
        raise InputFormatError("file not found", p, field="ortho")
    try:
        with rasterio.open(p) as ds:
            if ds.count < 3:
                raise InputFormatError(f"an RGB orthophoto needs 3 bands, the raster has {ds.count}", p)
            if ds.dtypes[0] != "uint8":
                raise InputFormatError(f"expected 8-bit RGB, the raster is {ds.dtypes[0]}", p)
            if ds.crs is None:
                raise InputFormatError("raster has no CRS", p, field="crs")
            t = ds.transform
            if abs(t.b) > 0 or abs(t.d) > 0 or not np.isclose(-t.e, t.a, rtol=1e-9, atol=0):
                raise InputFormatError(f"not a north-up grid with square cells (transform {tuple(t)[:6]})", p)
            rgb = np.moveaxis(ds.read([1, 2, 3]), 0, -1)
            valid = ds.dataset_mask() > 0
            crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
    except RasterioIOError as exc:
        raise InputFormatError(f"cannot read raster: {exc}", p) from None
    h = crs.sub_crs_list[0] if crs.is_compound else (crs.to_2d() if len(crs.axis_info) == 3 else crs)
    if frame is not None and frame.kind == "map" and pyproj.CRS.from_user_input(frame.crs).equals(h, ignore_axis_order=True):
        f = frame
    else:
        code = h.to_epsg(min_confidence=100)
        f = WorldFrame.map(f"EPSG:{code}" if code else h.to_wkt())
    return OrthoRaster(np.ascontiguousarray(rgb), float(t.c), float(t.f), float(t.a), f, valid)


def _coverage(t: FacadeTexture) -> float:
    """Fraction of a façade's texels (those inside its outline: a gable end's wall up to its roof line) coloured."""
    return round(float(np.sum(t.valid)) / max(int(t.stats.get("texels", t.valid.size)), 1), 4)


def _write_png(path: Path, rgb: np.ndarray, alpha: np.ndarray | None = None) -> None:
    import cv2

    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if alpha is not None:
        img = np.dstack([img, np.where(alpha, 255, 0).astype(np.uint8)])
    if not cv2.imwrite(str(path), img):
        raise SkyrigError(f"cannot write {path}")


def _buildings_gpkg(path: Path, buildings: Sequence[BuildingBlock], frame: WorldFrame) -> None:
    import shapely

    from skyrig.geodesy.statement import file_crs
    from skyrig.io.gpkg import write_gpkg

    polys = [shapely.Polygon(np.asarray(b.footprint, float)) for b in buildings]
    ridge = [max([float(np.max(np.asarray(r)[:, 2])) for r in b.roof] + [b.eave_z]) for b in buildings]
    fields = {"id": np.array([b.id for b in buildings], np.int64),
              "ground_z": np.array([b.ground_z for b in buildings]),
              "eave_z": np.array([b.eave_z for b in buildings]),
              "ridge_z": np.array(ridge),
              "height_m": np.array([r - b.ground_z for r, b in zip(ridge, buildings)]),
              "roof_planes": np.array([max(len(b.roof), 1) for b in buildings], np.int64),
              "source": np.array([str(b.source) for b in buildings]),
              "clipped": np.array([int(b.clipped) for b in buildings], np.int64),
              "border_edges": np.array([",".join(str(i) for i in b.border_edges) for b in buildings])}
    roof_geoms, roof_id, roof_k = [], [], []
    for b in buildings:
        for k, r in enumerate(b.roof):
            roof_geoms.append(shapely.Polygon(np.asarray(r, float)))
            roof_id.append(b.id)
            roof_k.append(k)
    layers = {"buildings": (polys, fields)}
    if roof_geoms:
        layers["roofs"] = (roof_geoms, {"building": np.array(roof_id, np.int64), "plane": np.array(roof_k, np.int64)})
    fc = file_crs(frame)
    write_gpkg(path, layers, fc.full.to_wkt())


def _complete(extracted: list[BuildingBlock], given: list[BuildingBlock], min_overlap: float = 0.2
              ) -> list[BuildingBlock]:
    """Buildings extracted from the DSM completed by given footprints: a footprint is added when no extracted
    building overlaps it by more than ``min_overlap`` of either's area; an extracted building that the DSM's border
    cut (``clipped``) and that a footprint overlaps so is replaced by the footprint.  Ids: the extracted ones
    keep theirs, the footprints' follow."""
    import shapely
    from dataclasses import replace as _replace

    if not given:
        return list(extracted)
    ex_p = [shapely.Polygon(np.asarray(b.footprint, float)) for b in extracted]
    drop: set[int] = set()
    add = []
    for b in given:
        gp = shapely.Polygon(np.asarray(b.footprint, float))
        over = [i for i, q in enumerate(ex_p)
                if gp.intersection(q).area > min_overlap * min(gp.area, q.area)]
        if not over:
            add.append(b)
        elif all(extracted[i].clipped for i in over):
            drop.update(over)
            add.append(b)
    nxt = max([b.id for b in extracted] + [-1]) + 1
    return [b for i, b in enumerate(extracted) if i not in drop] + [_replace(b, id=nxt + k) for k, b in enumerate(add)]


def run_facades(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], image_paths: Sequence[str],
                dsm: DsmGrid | str | Path, outdir: str | Path, *, footprints: str | Path | None = None,
                extend_dsms: Sequence[DsmGrid | str | Path] = (),
                ortho: OrthoRaster | str | Path | None = None, texel_m: float | None = None, max_images: int = 3,
                image_format: str = "png", refine: bool = True, feet: bool = True, inputs: Sequence[str] = (),
                options: dict | None = None, progress: Callable[[int, int], None] | None = None,
                footprint_layer: str | None = None, eave_field: str | None = None, ridge_field: str | None = None,
                height_reference: str = "ground", footprint_mode: str = "replace",
                refine_footprints: bool = False) -> FacadesOutputs:
    """Building blocks, façade textures and a textured 3D model into ``outdir`` (module docstring).

    Parameters
    ----------
    eo, cameras, image_paths
        Oriented images (any frame), their cameras, and one file per ``eo`` row.
    dsm
        The DSM (a :class:`DsmGrid` or a COG path) in a projected map CRS: buildings, occlusions, output CRS.
    outdir
        Output folder (published as a set).
    footprints
        A GeoPackage of footprint polygons (any CRS); default: buildings extracted from the DSM.  A footprint's
        heights come from the DSM where it measured the roof (half of the cells inside), else from the layer's
        ``eave_field`` (and ``ridge_field``): a cadastre's building beyond the DSM's coverage still gets its walls,
        textured from the obliques; the occlusion surface holds it too
        (:func:`skyrig.dense.buildings.surface_with_buildings`).
    footprint_layer
        The layer (default: ``buildings``, else the only polygon layer).
    eave_field, ridge_field
        Attributes with each footprint's eave (and ridge) height in metres (:class:`FootprintHeights`); NULL: none.
    height_reference
        ``"ground"``: the heights are above the ground at the footprint; ``"absolute"``: in the DSM's vertical
        reference (``vertical_reference`` in facades.json).
    footprint_mode
        ``"replace"``: the footprints are the buildings (none extracted from the DSM); ``"complete"``: buildings
        are extracted from the DSM (and refined) and completed by the footprints that no extracted building
        overlaps; a footprint also replaces the extracted buildings it overlaps that the DSM's border cut.
    refine_footprints
        Move the footprints' walls onto their feet as the obliques show them too
        (:func:`skyrig.dense.facades.refine_wall_feet`; a cadastre's outline is a few decimetres off, and a wall
        0.2 m off shifts its texture by about as much in a 45 deg oblique).
    extend_dsms
        DSMs (grids or COG paths, the DSM's frame) that reach beyond the DSM's surveyed area, e.g. matched from
        pairs of oblique images of one viewing direction each (``skyrig dsm --heads left``): the DSM is extended
        with them (:func:`skyrig.dense.buildings.extend_dsm`) for the buildings and the occlusions, so that the
        buildings the obliques see beyond the nadir images' stereo coverage get walls and textures.
    refine
        Move the walls of DSM-extracted buildings onto the roof outline seen in the images
        (:func:`skyrig.dense.facades.refine_walls`); footprints given as a file are kept as they are.
    feet
        Then move each wall onto its foot as the images that texture it show it
        (:func:`skyrig.dense.facades.refine_wall_feet`; DSM-extracted buildings, with ``refine``).
    ortho
        An RGB orthophoto (path or :class:`OrthoRaster`) to texture the roofs; default: a flat colour.
    texel_m
        Façade texel size in the DSM's metres (default: the best image's footprint, per façade).
    max_images
        Images blended into one façade at most.
    image_format
        ``"png"`` or ``"jpeg"`` for the textures inside the GLB.

    Raises
    ------
    NoBuildingsError
        No building in the DSM / footprints (a failed result).
    InputFormatError, SkyrigError
        Bad inputs (named).
    """
    import time

    from skyrig.dense.buildings import (EAVE_RANGE_M, ExtractionConfig, FootprintHeights, buildings_from_footprints,
                                        extend_dsm, extract_buildings, surface_with_buildings)
    from skyrig.dense.facades import refine_wall_feet, refine_walls, texture_facades
    from skyrig.dense.model import build_model
    from skyrig.io.dsm_cog import read_dsm_cog
    from skyrig.io.gltf import write_glb, write_obj
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.pipeline.dense import ImageFiles
    from skyrig.report.viewer import write_viewer

    t0 = time.time()
    grid = read_dsm_cog(dsm) if not isinstance(dsm, DsmGrid) else dsm
    if grid.frame.kind != "map":
        raise SkyrigError(f"the DSM must be in a projected map CRS, not a {grid.frame.kind} frame")
    extended_cells = 0
    if extend_dsms:
        more = [read_dsm_cog(d) if not isinstance(d, DsmGrid) else d for d in extend_dsms]
        grid = extend_dsm(grid, more)
        extended_cells = int(grid.metadata.get("extended_by", {}).get("cells", 0))
        logger.info("facades: DSM extended by %d cells of %d other DSM(s)", extended_cells, len(more))
    if texel_m is not None and not texel_m > 0:
        raise SkyrigError(f"texel size must be positive, got {texel_m} (option: texel)")
    if len(image_paths) != len(eo):
        raise SkyrigError(f"{len(image_paths)} image files for {len(eo)} orientations")
    missing = sorted({str(c) for c in eo.camera} - set(cameras))
    if missing:
        raise SkyrigError(f"no camera for {', '.join(missing[:5])} (option: camera)")
    orthoraster = read_ortho_raster(ortho, grid.frame) if isinstance(ortho, (str, Path)) else ortho
    if footprint_mode not in ("replace", "complete"):
        raise SkyrigError(f"footprint mode must be 'replace' or 'complete', not {footprint_mode!r} "
                          "(option: footprint_mode)")
    if footprints is None and (eave_field or ridge_field):
        raise SkyrigError("footprint height fields given without footprints (option: footprints)")
    if ridge_field and not eave_field:
        raise SkyrigError("a ridge height field needs an eave height field too (option: eave_field)")
    given: list[BuildingBlock] = []
    from skyrig.pipeline.inputs import require_cameras

    require_cameras(eo, cameras)
    loader = ImageFiles(image_paths, [(cameras[str(c)].width, cameras[str(c)].height) for c in eo.camera])
    if footprints is not None:
        fl = read_footprint_layer(footprints, grid.frame, footprint_layer,
                                  [f for f in (eave_field, ridge_field) if f], max_height_m=None
                                  if height_reference == "absolute" else EAVE_RANGE_M[1])
        hts = None
        if eave_field:
            name = f"{Path(footprints).name} layer {fl.layer}"
            hts = FootprintHeights(fl.heights[eave_field], fl.heights.get(ridge_field) if ridge_field else None,
                                   height_reference, f"{name} field {eave_field}"
                                   + (f" / {ridge_field}" if ridge_field else "")
                                   + (" above the ground" if height_reference == "ground" else
                                      f" ({grid.vertical_reference})"),
                                   tuple(f"{Path(footprints).name} {lab}" for lab in fl.labels))
        given = buildings_from_footprints(fl.rings, grid, source=Path(footprints).name, heights=hts,
                                          labels=[f"{Path(footprints).name} {lab}" for lab in fl.labels])
        if refine_footprints and given:
            given = refine_wall_feet(given, eo, cameras, loader, surface_with_buildings(
                grid, [b for b in given if "; heights: " in str(b.source)]))
    if footprints is None or footprint_mode == "complete":
        # buildings cut by the DSM's border too (clipped there; their edges on the border get no texture)
        buildings = extract_buildings(grid, config=ExtractionConfig(clip_border=True))
        if buildings and refine:
            # walls extracted from a matched DSM sit a fraction of a metre off; the images show the roof outline
            buildings = refine_walls(buildings, eo, cameras, loader, grid)
            if feet:
                # a texture is shifted by the wall's offset times the view's r_z / r_n: the foot decides
                buildings = refine_wall_feet(buildings, eo, cameras, loader, grid)
        buildings = _complete(buildings, given)
    else:
        buildings = given
    if not buildings:
        raise NoBuildingsError("no buildings found" + (" among the footprints" if footprints else
                                                        " in the DSM (nothing higher than 2.5 m above the ground over 20 m2)"))
    # the occlusion surface holds the buildings the DSM did not measure (footprints with given heights)
    grid = surface_with_buildings(grid, [b for b in buildings if "; heights: " in str(b.source)])
    t_build = time.time() - t0
    logger.info("facades: %d buildings, %d façades", len(buildings), sum(len(b.footprint) for b in buildings))
    textures = texture_facades(buildings, eo, cameras, loader, grid, texel_m=texel_m, max_images=max_images,
                               progress=progress)
    t_tex = time.time() - t0 - t_build
    seen = [t for t in textures if np.any(t.valid)]
    model = build_model(buildings, seen, grid.frame, roof_rgb_source=orthoraster,
                        vertical_reference=grid.vertical_reference)
    per_facade = []
    clipped = {b.id for b in buildings if b.clipped}
    for t in textures:
        f = t.facade
        per_facade.append({"building": int(f.building), "edge": int(f.index), "clipped": f.building in clipped, "file": f"facades/b{f.building}_f{f.index}.png",
                           "width_m": round(f.width_m, 3), "height_m": round(f.height_m, 3),
                           "texel_m": round(float(t.texel_m), 4), "size_px": [int(t.rgb.shape[1]), int(t.rgb.shape[0])],
                           "images": list(t.images), "coverage": _coverage(t),
                           "stats": json.loads(json.dumps(t.stats, default=str))})
    cov = np.array([p["coverage"] for p in per_facade]) if per_facade else np.zeros(0)
    summary = {
        "frame": grid.frame.to_text(), "vertical_reference": grid.vertical_reference,
        "buildings": len(buildings), "buildings_clipped": len(clipped),
        "border_edges": sum(len(b.border_edges) for b in buildings), "facades": len(textures), "facades_seen": len(seen),
        "coverage_median": float(np.median(cov)) if len(cov) else None,
        "texel_median_m": float(np.median([p["texel_m"] for p in per_facade])) if per_facade else None,
        "roofs": "orthophoto" if orthoraster is not None else "flat colour",
        "source": (str(footprints) if footprint_mode == "replace" else f"extracted from the DSM, completed by {footprints}")
        if footprints else "extracted from the DSM",
        "footprints": None if footprints is None else {
            "file": str(footprints), "mode": footprint_mode, "given": len(given),
            "used": sum(str(b.source).startswith(Path(footprints).name) for b in buildings),
            "heights_from_attributes": sum("; heights: " in str(b.source) for b in buildings),
            "eave_field": eave_field, "ridge_field": ridge_field,
            "refined": bool(refine_footprints),
            "height_reference": height_reference if eave_field else None,
            "occlusion_cells_burnt": int(grid.metadata.get("buildings_burnt", {}).get("cells", 0))},
        "dsm_extended_cells": extended_cells,
        "triangles": model.n_triangles, "seconds": {"buildings": round(t_build, 2), "textures": round(t_tex, 2)},
        "facade_list": per_facade,
    }
    out = Path(outdir)
    with stage_folder(out, stage="facades", inputs=describe_inputs(list(inputs)), options=options or {}) as tmp:
        side = write_glb(tmp / "model.glb", model, image_format=image_format)
        write_obj(tmp / "model.obj", model)
        (tmp / "facades").mkdir()
        for t in textures:
            _write_png(tmp / "facades" / f"b{t.facade.building}_f{t.facade.index}.png", t.rgb, t.valid)
        _buildings_gpkg(tmp / "buildings.gpkg", buildings, grid.frame)
        write_viewer(tmp / "viewer.html", tmp / "model.glb", title=f"skyrig: {len(buildings)} buildings")
        summary["origin"] = side["origin"]
        summary["glb_bytes"] = (tmp / "model.glb").stat().st_size
        (tmp / "facades.json").write_text(json.dumps(summary, indent=1) + "\n")
    return FacadesOutputs(out, out / "model.glb", out / "viewer.html", list(buildings), list(textures), model, summary)
