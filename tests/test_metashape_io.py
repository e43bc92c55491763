"""Agisoft Metashape calibration and cameras XML (issue 33).

Independent answers: the projection formula of the Metashape Professional manual, Appendix C (frame cameras:
``u = w/2 + cx + x'(f + B1) + y' B2``, ``v = h/2 + cy + y' f`` from the image corner, P1 on ``r² + 2x²``), and the
camera / component / chunk transforms as the manual and Metashape's Python API define them (camera to internal
to geocentric), written out here by hand with numpy; scipy builds the rotations.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyrig.camera.convert import compare_cameras, convert_camera, exact_conversion
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.geodesy.frame import WorldFrame
from skyrig.io.metashape import (read_metashape_calibration, read_metashape_cameras, write_metashape_calibration,
                                 write_metashape_cameras)

W, H = 5472, 3648
CAL = dict(f=3685.31, cx=-12.75, cy=9.125, b1=2.5, b2=-0.75, k1=-0.0123, k2=0.0151, k3=-0.0042, k4=0.0011,
           p1=-4.2e-4, p2=2.7e-4)


def _cal_xml(cal=CAL, extra=""):
    body = "".join(f"  <{k}>{v!r}</{k}>\n" for k, v in cal.items())
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<calibration>\n  <projection>frame</projection>\n'
            f"  <width>{W}</width>\n  <height>{H}</height>\n{body}{extra}  <date>2024-05-01T10:00:00Z</date>\n"
            "</calibration>\n")


def _manual_project(cal, Xc):
    """Appendix C, frame cameras: camera-frame points (x right, y down, z forward) -> Metashape pixels."""
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    rad = 1 + cal["k1"] * r2 + cal["k2"] * r2**2 + cal["k3"] * r2**3 + cal["k4"] * r2**4
    xd = x * rad + cal["p1"] * (r2 + 2 * x * x) + 2 * cal["p2"] * x * y
    yd = y * rad + cal["p2"] * (r2 + 2 * y * y) + 2 * cal["p1"] * x * y
    u = W * 0.5 + cal["cx"] + xd * cal["f"] + xd * cal["b1"] + yd * cal["b2"]
    v = H * 0.5 + cal["cy"] + yd * cal["f"]
    return np.column_stack([u, v])


def _points_in_view(n=1000, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.7, 0.7, n), rng.uniform(-0.48, 0.48, n), np.ones(n)]) * rng.uniform(
        5, 50, (n, 1))


def test_calibration_projects_as_the_manual(tmp_path):
    (tmp_path / "cal.xml").write_text(_cal_xml())
    cam = read_metashape_calibration(tmp_path / "cal.xml")
    Xc = _points_in_view()
    # skyrig's camera frame is Metashape's with y and z flipped; pixels are Metashape's minus 0.5
    got = cam.project_pixels(Xc * [1, -1, -1])
    np.testing.assert_allclose(got + 0.5, _manual_project(CAL, Xc), rtol=0, atol=1e-6)
    # round trip: the same numbers back, projections to 1e-6 px
    write_metashape_calibration(tmp_path / "back.xml", cam)
    back = read_metashape_calibration(tmp_path / "back.xml", name=cam.name)
    np.testing.assert_allclose(back.intrinsics, cam.intrinsics, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(back.project_pixels(Xc * [1, -1, -1]), got, rtol=0, atol=1e-6)


def test_agisoft_opencv_exact_and_fitted(tmp_path):
    cal = dict(CAL, k4=0.0, b1=0.0, b2=0.0)
    cam = read_metashape_calibration(_write(tmp_path, cal))
    cv = exact_conversion(cam, "opencv")
    assert isinstance(cv.distortion, OpenCVDistortion)
    # OpenCV's p1 is Metashape's P2 and p2 its P1
    assert (cv.distortion.p1, cv.distortion.p2) == (cal["p2"], cal["p1"])
    assert compare_cameras(cam, cv).max_px < 1e-9
    back = exact_conversion(cv, "agisoft")
    assert back.distortion == cam.distortion
    # K4 has no OpenCV term: fitted, 0.0030 px RMS (0.033 px max) over the frame
    k4 = read_metashape_calibration(_write(tmp_path, dict(CAL, b1=0.0, b2=0.0), "k4.xml"))
    assert exact_conversion(k4, "opencv") is None
    assert convert_camera(k4, "opencv")[1].rms_px <= 0.01
    # B1 (fx != fy) and B2 (skew) have none either, and OpenCV's single focal length cannot absorb them
    # (0.63 px RMS); skyrig's Brown model has affinity and shear: 0.005 px RMS
    full = read_metashape_calibration(_write(tmp_path, CAL, "full.xml"))
    assert convert_camera(full, "opencv")[1].rms_px > 0.3
    assert convert_camera(full, "brown")[1].rms_px <= 0.01


def _write(d: pathlib.Path, cal=CAL, name="c.xml"):
    (d / name).write_text(_cal_xml(cal))
    return d / name


# a cameras export as Metashape writes it (structure of version 1.5.0), with a chunk transform to geocentric
# coordinates (rotation, translation, scale) and a component transform
CHUNK_R = Rotation.from_euler("zyx", [30, -10, 5], degrees=True).as_matrix()
CHUNK_T, CHUNK_S = np.array([4198000.5, 812000.25, 4706000.75]), 2.5
COMP_R = Rotation.from_euler("xyz", [2, 3, -4], degrees=True).as_matrix()
COMP_T, COMP_S = np.array([1.5, -2.0, 0.5]), 0.8
CAMS = [(Rotation.from_euler("xyz", [178, 2, 30 * k], degrees=True).as_matrix(), np.array([10.0 * k, 5.0, 40.0]))
        for k in range(3)]


def _sim(R, t, s):
    return f"<rotation>{_nums(R)}</rotation><translation>{_nums(t)}</translation><scale>{s!r}</scale>"


def _nums(a):
    return " ".join(repr(float(v)) for v in np.ravel(a))


def _cameras_xml():
    cal = "".join(f"<{k}>{v!r}</{k}>" for k, v in CAL.items())
    cams = ""
    for k, (R, t) in enumerate(CAMS):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t
        cams += (f'<camera id="{k}" sensor_id="0" component_id="0" label="IMG_{k:04d}">'
                 f"<transform>{_nums(M)}</transform>"
                 '<reference x="13.4" y="52.5" z="120" enabled="true"/></camera>\n')
    cams += '<camera id="3" sensor_id="0" component_id="0" label="IMG_not_aligned"/>\n'
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<document version="1.5.0">
  <chunk label="Chunk 1" enabled="true">
    <sensors next_id="1">
      <sensor id="0" label="FC6310 (8.8mm)" type="frame">
        <resolution width="{W}" height="{H}"/>
        <property name="pixel_width" value="0.0024107142857142856"/>
        <property name="pixel_height" value="0.0024107142857142856"/>
        <property name="focal_length" value="8.8"/>
        <calibration type="frame" class="adjusted"><resolution width="{W}" height="{H}"/>{cal}</calibration>
      </sensor>
    </sensors>
    <components next_id="1"><component id="0" label="Component 1"><transform>{_sim(COMP_R, COMP_T, COMP_S)}</transform></component></components>
    <cameras next_id="4" next_group_id="0">
{cams}    </cameras>
    <markers next_id="1"><marker id="0" label="GCP1"><reference x="13.401" y="52.519" z="35.5" enabled="true"/></marker></markers>
    <frames next_id="1"><frame id="0"><markers><marker marker_id="0">
      <location camera_id="0" pinned="true" x="2736.25" y="1824.75"/>
      <location camera_id="2" pinned="true" x="1000.5" y="900.5"/>
      <location camera_id="3" pinned="true" x="10" y="10"/>
    </marker></markers></frame></frames>
    <reference>GEOGCS["WGS 84",DATUM["World Geodetic System 1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]]</reference>
    <transform>{_sim(CHUNK_R, CHUNK_T, CHUNK_S)}</transform>
  </chunk>
</document>
"""


