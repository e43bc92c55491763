"""Forward intersection and ``skyrig image-to-world`` with absurd pixels: never a point thousands of km away
with a fake 0.000 px RMS (issue 13). Seeded synthetic block: three nadir images 300 m apart, 900 m above ground."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.camera.frame import FrameCamera
from skyrig.cli import main
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.ground import far_outside_image, forward_intersection, world_to_image
from skyrig.geometry.rotations import matrix_from_opk
from skyrig.io.eo_csv import write_eo_csv

UTM = WorldFrame.map("EPSG:32632")
CAM = FrameCamera("cam", 4000, 3000, 0.004, 16.0)


def _scene(seed=11, n=6):
    rng = np.random.default_rng(seed)
    c = np.array([[500000.0 + 300 * i, 5400000.0, 1000.0] for i in range(3)])
    eo = ExteriorOrientations([f"img{i}" for i in range(3)], ["cam"] * 3, c,
                              matrix_from_opk(*np.zeros((3, 3)).T, unit="deg"), UTM)
    truth = np.column_stack([rng.uniform(500200, 500400, n), rng.uniform(5399900, 5400100, n), rng.uniform(90, 110, n)])
    names = np.repeat([f"p{i}" for i in range(n)], 3)
    images = np.tile(["img0", "img1", "img2"], n)
    px = world_to_image(eo, {"cam": CAM}, images, np.repeat(truth, 3, axis=0), UTM)
    assert np.all(CAM.in_image(px))
    return eo, truth, names, images, px


@pytest.mark.parametrize("bad", [1e9, -1e9, np.nan, np.inf, 3 * 4000.0])
def test_absurd_pixel_is_left_out_and_reported(bad):
    eo, truth, names, images, px = _scene()
    px[0, 0] = bad  # p0 in img0
    res = forward_intersection(eo, {"cam": CAM}, names, images, px, UTM)
    assert not res.used[0] and res.used[1:].all()
    assert res.n_rays[0] == 2 and res.valid.all()
    np.testing.assert_allclose(res.xyz, truth, atol=1e-4)  # p0 from its two good rays
    assert res.rms_px.max() < 1e-6
    if np.isfinite(bad):  # the left-out measurement's residual is stated as it is, not zeroed
        assert abs(res.residual_px[0, 0]) > 1000.0
    assert "img0" in res.note[0] and "left out" in res.note[0] and (res.note[1:] == "").all()


def test_point_with_one_usable_ray_is_not_invented():
    eo, truth, names, images, px = _scene()
    px[0, 0], px[1, 1] = 1e9, np.nan  # p0 keeps only its img2 ray
    res = forward_intersection(eo, {"cam": CAM}, names, images, px, UTM)
    assert res.n_rays[0] == 1 and not res.valid[0] and np.isnan(res.xyz[0]).all() and np.isnan(res.rms_px[0])
    assert "1 usable ray" in res.note[0]
    assert res.valid[1:].all()


def test_rays_meeting_behind_the_cameras_are_flagged_not_zeroed():
    eo, truth, names, images, px = _scene()
    # p0: img0 looks far to the west, img1 far to the east (inside the image): the rays diverge downwards,
    # their closest approach is above the cameras
    px[0] = [0.0, 1500.0]
    px[1] = [3999.0, 1500.0]
    res = forward_intersection(eo, {"cam": CAM}, names[3:] .tolist() + ["q", "q"],
                               images[3:].tolist() + ["img0", "img1"], np.vstack([px[3:], px[:2]]), UTM)
    q = list(res.point).index("q")
    assert res.used.all() and res.n_rays[q] == 2
    assert not res.valid[q] and np.isnan(res.rms_px[q]) and "behind" in res.note[q]
    assert res.valid[[k for k in range(len(res.point)) if k != q]].all()


def test_far_outside_image_margin():
    eo, _, _, _, _ = _scene()
    px = np.array([[-0.5, -0.5], [3999.5, 2999.5], [-4000.4, 1500.0], [-4000.6, 1500.0], [7999.4, 1.0],
                   [8000.0, 1.0], [1.0, 5999.4], [1.0, 6000.0], [np.nan, 1.0]])
    far = far_outside_image(eo, {"cam": CAM}, ["img0"] * len(px), px)
    assert far.tolist() == [False, False, False, True, False, True, False, True, True]


# ------------------------------------------------------------------------------------------------ the command
def _project(tmp_path, px, names, images):
    eo, *_ = _scene()
    write_eo_csv(eo, tmp_path / "eo.csv")
    (tmp_path / "cam.txt").write_text("Name = cam\nPPAx = 1999.5\nPPAy = 1499.5\nfocal = 4000\nwidth = 4000\n"
                                      "height = 3000\n", encoding="utf-8")
    rows = "".join(f"{n},{i},{float(c)!r},{float(r)!r}\n" for n, i, (c, r) in zip(names, images, px))
    (tmp_path / "mes.csv").write_text("point,image,column,row\n" + rows, encoding="utf-8")
    (tmp_path / "t.mes").write_text("".join(f"{n} {i} {float(c)!r} {float(r)!r}\n" for n, i, (c, r) in zip(names, images, px)),
                                    encoding="utf-8")


def _run(tmp_path, mes="mes.csv"):
    return CliRunner().invoke(main, ["image-to-world", "--eo", str(tmp_path / "eo.csv"), "--camera",
                                     str(tmp_path / "cam.txt"), "--measurements", str(tmp_path / mes), "--intersect",
                                     "-o", str(tmp_path / "out.csv")])


def test_cli_good_measurements(tmp_path):
    _, truth, names, images, px = _scene()
    _project(tmp_path, px, names, images)
    res = _run(tmp_path)
    assert res.exit_code == 0, res.output
    assert "intersected 6 of 6 points" in res.output and "RMS 0.000 px over 18 measurements" in res.output
    from skyrig.io.points_csv import read_points_csv

    back = read_points_csv(tmp_path / "out.csv")
    np.testing.assert_allclose(back.xyz[np.argsort(back.name)], truth, atol=1e-3)


@pytest.mark.parametrize("mes, line", [("mes.csv", 3), ("t.mes", 2)])
@pytest.mark.parametrize("k, col, row, field", [(1, 1e9, 100.0, "column"), (1, 200.0, -7e5, "row")])
def test_cli_pixel_far_outside_names_file_line_field(tmp_path, mes, line, k, col, row, field):
    _, truth, names, images, px = _scene()
    px[k] = [col, row]
    _project(tmp_path, px, names, images)
    res = _run(tmp_path, mes)
    assert res.exit_code == 2 and "Traceback" not in res.output
    msg = res.output
    assert str(tmp_path / mes) in msg and f"line {line}" in msg and f"field '{field}'" in msg
    assert "more than one image size outside image 'img1' (4000 x 3000 px)" in msg
    assert "array(" not in msg and not (tmp_path / "out.csv").exists()


def test_cli_unknown_image_names_file_and_line(tmp_path):
    _, truth, names, images, px = _scene()
    images = images.copy()
    images[4] = "img9"
    _project(tmp_path, px, names, images)
    res = _run(tmp_path)
    assert res.exit_code == 2 and "line 6" in res.output and "'img9'" in res.output and "field 'image'" in res.output


def test_cli_invalid_point_is_a_warning_with_nan_not_zero(tmp_path):
    _, truth, names, images, px = _scene()
    names = names.astype("U10")
    px = px.copy()
    names[:2] = "q"
    names[2] = "lonely"
    px[0], px[1] = [0.0, 1500.0], [3999.0, 1500.0]
    _project(tmp_path, px, names, images)
    res = _run(tmp_path)
    assert res.exit_code == 0, res.output
    assert "warning: point 'q':" in res.output and "behind" in res.output
    assert "warning: point 'lonely':" in res.output and "1 usable ray" in res.output
    assert "intersected 5 of 7 points" in res.output and "over 15 measurements" in res.output
    text = (tmp_path / "out.csv").read_text()
    q_row = next(r for r in text.splitlines() if r.startswith("q,"))
    assert "nan" in q_row.lower() and ",0.0" not in q_row
