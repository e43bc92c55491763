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
from skyrig.errors import OptionError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame

__all__ = ["make_dsm", "make_ortho", "make_facades", "cli_spelling"]

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


def make_dsm(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
             outdir: str | Path, *, crs: str | None = None, geoid: str | None = None,
             height_range: Sequence[float] | None = None, points: str | PathLike[str] | None = None,
             heads: str | Sequence[str] | None = None, area: Sequence[float] | None = None,
             resolution: float | None = None, mode: str = "sgbm", pairs_per_image: int = 6, min_support: int = 2,
             fill: bool = False, cloud: bool = True, min_depth: float | None = None, tile_cells: int = 2048,
             executor: str = "auto", workers: int | None = None, scheduler: str | None = None,
             inputs: Sequence[str | PathLike[str]] = (), progress: Progress = None,
             echo: Echo = lambda line: None, spell: Callable[[str], str] = cli_spelling) -> Any:
    """DSM (COG), dense cloud (LAZ), hillshade and summary of oriented images into ``outdir``
    (:func:`skyrig.pipeline.dense.run_dsm`).

    ``crs`` / ``geoid``: output CRS and geoid (default: the EO's map CRS and geoid).  ``height_range``: expected
    surface heights in the output heights; without it, derived from sparse ``points`` (e.g. an adjustment's
    points.csv).  ``heads``: only these rig heads / image-name parts.
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
        raise OptionError(spell("crs"), f"the EO file is in a {eo.frame.kind} frame: give the output CRS")
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
    _positive(min_support, "min_support", spell, "at least 1", 1)
    _positive(pairs_per_image, "pairs_per_image", spell, "at least 1", 1)
    _positive(tile_cells, "tile_cells", spell, "at least 64 cells", 64)
    if mode not in ("sgbm", "hh", "3way", "hh4"):
        raise OptionError(spell("mode"), f"unknown mode {mode!r} (sgbm, hh, 3way, hh4)")
    paths = find_images(eo, [str(p) for p in images])
    base = DenseConfig()
    cfg = DenseConfig(cell_m=resolution, pairs=replace(base.pairs, pairs_per_image=pairs_per_image),
                      sgm=replace(base.sgm, mode=mode), fusion=replace(base.fusion, min_support=min_support),
                      fill_holes=fill, cloud=cloud, tile_cells=tile_cells, min_depth_m=min_depth)
    heads_text = heads if heads is None or isinstance(heads, str) else ",".join(heads)
    options = {"crs": out_frame.crs, "geoid": out_frame.geoid, "height_range": [float(h) for h in height_range],
               "area": None if area is None else [float(a) for a in area], "resolution": resolution, "mode": mode,
               "pairs_per_image": pairs_per_image, "min_support": min_support, "fill": fill, "cloud": cloud,
               "tile_cells": tile_cells, "heads": heads_text or None, "min_depth": min_depth}
    return run_dsm(eo, cameras, paths, out_frame, (float(height_range[0]), float(height_range[1])), outdir,
                   area=tuple(area) if area else None, config=cfg, executor=_executor_kind(executor), workers=workers,
                   scheduler=scheduler, inputs=[str(i) for i in inputs] + ([str(points)] if points else []),
                   options=options, progress=progress)


def make_ortho(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
               dsm: str | PathLike[str], outdir: str | Path, *, heads: str | Sequence[str] | None = None,
               head_mosaics: str | Sequence[str] | None = None, crs: str | None = None,
               area: Sequence[float] | None = None, resolution: float | None = None, max_off_nadir: float = 60.0,
               feather: float | None = None, balance: bool = True, tile_cells: int = 2048, executor: str = "auto",
               workers: int | None = None, scheduler: str | None = None, inputs: Sequence[str | PathLike[str]] = (),
               progress: Progress = None, spell: Callable[[str], str] = cli_spelling) -> Any:
    """True orthomosaic of oriented images on a DSM into ``outdir`` (:func:`skyrig.pipeline.ortho.run_ortho`):
    the main mosaic from the images of ``heads`` (all by default), and one mosaic per name in ``head_mosaics``.

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
    grid = load_dsm_for(dsm, crs)
    paths = find_images(eo_all, [str(p) for p in images])
    cfg = OrthoConfig(cell_m=resolution, max_off_nadir_deg=max_off_nadir, feather_m=feather, balance=balance,
                      tile_cells=tile_cells)
    options = {"dsm": str(dsm), "crs": grid.frame.crs, "heads": _text(heads), "head_mosaics": _text(head_mosaics),
               "area": None if area is None else [float(a) for a in area], "resolution": resolution,
               "max_off_nadir": max_off_nadir, "feather": feather, "balance": balance, "tile_cells": tile_cells}
    return run_ortho(eo_all, cameras, paths, grid, outdir, area=tuple(area) if area else None, config=cfg,
                     main_rows=np.arange(len(main)),
                     head_sets={h: [pos[int(r)] for r in rows] for h, rows in sets.items()} or None,
                     executor=_executor_kind(executor), workers=workers, scheduler=scheduler,
                     inputs=[*map(str, inputs), str(dsm)], options=options, progress=progress)


def make_facades(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], images: Sequence[str | PathLike[str]],
                 dsm: str | PathLike[str], outdir: str | Path, *, heads: str | Sequence[str] | None = None,
                 footprints: str | PathLike[str] | None = None, ortho: str | PathLike[str] | None = None,
                 texel: float | None = None, max_images: int = 3, texture_format: str = "png", refine: bool = True,
                 inputs: Sequence[str | PathLike[str]] = (), progress: Progress = None,
                 spell: Callable[[str], str] = cli_spelling) -> Any:
    """Buildings, façade textures and a textured 3D model into ``outdir``
    (:func:`skyrig.pipeline.facades.run_facades`).

    Raises :class:`skyrig.pipeline.facades.NoBuildingsError` (a failed run) when the DSM holds no building."""
    from skyrig.pipeline.dense import find_images
    from skyrig.pipeline.facades import run_facades
    from skyrig.pipeline.inputs import select_heads

    _positive(texel, "texel", spell)
    _positive(max_images, "max_images", spell, "at least 1", 1)
    if texture_format not in ("png", "jpeg"):
        raise OptionError(spell("texture_format"), f"unknown format {texture_format!r} (png, jpeg)")
    eo = select_heads(eo, heads, spell("heads"))
    paths = find_images(eo, [str(p) for p in images])
    extra = [str(p) for p in (footprints, ortho) if p]
    options = {"heads": _text(heads), "footprints": None if footprints is None else str(footprints),
               "ortho": None if ortho is None else str(ortho), "texel": texel, "max_images": max_images,
               "texture_format": texture_format, "refine": refine}
    return run_facades(eo, cameras, paths, str(dsm), outdir, footprints=footprints, ortho=ortho, texel_m=texel,
                       max_images=max_images, image_format=texture_format, refine=refine,
                       inputs=[str(dsm), *map(str, inputs), *extra], options=options, progress=progress)


def _text(spec: str | Sequence[str] | None) -> str | None:
    """A head list as the comma text the manifests record (None when empty)."""
    if not spec:
        return None
    return spec if isinstance(spec, str) else ",".join(spec)
