"""``skyrig ortho --surface dtm`` (issue 31): a classic orthophoto on the DTM.  One nadir image of hilly ground
(relief +-12 m under a camera 300 m up) with bright dots drawn where ground points of the DTM project (the
pinhole model applied here in the map frame, independently of skyrig's ortho code); in the orthophoto each dot must
lie on its ground point's map position - on a plane at the mean height it would be off by up to 2.2 m (9 cells)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main

E0, N0 = 500000.0, 5800000.0
H_CAM = 400.0  # camera height (ellipsoidal), the ground 88-112 m


def _height(x, y):
    return 100.0 + 12.0 * np.sin((x - E0) / 25.0) * np.cos((y - N0) / 35.0)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    from skyrig.camera.frame import FrameCamera
    from skyrig.dense.grid import DsmGrid, GridSpec
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.geometry.pose import Pose
    from skyrig.io.dsm_cog import write_dsm_cog
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.images import write_image
    from skyrig.io.rig_file import write_rig
    from skyrig.io.terrain_files import write_dtm_cog
    from skyrig.rig import presets
    from skyrig.rig.rig import Head, Rig
    from skyrig.terrain.dtm import DtmGrid

    d = tmp_path_factory.mktemp("ortho_dtm")
    frame = WorldFrame.map("EPSG:25832")
    g = GridSpec(E0, N0 + 200.0, 1.0, 200, 200)
    xx, yy = g.cell_centres()
    h = _height(xx, yy).astype(np.float32)
    ones = np.ones(g.shape)
    for name, hh in (("dtm.tif", h), ("plane.tif", np.full(g.shape, 100.0, np.float32))):
        write_dtm_cog(d / name, DtmGrid(g, frame, hh, (0.02 * ones).astype(np.float32), ones.astype(np.int32),
                                        ones.astype(np.uint8)))
    z = np.zeros(g.shape, np.float32)
    write_dsm_cog(d / "dsm.tif", DsmGrid(g, frame, h, ones.astype(np.int16), z, z + 0.02, np.zeros(g.shape, bool)))
    cam = FrameCamera("cam", 1000, 800, 0.01, 20.0)
    write_rig(Rig("one", [Head("cam", cam, mounting=presets.oblique_mounting(0, 0))]), d / "rig.yaml")
    centre = np.array([E0 + 100.0, N0 + 100.0, H_CAM])
    eo = ExteriorOrientations(np.array(["img.png"]), np.array(["cam"]), centre[None], np.eye(3)[None], frame,
                              head=np.array(["cam"]))
    write_eo_csv(eo, d / "eo.csv")
    # ground points off nadir (on the crests and troughs: up to 2.2 m of relief displacement) and at nadir
    gx = E0 + 100.0 + np.array([-60.7, -60.7, 17.8, 17.8, 0.0, 55.0, -55.0, 55.0])
    gy = N0 + 100.0 + np.array([0.0, 45.0, 45.0, 10.0, 0.0, -45.0, -45.0, 45.0])
    P = np.column_stack([gx, gy, _height(gx, gy)])
    px = cam.world_to_pixel(Pose(np.eye(3), centre, "world", "camera"), P)
    cols, rows = np.meshgrid(np.arange(cam.width), np.arange(cam.height))  # pixel centres (skyrig: integers)
    img = np.full((cam.height, cam.width), 60.0)
    for c, r in px:  # a disc of 3 px radius, anti-aliased over one pixel
        img += 190.0 * np.clip(3.5 - np.hypot(cols - c, rows - r), 0.0, 1.0)
    (d / "img").mkdir()
    write_image(d / "img" / "img.png", np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2))
    return d, P


def _ortho(d, *extra):
    return CliRunner().invoke(main, ["ortho", "--eo", str(d / "eo.csv"), "--camera", str(d / "rig.yaml"), "--images",
                                     str(d / "img"), "--resolution", "0.25", "--no-balance", *map(str, extra)],
                              catch_exceptions=False)


def _dots(path, n):
    """Centroids (map x, y) of the ``n`` bright dots in an orthophoto, brightness above the background weighted."""
    import rasterio
    from scipy import ndimage

    with rasterio.open(path) as ds:
        v = ds.read(1).astype(np.float64)
        t = ds.transform
    w = np.clip(v - 70.0, 0, None)
    lab, k = ndimage.label(w > 30.0)
    assert k == n, k
    rc = np.array(ndimage.center_of_mass(w, lab, range(1, k + 1)))
    return np.column_stack([t.c + (rc[:, 1] + 0.5) * t.a, t.f + (rc[:, 0] + 0.5) * t.e])


def test_classic_ortho_on_the_dtm_puts_ground_points_in_place(block):
    import json

    d, P = block
    r = _ortho(block[0], "--surface", "dtm", "--dtm", d / "dtm.tif", "-o", d / "o")
    assert r.exit_code == 0, r.output
    assert "classic orthophoto on the DTM" in r.output
    got = _dots(d / "o" / "ortho.tif", len(P))
    # match each ground point to its nearest dot
    dist = np.hypot(got[None, :, 0] - P[:, None, 0], got[None, :, 1] - P[:, None, 1]).min(axis=1)
    assert dist.max() < 0.1, dist  # 0.4 cell (measured <= 0.04 m: the map projection's scale, 0.9996, over 70 m)
    assert json.loads((d / "o" / "manifest.json").read_text())["options"]["surface"] == "dtm"
    # the relief matters: on a plane at the mean height (100 m) the dots move where the ray through each ground
    # point meets the plane (up to 2.2 m away)
    r = _ortho(block[0], "--surface", "dtm", "--dtm", d / "plane.tif", "-o", d / "p")
    assert r.exit_code == 0, r.output
    on_plane = _dots(d / "p" / "ortho.tif", len(P))
    c = np.array([E0 + 100.0, N0 + 100.0, H_CAM])
    want = c[:2] + (P[:, :2] - c[:2]) * ((H_CAM - 100.0) / (H_CAM - P[:, 2]))[:, None]
    moved = np.hypot(*(want - P[:, :2]).T)
    assert moved.max() > 2.0
    dist = np.hypot(on_plane[None, :, 0] - want[:, None, 0], on_plane[None, :, 1] - want[:, None, 1]).min(axis=1)
    assert dist.max() < 0.1, dist


def test_surface_options_refused_in_words(block):
    d, _ = block
    r = _ortho(d, "--surface", "dtm", "--dtm", d / "dsm.tif", "-o", d / "x")
    assert r.exit_code == 2 and "is a DSM, not a DTM" in r.output and "dsm.tif" in r.output, r.output
    r = _ortho(d, "--surface", "dtm", "--dsm", d / "dsm.tif", "-o", d / "x")
    assert r.exit_code == 2 and "--dtm" in r.output, r.output
    r = _ortho(d, "--dtm", d / "dtm.tif", "--dsm", d / "dsm.tif", "-o", d / "x")
    assert r.exit_code == 2 and "not used with --surface dsm" in r.output, r.output
    assert not (d / "x").exists()


def test_project_stage_ortho_dtm_on_the_dtm_stage_output(block, tmp_path):
    """The runner's ``ortho-dtm`` stage (after ``dtm``) takes the dtm stage's DTM: the same dots in place."""
    from types import SimpleNamespace

    from skyrig.pipeline.project import ExecutorSpec
    from skyrig.pipeline.run import STAGES

    d, P = block
    st = STAGES["ortho-dtm"]
    assert st.requires == ("eo", "dtm") and list(STAGES).index("ortho-dtm") > list(STAGES).index("dtm")
    opts = {k: v.default for k, v in st.options.items()} | {"resolution": 0.25, "balance": False}
    files = {"eo": d / "eo.csv", "dtm": d / "dtm.tif"}
    ctx = SimpleNamespace(options=opts, need=files.__getitem__, out=tmp_path / "stage", upstream={},
                          spec=SimpleNamespace(name="ortho-dtm"),
                          project=SimpleNamespace(images=[d / "img"], rig=d / "rig.yaml", cameras=[],
                                                  executor=ExecutorSpec()), progress=lambda done, total: None)
    s = st.run(ctx)
    assert s["images_used"] == 1
    got = _dots(tmp_path / "stage" / "ortho.tif", len(P))
    assert np.hypot(got[None, :, 0] - P[:, None, 0], got[None, :, 1] - P[:, None, 1]).min(axis=1).max() < 0.1
