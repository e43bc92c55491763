"""Camera models users bring from other programs (issue 12, 1d): the forward model (distortion at the ideal
point, balanced radial K1..K4 with R0, distortion centre, decentring, affinity, shear) and ``convert_camera``.

Independent answers: the formulas written out here term by term; central differences for the Jacobians; and for
each conversion an independent least-squares fit (``scipy.optimize.least_squares`` on the same grid, with the
source rays and the target projection written out here, including the fixed-point inversion of Brown's
correction), whose fitted camera and residual must agree with skyrig's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

from skyrig.camera import (
    BrownDistortion,
    ForwardDistortion,
    FrameCamera,
    compare_cameras,
    convert_camera,
    distortion_from_dict,
    distortion_models,
    project_camera_with_jacobians,
)
from skyrig.camera.convert import frame_grid
from skyrig.camera.distortion import _fields_are_params

PIXEL_MM = 0.0064
W, H = 5616, 3744
HALF_W, HALF_H = W * PIXEL_MM / 2, H * PIXEL_MM / 2
FOCAL = 28.0
BROWN = BrownDistortion(k1=1.0e-4, k2=-1.5e-7, k3=1.0e-10, p1=2.0e-6, p2=-3.0e-6, b1=5.0e-5, b2=-3.0e-5)
FORWARD = ForwardDistortion(xc_mm=0.04, yc_mm=-0.03, k1=-1.0e-4, k2=1.8e-7, k3=-1.5e-10, k4=5e-14, p1=-2.0e-6,
                            p2=3.0e-6, b1=-5.0e-5, b2=3.0e-5, r0_mm=15.0)
FD_STEPS = [1e-5, 1e-5, 1e-8, 1e-11, 1e-14, 1e-17, 1e-7, 1e-7, 1e-6, 1e-6]


def cam(dist, focal=FOCAL, pp=(0.012, -0.009)) -> FrameCamera:  # type: ignore[no-untyped-def]
    return FrameCamera("c", W, H, PIXEL_MM, focal, pp[0], pp[1], dist)


def image_points(n: int = 200, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-HALF_W, -HALF_H], [HALF_W, HALF_H], size=(n, 2))
    return np.vstack([pts, [[HALF_W, HALF_H], [-HALF_W, HALF_H], [-HALF_W, -HALF_H], [HALF_W, -HALF_H], [0, 0]]])


# ---------------------------------------------------------------------- formulas written out
def forward_scalar(m: ForwardDistortion, qx: float, qy: float) -> tuple[float, float]:
    ux, uy = qx - m.xc_mm, qy - m.yc_mm
    r = np.hypot(ux, uy)
    R = m.r0_mm
    rho = m.k1 * (r**2 - R**2) + m.k2 * (r**4 - R**4) + m.k3 * (r**6 - R**6) + m.k4 * (r**8 - R**8)
    dx = ux * rho + m.p1 * (r**2 + 2 * ux**2) + 2 * m.p2 * ux * uy + m.b1 * ux + m.b2 * uy
    dy = uy * rho + m.p2 * (r**2 + 2 * uy**2) + 2 * m.p1 * ux * uy
    return qx + dx, qy + dy


def forward_vec(p: np.ndarray, q: np.ndarray, r0: float) -> np.ndarray:
    """Forward distortion, parameters ``(xc, yc, k1..k4, p1, p2, b1, b2)``, ideal ``q (N, 2)`` -> observed."""
    xc, yc, k1, k2, k3, k4, p1, p2, b1, b2 = p
    ux, uy = q[:, 0] - xc, q[:, 1] - yc
    r2 = ux**2 + uy**2
    R2 = r0**2
    rho = k1 * (r2 - R2) + k2 * (r2**2 - R2**2) + k3 * (r2**3 - R2**3) + k4 * (r2**4 - R2**4)
    return np.column_stack([q[:, 0] + ux * rho + p1 * (r2 + 2 * ux**2) + 2 * p2 * ux * uy + b1 * ux + b2 * uy,
                            q[:, 1] + uy * rho + p2 * (r2 + 2 * uy**2) + 2 * p1 * ux * uy])


def brown_correct_vec(p: np.ndarray, o: np.ndarray) -> np.ndarray:
    """Australis correction (Fraser 1997), parameters ``(k1, k2, k3, p1, p2, b1, b2)``: observed -> ideal."""
    k1, k2, k3, p1, p2, b1, b2 = p
    x, y = o[:, 0], o[:, 1]
    r2 = x**2 + y**2
    dr = k1 * r2 + k2 * r2**2 + k3 * r2**3
    return np.column_stack([x + x * dr + p1 * (r2 + 2 * x**2) + 2 * p2 * x * y + b1 * x + b2 * y,
                            y + y * dr + p2 * (r2 + 2 * y**2) + 2 * p1 * x * y])


def fixed_point(fun, target: np.ndarray, n_iter: int = 60) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Solve ``fun(x) = target`` by ``x <- x - (fun(x) - target)`` (distortion is a small perturbation)."""
    x = target.copy()
    for _ in range(n_iter):
        x = x - (fun(x) - target)
    return x


