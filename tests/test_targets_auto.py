"""Automatic target detection (skyrig.match.targets, issue 32): chequer corners and ArUco markers drawn at a known
sub-pixel position through a projective warp of a high-resolution template (8x supersampled, Gaussian PSF, area
averaged: anti-aliased), with noise; and no detection on a target-free textured patch.

Tolerances.  Chequer: a straight edge of contrast C, Gaussian width s and noise sn gives an edge offset of
sn sqrt(2 sqrt(pi) s / L) / C over L pixels along it; with C = 150, sn = 3, s = 1.2 (the PSF, FWHM 2.8 px) and
L = 20 (cornerSubPix's 11 x 11 window) that is 0.013 px per edge; 0.1 px is ~7 of those, leaving room for the
sampling bias of cornerSubPix's discrete window (measured: max 0.08 px, typically 0.03).  ArUco: the corners
are re-measured as intersections of lines fitted to 16 mid-grey crossings per outer edge; with C = 205, sn = 3,
s = 0.8 that is 0.006 px per edge, and the marker's inner cells stay beyond the 3-px profiles: 0.1 px is again
generous (measured: max 0.04 px; the detector's own cornerSubPix corners gave 0.17 px, a rounded-corner bias).
No false positive in 45 searches of a textured patch with straight edges and a line crossing an edge.
"""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from skyrig.match.targets import aruco_centre, chequer_centre, detect_target  # noqa: E402

S = 8  # supersampling


