"""The ``calqc`` correction grid (paper 004's image deformation): a covariance function fitted to image residuals,
the grid by least-squares collocation, the part of it the calibration unknowns make, the grid's unknowns in the
joint adjustment with their collocation prior, and the grid's uncertainty propagated into the calibration
(:mod:`skyrig.calibrate.calqc` module docstring).  Also the smooth deformations a simulation injects (a wave, a
random field drawn from the same Gaussian covariance function).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import AdjustmentResult, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.factors.image_grid import GridSpec
from skyrig.calibrate.calqc_common import _cal_labels, _cal_values, _run
from skyrig.errors import SkyrigError

log = logging.getLogger("skyrig.calibrate.calqc")  # the recipe's log, whichever part writes

__all__ = ["wave_deformation", "random_field_deformation", "CovarianceFit", "calibration_basis", "fit_covariance",
           "CorrectionGrid", "bilinear_interpolation_variance", "grid_nodes_for", "collocation_grid",
           "without_calibration_part", "CALIBRATION_FIELDS", "calibration_part", "grid_from_result", "grid_uncertainty",
           "covariance_fit_spread", "grid_hyperparameter_covariance", "collocation_prior", "joint_grid_adjustment",
           "apply_grids"]


def wave_deformation(amplitude_px: float, width: int, height: int) -> Callable[[NDArray[np.float64]], NDArray]:
    """A smooth image deformation without mean, linear or radial part (not absorbed by the IO or the
    orientation): ``dx = a sin(2 pi u) cos(pi v)``, ``dy = a cos(pi u) sin(2 pi v)`` with ``u, v`` in [-1, 1]."""

    def d(pix: NDArray[np.float64]) -> NDArray[np.float64]:
        u = 2.0 * pix[:, 0] / (width - 1) - 1.0
        v = 2.0 * pix[:, 1] / (height - 1) - 1.0
        return amplitude_px * np.column_stack([np.sin(2 * np.pi * u) * np.cos(np.pi * v),
                                               np.cos(np.pi * u) * np.sin(2 * np.pi * v)])
    return d


@lru_cache(maxsize=4)
def _field_factor(amplitude_px: float, length_px: float, width: int, height: int, h: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The lattice of :func:`random_field_deformation` and a square root of the field's covariance on it."""
    xs = np.arange(-h, width - 1 + 2 * h, h)
    ys = np.arange(-h, height - 1 + 2 * h, h)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    C = _gauss(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2), amplitude_px ** 2, length_px)
    lam, V = np.linalg.eigh(C)
    return xs, ys, V * np.sqrt(np.clip(lam, 0.0, None))


def random_field_deformation(amplitude_px: float, length_px: float, width: int, height: int,
                             rng: np.random.Generator, spacing_px: float | None = None
                             ) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """A draw of a smooth random image deformation: each component an independent zero-mean Gaussian field with
    the covariance ``amplitude^2 exp(-(d / length)^2)`` (the simulation's own; the recipe fits its covariance
    function from the residuals and is not told this one).  Drawn exactly (eigen-decomposition of the covariance)
    on a lattice ``spacing_px`` apart (default ``length / 6``) reaching one spacing beyond the format, and
    interpolated bicubically in between (for that spacing the interpolation error is far below 1 % of the field)."""
    from scipy.interpolate import RectBivariateSpline

    h = float(spacing_px) if spacing_px else float(length_px) / 6.0
    xs, ys, F = _field_factor(float(amplitude_px), float(length_px), int(width), int(height), h)
    vals = F @ rng.standard_normal((F.shape[1], 2))
    spl = [RectBivariateSpline(ys, xs, vals[:, c].reshape(len(ys), len(xs)), kx=3, ky=3) for c in range(2)]

    def d(pix: NDArray[np.float64]) -> NDArray[np.float64]:
        pix = np.asarray(pix, float)
        return np.column_stack([s(pix[:, 1], pix[:, 0], grid=False) for s in spl])
    return d


# ------------------------------------------------------------------------------------------------ collocation
def _gauss(d: NDArray[np.float64], c0: float, L: float) -> NDArray[np.float64]:
    return c0 * np.exp(-np.square(d / L))


