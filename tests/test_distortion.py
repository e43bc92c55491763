"""Distortion models: formulas, inverses, Jacobians, registry, and the behaviour of Brown's parameters."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from skyrig.camera import (
    AgisoftDistortion,
    BrownDistortion,
    Distortion,
    NoDistortion,
    OpenCVDistortion,
    OpenCVRationalDistortion,
    distortion_from_dict,
    distortion_models,
    register_distortion,
)
from skyrig.errors import InputFormatError, SkyrigError

# MIDAS (paper 004): Canon EOS 1Ds Mark III, 5616 x 3744 px of 6.4 um -> 35.94 x 23.96 mm, 28 mm lens
PIXEL_MM = 0.0064
HALF_W, HALF_H = 5616 * PIXEL_MM / 2, 3744 * PIXEL_MM / 2
FOCAL = 28.0
MIDAS_BROWN = BrownDistortion(k1=-1.0e-4, k2=1.5e-7, k3=-1.0e-10, p1=2.0e-6, p2=-3.0e-6, b1=5.0e-5, b2=-3.0e-5)
OPENCV = OpenCVDistortion(k1=-0.12, k2=0.09, p1=4e-4, p2=-7e-4, k3=-0.02)
RATIONAL = OpenCVRationalDistortion(k1=0.3, k2=-0.05, p1=-3e-4, p2=5e-4, k3=0.01, k4=0.4, k5=-0.02, k6=0.005)
AGISOFT = AgisoftDistortion(k1=-0.11, k2=0.08, k3=-0.02, k4=0.004, p1=6e-4, p2=-3e-4, b1=2e-4, b2=-1e-4)
MODELS = [NoDistortion(), MIDAS_BROWN, OPENCV, RATIONAL, AGISOFT]

# finite-difference steps per parameter (each moves points by ~1e-5..1e-4 mm at the image corner)
FD_STEPS = {
    "brown": [1e-8, 1e-11, 1e-14, 1e-7, 1e-7, 1e-6, 1e-6],
    "opencv": [1e-6] * 5,
    "opencv_rational": [1e-6] * 8,
    "agisoft": [1e-6] * 8,
    "none": [],
}


def image_points(n: int = 200, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-HALF_W, -HALF_H], [HALF_W, HALF_H], size=(n, 2))
    corners = np.array([[HALF_W, HALF_H], [-HALF_W, HALF_H], [-HALF_W, -HALF_H], [HALF_W, -HALF_H], [0.0, 0.0]])
    return np.vstack([pts, corners])


def brown_correction_scalar(m: BrownDistortion, xb: float, yb: float) -> tuple[float, float]:
    """Australis correction written out term by term (Fraser 1997), one point at a time."""
    r2 = xb**2 + yb**2
    dr = m.k1 * r2 + m.k2 * r2**2 + m.k3 * r2**3
    dx = xb * dr + m.p1 * (r2 + 2 * xb**2) + 2 * m.p2 * xb * yb + m.b1 * xb + m.b2 * yb
    dy = yb * dr + m.p2 * (r2 + 2 * yb**2) + 2 * m.p1 * xb * yb
    return xb + dx, yb + dy


def test_brown_undistort_is_the_australis_correction() -> None:
    obs = image_points(30)
    got = MIDAS_BROWN.undistort(obs, FOCAL)
    want = np.array([brown_correction_scalar(MIDAS_BROWN, float(x), float(y)) for x, y in obs])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    np.testing.assert_allclose(MIDAS_BROWN.correction(obs), want - obs, rtol=0, atol=1e-13)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_round_trips_to_1e12_mm(model: Distortion) -> None:
    ideal = image_points()
    obs = model.distort(ideal, FOCAL)
    assert np.all(np.isfinite(obs))
    np.testing.assert_allclose(model.undistort(obs, FOCAL), ideal, rtol=0, atol=1e-12)
    # and the other way round
    back = model.distort(model.undistort(ideal, FOCAL), FOCAL)
    np.testing.assert_allclose(back, ideal, rtol=0, atol=1e-12)
    # batch shape (..., 2) is kept
    assert model.distort(ideal.reshape(5, -1, 2), FOCAL).shape == (5, ideal.shape[0] // 5, 2)


def _check_columns(analytic: np.ndarray, numeric: np.ndarray, rel: float = 1e-6) -> None:
    """Each Jacobian column agrees to ``rel`` of that column's largest entry."""
    a = analytic.reshape(analytic.shape[0], 2, -1)
    b = numeric.reshape(numeric.shape[0], 2, -1)
    for j in range(a.shape[2]):
        scale = max(np.abs(b[:, :, j]).max(), 1e-300)
        err = np.abs(a[:, :, j] - b[:, :, j]).max()
        assert err <= rel * scale, f"column {j}: error {err:.3g} vs scale {scale:.3g}"


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_jacobians_against_central_differences(model: Distortion) -> None:
    ideal = image_points(60, seed=7)
    obs, j_ideal, j_params, j_focal = model.distort_with_jacobians(ideal, FOCAL)
    np.testing.assert_allclose(obs, model.distort(ideal, FOCAL), rtol=0, atol=1e-15)
    assert j_ideal.shape == (len(ideal), 2, 2)
    assert j_params.shape == (len(ideal), 2, model.n_params)
    assert j_focal.shape == (len(ideal), 2)

    h = 1e-4
    num = np.empty_like(j_ideal)
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        num[:, :, k] = (model.distort(ideal + e, FOCAL) - model.distort(ideal - e, FOCAL)) / (2 * h)
    _check_columns(j_ideal, num)
    np.testing.assert_allclose(model.jacobian_ideal(ideal, FOCAL), j_ideal)

    p0 = model.params
    num = np.empty_like(j_params)
    for k, step in enumerate(FD_STEPS[model.name]):
        dp = np.zeros_like(p0)
        dp[k] = step
        plus = type(model).from_params(p0 + dp).distort(ideal, FOCAL)
        minus = type(model).from_params(p0 - dp).distort(ideal, FOCAL)
        num[:, :, k] = (plus - minus) / (2 * step)
    _check_columns(j_params, num)
    np.testing.assert_allclose(model.jacobian_params(ideal, FOCAL), j_params)

    hf = 1e-3
    num_f = (model.distort(ideal, FOCAL + hf) - model.distort(ideal, FOCAL - hf)) / (2 * hf)
    if model.name.startswith("opencv") or model.name == "agisoft":  # models on normalised coordinates
        _check_columns(j_focal[:, :, None], num_f[:, :, None])
    else:  # mm-based models do not depend on the focal length
        assert np.all(j_focal == 0) and np.all(num_f == 0)
    np.testing.assert_allclose(model.jacobian_focal(ideal, FOCAL), j_focal)