def test_cameras_export_projects_as_metashape(tmp_path):
    (tmp_path / "cameras.xml").write_text(_cameras_xml())
    ch = read_metashape_cameras(tmp_path / "cameras.xml")
    assert list(ch.image_name) == ["IMG_0000", "IMG_0001", "IMG_0002"] and ch.frame == WorldFrame.ecef()
    cam = ch.cameras["0"]
    assert cam.name == "FC6310 (8.8mm)" and cam.pixel_size_mm == pytest.approx(0.0024107142857142856)
    for k, (Rc, tc) in enumerate(CAMS):
        # by hand: points in front of camera k, through camera -> internal -> component -> chunk (geocentric)
        Xc = _points_in_view(300, seed=k)
        Xi = Xc @ Rc.T + tc
        Xk = COMP_S * Xi @ COMP_R.T + COMP_T
        Xw = CHUNK_S * Xk @ CHUNK_R.T + CHUNK_T
        got = cam.world_to_pixel(ch.world_from_camera[k], Xw)
        np.testing.assert_allclose(got + 0.5, _manual_project(CAL, Xc), rtol=0, atol=1e-6)
    np.testing.assert_allclose(ch.obs_pixel, [[2735.75, 1824.25], [1000.0, 900.0]])
    assert list(ch.obs_image) == [0, 2] and ch.marker_name[0] == "GCP1"
    np.testing.assert_allclose(ch.marker_xyz[0], [13.401, 52.519, 35.5])
    # orientations in a map CRS, through ECEF (rigorous)
    eo = ch.orientations(WorldFrame.map("EPSG:4326"))
    assert len(eo) == 3 and np.isfinite(eo.centre).all()

    # round trip through skyrig's writer: the same poses, cameras and measurements
    write_metashape_cameras(tmp_path / "back.xml", ch)
    back = read_metashape_cameras(tmp_path / "back.xml")
    np.testing.assert_allclose(back.world_from_camera.rotation, ch.world_from_camera.rotation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.world_from_camera.translation, ch.world_from_camera.translation, rtol=1e-15)
    assert back.cameras["0"] == ch.cameras["0"] and back.frame == ch.frame and back.crs_wkt == ch.crs_wkt
    np.testing.assert_allclose(back.obs_pixel, ch.obs_pixel, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.obs_marker, ch.obs_marker)


