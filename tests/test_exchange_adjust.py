"""A block taken out to other programs' formats and brought back adjusts to the same sigma0 (issue 33).

The block: 10 images of 5 cameras (OpenCV models) around 200 points, measurements with 0.3 px noise, control on 6
points (so that the Metashape markers carry references).  Out through COLMAP (binary), OpenSfM (reconstruction +
tracks) and Metashape (cameras XML with markers) and back, each adjusts (free camera poses and points, control
weighted) to the sigma0 of the original block to 1e-6 relative.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import SolverOptions, StatisticsOptions, Unknowns
from skyrig.camera.frame import FrameCamera
from skyrig.camera.opencv import OpenCVDistortion
from skyrig.io.colmap import block_from_colmap, colmap_from_block
from skyrig.io.colmap_folder import read_colmap, write_colmap
from skyrig.io.metashape import block_from_metashape, metashape_from_block, read_metashape_cameras, write_metashape_cameras
from skyrig.io.opensfm import (block_from_opensfm, opensfm_from_block, read_opensfm, read_opensfm_tracks,
                               write_opensfm, write_opensfm_tracks)
from test_colmap_io import _model

CONFIG = AdjustConfig(unknowns=Unknowns(datum="auto"), statistics=StatisticsOptions(compute=False),
                      solver=SolverOptions(max_iterations=20))


@pytest.fixture(scope="module")
def block():
    m = _model(seed=12, noise_px=0.3)
    # Metashape has no rational model: the fifth camera as a plain OpenCV one (measurements then fit it less well)
    m.cameras[7] = FrameCamera.from_pixels("e", 1280, 960, 1220.0, 644.4, 471.3,
                                           distortion=OpenCVDistortion(-0.1, 0.03, -0.0009, 0.0012, 0.004))
    b = block_from_colmap(m, sigma_px=0.3)
    ctrl = np.arange(0, 60, 10)
    return replace(b, control_point=ctrl, control_xyz=b.point_xyz[ctrl].copy(), control_sigma=0.01,
                   control_check=None)


@pytest.fixture(scope="module")
def sigma0(block):
    return _sigma0(block)


def _sigma0(b):
    r = adjust(b, CONFIG)
    return r.sigma0


def _with_control(b, ref):
    return replace(b, control_point=ref.control_point, control_xyz=ref.control_xyz, control_sigma=0.01,
                   control_check=None)


def test_same_sigma0_through_colmap_opensfm_metashape(block, sigma0, tmp_path):
    s0 = sigma0
    assert 0.5 < s0 < 2.0  # the measurements' noise at their sigma (the fifth camera a little off)
    write_colmap(tmp_path / "colmap", colmap_from_block(block))
    b1 = _with_control(block_from_colmap(read_colmap(tmp_path / "colmap"), sigma_px=0.3), block)
    rec = opensfm_from_block(block)
    write_opensfm(tmp_path / "reconstruction.json", rec)
    write_opensfm_tracks(tmp_path / "tracks.csv", rec)
    r2 = read_opensfm_tracks(tmp_path / "tracks.csv", read_opensfm(tmp_path / "reconstruction.json")[0])
    b2 = _with_control(block_from_opensfm(r2, sigma_px=0.3), block)
    write_metashape_cameras(tmp_path / "cameras.xml", metashape_from_block(block))
    b3 = block_from_metashape(read_metashape_cameras(tmp_path / "cameras.xml"), sigma_px=0.3, control_sigma_m=0.01)
    assert b3.control_point is not None and len(b3.control_point) == 6
    from test_metashape_io import psx_from_cameras_xml

    from skyrig.io.metashape import read_metashape_project

    psx = psx_from_cameras_xml((tmp_path / "cameras.xml").read_text(), tmp_path / "block.psx", group=True)
    b4 = block_from_metashape(read_metashape_project(psx), sigma_px=0.3, control_sigma_m=0.01)
    for b in (b1, b2, b3, b4):
        assert b.n_observations == block.n_observations
        assert _sigma0(b) == pytest.approx(s0, rel=1e-6)


@pytest.mark.slow
def test_cli_export_then_import_adjusts_the_same(block, sigma0, tmp_path):
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.io.block_file import read_block, write_block

    write_block(tmp_path / "block.json", block)
    s0 = sigma0
    run = CliRunner()
    for fmt, out in (("colmap", "model"), ("opensfm", "osfm/reconstruction.json"), ("metashape-xml", "cameras.xml")):
        r = run.invoke(main, ["export", fmt, str(tmp_path / "block.json"), "-o", str(tmp_path / out)])
        assert r.exit_code == 0, r.output
        r = run.invoke(main, ["import", fmt, str(tmp_path / out), "-o", str(tmp_path / f"{fmt}.json"),
                              "--sigma-px", "0.3"])
        assert r.exit_code == 0, r.output
        b = read_block(tmp_path / f"{fmt}.json").block
        if fmt != "metashape-xml":  # COLMAP and OpenSfM models carry no control: the block's is put back
            b = _with_control(b, block)
        assert b.n_observations == block.n_observations
        assert _sigma0(b) == pytest.approx(s0, rel=1e-6), fmt
    # MicMac's images are file names in its working directory: a name with a folder part is refused
    r = run.invoke(main, ["export", "micmac", str(tmp_path / "block.json"), "-o", str(tmp_path / "Ori-Out")])
    assert r.exit_code != 0 and "image_name" in r.output, r.output
    names = np.array([n.replace("/", "_") for n in block.image_name])
    write_block(tmp_path / "block.json", replace(block, image_name=names, station_name=names))
    # MicMac's radial model holds no OpenCV camera exactly: refused, or fitted with the residual printed
    r = run.invoke(main, ["export", "micmac", str(tmp_path / "block.json"), "-o", str(tmp_path / "Ori-Out")])
    assert r.exit_code != 0 and "--fit-cameras" in r.output, r.output
    r = run.invoke(main, ["export", "micmac", str(tmp_path / "block.json"), "-o", str(tmp_path / "Ori-Out"),
                          "--fit-cameras", "--max-residual-px", "1"])
    assert r.exit_code == 0 and len(list((tmp_path / "Ori-Out").glob("Orientation-*.xml"))) == 10, r.output
    assert "forward fit over the frame: RMS" in r.output
