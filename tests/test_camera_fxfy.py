"""Cameras with two focal lengths fx != fy (issue 13: "a K with fx != fy cannot be entered").

Independent answer: a two-focal pinhole written here in plain numpy (OpenCV's camera frame: x right, y down, z
forward; col = fx X/Z + cx, row = fy Y/Z + cy; COLMAP's pixel origin half a pixel off), against which the
projected pixels of the camera each reader builds must agree to 1e-9 px.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skyrig.adjust.synthetic import synthetic_block
from skyrig.camera.aspect import camera_from_fx_fy, fx_fy_px
from skyrig.camera.brown import BrownDistortion
from skyrig.errors import InputFormatError
from skyrig.io.block_file import read_block, write_block
from skyrig.io.colmap_text import read_colmap_cameras
from skyrig.io.rig_file import read_rig, write_rig

FX, FY, CX, CY, W, H = 3012.5, 2987.25, 2010.3, 1498.7, 4000, 3000


def _points(n=300, seed=0):
    """Points in skyrig's camera frame (x right, y up, looking along -z), spread over the image."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(20.0, 300.0, n)
    return np.column_stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.45, 0.45, n) * z, -z])


def _pinhole(P, fx, fy, cx, cy):
    """The two-focal pinhole in OpenCV's frame (X_cv = X, Y_cv = -Y, Z_cv = -Z): pixels (col, row)."""
    X, Y, Z = P[:, 0], -P[:, 1], -P[:, 2]
    return np.column_stack([fx * X / Z + cx, fy * Y / Z + cy])


def test_camera_projects_as_the_two_focal_pinhole():
    cam = camera_from_fx_fy("c", W, H, FX, FY, CX, CY, pixel_size_mm=0.0039)
    P = _points()
    np.testing.assert_allclose(cam.project_pixels(P), _pinhole(P, FX, FY, CX, CY), rtol=0, atol=1e-9)
    # and back: the viewing ray of each pinhole pixel goes through its point
    r = cam.rays_from_pixels(_pinhole(P, FX, FY, CX, CY))
    np.testing.assert_allclose(r, P / np.linalg.norm(P, axis=1, keepdims=True), rtol=0, atol=1e-12)
    assert isinstance(cam.distortion, BrownDistortion) and cam.focal_px == pytest.approx(FY, rel=1e-15)
    assert fx_fy_px(cam) == pytest.approx((FX, FY), rel=1e-14)
    square = camera_from_fx_fy("s", W, H, FX, FX, CX, CY)
    assert square.distortion.n_params == 0 and fx_fy_px(square) is None


def test_colmap_pinhole_with_fx_ne_fy(tmp_path):
    p = tmp_path / "cameras.txt"
    p.write_text(f"# Camera list\n1 PINHOLE {W} {H} {FX} {FY} {CX} {CY}\n"
                 f"2 OPENCV {W} {H} {FX} {FY} {CX} {CY} 0 0 0 0\n")
    cams = read_colmap_cameras(p)
    P = _points(seed=1)
    for cid in (1, 2):
        # COLMAP's pixel origin is the corner of the top-left pixel, skyrig's its centre
        np.testing.assert_allclose(cams[cid].project_pixels(P), _pinhole(P, FX, FY, CX, CY) - 0.5, rtol=0, atol=1e-9)


def test_colmap_opencv_with_coefficients_and_fx_ne_fy_is_refused_naming_the_line(tmp_path):
    p = tmp_path / "cameras.txt"
    p.write_text(f"# c\n1 PINHOLE {W} {H} {FX} {FX} {CX} {CY}\n2 OPENCV {W} {H} {FX} {FY} {CX} {CY} -0.1 0.01 0 0\n")
    with pytest.raises(InputFormatError, match="opencv") as e:
        read_colmap_cameras(p)
    assert e.value.path == str(p) and e.value.line == 3 and e.value.field == "fy"


def test_block_file_focal_px_pair_reads_exactly_and_writes_back(tmp_path):
    block, _ = synthetic_block(seed=1, n_strips=2, n_per_strip=4, n_points=60)
    p = tmp_path / "block.json"
    write_block(p, block)
    man = json.loads(p.read_text())
    man["cameras"][0].update(focal_px=[FX, FY], pp_col=CX, pp_row=CY, width=W, height=H)
    man["cameras"][0].pop("distortion", None)
    man.pop("checksums")
    p.write_text(json.dumps(man))
    cam = read_block(p).block.cameras[0]
    P = _points(seed=2)
    np.testing.assert_allclose(cam.project_pixels(P), _pinhole(P, FX, FY, CX, CY), rtol=0, atol=1e-9)
    b2 = read_block(p).block
    write_block(tmp_path / "again.json", b2)
    back = json.loads((tmp_path / "again.json").read_text())["cameras"][0]
    assert back["focal_px"] == pytest.approx([FX, FY], rel=1e-14) and "distortion" not in back
    cam2 = read_block(tmp_path / "again.json").block.cameras[0]
    np.testing.assert_allclose(cam2.project_pixels(P), _pinhole(P, FX, FY, CX, CY), rtol=0, atol=1e-9)