def test_writers_refuse_or_fit_other_models(tmp_path):
    from skyrig.camera.brown import BrownDistortion
    from skyrig.camera.frame import FrameCamera

    cam = FrameCamera("brown", 4000, 3000, 0.004, 16.0, 0.01, -0.02, BrownDistortion(k1=-2e-4, k2=1e-7, p1=1e-6))
    with pytest.raises(OptionError, match="brown"):
        write_metashape_calibration(tmp_path / "c.xml", cam)
    rep = write_metashape_calibration(tmp_path / "c.xml", cam, fit_cameras=True)
    assert rep.rms_px <= 0.01
    back = read_metashape_calibration(tmp_path / "c.xml", name="brown")
    # pixels do not depend on the pixel size (the calibration file has none): the residual is the fit's
    assert compare_cameras(cam, back).rms_px == pytest.approx(rep.rms_px, rel=1e-3, abs=1e-7)


@pytest.mark.parametrize("old, new, needle", [
    ("<projection>frame</projection>", "<projection>fisheye</projection>", "line 3, field 'projection'"),
    (f"<f>{CAL['f']!r}</f>", "<f>abc</f>", "line 6, field 'f'"),
    (f"<f>{CAL['f']!r}</f>", "<f>-5</f>", "field 'f'"),
    ("<date>", "<p3>0.001</p3><date>", "field 'p3'"),
    ("</calibration>", "", "not well-formed"),
])
def test_bad_calibration_named(tmp_path, old, new, needle):
    text = _cal_xml()
    assert old in text
    (tmp_path / "c.xml").write_text(text.replace(old, new))
    with pytest.raises(InputFormatError, match=needle) as e:
        read_metashape_calibration(tmp_path / "c.xml")
    assert "c.xml" in str(e.value)


@pytest.mark.parametrize("old, new, needle", [
    ('<document version="1.5.0">', '<document version="9.0.0">', "version"),
    ('label="IMG_0001"', 'label="IMG_0001" sensor_id="7"', "."),  # duplicate attribute: malformed
    ('<camera id="1" sensor_id="0"', '<camera id="1" sensor_id="5"', "field 'sensor_id'"),
    ('type="frame" class="adjusted"><resolution width="5472"', 'type="frame" class="adjusted"><resolution width="4000"',
     "field 'resolution'"),
])
def test_bad_cameras_export_named(tmp_path, old, new, needle):
    text = _cameras_xml()
    assert old in text
    (tmp_path / "c.xml").write_text(text.replace(old, new, 1))
    with pytest.raises(InputFormatError, match=needle) as e:
        read_metashape_cameras(tmp_path / "c.xml")
    assert "c.xml" in str(e.value) and "line" in str(e.value)