# ---------------------------------------------------------------------- Brown: physical behaviour
def test_brown_radial_displacement_at_the_midas_corner() -> None:
    """K1 = -1e-4 mm^-2 with a 28 mm lens: a few percent at the corner, as for a wide-angle lens."""
    k1 = -1.0e-4
    m = BrownDistortion(k1=k1)
    corner_ideal = np.array([[HALF_W, HALF_H]])
    r_ideal = float(np.hypot(HALF_W, HALF_H))  # 21.6 mm
    obs = m.distort(corner_ideal, FOCAL)[0]
    # independent answer: the observed radius rho solves rho (1 + K1 rho^2) = r_ideal (radial only)
    roots = np.roots([k1, 0.0, 1.0, -r_ideal])
    rho = min(r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0)
    assert abs(np.hypot(*obs) - rho) < 1e-10
    # displacement is radial (parallel to the position vector)
    assert abs(obs[0] * corner_ideal[0, 1] - obs[1] * corner_ideal[0, 0]) < 1e-12
    # negative K1 in the Australis convention moves points outwards (pincushion)
    shift_mm = rho - r_ideal
    assert shift_mm > 0
    # plausible size for a wide-angle lens: a few percent of the radius (here ~1.2 mm, ~180 pixels of
    # 6.4 um), far above the 0.1 px measuring precision of the cage calibration, so it must be modelled
    assert 0.01 < shift_mm / r_ideal < 0.08
    assert 30 < shift_mm / PIXEL_MM < 300
    # cubic law near the centre: at a tenth of the radius the shift is ~1/1000 of the first-order corner value
    small = m.distort(corner_ideal / 10, FOCAL)[0]
    np.testing.assert_allclose(np.hypot(*small) - r_ideal / 10, -k1 * (r_ideal / 10) ** 3, rtol=2e-3)
    # positive K1 is barrel: points move inwards
    assert np.hypot(*BrownDistortion(k1=1e-4).distort(corner_ideal, FOCAL)[0]) < r_ideal


