"""COLMAP models in both directions and both encodings (issue 33).

Independent answers: pycolmap (COLMAP's own reader/writer and camera models) reads what skyrig writes and
writes what skyrig reads; its projections and reprojection errors are compared with skyrig's.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.camera.brown import BrownDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion, OpenCVRationalDistortion
from skyrig.errors import InputFormatError, OptionError
from skyrig.geometry.pose import Pose
from skyrig.io.colmap import ColmapModel, block_from_colmap, colmap_from_block
from skyrig.io.colmap_folder import read_colmap, write_colmap
from skyrig.io.colmap_binary import read_colmap_binary
from skyrig.io.colmap_text import read_colmap_text

pycolmap = pytest.importorskip("pycolmap")

W, H = 1280, 960
F = np.diag([1.0, -1.0, -1.0])


def _cameras():
    return {
        1: FrameCamera.from_pixels("a", W, H, 1200.0, 640.3, 479.6),
        2: FrameCamera.from_pixels("b", W, H, 1150.0, 630.7, 482.2, distortion=OpenCVDistortion(k1=-0.08)),
        3: FrameCamera.from_pixels("c", W, H, 1250.0, 641.0, 475.5, distortion=OpenCVDistortion(k1=-0.11, k2=0.04)),
        4: FrameCamera.from_pixels("d", W, H, 1180.0, 636.1, 488.9,
                                   distortion=OpenCVDistortion(-0.12, 0.05, 0.0011, -0.0007)),
        7: FrameCamera.from_pixels("e", W, H, 1220.0, 644.4, 471.3,
                                   distortion=OpenCVRationalDistortion(-0.1, 0.03, -0.0009, 0.0012, 0.004, 0.01,
                                                                       -0.002, 0.001)),
    }


def _model(seed=3, noise_px=0.3) -> ColmapModel:
    """A ring of 10 images looking at a cloud of 200 points; measurements = projections + noise."""
    rng = np.random.default_rng(seed)
    cams = _cameras()
    cids = sorted(cams)
    X = rng.uniform([-10, -10, -2], [10, 10, 2], (200, 3))
    R, C, cam_of = [], [], []
    for i in range(10):
        ang = 2 * np.pi * i / 10
        c = np.array([25 * np.cos(ang), 25 * np.sin(ang), 15.0 + 2 * (i % 3)])
        z = -c / np.linalg.norm(c)  # COLMAP +z (forward) towards the origin
        x = np.cross(z, [0, 0, 1.0]) + rng.normal(0, 0.1, 3)
        x -= z * (x @ z)
        x /= np.linalg.norm(x)
        R_cw = np.stack([x, np.cross(z, x), z])
        R.append(R_cw.T @ F)
        C.append(c)
        cam_of.append(cids[i % len(cids)])
    pose = Pose(np.array(R), np.array(C), "world", "camera")
    oi, op, opx = [], [], []
    for i in range(10):
        px = cams[cam_of[i]].world_to_pixel(pose[i], X)
        ok = np.flatnonzero(np.isfinite(px).all(1) & (px[:, 0] > 0) & (px[:, 0] < W - 1) & (px[:, 1] > 0)
                            & (px[:, 1] < H - 1))
        oi += [i] * ok.size
        op += ok.tolist()
        opx.append(px[ok] + rng.normal(0, noise_px, (ok.size, 2)))
    oi, op = np.array(oi), np.array(op)
    keep = np.flatnonzero(np.bincount(op, minlength=len(X)) >= 2)
    remap = -np.ones(len(X), np.int64)
    remap[keep] = np.arange(keep.size)
    sel = remap[op] >= 0
    return ColmapModel(cams, np.arange(11, 21), np.array([f"dir/img_{i:02d}.jpg" for i in range(10)]),
                       np.array(cam_of), pose, np.arange(keep.size) * 3 + 5, X[keep],
                       rng.integers(0, 256, (keep.size, 3)).astype(np.uint8), np.full(keep.size, -1.0),
                       oi[sel], remap[op[sel]], np.concatenate(opx)[sel])


def _assert_same(a: ColmapModel, b: ColmapModel, rtol=1e-12):
    np.testing.assert_array_equal(a.image_id, b.image_id)
    np.testing.assert_array_equal(a.image_name, b.image_name)
    np.testing.assert_array_equal(a.image_camera_id, b.image_camera_id)
    np.testing.assert_allclose(a.world_from_camera.rotation, b.world_from_camera.rotation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.world_from_camera.translation, b.world_from_camera.translation, rtol=rtol, atol=1e-12)
    np.testing.assert_array_equal(a.point_id, b.point_id)
    np.testing.assert_allclose(a.point_xyz, b.point_xyz, rtol=rtol)
    np.testing.assert_array_equal(a.point_rgb, b.point_rgb)
    np.testing.assert_array_equal(a.obs_image, b.obs_image)
    np.testing.assert_array_equal(a.obs_point, b.obs_point)
    np.testing.assert_allclose(a.obs_pixel, b.obs_pixel, rtol=0, atol=1e-9)
    assert sorted(a.cameras) == sorted(b.cameras)
    rng = np.random.default_rng(0)
    for k in a.cameras:
        ca, cb = a.cameras[k], b.cameras[k]
        assert (ca.width, ca.height) == (cb.width, cb.height)
        np.testing.assert_allclose(cb.intrinsics[:3], ca.intrinsics[:3], rtol=1e-12, atol=1e-12)
        # 1,000 random rays through both cameras: the same pixels to 1e-6 px
        P = np.column_stack([rng.uniform(-0.5, 0.5, (1000, 2)), -np.ones(1000)])
        np.testing.assert_allclose(cb.project_pixels(P), ca.project_pixels(P), rtol=0, atol=1e-6)


@pytest.mark.parametrize("binary", [False, True])
def test_round_trip_exact(tmp_path, binary):
    m = _model()
    files = write_colmap(tmp_path, m, binary=binary)
    assert [f.suffix for f in files] == [".bin" if binary else ".txt"] * 3
    back = (read_colmap_binary if binary else read_colmap_text)(tmp_path)
    _assert_same(m, back)
    assert [type(back.cameras[k].distortion).name for k in sorted(back.cameras)] == [
        "none", "opencv", "opencv", "opencv", "opencv_rational"]
    assert read_colmap(tmp_path).image_name[3] == "dir/img_03.jpg"


def _pycolmap_residuals(rec):
    """Per observation (image id, point id) -> pycolmap's projection minus the keypoint (COLMAP px)."""
    out = {}
    for iid, img in rec.images.items():
        cam = rec.cameras[img.camera_id]
        T = img.cam_from_world()
        for p2 in img.points2D:
            if p2.has_point3D():
                uv = cam.img_from_cam(T * rec.points3D[p2.point3D_id].xyz)
                out[(iid, p2.point3D_id)] = uv - p2.xy
    return out


