"""The measuring aid on real images (issue 32's acceptance "the opensfm berlin GCPs found within 2 px of their
published image measurements"): ``bench/measure_berlin.py`` drives :class:`skyrig.web.measure.MeasureSession`
(one image measured -> prediction -> ``propose(..., "lsm")`` in the others; leave one out by intersection) on the
three phone images, against the published ODM measurements.

Measured (adjust0 block of bench/real.py, 2026-11-29), the page's refinement with a cross-correlation search
within 3 sigma of the prediction (``propose(..., search_px=)``, :func:`skyrig.match.lsm.search_lsm`): one image
measured, 44 cases: 7 within 2 px (the predictions alone: 0; prediction RMS 21.6 px), 20 refined, their RMS 5.2 px;
leave one out, 18 cases: 1 within 2 px (prediction RMS 12.3 px), 11 refined, RMS 5.9 px.  Without the search (LSM
from the prediction, as before): 1/44 and 0/18.

Why 2 px is out of reach on this block: 2 px agreement is below what the block's geometry can confirm at these
points.  The published measurements, intersected all three together (6 points seen in 3 images), leave residuals
of 3.6 px RMS (max 6.7 px); one published measurement with the two LSM proposals (correlation 0.92-1.00) leaves
4.3 px RMS (max 6.8 px), against an orientation whose 4,077 tie observations fit to 0.53 / 0.34 px RMS.  So
neither the clicks nor the matched homologues are consistent with the orientation to 2 px at these natural points
(plausible causes, not verified here: points on building edges at depth discontinuities, several near the frame
edge where the self-calibrated phone distortion is least determined, wide-baseline views); which of the two is
nearer the truth cannot be told from these three images.  Scored instead against the intersection-consistent
positions (every published measurement of the point intersected and projected back into each image; the bench
prints both): 9/44 (one image) and 2/18 (leave one out) within 2 px, refined RMS 5.7 / 5.9 px, while the published
measurements themselves lie 3.3 / 3.6 px RMS from those positions: the proposals are no nearer the block's
consistent positions than the published clicks, so this does not rescue the 2 px line either (measured
2026-11-29).  Through OpenSfM's own reconstruction instead of skyrig's block the published clicks disagree the same
(3.6 px RMS, 6 of 18 within 2 px of their own intersection): the judge asks a proposal to reproduce click errors
of several pixels, which even the block-consistent position cannot.  The 2 px acceptance is kept as a strict xfail.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow
sys.path.insert(0, str(ROOT / "bench"))


@pytest.fixture(scope="module")
def cases():
    data = shared_path("opensfm", "berlin").parents[1]
    sys.path.insert(0, str(ROOT / "bench"))
    from measure_berlin import evaluate

    work = Path(os.environ.get("SKYRIG_REAL_WORK", "/tmp/skyrig-real"))
    return evaluate(data, work, 0)


def test_berlin_cases_complete(cases):
    """Every published measurement is proposed from every other image of its point (26 measurements of 10 points:
    44 ordered pairs) and, for the 6 points seen in 3 images, from the other two (18)."""
    assert len(cases["one"]) == 44 and len(cases["loo"]) == 18


def test_berlin_refinement_beats_prediction(cases):
    """The searched refinement brings proposals nearer the published clicks than the predictions: more within
    2 px, a smaller median error; a proposal never lies beyond its search radius + 3 px from its start."""
    from measure_berlin import summary

    for key, least in (("one", 15), ("loo", 8)):
        s = summary(cases[key])
        e = np.array([c["error_px"] for c in cases[key]])
        s0 = np.array([c["start_px"] for c in cases[key]])
        assert s["refined"] >= least and s["within_tol"] > s["start_within_tol"], s
        assert np.median(e) < np.median(s0), (np.median(e), np.median(s0))
        assert s["rms_refined_px"] < 7.0, s
        assert np.all(e <= s0 + np.array([c["search_px"] for c in cases[key]]) + 3.0 + 1e-6)


def test_berlin_published_consistency(cases):
    """The reason for the xfail below: on an orientation that fits its tie points to about half a pixel, the
    published measurements disagree with their own intersection by more than 2 px RMS (measured 3.6 px), and so
    do the matched homologues (one published + two proposals: 4.3 px)."""
    r = np.array([c["residual_px"] for c in cases["consistency"]])
    assert len(r) == 18
    assert 2.0 < np.sqrt(np.mean(r**2)) < 6.0
    q = np.array([c["residual_px"] for c in cases["proposal_consistency"]])  # one published + two proposals
    assert len(q) >= 6 and 2.0 < np.sqrt(np.mean(q**2)) < 6.0


def test_berlin_published_clicks_disagree_through_opensfms_own_reconstruction():
    """The judge of the xfail below, checked against the peer's orientation instead of skyrig's: through OpenSfM's
    own reconstruction of the three images (``reconstruction_example.json``, fitting OpenSfM's own features to
    about a pixel: test_opensfm_io), the published clicks of the 6 points seen in 3 images disagree with their own
    intersection by 3.6 px RMS (max 8.0 px), as through skyrig's block (3.6 px): the disagreement is the clicks',
    not skyrig's orientation.  Residuals understate the clicks' errors (the intersection absorbs part of them), yet
    only 6 of the 18 clicks lie within 2 px of even their own intersection: a proposal at the block-consistent
    position, the best any refinement can aim for, would meet "within 2 px of the published measurement" for about
    a third of them, not the 90 % the test below asks.  The points seen twice (one redundant coordinate) agree to
    0.6 px."""
    from measure_berlin import opensfm_consistency

    res = opensfm_consistency(shared_path("opensfm", "berlin").parents[1])
    three = np.array([c["residual_px"] for c in res if c["n_images"] == 3])
    two = np.array([c["residual_px"] for c in res if c["n_images"] == 2])
    assert len(three) == 18 and len(two) == 8
    assert 2.0 < np.sqrt(np.mean(three**2)) < 6.0 and np.mean(three <= 2.0) < 0.5
    assert two.max() < 1.0


@pytest.mark.xfail(strict=True, reason="published clicks and matched homologues are both only ~4 px consistent "
                   "with the block at these points (test_berlin_published_consistency): 7/44 (one image) and 1/18 "
                   "(leave one out) within 2 px")
def test_berlin_within_2px(cases):
    from measure_berlin import summary

    for key in ("one", "loo"):
        s = summary(cases[key])
        assert s["within_tol"] >= 0.9 * s["cases"], (key, s)