def _render(template: np.ndarray, H_lo: np.ndarray, shape: tuple[int, int], bg: float, psf: float,
            noise: float, rng) -> np.ndarray:
    """``template`` (grey, its pixel (i, j) centre at (j, i)) warped by ``H_lo`` (template pixels -> low-res
    pixels, pixel centres at integers) onto a low-res image of ``shape`` with background ``bg``."""
    # low-res x = (X_hr + 0.5) / S - 0.5  <=>  X_hr = S (x + 0.5) - 0.5
    A = np.array([[S, 0, S / 2 - 0.5], [0, S, S / 2 - 0.5], [0, 0, 1.0]])
    hr = cv2.warpPerspective(template.astype(np.float32), A @ H_lo, (shape[1] * S, shape[0] * S),
                             flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
    hr = np.where(hr < 0, bg, hr).astype(np.float32)
    hr = cv2.GaussianBlur(hr, (0, 0), psf * S)
    lo = hr.reshape(shape[0], S, shape[1], S).mean(axis=(1, 3))
    return lo + rng.normal(0.0, noise, lo.shape)


def _homography(rng, centre_lo, tpl_centre, scale) -> np.ndarray:
    """A projective map taking the template's point ``tpl_centre`` to ``centre_lo``: scale, rotation, shear and a
    perspective term."""
    a = rng.uniform(0, np.pi)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    M = R @ np.array([[1.0, rng.uniform(-0.25, 0.25)], [0.0, rng.uniform(0.7, 1.0)]]) * scale
    H = np.eye(3)
    H[:2, :2] = M
    H[2, :2] = rng.uniform(-1, 1, 2) * 2e-4
    T0 = np.array([[1, 0, -tpl_centre[0]], [0, 1, -tpl_centre[1]], [0, 0, 1.0]])
    H = H @ T0
    H /= H[2, 2]
    p = H @ [*tpl_centre, 1.0]  # = (0, 0, w): rescale so the centre maps to centre_lo
    T1 = np.array([[1, 0, centre_lo[0]], [0, 1, centre_lo[1]], [0, 0, 1.0]])
    assert np.allclose(p[:2], 0)
    return T1 @ H


def _chequer_template(n=400) -> np.ndarray:
    t = np.full((n, n), 40.0)
    t[: n // 2, : n // 2] = 190.0
    t[n // 2:, n // 2:] = 190.0
    return t


def test_chequer_corner_found_to_a_tenth_of_a_pixel():
    rng = np.random.default_rng(7)
    tpl = _chequer_template()
    # template pixel centres at integers: the corner is between pixels 199 and 200
    c_tpl = (199.5, 199.5)
    errs = []
    for _ in range(12):
        truth = np.array([40.0, 40.0]) + rng.uniform(-3, 3, 2)
        H = _homography(rng, truth, c_tpl, scale=0.12)  # 400 template px -> ~48 px: squares of ~24 px
        img = _render(tpl, H, (80, 80), 115.0, psf=1.2, noise=3.0, rng=rng)
        f = chequer_centre(img, truth + rng.uniform(-4, 4, 2), search_px=8.0)
        assert f.ok, f.note
        errs.append(np.hypot(*(f.xy - truth)))
        assert f.sigma_px < 0.05
    assert max(errs) < 0.1, errs
    # through detect_target (the disc search would take one bright square: the chequer test comes first)
    f, words, _ = detect_target(img, truth, search_px=8.0)
    assert f.ok and words == "chequer corner" and np.hypot(*(f.xy - truth)) < 0.1


def _textured(rng, shape=(80, 80)) -> np.ndarray:
    """Ground-like texture: smoothed noise at several scales, a few straight edges (a road, a roof)."""
    img = np.zeros(shape)
    for s, a in ((1.0, 20), (3.0, 40), (8.0, 60)):
        img += a * cv2.GaussianBlur(rng.normal(0, 1, shape), (0, 0), s) * s
    img[:, 50:] += 60.0  # a straight edge
    img[30:34, :] -= 50.0  # a line crossing it
    return 120.0 + img + rng.normal(0, 3.0, shape)


def test_no_target_on_a_textured_patch():
    rng = np.random.default_rng(11)
    found = 0
    tries = 0
    for _ in range(15):
        img = _textured(rng)
        for xy0 in ([40.0, 40.0], [50.0, 32.0], [25.0, 55.0]):
            tries += 1
            f, _, _ = detect_target(img, xy0, search_px=12.0)
            found += f.ok
    assert found == 0, f"{found} false targets in {tries} searches"


def test_aruco_marker_centre():
    rng = np.random.default_rng(5)
    dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    m = dic.generateImageMarker(17, 360).astype(np.float64)  # 6 cells of 60 px (4 x 4 + black border)
    tpl = np.full((600, 600), 230.0)
    tpl[120:480, 120:480] = np.where(m > 127, 230.0, 25.0)
    c_tpl = (299.5, 299.5)  # the marker's centre in template pixel coordinates
    errs = []
    for _ in range(8):
        truth = np.array([50.0, 50.0]) + rng.uniform(-3, 3, 2)
        H = _homography(rng, truth, c_tpl, scale=0.11)  # marker ~40 px, cells ~6.6 px
        img = _render(tpl, H, (100, 100), 110.0, psf=0.8, noise=3.0, rng=rng)
        mk = aruco_centre(img, truth + rng.uniform(-3, 3, 2))
        assert mk is not None and mk.marker_id == 17 and mk.dictionary == "DICT_4X4_250"
        errs.append(np.hypot(*(mk.fit.xy - truth)))
    assert max(errs) < 0.1, errs
    f, words, _ = detect_target(img, truth)
    assert f.ok and "marker 17" in words
    # a marker far from the start position is not taken
    assert aruco_centre(img, truth + [45.0, 0.0], search_px=5.0) is None


def test_target_kinds_in_words():
    """``--targets``: a list of kinds or 'none'; an unknown kind is refused naming the option."""
    import click

    from skyrig.cli.measure import _target_kinds

    assert _target_kinds("chequer, disc") == ("chequer", "disc") and _target_kinds("none") == ()
    with pytest.raises(click.BadParameter, match="unknown target kind 'qr'"):
        _target_kinds("disc,qr")
    with pytest.raises(ValueError, match="unknown target kind 'qr'"):
        detect_target(np.zeros((40, 40)), (20.0, 20.0), kinds=("qr",))
