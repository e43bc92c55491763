"""Frame camera: OpenCV cross-checks, round trips, analytic Jacobians, GSD and footprints."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from skyrig.camera import (
    JACOBIAN_KINDS,
    BrownDistortion,
    FrameCamera,
    NoDistortion,
    OpenCVDistortion,
    OpenCVRationalDistortion,
    footprint_on_plane,
    footprint_on_surface,
    intersect_rays_with_surface,
    project_camera_with_jacobians,
    project_with_jacobians,
)
from skyrig.errors import GeometryError
from skyrig.geometry import Pose, matrix_from_opk, matrix_from_rotvec

# MIDAS 28 mm head (paper 004): Canon EOS 1Ds Mark III, 5616 x 3744 px, 6.4 um
W, H, PIX, F = 5616, 3744, 0.0064, 28.0
BROWN = BrownDistortion(k1=-1.0e-4, k2=1.5e-7, k3=-1.0e-10, p1=2.0e-6, p2=-3.0e-6, b1=5.0e-5, b2=-3.0e-5)
OPENCV = OpenCVDistortion(k1=-0.12, k2=0.09, p1=4e-4, p2=-7e-4, k3=-0.02)
RATIONAL = OpenCVRationalDistortion(k1=0.3, k2=-0.05, p1=-3e-4, p2=5e-4, k3=0.01, k4=0.4, k5=-0.02, k6=0.005)
# OpenCV's camera frame from ours: x right, y down, z forward
CV_FROM_CAM = np.diag([1.0, -1.0, -1.0])


def midas(distortion=None) -> FrameCamera:  # type: ignore[no-untyped-def]
    return FrameCamera("midas28", W, H, PIX, F, ppx_mm=0.071, ppy_mm=-0.043, distortion=distortion or NoDistortion())


def points_in_view(n: int, seed: int = 0, depth=(5.0, 50.0), fill: float = 0.95) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Camera-frame points whose ideal projections fill the image (z < 0)."""
    rng = np.random.default_rng(seed)
    z = -rng.uniform(*depth, size=n)
    u = rng.uniform(-fill, fill, size=n) * (W * PIX / 2) / F
    v = rng.uniform(-fill, fill, size=n) * (H * PIX / 2) / F
    return np.stack([-u * z, -v * z, z], axis=1)


def oblique_pose(seed: int = 3) -> Pose:
    rng = np.random.default_rng(seed)
    R = matrix_from_opk(*np.radians(rng.uniform([-40, -10, -180], [40, 10, 180])))
    return Pose(R, np.array([512300.0, 4300200.0, 2430.0]), "world", "camera")


# ---------------------------------------------------------------------- OpenCV cross-check
@pytest.mark.parametrize("dist", [NoDistortion(), OPENCV, RATIONAL], ids=lambda d: d.name)
def test_project_pixels_matches_cv2_projectPoints(dist) -> None:  # type: ignore[no-untyped-def]
    f_px, cx, cy = 4375.3, 2810.7, 1869.2
    cam = FrameCamera.from_pixels("c", W, H, f_px, cx, cy, pixel_size_mm=PIX, distortion=dist)
    pts = points_in_view(500)
    K = np.array([[f_px, 0, cx], [0, f_px, cy], [0, 0, 1.0]])
    coeffs = dist.params if dist.n_params else np.zeros(5)
    ref, _ = cv2.projectPoints((pts @ CV_FROM_CAM.T)[:, None, :], np.zeros(3), np.zeros(3), K, coeffs)
    np.testing.assert_allclose(cam.project_pixels(pts), ref[:, 0, :], rtol=0, atol=1e-6)
    assert cam.principal_point_px == pytest.approx((cx, cy), abs=1e-9)


def test_world_to_pixel_matches_cv2_with_a_pose() -> None:
    cam = midas(OPENCV)
    pose = oblique_pose()
    pts_w = pose.apply(points_in_view(300, depth=(400.0, 1500.0)))
    cv_from_world = CV_FROM_CAM @ pose.rotation.T
    rvec, _ = cv2.Rodrigues(cv_from_world)
    tvec = -cv_from_world @ pose.translation
    fx = cam.focal_px
    cx, cy = cam.principal_point_px
    K = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    ref, _ = cv2.projectPoints(pts_w[:, None, :], rvec, tvec, K, OPENCV.params)
    np.testing.assert_allclose(cam.world_to_pixel(pose, pts_w), ref[:, 0, :], rtol=0, atol=1e-6)