def test_reference_csv(tmp_path):
    from skyrig.io.metashape import read_metashape_reference, write_metashape_reference

    # as Metashape's reference export writes it (comment header, then label, coordinates, accuracies)
    text = ("# Markers (3)\n#Label,X/Longitude,Y/Latitude,Z/Altitude,Accuracy_X/Y_(m),Accuracy_Z_(m)\n"
            "GCP1,13.4012,52.5191,35.12,0.02,0.03\nGCP2,13.4021,52.5187,36.40,0.02,0.05\nGCP3,13.4030,52.5199,34.9,,\n")
    (tmp_path / "ref.csv").write_text(text)
    frame = WorldFrame.map("EPSG:4979")
    ref = read_metashape_reference(tmp_path / "ref.csv", frame, columns="nxyzXZ")
    assert list(ref.points.name) == ["GCP1", "GCP2", "GCP3"]
    np.testing.assert_allclose(ref.points.xyz[1], [13.4021, 52.5187, 36.40])
    np.testing.assert_allclose(ref.accuracy[:2], [[0.02, 0.02, 0.03], [0.02, 0.02, 0.05]])
    assert np.isnan(ref.accuracy[2]).all()
    write_metashape_reference(tmp_path / "back.csv", ref)
    back = read_metashape_reference(tmp_path / "back.csv", frame, columns="nxyzXYZ")
    np.testing.assert_array_equal(back.points.xyz, ref.points.xyz)
    np.testing.assert_array_equal(np.nan_to_num(back.accuracy, nan=-1), np.nan_to_num(ref.accuracy, nan=-1))
    with pytest.raises(InputFormatError, match=r"ref.csv, line 4: expected 6 columns"):
        (tmp_path / "ref.csv").write_text(text.replace("52.5187", "52,5187"))
        read_metashape_reference(tmp_path / "ref.csv", frame, columns="nxyzXZ")
    with pytest.raises(OptionError, match="columns"):
        read_metashape_reference(tmp_path / "back.csv", frame, columns="nxy")


def psx_from_cameras_xml(xml_text: str, psx: Path, group: bool = False) -> Path:
    """A Metashape project ``psx`` (``NAME.psx`` + ``NAME.files``) holding the chunk of a cameras export, built to
    the documented layout: the .psx an XML ``<document path="{projectname}.files/project.zip">``; project.zip's
    doc.xml listing ``<chunks><chunk id="0" path="0/chunk.zip"/>``; chunk.zip's doc.xml the ``<chunk>`` with its
    frames as ``<frame id path="0/frame.zip"/>``; frame.zip's doc.xml the ``<frame>`` with the marker
    measurements.  ``group``: the cameras inside a camera group (a folder in Metashape's workspace)."""
    import xml.etree.ElementTree as ET
    import zipfile

    doc = ET.fromstring(xml_text)
    ch = doc.find("chunk")
    files = psx.with_name(psx.stem + ".files")
    (files / "0" / "0").mkdir(parents=True)
    frames = ch.find("frames")
    for k, fr in enumerate(list(frames) if frames is not None else []):
        frame_doc = ET.Element("frame", {"version": doc.get("version", "1.5.0")})
        frame_doc.extend(list(fr))
        with zipfile.ZipFile(files / "0" / f"{k}" / "frame.zip", "w") as z:
            z.writestr("doc.xml", ET.tostring(frame_doc, encoding="unicode"))
        frames.remove(fr)
        ET.SubElement(frames, "frame", {"id": str(k), "path": f"{k}/frame.zip"})
    if group:
        cams = ch.find("cameras")
        g = ET.SubElement(cams, "group", {"id": "0", "label": "100MEDIA", "type": "folder"})
        for c in [c for c in cams if c.tag == "camera"]:
            cams.remove(c)
            g.append(c)
    ch.set("version", doc.get("version", "1.5.0"))
    with zipfile.ZipFile(files / "0" / "chunk.zip", "w") as z:
        z.writestr("doc.xml", ET.tostring(ch, encoding="unicode"))
    with zipfile.ZipFile(files / "project.zip", "w") as z:
        z.writestr("doc.xml", '<document version="1.5.0"><chunks next_id="1" active_id="0">'
                              '<chunk id="0" path="0/chunk.zip"/></chunks></document>')
    psx.write_text('<?xml version="1.0" encoding="UTF-8"?>\n'
                   '<document version="1.5.0" path="{projectname}.files/project.zip"/>\n')
    return psx


