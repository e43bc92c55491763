"""The dense stage's products written tile by tile: the stage process never holds the whole grid or cloud.

:class:`StreamedDsm` takes the ground tiles' results as the executor hands them over
(:meth:`skyrig.pipeline.executor.Executor.completed`, in any order) and writes each out at once: its grid layers
(:data:`skyrig.dense.surface.TILE_LAYERS`) into a scratch GeoTIFF, its cloud points into a scratch file of its own.
:meth:`StreamedDsm.finish` then confirms (and fills) the cells window by window, each window read with the cells
around it that the confirmation looks at (:func:`skyrig.dense.surface.confirm_reach`), into the DSM's bands;
:meth:`StreamedDsm.publish` copies them into the COG, shades the hillshade window by window and writes the cloud
tile after tile into one LAZ.  The products hold what :func:`skyrig.dense.surface.assemble` and the whole-array
writers give (the same cells, the same points in the same order); memory is bounded by a tile (its result, the
window and its margin, GDAL's block cache), not by the block.  One exception: with hole filling
(``DenseConfig.fill_holes``, off by default) the height band is held whole for OpenCV's inpainting, whose values
depend on the whole rim of a hole (inpainting windows with 60 cells of margin changed filled heights by up to
2.9 m on a test grid): 4 bytes a cell.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.grid import DenseCloud
from skyrig.dense.surface import (TILE_LAYERS, DensePlan, DenseStats, TileResult, TileTally, confirm_reach,
                                  confirm_window, dsm_metadata, fill_holes, tile_layers,
                                  vertical_reference)

logger = logging.getLogger(__name__)

_COUNTS = {"support", "cand_support", "cand2_support"}


class StreamedDsm:
    """Tile results in, the DSM's bands, hillshade and cloud out, tile by tile (module docstring).

    ``scratch``: an empty folder for the scratch files (the caller removes it)."""

    def __init__(self, plan: DensePlan, scratch: Path) -> None:
        from skyrig.io.dsm_cog import DSM_BANDS, WindowedBands

        self.plan = plan
        self.scratch = Path(scratch)
        self.vref = vertical_reference(plan.out_frame)
        self._raw = WindowedBands(self.scratch / "layers.tif", plan.grid, plan.out_frame,
                                  [(n, "") for n in TILE_LAYERS])
        self._final = WindowedBands(self.scratch / "dsm.tif", plan.grid, plan.out_frame,
                                    [(n, _unit(n)) for n in DSM_BANDS], vertical_reference=self.vref,
                                    metadata=dsm_metadata(plan))
        self.tally = TileTally()
        self._clouds: dict[int, int] = {}  # tile -> points in its scratch file
        self._lo = np.full(3, np.inf)
        self._hi = np.full(3, -np.inf)
        self.cells_valid = 0
        self.sigma_median: float | None = None
        self.support_median: float | None = None

    # -- tiles in ---------------------------------------------------------------------------------------------------

    def add(self, k: int, r: TileResult) -> None:
        """Tile ``k``'s result written out (any order); the caller drops it."""
        r0, c0, _, _ = r.window
        self._raw.write(r0, c0, tile_layers(r))
        if self.plan.config.cloud and r.cloud is not None and len(r.cloud[0]):
            xyz = np.asarray(r.cloud[0], np.float64)
            self._lo = np.minimum(self._lo, xyz.min(axis=0))
            self._hi = np.maximum(self._hi, xyz.max(axis=0))
            xyz_, rgb, normal, support, sigma = r.cloud
            np.savez(self.scratch / f"cloud-{k:06d}.npz", xyz=xyz_, rgb=rgb, normal=normal, support=support,
                     sigma=sigma)
            self._clouds[k] = len(xyz)
        self.tally.add(r)

    @property
    def cloud_points(self) -> int:
        return sum(self._clouds.values())

    def stats(self) -> DenseStats:
        return self.tally.stats(self.plan)

    # -- the grid ---------------------------------------------------------------------------------------------------

    def finish(self) -> None:
        """Confirm (and fill) every window into the DSM's bands; :attr:`cells_valid`, :attr:`sigma_median` and
        :attr:`support_median` (as ``nanmedian(sigma)`` and ``median(support[valid])`` of the whole grid)."""
        from skyrig.io.dsm_cog import WindowedBands

        plan, cfg = self.plan, self.plan.config
        fill = bool(cfg.fill_holes)
        target = self._final
        if fill:  # the filling looks at confirmed cells around its window: those go to a scratch file first
            target = WindowedBands(self.scratch / "confirmed.tif", plan.grid, plan.out_frame,
                                   [(n, "") for n in ("height", "support", "spread", "sigma")])
        sigmas, supports = _Kth(), np.zeros(65536, np.int64)
        try:
            for r0, c0, h, w in plan.tiles:
                (a0, b0, a1, b1) = _around(plan, r0, c0, h, w, confirm_reach(cfg))
                layers = [self._raw.read(n, a0, b0, a1 - a0, b1 - b0) for n in TILE_LAYERS]
                layers = [a.astype(np.int16) if n in _COUNTS else a for n, a in zip(TILE_LAYERS, layers)]
                hgt, sup, spr, sg = confirm_window(layers, (r0 - a0, c0 - b0, h, w), plan.grid.cell_m, cfg)
                del layers
                if fill:
                    target.write(r0, c0, [hgt, sup, spr, sg])
                    continue
                self._count(hgt, sup, sg, sigmas, supports)
                target.write(r0, c0, [hgt, sup, spr, sg, np.zeros(hgt.shape, bool)])
            if fill:  # OpenCV's inpainting of a hole depends on all of its rim: the one band held whole
                zf, filled = fill_holes(target.read("height", 0, 0, *plan.grid.shape), cfg.fill_max_cells)
                for r0, c0, h, w in plan.tiles:
                    sl = (slice(r0, r0 + h), slice(c0, c0 + w))
                    n_sup, spr, sg = (target.read(n, r0, c0, h, w) for n in ("support", "spread", "sigma"))
                    self._count(zf[sl], n_sup.astype(np.int16), sg, sigmas, supports)
                    self._final.write(r0, c0, [zf[sl], n_sup, spr, sg, filled[sl]])
                del zf, filled
        finally:
            if fill:
                target.close()
        self.support_median = _median_of_counts(supports)
        if sigmas.n:  # the exact middle values: a second look at the sigmas, in their histogram's bins
            sigmas.refine(self._final.read("sigma", r0, c0, h, w) for r0, c0, h, w in plan.tiles)
            self.sigma_median = sigmas.median()

    def _count(self, hgt: NDArray, sup: NDArray, sg: NDArray, sigmas: "_Kth", supports: NDArray) -> None:
        valid = np.isfinite(hgt)
        self.cells_valid += int(valid.sum())
        supports += np.bincount(sup[valid].astype(np.int64) + 32768, minlength=65536)
        sigmas.count(sg[np.isfinite(sg)])

    # -- products ---------------------------------------------------------------------------------------------------

    def publish(self, dsm: Path, hillshade: Path, cloud: Path | None) -> int:
        """The DSM as a COG, its hillshade, and (``cloud`` given) the cloud as LAZ; returns the cloud's points."""
        from skyrig.io.dense_laz import write_dense_cloud_chunks
        from skyrig.io.dsm_cog import write_hillshade_png_windows

        self._final.publish(dsm)
        write_hillshade_png_windows(hillshade, self._final, self.scratch / "hillshade.tif",
                                    window_cells=self.plan.config.tile_cells)
        if cloud is None or not self._clouds:
            return 0
        return write_dense_cloud_chunks(cloud, self._cloud_pieces(), self.plan.out_frame, self.vref, self._lo,
                                        self._hi)

    def _cloud_pieces(self) -> Iterator[DenseCloud]:
        for k in sorted(self._clouds):  # tile order, as assemble concatenates them
            with np.load(self.scratch / f"cloud-{k:06d}.npz") as z:
                yield DenseCloud(z["xyz"], z["rgb"], z["normal"], z["support"], z["sigma"], self.plan.out_frame,
                                 self.vref)

    def close(self) -> None:
        self._raw.close()
        self._final.close()

    def __enter__(self) -> "StreamedDsm":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _unit(name: str) -> str:
    return "metre" if name in ("height", "spread", "sigma") else ""