def test_brown_b1_is_affinity_and_b2_is_shear() -> None:
    b1, b2 = 2e-3, -3e-3
    grid = np.stack(np.meshgrid(np.linspace(-15, 15, 7), np.linspace(-10, 10, 5)), axis=-1).reshape(-1, 2)
    for model, A in (
        (BrownDistortion(b1=b1), np.array([[1 + b1, 0.0], [0.0, 1.0]])),
        (BrownDistortion(b2=b2), np.array([[1.0, b2], [0.0, 1.0]])),
        (BrownDistortion(b1=b1, b2=b2), np.array([[1 + b1, b2], [0.0, 1.0]])),
    ):
        # the correction is the linear map A, so lines stay lines and parallels stay parallel
        np.testing.assert_allclose(model.undistort(grid, FOCAL), grid @ A.T, rtol=0, atol=1e-13)
        np.testing.assert_allclose(model.distort(grid, FOCAL), np.linalg.solve(A, grid.T).T, rtol=0, atol=1e-12)
    # affinity: x scale differs from y scale by (1 + B1); the axes stay orthogonal
    ex, ey = BrownDistortion(b1=b1).undistort(np.array([[1.0, 0.0], [0.0, 1.0]]), FOCAL)
    assert math.isclose(np.linalg.norm(ex) / np.linalg.norm(ey), 1 + b1, rel_tol=1e-12)
    assert abs(ex @ ey) < 1e-15
    # shear: the image y axis is tilted by atan(B2) against the x axis, lengths along x unchanged
    ex, ey = BrownDistortion(b2=b2).undistort(np.array([[1.0, 0.0], [0.0, 1.0]]), FOCAL)
    angle = math.atan2(ey[0], ey[1])
    assert math.isclose(angle, math.atan(b2), rel_tol=1e-12)
    assert math.isclose(np.linalg.norm(ex), 1.0, rel_tol=1e-15)


def test_brown_decentring_is_not_radial() -> None:
    m = BrownDistortion(p1=1e-5)
    # on the y axis: dx = P1 r^2 (perpendicular to the radius), dy = 0
    np.testing.assert_allclose(m.correction(np.array([[0.0, 10.0]])), [[1e-5 * 100, 0.0]], atol=1e-15)
    # on the x axis: dx = 3 P1 x^2 (along the radius)
    np.testing.assert_allclose(m.correction(np.array([[10.0, 0.0]])), [[3e-5 * 100, 0.0]], atol=1e-15)


# ---------------------------------------------------------------------- registry and dictionaries
@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_dict_and_params_round_trip(model: Distortion) -> None:
    d = model.to_dict()
    assert d["model"] == model.name
    assert distortion_from_dict(d) == model
    assert type(model).from_params(model.params) == model
    assert list(model.params_dict()) == list(model.param_names)
    assert tuple(f.name for f in dataclasses.fields(type(model))) == model.param_names
    assert len(model.param_units) == model.n_params


def test_registry_contents_and_errors() -> None:
    models = distortion_models()
    assert {"none", "brown", "opencv", "opencv_rational"} <= set(models)
    assert distortion_from_dict({"model": "Brown", "K1": -1e-4, "P2": 1e-6}) == BrownDistortion(k1=-1e-4, p2=1e-6)
    assert distortion_from_dict({"model": "opencv"}) == OpenCVDistortion()
    with pytest.raises(InputFormatError) as e:
        distortion_from_dict({"model": "fisheye-unknown"})
    assert e.value.field == "model"
    with pytest.raises(InputFormatError) as e:
        distortion_from_dict({"model": "brown", "k4": 1.0})
    assert e.value.field == "k4"
    with pytest.raises(InputFormatError) as e:
        distortion_from_dict({"model": "brown", "k1": "abc"})
    assert e.value.field == "k1"
    with pytest.raises(InputFormatError):
        distortion_from_dict({"k1": 0.1})
    with pytest.raises(InputFormatError):
        BrownDistortion.from_dict({"model": "opencv"})
    with pytest.raises(ValueError):
        BrownDistortion.from_params([1.0, 2.0])


def test_register_a_new_model() -> None:
    @register_distortion
    @dataclass(frozen=True)
    class RadialScale(Distortion):
        s: float = 0.0
        name: ClassVar[str] = "test_radial_scale"
        param_names: ClassVar[tuple[str, ...]] = ("s",)
        param_units: ClassVar[tuple[str, ...]] = ("1",)

        def distort_with_jacobians(self, xy_ideal, focal_mm):  # type: ignore[no-untyped-def]
            xy = np.asarray(xy_ideal, dtype=float).reshape(-1, 2)
            n = len(xy)
            return (1 + self.s) * xy, np.broadcast_to((1 + self.s) * np.eye(2), (n, 2, 2)), xy[:, :, None], np.zeros((n, 2))

    m = distortion_from_dict({"model": "test_radial_scale", "s": 0.01})
    assert isinstance(m, RadialScale)
    # the base class supplies undistort by Newton
    np.testing.assert_allclose(m.undistort(np.array([[1.01, 2.02]]), FOCAL), [[1.0, 2.0]], atol=1e-13)
    with pytest.raises(SkyrigError):

        @register_distortion
        @dataclass(frozen=True)
        class Clash(Distortion):
            name: ClassVar[str] = "brown"
