"""MicMac Ori folders and AutoCal calibrations (issue 33).

Independent answer: MicMac's projection in the eConvApero_DistM2C convention, as MicMac's documentation gives it
and a peer reader (a Qt/Eigen depth-map tool reading Orientation-*.xml and AutoCal) implements it, written out
here by hand: ``Pc = R^T (Pg - C)``, ``U = PP + F (x/z, y/z)``, ``d = U - CDist``,
``observed = CDist + (1 + R3 rho² + R5 rho⁴ + R7 rho⁶) d``.  The half-pixel origin is skyrig's assumption (module
docstring), applied here explicitly.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyrig.errors import InputFormatError, OptionError
from skyrig.io.micmac import read_micmac_calibration, read_micmac_ori, write_micmac_calibration, write_micmac_ori

W, H = 6000, 4000
PP, F_PX, CDIST = (3010.25, 1987.5), 4512.75, (3021.5, 1979.25)
R3, R5, R7 = 2.1e-9, -3.4e-17, 1.5e-25


def _autocal():
    return f"""<?xml version="1.0" ?>
<ExportAPERO>
     <CalibrationInternConique>
          <KnownConv>eConvApero_DistM2C</KnownConv>
          <PP>{PP[0]} {PP[1]}</PP>
          <F>{F_PX}</F>
          <SzIm>{W} {H}</SzIm>
          <CalibDistortion>
               <ModRad>
                    <CDist>{CDIST[0]} {CDIST[1]}</CDist>
                    <CoeffDist>{R3}</CoeffDist>
                    <CoeffDist>{R5}</CoeffDist>
                    <CoeffDist>{R7}</CoeffDist>
                    <CoeffDistInv>-2.1e-9</CoeffDistInv>
               </ModRad>
          </CalibDistortion>
     </CalibrationInternConique>
</ExportAPERO>
"""


ROTS = [Rotation.from_euler("xyz", [180 + 3 * k, 2 - k, 40 * k], degrees=True).as_matrix() for k in range(3)]
CENTRES = [np.array([1000.0 + 150 * k, 2000.0 - 20 * k, 850.0 + k]) for k in range(3)]


def _orientation(k):
    rows = "".join(f"<L{i + 1}>{' '.join(repr(float(v)) for v in ROTS[k][i])}</L{i + 1}>" for i in range(3))
    return f"""<?xml version="1.0" ?>
<ExportAPERO>
     <OrientationConique>
          <OrIntImaM2C><I00>0 0</I00><V10>1 0</V10><V01>0 1</V01></OrIntImaM2C>
          <TypeProj>eProjStenope</TypeProj>
          <ZoneUtileInPixel>true</ZoneUtileInPixel>
          <FileInterne>Ori-Test/AutoCal_Foc-35000_Cam-X.xml</FileInterne>
          <RelativeNameFI>true</RelativeNameFI>
          <Externe>
               <AltiSol>100</AltiSol>
               <Profondeur>750</Profondeur>
               <Time>0</Time>
               <KnownConv>eConvApero_DistM2C</KnownConv>
               <Centre>{' '.join(repr(float(v)) for v in CENTRES[k])}</Centre>
               <IncCentre>1 1 1</IncCentre>
               <ParamRotation><CodageMatr>{rows}</CodageMatr></ParamRotation>
          </Externe>
          <ConvOri><KnownConv>eConvApero_DistM2C</KnownConv></ConvOri>
     </OrientationConique>
