"""Issue 33: ``skyrig import project FOLDER -o OUT``: another program's project folder, told by its files (COLMAP,
OpenSfM, Metashape cameras XML, Pix4D params), brought in as a skyrig project folder (eo.csv and side-car,
cameras.yaml, points.csv, tie_points.csv, block.json, import.json).

The independent answer: a simulated ring of 10 images around 200 points (tests/test_colmap_io.py: the true
poses, cameras and points, measurements = projections + 0.3 px noise), moved into UTM 32N and written in each
program's layout; what is imported must give back the true orientations and points, and the imported points
projected through the imported orientations and cameras must land on the measurements with the noise's RMS."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.errors import InputFormatError
from skyrig.geodesy.frame import WorldFrame
from skyrig.geometry.pose import Pose

SHIFT = np.array([550_000.0, 5_800_000.0, 100.0])
CRS = "EPSG:25832"


@pytest.fixture(scope="module")
def model():
    from test_colmap_io import _model

    from skyrig.camera.frame import FrameCamera
    from skyrig.camera.opencv import OpenCVDistortion

    m = _model(seed=12, noise_px=0.3)
    m.cameras[7] = FrameCamera.from_pixels("e", 1280, 960, 1220.0, 644.4, 471.3,
                                           distortion=OpenCVDistortion(-0.1, 0.03, -0.0009, 0.0012, 0.004))
    pose = m.world_from_camera
    return replace(m, world_from_camera=Pose(pose.rotation, pose.translation + SHIFT, "world", "camera"),
                   point_xyz=m.point_xyz + SHIFT)


def _write(kind: str, m, root: Path) -> Path:
    """The model in ``kind``'s project layout under ``root / kind``; returns that folder."""
    from skyrig.io.colmap import block_from_colmap, colmap_from_block

    folder = root / kind
    block = block_from_colmap(m, sigma_px=0.3)
    if kind == "colmap":
        from skyrig.io.colmap_folder import write_colmap

        (folder / "images").mkdir(parents=True)
        write_colmap(folder / "sparse" / "0", colmap_from_block(block))
    elif kind == "opensfm":
        from skyrig.io.opensfm import opensfm_from_block, write_opensfm, write_opensfm_tracks

        folder.mkdir()
        rec = opensfm_from_block(block, None)
        write_opensfm(folder / "reconstruction.json", rec)
        write_opensfm_tracks(folder / "tracks.csv", rec)
    elif kind == "metashape":
        from skyrig.io.metashape import metashape_from_block, write_metashape_cameras

        folder.mkdir()
        write_metashape_cameras(folder / "cameras.xml", metashape_from_block(block))
    elif kind == "metashape-psx":  # the same chunk as a Metashape project (NAME.psx + NAME.files)
        from test_metashape_io import psx_from_cameras_xml

        from skyrig.io.metashape import metashape_from_block, write_metashape_cameras

        folder.mkdir()
        write_metashape_cameras(root / "chunk.xml", metashape_from_block(block))
        psx_from_cameras_xml((root / "chunk.xml").read_text(), folder / "ring.psx", group=True)
        (root / "chunk.xml").unlink()
    else:
        from skyrig.io.pix4d import Pix4dCameras, write_pix4d_calibrated_cameras

        params = folder / "1_initial" / "params"
        params.mkdir(parents=True)
        cams = {c.name: c for c in block.cameras}
        pose = Pose(block.station_rotation, block.station_centre, "world", "camera")
        ids = np.array([block.cameras[c].name for c in block.image_camera])
        off = np.round(SHIFT)
        write_pix4d_calibrated_cameras(params / "ring_calibrated_camera_parameters.txt",
                                       Pix4dCameras(cams, block.image_name, ids, pose), off)
        (params / "ring_offset.xyz").write_text(" ".join(f"{v:.3f}" for v in off) + "\n")
        (params / "ring_wkt.prj").write_text(CRS + "\n")
    return folder


def _import(folder: Path, out: Path, *extra: str):
    from skyrig.cli import main

    r = CliRunner().invoke(main, ["import", "project", str(folder), "-o", str(out), *extra])
    assert "Traceback" not in r.output, r.output
    return r


@pytest.mark.parametrize("kind", ["colmap", "opensfm", "metashape", "metashape-psx", "pix4d"])
def test_project_folder_import_gives_back_the_truth(model, tmp_path, kind):
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.rig_file import read_rig

    folder = _write(kind, model, tmp_path)
    extra = () if kind == "pix4d" else ("--crs", CRS)  # Pix4D's _wkt.prj states it; the others were not georeferenced
    r = _import(folder, tmp_path / "out", *extra)
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    info = json.loads((out / "import.json").read_text())
    assert info["program"] == {"metashape": "metashape-xml"}.get(kind, kind) and info["images"] == 10
    assert (out / "manifest.json").is_file()  # published as a set
    eo = read_eo_csv(out / "eo.csv")
    if eo.frame.kind == "map":
        assert eo.frame.crs == CRS
    order = [list(model.image_name).index(n) for n in eo.image]
    in_map = eo.to_frame(WorldFrame.map(CRS))
    np.testing.assert_allclose(in_map.centre, model.world_from_camera.translation[order], atol=2e-3)
    rig = read_rig(out / "cameras.yaml")
    assert set(rig.heads) == set(map(str, eo.camera))
    if kind == "pix4d":  # Pix4D's params hold no tie points
        assert not (out / "points.csv").exists() and "points.csv" not in info["written"]
        return
    pts = read_points_csv(out / "points.csv")
    meas = read_measurements_csv(out / "tie_points.csv")
    assert info["points"] == len(pts.name) == len(model.point_xyz) and info["measurements"] == len(meas.point)
    if pts.frame.kind == "map":  # every imported point is a true point
        d = np.linalg.norm(pts.xyz[:, None, :] - model.point_xyz[None, :, :], axis=2).min(axis=1)
        assert d.max() < 1e-3, d.max()
    # the imported points through the imported orientations and cameras land on the measurements: the noise
    idx = {str(n): k for k, n in enumerate(pts.name)}
    pose = eo.pose()
    res = []
    for i, name in enumerate(eo.image):
        sel = np.flatnonzero(meas.image == name)
        px = rig.heads[str(eo.camera[i])].camera.world_to_pixel(pose[i], pts.xyz[[idx[str(p)] for p in meas.point[sel]]])
        res.append(px - meas.pixel[sel])
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    assert 0.2 < rms < 0.4, rms


def test_what_is_not_one_project_is_refused(model, tmp_path):
    r = _import(tmp_path, tmp_path / "x")
    assert r.exit_code == 2 and "no project of another program found" in r.output, r.output
    _write("colmap", model, tmp_path / "two")
    _write("metashape", model, tmp_path / "two")
    r = _import(tmp_path / "two", tmp_path / "x", "--crs", CRS)
    assert r.exit_code == 2 and "2 projects found (colmap: colmap/sparse/0; metashape-xml: metashape/cameras.xml)" \
        in r.output, r.output
    r = _import(tmp_path / "two" / "colmap", tmp_path / "x")
    assert r.exit_code == 2 and "--crs" in r.output and not (tmp_path / "x").exists(), r.output


def test_detect_names_the_folder():
    from skyrig.io.project_import import detect_project

    with pytest.raises(InputFormatError, match="not a folder"):
        detect_project("/nonexistent/folder")
