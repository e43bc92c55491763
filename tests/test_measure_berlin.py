"""The measuring aid on real images (issue 32's acceptance "the opensfm berlin GCPs found within 2 px of their
published image measurements"): ``bench/measure_berlin.py`` drives :class:`skyrig.web.measure.MeasureSession` on the
three phone images against the published ODM measurements: each published measurement in turn taken as the user's
one click, the point predicted in the other images along that click's ray (depth from the surveyed point) and
``propose(..., "lsm")`` there (:func:`skyrig.match.propagate.propagate_point`: the template warped by the maps
planes through the point induce, cross-correlation within 3 sigma of the prediction, affine least-squares matching,
refused below 0.85 or where the correlation peak is not unique; from every image measured, the matches averaged);
and leave one out (the two others measured, the third predicted by their intersection).

Measured (adjust0 block of bench/real.py, 2026-11-29): one image measured, 44 cases: 12 within 2 px of the published
measurement (the ray predictions alone: 8, RMS 10.9 px), 31 refined, their RMS 4.1 px (median of all 3.9 px); per
point within 2 px / refined / cases: g01 0/6/6, g02 3/6/6, g03 2/2/2, g04 0/0/6, g05 0/3/6, g06 2/2/2, g07 0/4/6,
g08 2/6/6, g09 2/0/2, g10 1/2/2.  Leave one out, 18 cases: 5 within 2 px, 13 refined, RMS 4.4 px.  (Before, LSM
from the ground prediction with the ground-plane map and the identity: 7/44 and 1/18, refined RMS 5.2 / 5.9 px.)

Why 2 px is out of reach: the published clicks are not repeatable to 2 px on these natural points (a blank patch of
sunlit wall g05, a dark blot in a railing g07, a small square on a pipe clicked left, right and at the centre of it
in the three images g01), while the matching is: the proposal in B from A's click and the proposal in B through C
(A -> C, then C -> B) agree to 0.20 px RMS (20 chains, all within 2 px); A -> B and B -> A err by opposite amounts
(``e_AB + M e_BA`` 0.65 px RMS over 13 pairs where the errors are 3.4 px RMS: the matching lands on the homologue
of the click it starts from, the error is the two clicks' disagreement); one click and its two proposals intersect
through OpenSfM's own reconstruction with 1.47 px RMS residuals; and the published clicks, intersected all
three together, leave 3.6 px RMS (through skyrig's block and through OpenSfM's own reconstruction alike).  A
proposal that lands on the homologue of A's click differs from B's click by both clicks' errors.  The 2 px
acceptance is kept as a strict xfail.
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

    for key, least in (("one", 25), ("loo", 10)):
        s = summary(cases[key])
        e = np.array([c["error_px"] for c in cases[key]])
        s0 = np.array([c["start_px"] for c in cases[key]])
        assert s["refined"] >= least and s["within_tol"] > s["start_within_tol"], s
        assert np.median(e) < np.median(s0), (np.median(e), np.median(s0))
        assert s["rms_refined_px"] < 5.5, s
        assert np.all(e <= s0 + np.array([c["search_px"] for c in cases[key]]) + 3.0 + 1e-6)


def test_berlin_matching_is_self_consistent(cases):
    """The matching alone, no published measurement of the target image entering: the proposal in B from A's click
    and the one through C (A -> C proposed, accepted, then C -> B) agree to well under a pixel (measured 0.20 px RMS
    over 20 chains, all within 2 px), where the published clicks disagree by 3.6 px RMS."""
    d = np.array([c["difference_px"] for c in cases["chain"]])
    assert len(d) >= 15, len(d)
    assert np.sqrt(np.mean(d**2)) < 0.5 and np.all(d <= 2.0), d


def test_berlin_errors_are_the_clicks_disagreement(cases):
    """There and back: where A -> B and B -> A are both refined, their errors against the published clicks are
    opposite (``e_AB + M e_BA`` vanishes when each match lands on the homologue of the click it starts from, the
    clicks' errors whatever they are; ``M`` the local map A -> B): measured 0.65 px RMS over 13 pairs against errors
    of 3.4 px RMS."""
    rv = cases["reversal"]
    cl = np.array([c["closure_px"] for c in rv])
    e = np.array([[c["error_px"], c["back_error_px"]] for c in rv])
    assert len(rv) >= 10, len(rv)
    assert np.sqrt(np.mean(cl**2)) < 1.0 and np.sqrt(np.mean(cl**2)) < 0.35 * np.sqrt(np.mean(e**2)), (cl, e)


def test_berlin_published_consistency(cases):
    """The reason for the xfail below: on an orientation that fits its tie points to about half a pixel, the
    published measurements disagree with their own intersection by more than 2 px RMS (measured 3.6 px), and so
    do the matched homologues (one published + two proposals: 3.4 px) through skyrig's block; through OpenSfM's
    reconstruction the same homologues agree to 1.5 px (test below): at these points skyrig's three-image block
    (self-calibrated phone camera) is the weaker judge."""
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


def test_berlin_proposals_agree_through_opensfms_own_reconstruction(cases):
    """The matched homologues judged by the peer's orientation (``reconstruction_example.json``): one published
    measurement and its two proposals, intersected, leave 1.47 px RMS (max 2.85; g01 and g08 about 0.5 px) where the
    three published clicks leave 3.59 px: the proposals are images of one point, the clicks are not."""
    from measure_berlin import opensfm_consistency, opensfm_proposal_consistency

    data = shared_path("opensfm", "berlin").parents[1]
    r = np.array([c["residual_px"] for c in opensfm_proposal_consistency(data, cases["one"])])
    clicks = np.array([c["residual_px"] for c in opensfm_consistency(data) if c["n_images"] == 3])
    assert len(r) >= 24, len(r)
    assert np.sqrt(np.mean(r**2)) < 2.0 and np.sqrt(np.mean(r**2)) < 0.5 * np.sqrt(np.mean(clicks**2)), (r, clicks)


@pytest.mark.xfail(strict=True, reason="the published clicks of these natural points are repeatable to ~4 px, the "
                   "matching to 0.2 px (test_berlin_matching_is_self_consistent): 12/44 (one image) and 5/18 (leave "
                   "one out) within 2 px")
def test_berlin_within_2px(cases):
    from measure_berlin import summary

    for key in ("one", "loo"):
        s = summary(cases[key])
        assert s["within_tol"] >= 0.9 * s["cases"], (key, s)
