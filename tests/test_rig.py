"""Rigs: published figures of the papers' systems, mounting conventions, the tumbling head against an
independently written composition, boresight curves."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import gamma as gamma_fn

from skyrig.camera import FrameCamera, footprint_on_plane
from skyrig.errors import GeometryError, SkyrigError
from skyrig.geometry import Pose
from skyrig.rig import (
    PRESETS,
    ActuatedHead,
    BoresightCurve,
    Head,
    HeadNotFoundError,
    Rig,
    mounting_from_rpy,
    oblique_mounting,
    preset,
)

DEG = np.pi / 180.0


# ---------------------------------------------------------------- independent elementary rotations
def Rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


N = np.diag([1.0, -1.0, -1.0])  # standard nadir mount, written out here on purpose
ENU_FROM_NED = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])


def world_pose(head: Head, height_m: float, beta: float | None = None) -> Pose:
    """Level flight heading north at ``height_m`` above the plane z = 0 (ENU world)."""
    p = head.body_from_camera(beta)
    return Pose(ENU_FROM_NED @ p.rotation, np.array([0.0, 0.0, height_m]) + ENU_FROM_NED @ p.translation,
                "world", p.src)


# ---------------------------------------------------------------- published figures
@pytest.mark.parametrize(
    "name, height_m, quoted_cm",
    [
        # paper 004: 28 mm nadir at 600 m and 1200 m -> "14cm and 27cm"; 50 mm nadir at 750 m and
        # 1500 m -> GSD 10 cm and 19 cm (Table 11).  The paper quotes whole centimetres, so the
        # computed GSD must round to the quoted figure.
        ("midas", 600.0, 14),
        ("midas", 1200.0, 27),
        ("midas-50", 750.0, 10),
        ("midas-50", 1500.0, 19),
        # paper 000 Tab. 1: "~2 cm @ 100 m"; section 4: 200 m -> "approximately 3 cm"
        ("macs-tumblecam", 100.0, 2),
        ("macs-tumblecam", 200.0, 3),
    ],
)
def test_nadir_gsd_matches_papers(name: str, height_m: float, quoted_cm: int) -> None:
    nadir = preset(name).head("nadir")
    gsd = float(nadir.camera.gsd(height_m))
    assert round(gsd * 100) == quoted_cm
    # the same GSD from the ground footprint (ground extent / pixels), independent of camera.gsd
    # (top-left to top-right corner spans exactly `width` pixels)
    fp = footprint_on_plane(nadir.camera, world_pose(nadir, height_m))
    assert np.linalg.norm(fp[1] - fp[0]) / nadir.camera.width == pytest.approx(gsd, rel=1e-9)


def test_midas_lenses_and_sensor() -> None:
    rig = preset("midas")
    assert rig.head_names == ["nadir", "forward", "right", "backward", "left"]
    assert rig.head("nadir").camera.focal_mm == 28.0
    for h in rig:
        assert (h.camera.width, h.camera.height) == (5616, 3744)
        assert h.camera.pixel_size_mm == pytest.approx(0.0064)
        if h.name != "nadir":
            assert h.camera.focal_mm == 50.0
            # 45 deg obliques (paper 004)
            assert np.degrees(np.arccos(h.optical_axis()[2])) == pytest.approx(45.0, abs=1e-9)
    s = np.sin(45 * DEG)
    assert rig.head("forward").optical_axis() == pytest.approx([s, 0, s])
    assert rig.head("right").optical_axis() == pytest.approx([0, s, s])
    assert rig.head("backward").optical_axis() == pytest.approx([-s, 0, s])
    assert rig.head("left").optical_axis() == pytest.approx([0, -s, s])
    assert all(h.camera.focal_mm == 50.0 for h in preset("midas-50"))


def test_dlr_3k_gsd_and_swath_at_1000m() -> None:
    rig = preset("dlr-3k")
    nadir = rig.head("nadir")
    # paper 001: "the pixel size at a flight height of 1000 m above ground is 15 cm".  Canon EOS 1Ds
    # Mark II: 7.2 um pixels, 50 mm -> 14.4 cm; the paper rounds to 15 cm, so allow +-1 cm.
    assert abs(float(nadir.camera.gsd(1000.0)) - 0.15) <= 0.01
    # "... and the image array covers up 2.8 km in width": the fan of the three footprints on flat
    # ground; the paper quotes one decimal of a kilometre, so the swath must round to 2.8 km.
    corners = np.concatenate([footprint_on_plane(h.camera, world_pose(h, 1000.0)) for h in rig])
    swath_m = np.ptp(corners[:, 0])  # east = across track when heading north
    assert round(swath_m / 100.0) / 10.0 == 2.8
    # 110 deg across-track field of view (paper 001): 2 x (35 deg + half the long side's FOV)
    half_long = np.degrees(np.arctan(4992 * 0.0072 / 2 / 50.0))
    assert round(2 * (35.0 + half_long)) == 110
    assert np.degrees(2 * np.arctan(swath_m / 2 / 1000.0)) == pytest.approx(2 * (35.0 + half_long), abs=0.01)
    # sideward tilt of about 35 deg, left and right
    assert rig.head("left").optical_axis() == pytest.approx([0, -np.sin(35 * DEG), np.cos(35 * DEG)])
    assert rig.head("right").optical_axis() == pytest.approx([0, np.sin(35 * DEG), np.cos(35 * DEG)])


def test_tumblecam_and_uav_presets() -> None:
    rig = preset("MACS_TumbleCam")
    cam = rig.head("oblique").camera
    assert (cam.width, cam.height, cam.pixel_size_mm, cam.focal_mm) == (3296, 2472, 0.0055, 35.0)
    obl = rig.head("oblique")
    assert isinstance(obl, ActuatedHead) and obl.gamma_rad == pytest.approx(30 * DEG)
    uav = preset("uav-single")
    assert len(uav) == 1
    # DJI FC300S: 1/2.3" sensor 6.17 mm wide, 3.61 mm focal length -> 81.2 deg horizontal FOV
    assert uav.head("camera").camera.fov_deg()[0] == pytest.approx(2 * np.degrees(np.arctan(6.17 / 2 / 3.61)))
    for name in PRESETS:
        assert preset(name).name  # every preset builds
    with pytest.raises(KeyError, match="presets: midas"):
        preset("nope")


# ---------------------------------------------------------------- mounting conventions
def test_standard_nadir_mount_and_view_angles() -> None:
    cam = FrameCamera("c", 100, 80, 0.01, 10.0)
    nadir = Head("n", cam)
    assert nadir.mounting == pytest.approx(N)
    assert nadir.optical_axis() == pytest.approx([0, 0, 1])  # looks down
    p = nadir.body_from_camera()
    assert (p.dst, p.src) == ("body", "camera:n")
    # image x along flight, image y to the left (documented convention)
    assert p.rotate([1, 0, 0]) == pytest.approx([1, 0, 0])
    assert p.rotate([0, 1, 0]) == pytest.approx([0, -1, 0])
    t = 30 * DEG
    # positive pitch looks forward, positive roll looks left, yaw turns the tilted view about z
    assert mounting_from_rpy(0, 30, 0) @ [0, 0, -1] == pytest.approx([np.sin(t), 0, np.cos(t)])
    assert mounting_from_rpy(30, 0, 0) @ [0, 0, -1] == pytest.approx([0, -np.sin(t), np.cos(t)])
    assert mounting_from_rpy(0, 30, 90) @ [0, 0, -1] == pytest.approx([0, np.sin(t), np.cos(t)])
    # independent composition Rz Ry Rx N, and the boresight (omega, phi, kappa about camera axes)
    r, pi, y, o, ph, k = 3.0, -7.0, 120.0, 0.05, -0.02, 0.3
    h = Head.from_angles("h", cam, (1.0, 2.0, 3.0), r, pi, y, (o, ph, k))
    expect = Rz(y * DEG) @ Ry(pi * DEG) @ Rx(r * DEG) @ N @ Rx(o * DEG) @ Ry(ph * DEG) @ Rz(k * DEG)
    assert h.body_from_camera().rotation == pytest.approx(expect, abs=1e-14)
    assert h.body_from_camera().translation == pytest.approx([1, 2, 3])
    assert h.mounting_rpy() == pytest.approx((r, pi, y))
    assert h.boresight_opk() == pytest.approx((o, ph, k))
    # vectorised over beta for a fixed head: the constant rotation, repeated
    assert h.body_from_camera(np.zeros(4)).rotation.shape == (4, 3, 3)


@pytest.mark.parametrize("azimuth", [0.0, 90.0, 180.0, -90.0, 33.0])
def test_oblique_mounting_is_upright(azimuth: float) -> None:
    m = oblique_mounting(azimuth, 45.0)
    a, t = azimuth * DEG, 45 * DEG
    assert m @ [0, 0, -1] == pytest.approx([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
    assert (m @ [1, 0, 0])[2] == pytest.approx(0.0, abs=1e-15)  # image x horizontal
    up = m @ [0, 1, 0]
    assert up[2] < 0  # image top points upwards (body z is down) ...
    assert up[:2] @ [np.cos(a), np.sin(a)] > 0  # ... and towards the far field


def test_rig_pickles() -> None:
    """Rigs travel to worker processes in parallel stages."""
    import pickle

    beta_s, corr_s = _curve_samples()
    rig = preset("macs-tumblecam")
    rig = Rig(rig.name, [rig.head("nadir"), rig.head("oblique").with_(curve=BoresightCurve(beta_s, corr_s))])
    back = pickle.loads(pickle.dumps(rig))
    assert back.isclose(rig, atol=0.0)
    b = np.linspace(0, 7, 9)
    assert np.array_equal(back.body_from_camera("oblique", b).rotation, rig.body_from_camera("oblique", b).rotation)


def test_rig_errors() -> None:
    cam = FrameCamera("c", 100, 80, 0.01, 10.0)
    rig = Rig("r", [Head("a", cam), Head("b", cam)])
    with pytest.raises(HeadNotFoundError, match="heads: a, b") as info:
        rig.head("c")
    assert isinstance(info.value, KeyError) and isinstance(info.value, SkyrigError)
    with pytest.raises(SkyrigError, match="two heads"):
        Rig("r", [Head("a", cam), Head("a", cam)])
    with pytest.raises(GeometryError):
        Head("x", cam, mounting=np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(GeometryError):
        Head("x", cam, lever_arm_m=[1.0, 2.0])
    tumbling = ActuatedHead("t", cam, gamma_rad=0.5)
    with pytest.raises(SkyrigError, match="actuator angle"):
        tumbling.body_from_camera()
    rig2 = Rig("r", [Head("a", cam, lever_arm_m=[1, 2, 3])], antenna_lever_arm_m=[0.5, 0, -1])
    assert rig2.antenna_to_camera_m("a") == pytest.approx([0.5, 2, 4])


# ---------------------------------------------------------------- tumbling head (paper 000, 3.4)
def _curve_samples() -> tuple[np.ndarray, np.ndarray]:
    beta = np.arange(0, 360, 30.0) * DEG
    corr = np.stack([0.02 * np.sin(beta + 0.3), -0.015 * np.cos(2 * beta), 0.05 * np.sin(beta) ** 2], 1) * DEG
    return beta, corr


def test_tumbling_head_against_independent_composition() -> None:
    beta_s, corr_s = _curve_samples()
    curve = BoresightCurve(beta_s, corr_s)
    cam = FrameCamera("c", 100, 80, 0.01, 10.0)
    g = 30.0
    hr, hp, hy = 0.4, -0.7, 1.5  # sensor head slightly misaligned in the body
    bo = (0.01, -0.03, 0.2)
    head = ActuatedHead.tumbling("obl", cam, g, lever_arm_m=(0.1, 0.2, 0.3), head_rpy=(hr, hp, hy),
                                 boresight_opk=bo, curve=curve)
    idx = [0, 1, 4, 7, 11]  # sample positions: the curve passes through its samples
    beta = beta_s[idx]
    got = head.body_from_camera(beta)
    assert got.rotation.shape == (5, 3, 3) and got.translation.shape == (5, 3)
    assert (got.dst, got.src) == ("body", "camera:obl")
    for i, b in zip(idx, beta):
        dr, dp, dy = corr_s[i]
        roll = np.sin(b) * g * DEG + dr
        pitch = np.cos(b) * g * DEG + dp
        expect = (Rz(hy * DEG) @ Ry(hp * DEG) @ Rx(hr * DEG)  # body_from_head
                  @ Rz(dy) @ Ry(pitch) @ Rx(roll)  # tumbling offsets + corrections about head x, y, z
                  @ N @ Rx(bo[0] * DEG) @ Ry(bo[1] * DEG) @ Rz(bo[2] * DEG))
        k = idx.index(i)
        assert got.rotation[k] == pytest.approx(expect, abs=1e-14)
        assert got.translation[k] == pytest.approx([0.1, 0.2, 0.3])


def test_oblique_eo_from_nadir_eo() -> None:
    """Paper 000, 3.4: the oblique image's EO is the nadir EO composed with the beta-dependent mounting."""
    rig = preset("macs-tumblecam")
    cam = rig.head("nadir").camera
    rig = Rig(rig.name, [rig.head("nadir").with_(lever_arm_m=np.array([0.05, -0.03, 0.02])),
                         ActuatedHead("oblique", cam, np.array([0.05, 0.07, 0.03]), gamma_rad=30 * DEG)])
    # nadir EO: world_from_camera from (omega, phi, kappa) and a projection centre, written out here
    o, p, k = 2.0 * DEG, -1.5 * DEG, 37.0 * DEG
    r_wn = Rx(o) @ Ry(p) @ Rz(k)
    c_n = np.array([500.0, 800.0, 120.0])
    world_from_nadir = Pose(r_wn, c_n, "world", "camera:nadir")
    world_from_body = world_from_nadir @ rig.body_from_camera("nadir").inverse()
    for b in np.arange(0, 360, 45.0) * DEG:
        world_from_obl = world_from_body @ rig.body_from_camera("oblique", b)
        # independent: world_from_body = R_wn N^T, oblique = that @ Ry(pitch) Rx(roll) N
        r_wb = r_wn @ N.T
        expect_r = r_wb @ Ry(np.cos(b) * 30 * DEG) @ Rx(np.sin(b) * 30 * DEG) @ N
        expect_c = c_n + r_wb @ (np.array([0.05, 0.07, 0.03]) - np.array([0.05, -0.03, 0.02]))
        assert world_from_obl.rotation == pytest.approx(expect_r, abs=1e-13)
        assert world_from_obl.translation == pytest.approx(expect_c, abs=1e-9)
        assert (world_from_obl.dst, world_from_obl.src) == ("world", "camera:oblique")


