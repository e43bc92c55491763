"""Image reading (8/16 bit, EXIF GPS, DJI XMP), the resumable match store, bad input and the CLI."""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from conftest import shared_path
from skyrig.errors import InputFormatError
from skyrig.io.image_read import (
    camera_from_metadata, orientations_from_metadata, read_image, read_image_metadata,
)
from skyrig.match.features import FeatureConfig

LUND = "opensfm/lund/images"
BRIGHTON = "brighton-uav"


def test_8_and_16_bit_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    a16 = rng.integers(0, 65535, (40, 60), dtype=np.uint16)
    a8 = rng.integers(0, 255, (40, 60, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), a16)
    cv2.imwrite(str(tmp_path / "a.tif"), a16)
    cv2.imwrite(str(tmp_path / "b.png"), a8[..., ::-1])  # cv2 writes BGR
    for f in ("a.png", "a.tif"):
        got = read_image(tmp_path / f)
        assert got.dtype == np.uint16 and np.array_equal(got, a16)
        assert read_image_metadata(tmp_path / f).bits == 16
    assert np.array_equal(read_image(tmp_path / "b.png", gray=False), a8)
    small = read_image(tmp_path / "a.png", max_size=30)
    assert small.shape == (20, 30)


def test_lund_exif_gps_matches_mapillary_json():
    folder = shared_path(LUND)
    m = read_image_metadata(folder / "01.jpg")
    # independent source: the Mapillary app wrote the position again into the JSON ImageDescription
    from PIL import Image

    desc = json.loads(Image.open(folder / "01.jpg").getexif()[270])
    assert m.lat_deg == pytest.approx(float(desc["MAPLatitude"]), abs=2e-6)
    assert m.lon_deg == pytest.approx(float(desc["MAPLongitude"]), abs=2e-6)
    assert m.heading_deg == pytest.approx(desc["MAPCompassHeading"]["TrueHeading"])
    assert (m.width, m.height) == (1024, 768) and m.gimbal_ypr_deg is None


def test_brighton_exif_and_dji_xmp():
    folder = shared_path(BRIGHTON)
    m = read_image_metadata(folder / "DJI_0018.JPG")
    assert (m.width, m.height) == (4000, 2250) and m.model == "FC300S"
    # EXIF GPSAltitude and the XMP AbsoluteAltitude are written separately by the drone: they must agree
    assert m.alt_m == pytest.approx(float(m.xmp["drone-dji:AbsoluteAltitude"]), abs=0.01)
    assert m.gimbal_ypr_deg == (45.0, -89.9, 0.0) and m.flight_ypr_deg == (46.0, 1.8, 3.0)
    assert m.lon_deg < 0 and 46 < m.lat_deg < 47  # W longitude sign applied
    # 20 mm equivalent on a 36 mm frame: f = 20/36 * 4000 px
    assert camera_from_metadata(m).focal_px == pytest.approx(20 / 36 * 4000, rel=1e-9)
    o = orientations_from_metadata([read_image_metadata(p) for p in sorted(folder.glob("*.JPG"))[:3]])
    # gimbal pitch -89.9: camera looks down; image top (camera +y) towards the gimbal yaw (45 deg: north-east)
    R = o.eo.rotation[0]
    assert -R[2, 2] == pytest.approx(-np.cos(np.radians(0.1)), abs=1e-6)
    assert np.degrees(np.arctan2(R[0, 1], R[1, 1])) == pytest.approx(45.0, abs=0.2)
    assert o.ground_height == pytest.approx(o.eo.centre[0, 2] - 39.8, abs=1.0)


def _lund_subset(tmp_path, names=("01.jpg", "02.jpg", "03.jpg")):
    folder = shared_path(LUND)
    d = tmp_path / "images"
    d.mkdir()
    for n in names:
        shutil.copy(folder / n, d / n)
    return d


FAST = FeatureConfig(method="opencv", max_size=512, max_features=1500)


def test_unreadable_image_is_skipped_with_reason(tmp_path, caplog):
    from skyrig.cli.match import match_images

    d = _lund_subset(tmp_path)
    (d / "broken.jpg").write_bytes(b"this is not a jpeg")
    r = match_images([d], tmp_path / "out", FAST, pair_mode="exhaustive")
    assert "broken.jpg" in r.skipped and "not a readable image" in r.skipped["broken.jpg"]
    assert "broken.jpg" in caplog.text
    assert r.names == ["01.jpg", "02.jpg", "03.jpg"]
    assert json.loads((tmp_path / "out" / "report.json").read_text())["skipped_images"]["broken.jpg"]


