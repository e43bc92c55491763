"""16-bit camera images (12 or 14 bits in 16-bit TIFF / PNG, as aerial cameras deliver them) scaled to 8 bit by
one pair of levels for the block (skyrig.pipeline.dense.ImageFiles), judged against numpy's percentiles of the
full images decoded by OpenCV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skyrig.errors import InputFormatError
from skyrig.pipeline.dense import LEVEL_PERCENTILES, ImageFiles, sixteen_bit_levels


def _texture(seed: int, h: int = 300, w: int = 400) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 2.0)
    return np.clip(128 + 45 * g / g.std(), 0, 255).astype(np.uint8)


def _write12(path: Path, v8: np.ndarray, gain: float = 16.0, offset: float = 40.0) -> np.ndarray:
    """A 12-bit image (0..4095 in uint16) linear in the 8-bit one, three channels; returns what was written (RGB)."""
    import cv2

    rgb = np.stack([v8, np.roll(v8, 7, axis=1), np.roll(v8, 3, axis=0)], axis=2).astype(np.float64)
    v = np.clip(np.round(gain * rgb + offset), 0, 4095).astype(np.uint16)
    assert cv2.imwrite(str(path), np.ascontiguousarray(v[..., ::-1]))
    return v


def test_levels_are_the_blocks_percentiles_and_the_scale_is_linear(tmp_path: Path) -> None:
    import cv2

    written = []
    paths = []
    for k in range(3):
        p = tmp_path / f"img{k}.tif"
        written.append(_write12(p, _texture(k), offset=40.0 + 200 * k))  # the images differ in brightness
        paths.append(str(p))
    jpg = tmp_path / "eight.jpg"  # an 8-bit image in the same block keeps its values
    v8 = _texture(9)
    cv2.imwrite(str(jpg), np.repeat(v8[..., None], 3, axis=2), [cv2.IMWRITE_JPEG_QUALITY, 100])
    loader = ImageFiles(paths + [str(jpg)], [(400, 300)] * 4)
    # independent: numpy's percentiles of every decoded pixel of the 16-bit images (the loader samples a grid)
    full = np.concatenate([cv2.imread(p, cv2.IMREAD_UNCHANGED).reshape(-1) for p in paths])
    lo, hi = np.percentile(full, LEVEL_PERCENTILES)
    assert loader.levels is not None
    assert abs(loader.levels[0] - lo) < 0.01 * (hi - lo) and abs(loader.levels[1] - hi) < 0.01 * (hi - lo)
    for k in range(3):
        out = loader(k)
        assert out.dtype == np.uint8 and out.shape == (300, 400, 3)
        want = np.clip((written[k].astype(np.float64) - loader.levels[0]) * 255 / (loader.levels[1] - loader.levels[0]),
                       0, 255)
        assert np.abs(out.astype(np.float64) - want).max() <= 0.5 + 1e-6
        assert len(np.unique(out)) > 200  # OpenCV's own conversion (a shift by 8 bits) leaves at most 17 levels
    # one scale for the block: a brighter image stays brighter by the written offset difference
    d = loader(2).astype(float).mean() - loader(0).astype(float).mean()
    assert d == pytest.approx(400 * 255 / (loader.levels[1] - loader.levels[0]), rel=0.05)
    assert np.array_equal(loader(3)[..., 0], cv2.imread(str(jpg), cv2.IMREAD_GRAYSCALE))
    # a subset keeps the block's levels (an orthomosaic of one head is not rescaled on its own)
    assert loader.subset([2, 0]).levels == loader.levels
    assert np.array_equal(loader.subset([2, 0])(0), loader(2))


def test_eight_bit_blocks_have_no_levels_and_bad_sample_types_are_refused(tmp_path: Path) -> None:
    import cv2

    p = tmp_path / "a.png"
    cv2.imwrite(str(p), _texture(1))
    assert sixteen_bit_levels([str(p)]) is None
    assert ImageFiles([str(p)], [(400, 300)]).levels is None
    f = tmp_path / "float.tif"
    cv2.imwrite(str(f), _texture(2).astype(np.float32))
    with pytest.raises(InputFormatError, match="float32") as e:
        ImageFiles([str(p), str(f)], [(400, 300)] * 2)
    assert "float.tif" in str(e.value)
    flat = tmp_path / "flat.tif"
    cv2.imwrite(str(flat), np.full((300, 400), 1000, np.uint16))
    with pytest.raises(InputFormatError, match="without contrast"):
        ImageFiles([str(flat)], [(400, 300)])
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not an image")
    with pytest.raises(InputFormatError) as e:
        ImageFiles([str(bad)], [(400, 300)])
    assert "bad.tif" in str(e.value)


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
@pytest.mark.parametrize("kind", ["rgb8", "rgb16", "grey16", "rgb8_deflate", "rgba8"])
def test_windows_hold_the_whole_images_values(tmp_path: Path, kind: str) -> None:
    """ImageFiles.windowed_image (large TIFFs read window by window by the dense chain, through GDAL) returns the
    pixels the whole-image read (OpenCV) has there, bit for bit, in RGB and in grey."""
    import cv2
    import rasterio

    v = _texture(5)
    paths = []
    for k in range(2):
        p = tmp_path / f"w{k}.tif"
        if kind == "rgb16":
            _write12(p, np.roll(v, 11 * k, axis=1))
        elif kind == "grey16":
            assert cv2.imwrite(str(p), (16 * np.roll(v, 11 * k, axis=1).astype(np.uint16) + 40))
        else:
            rgb = np.stack([v, np.roll(v, 5, axis=1), 255 - v], axis=2)
            bands = np.moveaxis(rgb, -1, 0)
            if kind == "rgba8":
                bands = np.concatenate([bands, np.full((1,) + v.shape, 255, np.uint8)])
            with rasterio.open(p, "w", driver="GTiff", width=v.shape[1], height=v.shape[0], count=len(bands),
                               dtype="uint8", compress="deflate" if kind == "rgb8_deflate" else None,
                               photometric="RGB") as ds:
                ds.write(bands)
        paths.append(str(p))
    whole = ImageFiles(paths, [(400, 300)] * 2)
    win = ImageFiles(paths, [(400, 300)] * 2, window_min_pixels=0)
    assert win.levels == whole.levels and ImageFiles.WINDOW_MIN_PIXELS > 400 * 300
    assert whole.windowed_image(0) is None  # below the size where windows pay
    for i in range(2):
        full = whole(i)
        g = cv2.cvtColor(full, cv2.COLOR_RGB2GRAY)
        wr, wg = win.windowed_image(i), win.windowed_image(i, grey=True)
        assert (wr.width, wr.height, wr.channels, wg.channels) == (400, 300, 3, 1)
        for c0, r0, c1, r1 in ((0, 0, 400, 300), (17, 33, 250, 120), (399, 299, 400, 300)):
            assert np.array_equal(wr.read(c0, r0, c1, r1), full[r0:r1, c0:c1])
            assert np.array_equal(wg.read(c0, r0, c1, r1), g[r0:r1, c0:c1])
