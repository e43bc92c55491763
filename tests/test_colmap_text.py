"""COLMAP text models: pycolmap writes a known synthetic scene (Reconstruction.write_text), skyrig reads it
back; the independent answer is pycolmap's own projection of every point into every image (COLMAP
pixels, corner origin), which skyrig's FrameCamera projection must reproduce (minus 0.5 px) to 1e-6 px.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
from skyrig.errors import InputFormatError
from skyrig.io.colmap_text import block_from_colmap, read_colmap_text

pycolmap = pytest.importorskip("pycolmap")

# one camera per supported model (fx == fy: skyrig's cameras have square pixels)
CAMERAS = [
    ("SIMPLE_PINHOLE", [1200.0, 640.3, 479.6]),
    ("PINHOLE", [1100.0, 1100.0, 650.2, 470.1]),
    ("SIMPLE_RADIAL", [1150.0, 630.7, 482.2, -0.08]),
    ("RADIAL", [1250.0, 641.0, 475.5, -0.11, 0.04]),
    ("OPENCV", [1180.0, 1180.0, 636.1, 488.9, -0.12, 0.05, 0.0011, -0.0007]),
    ("FULL_OPENCV", [1220.0, 1220.0, 644.4, 471.3, -0.10, 0.03, -0.0009, 0.0012, 0.004, 0.01, -0.002, 0.001]),
]
W, H = 1280, 960


def _look_at(centre, target, rng):
    """COLMAP cam_from_world (z forward, y down) looking from centre at target, with a random roll."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0]) + rng.normal(0, 0.2, 3)
    x -= z * (x @ z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])  # rows: camera axes in world
    return R, -R @ centre


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    rng = np.random.default_rng(11)
    X = rng.uniform([-10, -10, -2], [10, 10, 2], (150, 3))
    rec = pycolmap.Reconstruction()
    for cid, (model, params) in enumerate(CAMERAS, start=1):
        cam = pycolmap.Camera.create_from_model_name(cid, model, params[0], W, H)
        cam.params = params
        rec.add_camera_with_trivial_rig(cam)
    truth = {}  # (image_id, point index) -> COLMAP pixel by pycolmap
    obs_of_point: dict[int, list] = {k: [] for k in range(len(X))}
    n_img = 12
    for i in range(n_img):
        ang = 2 * np.pi * i / n_img
        C = np.array([25 * np.cos(ang), 25 * np.sin(ang), 15.0 + 3 * (i % 3)])
        R, t = _look_at(C, np.array([0.0, 0.0, 0.0]), rng)
        cid = i % len(CAMERAS) + 1
        cam = rec.camera(cid)
        T = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
        kps, idx = [], []
        for k in range(len(X)):
            Pc = R @ X[k] + t
            uv = cam.img_from_cam(Pc)
            if Pc[2] > 0 and uv is not None and 0 <= uv[0] < W and 0 <= uv[1] < H:
                kps.append(uv)
                idx.append(k)
        kps.append([5.25, 7.75])  # an untriangulated keypoint (POINT3D_ID -1)
        img = pycolmap.Image(name=f"img{i:02d}.jpg", keypoints=np.array(kps), camera_id=cid, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, T)
        for j, k in enumerate(idx):
            obs_of_point[k].append(pycolmap.TrackElement(i + 1, j))
            truth[(i + 1, k)] = np.asarray(kps[j])
    ids = {}
    for k, els in obs_of_point.items():
        if len(els) >= 2:
            ids[k] = rec.add_point3D(X[k], pycolmap.Track(els))
    folder = tmp_path_factory.mktemp("colmap")
    rec.write_text(str(folder))
    return folder, rec, X, ids, truth


def test_read_back_projections_agree_with_pycolmap(scene):
    folder, rec, X, ids, truth = scene
    m = read_colmap_text(folder)
    assert len(m.image_id) == 12 and len(m.point_id) == len(ids) and len(m.cameras) == len(CAMERAS)
    id_to_k = {v: k for k, v in ids.items()}
    n = 0
    for i, iid in enumerate(m.image_id):
        cam = m.cameras[int(m.image_camera_id[i])]
        pose = m.world_from_camera[i]
        # every point of the scene that pycolmap projected into this image (triangulated or not)
        ks = [k for (ii, k) in truth if ii == iid]
        got = cam.world_to_pixel(pose, X[ks])
        want = np.array([pycolmap_px for (ii, k), pycolmap_px in truth.items() if ii == iid]) - 0.5
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
        n += len(ks)
    assert n > 300
    # the measurements read back are pycolmap's keypoints (minus 0.5), attached to the right points
    want = np.array([truth[(int(m.image_id[i]), id_to_k[int(m.point_id[p])])]
                     for i, p in zip(m.obs_image, m.obs_point)]) - 0.5
    np.testing.assert_allclose(m.obs_pixel, want, rtol=0, atol=1e-9)
    assert len(m.obs_image) == sum(len(rec.point3D(v).track.elements) for v in ids.values())