def test_optical_axis_sweeps_cone() -> None:
    cam = FrameCamera("c", 100, 80, 0.01, 10.0)
    g = 30 * DEG
    beta = np.linspace(0, 2 * np.pi, 361)
    # the cardan law keeps the axis exactly on the cone of half-angle gamma about the nadir axis
    cardan = ActuatedHead("t", cam, gamma_rad=g, law="cardan")
    axis = cardan.optical_axis(beta)
    assert np.degrees(np.arccos(np.clip(axis[:, 2], -1, 1))) == pytest.approx(np.full(beta.size, 30.0), abs=1e-9)
    # ... at azimuth -beta (beta = 0 forward, 90 deg left)
    expect = np.stack([np.sin(g) * np.cos(beta), -np.sin(g) * np.sin(beta), np.full_like(beta, np.cos(g))], 1)
    assert axis == pytest.approx(expect, abs=1e-12)
    # paper eqs 1-2 (linear in gamma): axis = Ry(theta) Rx(phi) (0,0,1) -> tilt acos(cos phi cos theta),
    # exactly gamma at beta = 0, 90, 180, 270 deg, 29.65 deg in between
    paper = ActuatedHead("t", cam, gamma_rad=g, law="paper")
    tilt = np.arccos(np.clip(paper.optical_axis(beta)[:, 2], -1, 1))
    assert tilt == pytest.approx(np.arccos(np.cos(g * np.sin(beta)) * np.cos(g * np.cos(beta))), abs=1e-12)
    assert np.degrees(tilt[::90]) == pytest.approx(30.0, abs=1e-9)
    assert np.degrees(tilt.min()) == pytest.approx(29.649, abs=1e-3)
    # with the nadir axis tilted (head mounted with a 5 deg pitch) the cone follows the head z axis
    tilted = ActuatedHead.tumbling("t", cam, 30.0, head_rpy=(0, 5, 0), law="cardan")
    head_z = Ry(5 * DEG) @ [0, 0, 1]
    assert np.degrees(np.arccos(tilted.optical_axis(beta) @ head_z)) == pytest.approx(np.full(361, 30.0), abs=1e-9)


