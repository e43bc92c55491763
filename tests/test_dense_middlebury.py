"""Matcher quality on public stereo benchmarks, through skyrig's one matching path
(:func:`skyrig.dense.sgm.match_rectified` with the default :class:`SgmConfig`), next to raw OpenCV StereoSGBM
on the same images in the same run.

Metric: share of pixels with known ground truth whose disparity is off by more than the threshold, an
invalid (unmatched) pixel counted as bad.

Raw StereoSGBM, "typical settings" (OpenCV's documented recipe, the same numbers as skyrig's defaults):
``minDisparity=0``, ``numDisparities`` = the search window rounded up to a multiple of 16, ``blockSize=5``,
``P1 = 8 * cn * 5**2``, ``P2 = 32 * cn * 5**2``, ``disp12MaxDiff=1``, ``preFilterCap=63``,
``uniquenessRatio=10``, ``speckleWindowSize=100``, ``speckleRange=2``, mode SGBM (5 paths), on the whole
images as given.  Raw SGBM leaves its first ``numDisparities`` columns without result (counted bad);
skyrig's path pads the crop so those columns get a match.

Disparity windows come from the ground truth's own range, not from tuning: ``[0, ceil(max GT)]``
(Cones 0..55, Motorcycle 0..60).  Both images are matched in grey, as the aerial path
(:func:`skyrig.dense.stereo.match_block`) does.

Cones (Middlebury 2003, quarter size 450 x 375, ``Cones_LEFT_GT.tif`` float d = x_left - x_right,
0 = unknown; ``Occlusion_LEFT.png`` 255 = visible in the right image): the issue's 12.75 % is raw
StereoSGBM's figure over the *non-occluded* known pixels (this test reproduces 13.6 % with the settings
above; 12.8 % with blockSize 3 and uniqueness 0).  Over *all* known pixels, occluded ones included
(11.9 % of the known pixels are seen by the left camera only), a matcher with a left-right check leaves
occlusions invalid, so neither unfilled path gets near 12.75 % there (skyrig 17.8 %, raw 23.4 %).  With
``SgmConfig(fill_occlusions=True, edge_erode_px=1)`` (the foreground fattening at depth edges eroded by 1 px, then
every unmatched pixel given the farther of its nearest matched row neighbours: the background an occluded pixel
sees) the same path gives a dense map: 11.0 % bad over all known pixels (5.2 % non-occluded), Motorcycle 7.5 %.

Motorcycle (Middlebury 2014, shipped in the scikit-image wheel, downsampled by 4 to 741 x 500;
``motorcycle_disp.npz`` ``arr_0`` float32, inf = unknown): the ground truth is the disparity between the
two given images' pixels (verified: both matchers agree with it to < 2 px on > 80 % of the pixels); the
calibration's ``doffs`` (31.086 px, scikit-image's docstring: "Principal point dx") only enters depth
``Z = f B / (d + doffs)``, not the matching, so no offset is applied.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path

cv2 = pytest.importorskip("cv2")

from skyrig.dense.sgm import SgmConfig, match_rectified  # noqa: E402

#: raw StereoSGBM's bad > 1 px on Cones, non-occluded known pixels (issue 10)
CONES_BOUND_PCT = 12.75
#: the issue's bound for Motorcycle, bad > 2 px over all known pixels
MOTORCYCLE_BOUND_PCT = 20.0
#: the dense (occlusion-filled) configuration of the same matching path
FILLED = SgmConfig(fill_occlusions=True, edge_erode_px=1)


def raw_sgbm(left: np.ndarray, right: np.ndarray, d_max: float, block_size: int = 5) -> np.ndarray:
    """Raw OpenCV StereoSGBM with the typical settings stated in the module docstring; NaN = invalid."""
    n = int(np.ceil((np.ceil(d_max) + 1) / 16.0)) * 16
    cn = 1 if left.ndim == 2 else left.shape[2]
    bs2 = block_size * block_size
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n, blockSize=block_size, P1=8 * cn * bs2,
                              P2=32 * cn * bs2, disp12MaxDiff=1, preFilterCap=63, uniquenessRatio=10,
                              speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM)
    d16 = m.compute(left, right)
    d = d16.astype(np.float32) / 16.0
    d[d16 < 0] = np.nan
    return d


def bad_pct(disp: np.ndarray, gt: np.ndarray, region: np.ndarray, threshold_px: float) -> float:
    """Per cent of ``region`` pixels with ``|disp - gt| > threshold`` or ``disp`` invalid (NaN)."""
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(disp) | (np.abs(disp - gt) > threshold_px)
    return float(100.0 * bad[region].mean())


def _read(path: Path, flags: int) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise OSError(f"cannot read {path}")
    return img


@pytest.fixture(scope="module")
def cones() -> dict[str, np.ndarray]:
    d = shared_path("middlebury-cones")
    gt = _read(d / "Cones_LEFT_GT.tif", cv2.IMREAD_UNCHANGED).astype(np.float32)
    return {"left": _read(d / "Cones_LEFT.tif", cv2.IMREAD_GRAYSCALE),
            "right": _read(d / "Cones_RIGHT.tif", cv2.IMREAD_GRAYSCALE),
            "gt": gt,
            "known": gt > 0,
            "visible": _read(d / "Occlusion_LEFT.png", cv2.IMREAD_GRAYSCALE) > 0}


@pytest.fixture(scope="module")
def motorcycle() -> dict[str, np.ndarray]:
    skimage = pytest.importorskip("skimage", reason="scikit-image (a dev dependency) ships Middlebury Motorcycle")
    d = Path(skimage.__file__).parent / "data"
    names = ("motorcycle_left.png", "motorcycle_right.png", "motorcycle_disp.npz")
    if not all((d / n).exists() for n in names):
        pytest.skip(f"this scikit-image wheel does not ship {', '.join(names)} in {d}")
    with np.load(d / "motorcycle_disp.npz") as z:
        gt = z["arr_0"].astype(np.float32)
    return {"left": _read(d / names[0], cv2.IMREAD_GRAYSCALE), "right": _read(d / names[1], cv2.IMREAD_GRAYSCALE),
            "gt": gt, "known": np.isfinite(gt)}


def test_cones_bad1_nonoccluded_within_raw_sgbm_figure(cones: dict[str, np.ndarray]) -> None:
    gt, known, visible = cones["gt"], cones["known"], cones["visible"]
    d_max = float(np.ceil(gt[known].max()))
    ours = match_rectified(cones["left"], cones["right"], 0.0, d_max, SgmConfig())
    raw = raw_sgbm(cones["left"], cones["right"], d_max)
    region = known & visible
    ours_pct, raw_pct = bad_pct(ours, gt, region, 1.0), bad_pct(raw, gt, region, 1.0)
    print(f"Cones bad>1 non-occluded: skyrig {ours_pct:.2f} %, raw StereoSGBM {raw_pct:.2f} %")
    assert ours_pct <= CONES_BOUND_PCT, f"skyrig {ours_pct:.2f} % > {CONES_BOUND_PCT} %"
    assert ours_pct <= raw_pct, f"skyrig {ours_pct:.2f} % worse than raw StereoSGBM {raw_pct:.2f} %"
    # all known pixels (occluded included, no fill): only the comparison with raw SGBM holds
    ours_all, raw_all = bad_pct(ours, gt, known, 1.0), bad_pct(raw, gt, known, 1.0)
    print(f"Cones bad>1 all known: skyrig {ours_all:.2f} %, raw StereoSGBM {raw_all:.2f} %")
    assert ours_all <= raw_all, f"skyrig {ours_all:.2f} % worse than raw StereoSGBM {raw_all:.2f} % (all known)"


def test_cones_bad1_all_known_filled_within_raw_sgbm_figure(cones: dict[str, np.ndarray]) -> None:
    """Dense disparities (occlusions filled with the background): all known pixels, occluded ones included, within
    raw StereoSGBM's 12.75 % and better than raw StereoSGBM on the same pixels."""
    gt, known, visible = cones["gt"], cones["known"], cones["visible"]
    d_max = float(np.ceil(gt[known].max()))
    ours = match_rectified(cones["left"], cones["right"], 0.0, d_max, FILLED)
    raw = raw_sgbm(cones["left"], cones["right"], d_max)
    ours_all, raw_all = bad_pct(ours, gt, known, 1.0), bad_pct(raw, gt, known, 1.0)
    print(f"Cones bad>1 all known, filled: skyrig {ours_all:.2f} %, raw StereoSGBM {raw_all:.2f} %")
    assert ours_all <= CONES_BOUND_PCT, f"skyrig {ours_all:.2f} % > {CONES_BOUND_PCT} % (all known, filled)"
    assert ours_all <= raw_all
    # the fill only adds pixels: where the unfilled path matched, the filled one is no worse than the bound there
    assert bad_pct(ours, gt, known & visible, 1.0) <= CONES_BOUND_PCT
    # only pixels without image content stay unmatched (the first columns carry no right-image match at all)
    assert np.isfinite(ours[known]).mean() > 0.99


