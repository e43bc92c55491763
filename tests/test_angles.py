"""Known-answer tests for skyrig.geometry.angles (deg / rad / gon)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyrig.errors import UnitError
from skyrig.geometry.angles import (
    check_plausible,
    convert_angle,
    from_radians,
    normalize_unit,
    to_radians,
    wrap_pi,
)


@pytest.mark.parametrize(
    ("value", "src", "dst", "expected"),
    [
        (100.0, "gon", "deg", 90.0),  # a right angle is 100 gon
        (400.0, "gon", "rad", 2.0 * math.pi),  # a full turn
        (180.0, "deg", "rad", math.pi),
        (1.0, "rad", "deg", 57.29577951308232),  # 180/pi, published constant
        (1.0, "deg", "gon", 10.0 / 9.0),
        (63.661977236758134, "gon", "rad", 1.0),  # 200/pi gon per radian
        (-45.0, "deg", "gon", -50.0),
    ],
)
def test_convert_known_values(value, src, dst, expected):
    assert convert_angle(value, src, dst) == pytest.approx(expected, rel=1e-15, abs=1e-15)


def test_to_from_radians_vectorised_and_aliases():
    deg = np.array([[0.0, 90.0], [-180.0, 360.0]])
    rad = to_radians(deg, "degrees")
    assert rad.shape == (2, 2)
    np.testing.assert_allclose(rad, [[0.0, math.pi / 2], [-math.pi, 2 * math.pi]], rtol=1e-15)
    np.testing.assert_allclose(from_radians(rad, "grad"), deg * 400.0 / 360.0, rtol=1e-15)
    for alias, canon in [("Deg", "deg"), (" radians ", "rad"), ("grads", "gon"), ("°", "deg")]:
        assert normalize_unit(alias) == canon


def test_round_trip_random():
    rng = np.random.default_rng(1)
    v = rng.uniform(-7, 7, 1000)
    for a in ("deg", "rad", "gon"):
        for b in ("deg", "rad", "gon"):
            np.testing.assert_allclose(convert_angle(convert_angle(v, a, b), b, a), v, rtol=1e-14, atol=1e-14)


def test_unknown_unit():
    with pytest.raises(UnitError):
        to_radians(1.0, "mil")
    with pytest.raises(ValueError):  # UnitError is also a ValueError
        normalize_unit("arcsec")


def test_wrap_pi():
    v = np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -3 * math.pi / 2, 7.0])
    w = wrap_pi(v)
    assert np.all(w >= -math.pi) and np.all(w < math.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(v), atol=1e-15)
    np.testing.assert_allclose(np.sin(w), np.sin(v), atol=1e-15)
    np.testing.assert_allclose(w[[0, 3, 4]], [0.0, -math.pi / 2, math.pi / 2], atol=1e-15)


def test_check_plausible():
    assert check_plausible([0.1, -3.0, 6.2], "rad") is None
    assert check_plausible([359.0, -359.0], "deg") is None
    assert check_plausible([399.0], "gon") is None
    assert check_plausible([], "rad") is None
    # degrees declared as radians: 120 rad is ~19 turns
    msg = check_plausible([1.0, 120.0], "rad")
    assert msg is not None and "120" in msg
    # gon read as degrees beyond a turn
    assert check_plausible([380.0], "deg") is not None
    assert check_plausible([380.0], "deg", limit_turns=2.0) is None
    assert "finite" in check_plausible([np.nan], "deg")
    with pytest.raises(UnitError):
        check_plausible([1.0], "furlong")
