"""Ground coordinates of control points (and check points, compared but not used).

Data (:class:`ControlRows` in ``block.observations['control']``;
the Block's keywords): ``control_point (K,)`` point indices, ``control_xyz (K, 3)`` m, ``control_sigma
(K, 3)`` m per axis, ``control_check (K,)`` True for a check point (weight 0) and optional
``control_cov_m2 (K, 3, 3)`` m².  Residual ``X[point] - xyz`` with the identity Jacobian on the point
(eliminated, or among the reduced columns for the end points of distances).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.base import (
    Factor,
    ObservationType,
    check_covariance,
    check_finite,
    check_index,
    check_positive,
    indexed_rows,
    whitening_matrices,
)

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State


@dataclass
class ControlRows:
    """Ground coordinates of control (and check) points: the rows of the ``control`` type (``block.observations['control']``; the block's keywords
    ``control_*`` route here).

    Attributes
    ----------
    point
        ``(K,)`` point index.
    xyz
        ``(K, 3)`` coordinates, m.
    sigma
        ``(K, 3)`` sigma per axis, m.
    check
        ``(K,)`` True for a check point (compared, not used).
    cov_m2
        optional ``(K, 3, 3)`` covariance, m².
    """

    point: NDArray[np.int64]
    xyz: NDArray[np.float64]
    sigma: NDArray[np.float64]
    check: NDArray[np.bool_]
    cov_m2: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.point)


class Control(ObservationType):
    name = "control"
    words = "control-point"
    components = ("X", "Y", "Z")
    units = "m"
    order = 10.0
    hints = (("datum_shift", "a datum difference between GNSS and control (or control in another CRS / "
                             "height reference)"),)
    datum_words = "control points"
    vce_split = ((0, 1), (2,))
    sigma_field = "sigma"
    cov_field = "cov_m2"
    rows = ControlRows
    keywords = (('control_point', 'point', None), ('control_xyz', 'xyz', None), ('control_sigma', 'sigma', 0.01), ('control_check', 'check', None), ('control_cov_m2', 'cov_m2', None))

    def data(self, block: "Block") -> ControlRows:
        return block.observations[self.name]

    def count(self, block: "Block") -> int:
        return len(self.data(block).point)

    def tested_count(self, block: "Block") -> int:
        return int((~self.data(block).check).sum())

    def normalise(self, block: "Block") -> None:
        d = self.data(block)
        k = indexed_rows(d, "point", "xyz", (3,), "sigma", "cov_m2", "control_cov_m2")
        d.check = np.zeros(k, bool) if d.check is None else np.asarray(d.check, dtype=bool).reshape(k)

    def validate(self, block: "Block") -> None:
        d = self.data(block)
        check_index("control_point", d.point, block.n_points, "point")
        check_finite("control_xyz", d.xyz)
        check_finite("control_sigma", d.sigma)
        check_positive("control_sigma", d.sigma)
        check_covariance("control_cov_m2", d.cov_m2)

    def controlled_points(self, block: "Block") -> NDArray[np.bool_]:
        d = self.data(block)
        out = np.zeros(block.n_points, bool)
        out[d.point[~d.check]] = True
        return out

    def initial_weight(self, block: "Block") -> NDArray[np.float64]:
        d = self.data(block)
        w = np.ones(self.count(block))
        w[d.check] = 0.0
        return w

    def fixes_datum(self, model: "Model") -> bool:
        return bool((model.weights[self.name] > 0).any())

    def prepare(self, model: "Model") -> NDArray[np.float64] | None:
        b = model.block
        d = self.data(b)
        return None if d.cov_m2 is None else whitening_matrices(d.cov_m2)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = self.data(b)
        p = d.point
        sig = d.sigma
        Wm = model.cache[self.name]
        if Wm is None:
            r = (s.X[p] - d.xyz) / sig
            J = np.zeros((len(p), 3, 3))
            J[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sig
        else:
            r = np.einsum("nij,nj->ni", Wm, s.X[p] - d.xyz)
            J = Wm
        f = Factor(self.name, r, sig, weight=model.weights[self.name], whiten=Wm)
        if jac and lay.n_p:
            f.point = lay.point[p]
            f.jp = J
        if jac and lay.has_rpoint:
            f.jc = J
            f.cols = lay.rpoint_cols[p]
        return [f]

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        return model.estimated_points()[self.data(model.block).point]

    def label(self, block: "Block", i: int) -> str:
        return f"control point {block.point_name[self.data(block).point[i]]}"


CONTROL = register(Control())
