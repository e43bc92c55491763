"""COLMAP SIFT's first octave (FeatureConfig.colmap_first_octave): on an image that fills the feature budget from
octave 0 on, skipping COLMAP's upsampled octave -1 keeps (nearly) the same keypoints; a budget octave 0 does not fill
falls back to COLMAP's default.  Judged against pycolmap's own run at its default first octave (-1)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.errors import ConfigError
from skyrig.match.features import OCTAVE0_PIXELS_PER_FEATURE, FeatureConfig, extract_features, first_octave

pytest.importorskip("pycolmap")


def _texture(h: int, w: int, seed: int = 3) -> np.ndarray:
    """Seeded blob texture with structure at several scales (grey uint8)."""
    import cv2

    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.float32)
    for s in (2.0, 5.0, 12.0):
        img += cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), s) * s
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return img.astype(np.uint8)


def test_auto_rule_and_option_check() -> None:
    fc = FeatureConfig(method="pycolmap", max_features=1000)
    assert first_octave(fc, (OCTAVE0_PIXELS_PER_FEATURE * 1000 // 1000, 1000)) == 0
    assert first_octave(fc, (OCTAVE0_PIXELS_PER_FEATURE * 1000 // 1000 - 1, 1000)) == -1
    assert first_octave(FeatureConfig(method="pycolmap", colmap_first_octave=-1), (9000, 9000)) == -1
    with pytest.raises(ConfigError, match="colmap_first_octave"):
        FeatureConfig(colmap_first_octave=1)


def test_octave0_keeps_colmaps_keypoints_when_the_budget_is_filled() -> None:
    from scipy.spatial import cKDTree

    img = _texture(900, 1200)
    budget = 1200  # 1.08 MP >= 800 px x 1,200: auto tries octave 0, whose keypoints fill the budget here
    auto = extract_features(img, FeatureConfig(method="pycolmap", max_size=None, max_features=budget))
    zero = extract_features(img, FeatureConfig(method="pycolmap", max_size=None, max_features=budget,
                                               colmap_first_octave=0))
    colmap = extract_features(img, FeatureConfig(method="pycolmap", max_size=None, max_features=budget,
                                                 colmap_first_octave=-1))
    assert len(zero) >= budget
    np.testing.assert_array_equal(auto.xy, zero.xy)
    dist, _ = cKDTree(zero.xy).query(colmap.xy)
    assert np.mean(dist < 0.5) >= 0.9, np.mean(dist < 0.5)
    assert abs(len(zero) - len(colmap)) <= 0.15 * len(colmap)


def test_unfilled_budget_falls_back_to_colmaps_default() -> None:
    import cv2

    rng = np.random.default_rng(5)  # a flat image with 25 small bright spots: few keypoints at any octave
    img = np.zeros((300, 400), np.float32)
    img[rng.integers(20, 280, 25), rng.integers(20, 380, 25)] = 1.0
    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    img = (img / img.max() * 200 + 20).astype(np.uint8)
    fc = FeatureConfig(method="pycolmap", max_size=None, max_features=100)
    assert first_octave(fc, img.shape) == 0  # 120,000 px >= 800 x 100: octave 0 is tried
    zero = extract_features(img, FeatureConfig(method="pycolmap", max_size=None, max_features=100,
                                               colmap_first_octave=0))
    assert len(zero) < 100  # the budget is not filled from octave 0
    auto = extract_features(img, fc)
    colmap = extract_features(img, FeatureConfig(method="pycolmap", max_size=None, max_features=100,
                                                 colmap_first_octave=-1))
    np.testing.assert_array_equal(auto.xy, colmap.xy)
