"""Correction grids of the image coordinates as unknowns of the adjustment, with their collocation prior.

A correction grid of a camera (paper 004: the image deformation a penta camera's heads carry beyond their
interior orientation) is a field over the image format, bilinear between nodes ``x_px (nx,)`` by ``y_px (ny,)``
pixels, with a value ``(ny, nx, 2)`` px per node: the systematic error of an image coordinate, observed minus
true.  The image factor (:mod:`skyrig.adjust.factors.image`) adds the grid, interpolated at the *measured*
pixel, to the projection of every observation of the camera: ``computed = project(X) + g(x_observed)``; its
Jacobian with respect to the node values is the four bilinear weights of the observation's cell (constant).

With ``image_grid="weighted"`` (:class:`~skyrig.adjust.config.AdjustConfig`) the node values are unknowns of
the adjustment, estimated together with the interior orientation, the boresights and everything else, and the
grid's **prior** is this module's observation: the node values of each component ``g_c (m,)`` are zero-mean with
the covariance ``C (m, m)`` of the signal at the nodes (least-squares collocation's covariance function evaluated
at the node distances, :func:`skyrig.calibrate.calqc.collocation_prior`), a factor ``prior:image_grid:<camera>``
of two rows (x, y) of ``m`` whitened components ``U g_c`` with ``C^-1 = U^T U``.  The prior is what keeps the
grid from taking what the other unknowns explain (a principal distance makes a radial field at no cost, the grid
only at the cost of its prior), and what lets the grid take a deformation that the other unknowns would
otherwise absorb in part through the tie points (an oblique head's principal distance bending to a nadir wave):
estimated jointly, the deformation goes where the data and the prior put it.  ``"fixed"``: the grid's values are
applied as known corrections (no unknowns); ``"free"``: node values without a prior (a datum defect with the
interior orientation unless the nodes are few).

Data: ``block.observations["image_grid"]`` = :class:`ImageGrids` (a list of :class:`GridSpec`, one per
camera).  The estimated values come back in the adjusted block's ``observations["image_grid"]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.base import BlockError, Factor, whitening_matrices
from skyrig.adjust.factors.prior import PriorType
from skyrig.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State

__all__ = ["GridSpec", "ImageGrids", "ImageGridPrior", "bilinear_weights", "IMAGE_GRID"]


def bilinear_weights(xs: NDArray[np.float64], ys: NDArray[np.float64], pix: NDArray[np.float64]
                     ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Nodes and weights of bilinear interpolation at ``pix (N, 2)`` (column, row) px on the grid ``xs (nx,)``
    by ``ys (ny,)``: ``(N, 4)`` node indices (row-major, ``iy * nx + ix``) and ``(N, 4)`` weights (sum 1).
    Positions outside the format are clamped to its edge (the grid is constant beyond it).

    >>> idx, w = bilinear_weights(np.array([0.0, 10.0]), np.array([0.0, 10.0]), np.array([[2.5, 5.0]]))
    >>> idx.tolist(), w.round(3).tolist()
    ([[0, 1, 2, 3]], [[0.375, 0.125, 0.375, 0.125]])
    """
    nx, ny = len(xs), len(ys)
    x = np.clip(pix[:, 0], xs[0], xs[-1])
    y = np.clip(pix[:, 1], ys[0], ys[-1])
    i = np.clip(np.searchsorted(xs, x, side="right") - 1, 0, nx - 2)
    j = np.clip(np.searchsorted(ys, y, side="right") - 1, 0, ny - 2)
    tx = (x - xs[i]) / (xs[i + 1] - xs[i])
    ty = (y - ys[j]) / (ys[j + 1] - ys[j])
    idx = np.column_stack([j * nx + i, j * nx + i + 1, (j + 1) * nx + i, (j + 1) * nx + i + 1]).astype(np.int64)
    w = np.column_stack([(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty])
    return idx, w


@dataclass
class GridSpec:
    """The correction grid of one camera.

    Attributes
    ----------
    camera
        Name of the block's camera whose observations the grid corrects.
    x_px, y_px
        ``(nx,)`` and ``(ny,)`` node positions (pixels, increasing; at least 2 each).
    value_px
        ``(ny, nx, 2)`` node values (px, observed minus true): the start of the adjustment, or the known
        correction with ``image_grid="fixed"``.
    cov_px2
        ``(m, m)`` prior covariance of the node values of one component (``m = nx ny``, row-major nodes),
        the same for x and y; None = no prior (``image_grid="free"``).
    """

    camera: str
    x_px: NDArray[np.float64]
    y_px: NDArray[np.float64]
    value_px: NDArray[np.float64]
    cov_px2: NDArray[np.float64] | None = None

    @property
    def n_nodes(self) -> int:
        return len(self.x_px) * len(self.y_px)


@dataclass
class ImageGrids:
    """The correction grids of a block (``block.observations["image_grid"]``), one per camera at most."""

    grids: list[GridSpec] = field(default_factory=list)
    #: whitening factors ``U`` of the priors (``C^-1 = U^T U``), per grid (set by :meth:`normalise`)
    _whiten: list = field(default_factory=list, repr=False)

    def __len__(self) -> int:
        return len(self.grids)

    def normalise(self, block: "Block") -> None:
        out = []
        for g in self.grids:
            xs = np.asarray(g.x_px, float).reshape(-1)
            ys = np.asarray(g.y_px, float).reshape(-1)
            v = np.asarray(g.value_px, float)
            cv = None if g.cov_px2 is None else np.asarray(g.cov_px2, float)
            out.append(replace(g, camera=str(g.camera), x_px=xs, y_px=ys, value_px=v, cov_px2=cv))
        self.grids = out
        self._whiten = []

    def validate(self, block: "Block") -> None:
        names = [c.name for c in block.cameras]
        seen = set()
        for k, g in enumerate(self.grids):
            where = f"observations['image_grid'].grids[{k}] (camera {g.camera!r})"
            if g.camera not in names:
                raise BlockError(f"{where}: the block has no camera of that name (has {names})")
            if g.camera in seen:
                raise BlockError(f"{where}: a second grid for the same camera")
            seen.add(g.camera)
            for nm, a in (("x_px", g.x_px), ("y_px", g.y_px)):
                if len(a) < 2 or not np.all(np.isfinite(a)) or not np.all(np.diff(a) > 0):
                    raise BlockError(f"{where}: {nm} must hold at least 2 finite increasing node positions")
            m = g.n_nodes
            if g.value_px.shape != (len(g.y_px), len(g.x_px), 2) or not np.all(np.isfinite(g.value_px)):
                raise BlockError(f"{where}: value_px must be finite with shape ({len(g.y_px)}, {len(g.x_px)}, 2), "
                                 f"got {g.value_px.shape}")
            if g.cov_px2 is not None:
                cv = g.cov_px2
                if cv.shape != (m, m) or not np.all(np.isfinite(cv)) or not np.allclose(cv, cv.T, atol=0.0,
                                                                                         rtol=1e-9):
                    raise BlockError(f"{where}: cov_px2 must be a finite symmetric ({m}, {m}) matrix")
                if not np.linalg.eigvalsh(cv)[0] > 0:
                    raise BlockError(f"{where}: cov_px2 is not positive definite (add a nugget to the node "
                                     "covariance)")

    def whiten(self, k: int) -> NDArray[np.float64]:
        """``U (m, m)`` of grid ``k``'s prior, ``C^-1 = U^T U`` (cached)."""
        if not self._whiten:
            self._whiten = [None] * len(self.grids)
        if self._whiten[k] is None:
            self._whiten[k] = whitening_matrices(self.grids[k].cov_px2[None])[0]  # type: ignore[index]
        return self._whiten[k]

    def values(self) -> NDArray[np.float64]:
        """All node values flat (grid by grid, node by node, x then y): the state vector of the grids."""
        if not self.grids:
            return np.zeros(0)
        return np.concatenate([g.value_px.reshape(-1) for g in self.grids])

    def with_values(self, flat: NDArray[np.float64]) -> "ImageGrids":
        """A copy with the node values from a flat vector (:meth:`values` order)."""
        out, o = [], 0
        for g in self.grids:
            m2 = 2 * g.n_nodes
            out.append(replace(g, value_px=np.asarray(flat[o:o + m2], float).reshape(g.value_px.shape).copy()))
            o += m2
        return ImageGrids(out, list(self._whiten))

    def offsets(self) -> NDArray[np.int64]:
        """``(G + 1,)`` start of each grid in the flat vector."""
        return np.concatenate([[0], np.cumsum([2 * g.n_nodes for g in self.grids])]).astype(np.int64)


def grids_of(block: "Block") -> ImageGrids | None:
    """The block's correction grids, None when it has none."""
    d = block.observations.get("image_grid")
    return d if d is not None and len(d) else None


class ImageGridPrior(PriorType):
    """The collocation prior of the correction grids' node values (``image_grid="weighted"``)."""

    name = "image_grid"
    words = "correction-grid prior"
    order = 102.0

    def data(self, block: "Block") -> ImageGrids | None:
        return block.observations.get(self.name)

    def present(self, model: "Model") -> bool:
        return model.layout.grid is not None and model.config.unknowns.image_grid == "weighted"

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        d = grids_of(model.block)
        lay = model.layout
        if d is None or lay.grid is None or model.config.unknowns.image_grid != "weighted":
            return []
        off = d.offsets()
        out = []
        for k, g in enumerate(d.grids):
            if g.cov_px2 is None:
                raise ConfigError(f"image_grid is 'weighted' but the grid of camera {g.camera!r} has no cov_px2 "
                                 "(its prior covariance)")
            m = g.n_nodes
            cols = lay.grid[off[k]:off[k + 1]].reshape(m, 2).T  # (2, m): x columns, y columns
            if not (cols >= 0).any():
                continue
            U = d.whiten(k)
            vals = s.grid[off[k]:off[k + 1]].reshape(m, 2).T  # type: ignore[index]
            r = vals @ U.T  # (2, m): U g_c per component
            sig = np.broadcast_to(np.sqrt(np.diag(g.cov_px2)), (2, m)).copy()
            Wm = np.broadcast_to(U, (2, m, m)).copy()
            f = Factor(f"prior:image_grid:{g.camera}", r, sig, weight=np.ones(2), whiten=Wm)
            if jac:
                f.jc, f.cols = Wm.copy(), np.ascontiguousarray(cols)
            out.append(f)
        return out

    def label(self, block: "Block", i: int) -> str:
        return f"correction-grid prior {'xy'[i % 2]}"


IMAGE_GRID = register(ImageGridPrior())