@pytest.mark.parametrize("binary", [False, True])
def test_pycolmap_reads_skyrig_export_with_the_same_residuals(tmp_path, binary):
    m = _model()
    write_colmap(tmp_path, m, binary=binary)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_reg_images() == 10 and rec.num_points3D() == len(m.point_id)
    assert rec.compute_num_observations() == len(m.obs_image)
    for i, iid in enumerate(m.image_id):
        img = rec.images[int(iid)]
        assert img.name == m.image_name[i]
        np.testing.assert_allclose(img.projection_center(), m.world_from_camera.translation[i], atol=1e-9)
        # COLMAP's viewing direction +z is skyrig's -z
        np.testing.assert_allclose(img.cam_from_world().rotation.matrix()[2],
                                   -m.world_from_camera.rotation[i][:, 2], atol=1e-12)
    # skyrig's residuals (projection - measurement) equal pycolmap's for every observation, to 1e-6 px
    res = _pycolmap_residuals(rec)
    mine = np.array([m.cameras[int(m.image_camera_id[i])].world_to_pixel(m.world_from_camera[i],
                                                                          m.point_xyz[p:p + 1])[0]
                     for i, p in zip(m.obs_image, m.obs_point)]) - m.obs_pixel
    theirs = np.array([res[(int(m.image_id[i]), int(m.point_id[p]))] for i, p in zip(m.obs_image, m.obs_point)])
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-6)
    rms = np.sqrt(np.mean(np.sum(mine**2, 1)))
    assert 0.3 < rms < 0.6  # the 0.3 px noise per axis (sqrt(2) * 0.3 = 0.42)
    # and COLMAP's own per-point errors (mean residual length of the track) agree with skyrig's
    rec.update_point_3d_errors()
    e = np.linalg.norm(mine, axis=1)
    per_point = np.bincount(m.obs_point, e) / np.bincount(m.obs_point)
    theirs_pp = np.array([rec.points3D[int(k)].error for k in m.point_id])
    np.testing.assert_allclose(theirs_pp, per_point, rtol=1e-9)
    assert rec.compute_mean_reprojection_error() == pytest.approx(per_point.mean(), rel=1e-9)


