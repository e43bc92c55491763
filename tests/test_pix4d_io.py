"""Pix4D calibrated external / camera parameters (issue 33).

Independent answers: two published pairs of Pix4D outputs of the same image, quoted in public code (kept here as
text): DSC_0157.JPG (7360 x 4912) with its line of ``calibrated_external_camera_parameters.txt`` and its block of
``calibrated_camera_parameters.txt``, and DJI_0954.JPG (4608 x 3456, easyidp's maize test project) with its block
and its row of ``pmatrix.txt`` (Pix4D's own P = K [R | -R t]).
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.errors import InputFormatError
from skyrig.geodesy.frame import WorldFrame
from skyrig.io.pix4d import (read_pix4d_calibrated_cameras, read_pix4d_external, read_pix4d_offset,
                             write_pix4d_calibrated_cameras, write_pix4d_external)

HEADER = """fileName imageWidth imageHeight
camera matrix K [3x3]
radial distortion [3x1]
tangential distortion [2x1]
camera position t [3x1]
camera rotation R [3x3]
camera model m = K [R|-Rt] X
"""
DSC = """
DSC_0157.JPG 7360 4912
7363.51850023951465118444 0 3686.33719996831450771424
0 7363.51850023951465118444 2439.04083412635009153746
0 0 1
-0.09005921067656787182 0.10773972435740564180 -0.01257054987797603419
-0.00029570539858373248 -0.00027422056492206067
114.12600004808672338186 378.81985574952466322429 -2.31159761431545440757
-0.49632901575943477734 0.86794436424468834890 -0.01816834310427051929
0.86649900151927328196 0.49400145706385401034 -0.07170802455019638366
-0.05326338781351704077 -0.05133362440616233424 -0.99726018196053234366
"""
EXTERNAL = "imageName X Y Z Omega Phi Kappa\nDSC_0157.JPG 332081.126000 3488911.819856 4093.688402 -2.946680 3.053212 119.804001\n"
DJI = """
DJI_0954.JPG 4608 3456
3952.81247514184087776812 0 2233.46124792750424603582
0 3952.81247514184087776812 1667.92521335858214115433
0 0 1
0.03833474118270804865 -0.01750917966495743258 0.02049798716391852335
0.00240851666319534747 0.00292562392135245920
21.54872206687879199194 -29.58734160676452162875 30.85702810138878149360
0.78389904231994589345 -0.62058396220897726892 -0.01943803742353054573
-0.62086105345046738169 -0.78318706257080084043 -0.03390541741516269608
0.00581753884797473961 0.03864674463298682638 -0.99923600083815289352
"""
PMAT = np.array([3111.599161, -2366.736021, -2308.589802, -65840.192261, -2444.444098, -3031.331712, -1800.672677,
                 18549.006987, 0.005818, 0.038647, -0.999236, 31.851547]).reshape(3, 4)
FRAME = WorldFrame.map("EPSG:32649")


def test_external_and_camera_parameters_agree(tmp_path):
    (tmp_path / "ccp.txt").write_text(HEADER + DSC)
    (tmp_path / "ext.txt").write_text(EXTERNAL)
    (tmp_path / "offset.xyz").write_text("331967.000 3488533.000 4096.000")
    eo = read_pix4d_external(tmp_path / "ext.txt", FRAME)
    cc = read_pix4d_calibrated_cameras(tmp_path / "ccp.txt", read_pix4d_offset(tmp_path / "offset.xyz"))
    # the two files' rotations agree to the OPK file's 6 decimals (4e-9), the centres to its micrometres
    assert np.abs(cc.world_from_camera.rotation[0] - eo.rotation[0]).max() < 2e-8
    assert np.abs(cc.world_from_camera.translation[0] - eo.centre[0]).max() < 2e-6


def test_camera_parameters_agree_with_the_pmatrix(tmp_path):
    (tmp_path / "ccp.txt").write_text(HEADER + DJI)
    cc = read_pix4d_calibrated_cameras(tmp_path / "ccp.txt")
    cam = cc.cameras[cc.image_camera_id[0]]
    rng = np.random.default_rng(0)
    X = cc.world_from_camera.translation[0] + rng.uniform([-20, -20, -31], [20, 20, -25], (200, 3))
    h = np.c_[X, np.ones(len(X))] @ PMAT.T
    want = h[:, :2] / h[:, 2:]  # Pix4D's own projection (no distortion), Pix4D pixels
    got = cam.with_(distortion=type(cam.distortion)()).world_to_pixel(cc.world_from_camera[0], X)
    np.testing.assert_allclose(got + 0.5, want, rtol=0, atol=0.02)  # P is given to 6 decimals


def test_round_trips(tmp_path):
    (tmp_path / "ccp.txt").write_text(HEADER + DSC + DJI)
    cc = read_pix4d_calibrated_cameras(tmp_path / "ccp.txt", (1.0, 2.0, 3.0))
    assert len(cc.cameras) == 2
    write_pix4d_calibrated_cameras(tmp_path / "back.txt", cc, (1.0, 2.0, 3.0))
    back = read_pix4d_calibrated_cameras(tmp_path / "back.txt", (1.0, 2.0, 3.0))
    assert back.cameras == cc.cameras
    np.testing.assert_allclose(back.world_from_camera.rotation, cc.world_from_camera.rotation, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.world_from_camera.translation, cc.world_from_camera.translation, rtol=1e-15)
    (tmp_path / "ext.txt").write_text(EXTERNAL)
    eo = read_pix4d_external(tmp_path / "ext.txt", FRAME)
    write_pix4d_external(tmp_path / "ext2.txt", eo)
    e2 = read_pix4d_external(tmp_path / "ext2.txt", FRAME)
    np.testing.assert_allclose(e2.rotation, eo.rotation, rtol=0, atol=1e-10)
    np.testing.assert_allclose(e2.centre, eo.centre, rtol=0, atol=1e-6)


@pytest.mark.parametrize("text, needle", [
    (EXTERNAL.replace("-2.946680", "-172.946680").replace("119.804001", "719.8"), "line 2, field 'Omega Phi Kappa'"),
    (EXTERNAL.replace("imageName X", "name X"), "line 1"),
    (EXTERNAL.replace("4093.688402 ", "4093.688402"), "line 2"),
])
def test_bad_external(tmp_path, text, needle):
    (tmp_path / "e.txt").write_text(text)
    with pytest.raises(InputFormatError, match=needle):
        read_pix4d_external(tmp_path / "e.txt", FRAME)


def test_bad_camera_parameters(tmp_path):
    (tmp_path / "c.txt").write_text(HEADER + DSC.replace("0 0 1\n", "0 0\n"))
    with pytest.raises(InputFormatError, match=r"c.txt, line 12, field 'camera matrix K'"):
        read_pix4d_calibrated_cameras(tmp_path / "c.txt")


def test_convert_cli_reads_and_writes_pix4d_opk(tmp_path):
    from click.testing import CliRunner

    from skyrig.cli import main

    src = tmp_path / "p_calibrated_external_camera_parameters.txt"
    src.write_text(EXTERNAL)
    run = CliRunner()
    r = run.invoke(main, ["convert", str(src), "--from-crs", "EPSG:32649", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    r = run.invoke(main, ["convert", str(tmp_path / "eo.csv"), "-o", str(tmp_path / "out.txt"), "--to-format",
                          "pix4d-opk"])
    assert r.exit_code == 0, r.output
    a, b = read_pix4d_external(src, FRAME), read_pix4d_external(tmp_path / "out.txt", FRAME)
    np.testing.assert_allclose(b.rotation, a.rotation, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.centre, a.centre, rtol=0, atol=1e-4)
