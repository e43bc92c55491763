"""The product commands as library functions: DSM, orthomosaic, façades / 3D model from oriented images.

``skyrig dsm`` / ``ortho`` / ``facades`` (:mod:`skyrig.cli`) and the project runner's stages of the same names
(:mod:`skyrig.pipeline.run`) both call :func:`make_dsm`, :func:`make_ortho` and :func:`make_facades` with the
orientations and cameras they loaded and the options as plain values; so a project run gives the same outputs as the
commands, and neither layer holds the other's code.  Option values are checked here; a bad one is an
:class:`skyrig.errors.OptionError` naming the option as the caller spells it (``spell("resolution")`` gives
``--resolution`` on the command line, ``stages.dsm.resolution`` in a project).

Each function writes its folder as a set (manifest last) through the ``run_*`` function it calls and returns that
function's result; ``progress(done, total)`` follows the tiles, ``echo`` receives the lines a user should read.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import OptionError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame

__all__ = ["make_dsm", "make_ortho", "make_facades", "make_plane_mosaic", "plane_in_local_frame", "cli_spelling"]

Progress = Callable[[int, int], None] | None
Echo = Callable[[str], None]


def cli_spelling(name: str) -> str:
    """``pairs_per_image`` -> ``--pairs-per-image``: how the command line names an option."""
    return "--" + name.replace("_", "-")


def _positive(value: float | None, name: str, spell: Callable[[str], str], what: str = "a positive size in metres",
              minimum: float | None = None) -> None:
    if value is None:
        return
    ok = value >= minimum if minimum is not None else value > 0
    if not ok:
        raise OptionError(spell(name), f"must be {what}, got {value}")


def _executor_kind(executor: str) -> str:
    if executor not in ("auto", "serial", "local", "scheduler"):
        raise OptionError("executor", f"unknown executor {executor!r} (auto, serial, local, scheduler)")
    return executor


def _image_scale(value: float | str | None, spell: Callable[[str], str]) -> float | None:
    """The dense chain's image scale (None: auto) from a number or ODM's quality name."""
    from skyrig.dense.levels import QUALITY, level_of_scale

    if value is None or value == "auto":
        return None
    if isinstance(value, str) and value in QUALITY:
        return QUALITY[value]
    try:
        scale = float(value)
    except (TypeError, ValueError):
        raise OptionError(spell("image_scale"), f"must be auto, a scale 1 / 0.5 / 0.25 / 0.125 / 0.0625 or one of "
                                                f"{', '.join(QUALITY)}, not {value!r}") from None
    try:
        level_of_scale(scale)
    except SkyrigError as exc:
        raise OptionError(spell("image_scale"), str(exc)) from None
    return scale


def make_dsm(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
             outdir: str | Path, *, crs: str | None = None, geoid: str | None = None,
             height_range: Sequence[float] | None = None, points: str | PathLike[str] | None = None,
             heads: str | Sequence[str] | None = None, area: Sequence[float] | None = None,
             resolution: float | None = None, mode: str = "sgbm", pairs_per_image: int = 6, min_support: int = 2,
             fill: bool = False, cloud: bool = True, min_depth: float | None = None, tile_cells: int = 2048,
             executor: str = "auto", workers: int | None = None, scheduler: str | None = None,
             inputs: Sequence[str | PathLike[str]] = (), progress: Progress = None,
             echo: Echo = lambda line: None, spell: Callable[[str], str] = cli_spelling,
             lr_check: str | None = None, window_min_mp: float | None = None,
             image_scale: float | str | None = "auto", orientation_sigma_px: float | None = None,
             tile_memory_mb: float | None = 1024.0, lr_band_cols: int | None = None) -> Any:
    """DSM (COG), dense cloud (LAZ), hillshade and summary of oriented images into ``outdir``
    (:func:`skyrig.pipeline.dense.run_dsm`).

    ``crs`` / ``geoid``: output CRS and geoid (default: the EO's map CRS and geoid).  ``height_range``: expected
    surface heights in the output heights; without it, derived from sparse ``points`` (e.g. an adjustment's
    points.csv).  ``heads``: only these rig heads / image-name parts.  ``lr_check``: the matcher's left-right
    check, ``"opencv"`` or ``"full"`` (:class:`skyrig.dense.sgm.SgmConfig`; default: :class:`DenseConfig`'s).
    ``window_min_mp``: TIFFs of at least this many megapixels are read window by window (default:
    :attr:`skyrig.pipeline.dense.ImageFiles.WINDOW_MIN_PIXELS`).  ``image_scale``: the scale the images are
    matched at, 1, 0.5, 0.25, 0.125, 0.0625 or ODM's names ultra, high, medium, low, lowest; ``"auto"``: from
    ``resolution``, without it the largest scale that keeps the images within 2048 px
    (:func:`skyrig.dense.levels.auto_image_scale`).  ``orientation_sigma_px``: the orientations' relative error
    as a disparity in full-resolution pixels, for the fusion's tolerance (:class:`DenseConfig`; None: 0).
    ``tile_memory_mb``: memory budget of one ground tile's work, the tiles' side chosen up to ``tile_cells`` to fit
    it (:class:`DenseConfig`; None: tiles of ``tile_cells``).
    ``lr_band_cols``: the banded check's ``SgmConfig.lr_band_cols_px`` (pixels, >= 0; None: :class:`DenseConfig`'s).
    """
    from dataclasses import replace

    from skyrig.dense.surface import DenseConfig
    from skyrig.pipeline.dense import find_images, height_range_from_points, run_dsm
    from skyrig.pipeline.inputs import select_heads

    eo = select_heads(eo, heads, spell("heads"))
    if crs:
        out_frame = WorldFrame.map(crs, geoid)
    elif eo.frame.kind == "map":
        out_frame = WorldFrame.map(eo.frame.crs, geoid if geoid else eo.frame.geoid)
    else:
        hint = f" (its own: '{eo.frame.to_text()}', the CRS carrying it)" if eo.frame.kind == "local" else ""
        raise OptionError(spell("crs"), f"the EO file is in a {eo.frame.kind} frame: give the output CRS{hint}")
    if height_range is None:
        if points is None:
            raise OptionError(spell("height_range"), "give the expected surface heights (MIN MAX) or sparse points "
                                                     f"to derive them from ({spell('points')})")
        from skyrig.io.points_csv import read_points_csv

        pts = read_points_csv(points)
        xyz = out_frame.from_ecef(pts.frame.to_ecef(pts.xyz))
        height_range = height_range_from_points(xyz[:, 2])
        echo(f"height range from {len(pts)} points: {height_range[0]:.2f} .. {height_range[1]:.2f} m")
    if len(height_range) != 2 or not height_range[0] < height_range[1]:
        raise OptionError(spell("height_range"), f"must be MIN MAX with MIN < MAX, got {list(height_range)}")
    _positive(resolution, "resolution", spell)
    _positive(min_depth, "min_depth", spell)
    _positive(orientation_sigma_px, "orientation_sigma_px", spell, "a positive number of pixels")
    _positive(min_support, "min_support", spell, "at least 1", 1)
    _positive(pairs_per_image, "pairs_per_image", spell, "at least 1", 1)
    _positive(tile_cells, "tile_cells", spell, "at least 64 cells", 64)
    _positive(tile_memory_mb, "tile_memory_mb", spell, "a positive number of MiB (null: tiles of tile_cells)")
    if mode not in ("sgbm", "hh", "3way", "hh4"):
        raise OptionError(spell("mode"), f"unknown mode {mode!r} (sgbm, hh, 3way, hh4)")
    if lr_check is not None and lr_check not in ("opencv", "banded", "full"):
        raise OptionError(spell("lr_check"), f"unknown left-right check {lr_check!r} (banded, full, opencv)")
    if lr_band_cols is not None and (isinstance(lr_band_cols, bool) or not isinstance(lr_band_cols, (int, np.integer))
                                     or lr_band_cols < 0):
        raise OptionError(spell("lr_band_cols"), f"must be a whole number of pixels >= 0, got {lr_band_cols!r}")
    if window_min_mp is not None and not window_min_mp >= 0:
        raise OptionError(spell("window_min_mp"), f"must be >= 0 megapixels, got {window_min_mp}")
    scale = _image_scale(image_scale, spell)
    paths = find_images(eo, [str(p) for p in images])
    base = DenseConfig()
    lr_check = base.sgm.lr_check if lr_check is None else lr_check
    lr_band_cols = base.sgm.lr_band_cols_px if lr_band_cols is None else int(lr_band_cols)
    cfg = DenseConfig(cell_m=resolution, pairs=replace(base.pairs, pairs_per_image=pairs_per_image),
                      sgm=replace(base.sgm, mode=mode, lr_check=lr_check, lr_band_cols_px=lr_band_cols),
                      fusion=replace(base.fusion, min_support=min_support),
                      fill_holes=fill, cloud=cloud, tile_cells=tile_cells, min_depth_m=min_depth, image_scale=scale,
                      orientation_sigma_px=orientation_sigma_px or 0.0,
                      tile_memory_mb=None if tile_memory_mb is None else float(tile_memory_mb))
    heads_text = heads if heads is None or isinstance(heads, str) else ",".join(heads)
    options = {"crs": out_frame.crs, "geoid": out_frame.geoid, "height_range": [float(h) for h in height_range],
               "area": None if area is None else [float(a) for a in area], "resolution": resolution, "mode": mode,
               "pairs_per_image": pairs_per_image, "min_support": min_support, "fill": fill, "cloud": cloud,
               "tile_cells": tile_cells, "heads": heads_text or None, "min_depth": min_depth,
               "lr_check": lr_check, "lr_band_cols": lr_band_cols, "window_min_mp": window_min_mp, "image_scale": image_scale,
               "orientation_sigma_px": orientation_sigma_px, "tile_memory_mb": tile_memory_mb}
    return run_dsm(eo, cameras, paths, out_frame, (float(height_range[0]), float(height_range[1])), outdir,
                   area=tuple(area) if area else None, config=cfg, executor=_executor_kind(executor), workers=workers,
                   scheduler=scheduler, inputs=[str(i) for i in inputs] + ([str(points)] if points else []),
                   options=options, progress=progress,
                   window_min_pixels=None if window_min_mp is None else int(round(window_min_mp * 1e6)))


def make_ortho(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
               dsm: str | PathLike[str], outdir: str | Path, *, heads: str | Sequence[str] | None = None,
               head_mosaics: str | Sequence[str] | None = None, crs: str | None = None,
               area: Sequence[float] | None = None, resolution: float | None = None, max_off_nadir: float = 60.0,
               feather: float | None = None, balance: bool = True, square: bool = True, tile_cells: int = 2048,
               executor: str = "auto",
               workers: int | None = None, scheduler: str | None = None, inputs: Sequence[str | PathLike[str]] = (),
               progress: Progress = None, spell: Callable[[str], str] = cli_spelling, surface: str = "dsm") -> Any:
    """True orthomosaic of oriented images on a DSM into ``outdir`` (:func:`skyrig.pipeline.ortho.run_ortho`):
    the main mosaic from the images of ``heads`` (all by default), and one mosaic per name in ``head_mosaics``.
    ``square``: buildings extracted from the DSM get square edges in the surface the images are projected on, their
    walls first moved onto the roof outline seen in steep images (:func:`skyrig.dense.ortho.square_buildings`).
    ``surface="dtm"``: ``dsm`` is a DTM COG (``skyrig terrain dtm``'s ``dtm.tif``) and the result a classic
    orthophoto on the bare earth (no buildings to square or to hide ground: they lean as in a classic ortho); a
    file tagged as a DSM (``SKYRIG_PRODUCT=dsm``) is refused.

    Raises :class:`skyrig.dense.ortho.EmptyMosaicError` (a failed run) when no cell can be coloured."""
    from skyrig.dense.ortho import OrthoConfig
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.inputs import head_rows
    from skyrig.pipeline.ortho import load_dsm_for, run_ortho

    main = np.arange(len(eo))
    if heads:
        _, rows = head_rows(eo, heads)
        main = np.unique(np.concatenate(rows)) if rows else main[:0]
        if len(main) == 0:
            raise OptionError(spell("heads"), f"{_text(heads)}: no image of the EO file matches")
    sets: dict[str, np.ndarray] = {}
    if head_mosaics:
        names, rows = head_rows(eo, head_mosaics)
        empty = [n for n, r in zip(names, rows) if len(r) == 0]
        if empty:
            raise OptionError(spell("head_mosaics"), f"no image matches {', '.join(empty)}")
        sets = dict(zip(names, rows))
    _positive(resolution, "resolution", spell)
    _positive(feather, "feather", spell)
    _positive(tile_cells, "tile_cells", spell, "at least 64 cells", 64)
    if not 0 < max_off_nadir < 89:
        raise OptionError(spell("max_off_nadir"), f"must be between 0 and 89 degrees, got {max_off_nadir}")
    # one orientation list: the main mosaic's images first, then those only the head mosaics use
    used = np.unique(np.concatenate([main, *sets.values()])) if sets else main
    order = np.concatenate([main, np.setdiff1d(used, main)])
    pos = {int(r): k for k, r in enumerate(order)}
    eo_all = eo.subset(order)
    if surface not in ("dsm", "dtm"):
        raise OptionError(spell("surface"), f"must be dsm or dtm, got {surface!r}")
    if surface == "dtm":
        _refuse_dsm_as_dtm(dsm, spell)
        square = False  # a DTM has no buildings
    grid = load_dsm_for(dsm, crs)
    paths = find_images(eo_all, [str(p) for p in images])
    cfg = OrthoConfig(cell_m=resolution, max_off_nadir_deg=max_off_nadir, feather_m=feather, balance=balance,
                      tile_cells=tile_cells, square_buildings=square, square_refine=square)
    options = {"dsm": str(dsm), "crs": grid.frame.crs, "heads": _text(heads), "head_mosaics": _text(head_mosaics),
               "area": None if area is None else [float(a) for a in area], "resolution": resolution,
               "max_off_nadir": max_off_nadir, "feather": feather, "balance": balance, "square": square,
               "tile_cells": tile_cells, "surface": surface}
    return run_ortho(eo_all, cameras, paths, grid, outdir, area=tuple(area) if area else None, config=cfg,
                     main_rows=np.arange(len(main)),
                     head_sets={h: [pos[int(r)] for r in rows] for h, rows in sets.items()} or None,
                     executor=_executor_kind(executor), workers=workers, scheduler=scheduler,
                     inputs=[*map(str, inputs), str(dsm)], options=options, progress=progress)


def _refuse_dsm_as_dtm(path: str | PathLike[str], spell: Callable[[str], str]) -> None:
    """A classic orthophoto needs the bare earth: a raster that skyrig wrote as a DSM (its bands) or an nDSM (its
    tag) is refused; any other height raster is taken as the user's DTM."""
    import rasterio

    from skyrig.errors import InputFormatError

    try:
        with rasterio.open(path) as ds:
            product = ds.tags().get("SKYRIG_PRODUCT", "")
            if not product and "support" in ds.descriptions:  # skyrig dsm's bands (height, support, spread, ...)
                product = "dsm"
    except Exception as exc:  # not a raster
        raise InputFormatError(f"cannot read the DTM ({exc})", path, field=spell("dtm")) from None
    if product and product != "dtm":
        raise InputFormatError(f"the file is a {product.upper()}, not a DTM: a classic orthophoto is projected onto "
                               "the bare earth (skyrig terrain dtm)", path, field=spell("dtm"))


def make_facades(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
                 dsm: str | PathLike[str], outdir: str | Path, *, heads: str | Sequence[str] | None = None,
                 footprints: str | PathLike[str] | None = None, ortho: str | PathLike[str] | None = None,
                 texel: float | None = None, max_images: int = 3, texture_format: str = "png", refine: bool = True,
                 extend_dsm: Sequence[str | PathLike[str]] = (), feet: bool = True,
                 inputs: Sequence[str | PathLike[str]] = (), progress: Progress = None,
                 spell: Callable[[str], str] = cli_spelling, footprint_layer: str | None = None,
                 footprint_eave: str | None = None, footprint_ridge: str | None = None,
                 footprint_heights: str = "above-ground", footprint_mode: str = "replace",
                 refine_footprints: bool = False) -> Any:
    """Buildings, façade textures and a textured 3D model into ``outdir``
    (:func:`skyrig.pipeline.facades.run_facades`).

    ``extend_dsm``: DSMs beyond the DSM's surveyed area (e.g. ``skyrig dsm --heads left`` and ``--heads right``:
    the obliques' own stereo coverage) for the buildings the obliques see there; ``feet``: walls moved onto their
    foot as the obliques show it (after ``refine``).  ``footprint_eave`` / ``footprint_ridge``: attributes of the
    footprints with their eave / ridge heights in metres (``footprint_heights``: ``above-ground`` or ``absolute``,
    the DSM's vertical reference), used where the DSM has no heights; ``footprint_mode``: ``replace`` (the
    footprints are the buildings) or ``complete`` (the DSM's buildings completed by the footprints it misses);
    ``refine_footprints``: their walls moved onto their feet as the obliques show them.

    Raises :class:`skyrig.pipeline.facades.NoBuildingsError` (a failed run) when the DSM holds no building."""
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.facades import run_facades
    from skyrig.pipeline.inputs import select_heads

    if footprint_heights not in ("above-ground", "absolute"):
        raise OptionError(spell("footprint_heights"),
                          f"unknown reference {footprint_heights!r} (above-ground, absolute)")
    if footprint_mode not in ("replace", "complete"):
        raise OptionError(spell("footprint_mode"), f"unknown mode {footprint_mode!r} (replace, complete)")
    if footprints is None:
        for name, val in (("footprint_layer", footprint_layer), ("footprint_eave", footprint_eave),
                          ("footprint_ridge", footprint_ridge), ("refine_footprints", refine_footprints)):
            if val:
                raise OptionError(spell(name), f"needs {spell('footprints')}")
    if footprint_ridge and not footprint_eave:
        raise OptionError(spell("footprint_ridge"), f"needs {spell('footprint_eave')} too")
    _positive(texel, "texel", spell)
    _positive(max_images, "max_images", spell, "at least 1", 1)
    if texture_format not in ("png", "jpeg"):
        raise OptionError(spell("texture_format"), f"unknown format {texture_format!r} (png, jpeg)")
    eo = select_heads(eo, heads, spell("heads"))
    paths = find_images(eo, [str(p) for p in images])
    for p in extend_dsm:
        if not Path(p).is_file():
            raise OptionError(spell("extend_dsm"), f"file not found: {p}")
    extra = [str(p) for p in (footprints, ortho, *extend_dsm) if p]
    options = {"heads": _text(heads), "footprints": None if footprints is None else str(footprints),
               "ortho": None if ortho is None else str(ortho), "texel": texel, "max_images": max_images,
               "texture_format": texture_format, "refine": refine, "extend_dsm": [str(p) for p in extend_dsm],
               "feet": feet}
    if footprints is not None:
        options.update({"footprint_layer": footprint_layer, "footprint_eave": footprint_eave,
                        "footprint_ridge": footprint_ridge, "footprint_heights": footprint_heights,
                        "footprint_mode": footprint_mode, "refine_footprints": refine_footprints})
    return run_facades(eo, cameras, paths, str(dsm), outdir, footprints=footprints, ortho=ortho, texel_m=texel,
                       max_images=max_images, image_format=texture_format, refine=refine, feet=feet,
                       extend_dsms=[str(p) for p in extend_dsm],
                       inputs=[str(dsm), *map(str, inputs), *extra], options=options, progress=progress,
                       footprint_layer=footprint_layer, eave_field=footprint_eave, ridge_field=footprint_ridge,
                       height_reference="ground" if footprint_heights == "above-ground" else "absolute",
                       footprint_mode=footprint_mode, refine_footprints=refine_footprints)


def plane_in_local_frame(eo: ExteriorOrientations, height: float | None = None,
                         plane: Sequence[float] | None = None, spell: Callable[[str], str] = cli_spelling) -> tuple[Any, Any]:
    """A mosaic plane given in the orientations' frame, as ``(local ENU frame, Plane in it)``.

    ``height``: the horizontal plane at this height (the EO's heights), under the mean projection centre; in the
    local frame it is the plane tangent to the ellipsoid there (off by d^2 / 2R from the level surface: 8 cm at
    1 km).  ``plane``: ``X Y Z NX NY NZ``, a point of the plane and its normal, both in the EO's frame (for a map CRS
    the normal's components are easting, northing, up; they are carried through ECEF, so meridian convergence and
    the projection's scale do not turn it).  The plane's axes: ``u`` east and ``v`` north for a (near) horizontal
    plane, else ``u`` horizontal along the plane and ``v`` up the plane, seen from the side the normal points to.
    """
    from skyrig.dense.plane_mosaic import Plane
    from skyrig.geodesy.frame import WorldFrame as Frame
    from skyrig.geodesy.crs import ecef_to_geodetic

    if (height is None) == (plane is None):
        raise OptionError(spell("height"), f"give the plane either as a height or as {spell('plane')} X Y Z NX NY NZ")
    if plane is not None:
        vals = np.asarray(plane, dtype=np.float64).reshape(-1)
        if vals.shape != (6,) or not np.all(np.isfinite(vals)) or np.linalg.norm(vals[3:]) == 0:
            raise OptionError(spell("plane"), "expected X Y Z NX NY NZ: a point and a non-zero normal")
        point, normal = vals[:3], vals[3:] / np.linalg.norm(vals[3:])
    else:
        if not np.isfinite(height):
            raise OptionError(spell("height"), f"must be a finite height in metres, got {height}")
        point = np.r_[eo.centre[:, :2].mean(axis=0), float(height)]
        normal = None
    p_ecef = eo.frame.to_ecef(point[None])[0]
    lat, lon, h = ecef_to_geodetic(p_ecef[None])
    local = Frame.local(float(lat[0]), float(lon[0]), float(h[0]))
    if normal is None:
        n = np.array([0.0, 0.0, 1.0])
    else:
        step = 10.0
        tip = local.from_ecef(eo.frame.to_ecef((point + step * normal)[None]))[0]
        base = local.from_ecef(p_ecef[None])[0]
        n = (tip - base) / np.linalg.norm(tip - base)
    up = np.array([0.0, 0.0, 1.0])
    if abs(n @ up) > 0.99:
        return local, Plane(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    u = np.cross(up, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return local, Plane(np.zeros(3), u, v / np.linalg.norm(v))


def make_plane_mosaic(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera],
                      images: Sequence[str | PathLike[str]], outdir: str | Path, *, height: float | None = None,
                      plane: Sequence[float] | None = None, heads: str | Sequence[str] | None = None,
                      resolution: float | None = None, window: int = 64, max_cells: int = 16_000_000,
                      inputs: Sequence[str | PathLike[str]] = (), spell: Callable[[str], str] = cli_spelling) -> dict:
    """The images projected onto one plane from their orientations alone, and the feature offsets across every
    seam (paper 000, Fig. 9; :mod:`skyrig.dense.plane_mosaic`), into ``outdir``: ``mosaic.png`` (RGBA, transparent
    where no image sees the plane), ``seams.csv`` (one row per seam: images, windows, median shift in mosaic
    pixels and metres), ``plane_mosaic.json`` (plane, grid, per-image GSD, seam statistics), ``manifest.json``.

    A seam's offset is the difference of its two images' orientation errors projected on the plane (plus the
    relief off the plane for images from different centres): the check of a tumbling head's boresight curve.
    Returns the summary written to ``plane_mosaic.json``.
    """
    import csv
    import json

    import cv2

    from skyrig.dense.plane_mosaic import plane_mosaic, seam_offsets
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.pipeline.dense import ImageFiles, find_images
    from skyrig.pipeline.inputs import select_heads

    eo = select_heads(eo, heads, spell("heads"))
    _positive(resolution, "resolution", spell)
    if window < 8:
        raise OptionError(spell("window"), f"must be at least 8 mosaic pixels, got {window}")
    local, pl = plane_in_local_frame(eo, height, plane, spell)
    eo_local = eo.to_frame(local)
    paths = find_images(eo, [str(p) for p in images])
    from skyrig.pipeline.inputs import require_cameras

    require_cameras(eo, cameras, spell("camera"))
    loader = ImageFiles(paths, [(cameras[str(c)].width, cameras[str(c)].height) for c in eo.camera])
    index = {str(n): k for k, n in enumerate(eo.image)}
    m = plane_mosaic(lambda name: loader(index[name]), eo_local, cameras, pl, cell_m=resolution, max_cells=max_cells)
    seams = seam_offsets(m, window_px=window)
    cell = m.grid.cell_m
    rows = []
    for sm in seams:
        if not len(sm.shift_px):
            continue
        d = sm.median_shift_px
        rows.append({"a": str(m.images[sm.a]), "b": str(m.images[sm.b]), "windows": int(len(sm.shift_px)),
                     "seam_cells": int(sm.seam_cells), "shift_col_px": float(d[0]), "shift_row_px": float(d[1]),
                     "offset_px": sm.offset_px, "offset_m": sm.offset_px * cell,
                     "response": float(np.median(sm.response))})
    off = np.array([r["offset_px"] for r in rows])
    covered = m.source >= 0
    summary = {
        "frame": eo.frame.to_text(), "plane_frame": local.to_text(),
        "plane": {"point": [float(x) for x in (plane[:3] if plane is not None else
                                              [*eo.centre[:, :2].mean(axis=0), height])],
                  "normal_local": pl.normal.tolist(), "u_local": pl.u_axis.tolist(), "v_local": pl.v_axis.tolist()},
        "grid": {"u0": m.grid.u0, "v0": m.grid.v0, "cell_m": cell, "rows": int(m.grid.shape[0]),
                 "cols": int(m.grid.shape[1])},
        "images": [{"image": str(n), "gsd_m": float(g), "cells": int(np.sum(m.source == k))}
                   for k, (n, g) in enumerate(zip(m.images, m.gsd_m))],
        "covered": float(covered.mean()),
        "seams": len(seams), "seams_measured": len(rows), "window_px": int(window),
        "max_offset_px": float(off.max()) if off.size else None,
        "median_offset_px": float(np.median(off)) if off.size else None,
        "rms_offset_px": float(np.sqrt(np.mean(off ** 2))) if off.size else None,
    }
    options = {"height": height, "plane": None if plane is None else [float(x) for x in plane],
               "heads": _text(heads), "resolution": resolution, "window": int(window)}
    with stage_folder(Path(outdir), stage="plane-mosaic", inputs=describe_inputs([*map(str, inputs)]),
                      options=options) as tmp:
        rgba = np.dstack([m.rgb[..., ::-1], np.where(covered, 255, 0).astype(np.uint8)])
        if not cv2.imwrite(str(tmp / "mosaic.png"), rgba):
            raise OSError(f"cannot write {tmp / 'mosaic.png'}")
        cols = ["a", "b", "windows", "seam_cells", "shift_col_px", "shift_row_px", "offset_px", "offset_m", "response"]
        with open(tmp / "seams.csv", "w", newline="") as fh:  # csv quotes image names holding commas
            w = csv.writer(fh)
            w.writerow(cols)
            w.writerows([f"{r[c]:.4f}" if isinstance(r[c], float) else r[c] for c in cols] for r in rows)
        (tmp / "plane_mosaic.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def _text(spec: str | Sequence[str] | None) -> str | None:
    """A head list as the comma text the manifests record (None when empty)."""
    if not spec:
        return None
    return spec if isinstance(spec, str) else ",".join(spec)