def test_cones_disparity_scale_and_sign(cones: dict[str, np.ndarray]) -> None:
    """The path returns d = x_left - x_right in pixels: the median error on well-matched pixels is ~0."""
    gt, known = cones["gt"], cones["known"]
    ours = match_rectified(cones["left"], cones["right"], 0.0, float(np.ceil(gt[known].max())))
    ok = known & np.isfinite(ours)
    assert ok.mean() > 0.7
    assert abs(float(np.median(ours[ok] - gt[ok]))) < 0.25


def test_motorcycle_bad2_within_bound_and_raw_sgbm(motorcycle: dict[str, np.ndarray]) -> None:
    gt, known = motorcycle["gt"], motorcycle["known"]
    d_max = float(np.ceil(gt[known].max()))
    ours = match_rectified(motorcycle["left"], motorcycle["right"], 0.0, d_max, SgmConfig())
    raw = raw_sgbm(motorcycle["left"], motorcycle["right"], d_max)
    ours_pct, raw_pct = bad_pct(ours, gt, known, 2.0), bad_pct(raw, gt, known, 2.0)
    print(f"Motorcycle bad>2 all known: skyrig {ours_pct:.2f} %, raw StereoSGBM {raw_pct:.2f} %")
    assert ours_pct <= MOTORCYCLE_BOUND_PCT, f"skyrig {ours_pct:.2f} % > {MOTORCYCLE_BOUND_PCT} %"
    assert ours_pct <= raw_pct, f"skyrig {ours_pct:.2f} % worse than raw StereoSGBM {raw_pct:.2f} %"
    filled = bad_pct(match_rectified(motorcycle["left"], motorcycle["right"], 0.0, d_max, FILLED), gt, known, 2.0)
    print(f"Motorcycle bad>2 all known, filled: skyrig {filled:.2f} %")
    assert filled <= min(ours_pct, MOTORCYCLE_BOUND_PCT)


def test_window_offset_shifts_disparities(cones: dict[str, np.ndarray]) -> None:
    """A window starting at a negative disparity (the right image shifted by -16 px) gives the same disparities: the shift is undone."""
    gt, known = cones["gt"], cones["known"]
    d_max = float(np.ceil(gt[known].max()))
    a = match_rectified(cones["left"], cones["right"], 0.0, d_max)
    b = match_rectified(cones["left"], cones["right"], -16.0, d_max)
    both = np.isfinite(a) & np.isfinite(b) & known
    assert both.mean() > 0.6
    assert float(np.mean(np.abs(a[both] - b[both]) <= 1.0)) > 0.97
