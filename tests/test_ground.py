"""Ground <-> image: DEM and height-surface intersection, forward intersection, on seeded synthetic scenes.

References: the synthetic truth (points placed on a known surface), and PROJ for every CRS step.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.camera.frame import FrameCamera
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.ground import Dem, forward_intersection, image_to_world_dem, image_to_world_height, world_to_image
from skyrig.geometry.rotations import matrix_from_opk

UTM = WorldFrame.map("EPSG:32632")
CAM = FrameCamera("cam", 4000, 3000, 0.004, 16.0)


def _eo(centres, opk_deg):
    c = np.asarray(centres, float)
    r = matrix_from_opk(*np.asarray(opk_deg, float).T, unit="deg")
    return ExteriorOrientations([f"img{i}" for i in range(len(c))], ["cam"] * len(c), c, r, UTM)


def _dem(fn, x0=500000.0, y0=5400000.0, n=400, cell=2.0):
    xs = x0 + (np.arange(n) + 0.5) * cell
    ys = y0 + n * cell - (np.arange(n) + 0.5) * cell
    X, Y = np.meshgrid(xs, ys)
    return Dem(fn(X, Y), (cell, 0.0, x0, 0.0, -cell, y0 + n * cell), UTM)


def test_dem_intersection_recovers_points_on_a_tilted_plane():
    # a plane is represented exactly by bilinear interpolation: truth is exact
    plane = lambda x, y: 200.0 + 0.03 * (x - 500000.0) - 0.02 * (y - 5400000.0)  # noqa: E731
    dem = _dem(plane)
    eo = _eo([[500400.0, 5400400.0, 1200.0], [500300.0, 5400350.0, 900.0]], [[2.0, -1.5, 30.0], [0.0, 40.0, 0.0]])
    rng = np.random.default_rng(1)
    xy = rng.uniform([500250, 5400250], [500550, 5400550], size=(200, 2))
    truth = np.column_stack([xy, plane(xy[:, 0], xy[:, 1])])
    images = np.where(np.arange(200) % 2 == 0, "img0", "img1")
    px = world_to_image(eo, {"cam": CAM}, images, truth, UTM)
    assert np.all(np.isfinite(px))
    back = image_to_world_dem(eo, {"cam": CAM}, images, px, dem)
    assert np.abs(back - truth).max() < 1e-3  # bisection to 2^-40 of the ray; the rest is PROJ round-off


def test_dem_intersection_returns_the_first_surface_hit():
    # a hill between an oblique camera and a point behind it: the ray hits the hill first
    hill = lambda x, y: 100.0 + 80.0 * np.exp(-((x - 500400.0) ** 2 + (y - 5400400.0) ** 2) / (2 * 40.0**2))  # noqa: E731
    dem = _dem(hill)
    eo = _eo([[500400.0, 5400000.0, 400.0]], [[60.0, 0.0, 0.0]])  # looks north, 60 deg off nadir
    behind = np.array([[500400.0, 5400520.0, float(hill(500400.0, 5400520.0))]])
    px = world_to_image(eo, {"cam": CAM}, ["img0"], behind, UTM)
    hit = image_to_world_dem(eo, {"cam": CAM}, ["img0"], px, dem)[0]
    assert hit[1] < 5400500.0  # stopped on the hill's south face
    assert abs(hit[2] - dem.sample(hit[:1], hit[1:2])[0]) < 0.01


def test_height_surface_in_a_map_frame_is_constant_ellipsoidal_height():
    eo = _eo([[500400.0, 5400400.0, 3000.0]], [[10.0, 5.0, 0.0]])
    px = np.array([[0.0, 0.0], [3999.0, 2999.0], [2000.0, 1500.0]])
    pts = image_to_world_height(eo, {"cam": CAM}, ["img0"] * 3, px, 150.0, UTM)
    np.testing.assert_allclose(pts[:, 2], 150.0, atol=1e-6)
    np.testing.assert_allclose(world_to_image(eo, {"cam": CAM}, ["img0"] * 3, pts, UTM), px, atol=1e-6)


def test_forward_intersection_with_noise_is_consistent_with_its_precision():
    rng = np.random.default_rng(7)
    centres = [[500000.0 + 300 * i, 5400000.0, 1000.0] for i in range(3)]
    eo = _eo(centres, [[0.0, 0.0, 0.0]] * 3)
    truth = np.column_stack([rng.uniform(500200, 500400, 50), rng.uniform(5399900, 5400100, 50), rng.uniform(90, 110, 50)])
    names = np.repeat([f"p{i}" for i in range(50)], 3)
    images = np.tile(["img0", "img1", "img2"], 50)
    px = world_to_image(eo, {"cam": CAM}, images, np.repeat(truth, 3, axis=0), UTM)
    sigma_px = 0.5
    res = forward_intersection(eo, {"cam": CAM}, names, images, px + rng.normal(0, sigma_px, px.shape), UTM)
    order = np.argsort([int(n[1:]) for n in res.point])
    err = res.xyz[order] - truth
    # predicted planimetric precision ~ sigma * GSD / sqrt(n_rays); GSD = 0.004/16*900 = 0.225 m
    gsd = 0.004 / 16.0 * 900.0
    assert np.sqrt(np.mean(err[:, :2] ** 2)) < 3 * sigma_px * gsd / np.sqrt(3)
    # residual RMS ~ sigma * sqrt(redundancy / observations) = sigma * sqrt(3/6)
    rms = np.sqrt(np.mean(res.residual_px**2))
    assert 0.5 * sigma_px * np.sqrt(0.5) < rms < 1.5 * sigma_px * np.sqrt(0.5)


def test_unknown_image_is_reported():
    eo = _eo([[500000.0, 5400000.0, 1000.0]], [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="nope"):
        world_to_image(eo, {"cam": CAM}, ["nope"], [[500000.0, 5400000.0, 0.0]], UTM)