def grid_pixels(nc: int = 61, nr: int = 41) -> np.ndarray:
    cc, rr = np.meshgrid(np.linspace(-0.5, W - 0.5, nc), np.linspace(-0.5, H - 0.5, nr))
    return np.column_stack([cc.ravel(), rr.ravel()])


def pix_to_mm(px: np.ndarray) -> np.ndarray:
    return np.column_stack([(px[:, 0] - (W - 1) / 2) * PIXEL_MM, -(px[:, 1] - (H - 1) / 2) * PIXEL_MM])


def mm_to_pix(mm: np.ndarray) -> np.ndarray:
    return np.column_stack([mm[:, 0] / PIXEL_MM + (W - 1) / 2, -mm[:, 1] / PIXEL_MM + (H - 1) / 2])


def source_directions(c: FrameCamera, px: np.ndarray) -> np.ndarray:
    """``(N, 2)`` ``-P_xy / P_z`` of the rays of observed pixels, computed here (not with skyrig)."""
    obs = pix_to_mm(px) - [c.ppx_mm, c.ppy_mm]
    d = c.distortion
    if isinstance(d, BrownDistortion):
        ideal = brown_correct_vec(d.params, obs)
    else:
        ideal = fixed_point(lambda q: forward_vec(d.params, q, d.r0_mm), obs)
    return ideal / c.focal_mm


