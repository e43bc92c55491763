"""The result of the ``tumbling-head`` recipe (paper 000, 3.4): the curves per circle, their mean and repeatability,
Tab. 2, the curve's statement, the calibration section and the JSON report (:mod:`skyrig.calibrate.tumbling`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.stats import sidak_z
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.calibrate.tumbling_fourier import (
    FourierCurve,
    RepeatShare,
    default_max_order,
    estimate_repeat_share,
    fit_fourier_curve,
)
from skyrig.calibrate.tumbling_setup import LabSetup
from skyrig.rig.boresight_curve import AXES, BoresightCurve
from skyrig.rig.rig import Rig

__all__ = ["FailedImage", "TumblingCalibration", "PAPER000_TABLE2_MDEG"]

#: paper 000 Tab. 2 as printed (MACS-TumbleCam, 72 positions x 5 circles): per axis the mean and the max of the
#: per-position standard deviation (2 sigma, 1/1000 deg) and the photo of the max
PAPER000_TABLE2_MDEG: dict[str, dict[str, float | int]] = {
    "droll": {"mean_std_mdeg": 8.6, "max_std_mdeg": 10.0, "photo_at_max": 219},
    "dpitch": {"mean_std_mdeg": 7.8, "max_std_mdeg": 17.0, "photo_at_max": 3},
    "dyaw": {"mean_std_mdeg": 35.9, "max_std_mdeg": 96.0, "photo_at_max": 3},
}


@dataclass(frozen=True)
class FailedImage:
    """A tumbling image the recipe left out (:func:`measure_position_offset` raised for it).

    Attributes
    ----------
    name, circle
        The image and its circle label.
    beta_rad
        Its actuator angle (radians).
    reason
        The error message.
    """

    name: str
    circle: str
    beta_rad: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: image, circle, beta_deg, reason."""
        return {"image": self.name, "circle": self.circle, "beta_deg": float(np.degrees(self.beta_rad)),
                "reason": self.reason}