def _around(plan: DensePlan, r0: int, c0: int, h: int, w: int, reach: int) -> tuple[int, int, int, int]:
    """The window widened by ``reach`` cells on every side, clipped to the grid: ``(row0, col0, row1, col1)``."""
    rows, cols = plan.grid.shape
    return max(r0 - reach, 0), max(c0 - reach, 0), min(r0 + h + reach, rows), min(c0 + w + reach, cols)


def _median_of_counts(hist: NDArray[np.int64]) -> float | None:
    """``np.median`` of int16 values given as a histogram (bin ``v + 32768``)."""
    n = int(hist.sum())
    if n == 0:
        return None
    cum = np.cumsum(hist)
    mid = [int(np.searchsorted(cum, k, side="right")) - 32768 for k in ((n - 1) // 2, n // 2)]
    return float(np.median(np.array(mid if n % 2 == 0 else mid[:1], np.int16)))


class _Kth:
    """The exact median of float32 values seen in pieces, in two looks: a histogram of the upper 16 bits of their
    order-preserving keys (:meth:`count`), then, for the bins that hold the middle ranks, of the lower 16 bits
    (:meth:`refine`).  Memory: the histograms, whatever the number of values."""

    def __init__(self) -> None:
        self.hist = np.zeros(65536, np.int64)
        self.n = 0
        self._bins: list[tuple[int, int]] = []  # per middle rank: (bin, rank within the bin)
        self._fine: dict[int, NDArray[np.int64]] = {}

    @staticmethod
    def _keys(v: NDArray) -> NDArray[np.uint32]:
        bits = np.ascontiguousarray(v, np.float32).view(np.uint32).ravel()
        return np.where(bits & np.uint32(0x80000000), ~bits, bits | np.uint32(0x80000000)).astype(np.uint32)

    def count(self, v: NDArray) -> None:
        k = self._keys(v)
        self.hist += np.bincount(k >> 16, minlength=65536)
        self.n += k.size

    def refine(self, pieces) -> None:
        cum = np.cumsum(self.hist)
        for rank in ((self.n - 1) // 2, self.n // 2):
            b = int(np.searchsorted(cum, rank, side="right"))
            self._bins.append((b, rank - (int(cum[b - 1]) if b else 0)))
        self._fine = {b: np.zeros(65536, np.int64) for b, _ in self._bins}
        for v in pieces:
            k = self._keys(v[np.isfinite(v)])
            for b, fine in self._fine.items():
                fine += np.bincount(k[(k >> 16) == b] & 0xFFFF, minlength=65536)

    def median(self) -> float:
        vals = []
        for b, r in self._bins:
            low = int(np.searchsorted(np.cumsum(self._fine[b]), r, side="right"))
            key = np.uint32((b << 16) | low)
            bits = key & np.uint32(0x7FFFFFFF) if key & np.uint32(0x80000000) else ~key
            vals.append(np.array([bits], np.uint32).view(np.float32)[0])
        return float(np.median(np.array(vals if self.n % 2 == 0 else vals[:1], np.float32)))