def independent_fit(source: FrameCamera, target: str, r0: float = 0.0, hold_centre: bool = True
                    ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(intrinsics, errors (N, 2) px, rms, max)`` of the target fitted with scipy."""
    px = grid_pixels()
    t = source_directions(source, px)

    def project(x: np.ndarray) -> np.ndarray:
        f, ppx, ppy = x[:3]
        q = f * t
        if target == "brown":
            obs = fixed_point(lambda o: brown_correct_vec(x[3:], o), q)
        else:
            p = np.concatenate([[0.0, 0.0], x[3:]]) if hold_centre else x[3:]
            obs = forward_vec(p, q, r0)
        return mm_to_pix(obs + [ppx, ppy])

    n_dist = 7 if target == "brown" else (8 if hold_centre else 10)
    x0 = np.concatenate([[source.focal_mm, source.ppx_mm, source.ppy_mm], np.zeros(n_dist)])
    # solve in well-scaled units: each parameter times its effect at the half diagonal rm (mm)
    rm = float(np.hypot(HALF_W, HALF_H))
    if target == "brown":
        s = np.array([1, 1, 1, rm**-2, rm**-4, rm**-6, rm**-1, rm**-1, 1, 1])
    else:
        s = np.array([1, 1, 1] + ([] if hold_centre else [1, 1]) + [rm**-2, rm**-4, rm**-6, rm**-8, rm**-1, rm**-1, 1, 1])
    sol = least_squares(lambda z: (project(z * s) - px).ravel(), x0 / s, method="trf", ftol=1e-15, xtol=1e-15,
                        gtol=1e-15, max_nfev=500)
    sol.x = sol.x * s
    err = project(sol.x) - px
    e = np.linalg.norm(err, axis=1)
    return sol.x, err, float(np.sqrt(np.mean(e**2))), float(e.max())


# ---------------------------------------------------------------------- the forward model
def test_forward_is_registered_and_reads_back_with_its_constant() -> None:
    assert distortion_models()["forward"] is ForwardDistortion
    _fields_are_params(ForwardDistortion)
    d = FORWARD.to_dict()
    assert d["model"] == "forward" and d["r0_mm"] == 15.0
    assert distortion_from_dict(d) == FORWARD
    assert "r0_mm" not in FORWARD.param_names and FORWARD.n_params == 10
    assert FORWARD.with_params(FORWARD.params * 2).r0_mm == 15.0
    c = cam(FORWARD)
    assert c.with_intrinsics(c.intrinsics).distortion == FORWARD  # the constant survives the intrinsic vector
    with pytest.raises(ValueError):
        ForwardDistortion(r0_mm=-1.0)


def test_forward_formula_round_trip_and_zero_at_r0() -> None:
    q = image_points()
    obs = FORWARD.distort(q, FOCAL)
    expect = np.array([forward_scalar(FORWARD, *p) for p in q])
    np.testing.assert_allclose(obs, expect, rtol=0, atol=1e-13)
    np.testing.assert_allclose(FORWARD.undistort(obs, FOCAL), q, rtol=0, atol=1e-11)
    # balanced: pure radial terms vanish at R0 around the distortion centre
    m = ForwardDistortion(xc_mm=0.5, yc_mm=-0.2, k1=1e-4, k2=-2e-7, k3=1e-10, k4=-1e-13, r0_mm=12.0)
    ang = np.linspace(0, 2 * np.pi, 13)
    ring = np.column_stack([0.5 + 12.0 * np.cos(ang), -0.2 + 12.0 * np.sin(ang)])
    np.testing.assert_allclose(m.distort(ring, FOCAL), ring, rtol=0, atol=1e-13)
    # ...and are radial about the centre, not about the principal point
    p = np.array([[0.5 + 5.0, -0.2]])
    assert abs(m.distort(p, FOCAL)[0, 1] - p[0, 1]) < 1e-15


def test_forward_jacobians_against_central_differences() -> None:
    q = image_points(60)
    obs, J, Jp, Jf = FORWARD.distort_with_jacobians(q, FOCAL)
    h = 1e-6
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        fd = (FORWARD.distort(q + e, FOCAL) - FORWARD.distort(q - e, FOCAL)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], fd, rtol=0, atol=1e-8)
    for j, (name, step) in enumerate(zip(FORWARD.param_names, FD_STEPS)):
        plus = dataclasses.replace(FORWARD, **{name: getattr(FORWARD, name) + step})
        minus = dataclasses.replace(FORWARD, **{name: getattr(FORWARD, name) - step})
        fd = (plus.distort(q, FOCAL) - minus.distort(q, FOCAL)) / (2 * step)
        scale = np.abs(fd).max() + 1e-300
        np.testing.assert_allclose(Jp[:, :, j] / scale, fd / scale, rtol=0, atol=1e-6, err_msg=name)
    np.testing.assert_array_equal(Jf, 0.0)
    # through the projection: d pixel / d intrinsics of a FrameCamera with this model
    c = cam(FORWARD)
    rng = np.random.default_rng(3)
    pc = np.column_stack([rng.uniform(-0.6, 0.6, 40), rng.uniform(-0.4, 0.4, 40), -np.ones(40)])
    _, _, d_intr = project_camera_with_jacobians(c, pc)
    steps = np.concatenate([[1e-6, 1e-6, 1e-6], FD_STEPS])
    for j, step in enumerate(steps):
        x = c.intrinsics
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        fd = (c.with_intrinsics(xp).project_pixels(pc) - c.with_intrinsics(xm).project_pixels(pc)) / (2 * step)
        scale = np.abs(fd).max() + 1e-300
        np.testing.assert_allclose(d_intr[:, :, j] / scale, fd / scale, rtol=0, atol=1e-6, err_msg=c.intrinsic_names[j])


# ---------------------------------------------------------------------- conversions
def check_against_independent(source: FrameCamera, converted: FrameCamera, rep, target: str, r0: float,  # type: ignore[no-untyped-def]
                              hold_centre: bool = True) -> dict[str, float]:
    x, err, rms, mx = independent_fit(source, target, r0, hold_centre)
    # the same camera: the two fits project the grid rays to the same pixels ...
    ours = converted.project_pixels(np.column_stack([source_directions(source, grid_pixels()),
                                                     -np.ones(len(grid_pixels()))]))
    theirs = grid_pixels() + err
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=2e-6)
    # ... the same parameters (the grid determines all of them) ...
    ours_x = converted.intrinsics if target == "brown" or not hold_centre else np.delete(converted.intrinsics, [3, 4])
    np.testing.assert_allclose(ours_x, x, rtol=1e-5, atol=1e-9 * np.abs(x).max())
    # ... and the same residual
    assert rep.rms_px == pytest.approx(rms, rel=1e-5, abs=1e-8)
    assert rep.max_px == pytest.approx(mx, rel=1e-5, abs=1e-8)
    return {"rms_px": rep.rms_px, "max_px": rep.max_px}


def test_brown_to_forward_with_r0_agrees_with_an_independent_fit() -> None:
    src = cam(BROWN)
    out, rep = convert_camera(src, ForwardDistortion(r0_mm=15.0), hold=("xc_mm", "yc_mm"))
    assert rep.converged and rep.fitted[:3] == ("focal_mm", "ppx_mm", "ppy_mm")
    assert out.distortion.r0_mm == 15.0
    figs = check_against_independent(src, out, rep, "forward", 15.0)
    # a strong distortion (about 150 px at the corner): the models differ by a few thousandths of a pixel
    assert figs["rms_px"] < 0.01 and figs["max_px"] < 0.1
    assert rep.region("edge").max_px == pytest.approx(rep.max_px)
    assert rep.region("centre").n_points + rep.region("middle").n_points + rep.region("edge").n_points == rep.n_points
    # balancing at R0 changes the principal distance by about -K1 R0² f (K1 ~ -Brown's K1)
    assert out.focal_mm < src.focal_mm
    assert out.focal_mm == pytest.approx(src.focal_mm * (1 + out.distortion.k1 * 15.0**2), rel=2e-2)


def test_forward_with_centre_to_brown_agrees_with_an_independent_fit() -> None:
    src = cam(FORWARD)
    out, rep = convert_camera(src, "brown")
    assert rep.converged and isinstance(out.distortion, BrownDistortion)
    figs = check_against_independent(src, out, rep, "brown", 0.0)
    assert figs["rms_px"] < 0.05


def test_round_trips_to_and_from_brown() -> None:
    src = cam(BROWN)
    fwd, rep1 = convert_camera(src, ForwardDistortion(r0_mm=15.0), hold=("xc_mm", "yc_mm"))
    back, rep2 = convert_camera(fwd, "brown")
    trip = compare_cameras(src, back)
    # the way back is as good as the way there, and the round trip lands on the source camera far inside either
    assert rep2.rms_px == pytest.approx(rep1.rms_px, rel=0.05)
    assert trip.rms_px < 0.05 * rep1.rms_px and trip.max_px < 0.05 * rep1.max_px
    np.testing.assert_allclose(back.intrinsics, src.intrinsics, rtol=0.05, atol=1e-6)
    # an exactly representable pair: Brown -> forward -> Brown of a pure affinity/shear + k1 (small) camera
    small = cam(BrownDistortion(k1=2e-6, b1=1e-5, b2=-2e-5))
    f2, r = convert_camera(small, "forward", hold=("xc_mm", "yc_mm"))
    b2_, r2 = convert_camera(f2, "brown")
    assert r.rms_px < 2e-3 and r2.rms_px < 2e-3 and compare_cameras(small, b2_).max_px < 1e-4


def test_identity_conversion_and_errors() -> None:
    src = cam(BROWN)
    same, rep = convert_camera(src, BROWN)
    assert rep.max_px < 1e-8
    np.testing.assert_allclose(same.intrinsics, src.intrinsics, rtol=1e-9, atol=1e-15)
    assert frame_grid(src, (3, 2)).shape == (6, 2)
    with pytest.raises(ValueError, match="hold"):
        convert_camera(src, "forward", hold=("k9",))
    with pytest.raises(ValueError, match="fit"):
        convert_camera(src, "forward", fit=("width",))
    d = rep.to_dict()
    assert d["regions"][-1]["rho_to"] is None and d["target_model"] == "brown"
