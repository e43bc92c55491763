"""Issue 33: Pix4D GCP and marks (GCP/MTP) files written from skyrig's ground points and image measurements, read
back, and checked against Pix4D's documented layout (support.pix4d.com: "Tie points (GCPs, CPs) import format"
and "How to import and export Tie Points marks": ``label,coordinate1,coordinate2,z[,acc_h,acc_v]`` with the
coordinates in the order of the CRS's axes; ``image,label,x,y[,accuracy]`` from the image's top-left corner)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.errors import InputFormatError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.io.pix4d_gcp import read_pix4d_gcps, read_pix4d_marks, write_pix4d_gcps, write_pix4d_marks


@pytest.mark.parametrize("crs, xyz", [
    ("EPSG:25832", [[549779.9947, 5803063.9487, 81.1025], [549831.2710, 5803061.1953, 80.8495]]),
    ("EPSG:4326", [[6.63212, 46.51877, 402.118], [6.63305, 46.51791, 401.964]]),
    ("EPSG:2056", [[2538512.337, 1152611.904, 402.118], [2538583.615, 1152516.271, 401.964]]),
])
def test_gcp_round_trip(tmp_path, crs, xyz):
    pts = GroundPoints(np.array(["GCP0", "GCP1"]), np.array(xyz), WorldFrame.map(crs))
    f = write_pix4d_gcps(tmp_path / "gcp.txt", pts, (0.02, 0.05))
    back, acc = read_pix4d_gcps(f)  # the CRS from the side-car
    assert list(back.name) == ["GCP0", "GCP1"] and back.frame.crs == pts.frame.crs
    np.testing.assert_allclose(back.xyz, pts.xyz, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(acc, [[0.02, 0.05]] * 2)
    rows = [ln.split(",") for ln in f.read_text().splitlines()]
    assert all(len(r) == 6 for r in rows)
    first = float(rows[0][1])  # Pix4D's coordinate1: the CRS's first axis (latitude for EPSG:4326)
    assert first == (xyz[0][1] if crs == "EPSG:4326" else xyz[0][0])


def test_gcp_axis_order_agrees_with_proj(tmp_path):
    """The same points in a geographic file (coordinate1 = latitude, EPSG:4326's first axis) and in a Swiss LV95
    file (coordinate1 = easting), as Pix4D's page lays them out, read to positions PROJ maps onto each other."""
    from pyproj import Transformer

    lat = [46.51877, 46.51791]
    lon = [6.63212, 6.63305]
    z = [402.118, 401.964]
    to_lv95 = Transformer.from_crs("EPSG:4326", "EPSG:2056")  # authority axis order: lat, lon -> E, N
    e, n = to_lv95.transform(lat, lon)
    (tmp_path / "geo.txt").write_text("".join(f"GCP{k},{lat[k]},{lon[k]},{z[k]}\n" for k in range(2)))
    (tmp_path / "lv95.txt").write_text("".join(f"GCP{k},{e[k]:.4f},{n[k]:.4f},{z[k]}\n" for k in range(2)))
    geo, acc = read_pix4d_gcps(tmp_path / "geo.txt", WorldFrame.map("EPSG:4326"))
    lv, _ = read_pix4d_gcps(tmp_path / "lv95.txt", WorldFrame.map("EPSG:2056"))
    assert acc is None
    np.testing.assert_allclose(geo.xyz[:, 0], lon)
    np.testing.assert_allclose(geo.xyz[:, 1], lat)
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:2056", always_xy=True).transform(geo.xyz[:, 0], geo.xyz[:, 1])
    np.testing.assert_allclose(np.c_[x, y], lv.xyz[:, :2], atol=1e-3)


def test_marks_round_trip_and_documented_origin(tmp_path):
    """skyrig's pixel origin is the centre of the top-left pixel, Pix4D's the image's corner: 0.5 apart."""
    m = ImageMeasurements(np.array(["GCP0", "GCP1", "GCP0"]), np.array(["IMG_1.JPG", "IMG_1.JPG", "IMG_2.JPG"]),
                          np.array([[0.0, 0.0], [2000.25, 1499.75], [12.5, 3999.0]]))
    f = write_pix4d_marks(tmp_path / "marks.txt", m, [0.5, 0.8, 1.0])
    rows = [ln.split(",") for ln in f.read_text().splitlines()]
    assert rows[0] == ["IMG_1.JPG", "GCP0", "0.5", "0.5", "0.5"]  # the top-left pixel's centre, from the corner
    back, acc = read_pix4d_marks(f)
    np.testing.assert_array_equal(back.pixel, m.pixel)
    assert list(back.point) == list(m.point) and list(back.image) == list(m.image)
    np.testing.assert_array_equal(acc, [0.5, 0.8, 1.0])
    # as Pix4D writes it with its "Image Directory" option: the folder is dropped, the four-column form read
    (tmp_path / "p4d.txt").write_text("C:\\flight\\IMG_1.JPG,GCP0,2000.5,1500.25\nD:/x/IMG_2.JPG,GCP0,3.0,4.0\n")
    got, acc = read_pix4d_marks(tmp_path / "p4d.txt")
    assert acc is None and list(got.image) == ["IMG_1.JPG", "IMG_2.JPG"]
    np.testing.assert_array_equal(got.pixel, [[2000.0, 1499.75], [2.5, 3.5]])


@pytest.mark.parametrize("name, text, where", [
    ("gcp", "G1,1.0,2.0\n", "line 1, field 'z'"),
    ("gcp", "G1,549779.9,5803063.9,81.1,0.02\n", "line 1, field 'accuracy_vertical'"),
    ("gcp", "G1,549779.9,5803063.9,81.1\nG1,549780.9,5803063.9,81.1\n", "line 2, field 'label'"),
    ("gcp", "G1,549779.9,5803063.9,81.1\nG2,549780.9,north,81.1\n", "line 2, field 'coordinate2'"),
    ("gcp", "G1,5803063.9,549779.9,81.1\n", "line 1, field 'coordinate1'"),  # northing first: swapped
    ("marks", "a.jpg,G1,10.0\n", "line 1, field 'y'"),
    ("marks", "a.jpg,G1,10.0,5.0\na.jpg,G1,11.0,5.0\n", "line 2, field 'label'"),
    ("marks", "a.jpg,G1,-10.0,5.0\n", "line 1, field 'x'"),
    ("marks", "a.jpg,G1,10.0,5.0,0\n", "line 1, field 'accuracy'"),
])
def test_bad_files_are_refused_naming_line_and_field(tmp_path, name, text, where):
    f = tmp_path / f"{name}.txt"
    f.write_text(text)
    with pytest.raises(InputFormatError, match=where):
        if name == "gcp":
            read_pix4d_gcps(f, WorldFrame.map("EPSG:25832"))
        else:
            read_pix4d_marks(f)


def test_export_gcp_command_from_a_skyrig_project(tmp_path):
    """``skyrig export-gcp pix4d`` on the demo's check points (skyrig CSV with side-car) and their projections
    into the images (skyrig world-to-image): the files read back equal the inputs."""
    from skyrig.cli import main
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.pipeline.demo import CRS, build_demo_project

    p = build_demo_project(tmp_path / "demo")
    r = CliRunner().invoke(main, ["georef", "--trajectory", str(p.trajectory), "--events", str(p.events),
                                  "--rig", str(p.rig), "--crs", CRS, "-o", str(p.eo)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["world-to-image", "--eo", str(p.eo), "--camera", str(p.rig), "--points",
                                  str(p.check_points), "-o", str(p.image_points)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "pix4d"
    r = CliRunner().invoke(main, ["export-gcp", "pix4d", "--points", str(p.check_points), "--measurements",
                                  str(p.image_points), "--accuracy", "0.01,0.03", "-o", str(out)])
    assert r.exit_code == 0, r.output
    pts, meas = read_points_csv(p.check_points), read_measurements_csv(p.image_points)
    got, acc = read_pix4d_gcps(out / "gcp.txt")
    assert list(got.name) == list(pts.name) and got.frame.crs == pts.frame.crs
    np.testing.assert_array_equal(got.xyz, pts.xyz)
    np.testing.assert_array_equal(acc, [[0.01, 0.03]] * len(pts.name))
    marks, macc = read_pix4d_marks(out / "marks.txt")
    np.testing.assert_allclose(marks.pixel, meas.pixel, atol=1e-12, rtol=0)
    assert list(marks.image) == list(meas.image) and np.all(macc == 0.5)