@pytest.mark.parametrize("law", ["paper", "cardan"])
def test_tumbling_does_not_turn_the_image_about_the_vertical(law: str) -> None:
    """Paper 000, 3.2 and Fig. 5: no rotation about the optical axis, "each image corner remains in
    the same relative position".  Measurable form: the image x axis always lies in the vertical plane
    through the head's x axis (it has no component along head y), so the footprint never turns about
    the vertical; a camera *rotated* about z by beta (a turntable) would fail this."""
    cam = FrameCamera("c", 100, 80, 0.01, 10.0)
    head = ActuatedHead("t", cam, gamma_rad=30 * DEG, law=law)
    beta = np.linspace(0, 2 * np.pi, 73)
    x_img = head.body_from_camera_rotation(beta) @ np.array([1.0, 0, 0])
    assert np.abs(x_img[:, 1]) == pytest.approx(np.zeros(73), abs=1e-15)
    assert np.all(x_img[:, 0] > 0.8)  # and it keeps pointing forward
    turntable = np.array([Rz(b) @ Ry(30 * DEG) @ N for b in beta]) @ np.array([1.0, 0, 0])
    assert np.max(np.abs(turntable[:, 1])) > 0.8


# ---------------------------------------------------------------- boresight curve
def test_curve_interpolation_is_periodic_and_accurate() -> None:
    beta = np.arange(72) * 5 * DEG
    truth = np.stack([np.sin(beta), np.cos(2 * beta), np.sin(beta + 1) ** 3], 1) * 1e-3
    h = 5 * DEG
    # error bounds (x 1e-3 scale): cubic spline 5/384 h^4 max|f''''| with max|f''''| = 21 for sin^3
    # ((3 sin x - sin 3x) / 4); linear h^2 / 8 max|f''| with max|f''| = 4 for cos 2x
    for interp, tol in (("cubic", 5 / 384 * h**4 * 21 * 1e-3), ("linear", h**2 / 8 * 4 * 1e-3)):
        c = BoresightCurve(beta, truth, interpolation=interp)
        assert c(beta) == pytest.approx(truth, abs=1e-15)  # through the samples
        q = np.linspace(-7.0, 13.0, 1001)
        want = np.stack([np.sin(q), np.cos(2 * q), np.sin(q + 1) ** 3], 1) * 1e-3
        assert np.max(np.abs(c(q) - want)) < tol
        assert c(q) == pytest.approx(c(q + 2 * np.pi), abs=1e-15)
        # continuity across 2 pi (value and, for cubic, slope)
        eps = 1e-7
        left, right = c(2 * np.pi - eps), c(eps)
        assert np.max(np.abs(left - right)) < 1e-8
        if interp == "cubic":
            s_left = (c(2 * np.pi - eps) - c(2 * np.pi - 2 * eps)) / eps
            s_right = (c(2 * eps) - c(eps)) / eps
            assert s_left == pytest.approx(s_right, abs=1e-6)
    assert c(np.zeros((2, 3))).shape == (2, 3, 3)