def test_duplicate_name_across_folders_is_an_error(tmp_path):
    from skyrig.cli.match import collect_images

    d1 = _lund_subset(tmp_path)
    d2 = tmp_path / "head2"
    d2.mkdir()
    shutil.copy(d1 / "01.jpg", d2 / "01.jpg")
    with pytest.raises(InputFormatError, match="duplicate image name '01.jpg'"):
        collect_images([d1, d2])


def test_missing_gps_is_reported(tmp_path):
    from skyrig.cli.match import match_images

    d = tmp_path / "images"
    d.mkdir()
    img = read_image(shared_path(LUND) / "01.jpg")
    for n in ("a.png", "b.png"):
        cv2.imwrite(str(d / n), img)  # PNG: pixels without EXIF
    with pytest.raises(InputFormatError, match="GPSLatitude"):
        match_images([d], tmp_path / "out", FAST, pair_mode="gps")


def test_interrupted_run_keeps_what_was_matched(tmp_path):
    from skyrig.cli.match import match_images

    from skyrig.match.matching import MatchConfig

    d = _lund_subset(tmp_path)
    out = tmp_path / "out"
    exact = MatchConfig(matcher="bruteforce")  # deterministic (FLANN's kd-trees are randomised)
    r1 = match_images([d], out, FAST, exact, pair_mode="exhaustive")
    files = sorted((out / "matches").glob("*.npz")) + sorted((out / "features").glob("*.npz"))
    assert len(files) == 3 + 3
    # simulate an interruption: one pair's result and one image's features never got written
    lost = [out / "matches" / "02.jpg__03.jpg.npz", out / "features" / "03.jpg.npz"]
    for f in lost:
        f.unlink()
    stamp = {f: f.stat().st_mtime_ns for f in files if f not in lost}
    r2 = match_images([d], out, FAST, exact, pair_mode="exhaustive")
    for f, t in stamp.items():
        assert f.stat().st_mtime_ns == t, f"{f.name} was recomputed"
    assert all(f.exists() for f in lost)
    assert r2.report["n_tracks"] == r1.report["n_tracks"]
    assert not list(out.rglob("*.tmp*"))
    # changed settings are refused rather than silently mixed
    with pytest.raises(InputFormatError, match="other settings"):
        match_images([d], out, FeatureConfig(method="opencv", max_size=400), exact, pair_mode="exhaustive")


def test_cli_match(tmp_path):
    from skyrig.cli.match import command
    from skyrig.io.points_csv import read_measurements_csv

    proj = tmp_path / "proj"
    proj.mkdir()
    _lund_subset(proj, ("01.jpg", "02.jpg", "03.jpg", "04.jpg"))
    res = CliRunner().invoke(command, [str(proj), "--method", "opencv", "--max-size", "512",
                                       "--max-features", "1500", "--scheduler", "sync", "--lsm", "--thin", "4"])
    assert res.exit_code == 0, res.output
    assert "pairs matched (gps)" in res.output
    m = read_measurements_csv(proj / "match" / "tie_points.csv")
    assert set(m.image) == {"01.jpg", "02.jpg", "03.jpg", "04.jpg"}
    assert (proj / "match" / "coverage.png").stat().st_size > 0
    assert np.all((m.pixel >= -0.5) & (m.pixel <= [1023.5, 767.5]))
    rep = json.loads((proj / "match" / "report.json").read_text())
    assert rep["lsm_refined_fraction"] > 0.5
    assert rep["n_tracks"] <= rep["n_tracks_before_thinning"]


def test_match_tasks_carry_their_pair_only(tmp_path, monkeypatch):
    """Each pair's task is pickled on its own for worker processes / a cluster: it must carry its two images'
    names, cameras and poses, not the block's lists (those made the submitting process's memory grow as images x
    pairs: 4.4 GB at 540 images).  Independent yardstick: the pickled task of a pair is the same size in a block
    of 3 images and in one of 5."""
    import pickle

    import skyrig.pipeline.match as pm

    sizes: dict[int, int] = {}
    real = pm._run_dask

    def capture(tasks, scheduler, workers, progress):
        if tasks and tasks[0].fn is pm._match_one:
            sizes[n] = max(len(pickle.dumps(t)) for t in tasks)
        return real(tasks, scheduler, workers, progress)

    monkeypatch.setattr(pm, "_run_dask", capture)
    for n, names in ((3, ("01.jpg", "02.jpg", "03.jpg")), (5, ("01.jpg", "02.jpg", "03.jpg", "04.jpg", "05.jpg"))):
        (tmp_path / str(n)).mkdir()
        d = _lund_subset(tmp_path / str(n), names)
        pm.match_images([d], tmp_path / str(n) / "out", FAST, pair_mode="exhaustive", scheduler="sync")
    assert sizes[3] == sizes[5]