# ---------------------------------------------------------------------- round trips and conventions
@pytest.mark.parametrize("dist", [NoDistortion(), BROWN, OPENCV, RATIONAL], ids=lambda d: d.name)
def test_project_rays_reproject(dist) -> None:  # type: ignore[no-untyped-def]
    cam = midas(dist)
    pts = points_in_view(400, seed=5)
    px = cam.project_pixels(pts)
    rays = cam.rays_from_pixels(px)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(rays, pts / np.linalg.norm(pts, axis=1, keepdims=True), rtol=0, atol=1e-9)
    again = cam.project_pixels(rays * 17.0)
    np.testing.assert_allclose(again, px, rtol=1e-9, atol=0)
    assert cam.in_image(px).all()


def test_axis_directions_and_pixel_origin() -> None:
    cam = FrameCamera("c", 101, 81, 0.01, 10.0)
    # a point on the optical axis lands on the centre of the array (pixel 50, 40)
    np.testing.assert_allclose(cam.project_pixels([[0.0, 0.0, -5.0]]), [[50.0, 40.0]])
    # +x in the camera frame -> column increases; +y (up) -> row decreases
    c = cam.project_pixels([[0.1, 0.0, -5.0], [0.0, 0.1, -5.0]])
    assert c[0, 0] > 50 and c[0, 1] == pytest.approx(40.0)
    assert c[1, 1] < 40 and c[1, 0] == pytest.approx(50.0)
    # behind the camera -> NaN
    assert np.isnan(cam.project_pixels([[0.0, 0.0, 5.0]])).all()
    np.testing.assert_allclose(cam.pixel_to_image(cam.image_to_pixel([[0.3, -0.2]])), [[0.3, -0.2]])


def test_intrinsics_vector_round_trip() -> None:
    cam = midas(BROWN)
    assert cam.intrinsic_names == ("focal_mm", "ppx_mm", "ppy_mm", "k1", "k2", "k3", "p1", "p2", "b1", "b2")
    assert cam.with_intrinsics(cam.intrinsics) == cam
    with pytest.raises(ValueError):
        cam.with_intrinsics(cam.intrinsics[:-1])


# ---------------------------------------------------------------------- Jacobians
def _check_columns(analytic: np.ndarray, numeric: np.ndarray, rel: float = 1e-6) -> None:
    for j in range(analytic.shape[2]):
        scale = np.abs(numeric[:, :, j]).max()
        err = np.abs(analytic[:, :, j] - numeric[:, :, j]).max()
        assert err <= rel * scale, f"column {j}: error {err:.3g}, scale {scale:.3g}"


def _central(fun, x0: np.ndarray, steps) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for k, h in enumerate(steps):
        e = np.zeros_like(x0)
        e[..., k] = h
        cols.append((fun(x0 + e) - fun(x0 - e)) / (2 * h))
    return np.stack(cols, axis=-1)


INTRINSIC_STEPS = {
    "brown": [1e-4, 1e-4, 1e-4, 1e-8, 1e-11, 1e-14, 1e-7, 1e-7, 1e-6, 1e-6],
    "opencv": [1e-4, 1e-4, 1e-4] + [1e-6] * 5,
    "opencv_rational": [1e-4, 1e-4, 1e-4] + [1e-6] * 8,
    "none": [1e-4, 1e-4, 1e-4],
}


@pytest.mark.parametrize("dist", [NoDistortion(), BROWN, OPENCV, RATIONAL], ids=lambda d: d.name)
def test_jacobians_against_finite_differences(dist) -> None:  # type: ignore[no-untyped-def]
    cam = midas(dist)
    pose = oblique_pose()
    pts_c = points_in_view(80, seed=11, depth=(400.0, 1500.0), fill=0.9)
    pts_w = pose.apply(pts_c)
    px, jac = project_with_jacobians(cam, pose, pts_w, want=JACOBIAN_KINDS)
    np.testing.assert_allclose(px, cam.world_to_pixel(pose, pts_w), rtol=0, atol=1e-9)
    assert jac["point_camera"].shape == (80, 2, 3) and jac["point"].shape == (80, 2, 3)
    assert jac["pose"].shape == (80, 2, 6) and jac["intrinsics"].shape == (80, 2, 3 + dist.n_params)

    # camera-frame point
    num = _central(cam.project_pixels, pts_c, [1e-2] * 3)
    _check_columns(jac["point_camera"], num)
    # world point (each point perturbed on its own: the map is point-wise)
    num = _central(lambda x: cam.world_to_pixel(pose, x), pts_w, [1e-2] * 3)
    _check_columns(jac["point"], num)
    # pose: projection centre, then world_from_camera = R @ expmap(dtheta)
    R, C = pose.rotation, pose.translation

    def by_pose(delta: np.ndarray) -> np.ndarray:
        return cam.world_to_pixel(Pose(R @ matrix_from_rotvec(delta[3:]), C + delta[:3], "world", "camera"), pts_w)

    num = np.stack(
        [_central(lambda d: by_pose(d[0]), np.zeros((1, 6)), [1e-2] * 3 + [1e-6] * 3)[..., k] for k in range(6)],
        axis=-1,
    )
    _check_columns(jac["pose"], num)
    # intrinsics
    num = _central(lambda v: cam.with_intrinsics(v[0]).world_to_pixel(pose, pts_w), cam.intrinsics[None, :],
                   INTRINSIC_STEPS[dist.name])
    _check_columns(jac["intrinsics"], num)


