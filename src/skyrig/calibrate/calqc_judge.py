"""Judging a ``calqc`` calibration against a simulation's truth: errors whitened by the calibration's joint
covariance, and the share within k sigma.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.stats import sidak_z
from skyrig.calibrate.calqc_simulation import ScenarioTruth

__all__ = ["normalised_errors", "within_sigma_summary"]


def normalised_errors(cal: Any, truth: ScenarioTruth) -> tuple[dict[str, float], NDArray[np.float64]]:
    """A simulation's calibration errors (``cal``: a :class:`~skyrig.calibrate.calqc.CalqcCalibration`) against its
    truth (:func:`midas_calqc_scenario`): per parameter
    ``(estimate - truth) / sigma`` (every head's boresight rx, ry, rz and IO, the datum shift X, Y, Z), and the same
    errors whitened by their joint covariance (``L^-1 e`` with ``L L^T`` the covariance of all of them, in the order
    of :attr:`CalqcCalibration.covariance_labels`): for honest sigmas and correlations the latter are independent
    N(0, 1) values, so their pooled distribution tests the covariance itself, while the per-parameter values of
    one run are correlated with each other."""
    z: dict[str, float] = {}
    for h, (v, cov) in cal.boresight.items():
        for a, x in zip(("rx", "ry", "rz"), (v - truth.boresight_rotvec_rad[h]) / np.sqrt(np.diag(cov))):
            z[f"boresight {h} {a}"] = float(x)
    for h, (names, v, cov) in cal.interior.items():
        tv = np.array([truth.intrinsics[h][n] for n in names])
        for n, x in zip(names, (v - tv) / np.sqrt(np.diag(cov))):
            z[f"IO {h} {n}"] = float(x)
    for a, x in zip("XYZ", (cal.datum_shift_m - truth.datum_shift_m) / np.sqrt(np.diag(cal.datum_shift_cov_m2))):
        z[f"datum shift {a}"] = float(x)
    if cal.covariance is None:
        raise ValueError("normalised_errors: the calibration carries no joint covariance")
    e, keep = [], []
    head_of_cam = {h.camera.name: h.name for h in cal.rig_in}
    for k, (g, o, c) in enumerate(cal.covariance_labels):
        if g == "boresight":
            i = ("rx", "ry", "rz").index(c)
            e.append(cal.boresight[o][0][i] - truth.boresight_rotvec_rad[o][i])
        elif g == "intrinsics":
            names, v, _ = cal.interior[head_of_cam[o]]
            e.append(v[list(names).index(c)] - truth.intrinsics[head_of_cam[o]][c])
        elif g == "datum_shift":
            i = "XYZ".index(c)
            e.append(cal.datum_shift_m[i] - truth.datum_shift_m[i])
        else:
            continue
        keep.append(k)
    cv = np.asarray(cal.covariance)[np.ix_(keep, keep)]
    return z, np.linalg.solve(np.linalg.cholesky(cv), np.asarray(e, float))


def within_sigma_summary(z: Sequence[float] | NDArray[np.float64], k: float = 2.0,
                         level: float = 0.95) -> dict[str, Any]:
    """How a set of normalised errors ``(estimate - truth) / sigma`` (a simulation's, where the truth is known)
    stands against two readings of "within ``k`` sigma": the literal count within ``k``, with the count expected of
    N(0, 1) values and the chance that all of them are (``0.954 ** 33 = 0.21`` for 33 parameters at 2 sigma); and
    the family-wise test, every ``|z|`` within the Sidak bound for that many parameters at ``level``
    (:func:`skyrig.adjust.stats.sidak_z`)."""
    from scipy.stats import norm

    a = np.abs(np.asarray(z, float).ravel())
    p1 = float(2.0 * norm.cdf(k) - 1.0)
    b = sidak_z(max(a.size, 1), level)
    return {"n": int(a.size), "k_sigma": float(k), "within_k": int(np.sum(a <= k)), "expected_within_k": a.size * p1,
            "probability_all_within_k": p1 ** a.size, "max_abs_z": float(a.max()) if a.size else 0.0,
            "family_wise_level": float(level), "family_wise_bound": b, "within_family_wise_bound": bool(np.all(a <= b))}
