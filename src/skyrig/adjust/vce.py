"""Variance component estimation: choosing the a-priori sigma of observation groups from the data.

Förstner's iterative estimate: for a group ``g`` (or a set of its axes) with whitened residuals
``z_i`` (``v_i / sigma_i``, or ``W v`` for rows with a full covariance, ``W^T W = Σ^-1``) and
redundancy numbers ``r_i`` (sum over all rows = n - u)::

    s_g^2 = sum_g z_i^2 / sum_g r_i          sigma_i <- sigma_i * s_g     (Σ_i <- s_g^2 Σ_i)

repeated until every factor ``s_g`` is within ``tolerance`` of 1.  At convergence each group's
a-posteriori variance factor is 1: the weights are those the block's own residuals support.  The
estimate needs redundancy in the group (a group with ``sum r_i`` below ``min_redundancy`` is left as
given) and assumes the functional model is right: a systematic model error shows up as an inflated
variance of the group that absorbs it.

Full covariances
----------------
Where a group carries full covariances (``Block.obs_cov_px2``, ``control_cov_m2``, ``gnss_cov_m2``,
``imu_cov_rad2``) the covariance rows are what is scaled (and the per-axis sigmas, ``sqrt(diag)``, with
them), so the correlations stay as given:

* a component made of a set of axes (e.g. horizontal ``(0, 1)`` and vertical ``(2,)`` of GNSS) scales
  the diagonal block ``Σ[axes, axes]`` by ``s^2``.  This is exact when no row correlates axes of
  different sets (``Σ`` block diagonal with respect to the split): the whitened components of a set
  then depend on that set's axes only;
* when some row of the group does correlate axes of different sets (a general 3x3 GNSS covariance),
  a horizontal / vertical split has no meaning: the group's sets are **merged into one component**
  over all its axes, one factor scales the whole covariance ``Σ <- s^2 Σ``, and
  :attr:`VarianceComponents.notes` says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import AdjustmentResult, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.factors import observation_types, require_type
from skyrig.adjust.model import whitening_matrices
from skyrig.errors import ConfigError

__all__ = ["VarianceComponents", "estimate_variance_components", "DEFAULT_SPLIT"]

def _vce_types() -> dict:
    """The observation types whose variance components can be estimated (those with a ``vce_split``)."""
    return {t.name: t for t in observation_types() if t.vce_split is not None}


#: default axis sets (each type's ``vce_split``): one component for image x/y, horizontal vs vertical for
#: GNSS and control, one for the three IMU angles
DEFAULT_SPLIT: Mapping[str, tuple[tuple[int, ...], ...]] = {n: t.vce_split for n, t in _vce_types().items()}


@dataclass
class VarianceComponents:
    """Outcome of :func:`estimate_variance_components`.

    Attributes
    ----------
    block
        The block with re-scaled sigmas and covariances (a copy).
    result
        The adjustment at the final weights.
    sigma
        Final a-priori sigma per component ``{"gnss[0, 1]": value, ...}`` (the first row's value; units
        of the group: px, m, rad).
    variance_factor
        Per component the total factor by which the given variances (and covariance blocks) were
        multiplied: the estimated variance of unit weight of the component relative to the input
        (4 means the given sigmas were 2x too small).
    history
        Per iteration the factors ``s_g`` (sigma ratios) of every component.
    converged
        All factors within tolerance of 1.
    notes
        What was done differently from the requested split (components merged because full
        covariances correlate their axes).
    """

    block: Block
    result: AdjustmentResult
    sigma: dict[str, float]
    history: list[dict[str, float]] = field(default_factory=list)
    converged: bool = False
    variance_factor: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _separable(cov: NDArray[np.float64], sets: Sequence[Sequence[int]], rtol: float = 1e-12) -> bool:
    """True when no covariance row correlates axes of different sets (axes in no set form one more set)."""
    d = cov.shape[1]
    label = np.full(d, -1)
    for k, axes in enumerate(sets):
        label[list(axes)] = k
    cross = label[:, None] != label[None, :]
    if not cross.any() or len(cov) == 0:
        return True
    sd = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    scale = sd[:, :, None] * sd[:, None, :]
    return bool((np.abs(cov[:, cross]) <= rtol * scale[:, cross]).all())


def _components(block: Block, split: Mapping[str, Sequence[Sequence[int]]]
                ) -> tuple[dict[str, list[list[int]]], list[str]]:
    """Effective axis sets per group (merged where full covariances correlate the requested sets)."""
    out: dict[str, list[list[int]]] = {}
    notes: list[str] = []
    for g, sets in split.items():
        types = _vce_types()
        if g not in types:
            raise ConfigError(f"unknown observation group {g!r} in split; known: {sorted(types)}")
        sets_l = [sorted(int(a) for a in axes) for axes in sets]
        cov = types[g].get_cov(block)
        if cov is not None and len(sets_l) > 1 and not _separable(cov, sets_l):
            d = cov.shape[1]
            notes.append(f"{g}: the full covariances correlate axes of different components "
                         f"{', '.join(map(str, sets_l))}; one variance factor scales the whole {d}x{d} "
                         f"covariance (component {g}{list(range(d))})")
            sets_l = [list(range(d))]
        out[g] = sets_l
    return out, notes


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
        Block with a-priori sigmas or covariances (starting values of the iteration; only their
        ratios and correlations within a component are kept).
    config
        Adjustment configuration (``statistics`` must be on: redundancy numbers are needed).
    split
        Axis sets per group (default :data:`DEFAULT_SPLIT`); groups absent from the block are skipped.
        For a group with full covariances that correlate axes of different sets the sets are merged
        (see the module docstring and ``notes`` of the result).
    max_iterations, tolerance
        Stop after this many adjustments or when every ``|s_g - 1| < tolerance``.
    min_redundancy
        Components with less total redundancy keep their sigma.
    callback
        ``callback(iteration, factors)`` after each adjustment.
    """
    cfg = config or AdjustConfig()
    if not cfg.statistics.compute:
        raise ConfigError("variance component estimation needs statistics=True (redundancy numbers)")
    split = DEFAULT_SPLIT if split is None else split
    b = block.copy()
    comps, notes = _components(b, split)
    total: dict[str, float] = {}
    history: list[dict[str, float]] = []
    converged = False
    res = None
    for it in range(1, max_iterations + 1):
        res = adjust(b, cfg)
        factors: dict[str, float] = {}
        for g, sets in comps.items():
            gr = res.residuals.get(g)
            if gr is None or gr.redundancy is None or len(gr.residual) == 0:
                continue
            t = require_type(g)
            sig = t.get_sigma(b)
            cov = t.get_cov(b)
            act = gr.weight > 0
            if cov is None:
                z = gr.residual / sig
            else:  # the rows the adjustment used: W v with W^T W = cov^-1
                z = np.einsum("nij,nj->ni", whitening_matrices(cov), gr.residual)
            z2 = z**2
            new = sig.copy()
            new_cov = None if cov is None else cov.copy()
            for ax in sets:
                red = float(gr.redundancy[act][:, ax].sum())
                if red < min_redundancy:
                    continue
                s = float(np.sqrt(z2[act][:, ax].sum() / red))
                key = f"{g}{ax}"
                factors[key] = s
                total[key] = total.get(key, 1.0) * s * s
                new[:, ax] = sig[:, ax] * s
                if new_cov is not None:
                    new_cov[:, np.array(ax)[:, None], np.array(ax)[None, :]] *= s * s
            t.set_sigma(b, new)
            if new_cov is not None:
                t.set_cov(b, new_cov)
                t.set_sigma(b, np.sqrt(np.diagonal(new_cov, axis1=1, axis2=2)).copy())
        history.append(factors)
        if callback is not None:
            callback(it, factors)
        if all(abs(v - 1.0) < tolerance for v in factors.values()):
            converged = True
            break
    if not converged:  # the weights were changed after the last adjustment
        res = adjust(b, cfg)
    if res is None:
        raise ConfigError(f"max_iterations must be >= 1, got {max_iterations}")
    sigma = {}
    for g, sets in comps.items():
        sig = require_type(g).get_sigma(b)
        if len(sig):
            for ax in sets:
                sigma[f"{g}{ax}"] = float(sig[0, ax[0]])
    return VarianceComponents(b, res, sigma, history, converged, total, notes)
