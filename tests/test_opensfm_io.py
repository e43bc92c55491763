"""OpenSfM reconstructions (issue 33): read, written, and checked against OpenSfM's own sample data.

Independent answers: OpenSfM's documented projection (``doc/source/geometry.rst``: angle-axis world-to-camera
rotation, normalised coordinates with the larger side 1 and the pixel matrix ``H``, the ``DistoBrown``
formulas of ``camera_distortions_functions.h``) written out here with scipy's rotation, and the measured
feature positions of the Berlin sample (``tracks_example.csv``, BSD-2, mapillary/OpenSfM ``data/berlin``)
that OpenSfM reconstructed ``reconstruction_example.json`` from.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import shared_path
from skyrig.camera.brown import BrownDistortion
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.io.opensfm import (block_from_opensfm, camera_from_opensfm, opensfm_camera, read_opensfm,
                               read_opensfm_cameras, read_opensfm_tracks, write_opensfm, write_opensfm_cameras,
                               write_opensfm_tracks)



def _berlin_dir():
    return shared_path("opensfm", "berlin")  # skips when ../shared/data is absent


def _opensfm_project(cam: dict, shot: dict, X: np.ndarray) -> np.ndarray:
    """OpenSfM's documented projection to pixels (origin: centre of the top-left pixel)."""
    R = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    Xc = X @ R.T + np.asarray(shot["translation"])
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    g = lambda k: cam.get(k, 0.0)  # noqa: E731
    radial = 1 + g("k1") * r2 + g("k2") * r2**2 + g("k3") * r2**3
    xd = x * radial + 2 * g("p1") * x * y + g("p2") * (r2 + 2 * x * x)
    yd = y * radial + 2 * g("p2") * x * y + g("p1") * (r2 + 2 * y * y)
    fx, fy = (cam["focal"], cam["focal"]) if "focal" in cam else (cam["focal_x"], cam["focal_y"])
    u, v = fx * xd + g("c_x"), fy * yd + g("c_y")
    w, h = cam["width"], cam["height"]
    s = max(w, h)
    return np.column_stack([u * s + (w - 1) / 2, v * s + (h - 1) / 2])


@pytest.fixture(scope="module")
def berlin():
    BERLIN = _berlin_dir()
    raw = json.loads((BERLIN / "reconstruction_example.json").read_text())[0]
    rec = read_opensfm_tracks(BERLIN / "tracks_example.csv", read_opensfm(BERLIN / "reconstruction_example.json")[0])
    return raw, rec


def test_berlin_projection_matches_opensfm_formula_and_its_measurements(berlin):
    raw, rec = berlin
    assert len(rec.image_name) == 3 and len(rec.point_id) == 1430 and len(rec.obs_image) > 3000
    assert rec.frame is not None and rec.frame.origin == pytest.approx((52.51896296296295, 13.400376851851851, 0.0))
    for i, name in enumerate(rec.image_name):
        shot = raw["shots"][name]
        cam = rec.cameras[rec.image_camera_id[i]]
        sel = rec.obs_image == i
        X = rec.point_xyz[rec.obs_point[sel]]
        got = cam.world_to_pixel(rec.world_from_camera[i], X)
        np.testing.assert_allclose(got, _opensfm_project(raw["cameras"][shot["camera"]], shot, X), rtol=0, atol=1e-6)
        # OpenSfM's own measurements (features at 1024 px, the images 3264 px wide): medians 0.68-1.23 px
        e = np.linalg.norm(got - rec.obs_pixel[sel], axis=1)
        assert np.median(e) < 1.5, name
        # a half-pixel or axis mistake would show: the y-flip of the measurements is far off
        flipped = rec.obs_pixel[sel] * [1, -1] + [0, cam.height - 1]
        assert np.median(np.linalg.norm(got - flipped, axis=1)) > 50


def test_berlin_round_trip(berlin, tmp_path):
    _, rec = berlin
    write_opensfm(tmp_path / "reconstruction.json", rec)
    write_opensfm_tracks(tmp_path / "tracks.csv", rec)
    back = read_opensfm_tracks(tmp_path / "tracks.csv", read_opensfm(tmp_path / "reconstruction.json")[0])
    np.testing.assert_array_equal(back.image_name, rec.image_name)
    np.testing.assert_allclose(back.world_from_camera.rotation, rec.world_from_camera.rotation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.world_from_camera.translation, rec.world_from_camera.translation, rtol=1e-12)
    np.testing.assert_allclose(back.point_xyz, rec.point_xyz, rtol=1e-15)
    assert back.cameras == rec.cameras and back.frame == rec.frame
    assert back.shot_extra[0]["gps_position"] == rec.shot_extra[0]["gps_position"]
    np.testing.assert_array_equal(back.obs_point, rec.obs_point)
    np.testing.assert_allclose(back.obs_pixel, rec.obs_pixel, rtol=0, atol=1e-9)
    # the written file is OpenSfM's: same camera dictionary, perspective model kept
    raw = json.loads((tmp_path / "reconstruction.json").read_text())[0]
    orig = json.loads((_berlin_dir() / "reconstruction_example.json").read_text())[0]
    for k, c in orig["cameras"].items():
        assert set(raw["cameras"][k]) == set(c)
        for q, v in c.items():
            assert raw["cameras"][k][q] == (v if isinstance(v, str) else pytest.approx(v, rel=1e-15))
    b = block_from_opensfm(back)
    b.validate()
    assert b.n_observations > 3000 and str(b.frame) == "local ENU at lat 52.518962963 lon 13.400376852 h 0.000"


