"""EO file formats: skyrig EO CSV, ODM gcp_list.txt / geo.txt, IGN OPK writer; bad input names file, line, field."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.rotations import matrix_from_opk, matrix_from_rpy, ENU_FROM_NED, NADIR_BODY_FROM_CAMERA
from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
from skyrig.io.ign import read_ign_opk, write_ign_opk
from skyrig.io.odm import read_gcp_list, read_geo_txt, rotation_from_gimbal_ypr, write_geo_txt, gimbal_ypr_from_eo


def _eo(frame=WorldFrame.map("EPSG:25832")):
    rng = np.random.default_rng(3)
    n = 5
    c = np.column_stack([rng.uniform(5e5, 5.1e5, n), rng.uniform(5.7e6, 5.71e6, n), rng.uniform(800, 1200, n)])
    r = matrix_from_opk(rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-180, 180, n), unit="deg")
    return ExteriorOrientations([f"i{k}.tif" for k in range(n)], ["nadir"] * n, c, r, frame,
                                time_s=np.arange(n) * 1.5, head=["nadir"] * n, exposure=np.arange(n))


@pytest.mark.parametrize("convention", ["opk", "pok", "ypr"])
@pytest.mark.parametrize("unit", ["deg", "rad", "gon"])
def test_eo_csv_round_trip(tmp_path, convention, unit):
    eo = _eo()
    write_eo_csv(eo, tmp_path / "eo.csv", unit=unit, convention=convention)
    back = read_eo_csv(tmp_path / "eo.csv")
    np.testing.assert_allclose(back.centre, eo.centre, atol=1e-4)
    np.testing.assert_allclose(back.rotation, eo.rotation, atol=1e-9)
    assert list(back.image) == list(eo.image) and back.frame == eo.frame
    np.testing.assert_array_equal(back.exposure, eo.exposure)


def test_ypr_known_answer_with_meridian_convergence(tmp_path):
    # A camera in the standard nadir mount on a level platform heading true north (yaw 0).  In UTM 32N at
    # 12 E (3 deg east of the central meridian) grid north lies clockwise of true north by the convergence c,
    # so the image x axis (forward = true north) has grid azimuth -c: kappa = 90 deg + c.
    lon, lat = 12.0, 50.0
    x, y = pyproj.Transformer.from_crs(4326, 25832, always_xy=True).transform(lon, lat)
    t = pyproj.Transformer.from_crs(4326, 25832, always_xy=True)
    (x1, y1), (x2, y2) = t.transform(lon, lat - 1e-6), t.transform(lon, lat + 1e-6)
    conv = np.degrees(np.arctan2(x2 - x1, y2 - y1))  # grid azimuth of true north = -c (central difference)
    (tmp_path / "e.csv").write_text(
        "# skyrig-eo 1\n# crs: EPSG:25832\n# heights: ellipsoidal\n# angles: deg\n# convention: ypr\n"
        f"image,camera,x,y,z,yaw,pitch,roll\na,cam,{x},{y},1000,0,0,0\n"
    )
    eo = read_eo_csv(tmp_path / "e.csv")
    from skyrig.geometry.rotations import opk_from_matrix

    o, p, k = opk_from_matrix(eo.rotation, unit="deg")
    assert abs(o[0]) < 1e-3 and abs(p[0]) < 1e-3  # the local vertical tilts by ~1e-5 deg within metres
    assert abs(k[0] - (90.0 - conv)) < 1e-6, (k[0], 90.0 - conv)


BAD = [
    ("# skyrig-eo 2\n", 1, None, "version"),
    ("# skyrig-eo 1\n# crs: EPSG:999999\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\n", 2, "crs", "unknown"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: degs\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\n", 3, "angles", "unit"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi\na,c,1,2,3,0,0\n", 5, "kappa", "missing"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\na,c,1,2,nan,0,0,0\n", 6, "z", "finite"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: rad\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\na,c,1,2,3,0,0,0.1\nb,c,1,2,3,0,0,90\n", 7, "kappa", "turn"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa,colour\na,c,1,2,3,0,0,0,red\n", 5, "colour", "unknown column"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# heights: orthometric\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\n", None, "geoid", "geoid"),
    ("# skyrig-eo 1\n# crs: EPSG:25832\n# angles: deg\n# convention: opk\nimage,camera,x,y,z,omega,phi,kappa\na,c,1,2,3,0,0,0\na,c,1,2,3,0,0,0\n", 7, "image", "duplicate"),
]


@pytest.mark.parametrize("text, line, field, words", BAD)
def test_eo_csv_bad_input_names_file_line_field(tmp_path, text, line, field, words):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputFormatError) as err:
        read_eo_csv(p)
    e = err.value
    assert e.path == str(p) and str(p) in str(e)
    if line is not None:
        assert e.line == line
    if field is not None:
        assert e.field == field
    assert words.lower() in str(e).lower()


def test_writer_is_atomic(tmp_path):
    p = tmp_path / "eo.csv"
    p.write_text("precious")
    bad = _eo()
    object.__setattr__(bad, "camera", None)  # make the writer fail half-way
    with pytest.raises(Exception):
        write_eo_csv(bad, p)
    assert p.read_text() == "precious"
    assert [f.name for f in tmp_path.iterdir()] == ["eo.csv"]


def test_ign_opk_round_trip(tmp_path):
    eo = _eo(WorldFrame.map("EPSG:2154"))
    write_ign_opk(tmp_path / "a.OPK", eo)
    back = read_ign_opk(tmp_path / "a.OPK", WorldFrame.map("EPSG:2154"))
    np.testing.assert_allclose(back.centre, eo.centre, atol=1e-3)
    np.testing.assert_allclose(back.rotation, eo.rotation, atol=1e-11)


def test_odm_gcp_list_reads_the_berlin_sample():
    from conftest import shared_path

    p = shared_path("opensfm", "berlin", "gcp_list.txt_from_commit_c7d5152_parent")
    pts, mes = read_gcp_list(p)
    assert pts.frame.crs == "EPSG:4326" and len(mes) >= 4
    assert np.allclose(pts.xyz[0], [13.4007407457, 52.519134104, 12.0792090446])
    assert mes.image[0] == "02.jpg" and np.allclose(mes.pixel[0], [2639.18148357, 938.06742366])


def test_geo_txt_round_trip_and_dji_nadir(tmp_path):
    eo = _eo(WorldFrame.map("EPSG:4326"))
    c = eo.centre.copy()
    c[:, 0], c[:, 1] = 13.4 + (c[:, 0] - 5e5) * 1e-5, 52.5 + (c[:, 1] - 5.7e6) * 1e-5
    eo = ExteriorOrientations(eo.image, eo.camera, c, eo.rotation, eo.frame)
    write_geo_txt(tmp_path / "geo.txt", eo)
    g = read_geo_txt(tmp_path / "geo.txt")
    np.testing.assert_allclose(g.xyz, eo.centre, atol=1e-9)
    np.testing.assert_allclose(rotation_from_gimbal_ypr(g.frame, g.xyz, g.ypr_deg), eo.rotation, atol=1e-7)
    # independent: a DJI gimbal pitched -90 deg with yaw 0 looks down with the image top to true north, so the
    # ENU-from-camera rotation is the identity (image x east, y north, z up)
    r = rotation_from_gimbal_ypr(WorldFrame.local(52.5, 13.4, 0.0), np.zeros((1, 3)), np.array([[0.0, -90.0, 0.0]]))
    np.testing.assert_allclose(r[0], np.eye(3), atol=1e-12)
