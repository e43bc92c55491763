"""Camera priors from image metadata (skyrig.io.camera_prior, issue 28): each source's value computed here by hand
from the tags (f_px = f_mm / sensor_width_mm x long side; DJI DewarpData fields as DJI documents them), the stated
sigmas, and every contradiction or gap said in words naming the file and the field."""

from __future__ import annotations

import json
from importlib import resources

import pytest

from skyrig.errors import InputFormatError, SkyrigError
from skyrig.io.camera_prior import SIGMA_35MM, SIGMA_NONE, SIGMA_SENSOR, SIGMA_VENDOR, camera_prior, sensor_width_mm
from skyrig.io.image_read import ImageMetadata


def meta(**kw) -> ImageMetadata:
    d = dict(name="IMG.JPG", path="/flight/IMG.JPG", width=4000, height=2250)
    d.update(kw)
    return ImageMetadata(**d)


def test_database_is_the_vendored_opensfm_file_with_its_licence():
    root = resources.files("skyrig").joinpath("data")
    table = json.loads(root.joinpath("sensor_data.json").read_text())
    assert len(table) > 3000 and table["DJI FC300S"] == 6.16
    assert "BSD" in root.joinpath("sensor_data.README.md").read_text()
    assert "Redistribution and use" in root.joinpath("sensor_data.LICENSE").read_text()


def test_focal_from_exif_focal_and_database_sensor_width():
    p = camera_prior(meta(make="DJI", model="FC300S", focal_mm=3.61, focal35_mm=20.0))
    assert p.focal_px == pytest.approx(3.61 / 6.16 * 4000)  # 2,344.2 px
    assert p.focal_sigma_px == pytest.approx(SIGMA_SENSOR * p.focal_px)
    assert p.pixel_size_mm == pytest.approx(6.16 / 4000)
    assert p.pp_px == pytest.approx((1999.5, 1124.5))
    assert "OpenSfM sensor database" in p.source and not p.warnings  # 35-mm value 2,222 px: within 12 %


def test_model_that_repeats_the_make_is_found():
    assert sensor_width_mm("Canon", "Canon EOS 5D Mark II") == 36.0
    assert sensor_width_mm("", "") is None


def test_contradictory_35mm_value_is_warned_naming_file_and_field():
    p = camera_prior(meta(make="DJI", model="FC300S", focal_mm=3.61, focal35_mm=28.0))  # 3,111 px vs 2,344 px
    assert p.focal_px == pytest.approx(3.61 / 6.16 * 4000)
    (w,) = p.warnings
    assert "/flight/IMG.JPG" in w and "FocalLengthIn35mmFilm" in w and "contradictory" in w


def test_camera_missing_from_the_database_uses_the_35mm_value_and_says_so():
    p = camera_prior(meta(make="Nobody", model="X-1", focal_mm=4.0, focal35_mm=24.0))
    assert p.focal_px == pytest.approx(24.0 / 36.0 * 4000)
    assert p.focal_sigma_px == pytest.approx(SIGMA_35MM * p.focal_px)
    (w,) = p.warnings
    assert "nobody x-1" in w and "not in the sensor database" in w and "/flight/IMG.JPG" in w


def test_focal_plane_resolution_gives_the_pixel_pitch():
    # 4000 px over 6.4 mm: FocalPlaneXResolution 625 px/mm (unit 4 = mm)
    p = camera_prior(meta(make="Nobody", model="X-2", focal_mm=4.0, focal_plane_width_mm=6.4))
    assert p.focal_px == pytest.approx(4.0 / 6.4 * 4000)
    assert "FocalPlaneXResolution" in p.source


def test_no_metadata_at_all_is_a_weak_prior_with_a_warning():
    p = camera_prior(meta(width=3072, height=2048))
    assert p.focal_px == pytest.approx(1.2 * 3072) and p.focal_sigma_px == pytest.approx(SIGMA_NONE * p.focal_px)
    assert p.warnings and "no usable focal length" in p.warnings[0]


def test_dji_dewarp_data_is_a_factory_calibration():
    dw = "2020-09-08;3669.620000000000,3669.620000000000,8.450000000000,-16.120000000000,-0.273340000000," \
         "0.118237000000,0.000140770000,-0.000048700000,-0.038003000000"
    m = meta(make="DJI", model="FC6310", width=5472, height=3648, focal_mm=8.8, xmp={"drone-dji:DewarpData": dw})
    p = camera_prior(m)
    assert p.focal_px == pytest.approx(3669.62)
    assert p.focal_sigma_px == pytest.approx(SIGMA_VENDOR * 3669.62)
    assert p.pp_px == pytest.approx((2735.5 + 8.45, 1823.5 - 16.12))  # offsets from the image centre
    assert p.distortion == pytest.approx({"k1": -0.27334, "k2": 0.118237, "p1": 0.00014077, "p2": -0.0000487,
                                          "k3": -0.038003})
    assert "DewarpData" in p.source
    # EXIF 8.8 mm with the FC6310's 13.2 mm sensor: 3,648 px, 0.6 % from the factory value: no warning
    assert not p.warnings


def test_damaged_dewarp_data_names_the_field():
    m = meta(xmp={"drone-dji:DewarpData": "2020-09-08;3669.6,abc"})
    with pytest.raises(InputFormatError) as e:
        camera_prior(m)
    assert "drone-dji:DewarpData" in str(e.value) and "/flight/IMG.JPG" in str(e.value)


@pytest.mark.parametrize("bad", [0.0, -0.03, float("nan")])
def test_prior_sigma_not_positive_is_refused_naming_the_option(bad):
    with pytest.raises(SkyrigError) as e:
        camera_prior(meta(make="DJI", model="FC300S", focal_mm=3.61), focal_sigma_rel=bad)
    assert "focal_prior_rel" in str(e.value)


def test_uav_config_refuses_a_zero_prior_sigma():
    from skyrig.pipeline.uav import UavConfig

    with pytest.raises(ValueError, match="focal_prior_rel"):
        UavConfig.from_dict({"focal_prior_rel": 0}, "cfg.json")
    assert UavConfig.from_dict({"focal_determinable": 0.4}).determinable_ratio == 0.4  # the deprecated name


def test_given_camera_of_another_size_is_refused(tmp_path):
    import numpy as np

    from skyrig.camera.frame import FrameCamera
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.pipeline.uav import orient_input

    from PIL import Image

    Image.new("RGB", (64, 48)).save(tmp_path / "a.jpg")
    Image.new("RGB", (64, 48)).save(tmp_path / "b.jpg")
    cam = FrameCamera.from_pixels("cam", 640, 480, 500.0, 319.5, 239.5)
    meas = ImageMeasurements(np.array(["p", "p"]), np.array(["a.jpg", "b.jpg"]), np.zeros((2, 2)))
    with pytest.raises(InputFormatError) as e:
        orient_input(tmp_path, meas, cam, sources={"camera": "rig.yaml"})
    assert "rig.yaml" in str(e.value) and "640 x 480" in str(e.value) and "64 x 48" in str(e.value)
