"""``calibrate_calqc``'s stated covariance against the truth of many seeded simulations (issue 12: "Normalised errors
of every estimated calibration parameter over >= 20 seeds are consistent with N(0,1)").

Each seed draws a new simulated MIDAS boresight flight (two heights, both directions, IO errors and a GNSS datum
shift; :func:`skyrig.calibrate.calqc.midas_calqc_scenario`) and a new smooth random deformation of the nadir camera
from the simulation's own covariance function (Gaussian, :func:`~skyrig.calibrate.calqc.random_field_deformation`);
the recipe runs with its correction grid as unknowns of the adjustment and fits the grid's covariance function from
the data itself.  The a-priori sigmas are the simulated noise.  The tolerances come from the number of draws only:
every test at the 1 % level.

The small tests check the statistics helpers the bench and this test use against closed forms.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2, kstest, norm

from skyrig.adjust.stats import sidak_z
from skyrig.calibrate.calqc import within_sigma_summary

SEEDS = 20
WIDTH, TIES = 400, 400  # reduced flight; the per-seed cost is mostly the adjustments' (a few seconds each)
DEFORMATION_PX = 0.05  # RMS per component of the nadir field: about 0.5 of the image noise (0.096 px at 400 px)


def test_family_wise_bound_is_sidak_and_matches_a_simulation() -> None:
    # closed form: P(all n |z| <= b) = (2 Phi(b) - 1)^n = level
    b = sidak_z(33)
    assert (2 * norm.cdf(b) - 1) ** 33 == pytest.approx(0.95, abs=1e-9)
    assert b == pytest.approx(3.1646, abs=1e-3)
    # independent: share of 20,000 simulated sets of 33 N(0,1) values inside the bound (binomial sigma 0.0015)
    z = np.random.default_rng(0).standard_normal((20000, 33))
    assert np.mean(np.all(np.abs(z) <= b, axis=1)) == pytest.approx(0.95, abs=0.006)
    s = within_sigma_summary(np.r_[np.zeros(31), 2.5, -3.3])
    assert s["within_k"] == 31 and s["n"] == 33 and not s["within_family_wise_bound"]
    assert s["probability_all_within_k"] == pytest.approx(np.mean(np.all(np.abs(z) <= 2, axis=1)), abs=0.01)


def test_random_field_deformation_has_the_stated_covariance() -> None:
    from skyrig.calibrate.calqc import random_field_deformation

    W, H, L, a = 300, 200, 60.0, 0.3
    p = np.random.default_rng(0).uniform([0, 0], [W - 1 - L, H - 1], (200, 2))
    d = [[], [], []]
    for s in range(60):  # 60 draws x 200 positions (about 15 independent patches a draw)
        f = random_field_deformation(a, L, W, H, np.random.default_rng(s))
        for k, off in enumerate((0.0, 0.5 * L, L)):
            d[k].append(f(p + [off, 0.0]))
    d0, dh, d1 = (np.array(x) for x in d)
    # variance a^2 at a point, a^2 exp(-(d/L)^2) between points d apart (relative sigma of these means ~0.05)
    assert np.mean(d0 * d0) == pytest.approx(a * a, rel=0.15)
    assert np.mean(d0 * dh) == pytest.approx(a * a * np.exp(-0.25), rel=0.15)
    assert np.mean(d0 * d1) == pytest.approx(a * a * np.exp(-1.0), rel=0.2)
    # smooth: the field over 1 px changes by far less than its amplitude
    f = random_field_deformation(a, L, W, H, np.random.default_rng(1))
    q = np.random.default_rng(2).uniform([0, 0], [W - 1, H - 1], (500, 2))
    assert np.abs(f(q + [1.0, 0.0]) - f(q)).max() < 0.1 * a


@pytest.mark.slow
def test_calqc_normalised_errors_over_seeds_are_standard_normal() -> None:
    from skyrig.calibrate.calqc import calibrate_calqc, midas_calqc_scenario, normalised_errors

    zs, ws = [], []
    for seed in range(1, SEEDS + 1):
        data, truth = midas_calqc_scenario("reduced", seed, tie_points=TIES, camera_width_px=WIDTH,
                                           deformation_px=DEFORMATION_PX, deformation="random")
        # (steps 2-3 once: the values and the covariance are those of the joint adjustment with the grid, which
        # starts there and converges by itself; the repetitions only make the stepwise recipe reach it)
        cal = calibrate_calqc(data, variants=False, grid=True, design=False, max_cycles=1, **truth.simulated_sigmas())
        z, w = normalised_errors(cal, truth)
        zs.append(list(z.values()))
        ws.append(w)
    z = np.array(zs)  # (seeds, 33): every head's boresight and IO, the datum shift
    w = np.concatenate(ws)  # independent N(0,1) under the hypothesis
    n = w.size
    # the whitened errors: KS against N(0,1), and their sum of squares inside the chi-square interval (1 %)
    assert kstest(w, "norm").pvalue > 0.01
    lo, hi = chi2.ppf([0.005, 0.995], n)
    assert lo < float(w @ w) < hi, (float(w @ w) / n, lo / n, hi / n)
    # every parameter over the seeds (independent draws): KS against N(0,1), 33 tests at 1 % family-wise (Sidak)
    p_min = min(kstest(z[:, j], "norm").pvalue for j in range(z.shape[1]))
    assert 1.0 - (1.0 - p_min) ** z.shape[1] > 0.01
    # and its spread: the RMS of each parameter's 20 z's inside the chi-square interval for 20 values (Sidak 1 %)
    a = 1.0 - 0.99 ** (1.0 / z.shape[1])
    lo, hi = np.sqrt(chi2.ppf([a / 2, 1 - a / 2], SEEDS) / SEEDS)
    rms = np.sqrt(np.mean(z * z, axis=0))
    assert np.all((rms > lo) & (rms < hi)), (rms.round(2), lo, hi)