def test_curve_averaging_recovers_repeatability() -> None:
    """5 circles x 72 positions as in paper 000; the noise is the paper's Tab. 2 mean 2-sigma values."""
    rng = np.random.default_rng(20130501)
    beta = np.arange(72) * 5 * DEG
    truth = np.stack([0.02 * np.sin(beta), 0.015 * np.cos(beta + 0.4), 0.05 * np.sin(2 * beta)], 1) * DEG
    sigma = np.array([8.6, 7.8, 35.9]) / 1000 / 2 * DEG  # Tab. 2 gives 2 sigma
    circles = truth[None] + rng.normal(0.0, 1.0, (5, 72, 3)) * sigma
    curve = BoresightCurve.from_circles(beta, circles)
    assert np.all(curve.count == 5)
    n = 5
    c4 = np.sqrt(2 / (n - 1)) * gamma_fn(n / 2) / gamma_fn((n - 1) / 2)  # E[s] = c4 sigma
    rep = curve.repeatability()
    # mean of 72 sample stds: relative spread sqrt(1 - c4^2) / c4 / sqrt(72) = 4.3 %; allow 15 %
    assert rep.mean_std_rad == pytest.approx(c4 * sigma, rel=0.15)
    assert np.all(rep.max_std_rad > rep.mean_std_rad)
    # the mean curve: error sigma / sqrt(5) per position; RMS over 72 positions within 25 %
    rms = np.sqrt(np.mean((curve.corrections_rad - truth) ** 2, axis=0))
    assert rms == pytest.approx(sigma / np.sqrt(n), rel=0.25)
    table = rep.as_table_deg(2.0)
    assert table["dyaw"][0] == pytest.approx(35.9e-3 * c4, rel=0.15)
    # 361 image triplets: 5 circles plus the closing position 360 deg == 0 deg
    b361 = np.concatenate([np.tile(beta, 5), [2 * np.pi]])
    c361 = np.concatenate([circles.reshape(-1, 3), circles[:1, 0]])
    curve361 = BoresightCurve.from_samples(b361, c361)
    assert curve361.beta_rad.size == 72 and curve361.count[0] == 6 and np.all(curve361.count[1:] == 5)
    assert curve361.corrections_rad[1:] == pytest.approx(curve.corrections_rad[1:], abs=1e-18)


def test_curve_errors() -> None:
    with pytest.raises(SkyrigError, match="coincide"):
        BoresightCurve(np.array([0.0, 2 * np.pi, 1.0]), np.zeros((3, 3)))
    with pytest.raises(SkyrigError, match="at least 3"):
        BoresightCurve(np.array([0.0, 1.0]), np.zeros((2, 3)))
    with pytest.raises(SkyrigError, match="repeatability"):
        BoresightCurve(np.array([0.0, 1.0, 2.0]), np.zeros((3, 3))).repeatability()
