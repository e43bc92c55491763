"""calqc's design study (issue 12: "with one flight direction only, the recipe names the inseparable unknowns and
the flight that would separate them"): the multiple correlation against an independent regression, and on the
simulated MIDAS flight the unknowns named with one direction / one height against what the real flight with the
other direction / height gives (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.calibrate.calqc import _multiple_correlation


def test_multiple_correlation_equals_the_r2_of_a_regression_on_the_others() -> None:
    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 6))
    A[:, 5] = A[:, 0] + 0.1 * A[:, 5]  # one unknown nearly a copy of another
    cov = A.T @ A
    _, rho = _multiple_correlation(cov)
    x = rng.multivariate_normal(np.zeros(6), cov, size=200_000)
    for i in range(6):
        others = np.column_stack([np.delete(x, i, axis=1), np.ones(len(x))])
        coef, *_ = np.linalg.lstsq(others, x[:, i], rcond=None)
        r2 = 1.0 - np.var(x[:, i] - others @ coef) / np.var(x[:, i])
        assert rho[i] ** 2 == pytest.approx(r2, abs=5e-3)
    assert rho[0] > 0.99 and rho[5] > 0.99


def _run(directions: str, heights: str):  # type: ignore[no-untyped-def]
    from skyrig.calibrate.calqc import calibrate_calqc, midas_calqc_scenario

    data, _ = midas_calqc_scenario("reduced", 1, tie_points=800, camera_width_px=600, directions=directions,
                                   heights=heights)
    return calibrate_calqc(data, variants=False, grid=False)


def _entry(design, label):  # type: ignore[no-untyped-def]
    for es in design["by_head"].values():
        for e in es:
            if tuple(e["unknown"]) == label:
                return e
    return None


def _unknown(design, label):  # type: ignore[no-untyped-def]
    return next(u for u in design["unknowns"] if tuple(u["unknown"]) == label)


@pytest.mark.slow
def test_one_direction_names_the_datum_shift_and_the_opposite_direction_the_real_flight_confirms() -> None:
    one = _run("one", "both").design
    both = _run("both", "both").design
    assert "opposite-direction" in one["flights_tried"] and "opposite-direction" not in both["flights_tried"]
    for a in "XY":
        lab = ("datum_shift", "gnss", a)
        e = _entry(one, lab)
        assert e is not None and e["separating_flight"] == "opposite-direction", e
        # the prediction against the flight really flown in both directions (same seed, its own strips)
        pred = e["with_flight"]["opposite-direction"]
        real = _unknown(both, lab)
        assert pred["sigma"] == pytest.approx(real["sigma"], rel=0.15)
        assert pred["multiple_correlation"] < 0.5 and real["multiple_correlation"] < 0.5 < e["multiple_correlation"]
        assert _entry(both, lab) is None  # nothing left to name about it with both directions
    # a principal point and the boresight about the other image axis: inseparable whatever is flown, in both
    for head, cam in (("forward", "midas-forward-50mm"), ("backward", "midas-backward-50mm")):
        for d in (one, both):
            e = _entry(d, ("intrinsics", cam, "ppy_mm"))
            assert e is not None and e["separating_flight"] is None and e["head"] == head
            assert ["boresight", head, "rx"] in [p["unknown"] for p in e["partners"]]


@pytest.mark.slow
def test_one_height_names_the_nadir_principal_distance_with_the_vertical_datum_shift() -> None:
    low = _run("one", "low")
    e = _entry(low.design, ("intrinsics", "midas-nadir-28mm", "focal_mm"))
    assert e is not None and e["head"] == "nadir" and e["separating_flight"] == "second-height", e
    assert ["datum_shift", "gnss", "Z"] in [p["unknown"] for p in e["partners"]]
    # the real second height (same seed) lowers that correlation, as the design study says a second height would
    two = _run("one", "both").design

    def r(d):  # type: ignore[no-untyped-def]
        labs = [tuple(x) for x in d["labels"]]
        return d["correlation"][labs.index(("intrinsics", "midas-nadir-28mm", "focal_mm"))][
            labs.index(("datum_shift", "gnss", "Z"))]

    assert abs(r(two)) < abs(r(low.design)) - 0.1