</ExportAPERO>
"""


def _by_hand(k, Pg):
    Pc = (Pg - CENTRES[k]) @ ROTS[k]  # R^T (Pg - C)
    U = np.array(PP) + F_PX * Pc[:, :2] / Pc[:, 2:3]
    d = U - CDIST
    rho2 = np.sum(d * d, axis=1, keepdims=True)
    return np.array(CDIST) + (1 + R3 * rho2 + R5 * rho2**2 + R7 * rho2**3) * d


@pytest.fixture
def ori(tmp_path):
    d = tmp_path / "Ori-Test"
    d.mkdir()
    (d / "AutoCal_Foc-35000_Cam-X.xml").write_text(_autocal())
    for k in range(3):
        (d / f"Orientation-IMG_{k}.JPG.xml").write_text(_orientation(k))
    return d


def test_projection_as_micmac(ori):
    o = read_micmac_ori(ori)
    assert list(o.image_name) == ["IMG_0.JPG", "IMG_1.JPG", "IMG_2.JPG"]
    cam = o.cameras["AutoCal_Foc-35000_Cam-X.xml"]
    rng = np.random.default_rng(2)
    for k in range(3):
        # ground points in front of camera k (z forward in MicMac's camera frame)
        Pc = np.column_stack([rng.uniform(-0.6, 0.6, (500, 2)), np.ones(500)]) * rng.uniform(300, 900, (500, 1))
        Pg = Pc @ ROTS[k].T + CENTRES[k]
        got = cam.world_to_pixel(o.world_from_camera[k], Pg)
        np.testing.assert_allclose(got + 0.5, _by_hand(k, Pg), rtol=0, atol=1e-6)


def test_round_trip(ori, tmp_path):
    o = read_micmac_ori(ori)
    out = tmp_path / "Ori-Back"
    write_micmac_ori(out, o)
    back = read_micmac_ori(out)
    np.testing.assert_array_equal(back.image_name, o.image_name)
    np.testing.assert_allclose(back.world_from_camera.rotation, o.world_from_camera.rotation, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.world_from_camera.translation, o.world_from_camera.translation, rtol=1e-15)
    (c1,), (c2,) = o.cameras.values(), back.cameras.values()
    np.testing.assert_allclose(c2.intrinsics, c1.intrinsics, rtol=1e-12, atol=1e-15)
    cal = read_micmac_calibration(ori / "AutoCal_Foc-35000_Cam-X.xml")
    write_micmac_calibration(tmp_path / "c.xml", cal)
    assert np.allclose(read_micmac_calibration(tmp_path / "c.xml").intrinsics, cal.intrinsics, rtol=1e-12, atol=0)


def test_other_models_exact_refused_or_fitted(tmp_path):
    from skyrig.camera.convert import compare_cameras
    from skyrig.camera.frame import FrameCamera
    from skyrig.camera.opencv import OpenCVDistortion

    radial = FrameCamera.from_pixels("cv", 4000, 3000, 3000.0, 2010.0, 1490.0,
                                     distortion=OpenCVDistortion(k1=-0.05, k2=0.01))
    write_micmac_calibration(tmp_path / "r.xml", radial)  # OpenCV radial only: MicMac's ModRad exactly
    assert compare_cameras(radial, read_micmac_calibration(tmp_path / "r.xml")).max_px < 1e-9
    cam = radial.with_(distortion=OpenCVDistortion(k1=-0.05, k2=0.01, p1=5e-5))
    with pytest.raises(OptionError, match="opencv"):
        write_micmac_calibration(tmp_path / "c.xml", cam)
    write_micmac_calibration(tmp_path / "c.xml", cam, fit_cameras=True)
    assert compare_cameras(cam, read_micmac_calibration(tmp_path / "c.xml")).rms_px <= 0.01


@pytest.mark.parametrize("which, old, new, needle", [
    ("ori", "<Externe>\n               <AltiSol>", "<Externe><KnownConv>eConvOriLib</KnownConv><AltiSol>",
     "field 'KnownConv'"),
    ("ori", "Ori-Test/AutoCal_Foc-35000_Cam-X.xml", "Ori-Test/missing.xml", "field 'FileInterne'"),
    ("ori", "<V10>1 0</V10>", "<V10>1.01 0</V10>", "field 'OrIntImaM2C'"),
    ("cal", "<F>4512.75</F>", "<F>x</F>", "line 6, field 'F'"),
    ("cal", "<ModRad>", "<ModUnif>", "not well-formed"),
])
def test_bad_files_named(ori, which, old, new, needle):
    f = ori / ("Orientation-IMG_1.JPG.xml" if which == "ori" else "AutoCal_Foc-35000_Cam-X.xml")
    text = f.read_text()
    assert old in text
    f.write_text(text.replace(old, new, 1))
    with pytest.raises(InputFormatError, match=needle):
        read_micmac_ori(ori)


def test_micmac_to_opencv_exact_or_fitted(ori, tmp_path):
    """MicMac's radial model about the principal point is OpenCV's k1 k2 k3 exactly (k_i = R_(2i+1) F^(2i)); about
    its own centre (11 px away here) it has no exact OpenCV twin and the fit's residual is reported (this lens: 76 px
    of distortion at the corners, OpenCV k1 k2 p1 p2 k3 with focal and principal point: 0.017 px RMS, 0.11 px
    max)."""
    from skyrig.camera.convert import compare_cameras, convert_camera, exact_conversion

    cam = read_micmac_calibration(ori / "AutoCal_Foc-35000_Cam-X.xml")
    assert exact_conversion(cam, "opencv") is None
    rep = convert_camera(cam, "opencv")[1]
    assert 0.005 < rep.rms_px < 0.03 and rep.max_px < 0.2
    (tmp_path / "c.xml").write_text(_autocal().replace(f"<CDist>{CDIST[0]} {CDIST[1]}", f"<CDist>{PP[0]} {PP[1]}"))
    centred = read_micmac_calibration(tmp_path / "c.xml")
    cv = exact_conversion(centred, "opencv")
    assert cv.distortion.k1 == pytest.approx(R3 * F_PX**2, rel=1e-12)
    assert compare_cameras(centred, cv).max_px < 1e-9
    assert compare_cameras(centred, exact_conversion(cv, "forward")).max_px < 1e-9