@pytest.mark.parametrize("group", [False, True])
def test_psx_project_reads_as_its_cameras_export(tmp_path, group):
    """The .psx holding the chunk of the export above reads to the same sensors, poses and markers (whose
    projections the export test checks by hand against Metashape's documented model)."""
    from skyrig.io.metashape import read_metashape_project

    (tmp_path / "cameras.xml").write_text(_cameras_xml())
    ref = read_metashape_cameras(tmp_path / "cameras.xml")
    ch = read_metashape_project(psx_from_cameras_xml(_cameras_xml(), tmp_path / "proj.psx", group))
    assert list(ch.image_name) == list(ref.image_name) and ch.frame == ref.frame and ch.crs_wkt == ref.crs_wkt
    assert ch.cameras == ref.cameras
    np.testing.assert_array_equal(ch.world_from_camera.rotation, ref.world_from_camera.rotation)
    np.testing.assert_array_equal(ch.world_from_camera.translation, ref.world_from_camera.translation)
    np.testing.assert_array_equal(ch.obs_pixel, ref.obs_pixel)
    np.testing.assert_array_equal(ch.obs_image, ref.obs_image)
    np.testing.assert_array_equal(ch.marker_xyz, ref.marker_xyz)


def test_psx_project_damaged_is_named(tmp_path):
    from skyrig.io.metashape import read_metashape_project

    psx = psx_from_cameras_xml(_cameras_xml(), tmp_path / "proj.psx")
    (tmp_path / "proj.files" / "0" / "0" / "frame.zip").write_bytes(b"PK\x03\x04 cut")
    with pytest.raises(InputFormatError, match=r"frame\.zip.*not a readable zip archive"):
        read_metashape_project(psx)
    (tmp_path / "proj.files" / "0" / "chunk.zip").unlink()
    with pytest.raises(InputFormatError, match=r"chunk\.zip.*file not found"):
        read_metashape_project(psx)
    psx.write_text('<document version="1.5.0" path="../elsewhere/project.zip"/>')
    with pytest.raises(InputFormatError, match=r"proj\.psx, line 1, field 'path'.*leads out of"):
        read_metashape_project(psx)


def test_convert_reads_a_psx_project(tmp_path):
    """``skyrig convert NAME.psx`` (format told by the name): the chunk's orientations as the export's."""
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.io.eo_csv import read_eo_csv

    (tmp_path / "cameras.xml").write_text(_cameras_xml())
    ref = read_metashape_cameras(tmp_path / "cameras.xml").orientations(WorldFrame.ecef())
    psx = psx_from_cameras_xml(_cameras_xml(), tmp_path / "proj.psx")
    r = CliRunner().invoke(main, ["convert", str(psx), "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    eo = read_eo_csv(tmp_path / "eo.csv")
    assert list(eo.image) == list(ref.image)
    np.testing.assert_allclose(eo.centre, ref.centre, rtol=0, atol=1e-4)
    np.testing.assert_allclose(eo.rotation, ref.rotation, rtol=0, atol=1e-9)


def test_import_metashape_psx_writes_the_block(tmp_path):
    """``skyrig import metashape-psx NAME.psx -o block.json``: the same block as from the cameras export."""
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.io.block_file import read_block

    (tmp_path / "cameras.xml").write_text(_cameras_xml())
    psx = psx_from_cameras_xml(_cameras_xml(), tmp_path / "proj.psx")
    for fmt, src in (("metashape-xml", tmp_path / "cameras.xml"), ("metashape-psx", psx)):
        r = CliRunner().invoke(main, ["import", fmt, str(src), "-o", str(tmp_path / f"{fmt}.json")])
        assert r.exit_code == 0, r.output
    a = read_block(tmp_path / "metashape-xml.json").block
    b = read_block(tmp_path / "metashape-psx.json").block
    assert list(a.image_name) == list(b.image_name) and a.n_observations == b.n_observations
    np.testing.assert_array_equal(a.station_centre, b.station_centre)
