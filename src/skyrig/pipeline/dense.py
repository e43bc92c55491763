"""The dense stage over files: oriented images in, a DSM (COG), a dense cloud (LAZ), a hillshade and a report out.

``run_dsm`` checks the inputs (every oriented image exists, is readable and has its camera's size), plans the
work with :func:`skyrig.dense.surface.plan_dense`, runs the ground tiles through
:class:`skyrig.pipeline.executor.Executor` (serial, local worker processes or a ``dask.distributed``
scheduler), writes each tile's result out as it completes (:mod:`skyrig.pipeline.dense_stream`: the stage holds a
tile, never the block) and publishes the output folder as a set (:func:`skyrig.io.stage.stage_folder`): nothing is
half-written, the manifest comes last.
"""

from __future__ import annotations

import json
import logging
import shutil
import tempfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Mapping, Sequence

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.dense.surface import DenseConfig, DenseStats, _TileJob, plan_dense
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame

if TYPE_CHECKING:
    from skyrig.dense.rectify import WindowedImage

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


#: percentiles of the pooled samples that map to 0 and 255 when 16-bit images are scaled to 8 bit
LEVEL_PERCENTILES = (0.1, 99.9)


def sixteen_bit_levels(paths: Sequence[str], max_images: int = 12, samples_per_image: int = 65536
                       ) -> tuple[float, float] | None:
    """The grey levels that 16-bit images are scaled by to 8 bit (``lo -> 0``, ``hi -> 255``), one pair for the
    whole block, or None when no image is 16 bit.

    Aerial cameras often deliver 12 or 14 bits in 16-bit TIFFs; OpenCV's own conversion (a shift by 8 bits) turns
    them nearly black, and SGM, the orthomosaic and the textures would run on a few grey levels.  One linear scale
    for all images and channels keeps their radiometry comparable (a per-image stretch would give every image its
    own gain: seams in the mosaic, and a cost offset between the images of a stereo pair).  ``lo``, ``hi``: the
    :data:`LEVEL_PERCENTILES` (rounded down / up to whole numbers) of the pooled samples (every channel) of up to
    ``max_images`` 16-bit images taken evenly through the block, each sampled on a regular grid of about
    ``samples_per_image`` pixels.  The images' sample types are read from their headers (rasterio / GDAL); JPEGs are
    8 bit.

    Raises
    ------
    InputFormatError
        An image whose header cannot be read, a sample type other than 8 or 16 bit unsigned, or 16-bit images
        without contrast (``hi <= lo``).
    """
    with _no_georef_warning():  # camera images carry no georeference
        return _sixteen_bit_levels(paths, max_images, samples_per_image)