@dataclass
class TumblingCalibration:
    """Result of :func:`calibrate_tumbling_head`.

    An image the recipe could not measure (:attr:`failed`) is NaN in :attr:`corrections_rad`, :attr:`sigma_rad`
    and :attr:`covariance_rad2` and 0 in :attr:`windows`; every statistic uses the ``C_k`` circles measured at
    position ``k`` (:attr:`counts`): the mean and std of the position over its ``C_k`` values, the pooled scatter
    with ``N - K`` degrees of freedom (``N`` images measured), the mean's scatter part ``pooled^2 / C_k``.

    Attributes
    ----------
    beta_rad
        ``(K,)`` actuator positions (radians, sorted as given by the first circle).
    circles
        ``(C,)`` circle labels.
    corrections_rad
        ``(C, K, 3)`` measured (droll, dpitch, dyaw) per circle and position (radians).
    sigma_rad
        ``(C, K, 3)`` their standard deviations from each image's fit (radians).
    images
        ``(C, K)`` image names (also of the images left out).
    windows
        ``(C, K)`` correlation windows used per image (0: left out).
    curve
        The mean curve with the per-position repeatability (``std_rad``, ``count``).
    setup
        The lab set-up.
    covariance_rad2
        ``(C, K, 3, 3)`` each image's fit covariance (radians^2; the tilt across the view and the yaw are strongly
        correlated in one image), or None: uncorrelated with ``sigma_rad``.
    failed
        The images left out, with the reasons (:class:`FailedImage`).
    """

    beta_rad: NDArray[np.float64]
    circles: NDArray[np.str_]
    corrections_rad: NDArray[np.float64]
    sigma_rad: NDArray[np.float64]
    images: NDArray[np.str_]
    windows: NDArray[np.int64]
    curve: BoresightCurve
    setup: LabSetup
    covariance_rad2: NDArray[np.float64] | None = None
    failed: tuple[FailedImage, ...] = ()

    @property
    def measured(self) -> NDArray[np.bool_]:
        """``(C, K)`` whether the image was measured (not left out: its corrections are finite)."""
        return np.all(np.isfinite(self.corrections_rad), axis=-1)

    @property
    def counts(self) -> NDArray[np.int64]:
        """``(K,)`` ``C_k``: the circles measured at each position."""
        return self.measured.sum(axis=0).astype(np.int64)

    @property
    def scatter_dof(self) -> int:
        """Degrees of freedom of the pooled scatter :attr:`pooled_std_rad`: ``sum_k (C_k - 1) = N - K``
        (``K (C - 1)`` when every image was measured)."""
        return int(np.sum(self.counts - 1))

    def _position_mean(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Mean over the circles measured at each position of a ``(C, K, ...)`` per-image array."""
        m = self.measured.reshape(self.measured.shape + (1,) * (x.ndim - 2))
        return np.where(m, x, 0.0).sum(axis=0) / self.counts.reshape((-1,) + (1,) * (x.ndim - 2))

    @property
    def mean_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` mean correction per position (over its ``C_k`` circles), in ``beta_rad`` order."""
        return self._position_mean(self.corrections_rad)

    @property
    def std_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` repeatability per position (sample std of its ``C_k`` values about their mean, ``ddof=1``)."""
        dev = np.where(self.measured[..., None], self.corrections_rad - self.mean_rad[None], 0.0)
        return np.sqrt(np.sum(dev ** 2, axis=0) / (self.counts[:, None] - 1))

    @property
    def pooled_std_rad(self) -> NDArray[np.float64]:
        """``(3,)`` the repeatability pooled over the positions: ``sqrt(sum_k (C_k - 1) std_k^2 / (N - K))``
        (:attr:`scatter_dof` degrees of freedom; ``sqrt(mean_k std_k^2)`` when every image was measured)."""
        w = (self.counts - 1)[:, None]
        return np.sqrt(np.sum(w * self.std_rad ** 2, axis=0) / self.scatter_dof)

    @property
    def fit_variance_rad2(self) -> NDArray[np.float64]:
        """``(K, 3)`` ``fit_k^2``: the mean fit variance of the images measured at each position."""
        return self._position_mean(self.sigma_rad ** 2)

    @property
    def measurement_variance_rad2(self) -> NDArray[np.float64]:
        """``(3,)`` the mean variance of one image's angular offset from its fit (``sigma0^2 (J^T J)^-1`` of the
        window shifts, :func:`measure_position_offset`), over the measured images."""
        return np.mean(self.sigma_rad[self.measured] ** 2, axis=0)

    @cached_property
    def repeat_share(self) -> RepeatShare:
        """The repeating part of the image comparison's error as a share ``lambda`` of the fit variance, per axis
        (:func:`estimate_repeat_share` on the mean curve).

        The mean curve's error at position ``k`` is the circle mean of the mechanism's repeat errors and of the part
        of the comparison's error that changes from circle to circle (image noise, the sampling phase), variance
        ``pooled^2 / C``, plus the part that repeats (the same texture is compared at a position in every circle),
        which does not average out: ``rep_k^2``, independent between positions.  Its shape follows the position's
        fit variance (the repeating part of the window shifts goes through the same ``(J^T J)^-1``):
        ``rep_k^2 = lambda f_k`` with ``0 <= lambda <= 1`` (all of a fit's error at most repeats).  A smooth series
        that holds the curve leaves residuals with variance ``pooled^2 / C + lambda f_k``; ``lambda`` is their REML
        estimate, ``pooled^2`` taken as known (``K (C - 1)`` degrees of freedom).  The series: first the default
        highest order (:func:`default_max_order`), then the order :func:`fit_fourier_curve` selects (``alpha = 1e-3``)
        with the sigmas of that share, re-estimated until the order repeats (the final share is estimated with the
        series :meth:`fourier_curve` states).  Fewer than 4 positions: no redundancy, ``lambda = 1`` (the bound),
        ``order`` and ``dof`` 0.  With images left out the scatter part is ``pooled^2 / C_k`` per position."""
        k = self.corrections_rad.shape[1]
        s = self.pooled_std_rad[None] ** 2 / self.counts[:, None]
        f = self.fit_variance_rad2
        if k < 4:
            return RepeatShare(np.ones(3), np.full(3, np.nan), 0, 0)
        order = default_max_order(k)
        rs = estimate_repeat_share(self.beta_rad, self.mean_rad, s, f, order)
        for _ in range(5):
            n = fit_fourier_curve(self.beta_rad, self.mean_rad, np.sqrt(s + rs.share * f), None, 1e-3).order
            if n == order:
                break
            order = n
            rs = estimate_repeat_share(self.beta_rad, self.mean_rad, s, f, order)
        return rs

    @property
    def standard_error_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` standard error of the mean curve: ``sqrt(pooled^2 / C + lambda fit_k^2)``, ``pooled`` the
        repeatability pooled over the positions (one position's own std has only ``C - 1`` degrees of freedom, too
        few to weight it), ``fit_k^2`` the mean fit variance of the position's images and ``lambda`` the share of
        it that repeats from circle to circle (:attr:`repeat_share`, estimated from the mean curve's residuals about
        a Fourier series).

        An estimate, not a bound: the scatter over the circles holds the mechanism's repeat error and the part of
        the comparison's error that changes from circle to circle; the repeating part is added once, as estimated.
        Both variance parts are estimated, so ``(mean - truth) / standard_error`` is about Student-t with
        :attr:`standard_error_dof` degrees of freedom (near N(0, 1) at 30 or more).  The upper bound the recipe
        stated before (the fit variance added in full, ``lambda = 1``) is :attr:`standard_error_bound_rad`.  With
        images left out, ``C`` is the position's ``C_k`` (:attr:`counts`) and ``fit_k^2`` the mean over its measured
        images."""
        lam = self.repeat_share.share
        return np.sqrt(self.pooled_std_rad[None] ** 2 / self.counts[:, None] + lam[None] * self.fit_variance_rad2)

    @property
    def standard_error_bound_rad(self) -> NDArray[np.float64]:
        """``(K, 3)`` an upper bound of the mean curve's standard error: ``sqrt(pooled^2 / C + fit_k^2)``, the fit
        variance added in full as the bound of the repeating comparison error (``lambda = 1`` in
        :attr:`standard_error_rad`; it counts the part of the comparison's error that changes from circle to circle
        twice: once in ``pooled`` and again in the fit variance); ``C_k`` circles where images were left out."""
        return np.sqrt(self.pooled_std_rad[None] ** 2 / self.counts[:, None] + self.fit_variance_rad2)

    @property
    def standard_error_dof(self) -> NDArray[np.float64]:
        """``(K, 3)`` Satterthwaite's degrees of freedom of :attr:`standard_error_rad`'s variance
        ``v_k = s + lambda f_k``: ``2 v_k^2 / (2 s^2 / (K (C - 1)) + f_k^2 se(lambda)^2)``, ``s = pooled^2 / C`` a
        chi-square with ``K (C - 1)`` degrees of freedom and ``se(lambda)`` :attr:`repeat_share`'s standard error
        (the share is estimated from the series' ``dof`` residuals, so this is about ``dof`` where the repeating
        part dominates and about ``K (C - 1)`` where the scatter does; with images left out ``s = pooled^2 / C_k``
        and :attr:`scatter_dof` = ``N - K`` in place of ``K (C - 1)``)."""
        s = self.pooled_std_rad[None] ** 2 / self.counts[:, None]
        f = self.fit_variance_rad2
        rs = self.repeat_share
        v = s + rs.share[None] * f
        var_v = 2 * s ** 2 / self.scatter_dof + f ** 2 * np.nan_to_num(rs.share_se)[None] ** 2
        return 2 * v ** 2 / np.maximum(var_v, 1e-300)

    @property
    def fit_covariance_rad2(self) -> NDArray[np.float64]:
        """``(C, K, 3, 3)`` each image's fit covariance (:attr:`covariance_rad2`, or diagonal from
        :attr:`sigma_rad`)."""
        if self.covariance_rad2 is not None:
            return self.covariance_rad2
        return self.sigma_rad[..., :, None] * np.eye(3) * self.sigma_rad[..., None, :]

    @property
    def mean_covariance_rad2(self) -> NDArray[np.float64]:
        """``(K, 3, 3)`` covariance of the mean curve per position, the matrix form of :attr:`standard_error_rad`:
        the scatter over the circles pooled over the positions (``K (C - 1)`` degrees of freedom) over ``C`` plus
        the repeating part, the position's mean fit covariance scaled by ``sqrt(lambda_i lambda_j)``
        (:attr:`repeat_share`).  Its diagonal is ``standard_error_rad^2``; positions uncorrelated.  With images
        left out: the scatter over ``N - K`` degrees of freedom, over ``C_k``, and the mean fit covariance of the
        position's measured images."""
        dev = np.where(self.measured[..., None], self.corrections_rad - self.mean_rad[None], 0.0)
        scatter = np.einsum("cki,ckj->ij", dev, dev) / self.scatter_dof
        root = np.sqrt(self.repeat_share.share)
        return (scatter[None] / self.counts[:, None, None]
                + self._position_mean(self.fit_covariance_rad2) * np.outer(root, root)[None])

    def mechanism_repeatability_rad(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(std, se)``, each ``(3,)`` radians, 1 sigma: the mechanism's own repeatability with the measurement
        noise removed, ``sqrt(max(pooled^2 - m, 0))`` (``m`` = :attr:`measurement_variance_rad2`), and its standard
        error by the delta method from the chi-square spread of the pooled variance (``K (C - 1)`` degrees of
        freedom) and of the fit variances (``sum of the fits' redundancies``).

        The scatter over the circles holds the mechanism's repeat error and the part of the comparison's error
        that changes from circle to circle; ``m`` also holds the part that repeats, so the estimate leans low by at
        most that part, ``lambda m`` with ``lambda`` the share of :attr:`repeat_share` (on the simulated 72 x 5 lab
        at 320 px the realised share averages 0.16-0.21 per axis over 24 labs; the estimate is not used here: it
        averages 0.19-0.24 and scatters by 0.13-0.27 between labs, as much as the bias it would
        remove).  Where ``pooled^2 <= m`` the std is 0
        and ``se`` is the one-sided bound ``sqrt(2 sd(pooled^2))``.  With images left out: ``N - K`` degrees of
        freedom (:attr:`scatter_dof`) and the measured images' fits."""
        dof = self.scatter_dof
        pooled2 = self.pooled_std_rad ** 2
        m = self.measurement_variance_rad2
        red = max(int(np.sum(2 * self.windows[self.measured] - 3)), 1)
        var_v = 2 * pooled2 ** 2 / dof + 2 * m ** 2 / red
        v = pooled2 - m
        std = np.sqrt(np.clip(v, 0.0, None))
        se = np.where(v > 0, np.sqrt(var_v) / (2 * np.sqrt(np.clip(v, 1e-300, None))), np.sqrt(2 * np.sqrt(var_v)))
        return std, se

    def mechanism_std_rad(self) -> NDArray[np.float64]:
        """``(3,)`` the mechanism's repeatability with the measurement noise removed (see
        :meth:`mechanism_repeatability_rad`)."""
        return self.mechanism_repeatability_rad()[0]

    def fourier_curve(self, order: int | None = None, alpha: float = 1e-3) -> FourierCurve:
        """The mean curve stated as a Fourier series in the actuator angle with the covariance of its terms
        (:func:`fit_fourier_curve` on :attr:`mean_rad` weighted by :attr:`standard_error_rad`; ``order`` None: the
        highest harmonic that differs from zero at ``alpha``; at the default ``alpha`` this is the order
        :attr:`repeat_share` was estimated with)."""
        return fit_fourier_curve(self.beta_rad, self.mean_rad, self.standard_error_rad, order, alpha)

    def curve_statement(self, level: float = 0.95, order: int | None = None) -> dict[str, Any]:
        """How far the estimated curve may be from the mechanism's, stated two ways (JSON-ready, 1/1000 deg).

        ``lookup``: the per-position means (paper 000's table, written into the rig file) with their standard
        errors (:attr:`standard_error_rad`: estimates, not bounds), positions independent: the simultaneous band
        over the ``3 K`` values is Sidak's ``|z|`` bound (:func:`skyrig.adjust.stats.sidak_z`), and "every value
        within 2 sigma" has probability ``0.9545^(3 K)`` if the sigmas are exact; also the repeating comparison
        error's share of the fit variance (:attr:`repeat_share`, with its standard error, the series order and
        redundancy it was estimated with), the sigmas' median degrees of freedom per axis
        (:attr:`standard_error_dof`) and the upper bound of the sigmas (:attr:`standard_error_bound_rad`), the
        circles measured per position (fewest) and the images left out (:attr:`failed`: names and reasons).
        ``fourier``: the series of :meth:`fourier_curve` with its terms' sigma, its values' sigma at the
        positions, the simultaneous band from its covariance (the values are correlated) and the probability of
        "every value within 2 sigma" under that covariance."""
        from scipy.stats import norm

        k = int(self.beta_rad.size)
        md = 1000.0 * 180.0 / np.pi
        p2 = float((2.0 * norm.cdf(2.0) - 1.0) ** (3 * k))
        rs = self.repeat_share
        dof = np.median(self.standard_error_dof, axis=0)
        out: dict[str, Any] = {"level": level, "lookup": {
            "values": 3 * k, "simultaneous_z": sidak_z(3 * k, level), "p_every_value_within_2sigma": p2,
            "sigma_mdeg": {a: (md * self.standard_error_rad[:, i]).tolist() for i, a in enumerate(AXES)},
            "sigma_model": "sqrt(pooled^2 / C_k + repeat_share * fit_k^2), C_k circles measured at the position",
            "circles_per_position_min": int(self.counts.min()), "pooled_dof": self.scatter_dof,
            "images_left_out": [f.to_dict() for f in self.failed],
            "repeat_share": dict(zip(AXES, rs.share.tolist())),
            "repeat_share_se": dict(zip(AXES, rs.share_se.tolist())),
            "repeat_share_order": rs.order, "repeat_share_dof": rs.dof,
            "sigma_dof_median": dict(zip(AXES, dof.tolist())),
            "sigma_bound_mdeg": {a: (md * self.standard_error_bound_rad[:, i]).tolist() for i, a in enumerate(AXES)}}}
        if k >= 4:  # a series of order 1 with a redundancy
            f = self.fourier_curve(order)
            sd = np.sqrt(np.diagonal(f.covariance_rad2, axis1=1, axis2=2))
            draws = f.max_abs_z_draws(self.beta_rad)
            names = ["a0"] + [f"{t}{j}" for j in range(1, f.order + 1) for t in ("a", "b")]
            out["fourier"] = {
                "order": f.order, "dof": f.dof, "terms": names,
                "coefficients_mdeg": {a: (md * f.coefficients_rad[:, i]).tolist() for i, a in enumerate(AXES)},
                "coefficient_sigma_mdeg": {a: (md * sd[i]).tolist() for i, a in enumerate(AXES)},
                "variance_factor": dict(zip(AXES, f.variance_factor.tolist())),
                "harmonic_chi2_6dof": f.harmonic_chi2.tolist(),
                "values_mdeg": {a: (md * f(self.beta_rad)[:, i]).tolist() for i, a in enumerate(AXES)},
                "values_sigma_mdeg": {a: (md * f.sigma_rad(self.beta_rad)[:, i]).tolist() for i, a in enumerate(AXES)},
                "simultaneous_z": float(np.quantile(draws, level)),
                "p_every_value_within_2sigma": float(np.mean(draws <= 2.0))}
        return out

    def table2(self, k_sigma: float = 2.0) -> dict[str, dict[str, Any]]:
        """Paper 000 Tab. 2: per axis the mean and the max of the per-position standard deviation (``k_sigma``
        scaled, degrees and 1/1000 deg), the position (beta, deg) and the image of the max (the image of that
        position farthest from the mean curve); also the per-image measurement sigma (RMS of the fits), the pooled
        repeatability, and the mechanism's repeatability with the measurement noise removed and its standard error
        (:meth:`mechanism_repeatability_rad`), all scaled.  Images left out (:attr:`failed`) are not in it."""
        std = self.std_rad
        mech, mech_se = self.mechanism_repeatability_rad()
        fit = np.sqrt(self.measurement_variance_rad2)
        pooled = self.pooled_std_rad
        out = {}
        for i, a in enumerate(AXES):
            k = int(np.argmax(std[:, i]))
            c = int(np.nanargmax(np.abs(self.corrections_rad[:, k, i] - self.mean_rad[k, i])))
            mean_deg = float(np.degrees(np.mean(std[:, i])) * k_sigma)
            max_deg = float(np.degrees(std[k, i]) * k_sigma)
            out[a] = {"mean_std_deg": mean_deg, "max_std_deg": max_deg, "mean_std_mdeg": 1000 * mean_deg,
                      "max_std_mdeg": 1000 * max_deg, "k_sigma": k_sigma,
                      "beta_at_max_deg": float(np.degrees(self.beta_rad[k])), "image_at_max": str(self.images[c, k]),
                      "measurement_sigma_mdeg": 1000 * float(np.degrees(fit[i]) * k_sigma),
                      "pooled_std_mdeg": 1000 * float(np.degrees(pooled[i]) * k_sigma),
                      "mechanism_std_mdeg": 1000 * float(np.degrees(mech[i]) * k_sigma),
                      "mechanism_std_deg": float(np.degrees(mech[i]) * k_sigma),
                      "mechanism_std_se_mdeg": 1000 * float(np.degrees(mech_se[i]) * k_sigma)}
        return out

    def calibrated_rig(self) -> Rig:
        """The set-up's rig with the mean curve on the tumbling head."""
        from dataclasses import replace

        rig = self.setup.rig
        return replace(rig, heads={n: (h.with_(curve=self.curve) if n == self.setup.head else h)
                                   for n, h in rig.heads.items()})

    def rig_calibration(self, flight: str = "", date: str = "", software: str = "",
                        previous: RigCalibration | None = None) -> RigCalibration:
        """The calibration section: the tumbling head's ``actuator`` block (values: the mean curve, degrees;
        sigma: its standard errors :attr:`standard_error_rad`; correlations: the three axes of a position from
        :attr:`mean_covariance_rad2`, positions uncorrelated) and provenance (with the repeating comparison error's
        share :attr:`repeat_share` per axis, the number of images left out and the fewest circles at a position;
        the notes name the images left out and why); other heads kept from ``previous``."""
        names = [f"{a}_deg@{np.degrees(b):.4f}" for b in self.beta_rad for a in AXES]
        values = np.degrees(self.mean_rad).reshape(-1)
        sig = np.degrees(self.standard_error_rad).reshape(-1)
        cov = self.mean_covariance_rad2
        sd = np.sqrt(np.einsum("kii->ki", cov))
        corr = np.zeros((len(names), len(names)))
        for k in range(self.beta_rad.size):  # block diagonal: the three axes of a position are correlated
            corr[3 * k:3 * k + 3, 3 * k:3 * k + 3] = np.clip(cov[k] / np.outer(sd[k], sd[k]), -1.0, 1.0)
        corr[np.diag_indices_from(corr)] = 1.0
        block = CovarianceBlock(tuple(names), np.nan_to_num(sig), np.nan_to_num(corr), values)
        rep = self.table2(1.0)
        stats = {"positions": int(self.beta_rad.size), "circles": int(self.corrections_rad.shape[0]),
                 "images": int(self.measured.sum()), "images_left_out": len(self.failed),
                 "circles_per_position_min": int(self.counts.min()),
                 "windows_min": int(self.windows[self.measured].min()),
                 **{f"{a}_mean_std_deg": rep[a]["mean_std_deg"] for a in AXES},
                 **{f"{a}_max_std_deg": rep[a]["max_std_deg"] for a in AXES},
                 **{f"{a}_fit_sigma_median_deg": float(np.degrees(np.median(self.sigma_rad[self.measured][:, i])))
                    for i, a in enumerate(AXES)},
                 **{f"{a}_mechanism_std_deg": rep[a]["mechanism_std_deg"] for a in AXES},
                 **{f"{a}_mechanism_std_se_deg": rep[a]["mechanism_std_se_mdeg"] / 1000 for a in AXES},
                 **{f"{a}_repeat_share": float(self.repeat_share.share[i]) for i, a in enumerate(AXES)},
                 **{f"{a}_repeat_share_se": float(self.repeat_share.share_se[i]) for i, a in enumerate(AXES)}}
        notes = ("laboratory calibration (paper 000, 3.4): tumbling images against a static reference camera "
                 "through a common plane, phase correlation of windows, small-rotation least squares per "
                 "image iterated to zero shift; mean curve over circles")
        if self.failed:
            notes += (f"; {len(self.failed)} images left out (the curve at their positions from the other circles): "
                      + _failed_list(self.failed, most=len(self.failed)))
        prov = Provenance("tumbling-head", flight, date, software, stats, notes)
        heads = dict(previous.heads) if previous is not None else {}
        prev = heads.get(self.setup.head, HeadCalibration())
        heads[self.setup.head] = HeadCalibration(prev.lever_arm_m, prev.boresight_opk_deg, prev.interior, block, prov)
        return RigCalibration(heads, None if previous is None else previous.antenna_lever_arm_m,
                              prov if previous is None or previous.provenance is None else previous.provenance)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report: Tab. 2, the mean curve with its repeatability, every measurement, the images left
        out (``images_left_out``: image, circle, beta_deg, reason)."""
        fc = self.fit_covariance_rad2
        mc = self.mean_covariance_rad2
        se, se_bound = self.standard_error_rad, self.standard_error_bound_rad
        return {
            "recipe": "tumbling-head",
            "head": self.setup.head, "reference_head": self.setup.reference_head,
            "plane_distance_m": self.setup.plane_distance_m,
            "positions": int(self.beta_rad.size), "circles": [str(c) for c in self.circles],
            "images_measured": int(self.measured.sum()),
            "images_left_out": [f.to_dict() for f in self.failed],
            "table2_2sigma": self.table2(2.0),
            "table2_paper000_mdeg": PAPER000_TABLE2_MDEG,
            "curve_statement": self.curve_statement(),
            "curve": [{"beta_deg": float(np.degrees(b)), "circles_measured": int(self.counts[k]),
                       **{f"{a}_mdeg": 1000 * float(np.degrees(self.mean_rad[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_std_mdeg": 1000 * float(np.degrees(self.std_rad[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_se_mdeg": 1000 * float(np.degrees(se[k, i])) for i, a in enumerate(AXES)},
                       **{f"{a}_se_bound_mdeg": 1000 * float(np.degrees(se_bound[k, i])) for i, a in enumerate(AXES)},
                       **{f"r_{AXES[i]}_{AXES[j]}": float(mc[k, i, j] / np.sqrt(mc[k, i, i] * mc[k, j, j]))
                          for i, j in ((0, 1), (0, 2), (1, 2))}}
                      for k, b in enumerate(self.beta_rad)],
            "measurements": [{"image": str(self.images[c, k]), "circle": str(self.circles[c]),
                              "beta_deg": float(np.degrees(self.beta_rad[k])), "windows": int(self.windows[c, k]),
                              **{f"{a}_mdeg": 1000 * float(np.degrees(self.corrections_rad[c, k, i]))
                                 for i, a in enumerate(AXES)},
                              **{f"{a}_sigma_mdeg": 1000 * float(np.degrees(self.sigma_rad[c, k, i]))
                                 for i, a in enumerate(AXES)},
                              **{f"r_{AXES[i]}_{AXES[j]}":
                                 float(fc[c, k, i, j] / np.sqrt(fc[c, k, i, i] * fc[c, k, j, j]))
                                 for i, j in ((0, 1), (0, 2), (1, 2))}}
                             for c in range(len(self.circles)) for k in range(self.beta_rad.size)
                             if self.measured[c, k]],
        }



def _failed_list(failed: Sequence[FailedImage], most: int = 8) -> str:
    """The failed images for a message or a note: name, circle, beta and reason of the first ``most``."""
    out = "; ".join(f"{f.name} (circle {f.circle}, beta {np.degrees(f.beta_rad):.4f} deg): {f.reason}"
                    for f in failed[:most])
    return out + (f"; and {len(failed) - most} more" if len(failed) > most else "")
