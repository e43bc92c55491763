"""skyrig.match.propagate.search_lsm: a start far off (beyond LSM's pull-in) and a scale / shear change between the
views, on a synthetic texture whose true homologue is known exactly (image 2 = image 1 under a known affine)."""

from __future__ import annotations

import cv2
import numpy as np

from skyrig.match.lsm import lsm_refine
from skyrig.match.propagate import search_lsm


def _pair(A: np.ndarray, t: np.ndarray, seed: int = 3):
    rng = np.random.default_rng(seed)
    g1 = cv2.GaussianBlur(rng.uniform(0, 255, (240, 240)).astype(np.float32), (0, 0), 2.0)
    M = np.c_[A, t]  # image 2 pixel = A @ image 1 pixel + t
    g2 = cv2.warpAffine(g1, M, (240, 240), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return g1, g2, M


def test_search_finds_far_start_under_scale_and_shear():
    A = np.array([[1.25, 0.15], [-0.05, 0.9]])
    g1, g2, M = _pair(A, np.array([-20.0, 12.0]))
    x1 = np.array([110.3, 118.7])
    truth = M[:, :2] @ x1 + M[:, 2]
    start = truth + [19.0, -14.0]  # 23.6 px off
    # plain LSM from there (the page before): no convergence to the truth
    plain = lsm_refine(g1, g2, x1[None], start[None], A[None], half_size=10, max_shift_px=8.0)
    assert not (plain.ok[0] and np.hypot(*(plain.xy2[0] - truth)) < 0.5)
    # identity as the only candidate cannot match a 25 % scale change exactly; the true affine among candidates wins
    xy, ok, sig, corr, _ = search_lsm(g1, g2, x1, start, np.stack([np.eye(2), A]), search_px=30.0)
    assert ok and corr > 0.95
    assert np.hypot(*(xy - truth)) < 0.1, (xy, truth)
    assert 0 < sig < 0.2


def test_search_refuses_beyond_radius_and_zero_search_is_plain_lsm():
    A = np.eye(2)
    g1, g2, M = _pair(A, np.array([5.0, -3.0]), seed=5)
    x1 = np.array([120.0, 120.0])
    truth = x1 + M[:, 2]
    # the homologue 24 px from the start, search 10 px: not found there (no proposal beyond the radius + 3 px)
    xy, ok, *_ = search_lsm(g1, g2, x1, truth + [24.0, 0.0], A[None], search_px=10.0)
    assert not ok or np.hypot(*(xy - (truth + [24.0, 0.0]))) <= 13.0 + 1e-9
    # no search: LSM from a start 2 px off, as lsm_refine
    xy, ok, *_ = search_lsm(g1, g2, x1, truth + [1.5, -1.2], A[None], search_px=0.0)
    ref = lsm_refine(g1, g2, x1[None], (truth + [1.5, -1.2])[None], A[None], half_size=10, max_shift_px=8.0)
    assert ok and np.allclose(xy, ref.xy2[0]) and np.hypot(*(xy - truth)) < 0.05