def test_block_file_focal_px_pair_with_opencv_distortion_is_refused(tmp_path):
    block, _ = synthetic_block(seed=1, n_strips=2, n_per_strip=4, n_points=60)
    p = tmp_path / "block.json"
    write_block(p, block)
    man = json.loads(p.read_text())
    man["cameras"][0].update(focal_px=[FX, FY], distortion={"model": "opencv", "k1": -0.1})
    p.write_text(json.dumps(man))
    with pytest.raises(InputFormatError, match="brown") as e:
        read_block(p)
    assert e.value.path == str(p) and e.value.field == "cameras[0].focal_px"


RIG = """\
format: skyrig-rig
version: 1
name: r
heads:
- name: nadir
  camera:
    name: c
    width_px: {w}
    height_px: {h}
    pixel_size_um: 3.9
    focal_mm: {focal}
    ppx_mm: {ppx}
    ppy_mm: {ppy}
{dist}  lever_arm_m: [0.0, 0.0, 0.0]
"""


def _rig_text(focal, dist=""):
    pix = 0.0039
    ppx, ppy = (CX - (W - 1) / 2) * pix, -(CY - (H - 1) / 2) * pix  # image mm, y up, from the centre
    return RIG.format(w=W, h=H, focal=focal, ppx=repr(ppx), ppy=repr(ppy), dist=dist)


def test_rig_file_focal_mm_pair_reads_exactly_and_writes_back(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text(_rig_text(f"[{FX * 0.0039!r}, {FY * 0.0039!r}]"))
    cam = read_rig(p).head("nadir").camera
    P = _points(seed=3)
    np.testing.assert_allclose(cam.project_pixels(P), _pinhole(P, FX, FY, CX, CY), rtol=0, atol=1e-9)
    write_rig(read_rig(p), tmp_path / "again.yaml")
    text = (tmp_path / "again.yaml").read_text()
    assert "b1" not in text
    cam2 = read_rig(tmp_path / "again.yaml").head("nadir").camera
    assert fx_fy_px(cam2) == pytest.approx((FX, FY), rel=1e-13)
    np.testing.assert_allclose(cam2.project_pixels(P), _pinhole(P, FX, FY, CX, CY), rtol=0, atol=1e-9)


@pytest.mark.parametrize("focal, dist, words", [
    ("[10.0, 11.0]", "    distortion: {model: opencv, k1: -0.1}\n", "brown"),
    ("[10.0, 11.0]", "    distortion: {model: brown, b1: 0.001}\n", "b1"),
    ("[10.0, -11.0]", "", "positive"),
    ("[10.0, 11.0, 12.0]", "", "shape"),
])
def test_rig_file_bad_focal_pairs_name_line_and_field(tmp_path, focal, dist, words):
    p = tmp_path / "rig.yaml"
    p.write_text(_rig_text(focal, dist))
    with pytest.raises(InputFormatError, match=words) as e:
        read_rig(p)
    assert e.value.path == str(p) and e.value.field == "heads[0].camera.focal_mm" and e.value.line == 11


def test_brown_terms_are_kept_with_fx_ne_fy(tmp_path):
    """With a Brown distortion the pair sets its b1 and keeps the radial term: the projected pixels satisfy the
    Brown correction written out here (ideal = observed (1 + k1 r^2) + b1 x_observed, mm, from the principal point;
    ideal = the pinhole with principal distance fy)."""
    pix, k1 = 0.0039, 2.0e-5
    p = tmp_path / "rig.yaml"
    p.write_text(_rig_text(f"[{FX * pix!r}, {FY * pix!r}]", f"    distortion: {{model: brown, k1: {k1}}}\n"))
    cam = read_rig(p).head("nadir").camera
    d = cam.distortion
    assert d.k1 == k1 and d.b1 == pytest.approx(FY / FX - 1, rel=1e-14)
    P = _points(seed=4)
    cr = cam.project_pixels(P)
    x, y = (cr[:, 0] - CX) * pix, -(cr[:, 1] - CY) * pix  # observed mm from the principal point, y up
    r2 = x * x + y * y
    ideal = _pinhole(P, FY, FY, CX, CY)
    np.testing.assert_allclose(x * (1 + k1 * r2) + d.b1 * x, (ideal[:, 0] - CX) * pix, rtol=0, atol=1e-11)
    np.testing.assert_allclose(y * (1 + k1 * r2), -(ideal[:, 1] - CY) * pix, rtol=0, atol=1e-11)
