"""The boresight curve as a Fourier series in the actuator angle, and the repeating comparison error's share
(step 5 and the standard errors of the ``tumbling-head`` recipe, paper 000, 3.4; :mod:`skyrig.calibrate.tumbling`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import SkyrigError

__all__ = ["FourierCurve", "RepeatShare", "fit_fourier_curve", "fourier_design", "estimate_repeat_share",
           "default_max_order"]


def fourier_design(beta_rad: ArrayLike, order: int) -> NDArray[np.float64]:
    """``(n, 2 order + 1)`` design of a Fourier series in the actuator angle: ``1, cos b, sin b, ..., cos Nb,
    sin Nb``."""
    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    cols = [np.ones_like(b)]
    for j in range(1, int(order) + 1):
        cols += [np.cos(j * b), np.sin(j * b)]
    return np.column_stack(cols)


@dataclass(frozen=True)
class FourierCurve:
    """A boresight curve stated as a Fourier series in the actuator angle, with the covariance of its terms.

    The series is fitted by weighted least squares to the per-position mean curve (weights ``1 / sigma_k^2``,
    :attr:`TumblingCalibration.standard_error_rad`, positions independent), so its covariance is
    ``(A^T W A)^-1`` per axis, **not** scaled by the fit's variance factor: the per-position sigma already holds
    the variance estimated from these residuals (the repeating comparison error's share,
    :attr:`TumblingCalibration.repeat_share`, by REML at the order stated), so the variance factor is about 1 by
    construction there and scaling by it would count the residuals twice.  The sigmas are estimates, so a term's
    ``error / sigma`` is about Student-t with the degrees of freedom of :attr:`TumblingCalibration.standard_error_dof`
    (about the series' ``dof`` where the repeating part dominates); the bands below take the sigmas as exact.  The
    axes are fitted separately (the per-position correlations between axes are not used).

    Attributes
    ----------
    order
        Highest harmonic ``N``.
    coefficients_rad
        ``(2 N + 1, 3)`` terms ``[a_0, a_1, b_1, ..., a_N, b_N]`` per axis (radians): ``a_0 + sum_j a_j cos(j beta)
        + b_j sin(j beta)``.
    covariance_rad2
        ``(3, 2 N + 1, 2 N + 1)`` their covariance per axis (radians^2).
    variance_factor
        ``(3,)`` weighted residual square sum / ``dof`` (a diagnostic; about 1 if the series holds the curve and the
        per-position sigma is right, below 1 where the sigma is conservative (a share held at 1, the bound), above 1
        where the series misses harmonics).
    dof
        Redundancy of the fit (positions - terms).
    harmonic_chi2
        ``(N,)`` per harmonic the chi-square (6 degrees of freedom: cos and sin of three axes) of its terms against
        zero, from the fit at the order the selection started from; NaN where not computed.
    """

    order: int
    coefficients_rad: NDArray[np.float64]
    covariance_rad2: NDArray[np.float64]
    variance_factor: NDArray[np.float64]
    dof: int
    harmonic_chi2: NDArray[np.float64]

    def __call__(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(n, 3)`` the series at ``beta_rad`` (radians)."""
        return fourier_design(beta_rad, self.order) @ self.coefficients_rad

    def value_covariance(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(3, n, n)`` covariance of the series' values at ``beta_rad`` per axis (radians^2)."""
        a = fourier_design(beta_rad, self.order)
        return np.einsum("ik,akl,jl->aij", a, self.covariance_rad2, a)

    def sigma_rad(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``(n, 3)`` standard deviations of the series' values at ``beta_rad`` (radians)."""
        a = fourier_design(beta_rad, self.order)
        return np.sqrt(np.einsum("ik,akl,il->ia", a, self.covariance_rad2, a))

    def max_abs_z_draws(self, beta_rad: ArrayLike, draws: int = 20000, seed: int = 0) -> NDArray[np.float64]:
        """``(draws,)`` the largest ``|error / sigma|`` over the positions ``beta_rad`` and the three axes, for errors
        drawn from the terms' covariance (fixed ``seed``: reproducible)."""
        a = fourier_design(beta_rad, self.order)
        sig = self.sigma_rad(beta_rad)
        rng = np.random.default_rng(seed)
        out = np.zeros(int(draws))
        for i in range(3):
            chol = np.linalg.cholesky(self.covariance_rad2[i])
            x = rng.standard_normal((int(draws), a.shape[1])) @ chol.T
            out = np.maximum(out, np.abs(x @ a.T / sig[:, i]).max(axis=1))
        return out

    def simultaneous_z(self, beta_rad: ArrayLike, level: float = 0.95, draws: int = 20000, seed: int = 0) -> float:
        """The ``|z|`` half-width of the simultaneous band: the series' errors at every position ``beta_rad`` and on
        every axis stay within ``z sigma`` with probability ``level`` (the ``level`` quantile of
        :meth:`max_abs_z_draws`; the values are correlated, so it is below :func:`skyrig.adjust.stats.sidak_z`)."""
        return float(np.quantile(self.max_abs_z_draws(beta_rad, draws, seed), level))

    def probability_all_within(self, beta_rad: ArrayLike, k_sigma: float = 2.0, draws: int = 20000,
                               seed: int = 0) -> float:
        """Probability (under the terms' covariance) that the errors at every position and on every axis are within
        ``k_sigma`` of their own sigma."""
        return float(np.mean(self.max_abs_z_draws(beta_rad, draws, seed) <= k_sigma))


def fit_fourier_curve(beta_rad: ArrayLike, values_rad: ArrayLike, sigma_rad: ArrayLike, order: int | None = None,
                      alpha: float = 1e-3, max_order: int | None = None) -> FourierCurve:
    """Weighted least-squares Fourier series of a per-position curve (:class:`FourierCurve`).

    ``order`` None: chosen from the data: the series is fitted at ``max_order`` (default ``min(12, (K - 2) // 4)``
    for ``K`` positions, at least 1) and the order is the highest harmonic whose six terms (cos, sin of the three
    axes) differ from zero by a chi-square test at ``alpha`` (at least 1).  A curve with a harmonic above
    ``max_order``, or one too weak to pass the test, is biased in the series; the variance factor shows the former.
    """
    from scipy.stats import chi2

    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    y = np.asarray(values_rad, dtype=np.float64).reshape(b.size, 3)
    s = np.asarray(sigma_rad, dtype=np.float64).reshape(b.size, 3)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(s)) and np.all(s > 0)):
        raise SkyrigError("Fourier curve: the values and their sigmas must be finite, the sigmas > 0")
    k = b.size

    def fit(n: int) -> FourierCurve:
        a = fourier_design(b, n)
        coef = np.empty((a.shape[1], 3))
        cov = np.empty((3, a.shape[1], a.shape[1]))
        vf = np.empty(3)
        for i in range(3):
            w = 1.0 / s[:, i] ** 2
            n_mat = a.T @ (a * w[:, None])
            cov[i] = np.linalg.inv(n_mat)
            coef[:, i] = cov[i] @ (a.T @ (w * y[:, i]))
            r = y[:, i] - a @ coef[:, i]
            vf[i] = float(np.sum(w * r ** 2) / (k - a.shape[1])) if k > a.shape[1] else float("nan")
        hc = np.full(n, np.nan)
        for j in range(1, n + 1):
            sl = slice(2 * j - 1, 2 * j + 1)
            hc[j - 1] = sum(float(coef[sl, i] @ np.linalg.solve(cov[i][sl, sl], coef[sl, i])) for i in range(3))
        return FourierCurve(n, coef, cov, vf, k - a.shape[1], hc)

    if order is not None:
        if int(order) < 0 or 2 * int(order) + 1 > k:
            raise SkyrigError(f"Fourier curve: order {order} needs {2 * int(order) + 1} positions, the curve has {k}")
        return fit(int(order))
    top = default_max_order(k) if max_order is None else int(max_order)
    if 2 * top + 1 > k:
        raise SkyrigError(f"Fourier curve: order {top} needs {2 * top + 1} positions, the curve has {k}")
    full = fit(top)
    sig = np.flatnonzero(full.harmonic_chi2 > chi2.ppf(1.0 - alpha, 6))
    chosen = fit(int(sig.max()) + 1 if sig.size else 1)
    return FourierCurve(chosen.order, chosen.coefficients_rad, chosen.covariance_rad2, chosen.variance_factor,
                        chosen.dof, full.harmonic_chi2)


def default_max_order(positions: int) -> int:
    """The order a Fourier curve of ``positions`` values is first fitted at (the selection's start, and the series the
    repeating error's share is first estimated with): ``min(12, (K - 2) // 4)``, at least 1."""
    return max(1, min(12, (int(positions) - 2) // 4))


@dataclass(frozen=True)
class RepeatShare:
    """The repeating part of the image comparison's error, as a share of the fits' variance, per axis
    (:func:`estimate_repeat_share`).

    Attributes
    ----------
    share
        ``(3,)`` ``lambda``: the repeating error's variance at a position is ``lambda`` times the position's mean fit
        variance; in ``[0, 1]`` (1: the fit variance is all repeating, the upper bound; 0: none repeats).
    share_se
        ``(3,)`` its standard error (REML Fisher information, ``sqrt(2 / tr(P F P F))``).
    order
        Order of the Fourier series whose residuals estimated it.
    dof
        Redundancy of that series (positions - terms).
    """

    share: NDArray[np.float64]
    share_se: NDArray[np.float64]
    order: int
    dof: int


def estimate_repeat_share(beta_rad: ArrayLike, values_rad: ArrayLike, scatter_var_rad2: ArrayLike,
                          fit_var_rad2: ArrayLike, order: int) -> RepeatShare:
    """Restricted maximum likelihood (REML) estimate of the share ``lambda`` in the per-position variance model
    ``var_k = s + lambda f_k`` of a curve's values, from the residuals of a Fourier series of ``order`` that holds
    the curve.

    ``values_rad`` ``(K, 3)``: the per-position values (the mean curve); ``scatter_var_rad2`` ``(3,)`` or ``(K, 3)``:
    the known part ``s`` (the circle-to-circle scatter over ``C``); ``fit_var_rad2`` ``(K, 3)``: ``f_k`` (the mean
    fit variance of the position's images).  Per axis the REML log-likelihood
    ``-1/2 (sum log var_k + log det(A^T W A) + y^T P y)``, ``W = diag(1 / var_k)``, ``P = W - W A (A^T W A)^-1 A^T W``,
    is maximised over ``lambda in [0, 1]`` (bounded Brent); its standard error is ``sqrt(2 / tr(P F P F))`` at the
    estimate (``F = diag(f_k)``).  The REML estimate accounts for the ``2 order + 1`` terms the series takes from the
    residuals (the plain ``max(vf s^2 - s, 0) / f`` would not, and would not weight the positions).  A series that
    misses a harmonic of the curve puts it into the residuals and the share leans high (towards the bound); a share
    at 1 says the residuals are as large as the bound allows or larger.
    """
    from scipy.optimize import minimize_scalar

    b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
    k = b.size
    y = np.asarray(values_rad, dtype=np.float64).reshape(k, 3)
    s = np.broadcast_to(np.asarray(scatter_var_rad2, dtype=np.float64), (k, 3))
    f = np.asarray(fit_var_rad2, dtype=np.float64).reshape(k, 3)
    a = fourier_design(b, order)
    if k <= a.shape[1]:
        raise SkyrigError(f"repeat share: a series of order {order} needs more than {a.shape[1]} positions, got {k}")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(np.isfinite(f))
            and np.all(f > 0)):
        raise SkyrigError("repeat share: values and variances must be finite, the fit variances > 0")
    share, se = np.empty(3), np.empty(3)
    for i in range(3):
        yi, si, fi = y[:, i], s[:, i], f[:, i]
        floor = 1e-12 * float(np.mean(fi))

        def p_matrix(lam: float, si: NDArray[np.float64] = si, fi: NDArray[np.float64] = fi,
                     floor: float = floor) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
            v = np.maximum(si + lam * fi, floor)
            w = 1.0 / v
            aw = a * w[:, None]
            n_mat = a.T @ aw
            pm = np.diag(w) - aw @ np.linalg.solve(n_mat, aw.T)
            return pm, v, float(np.linalg.slogdet(n_mat)[1])

        def neg_loglik(lam: float, yi: NDArray[np.float64] = yi) -> float:
            pm, v, logdet_n = p_matrix(lam)
            return 0.5 * (float(np.sum(np.log(v))) + logdet_n + float(yi @ pm @ yi))

        res = minimize_scalar(neg_loglik, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-9})
        lam = float(res.x)
        for end in (0.0, 1.0):  # Brent stops xatol short of a bound: the bound itself if it is as likely
            if neg_loglik(end) <= neg_loglik(lam):
                lam = end
        pm = p_matrix(lam)[0]
        pf = pm * fi[None, :]
        share[i] = lam
        se[i] = float(np.sqrt(2.0 / max(float(np.sum(pf * pf.T)), 1e-300)))
    return RepeatShare(share, se, int(order), int(k - a.shape[1]))