def test_poses_and_camera_models(scene):
    folder, rec, *_ = scene
    m = read_colmap_text(folder)
    for i, iid in enumerate(m.image_id):
        T = rec.image(int(iid)).cam_from_world()
        # camera centre and viewing direction (COLMAP +z = skyrig -z)
        np.testing.assert_allclose(m.world_from_camera.translation[i], rec.image(int(iid)).projection_center(),
                                   atol=1e-9)
        np.testing.assert_allclose(m.world_from_camera.rotation[i] @ [0, 0, -1.0],
                                   T.rotation.matrix()[2], atol=1e-12)
    names = [type(c.distortion).name for c in (m.cameras[k] for k in sorted(m.cameras))]
    assert names == ["none", "none", "opencv", "opencv", "opencv", "opencv_rational"]
    pp = m.cameras[1].principal_point_px
    assert pp == pytest.approx((640.3 - 0.5, 479.6 - 0.5), abs=1e-9)


def test_block_adjusts_to_zero_residuals(scene):
    folder, *_ = scene
    b = block_from_colmap(read_colmap_text(folder))
    b.validate()
    # exact synthetic measurements: a free-network adjustment must leave (almost) nothing
    r = adjust(b, AdjustConfig(unknowns=Unknowns(datum="free"), statistics=StatisticsOptions(compute=False),
                               solver=SolverOptions(max_iterations=5)))
    rms = np.sqrt(np.mean(r.residuals["image"].residual ** 2))
    assert rms < 1e-5


@pytest.mark.parametrize(
    "fname, old, new, needle",
    [
        ("cameras.txt", "1 SIMPLE_PINHOLE", "1 OPENCV_FISHEYE", "MODEL"),
        ("cameras.txt", "2 PINHOLE 1280 960 1100 1100", "2 PINHOLE 1280 960 1100 -1100", "field 'fy'"),  # fx != fy: read
        ("cameras.txt", "1 SIMPLE_PINHOLE 1280 960 1200", "1 SIMPLE_PINHOLE 1280 960 abc", "field 'f'"),
        ("images.txt", "img00.jpg", "img00.jpg", None),
    ],
)
def test_bad_models(scene, tmp_path, fname, old, new, needle):
    folder, *_ = scene
    for f in ("cameras.txt", "images.txt", "points3D.txt"):
        text = (folder / f).read_text()
        if f == fname:
            assert old in text
            text = text.replace(old, new, 1)
        (tmp_path / f).write_text(text)
    if needle is None:
        read_colmap_text(tmp_path)  # unchanged copy reads
        return
    with pytest.raises(InputFormatError, match=needle) as e:
        read_colmap_text(tmp_path)
    assert "cameras.txt" in str(e.value) and "line" in str(e.value)


def test_unknown_point_and_camera_named(scene, tmp_path):
    folder, *_ = scene
    lines = (folder / "images.txt").read_text().split("\n")
    hdr = next(i for i, s in enumerate(lines) if s and not s.startswith("#"))
    f = lines[hdr + 1].split()
    f[2] = "999999"  # first keypoint names a point that does not exist
    lines[hdr + 1] = " ".join(f)
    for name in ("cameras.txt", "points3D.txt"):
        (tmp_path / name).write_text((folder / name).read_text())
    (tmp_path / "images.txt").write_text("\n".join(lines))
    with pytest.raises(InputFormatError, match=rf"images.txt, line {hdr + 2}, field 'POINT3D_ID'"):
        read_colmap_text(tmp_path)
    g = lines[hdr].split()
    g[8] = "77"
    lines[hdr] = " ".join(g)
    (tmp_path / "images.txt").write_text("\n".join(lines))
    with pytest.raises(InputFormatError, match=rf"line {hdr + 1}, field 'CAMERA_ID'"):
        read_colmap_text(tmp_path)