@contextmanager
def _no_georef_warning() -> Iterator[None]:
    """rasterio's warning that a file has no georeference, silenced (camera images have none)."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        yield


def _sixteen_bit_levels(paths: Sequence[str], max_images: int, samples_per_image: int) -> tuple[float, float] | None:
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.errors import RasterioIOError

    wide: list[str] = []
    for p in paths:
        if Path(p).suffix.lower() in (".jpg", ".jpeg"):
            continue
        try:
            with rasterio.open(p) as ds:
                dt = ds.dtypes[0]
        except RasterioIOError as exc:
            raise InputFormatError(f"cannot read the image header: {exc}", p) from None
        if dt == "uint16":
            wide.append(str(p))
        elif dt != "uint8":
            raise InputFormatError(f"unsupported sample type {dt} (8 or 16 bit unsigned expected)", p)
    if not wide:
        return None
    pick = [wide[int(k)] for k in np.unique(np.linspace(0, len(wide) - 1, min(max_images, len(wide))).round())]
    pooled = []
    for p in pick:
        with rasterio.open(p) as ds:
            step = max(1, int(np.sqrt(ds.width * ds.height / samples_per_image)))
            bands = list(range(1, min(ds.count, 3) + 1))
            a = ds.read(bands, out_shape=(len(bands), max(1, ds.height // step), max(1, ds.width // step)),
                        resampling=Resampling.nearest)
        pooled.append(a.reshape(-1))
    lo, hi = np.percentile(np.concatenate(pooled), LEVEL_PERCENTILES)
    lo, hi = np.floor(lo), np.ceil(hi)
    if not hi > lo:
        raise InputFormatError(f"16-bit images without contrast (levels {lo:.0f} .. {hi:.0f} in {len(pick)} "
                               "sampled images)", pick[0])
    logger.info("16-bit images (%d of %d): scaled to 8 bit by the levels %.0f .. %.0f (the %g / %g %% percentiles "
                "of %d images)", len(wide), len(paths), lo, hi, *LEVEL_PERCENTILES, len(pick))
    return float(lo), float(hi)


class ImageFiles:
    """Picklable image loader for the tiles: ``loader(i)`` reads image ``i`` as RGB uint8 and checks its size.

    16-bit images (TIFF, PNG) are scaled to 8 bit by one pair of levels for the whole loader
    (:func:`sixteen_bit_levels`, worked out once when the loader is made, unless ``levels`` is given), never by
    OpenCV's shift by 8 bits; :attr:`levels` is None when every image is 8 bit.  :meth:`subset` keeps the levels."""

    #: TIFFs of at least this many pixels are read window by window by the dense chain (:meth:`windowed_image`)
    WINDOW_MIN_PIXELS = 60_000_000

    def __init__(self, paths: Sequence[str], sizes: Sequence[tuple[int, int]],
                 levels: tuple[float, float] | None | str = "auto", window_min_pixels: int | None = None) -> None:
        self.paths = [str(p) for p in paths]
        self.sizes = [tuple(s) for s in sizes]
        self.window_min_pixels = self.WINDOW_MIN_PIXELS if window_min_pixels is None else int(window_min_pixels)
        if len(self.paths) != len(self.sizes):
            raise SkyrigError(f"{len(self.paths)} image files for {len(self.sizes)} image sizes")
        if isinstance(levels, str):
            if levels != "auto":
                raise SkyrigError(f"levels must be 'auto', None or (lo, hi), not {levels!r}")
            levels = sixteen_bit_levels(self.paths)
        self.levels = None if levels is None else (float(levels[0]), float(levels[1]))

    def subset(self, rows: Sequence[int]) -> "ImageFiles":
        """The loader of images ``rows`` (in that order), with this loader's levels."""
        return ImageFiles([self.paths[i] for i in rows], [self.sizes[i] for i in rows], self.levels,
                          self.window_min_pixels)

    def windowed_image(self, i: int, grey: bool = False) -> WindowedImage | None:
        """Image ``i`` to be read window by window (RGB, or grey with ``grey``), or None when it is read whole: a
        TIFF of at least ``window_min_pixels`` pixels (a large-format aerial frame: 100-450 MP, 0.3-1.4 GB in RGB
        each, of which a block of the dense chain samples a few megapixels) that is not palette-coded.  The windows
        hold the values the whole image has there (the same levels; tested bit for bit on uncompressed and deflate
        TIFFs; GDAL decodes them instead of OpenCV)."""
        from skyrig.dense.rectify import WindowedImage

        w, h = self.sizes[i]
        if w * h < self.window_min_pixels or Path(self.paths[i]).suffix.lower() not in (".tif", ".tiff"):
            return None
        bands = self._window_bands(i)
        if bands is None:
            return None
        return WindowedImage(w, h, 1 if grey else 3, partial(self._read_window, i, grey, bands))

    def _size_error(self, i: int, w: int, h: int) -> InputFormatError:
        return InputFormatError(f"image is {w} x {h} px but its camera is {self.sizes[i][0]} x {self.sizes[i][1]} px "
                                "(wrong camera, a resized copy, or an EXIF orientation tag that rotates it)",
                                self.paths[i])

    def _window_bands(self, i: int) -> list[int] | None:
        """Bands to read (RGB or grey), None when the file is not read in windows (palette-coded)."""
        import rasterio
        from rasterio.enums import ColorInterp

        p = self.paths[i]
        with _no_georef_warning(), rasterio.open(p) as ds:
            if (ds.width, ds.height) != self.sizes[i]:
                raise self._size_error(i, ds.width, ds.height)
            if ds.colorinterp and ds.colorinterp[0] == ColorInterp.palette:
                return None
            return [1, 2, 3] if ds.count >= 3 else [1]

    def _read_window(self, i: int, grey: bool, bands: list[int], c0: int, r0: int, c1: int, r1: int) -> np.ndarray:
        import cv2
        import rasterio
        from rasterio.windows import Window

        with _no_georef_warning(), rasterio.open(self.paths[i]) as ds:
            a = ds.read(bands, window=Window(c0, r0, c1 - c0, r1 - r0))
        img = np.ascontiguousarray(np.moveaxis(a, 0, -1) if len(bands) == 3 else a[0])
        img = self._to_8bit(img, i)
        if grey:
            return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        return img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)

    def _to_8bit(self, img: np.ndarray, i: int) -> np.ndarray:
        """An 8 or 16-bit image (any channels) in 8 bit: 16 bit scaled by the block's levels."""
        import cv2

        if img.dtype == np.uint16:
            if self.levels is None:
                raise InputFormatError("16-bit image in a block whose levels were worked out as all 8 bit (the file "
                                       "changed since?)", self.paths[i])
            lo, hi = self.levels  # whole numbers: the subtraction is exact in 16 bits (saturating at 0)
            return cv2.convertScaleAbs(cv2.subtract(img, (lo, lo, lo, 0.0)), alpha=255.0 / (hi - lo))
        if img.dtype != np.uint8:
            raise InputFormatError(f"unsupported sample type {img.dtype} (8 or 16 bit expected)", self.paths[i])
        return img

    def __call__(self, i: int) -> np.ndarray:
        import cv2

        img = cv2.imread(self.paths[i], cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise InputFormatError("cannot read the image (missing, truncated or not an image)", self.paths[i])
        h, w = img.shape[:2]
        if (w, h) != self.sizes[i]:
            raise self._size_error(i, w, h)
        return cv2.cvtColor(self._to_8bit(img, i), cv2.COLOR_BGR2RGB)


def find_images(eo: ExteriorOrientations, images: Sequence[str]) -> list[str]:
    """The file of every oriented image, from folders and/or files.

    Raises
    ------
    InputFormatError
        When an oriented image has no file, or a file given explicitly has no orientation.
    """
    by_name: dict[str, str] = {}
    explicit: list[Path] = []
    for entry in images:
        p = Path(entry)
        if p.is_dir():
            for f in sorted(p.iterdir()):
                if f.suffix.lower() in IMAGE_SUFFIXES:
                    by_name.setdefault(f.name, str(f))
        elif p.is_file():
            by_name[p.name] = str(p)
            explicit.append(p)
        else:
            raise InputFormatError("no such image or folder", p, field="images")
    names = set(eo.image.tolist())
    stray = [str(p) for p in explicit if p.name not in names]
    if stray:
        raise InputFormatError(f"{len(stray)} image(s) given have no orientation in the EO file: "
                               + ", ".join(stray[:5]) + (" ..." if len(stray) > 5 else ""), stray[0], field="images")
    missing = [n for n in eo.image if n not in by_name]
    if missing:
        raise InputFormatError(f"{len(missing)} oriented image(s) not found among the images given: "
                               + ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else ""), field="images")
    unused = len(set(by_name) - names)
    if unused:
        logger.info("%d image file(s) have no orientation and are not used", unused)
    return [by_name[n] for n in eo.image]