BROWN = {"projection_type": "brown", "width": 4000, "height": 3000, "focal_x": 0.71, "focal_y": 0.71,
         "c_x": 0.0123, "c_y": -0.0081, "k1": -0.12, "k2": 0.05, "p1": 0.0011, "p2": -0.0007, "k3": 0.01}


@pytest.mark.parametrize("cam", [
    BROWN,
    {"projection_type": "brown", "width": 1000, "height": 1500, "focal_x": 0.9, "focal_y": 0.93, "c_x": 0.01,
     "c_y": 0.02, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0},
    {"projection_type": "radial", "width": 640, "height": 480, "focal_x": 1.1, "focal_y": 1.1, "c_x": -0.01,
     "c_y": 0.0, "k1": 0.2, "k2": -0.1},
    {"projection_type": "simple_radial", "width": 640, "height": 480, "focal_x": 1.1, "focal_y": 1.1, "c_x": 0.0,
     "c_y": 0.01, "k1": -0.05},
])
def test_camera_models_project_as_opensfm(cam, tmp_path):
    rng = np.random.default_rng(1)
    c = camera_from_opensfm("c", cam)
    shot = {"rotation": rng.normal(0, 0.5, 3).tolist(), "translation": rng.normal(0, 2, 3).tolist()}
    R = Rotation.from_rotvec(shot["rotation"]).as_matrix()
    Xc = np.column_stack([rng.uniform(-0.4, 0.4, (1000, 2)), np.ones(1000)]) * rng.uniform(5, 20, (1000, 1))
    X = (Xc - shot["translation"]) @ R  # world points in front of the camera
    from skyrig.geometry.pose import Pose

    pose = Pose(R.T @ np.diag([1.0, -1, -1]), -R.T @ shot["translation"], "world", "camera")
    np.testing.assert_allclose(c.world_to_pixel(pose, X), _opensfm_project(cam, shot, X), rtol=0, atol=1e-6)
    # the camera file round trip: the same dictionary back (models kept)
    write_opensfm_cameras(tmp_path / "camera_models_overrides.json", {"c": c})
    back = read_opensfm_cameras(tmp_path / "camera_models_overrides.json")["c"]
    assert back == c
    out = opensfm_camera(c)
    for k, v in cam.items():
        if k in out and k != "projection_type":  # radial and simple_radial are written as brown
            assert out[k] == (pytest.approx(v, rel=1e-12, abs=1e-15) if not isinstance(v, str) else v)


def test_brown_australis_camera_refused_or_fitted(tmp_path, berlin):
    _, rec = berlin
    k = rec.image_camera_id[0]
    cam = rec.cameras[k]
    rec2 = type(rec)(**{f: getattr(rec, f) for f in rec.__dataclass_fields__})
    rec2.cameras = {k: cam.with_(distortion=BrownDistortion(k1=0.003, p1=1e-5))}
    rec2.fit_reports = {}
    with pytest.raises(OptionError, match="brown"):
        write_opensfm(tmp_path / "r.json", rec2)
    write_opensfm(tmp_path / "r.json", rec2, fit_cameras=True)
    assert rec2.fit_reports[k].rms_px <= 0.01
    assert isinstance(read_opensfm(tmp_path / "r.json")[0].cameras[k].distortion, OpenCVDistortion)


@pytest.mark.parametrize("edit, needle", [
    (lambda d: d[0]["cameras"].__setitem__("x", {"projection_type": "fisheye", "width": 10, "height": 10,
                                                 "focal": 1, "k1": 0, "k2": 0}), "projection_type"),
    (lambda d: d[0]["shots"]["01.jpg"].__setitem__("rotation", [90.0, 0.0, 10.0]), "degrees"),
    (lambda d: d[0]["shots"]["01.jpg"].__setitem__("camera", "nope"), "unknown camera"),
    (lambda d: d[0]["shots"]["01.jpg"].__setitem__("translation", [1, "a", 2]), "translation"),
    (lambda d: d[0]["cameras"][next(iter(d[0]["cameras"]))].__setitem__("width", 0), "width"),
])
def test_bad_reconstructions_are_named(tmp_path, edit, needle):
    d = json.loads((_berlin_dir() / "reconstruction_example.json").read_text())
    edit(d)
    (tmp_path / "r.json").write_text(json.dumps(d))
    with pytest.raises(InputFormatError, match=needle) as e:
        read_opensfm(tmp_path / "r.json")
    assert "r.json" in str(e.value)


def test_bad_tracks_version(tmp_path, berlin):
    _, rec = berlin
    (tmp_path / "t.csv").write_text("OPENSFM_TRACKS_VERSION_v9\n")
    with pytest.raises(InputFormatError, match="t.csv, line 1, field 'version'"):
        read_opensfm_tracks(tmp_path / "t.csv", rec)
    (tmp_path / "t.csv").write_text("OPENSFM_TRACKS_VERSION_v2\n01.jpg\t1\t2\t0.1\t0.2\n")
    with pytest.raises(InputFormatError, match="line 2"):
        read_opensfm_tracks(tmp_path / "t.csv", rec)
