"""Priors on the station poses (``poses="weighted"``: the starting pose observed with the configured sigma).

A prior row is ``(current - start) / sigma`` with the identity Jacobian over the group's columns (the
rotation part as the rotation vector ``log(R0^T R)``); its factor is named ``prior:<group>``.  Priors
are not tested by data snooping and are left out of the observations' cost in the report.
:func:`prior_factor` is shared with :mod:`skyrig.adjust.factors.calibration`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.base import Factor, ObservationType
from skyrig.geometry.rotations import rotvec_from_matrix

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State


def prior_factor(name: str, diff: NDArray, cols: NDArray, sigma: NDArray, jac: bool) -> Factor:
    """The factor ``prior:<name>``: rows ``diff (n, k)`` (or ``(k,)``) over ``sigma`` on columns ``cols``."""
    diff = diff.reshape(-1, cols.shape[-1]) if diff.ndim == 1 else diff
    cols2 = cols.reshape(diff.shape)
    sig = np.broadcast_to(sigma, diff.shape).astype(np.float64)
    f = Factor(f"prior:{name}", diff / sig, sig, weight=np.ones(len(diff)))
    if jac:
        k = diff.shape[1]
        j = np.zeros((len(diff), k, k))
        j[:, np.arange(k), np.arange(k)] = 1.0 / sig
        f.jc, f.cols = j, cols2
    return f


class PriorType(ObservationType):
    """Base of the prior types: no data in the block, no weights, not snooped, every row varies."""

    words = "prior"
    components = ()  # the prior's factor names its group: ``prior:<group>`` (units of that group)
    snooped = False
    share_checked = False

    def count(self, block: "Block") -> int:
        return 0

    def initial_weight(self, block: "Block") -> None:
        return None

    def present(self, model: "Model") -> bool:
        return True

    def label(self, block: "Block", i: int) -> str:
        return f"prior[{i}]"


class PosePrior(PriorType):
    name = "prior"
    order = 100.0

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        cfg, lay, s0 = model.config, model.layout, model.initial
        if cfg.unknowns.poses != "weighted":
            return []
        d = np.concatenate([s.C - s0.C, rotvec_from_matrix(np.swapaxes(s0.R, 1, 2) @ s.R)], axis=1)
        return [prior_factor("pose", d, lay.pose, np.array([cfg.unknowns.pose_sigma_m] * 3 + [cfg.unknowns.pose_sigma_rad] * 3), jac)]


POSE_PRIOR = register(PosePrior())