def test_jacobians_with_a_batch_of_poses() -> None:
    cam = midas(BROWN)
    n = 20
    poses = [oblique_pose(seed) for seed in range(n)]
    batch = Pose(np.stack([p.rotation for p in poses]), np.stack([p.translation for p in poses]), "world", "camera")
    pts_c = points_in_view(n, seed=2, depth=(400.0, 900.0))
    pts_w = np.stack([p.apply(x) for p, x in zip(poses, pts_c)])
    px, jac = project_with_jacobians(cam, batch, pts_w)
    assert set(jac) == {"point", "pose", "intrinsics"}
    for i, p in enumerate(poses):
        px1, jac1 = project_with_jacobians(cam, p, pts_w[i : i + 1])
        np.testing.assert_allclose(px[i], px1[0], rtol=1e-14)
        for k in jac:
            np.testing.assert_allclose(jac[k][i], jac1[k][0], rtol=1e-12, atol=1e-12)
    px_c, d_point, d_intr = project_camera_with_jacobians(cam, pts_c)
    np.testing.assert_allclose(px_c, px, rtol=0, atol=1e-8)
    with pytest.raises(ValueError):
        project_with_jacobians(cam, batch, pts_w, want=("rotation",))
    # behind the camera: NaN, not garbage
    px_b, jac_b = project_with_jacobians(cam, poses[0], poses[0].apply([[0.0, 0.0, 10.0]]))
    assert np.isnan(px_b).all() and np.isnan(jac_b["pose"]).all()


# ---------------------------------------------------------------------- GSD
def test_gsd_nadir_and_published_midas_figures() -> None:
    cam = FrameCamera("nadir28", W, H, PIX, F)
    h_m = 2000 * 0.3048  # paper 004, 28 mm bore-sight flight at 2,000 ft above ground: GSD "5 inch"
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 1820.0 + h_m]), "world", "camera")
    g = cam.gsd_at(pose, ground_height=1820.0)
    assert g.col_m == pytest.approx(float(cam.gsd(h_m)), rel=1e-12)
    assert g.row_m == pytest.approx(h_m * PIX / F, rel=1e-12)
    assert g.area_m2 == pytest.approx(g.col_m * g.row_m, rel=1e-12)
    assert g.slant_m == pytest.approx(h_m, rel=1e-12)
    assert g.col_m / 0.0254 == pytest.approx(5.0, rel=0.12)  # published: 5 in (computed 5.5 in)
    g2 = cam.gsd_at(Pose(np.eye(3), np.array([0.0, 0.0, 1820.0 + 2 * h_m]), "world", "camera"), 1820.0)
    assert g2.col_m / 0.0254 == pytest.approx(10.5, rel=0.06)  # 4,000 ft: published 10.5 in


def test_gsd_oblique_45_degrees() -> None:
    cam = FrameCamera("oblique50", W, H, PIX, 50.0)
    hgt, tilt = 600.0, math.radians(45.0)
    pose = Pose(matrix_from_opk(tilt, 0.0, 0.0), np.array([0.0, 0.0, hgt]), "world", "camera")
    g = cam.gsd_at(pose, 0.0)
    # independent geometry: slant range H / cos t; across-tilt H p / (f cos t), along-tilt H p / (f cos^2 t)
    assert g.slant_m == pytest.approx(hgt / math.cos(tilt), rel=1e-12)
    assert g.col_m == pytest.approx(hgt * PIX / 50.0 / math.cos(tilt), rel=1e-9)
    assert g.row_m == pytest.approx(hgt * PIX / 50.0 / math.cos(tilt) ** 2, rel=1e-9)
    assert g.mean_m == pytest.approx((g.col_m + g.row_m) / 2)


