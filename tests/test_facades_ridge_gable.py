"""Gabled roofs measured in part only (skyrig.dense.buildings.fit_ridge_gable and extract_buildings' ridge_gable).

A seeded synthetic DSM: a gabled house (ridge turned 17 deg from the grid) cut by the survey's border nearly along
its ridge, so that one eave lies beyond it and the ridge is not in the middle of what was measured (the case of a
house at a block's edge).  Cell heights are the true roof at the cell centres plus white noise of SIGMA.  The truth
is the house's parameters; the tolerances come from the noise: the predicted covariance sigma^2 (J^T J)^-1 of the
six ridge parameters at the true values over the same cells (J the model's, not the fit's), and errors must lie
within 4.5 predicted sigmas (about one in 10^5 per parameter for a correct fit).  Surfaces that are not a gable
(one plane, a valley, a tree crown) must not get a ridge.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.dense.buildings import ExtractionConfig, extract_buildings, fit_ridge_gable
from skyrig.dense.grid import DsmGrid, GridSpec
from skyrig.georef.eo import WorldFrame

CELL = 0.3
SIGMA = 0.05
N = 140
THETA = np.radians(17.0)  # ridge direction from +x
CTR = np.array([500021.0, 5800021.0])
HALF_ACROSS, HALF_ALONG = 6.0, 8.0
GROUND, EAVE, RIDGE = 100.0, 106.0, 110.0
SLOPE = (RIDGE - EAVE) / HALF_ACROSS
T = np.array([np.cos(THETA), np.sin(THETA)])
NRM = np.array([-T[1], T[0]])


def _grid() -> GridSpec:
    return GridSpec(500000.0, 5800042.0, CELL, N, N)


def _cells():
    g = _grid()
    xx, yy = g.cell_centres()
    P = np.stack([xx, yy], axis=-1)
    u, v = (P - CTR) @ NRM, (P - CTR) @ T
    house = (np.abs(u) <= HALF_ACROSS) & (np.abs(v) <= HALF_ALONG)
    measured = u < 3.0 + 0.15 * v  # the survey's border: nearly along the ridge, one eave beyond it
    return g, P, u, v, house, measured


def _dsm(roof) -> tuple[DsmGrid, np.ndarray, np.ndarray]:
    g, P, u, v, house, measured = _cells()
    z = np.where(house, roof(u, v), GROUND)
    z = z + np.random.default_rng(11).normal(0.0, SIGMA, z.shape)
    h = np.where(measured, z, np.nan).astype(np.float32)
    ok = np.isfinite(h)
    dsm = DsmGrid(g, WorldFrame.map("EPSG:25832"), h, ok.astype(np.int16) * 4,
                  np.where(ok, SIGMA, np.nan).astype(np.float32), np.where(ok, SIGMA, np.nan).astype(np.float32),
                  np.zeros(h.shape, bool))
    inner = house & measured & (np.abs(u) <= HALF_ACROSS - 2 * CELL) & (np.abs(v) <= HALF_ALONG - 2 * CELL)
    inner &= u < 3.0 + 0.15 * v - 2 * CELL
    return dsm, P, inner


def _gable(u, v):
    return RIDGE - SLOPE * np.abs(u)


def _model(p, Q):
    th, u0, c, g, alo, ahi = p
    t = np.array([np.cos(th), np.sin(th)])
    n = np.array([-t[1], t[0]])
    d = Q @ n - u0
    return c + g * (Q @ t) + alo * np.minimum(d, 0) + ahi * np.maximum(d, 0)


def _truth_and_covariance(xy, fit):
    """The true six parameters in the fit's parametrisation (plan origin: the cells' median, as the fit) and their
    predicted covariance sigma^2 (J^T J)^-1 at the truth, with J the model's Jacobian there (not the fit's)."""
    m = np.median(xy, axis=0)
    Q = xy - m
    th = THETA if np.dot(fit.direction, T) > 0 else THETA + np.pi
    t = np.array([np.cos(th), np.sin(th)])
    n = np.array([-t[1], t[0]])
    p_true = np.array([th, float((CTR - m) @ n), RIDGE, 0.0, SLOPE, -SLOPE])
    J = np.empty((len(xy), 6))
    for k in range(6):
        dp = np.zeros(6)
        dp[k] = 1e-6
        J[:, k] = (_model(p_true + dp, Q) - _model(p_true - dp, Q)) / 2e-6
    cov = SIGMA ** 2 * np.linalg.inv(J.T @ J)
    return m, t, n, p_true, J, cov


def test_a_gable_measured_in_part_is_found_with_its_ridge_within_the_noise():
    dsm, P, inner = _dsm(_gable)
    xy, z = P[inner], np.asarray(dsm.height, float)[inner]
    fit = fit_ridge_gable(xy, z, cell_m=CELL, noise_m=SIGMA)
    assert fit is not None and fit.accepted, fit
    # measured unevenly: the ridge is not in the middle of what was measured
    assert abs(np.median((xy - CTR) @ NRM)) > 1.0
    m, t, n, p_true, J, cov = _truth_and_covariance(xy, fit)
    se = np.sqrt(np.diag(cov))
    ang = np.arctan2(fit.direction[1], fit.direction[0]) - p_true[0]
    ang = (ang + np.pi / 2) % np.pi - np.pi / 2
    u0_fit = float((fit.origin - m) @ n)
    z_ridge_at_m = fit.ridge_z + fit.ridge_slope * float((m - fit.origin) @ fit.direction)
    sides = fit.slopes if np.dot(fit.normal, n) > 0 else (-fit.slopes[1], -fit.slopes[0])
    err = np.array([ang, u0_fit - p_true[1], z_ridge_at_m - RIDGE, fit.ridge_slope * np.dot(fit.direction, t),
                    sides[0] - SLOPE, sides[1] + SLOPE])
    assert np.all(np.abs(err) <= 4.5 * se), (err, se)
    # the roof surface itself over the measured cells
    dz = fit.height(xy) - _gable((xy - CTR) @ NRM, None)
    se_z = np.sqrt(np.einsum("ni,ij,nj->n", J, cov, J))
    assert np.all(np.abs(dz) <= 4.5 * se_z), float(np.max(np.abs(dz) / se_z))
    # the spread is the noise (1.4826 MAD of ~1300 normal residuals: a relative error of ~4 %)
    assert fit.spread == pytest.approx(SIGMA, rel=0.2)


def _roof_error(block, xy):
    planes = []
    for poly in block.roof:
        Pp = np.asarray(poly, float)
        planes.append(np.linalg.lstsq(np.c_[Pp[:, :2], np.ones(len(Pp))], Pp[:, 2], rcond=None)[0])
    roof = np.min([xy @ p[:2] + p[2] for p in planes], axis=0)
    return roof - _gable((xy - CTR) @ NRM, None)


def test_extraction_puts_the_ridge_of_a_cut_gable_where_the_heights_say():
    dsm, P, inner = _dsm(_gable)
    xy = P[inner]
    fit = fit_ridge_gable(xy, np.asarray(dsm.height, float)[inner], cell_m=CELL, noise_m=SIGMA)
    _, _, _, _, J, cov = _truth_and_covariance(xy, fit)
    tol = 4.5 * np.sqrt(np.einsum("ni,ij,nj->n", J, cov, J))

    def block(**kw):
        bl = extract_buildings(dsm, config=ExtractionConfig(max_outside=1.0, **kw))
        bl = [b for b in bl if np.linalg.norm(b.footprint.mean(axis=0) - CTR) < 10.0]
        assert len(bl) == 1
        return bl[0]

    b = block()
    assert len(b.roof) == 2
    err = _roof_error(b, xy)
    assert np.all(np.abs(err) <= tol), float(np.max(np.abs(err) / tol))
    assert abs(b.ground_z - GROUND) <= 3 * SIGMA
    # the rectangle's gable alone puts the ridge in the middle of the measured part, one eave being beyond the
    # border: off by metres there (this is what the ridge fit is for)
    err_rect = _roof_error(block(ridge_gable=False), xy)
    assert np.max(np.abs(err_rect)) > 10 * np.max(tol)


@pytest.mark.parametrize("name, roof", [
    ("one sloping plane", lambda u, v: EAVE + 0.4 * (u + HALF_ACROSS)),
    ("two planes rising away from a valley", lambda u, v: EAVE + SLOPE * np.abs(u)),
    ("a tree crown", lambda u, v: EAVE + 3.0 * np.cos(0.9 * u) * np.cos(0.7 * v) + np.sin(1.7 * u + 0.4 * v)),
])
def test_no_ridge_where_the_heights_do_not_choose_one(name, roof):
    dsm, P, inner = _dsm(roof)
    fit = fit_ridge_gable(P[inner], np.asarray(dsm.height, float)[inner], cell_m=CELL, noise_m=SIGMA)
    assert fit is None or not fit.accepted, (name, fit)
