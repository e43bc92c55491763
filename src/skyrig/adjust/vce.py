"""Variance component estimation: choosing the a-priori sigma of observation groups from the data.

Förstner's iterative estimate: for a group ``g`` (or a set of its axes) with whitened residuals
``v_i / sigma_i`` and redundancy numbers ``r_i`` (sum over all rows = n - u)::

    s_g^2 = sum_g (v_i / sigma_i)^2 / sum_g r_i          sigma_i <- sigma_i * s_g

repeated until every factor ``s_g`` is within ``tolerance`` of 1.  At convergence each group's
a-posteriori variance factor is 1: the weights are those the block's own residuals support.  The
estimate needs redundancy in the group (a group with ``sum r_i`` below ``min_redundancy`` is left as
given) and assumes the functional model is right: a systematic model error shows up as an inflated
variance of the group that absorbs it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from skyrig.adjust.adjust import AdjustmentResult, adjust
from skyrig.adjust.block import AdjustConfig, Block

__all__ = ["VarianceComponents", "estimate_variance_components", "DEFAULT_SPLIT"]

#: block attribute holding each group's sigma
_SIGMA_ATTR = {"image": "obs_sigma_px", "control": "control_sigma", "gnss": "gnss_sigma", "imu": "imu_sigma_rad"}

#: default axis sets: one component for image x/y, horizontal vs vertical for GNSS and control,
#: one for the three IMU angles
DEFAULT_SPLIT: Mapping[str, tuple[tuple[int, ...], ...]] = {
    "image": ((0, 1),),
    "control": ((0, 1), (2,)),
    "gnss": ((0, 1), (2,)),
    "imu": ((0, 1, 2),),
}


@dataclass
class VarianceComponents:
    """Outcome of :func:`estimate_variance_components`.

    Attributes
    ----------
    block
        The block with re-scaled sigmas (a copy).
    result
        The adjustment at the final weights.
    sigma
        Final a-priori sigma per component ``{"gnss[0, 1]": value, ...}`` (the first row's value; units
        of the group: px, m, rad).
    history
        Per iteration the factors ``s_g`` of every component.
    converged
        All factors within tolerance of 1.
    """

    block: Block
    result: AdjustmentResult
    sigma: dict[str, float]
    history: list[dict[str, float]] = field(default_factory=list)
    converged: bool = False


def estimate_variance_components(
    block: Block,
    config: AdjustConfig | None = None,
    split: Mapping[str, Sequence[Sequence[int]]] | None = None,
    max_iterations: int = 15,
    tolerance: float = 0.01,
    min_redundancy: float = 2.0,
    callback: Callable[[int, dict[str, float]], None] | None = None,
) -> VarianceComponents:
    """Iterate adjustment and re-weighting until the variance factor of every component is 1.

    Parameters
    ----------
    block
        Block with a-priori sigmas (starting values of the iteration; only their ratios within a
        component are kept).
    config
        Adjustment configuration (``statistics`` must be on: redundancy numbers are needed).
    split
        Axis sets per group (default :data:`DEFAULT_SPLIT`); groups absent from the block are skipped.
    max_iterations, tolerance
        Stop after this many adjustments or when every ``|s_g - 1| < tolerance``.
    min_redundancy
        Components with less total redundancy keep their sigma.
    callback
        ``callback(iteration, factors)`` after each adjustment.
    """
    cfg = config or AdjustConfig()
    if not cfg.statistics:
        raise ValueError("variance component estimation needs statistics=True (redundancy numbers)")
    split = DEFAULT_SPLIT if split is None else split
    b = block.copy()
    history: list[dict[str, float]] = []
    converged = False
    res = None
    for it in range(1, max_iterations + 1):
        res = adjust(b, cfg)
        factors: dict[str, float] = {}
        for g, sets in split.items():
            gr = res.residuals.get(g)
            if gr is None or gr.redundancy is None or len(gr.residual) == 0:
                continue
            sig = getattr(b, _SIGMA_ATTR[g])
            act = gr.weight > 0
            z2 = (gr.residual / sig) ** 2
            new = sig.copy()
            for axes in sets:
                ax = list(axes)
                red = float(gr.redundancy[act][:, ax].sum())
                if red < min_redundancy:
                    continue
                s = float(np.sqrt(z2[act][:, ax].sum() / red))
                factors[f"{g}{ax}"] = s
                new[:, ax] = sig[:, ax] * s
            setattr(b, _SIGMA_ATTR[g], new)
        history.append(factors)
        if callback is not None:
            callback(it, factors)
        if all(abs(v - 1.0) < tolerance for v in factors.values()):
            converged = True
            break
    if not converged:  # the weights were changed after the last adjustment
        res = adjust(b, cfg)
    assert res is not None
    sigma = {}
    for g, sets in split.items():
        sig = getattr(b, _SIGMA_ATTR[g])
        if len(sig):
            for axes in sets:
                sigma[f"{g}{list(axes)}"] = float(sig[0, list(axes)[0]])
    return VarianceComponents(b, res, sigma, history, converged)