def test_skyrig_reads_pycolmap_binary(tmp_path):
    """pycolmap writes (from its own objects) a binary model; skyrig reads it as its text twin."""
    m = _model(seed=5, noise_px=0.0)
    write_colmap(tmp_path / "t", m, binary=False)
    rec = pycolmap.Reconstruction(str(tmp_path / "t"))
    (tmp_path / "b").mkdir()
    rec.write_binary(str(tmp_path / "b"))  # also rigs.bin and frames.bin: ignored
    back = read_colmap_binary(tmp_path / "b")
    _assert_same(m, back)
    # pycolmap's projection of every point = skyrig's (minus the half pixel)
    for i, iid in enumerate(back.image_id):
        img = rec.images[int(iid)]
        cam = rec.cameras[img.camera_id]
        uv = np.array([cam.img_from_cam(img.cam_from_world() * x) for x in back.point_xyz[:50]])
        np.testing.assert_allclose(back.cameras[int(back.image_camera_id[i])].world_to_pixel(
            back.world_from_camera[i], back.point_xyz[:50]), uv - 0.5, rtol=0, atol=1e-6)


def test_brown_camera_refused_or_fitted(tmp_path):
    m = _model(seed=2, noise_px=0.0)
    brown = m.cameras[1].with_(distortion=BrownDistortion(k1=0.04, k2=-0.01, p1=2e-4, p2=-1e-4))
    m.cameras[1] = brown
    with pytest.raises(OptionError, match="brown"):
        write_colmap(tmp_path, m)
    write_colmap(tmp_path, m, fit_cameras=True)
    rep = m.fit_reports[1]
    assert rep.rms_px <= 0.01 and rep.target_model == "opencv"
    back = read_colmap(tmp_path)
    from skyrig.camera.convert import compare_cameras

    assert compare_cameras(brown, back.cameras[1]).rms_px == pytest.approx(rep.rms_px, rel=1e-3, abs=1e-7)


def test_block_export_reads_in_pycolmap(tmp_path):
    m = _model(seed=4)
    b = block_from_colmap(m)
    out = colmap_from_block(b)
    write_colmap(tmp_path, out)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.compute_num_observations() == b.n_observations
    np.testing.assert_allclose(rec.images[1].projection_center(), b.station_centre[0], atol=1e-9)


def test_bad_binary_files_are_named(tmp_path):
    m = _model(seed=6, noise_px=0.0)
    write_colmap(tmp_path, m)
    data = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFormatError, match=r"images.bin, line \d+, field .*(ends early|does not fit)"):
        read_colmap_binary(tmp_path)
    cams = bytearray((tmp_path / "cameras.bin").read_bytes())
    cams[12] = 99  # the first camera's model id
    (tmp_path / "cameras.bin").write_bytes(bytes(cams))
    with pytest.raises(InputFormatError, match=r"cameras.bin, line 1, field 'MODEL_ID'"):
        read_colmap_binary(tmp_path)
    # a text file given as binary
    (tmp_path / "cameras.bin").write_text("# Camera list\n1 PINHOLE 640 480 500 500 320 240\n")
    with pytest.raises(InputFormatError, match="cameras.bin"):
        read_colmap_binary(tmp_path)
    with pytest.raises(InputFormatError, match="not a COLMAP model folder"):
        read_colmap(tmp_path / "nothing")


def test_names_with_blanks_binary_only(tmp_path):
    m = _model(seed=7, noise_px=0.0)
    m.image_name = np.array([f"flight 1/img {i}.jpg" for i in range(10)])
    with pytest.raises(OptionError, match="blank"):
        write_colmap(tmp_path / "t", m, binary=False)
    write_colmap(tmp_path / "b", m, binary=True)
    rec = pycolmap.Reconstruction(str(tmp_path / "b"))
    assert rec.images[11].name == "flight 1/img 0.jpg"
    assert read_colmap(tmp_path / "b").image_name[9] == "flight 1/img 9.jpg"
