"""Tests for skyrig.geometry.pose.Pose: composition, inverse, application, frames, batches."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyrig.errors import FrameError
from skyrig.geometry.pose import Pose


def _pose(seed, dst, src, n=None):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    t = rng.normal(scale=100.0, size=(3,) if n is None else (n, 3))
    return Pose(R, t, dst, src)


def _homogeneous(p):
    m = np.zeros(p.rotation.shape[:-2] + (4, 4))
    m[..., :3, :3] = p.rotation
    m[..., :3, 3] = p.translation
    m[..., 3, 3] = 1.0
    return m


def test_apply_is_r_x_plus_t():
    p = _pose(1, "world", "camera")
    x = np.random.default_rng(2).normal(size=(7, 3))
    np.testing.assert_allclose(p.apply(x), x @ p.rotation.T + p.translation, atol=1e-12)
    # translation is the origin of src in dst
    np.testing.assert_allclose(p.apply(np.zeros(3)), p.translation, atol=1e-15)
    np.testing.assert_allclose(p.rotate(x), x @ p.rotation.T, atol=1e-12)
    np.testing.assert_allclose(p.apply_inverse(p.apply(x)), x, atol=1e-12)
    assert p.name == "world_from_camera"


def test_compose_matches_homogeneous_matrices():
    a = _pose(3, "world", "body")
    b = _pose(4, "body", "camera")
    c = a @ b
    assert (c.dst, c.src) == ("world", "camera")
    np.testing.assert_allclose(_homogeneous(c), _homogeneous(a) @ _homogeneous(b), atol=1e-10)
    x = np.random.default_rng(5).normal(size=(4, 3))
    np.testing.assert_allclose(c.apply(x), a.apply(b.apply(x)), atol=1e-10)


def test_inverse_identities():
    a = _pose(6, "world", "camera")
    inv = a.inverse()
    assert inv.name == "camera_from_world"
    np.testing.assert_allclose(_homogeneous(inv), np.linalg.inv(_homogeneous(a)), atol=1e-12)
    for e in (a @ inv, inv @ a):
        np.testing.assert_allclose(e.rotation, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(e.translation, 0.0, atol=1e-12)
    assert (a @ inv).name == "world_from_world"
    i = Pose.identity("world", "camera")
    np.testing.assert_allclose((a @ Pose.identity("camera", "camera")).translation, a.translation)
    np.testing.assert_array_equal(i.apply([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0])
    # associativity
    b, c = _pose(7, "camera", "sensor"), _pose(8, "sensor", "pixel")
    np.testing.assert_allclose(_homogeneous((a @ b) @ c), _homogeneous(a @ (b @ c)), atol=1e-10)


def test_mismatched_frames_raise():
    a = _pose(9, "world", "body")
    b = _pose(10, "camera", "sensor")
    with pytest.raises(FrameError, match="body"):
        a @ b
    with pytest.raises(ValueError):  # FrameError is a ValueError
        a @ a
    assert a.__matmul__(3) is NotImplemented


def test_bad_shapes():
    with pytest.raises(ValueError):
        Pose(np.eye(2), np.zeros(3), "a", "b")
    with pytest.raises(ValueError):
        Pose(np.eye(3), np.zeros(2), "a", "b")


def test_batch_broadcasting():
    n = 6
    batch = _pose(11, "world", "body", n)  # world_from_body per exposure
    mount = _pose(12, "body", "camera")  # one fixed mount
    wc = batch @ mount
    assert len(wc) == n and wc.rotation.shape == (n, 3, 3) and wc.translation.shape == (n, 3)
    for i in range(n):
        single = batch[i] @ mount
        np.testing.assert_allclose(wc[i].rotation, single.rotation, atol=1e-12)
        np.testing.assert_allclose(wc[i].translation, single.translation, atol=1e-10)
    # single @ batch too
    cam = _pose(13, "camera", "sensor", n)
    ms = mount @ cam
    for i in range(n):
        np.testing.assert_allclose(_homogeneous(ms[i]), _homogeneous(mount) @ _homogeneous(cam[i]), atol=1e-10)
    # apply: one point per pose, and the batch inverse
    x = np.random.default_rng(14).normal(size=(n, 3))
    y = wc.apply(x)
    for i in range(n):
        np.testing.assert_allclose(y[i], wc[i].apply(x[i]), atol=1e-10)
    np.testing.assert_allclose(wc.inverse().apply(y), x, atol=1e-9)
    np.testing.assert_allclose(wc.apply_inverse(y), x, atol=1e-9)
    with pytest.raises(TypeError):
        len(mount)


def test_frozen():
    p = Pose.identity("a", "b")
    with pytest.raises(Exception):
        p.dst = "c"  # type: ignore[misc]
