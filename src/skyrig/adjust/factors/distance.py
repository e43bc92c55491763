"""Distances between two object points (scale bars, paper 004's close-range test field).

Data (:class:`DistanceRows` in ``block.observations['distance']``;
the Block's keywords): ``distance_point (D, 2)`` point indices, ``distance_m (D,)`` observed distances
and ``distance_sigma_m (D,)`` m.  Residual ``|X_a - X_b| - d``, one row each.  A distance couples two
points, which the Schur elimination of points cannot: its end points are estimated among the reduced
unknowns (``Layout.rpoint``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.base import (
    BlockError,
    Factor,
    ObservationType,
    check_finite,
    check_index,
    check_positive,
    rows_of,
    sigma_rows,
)

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State


@dataclass
class DistanceRows:
    """Distances between two object points (scale bars): the rows of the ``distance`` type (``block.observations['distance']``; the block's keywords
    ``distance_*`` route here).

    Attributes
    ----------
    point
        ``(D, 2)`` point indices.
    m
        ``(D,)`` observed distances, m.
    sigma_m
        ``(D,)`` sigma, m.
    """

    point: NDArray[np.int64]
    m: NDArray[np.float64]
    sigma_m: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.point)


class Distance(ObservationType):
    name = "distance"
    words = "distance"
    components = ("d",)
    units = "m"
    order = 40.0
    sigma_field = "sigma_m"
    rows = DistanceRows
    keywords = (('distance_point', 'point', None), ('distance_m', 'm', None), ('distance_sigma_m', 'sigma_m', 0.001))

    def data(self, block: "Block") -> DistanceRows:
        return block.observations[self.name]

    def count(self, block: "Block") -> int:
        return block.n_distances

    def normalise(self, block: "Block") -> None:
        d = self.data(block)
        if d.point is None:
            d.point = np.zeros((0, 2), np.int64)
            d.m = np.zeros(0)
        nd = len(np.asarray(d.point).reshape(-1, 2))
        d.point = rows_of(d.point, (2,), np.int64, nd)
        d.m = rows_of(d.m, (), n=nd)
        d.sigma_m = sigma_rows(d.sigma_m, nd, None)

    def validate(self, block: "Block") -> None:
        d = self.data(block)
        check_positive("distance_sigma_m", d.sigma_m)
        check_index("distance_point", d.point.reshape(-1), block.n_points, "point")
        check_finite("distance_m", d.m)
        bad = np.flatnonzero(~(d.m > 0))
        if bad.size:
            raise BlockError(f"distance_m[{bad[0]}] must be > 0, got {d.m[bad[0]]}")
        bad = np.flatnonzero(d.point[:, 0] == d.point[:, 1])
        if bad.size:
            raise BlockError(f"distance {bad[0]} joins point "
                             f"{str(block.point_name[d.point[bad[0], 0]])!r} to itself")

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = self.data(b)
        a, c = d.point[:, 0], d.point[:, 1]
        dx = s.X[a] - s.X[c]
        L = np.linalg.norm(dx, axis=1)
        sig = d.sigma_m[:, None]
        f = Factor(self.name, ((L - d.m) / sig[:, 0])[:, None], sig,
                   weight=model.weights[self.name])
        if not jac:
            return [f]
        u = dx / np.where(L > 0, L, 1.0)[:, None]
        rp = lay.rpoint if lay.rpoint is not None else np.full((b.n_points, 3), -1, np.int64)
        f.jc = (np.concatenate([u, -u], axis=1) / sig)[:, None, :]
        f.cols = np.concatenate([rp[a], rp[c]], axis=1)
        return [f]

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        lay, b = model.layout, model.block
        d = self.data(b)
        rp_on = np.asarray((lay.rpoint_cols >= 0).any(axis=1), dtype=bool)
        return np.asarray(rp_on[d.point].any(axis=1), dtype=bool)

    def label(self, block: "Block", i: int) -> str:
        d = self.data(block)
        a, b = d.point[i]
        return f"distance {block.point_name[a]} - {block.point_name[b]}"


DISTANCE = register(Distance())