def test_gsd_at_agrees_with_footprint_differences_with_distortion() -> None:
    cam = midas(BROWN)
    pose = oblique_pose(8)
    pose = Pose(matrix_from_opk(*np.radians([30.0, -12.0, 70.0])), pose.translation, "world", "camera")
    pix = np.array([[1000.0, 900.0], [4000.0, 3000.0], [2807.5, 1871.5]])
    g = cam.gsd_at(pose, 1820.0, pixels=pix)
    h = 0.5
    dc = (footprint_on_plane(cam, pose, 1820.0, pix + [h, 0]) - footprint_on_plane(cam, pose, 1820.0, pix - [h, 0])) / (2 * h)
    dr = (footprint_on_plane(cam, pose, 1820.0, pix + [0, h]) - footprint_on_plane(cam, pose, 1820.0, pix - [0, h])) / (2 * h)
    np.testing.assert_allclose(g.col_m, np.linalg.norm(dc, axis=1), rtol=1e-6)
    np.testing.assert_allclose(g.row_m, np.linalg.norm(dr, axis=1), rtol=1e-6)
    with pytest.raises(GeometryError):
        cam.gsd_at(Pose(matrix_from_opk(math.radians(100), 0, 0), np.array([0, 0, 500.0]), "world", "camera"))


# ---------------------------------------------------------------------- footprints on surfaces
def test_footprint_on_flat_and_sloped_surfaces() -> None:
    cam = midas(BROWN)
    pose = Pose(matrix_from_opk(*np.radians([20.0, 5.0, 30.0])), np.array([100.0, 200.0, 2430.0]), "world", "camera")
    flat = footprint_on_surface(cam, pose, lambda x, y: np.full_like(x, 1820.0), tol_m=1e-7)
    np.testing.assert_allclose(flat, footprint_on_plane(cam, pose, 1820.0), rtol=0, atol=1e-6)

    a, b, c0 = 0.15, -0.08, 1800.0
    pix = np.random.default_rng(4).uniform([0, 0], [W - 1, H - 1], size=(500, 2))
    got = footprint_on_surface(cam, pose, lambda x, y: a * x + b * y + c0, pixels=pix, tol_m=1e-6)
    d = pose.rotate(cam.rays_from_pixels(pix))
    C = pose.translation
    t = (a * C[0] + b * C[1] + c0 - C[2]) / (d[:, 2] - a * d[:, 0] - b * d[:, 1])  # ray/plane, by hand
    np.testing.assert_allclose(got, C + t[:, None] * d, rtol=0, atol=1e-5)


def test_footprint_on_rough_terrain_oblique() -> None:
    cam = midas(OPENCV)
    pose = Pose(matrix_from_opk(math.radians(45.0), 0.0, 0.0), np.array([0.0, 0.0, 2430.0]), "world", "camera")

    def dem(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return 1820.0 + 40.0 * np.sin(x / 150.0) * np.cos(y / 90.0) + 0.05 * y

    pix = np.stack(np.meshgrid(np.linspace(0, W - 1, 40), np.linspace(H * 0.3, H - 1, 25)), -1).reshape(-1, 2)
    pts = footprint_on_surface(cam, pose, dem, pixels=pix, tol_m=1e-5)
    assert np.abs(pts[:, 2] - dem(pts[:, 0], pts[:, 1])).max() <= 1e-5
    # the points lie on the viewing rays, in front of the camera
    d = pose.rotate(cam.rays_from_pixels(pix))
    v = pts - pose.translation
    assert np.abs(np.cross(v, d)).max() < 1e-6 * np.linalg.norm(v, axis=1).max()
    assert np.all(np.einsum("ij,ij->i", v, d) > 0)
    # and re-project onto their pixels
    np.testing.assert_allclose(cam.world_to_pixel(pose, pts), pix, rtol=0, atol=1e-6)


def test_surface_intersection_errors() -> None:
    flat = lambda x, y: np.zeros_like(x)  # noqa: E731
    with pytest.raises(GeometryError):  # origin below the surface
        intersect_rays_with_surface([0.0, 0.0, -1.0], [[0.0, 0.0, -1.0]], flat)
    with pytest.raises(GeometryError):  # pointing at the sky
        intersect_rays_with_surface([0.0, 0.0, 100.0], [[0.0, 0.3, 1.0]], flat, max_distance_m=1e5)
    with pytest.raises(GeometryError):  # DEM undefined there
        intersect_rays_with_surface([0.0, 0.0, 100.0], [[1.0, 0.0, -0.1]], lambda x, y: np.where(x > 10, np.nan, 0.0))