def height_range_from_points(xyz_heights: np.ndarray, margin_m: float = 5.0) -> tuple[float, float]:
    """Expected surface heights from sparse points (e.g. an adjustment's tie points): 0.5-99.5 percentiles,
    widened by 10 % of their span and ``margin_m``."""
    h = np.asarray(xyz_heights, float)
    h = h[np.isfinite(h)]
    if len(h) < 3:
        raise SkyrigError("fewer than 3 points with heights: cannot derive the height range (option: height-range)")
    lo, hi = np.percentile(h, [0.5, 99.5])
    pad = 0.1 * (hi - lo) + margin_m
    return float(lo - pad), float(hi + pad)


@dataclass
class DsmOutputs:
    """Where :func:`run_dsm` put things, and its counts."""

    outdir: Path
    dsm: Path
    cloud: Path | None
    hillshade: Path
    report: Path
    stats: DenseStats
    summary: dict


def run_dsm(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], image_paths: Sequence[str],
            out_frame: WorldFrame, height_range: tuple[float, float], outdir: str | Path, *,
            area: tuple[float, float, float, float] | None = None, config: DenseConfig = DenseConfig(),
            executor: str = "auto", workers: int | None = None, scheduler: str | None = None,
            inputs: Sequence[str] = (), options: dict | None = None,
            progress: Callable[[int, int], None] | None = None, window_min_pixels: int | None = None) -> DsmOutputs:
    """Dense matching of oriented images into ``outdir`` (``dsm.tif``, ``cloud.laz``, ``dsm_hillshade.png``,
    ``dense.json``, ``manifest.json``).

    ``executor``: ``"serial"``, ``"local"`` (Dask worker processes), ``"scheduler"`` (with ``scheduler``), or
    ``"auto"`` (serial for one tile, local processes otherwise).  ``window_min_pixels``: TIFFs of at least this many
    pixels are read window by window (:meth:`ImageFiles.windowed_image`; None: its default)."""
    from skyrig.io.stage import describe_inputs, stage_folder
    from skyrig.pipeline.dense_stream import StreamedDsm
    from skyrig.pipeline.executor import Executor

    from skyrig.pipeline.inputs import require_cameras

    require_cameras(eo, cameras)
    loader = ImageFiles(image_paths, [(cameras[str(c)].width, cameras[str(c)].height) for c in eo.camera],
                        window_min_pixels=window_min_pixels)
    plan = plan_dense(eo, cameras, out_frame, height_range, area, config)
    logger.info("dense: %d pairs, %d tiles of %d x %d cells (%.3f m), GSD %.3f m, images matched at scale %g",
                len(plan.pairs), len(plan.tiles), plan.grid.width, plan.grid.height, plan.grid.cell_m, plan.gsd_m,
                0.5 ** plan.image_level)
    kind = executor
    if kind == "auto":
        kind = "scheduler" if scheduler else ("serial" if len(plan.tiles) == 1 else "local")
    job = _TileJob(plan, loader)
    out = Path(outdir)
    out.parent.mkdir(parents=True, exist_ok=True)
    for stale in out.parent.glob(f".{out.name}.scratch-*"):  # what a killed run into the same folder left
        shutil.rmtree(stale, ignore_errors=True)
    # every tile's result is written out as it comes (StreamedDsm): the stage holds one tile, never the block
    with tempfile.TemporaryDirectory(prefix=f".{out.name}.scratch-", dir=out.parent) as scratch, \
            StreamedDsm(plan, Path(scratch)) as streamed:
        with Executor(kind, workers=workers, scheduler=scheduler) as ex:
            for k, r in ex.completed(job, list(range(len(plan.tiles))), desc="dense tiles", progress=progress):
                streamed.add(k, r)
                del r
        stats = streamed.stats()
        streamed.finish()
        if not streamed.cells_valid:
            raise SkyrigError("dense matching found no surface: no cell has a height confirmed by two stereo pairs "
                              "(check the orientations, the height range and the image overlap)")
        n_cloud = streamed.cloud_points if config.cloud else 0
        summary = {
            "pairs": [{"left": str(plan.eo.image[p.left]), "right": str(plan.eo.image[p.right]),
                       "overlap": round(p.overlap, 3), "base_height": round(p.base_height, 3),
                       "intersection_deg": round(p.intersection_deg, 2)} for p in plan.pairs],
            "grid": {"x0": plan.grid.x0, "y0": plan.grid.y0, "cell_m": plan.grid.cell_m, "width": plan.grid.width,
                     "height": plan.grid.height},
            "frame": out_frame.to_text(),
            "vertical_reference": streamed.vref,
            "height_range": list(height_range),
            "cells_valid": streamed.cells_valid, "cells": plan.grid.width * plan.grid.height,
            "height_sigma_median_m": streamed.sigma_median,
            "support_median": streamed.support_median,
            "cloud_points": n_cloud,
            "stats": asdict(stats),
            "config": json.loads(json.dumps(asdict(config), default=str)),
            "executor": kind,
            "image_levels_16bit": None if loader.levels is None else list(loader.levels),
        }
        with stage_folder(out, stage="dsm", inputs=describe_inputs(list(inputs)), options=options or {}) as tmp:
            streamed.publish(tmp / "dsm.tif", tmp / "dsm_hillshade.png", tmp / "cloud.laz" if n_cloud else None)
            (tmp / "dense.json").write_text(json.dumps(summary, indent=1) + "\n")
    cloud = n_cloud > 0
    return DsmOutputs(out, out / "dsm.tif", out / "cloud.laz" if cloud else None,
                      out / "dsm_hillshade.png", out / "dense.json", stats, summary)