@dataclass(frozen=True)
class CovarianceFit:
    """The fitted covariance function of a residual field: ``C(d) = c0 exp(-(d/L)^2)`` (signal, px^2 per
    component, ``L`` px) plus a nugget (white-noise variance, px^2); and the empirical bins it was fitted to."""

    c0: float
    length_px: float
    nugget: float
    bins_px: NDArray[np.float64]
    empirical: NDArray[np.float64]
    pairs: NDArray[np.int64]
    variance: float
    # how much better the signal explains the binned covariance than the nugget alone: the decrease of the bins'
    # chi-square (each bin's mean product with its white-noise standard error variance / sqrt(2 pairs)); NaN where
    # not computed (only the detrended fit does)
    significance: float = float("nan")

    def __call__(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        return _gauss(d, self.c0, self.length_px)


def calibration_basis(pix: NDArray[np.float64], width: int, height: int) -> NDArray[np.float64]:
    """The fields a camera's calibration unknowns make over its format, at ``pix (N, 2)``: ``(2N, 6)``, the x
    components of the N points then their y components, in the order of :data:`CALIBRATION_FIELDS` (shifts, radial
    scale, rotation and the two tilt terms, as :func:`without_calibration_part` removes them from a grid)."""
    cx, cy = 0.5 * (width - 1.0), 0.5 * (height - 1.0)
    scale = max(float(np.hypot(cx, cy)), 1.0)
    return _calibration_fields((np.asarray(pix, float)[:, 0] - cx) / scale, (np.asarray(pix, float)[:, 1] - cy) / scale)


def _calibration_fields(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(2N, 6)`` the calibration fields at centred, scaled coordinates ``x, y (N,)``: shifts (principal point),
    radial scale (principal distance), rotation (kappa), and the projective terms of a rotation about the image x and
    y axes (boresight omega, phi: dx, dy = (f + x^2/f, xy/f) and (xy/f, f + y^2/f)); x components then y."""
    one, zero = np.ones(len(x)), np.zeros(len(x))
    return np.column_stack([np.r_[one, zero], np.r_[zero, one], np.r_[x, y], np.r_[-y, x],
                            np.r_[x * x, x * y], np.r_[x * y, y * y]])


class _DetrendedModel:
    """For a unit-variance Gaussian field of correlation length ``L``, observed at ``xy`` and freed of its
    calibration part by least squares there (:func:`calibration_basis`): the expected empirical covariance in the
    distance bins ``edges`` (both components pooled as :func:`fit_covariance` pools them) and at zero distance
    (:meth:`__call__`).  The geometry is set up once; each length costs a few ``(m, m)`` products."""

    def __init__(self, xy: NDArray[np.float64], width: int, height: int, edges: NDArray[np.float64]) -> None:
        m = len(xy)
        Q, _ = np.linalg.qr(calibration_basis(xy, width, height))
        self.Qx, self.Qy = Q[:m], Q[m:]
        self.iu = np.triu_indices(m, 1)
        self.D = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
        k = np.searchsorted(edges, self.D[self.iu], side="right") - 1
        self.inb = (k >= 0) & (k < len(edges) - 1)
        self.k = k[self.inb]
        self.nb = len(edges) - 1
        self.cnt = np.maximum(np.bincount(self.k, minlength=self.nb), 1)

    def __call__(self, L: float) -> tuple[NDArray[np.float64], float]:
        Qx, Qy = self.Qx, self.Qy
        C = _gauss(self.D, 1.0, float(L))
        CQx, CQy = C @ Qx, C @ Qy
        M = Qx.T @ CQx + Qy.T @ CQy
        # (I - P) blockdiag(C, C) (I - P), P = Q Q^T: the mean of its x-x and y-y blocks
        A = C - (Qx @ CQx.T + Qy @ CQy.T) + 0.5 * (Qx @ M @ Qx.T + Qy @ M @ Qy.T)  # (symmetric: QC^T = CQ^T)
        a = A[self.iu][self.inb]
        return np.bincount(self.k, weights=a, minlength=self.nb) / self.cnt, float(np.mean(np.diag(A)))


def fit_covariance(xy: NDArray[np.float64], v: NDArray[np.float64], max_distance: float, n_bins: int = 24,
                   max_points: int = 2500, seed: int = 0, detrend_format: tuple[int, int] | None = None,
                   model_points: int = 300) -> CovarianceFit:
    """Empirical covariance of a 2-vector field ``v`` at positions ``xy`` (mean removed; both components pooled),
    in ``n_bins`` distance bins up to ``max_distance``, fitted by a Gaussian plus a nugget (weighted by the
    number of pairs per bin; bins up to the first zero crossing of the empirical covariance).  Above ``max_points``
    positions a random subset estimates it.

    ``detrend_format=(width, height)``: the field is a residual field from which the calibration unknowns took
    their part (shifts, radial scale, rotation, tilts over that format), so it is freed of exactly that part by
    least squares, and the Gaussian is fitted to what such a detrended field's empirical covariance is expected
    to be (:class:`_DetrendedModel` on ``model_points`` of the positions), in every bin, its negative lobe
    included.  Without it a field's long-wavelength part, the part that goes into the IO and boresight, is missing
    from the residuals, and the fit returns too small a signal variance and correlation length (simulated MIDAS
    flight, 600 px, Gaussian nadir field of 0.05 px and 120 px: 0.0016-0.0022 px^2 and 81-120 px instead of 0.0025
    and 120), which makes the grid's prior, and with it the IO and boresight sigmas, too optimistic."""
    from scipy.optimize import curve_fit, minimize_scalar
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, float)
    v = np.asarray(v, float) - np.mean(v, axis=0)
    if detrend_format is not None:
        B = calibration_basis(xy, *detrend_format)
        vv = np.r_[v[:, 0], v[:, 1]]
        vv = vv - B @ np.linalg.lstsq(B, vv, rcond=None)[0]
        v = np.column_stack([vv[:len(xy)], vv[len(xy):]])
    if len(xy) > max_points:
        sel = np.random.default_rng(seed).choice(len(xy), max_points, replace=False)
        xy, v = xy[sel], v[sel]
    var = float(np.mean(np.sum(v * v, axis=1)) / 2.0)
    edges = np.linspace(0.0, max_distance, n_bins + 1)
    pairs = cKDTree(xy).query_pairs(max_distance, output_type="ndarray")
    emp = np.full(n_bins, np.nan)
    cnt = np.zeros(n_bins, np.int64)
    if len(pairs):
        d = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
        prod = np.sum(v[pairs[:, 0]] * v[pairs[:, 1]], axis=1) / 2.0
        k = np.clip(np.searchsorted(edges, d, side="right") - 1, 0, n_bins - 1)
        cnt = np.bincount(k, minlength=n_bins)
        s = np.bincount(k, weights=prod, minlength=n_bins)
        emp = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ok = cnt >= 10
    if detrend_format is not None:
        sub = np.random.default_rng(seed + 1).choice(len(xy), min(len(xy), int(model_points)), replace=False)
        lo, hi = np.log(edges[1] * 0.5), np.log(2.0 * max_distance)
        wgt = np.where(ok, cnt, 0).astype(float)
        e0 = np.where(ok, emp, 0.0)

        model = _DetrendedModel(xy[sub], detrend_format[0], detrend_format[1], edges)

        def best(logL: float) -> tuple[float, float, float]:
            mk, z0 = model(float(np.exp(logL)))
            den = float(np.sum(wgt * mk * mk))
            c = float(np.clip(np.sum(wgt * e0 * mk) / den, 0.0, var / max(z0, 1e-9))) if den > 0 else 0.0
            return float(np.sum(wgt * (e0 - c * mk) ** 2)), c, z0

        grid_l = np.linspace(lo, hi, 25)
        costs = [best(g)[0] for g in grid_l]
        j = int(np.argmin(costs))
        r = minimize_scalar(lambda g: best(g)[0], bounds=(grid_l[max(j - 1, 0)], grid_l[min(j + 1, 24)]),
                            method="bounded", options={"xatol": 1e-3})
        cost, c0, z0 = best(float(r.x))
        L = float(np.exp(r.x))
        nugget = max(var - c0 * z0, 1e-6 * max(var, 1e-12))
        # the fit's weights are the pair counts; a bin's mean product of white noise has the standard error
        # var / sqrt(2 n) (two components), so the chi-square decrease is (sum w e^2 - cost) * 2 / var^2
        signif = float((np.sum(wgt * e0 * e0) - cost) * 2.0 / max(var, 1e-300) ** 2)
        return CovarianceFit(c0, L, nugget, centres, emp, cnt, var, signif)
    nonpos = np.flatnonzero(ok & ~(emp > 0))
    if nonpos.size:  # fit up to the first zero crossing (an oscillating field is not Gaussian beyond it)
        ok &= np.arange(n_bins) < max(int(nonpos[0]), 3)
    c0, L = 0.0, max_distance / 4.0
    if ok.sum() >= 3 and np.nanmax(emp[ok]) > 0:
        try:
            p, _ = curve_fit(_gauss, centres[ok], emp[ok], p0=(max(float(emp[ok][0]), 1e-12), max_distance / 4.0),
                             sigma=1.0 / np.sqrt(cnt[ok]), bounds=([0.0, edges[1] * 0.5], [max(var, 1e-12),
                                                                                          4.0 * max_distance]))
            c0, L = float(p[0]), float(p[1])
        except (RuntimeError, ValueError):  # pragma: no cover - no signal to fit
            c0 = 0.0
    nugget = max(var - c0, 1e-6 * max(var, 1e-12))
    return CovarianceFit(c0, L, nugget, centres, emp, cnt, var)


@dataclass(frozen=True)
class CorrectionGrid:
    """A correction grid of one camera: nodes over the image format (pixels) with the predicted systematic
    image error (``(ny, nx, 2)`` px, observed minus true) and its sigma (``(ny, nx)`` px per component).
    :meth:`correct` subtracts the bilinearly interpolated grid from pixel coordinates."""

    camera: str
    x_px: NDArray[np.float64]
    y_px: NDArray[np.float64]
    value_px: NDArray[np.float64]
    sigma_px: NDArray[np.float64]
    covariance: CovarianceFit
    n_residuals: int
    posterior_factor: NDArray[np.float64] | None = None  # F, node-value posterior covariance F F^T per component

    def sample(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """A draw of the grid's error from its posterior (``(ny, nx, 2)`` px; zero without a signal)."""
        if self.posterior_factor is None:
            return np.zeros_like(self.value_px)
        z = rng.standard_normal((self.posterior_factor.shape[1], 2))
        return (self.posterior_factor @ z).reshape(self.value_px.shape)

    def at(self, pix: NDArray[np.float64]) -> NDArray[np.float64]:
        """The grid interpolated at ``(N, 2)`` pixels (bilinear; clamped at the format's edges)."""
        from scipy.interpolate import RegularGridInterpolator

        p = np.column_stack([np.clip(pix[:, 1], self.y_px[0], self.y_px[-1]),
                             np.clip(pix[:, 0], self.x_px[0], self.x_px[-1])])
        out = np.empty((len(pix), 2))
        for c in range(2):
            out[:, c] = RegularGridInterpolator((self.y_px, self.x_px), self.value_px[:, :, c])(p)
        return out

    def correct(self, pix: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(pix, float) - self.at(np.asarray(pix, float))

    def to_dict(self) -> dict[str, Any]:
        cf = self.covariance
        return {"camera": self.camera, "nodes_x_px": self.x_px.tolist(), "nodes_y_px": self.y_px.tolist(),
                "correction_px": self.value_px.tolist(), "sigma_px": self.sigma_px.tolist(),
                "residuals": self.n_residuals,
                "covariance": {"function": "gaussian c0 exp(-(d/L)^2) + nugget", "c0_px2": cf.c0,
                               "length_px": cf.length_px, "nugget_px2": cf.nugget, "variance_px2": cf.variance,
                               "bins_px": cf.bins_px.tolist(),
                               "empirical_px2": [None if not np.isfinite(e) else float(e) for e in cf.empirical],
                               "pairs": cf.pairs.tolist()},
                "max_correction_px": float(np.max(np.linalg.norm(self.value_px, axis=2))),
                "mean_sigma_px": float(np.mean(self.sigma_px))}


def bilinear_interpolation_variance(cov: CovarianceFit, hx: float, hy: float) -> float:
    """Variance (px^2 per component) of the error of bilinear interpolation of a signal with covariance ``cov``
    from nodes ``hx`` by ``hy`` px apart, at a cell centre (the worst point): ``C0 - 2 w^T c + w^T C w`` with the
    four weights 1/4."""
    r = float(np.hypot(hx, hy)) / 2.0
    cc = [cov(np.array([r]))[0]] * 4
    d = [0.0, hx, hy, float(np.hypot(hx, hy))]  # corner-to-corner distances: itself, along x, along y, diagonal
    cw = cov(np.array(d))
    ww = (4 * cw[0] + 4 * cw[1] + 4 * cw[2] + 4 * cw[3]) / 16.0
    return float(max(cov.c0 - 2.0 * 0.25 * float(np.sum(cc)) + ww, 0.0))


def grid_nodes_for(cov: CovarianceFit, width: int, height: int, max_fraction: float = 0.01,
                   min_nodes: int = 5, max_nodes: int = 61) -> int:
    """The number of grid nodes across the format (``nodes_x``) such that bilinear interpolation between the
    nodes loses at most ``max_fraction`` of the signal's variance at the worst point (a cell centre), by the fitted
    covariance (:func:`bilinear_interpolation_variance`): a grid too coarse for the signal's correlation length
    cannot hold it, and what it cannot hold stays in the coordinates (and in whatever unknowns it resembles).  A
    loss below ``max_fraction`` of one coordinate's noise variance (the nugget) is accepted too: a weak signal (or a
    covariance fitted to noise) needs no fine grid.  No signal: 13 nodes."""
    if not cov.c0 > 0:
        return 13
    tol = max_fraction * max(cov.c0, cov.nugget)
    for n in range(max(int(min_nodes), 2), int(max_nodes) + 1):
        ny = max(2, int(round(n * height / width)))
        hx, hy = (width - 1.0) / (n - 1), (height - 1.0) / (ny - 1)
        if bilinear_interpolation_variance(cov, hx, hy) <= tol:
            return n
    return int(max_nodes)


def _bilinear_design(xs: NDArray[np.float64], ys: NDArray[np.float64], pix: NDArray[np.float64]) -> Any:
    """Sparse ``(N, ny * nx)`` matrix of the bilinear weights of each position on the nodes (row-major, y then
    x; positions clamped to the format)."""
    from scipy.sparse import csr_matrix

    from skyrig.adjust.factors.image_grid import bilinear_weights

    idx, w = bilinear_weights(xs, ys, pix)
    nx, ny = len(xs), len(ys)
    rows = np.repeat(np.arange(len(pix)), 4)
    cols = idx.ravel()
    w = w.ravel()
    return csr_matrix((w, (rows, cols)), shape=(len(pix), nx * ny))


def collocation_grid(camera: str, width: int, height: int, pix: NDArray[np.float64], error: NDArray[np.float64],
                     nodes_x: int | None = None, nodes_y: int | None = None,
                     cov: CovarianceFit | None = None) -> CorrectionGrid:
    """Least-squares collocation of a residual field onto a grid (module docstring).

    ``pix`` ``(N, 2)`` image positions, ``error`` ``(N, 2)`` observed systematic error samples (e.g. observed
    minus computed image coordinates, px).  The signal is the field the grid holds - bilinear between its nodes,
    the node values a Gaussian process with the covariance function ``cov`` (default: fitted,
    :func:`fit_covariance`, up to half the format's diagonal) - and the node values are its prediction from all
    samples at once: ``g = C B^T (B C B^T + D)^-1 l`` with ``B`` the bilinear weights of the samples on the nodes,
    ``C`` the covariance of the nodes and ``D`` the nugget, computed in the nodes' space (``C = L L^T``,
    ``g = L (I + L^T B^T B L / nugget)^-1 L^T B^T l / nugget``), with the posterior sigma of every node.  Being the
    field that is applied (not a prediction at the nodes interpolated afterwards), it leaves in the coordinates
    only what a grid of that spacing cannot hold; ``nodes_x`` (default :func:`grid_nodes_for`: fine enough for the
    fitted correlation length) sets the spacing.  The mean of ``error`` is the trend (added back)."""
    pix = np.asarray(pix, float)
    error = np.asarray(error, float)
    if len(pix) < 10:
        raise SkyrigError(f"camera {camera!r}: {len(pix)} residuals, too few for a correction grid")
    diag = float(np.hypot(width, height))
    if cov is None:
        cov = fit_covariance(pix, error, 0.5 * diag)
    nx = int(nodes_x) if nodes_x else grid_nodes_for(cov, width, height)
    mean = error.mean(axis=0)
    l = error - mean
    ny = nodes_y or max(2, int(round(nx * height / width)))
    xs = np.linspace(0.0, width - 1.0, nx)
    ys = np.linspace(0.0, height - 1.0, ny)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    val = np.zeros((len(nodes), 2))
    var = np.full(len(nodes), cov.c0)
    if cov.c0 > 0:
        Cn = cov(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2))
        lam, V = np.linalg.eigh(Cn)
        keep = lam > 1e-10 * lam.max()  # a square root of the node covariance without its null directions
        Lh = V[:, keep] * np.sqrt(lam[keep])
        B = _bilinear_design(xs, ys, pix)
        BL = np.asarray(B @ Lh)
        S = np.eye(Lh.shape[1]) + (BL.T @ BL) / cov.nugget
        from scipy.linalg import cho_factor, cho_solve

        cf = cho_factor(S)
        val = Lh @ cho_solve(cf, BL.T @ l / cov.nugget)
        var = np.sum(Lh * cho_solve(cf, Lh.T).T, axis=1)
        from scipy.linalg import solve_triangular

        # posterior covariance of the node values (per component) = F F^T, F = Lh U^-1 (S = U^T U)
        factor = solve_triangular(np.triu(cf[0]) if not cf[1] else np.tril(cf[0]).T, Lh.T, trans="T", lower=False).T
    else:
        factor = None
    val += mean
    return CorrectionGrid(camera, xs, ys, val.reshape(ny, nx, 2),
                          np.sqrt(np.clip(var, 0.0, None)).reshape(ny, nx), cov, len(pix), factor)


def without_calibration_part(g: CorrectionGrid) -> CorrectionGrid:
    """The grid less its least-squares fit, over the nodes (uniform over the format), of the fields the
    calibration's own unknowns make: a shift in x and in y (principal point; boresight omega / phi), a radial
    scale about the format's centre (principal distance), a rotation about it (boresight kappa) and the projective
    terms of a rotation about the image axes (boresight omega / phi beside the principal point).

    The grid and those unknowns see the image residuals alike; without this a grid estimated from the residuals of
    an adjustment whose IO (or boresight) has absorbed part of a deformation keeps that part out of the grid for
    good, and the IO keeps its bias.  With it the grid holds only what the IO and the boresights cannot, and an
    IO estimated from coordinates corrected by the grid is free of the deformation's share (for a deformation
    without those parts on the format, e.g. :func:`wave_deformation`)."""
    coef, basis = _calibration_fit(g)
    v = np.r_[g.value_px[:, :, 0].ravel(), g.value_px[:, :, 1].ravel()]
    r = v - basis @ coef
    n = v.size // 2
    val = np.stack([r[:n].reshape(g.value_px.shape[:2]), r[n:].reshape(g.value_px.shape[:2])], axis=-1)
    return replace(g, value_px=val)


#: the fields of :func:`without_calibration_part`, in the order of :func:`calibration_part`'s coefficients
CALIBRATION_FIELDS = ("shift_x_px", "shift_y_px", "radial_scale", "rotation_rad", "tilt_about_y", "tilt_about_x")


def _calibration_fit(g: CorrectionGrid) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    gx, gy = np.meshgrid(g.x_px, g.y_px)
    cx, cy = 0.5 * (g.x_px[0] + g.x_px[-1]), 0.5 * (g.y_px[0] + g.y_px[-1])
    scale = max(float(np.hypot(cx, cy)), 1.0)  # one scale for x and y: the radial and rotation fields are isotropic
    basis = _calibration_fields((gx.ravel() - cx) / scale, (gy.ravel() - cy) / scale)
    v = np.r_[g.value_px[:, :, 0].ravel(), g.value_px[:, :, 1].ravel()]
    coef, *_ = np.linalg.lstsq(basis, v, rcond=None)
    return coef, basis


def calibration_part(g: CorrectionGrid) -> dict[str, float]:
    """The least-squares coefficients, over the grid's nodes, of the fields :func:`without_calibration_part`
    removes: shifts (px), radial scale (relative: a principal-distance change of ``f`` times it), rotation (rad)
    and the two tilt terms (px at the half diagonal)."""
    coef, _ = _calibration_fit(g)
    cx, cy = 0.5 * (g.x_px[0] + g.x_px[-1]), 0.5 * (g.y_px[0] + g.y_px[-1])
    scale = max(float(np.hypot(cx, cy)), 1.0)
    phys = coef.copy()
    phys[2] /= scale
    phys[3] /= scale
    return dict(zip(CALIBRATION_FIELDS, phys.tolist()))


def grid_from_result(res: AdjustmentResult, base: Mapping[str, CorrectionGrid] | None = None,
                     calibration_free: bool = False, **kw: Any) -> dict[str, CorrectionGrid]:
    """Per camera, the collocation grid of an adjustment's image residuals (observed minus computed).

    ``base``: grids the adjustment's coordinates were already corrected by; their values at the observations are
    added back, so the result is the whole deformation, not an increment (its sigma then describes the whole).
    ``calibration_free``: remove the part the calibration unknowns make (:func:`without_calibration_part`)."""
    b = res.block
    gr = res.residuals["image"]
    use = (gr.weight > 0) if gr.weight.ndim == 1 else (gr.weight > 0).all(axis=-1)
    out = {}
    cam_of_obs = b.image_camera[b.obs_image]
    for ci, cam in enumerate(b.cameras):
        sel = use & (cam_of_obs == ci)
        if sel.sum() < 10:
            continue
        err = -np.asarray(gr.residual)[sel]
        if base is not None and cam.name in base:
            err = err + base[cam.name].at(b.obs_pixel[sel])
        g = collocation_grid(cam.name, cam.width, cam.height, b.obs_pixel[sel], err, **kw)
        out[cam.name] = without_calibration_part(g) if calibration_free else g
    return out


def grid_uncertainty(block: Block, res: AdjustmentResult, grids: Mapping[str, CorrectionGrid], cfg: AdjustConfig,
                     draws: int = 8, seed: int = 0) -> NDArray[np.float64]:
    """The correction grids' posterior uncertainty propagated into the calibration unknowns (Monte Carlo).

    ``block``: the uncorrected block at the adjusted values of ``res`` (the joint adjustment on the coordinates the
    ``grids`` correct).  ``draws`` antithetic pairs: each grid plus and minus a draw from its posterior (the node
    values' full posterior covariance, :meth:`CorrectionGrid.sample`, less its calibration-like part as the grid
    itself), the joint adjustment again, and half the difference of the calibration unknowns; their mean outer
    product is the covariance to add to the adjustment's (the ``_cal_labels`` order of ``res``)."""
    rng = np.random.default_rng(seed)
    labels, _ = _cal_labels(res)

    cfg = cfg.with_reliability(snooping=False).with_statistics(compute=False)
    acc = np.zeros((len(labels), len(labels)))
    for _ in range(int(draws)):
        d = {k: without_calibration_part(replace(g, value_px=g.sample(rng))).value_px for k, g in grids.items()}
        pair = []
        for sign in (1.0, -1.0):
            gk = {k: replace(g, value_px=g.value_px + sign * d[k]) for k, g in grids.items()}
            pair.append(_cal_values(adjust(apply_grids(block, gk), cfg), labels))
        dv = 0.5 * (pair[0] - pair[1])
        acc += np.outer(dv, dv)
    return acc / max(int(draws), 1)


def covariance_fit_spread(xy: NDArray[np.float64], cov: CovarianceFit, width: int, height: int, draws: int = 16,
                          seed: int = 0) -> NDArray[np.float64]:
    """The sampling covariance of a detrended covariance fit (:func:`fit_covariance` with ``detrend_format``) in
    ``(log c0, log L)``, by parametric bootstrap: ``draws`` fields drawn from the fitted function itself
    (:func:`random_field_deformation`: the Gaussian signal, plus the nugget as white noise) at the positions ``xy``
    the fit used, each fitted again the same way.  Most of the spread is the field's own: a format only a few
    correlation lengths across holds few independent patches of it (600 x 400 px, L 120 px: sd of log c0 about
    0.3-0.45, of log L about 0.2)."""
    rng = np.random.default_rng([int(seed), 1207])
    max_d = 0.5 * float(np.hypot(width, height))
    # the lattice of the draw no finer than about 1500 nodes (its eigen-decomposition), however short the length
    spacing = max(cov.length_px / 6.0, float(np.sqrt(width * height / 1500.0)))
    out = []
    for _ in range(int(draws)):
        f = random_field_deformation(float(np.sqrt(cov.c0)), cov.length_px, width, height, rng, spacing)
        v = f(xy) + np.sqrt(max(cov.nugget, 0.0)) * rng.standard_normal((len(xy), 2))
        cf = fit_covariance(xy, v, max_d, detrend_format=(width, height))
        out.append([np.log(max(cf.c0, 1e-3 * cov.c0) / cov.c0), np.log(cf.length_px / cov.length_px)])
    return np.atleast_2d(np.cov(np.asarray(out).T))


def grid_hyperparameter_covariance(res: AdjustmentResult, grids: Mapping[str, CorrectionGrid], cfg: AdjustConfig,
                                   draws: int = 16, step: float = 0.1, seed: int = 0
                                   ) -> tuple[NDArray[np.float64], dict[str, list[list[float]]]]:
    """What the calibration covariance of the joint grid adjustment (:func:`joint_grid_adjustment`) omits: its
    collocation prior uses the covariance function fitted from the data as if it were known.  The estimated
    calibration unknowns move with the fitted signal variance ``c0`` and correlation length ``L``; to first order
    (Kackar and Harville 1984, estimated variance components) their covariance gains ``J S J^T``: ``J`` the change of
    the unknowns per unit of ``log c0`` and ``log L`` (the adjustment again with each one changed by ``step``, from
    its converged values), ``S`` the fit's sampling covariance in those (:func:`covariance_fit_spread`, ``draws``
    bootstrap fits at the positions of the camera's residuals), summed over the grids' cameras.

    ``res``: the joint adjustment with the grids' node values as unknowns; ``grids``: its grids.  Returns the
    covariance to add (the ``_cal_labels`` order of ``res``) and, per camera, ``S``."""
    from skyrig.adjust.factors.image_grid import ImageGrids

    labels, _ = _cal_labels(res)
    est = res.block.observations.get("image_grid")
    out = np.zeros((len(labels), len(labels)))
    spreads: dict[str, list[list[float]]] = {}
    if est is None or not grids:
        return out, spreads
    cfg_v = cfg.with_unknowns(image_grid="weighted").with_reliability(snooping=False).with_statistics(compute=False)
    v0 = _cal_values(res, labels)
    sel_of = _grid_residuals(res)
    names = [c.name for c in res.block.cameras]
    for g in est.grids:
        cg = grids.get(g.camera)
        if cg is None:
            continue
        ci = names.index(g.camera)
        cam = res.block.cameras[ci]
        cf = cg.covariance
        S = covariance_fit_spread(res.block.obs_pixel[sel_of[ci][0]], cf, cam.width, cam.height, draws, seed + ci)
        J = []
        for dc, dl in ((step, 0.0), (0.0, step)):
            cf2 = replace(cf, c0=cf.c0 * float(np.exp(dc)), length_px=cf.length_px * float(np.exp(dl)))
            specs = []
            for h in est.grids:
                if h.camera == g.camera:  # the same nodes, the prior of the changed function
                    sp = collocation_prior(h.camera, cam.width, cam.height, cf2, nodes_x=len(h.x_px))
                    sp.value_px = h.value_px.copy()
                    specs.append(sp)
                else:
                    specs.append(h)
            blk = replace(res.block, observations={**res.block.observations, "image_grid": ImageGrids(specs)})
            J.append((_cal_values(_run(blk, cfg_v, f"grid prior of {g.camera} changed"), labels) - v0) / step)
        Jm = np.column_stack(J)
        out += Jm @ S @ Jm.T
        spreads[g.camera] = S.tolist()
    return out, spreads


def collocation_prior(camera: str, width: int, height: int, cov: CovarianceFit, nodes_x: int | None = None,
                      max_fraction: float = 0.01) -> GridSpec:
    """The correction grid of a camera as unknowns of the adjustment: its nodes (``nodes_x`` across, default
    :func:`grid_nodes_for`, the spacing least-squares collocation would use) and the collocation prior of the node
    values (zero mean; covariance ``C(d)`` of the fitted function at the node distances, plus ``max_fraction`` of
    ``c0`` on the diagonal: what bilinear interpolation between nodes of that spacing loses at most, which also keeps
    the prior's inverse bounded), for :mod:`skyrig.adjust.factors.image_grid`."""
    nx = int(nodes_x) if nodes_x else grid_nodes_for(cov, width, height, max_fraction)
    ny = max(2, int(round(nx * height / width)))
    xs = np.linspace(0.0, width - 1.0, nx)
    ys = np.linspace(0.0, height - 1.0, ny)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    C = cov(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2))
    C = C + max_fraction * cov.c0 * np.eye(len(nodes))
    return GridSpec(camera, xs, ys, np.zeros((ny, nx, 2)), C)


def _grid_residuals(res: AdjustmentResult) -> dict[int, tuple[NDArray[np.bool_], NDArray[np.float64]]]:
    """Per camera index, the rows used and the whole systematic error at them (observed minus computed, plus the
    correction grid the adjustment already estimated or applied there)."""
    b = res.block
    gr = res.residuals["image"]
    use = (gr.weight > 0) if gr.weight.ndim == 1 else (gr.weight > 0).all(axis=-1)
    err = -np.asarray(gr.residual, float)
    grids = b.observations.get("image_grid")
    cam_of_obs = b.image_camera[b.obs_image]
    names = [c.name for c in b.cameras]
    if grids is not None:
        for g in grids.grids:
            ci = names.index(g.camera)
            sel = cam_of_obs == ci
            err[sel] += CorrectionGrid(g.camera, g.x_px, g.y_px, g.value_px, np.zeros(g.value_px.shape[:2]),
                                       None, 0).at(b.obs_pixel[sel])  # type: ignore[arg-type]
    return {ci: (use & (cam_of_obs == ci), err) for ci in range(len(b.cameras))}


def _estimated_grids(r: AdjustmentResult, fits: dict[str, CovarianceFit]) -> dict[str, CorrectionGrid]:
    """The correction grids the adjustment ``r`` estimated, with their posterior sigma and factor (from its
    covariance) and the covariance fit each was set up from."""
    grids: dict[str, CorrectionGrid] = {}
    est = r.block.observations.get("image_grid")
    if est is not None and r.covariance is not None:
        lab = r.layout.labels
        pos = {q: j for j, q in enumerate(lab)}
        Q = r.covariance.Qcc * r.sigma0 ** 2
        for g in est.grids:
            ny, nx = g.value_px.shape[:2]
            ix = [pos[("image_grid", g.camera, f"x{iy}_{jx}")] for iy in range(ny) for jx in range(nx)]
            Qx = Q[np.ix_(ix, ix)]
            lam, V = np.linalg.eigh(0.5 * (Qx + Qx.T))
            factor = V * np.sqrt(np.clip(lam, 0.0, None))
            ci = [c.name for c in r.block.cameras].index(g.camera)
            n_obs = int(np.sum(r.block.image_camera[r.block.obs_image] == ci))
            # the posterior sigma and factor of the x values (the prior is the same for y; their posteriors differ
            # only by the observations' geometry)
            grids[g.camera] = CorrectionGrid(g.camera, g.x_px, g.y_px, g.value_px.copy(),
                                             np.sqrt(np.clip(np.diag(Qx), 0.0, None)).reshape(ny, nx),
                                             fits[g.camera], n_obs, factor)
    return grids


def joint_grid_adjustment(block: Block, res: AdjustmentResult, cfg: AdjustConfig, nodes_x: int | None = None,
                          max_cycles: int = 3, what: str = "joint (IO, boresights, datum shift) with correction grids",
                          min_signal_fraction: float = 0.05, min_signal_chi2: float = 25.0,
                          cameras: Sequence[str] | None = None
                          ) -> tuple[AdjustmentResult, dict[str, CorrectionGrid], int]:
    """The correction grids estimated *in* the adjustment, together with the calibration (module docstring).

    ``block``: the block at the values of ``res`` (an adjustment without grids, e.g. the joint one); ``cfg`` its
    configuration.  Per camera, the residuals of ``res`` give the covariance function (:func:`fit_covariance`) and
    from it the nodes and the collocation prior (:func:`collocation_prior`); the block is adjusted with the node
    values as unknowns (``image_grid="weighted"``).  The covariance function is fitted again to the whole
    deformation (the new residuals plus the estimated grid) and the adjustment repeated while its signal variance or
    correlation length moves by more than 10 % (``max_cycles`` adjustments at most).  Returns the adjustment (its
    covariance holds the grids' uncertainty), the grids (values and posterior sigma from it) and the cycles run.

    ``min_signal_fraction``: a camera whose fitted signal variance is below this fraction of its noise variance gets
    no grid.  A covariance fitted to noise can show a weak signal with a correlation length of a few pixels, and
    :func:`grid_nodes_for` then asks for thousands of nodes (simulated MIDAS flight, 1200 px, seed 2: a 52 x 35 grid
    for a forward-camera "signal" of 1.4 % of the noise variance with a 15 px correlation length), which costs time
    and changes nothing: without those grids the recipe ran 77 s instead of 695 s, the nadir grid and the IO the same
    to 0.06 sigma).  Default 5 % (a signal RMS under 0.22 of the noise sigma); 0 gives every camera with a fitted
    signal its grid.  A camera whose fitted correlation length is under the width of the first distance bin gets
    no grid either: the fit then rests on that one bin's excess over the nugget (simulated MIDAS flight, 600 px,
    random nadir field, seed 2: forward camera c0 10 % of the noise, L 7.5 px = half a bin, the first bin 2 standard
    errors above zero and the others at zero), is not resolved from noise, and would ask for the most nodes
    (61 across).  Nor does a camera whose fitted signal lowers the chi-square of the binned covariance (against
    the nugget alone, white-noise standard errors) by less than ``min_signal_chi2`` (default 25, i.e. a 5-sigma
    signal; 400 px, seed 1: an oblique "signal" at L 12 px passed the two rules above and cost minutes).
    ``cameras``: the camera names that may get a grid (default: every camera)."""
    from skyrig.adjust.factors.image_grid import ImageGrids

    cfg_g = cfg.with_unknowns(image_grid="weighted")
    b0 = block
    fits: dict[str, CovarianceFit] = {}
    r, cycles = res, 0
    for cycles in range(1, int(max_cycles) + 1):
        rb = r.block
        specs = []
        new_fits = {}
        prev = rb.observations.get("image_grid")
        prev_by = {g.camera: g for g in prev.grids} if prev is not None else {}
        for ci, (sel, err) in _grid_residuals(r).items():
            cam = rb.cameras[ci]
            if sel.sum() < 10 or (cameras is not None and cam.name not in cameras):
                continue
            max_d = 0.5 * float(np.hypot(cam.width, cam.height))
            # (the residuals lack the part of the deformation the IO and boresight took: fitted as detrended)
            cf = fit_covariance(rb.obs_pixel[sel], err[sel], max_d, detrend_format=(cam.width, cam.height))
            if not cf.c0 > 0 or cf.c0 < min_signal_fraction * cf.nugget:
                continue
            if cf.significance < min_signal_chi2:
                # pairs share points, so the bins are not independent; the bar is set far above noise's values
                log.info("calqc grid %s: no grid (the fitted signal, c0 %.2g px^2, L %.0f px, lowers the binned "
                         "covariance's chi-square by only %.1f < %.0f: not told from noise)", cam.name, cf.c0,
                         cf.length_px, cf.significance, min_signal_chi2)
                continue
            if cf.length_px < max_d / len(cf.bins_px):
                # a correlation length under the first distance bin: only that bin's excess over the nugget carries
                # the "signal" (the fit sits at its lower bound), which is not resolved and is as likely noise
                log.info("calqc grid %s: no grid (fitted correlation length %.1f px under the %.1f px distance bin; "
                         "c0 %.2g px^2 is not resolved from the noise)", cam.name, cf.length_px,
                         max_d / len(cf.bins_px), cf.c0)
                continue
            new_fits[cam.name] = cf
            spec = collocation_prior(cam.name, cam.width, cam.height, cf, nodes_x)
            old = prev_by.get(cam.name)
            if old is not None and old.value_px.shape == spec.value_px.shape:
                spec.value_px = old.value_px.copy()  # the same nodes: start from the last estimate
            specs.append(spec)
        if not specs:
            return r, {}, cycles - 1
        moved = (not fits or set(fits) != set(new_fits) or any(
            abs(new_fits[k].c0 / fits[k].c0 - 1) > 0.1 or abs(new_fits[k].length_px / fits[k].length_px - 1) > 0.1
            for k in new_fits))
        if not moved:
            cycles -= 1
            break
        fits = new_fits
        bg = replace(b0, cameras=list(rb.cameras), head_boresight=rb.head_boresight.copy(),
                     datum_shift=rb.datum_shift.copy(), lever_arm=rb.lever_arm.copy(),
                     observations={**b0.observations, "image_grid": ImageGrids(specs)})
        r = _run(bg, cfg_g, f"{what}, cycle {cycles}")
        for k, cf in fits.items():
            log.info("calqc grid %s: c0 %.4f px^2, L %.0f px, nugget %.4f px^2", k, cf.c0, cf.length_px, cf.nugget)
    return r, _estimated_grids(r, fits), cycles


def apply_grids(block: Block, grids: Mapping[str, CorrectionGrid]) -> Block:
    """The block with each camera's image coordinates corrected by its grid."""
    px = block.obs_pixel.copy()
    cam_of_obs = block.image_camera[block.obs_image]
    for ci, cam in enumerate(block.cameras):
        g = grids.get(cam.name)
        sel = cam_of_obs == ci
        if g is not None and sel.any():
            px[sel] = g.correct(px[sel])
    return replace(block, obs_pixel=px)
