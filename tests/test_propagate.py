"""skyrig.match.propagate: the local maps planes induce between two views (against the maps of pinhole cameras
differentiated numerically), and the propagation of a point by its appearance on synthetic textures whose true
homologue is known exactly (image B = image A under a known affine); its refusals (a repeated pattern, no
correlation)."""

from __future__ import annotations

import cv2
import numpy as np

from skyrig.match.propagate import plane_maps, propagate_point


def _look_at(C, target, f=1000.0, c=(500.0, 400.0)):
    """A pinhole camera at C looking at target (z forward, x right, y down), as ``X -> pixel``."""
    z = np.asarray(target, float) - C
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])  # camera_from_world

    def project(X):
        p = R @ (np.asarray(X, float) - C)
        return np.array([f * p[0] / p[2] + c[0], f * p[1] / p[2] + c[1]])
    return project


def _jac(fun, X, e=1e-6):
    return np.stack([(fun(X + d) - fun(X - d)) / (2 * e) for d in np.eye(3) * e], axis=1)


def test_plane_maps_match_the_cameras_on_that_plane():
    """Two cameras symmetric about a facade's normal (the plane y = 10, up z): the ``facade`` map equals the map the
    cameras induce on that plane (differentiated along it), and the ``ground`` map on the level plane; the maps
    differ from each other (this is a wide, oblique pair: 6 m baseline at 10 m)."""
    X = np.array([1.0, 10.0, 3.0])
    ca, cb = np.array([-2.0, 0.0, 1.6]), np.array([4.0, 0.0, 1.6])
    pa, pb = _look_at(ca, X + [0.5, 0, 0.3]), _look_at(cb, X + [-0.4, 0, -0.2])
    maps = plane_maps(_jac(pa, X), _jac(pb, X), X - ca, X - cb)
    assert set(maps) == {"ground", "facing", "facade"}
    for name, U in (("facade", np.array([[1.0, 0, 0], [0, 0, 1.0]]).T), ("ground", np.array([[1.0, 0, 0], [0, 1.0, 0]]).T)):
        truth = (_jac(pb, X) @ U) @ np.linalg.inv(_jac(pa, X) @ U)
        # the same map from the cameras' images of small steps along the plane
        steps = np.array([pb(X + U @ s) - pb(X) for s in ([0.01, 0], [0, 0.01])]).T @ np.linalg.inv(
            np.array([pa(X + U @ s) - pa(X) for s in ([0.01, 0], [0, 0.01])]).T)
        assert np.allclose(maps[name], truth, atol=1e-6) and np.allclose(maps[name], steps, atol=2e-3), name
    assert np.abs(maps["facade"] - maps["ground"]).max() > 0.1


def _texture(seed, size=320, blur=2.0):
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.uniform(0, 255, (size, size)).astype(np.float32), (0, 0), blur)


def test_propagation_under_scale_and_rotation_from_a_start_far_off():
    """Image B = image A scaled 1.6 x and rotated 25 degrees: from a start 21 px off, searched within 30 px, the
    point is found within 0.05 px of its true homologue through the candidate map that is the true one; the identity
    alone does not find it."""
    g1 = _texture(1)
    a = np.radians(25.0)
    L = 1.6 * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    t = np.array([160.0, 160.0]) - L @ [150.0, 150.0]
    g2 = cv2.warpAffine(g1, np.c_[L, t], (320, 320), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    x1 = np.array([151.3, 148.6])
    truth = L @ x1 + t
    start = truth + [-15.0, 15.0]
    got = propagate_point(g1, x1, g2, start, 30.0, {"true": L, "half": 0.5 * L})
    assert got.ok and got.source == "true", got
    assert np.hypot(*(got.xy - truth)) < 0.05 and got.correlation > 0.97, (got.xy, truth)
    alone = propagate_point(g1, x1, g2, start, 30.0, {})
    assert not (alone.ok and np.hypot(*(alone.xy - truth)) < 0.5), alone


def test_refusals_repeated_pattern_and_no_correlation():
    """A texture repeating every 14 px along the rows, searched over 20 px: two equal correlation peaks, refused
    as ambiguous (found without the check); an unrelated image: refused for its correlation."""
    tile = _texture(2, size=320)[:, :14]
    g1 = np.tile(tile, (1, 23))[:, :320].copy()
    g2 = np.roll(g1, 5, axis=1)
    x1 = np.array([160.0, 160.0])
    got = propagate_point(g1, x1, g2, x1 + [5.0, 0.0], 20.0, {})
    assert not got.ok and "ambiguous" in got.note, got
    loose = propagate_point(g1, x1, g2, x1 + [5.0, 0.0], 20.0, {}, ambiguity=None)
    assert loose.ok and abs((loose.xy[0] - x1[0] - 5.0 + 7.0) % 14.0 - 7.0) < 0.05 and abs(loose.xy[1] - 160.0) < 0.05
    other = propagate_point(g1, x1, _texture(9), x1, 10.0, {}, min_correlation=0.8)
    assert not other.ok and "below 0.80" in other.note, other
