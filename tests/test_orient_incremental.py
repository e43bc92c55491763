"""Orientation without GNSS (skyrig.orient.incremental, ``skyrig adjust-uav --no-gps``).

Simulated close-range set (:func:`skyrig.simulate.closerange.facade_set`): a façade with relief, 12 convergent
images in two rows (some rolled 90 deg), 0.5 px measurement noise, 1 % gross mismatches, a start camera with the focal
length 4 % off, no principal point offset and no distortion (the true camera has both).  The truth of the seeded
simulation is the independent answer; tolerances are the adjustment's own predicted precision (4 sigma) after the
datum (a rigid motion for the scale-bar datum, whose scale is estimated; nothing for control points).

Real set (slow): the 29 OpenSfM lund phone images without their GPS, oriented from the CLI, then compared with the
EXIF GPS after a similarity and with pycolmap's own reconstruction of the same images in the same run.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.camera.opencv import OpenCVDistortion
from skyrig.match.colmap_check import similarity_transform
from skyrig.orient.incremental import OrientConfig, OrientInput, orient_incremental
from skyrig.simulate.closerange import facade_set

SIGMA_PX = 0.5
BAR_SIGMA_M = 0.0005


def _set():
    return facade_set(seed=2, n_points=300, n_per_row=6, width_px=1000, sigma_px=SIGMA_PX)


def _start_camera(s):
    return s.camera.with_(focal_mm=s.camera.focal_mm * 1.04, ppx_mm=0.0, ppy_mm=0.0, distortion=OpenCVDistortion())


@pytest.fixture(scope="module")
def scale_bar_run():
    s = _set()
    rng = np.random.default_rng(7)
    idx = {n: k for k, n in enumerate(s.point_name)}
    inp = OrientInput(s.names, _start_camera(s), s.obs_point, s.obs_image, s.obs_pixel, s.point_name,
                      distance_track=np.array([[idx[a], idx[b]] for a, b in s.bars]),
                      distance_m=s.bar_length + rng.normal(0, BAR_SIGMA_M, len(s.bars)), distance_sigma_m=BAR_SIGMA_M)
    return s, orient_incremental(inp, OrientConfig(pixel_sigma_px=SIGMA_PX))


def test_scale_bar_set_oriented_within_predicted_precision(scale_bar_run):
    s, res = scale_bar_run
    assert res.oriented.all()
    assert res.summary["datum"]["kind"] == "scale-bar"
    # gross mismatches removed: reprojection RMS at the noise level (per axis 0.5 px -> 0.5 * sqrt(2) per point)
    assert res.summary["reprojection_rms_px"] < 1.15 * SIGMA_PX
    adj = res.adjustment
    assert adj.info.converged
    # rigid motion only (rotation + translation): the scale is what the scale bars must give
    _, Rr, _ = similarity_transform(res.centre, s.C)
    c0t, c0e = s.C.mean(axis=0), res.centre.mean(axis=0)
    d = (res.centre - c0e) @ Rr.T + c0t - s.C
    ps = adj.pose_sigma[:, :3]
    assert np.all(np.linalg.norm(d, axis=1) < 4 * np.linalg.norm(ps, axis=1)), \
        (np.linalg.norm(d, axis=1) / np.linalg.norm(ps, axis=1)).max()
    # scale: distance between the two farthest cameras against its predicted sigma
    D = np.linalg.norm(res.centre[:, None] - res.centre[None], axis=2)
    i, j = np.unravel_index(np.argmax(D), D.shape)
    cols = np.r_[adj.layout.pose[i, :3], adj.layout.pose[j, :3]]
    Q = adj.covariance.Qcc[np.ix_(cols, cols)] * adj.sigma0 ** 2
    u = (res.centre[i] - res.centre[j]) / D[i, j]
    sd = float(np.sqrt(np.r_[u, -u] @ Q @ np.r_[u, -u]))
    true = float(np.linalg.norm(s.C[i] - s.C[j]))
    assert abs(D[i, j] - true) < 4 * sd, (D[i, j] - true, sd)
    assert sd < 0.01 * true  # the scale bars determine the scale (to better than 1 %)
    # self-calibration recovered the camera
    sr = adj.sigma_reduced()
    name = res.camera.name
    assert abs(res.camera.focal_mm - s.camera.focal_mm) < 4 * sr[("intrinsics", name, "focal_mm")] * adj.sigma0
    assert abs(res.camera.distortion.k1 - s.camera.distortion.k1) < 4 * sr[("intrinsics", name, "k1")] * adj.sigma0


def test_seed_pair_has_parallax(scale_bar_run):
    _, res = scale_bar_run
    seed = res.summary["seed"]
    assert seed["median_intersection_angle_deg"] > 4.0
    assert seed["inliers"] >= 100


def _write_project(tmp_path, s, n_control=6):
    from skyrig.georef.observations import ImageMeasurements
    from skyrig.io.points_csv import write_measurements_csv
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.rig import Head, Rig

    proj = tmp_path / "facade"
    (proj / "match").mkdir(parents=True)
    write_measurements_csv(proj / "match" / "tie_points.csv",
                           ImageMeasurements(s.point_name[s.obs_point], s.names[s.obs_image], s.obs_pixel))
    write_rig(Rig("start", {"camera": Head("camera", _start_camera(s))}), proj / "camera.yaml")
    idx = {n: k for k, n in enumerate(s.point_name)}
    rows = "".join(f"{n},{s.X[idx[n]][0]:.4f},{s.X[idx[n]][1]:.4f},{s.X[idx[n]][2]:.4f}\n" for n in s.target_names)
    lines = rows.splitlines(keepends=True)
    head = "# crs: local 48.85 2.35 35.0\nname,x,y,z\n"
    (proj / "gcp.csv").write_text(head + "".join(lines[:n_control]))
    (proj / "check.csv").write_text(head + "".join(lines[n_control:]))
    (proj / "bars.csv").write_text("from,to,length_m,sigma_m\n" + "".join(
        f"{a},{b},{v:.4f},{BAR_SIGMA_M}\n" for (a, b), v in zip(s.bars, s.bar_length)))
    return proj


def test_cli_control_points_end_to_end(tmp_path):
    """``skyrig adjust-uav --no-gps --control --check --camera``: outputs in the control points' frame, centres and
    check points against the truth within the predicted precision."""
    from skyrig.cli import main
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_points_csv

    s = _set()
    proj = _write_project(tmp_path, s)
    r = CliRunner().invoke(main, ["adjust-uav", str(proj), "--no-gps", "--camera", str(proj / "camera.yaml"),
                                  "--control", str(proj / "gcp.csv"), "--control-sigma", "0.002",
                                  "--check", str(proj / "check.csv")])
    assert r.exit_code == 0, r.output
    out = proj / "adjust-uav"
    for f in ("eo.csv", "points.csv", "report.json", "report.html", "camera.yaml", "manifest.json"):
        assert (out / f).is_file(), f
    rep = json.loads((out / "report.json").read_text())
    assert rep["uav"]["datum"]["kind"] == "control"
    eo = read_eo_csv(out / "eo.csv")
    k = [list(s.names).index(n) for n in eo.image]
    # the EO is in the control points' frame (local ENU at the given origin): compare with the truth directly
    sig = np.array([rep["uav"]["centre_sigma_m"][str(n)] for n in eo.image])
    d = eo.centre - s.C[k]
    assert np.all(np.linalg.norm(d, axis=1) < 4 * np.linalg.norm(sig, axis=1)), \
        (np.linalg.norm(d, axis=1) / np.linalg.norm(sig, axis=1)).max()
    pts = read_points_csv(out / "points.csv")
    idx = {n: q for q, n in enumerate(pts.name)}
    checks = [n for n in s.target_names[6:] if n in idx]
    assert len(checks) >= 3
    tidx = {n: q for q, n in enumerate(s.point_name)}
    import csv

    with open(out / "points.csv") as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    for n in checks:
        dv = pts.xyz[idx[n]] - s.X[tidx[n]]
        sv = np.array([float(rows[n][c]) for c in ("sx", "sy", "sz")])
        assert np.linalg.norm(dv) < 4 * np.linalg.norm(sv), (n, dv, sv)


def test_cli_bad_scale_bar_file_names_line_and_field(tmp_path):
    from skyrig.cli import main

    s = _set()
    proj = _write_project(tmp_path, s)
    (proj / "bars.csv").write_text("from,to,length_m\nbar1a,bar1b,2.0\nbar2a,bar2b,-1\n")
    r = CliRunner().invoke(main, ["adjust-uav", str(proj), "--camera", str(proj / "camera.yaml"),
                                  "--scale-bar", str(proj / "bars.csv")])
    assert r.exit_code == 2, r.output
    assert "bars.csv" in r.output and "line 3" in r.output and "length_m" in r.output, r.output


def test_positions_datum_places_the_block_without_bending_it():
    """Approximate positions (GPS-like, 1 m noise) place the block by a similarity only: the orientation stays as
    good as the images make it (centres after a similarity onto the truth within 4 predicted sigma), and the
    similarity's residuals are the position noise (not absorbed by the block)."""
    s = _set()
    rng = np.random.default_rng(11)
    noisy = s.C + rng.normal(0, 1.0, s.C.shape)
    inp = OrientInput(s.names, _start_camera(s), s.obs_point, s.obs_image, s.obs_pixel, s.point_name,
                      positions=noisy)
    res = orient_incremental(inp, OrientConfig(pixel_sigma_px=SIGMA_PX))
    d = res.summary["datum"]
    assert d["kind"] == "positions"
    # 12 images, 7 similarity parameters: E[RMS^2] = 3 (12 - 7/3) / 12 sigma^2 -> about 1.55 m for sigma 1 m
    assert 0.8 < d["positions_similarity_rms_3d_m"] < 2.4, d
    sc, Rs, ts = similarity_transform(res.centre, s.C)
    dd = sc * res.centre @ Rs.T + ts - s.C
    ps = res.adjustment.pose_sigma[:, :3] * sc
    assert np.all(np.linalg.norm(dd, axis=1) < 4 * np.linalg.norm(ps, axis=1)), \
        (np.linalg.norm(dd, axis=1) / np.linalg.norm(ps, axis=1)).max()
    # and the block is near the truth's frame (within the noise of a 12-point similarity)
    assert np.sqrt(np.mean(np.sum((res.centre - s.C) ** 2, axis=1))) < 2.0


@pytest.fixture(scope="module")
def free_run():
    s = _set()
    inp = OrientInput(s.names, _start_camera(s), s.obs_point, s.obs_image, s.obs_pixel, s.point_name)
    return s, orient_incremental(inp, OrientConfig(pixel_sigma_px=SIGMA_PX))


def test_free_network_is_the_truth_up_to_a_similarity(free_run):
    """No control, no scale bar, no positions: inner constraints; the block equals the truth up to a similarity,
    within 4 predicted sigma (scaled by the similarity's scale)."""
    s, res = free_run
    assert res.summary["datum"]["kind"] == "free" and res.oriented.all()
    sc, Rs, ts = similarity_transform(res.centre, s.C)
    d = sc * res.centre @ Rs.T + ts - s.C
    ps = res.adjustment.pose_sigma[:, :3] * sc
    assert np.all(np.linalg.norm(d, axis=1) < 4 * np.linalg.norm(ps, axis=1)), \
        (np.linalg.norm(d, axis=1) / np.linalg.norm(ps, axis=1)).max()


def test_pycolmap_on_the_same_tracks_agrees_within_predicted_precision(free_run, tmp_path):
    """COLMAP's incremental mapper (pycolmap) on exactly the same measurements, from the same start camera
    (:func:`skyrig.orient.reference.pycolmap_from_tracks`): a peer orientation of the same information.  Both
    register every image; pycolmap's centres are the truth up to a similarity within 4 of skyrig's predicted sigma,
    and the two orientations agree within 4 sqrt(2) sigma (each has its own error of that size)."""
    pytest.importorskip("pycolmap")
    from skyrig.orient.reference import pycolmap_from_tracks

    s, res = free_run
    peer = pycolmap_from_tracks(s.names, _start_camera(s), s.obs_point, s.obs_image, s.obs_pixel, tmp_path)
    assert peer is not None and len(peer.names) == len(s.names), None if peer is None else peer.summary
    k = [list(s.names).index(n) for n in peer.names]
    ps = np.linalg.norm(res.adjustment.pose_sigma[:, :3], axis=1)[k]  # skyrig's block holds all images, input order
    sc, Rs, ts = similarity_transform(res.centre[k], s.C[k])
    sp, Rp, tp = similarity_transform(peer.C, s.C[k])
    zp = np.linalg.norm(sp * peer.C @ Rp.T + tp - s.C[k], axis=1) / (ps * sc)
    assert np.all(zp < 4), zp.max()
    s2, R2, t2 = similarity_transform(peer.C, res.centre[k])
    zd = np.linalg.norm(s2 * peer.C @ R2.T + t2 - res.centre[k], axis=1) / (np.sqrt(2.0) * ps)
    assert np.all(zd < 4), zd.max()
    # relative rotations (image 0 to each, free of the datum) agree within 4 sqrt(2) x their predicted sigma
    # (sigma of a relative rotation <= |sigma_0| + |sigma_i|: correlations only make it smaller)
    rs = np.linalg.norm(res.adjustment.pose_sigma[:, 3:], axis=1)[k]
    ours = np.einsum("ji,njk->nik", res.rotation[k][0], res.rotation[k])
    theirs = np.einsum("ji,njk->nik", peer.R[0], peer.R)
    dR = np.einsum("nji,njk->nik", ours, theirs)
    ang = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert np.all(ang[1:] < 4 * np.sqrt(2.0) * (rs[0] + rs[1:])), np.degrees(ang)
    # and COLMAP's self-calibrated focal length (start 4 % off) is the true one within 4 x skyrig's predicted sigma
    adj = res.adjustment
    sf = adj.sigma_reduced()[("intrinsics", res.camera.name, "focal_mm")] * adj.sigma0 / res.camera.pixel_size_mm
    assert abs(peer.focal_px - s.camera.focal_px) < 4 * sf, (peer.focal_px, sf)


def test_compare_on_same_tracks_report(free_run, tmp_path):
    """The report-level comparison (what ``adjust-uav --compare-pycolmap`` gives a set without images): every image
    registered and compared, the centre differences' RMS within 4 sqrt(2) x the RMS predicted sigma."""
    pytest.importorskip("pycolmap")
    from skyrig.orient.reference import compare_on_same_tracks

    s, res = free_run
    inp = OrientInput(s.names, _start_camera(s), s.obs_point, s.obs_image, s.obs_pixel, s.point_name)
    rep = compare_on_same_tracks(res, inp, tmp_path)
    assert rep["registered"] == len(s.names) and rep["centre_differences"]["common"] == len(s.names), rep
    sig = np.sqrt(np.mean(np.sum(res.adjustment.pose_sigma[:, :3] ** 2, axis=1)))
    assert rep["centre_differences"]["rms_m"] < 4 * np.sqrt(2.0) * sig, (rep["centre_differences"]["rms_m"], sig)


# ---------------------------------------------------------------------------------------------- real data
@pytest.mark.slow
def test_lund_without_gps_from_the_cli_against_gps_and_pycolmap(tmp_path):
    """The 29 lund phone images: tie points from exhaustive pairs (nothing of the GPS used), oriented from the CLI
    without GNSS; the EXIF GPS only places the block by a similarity.  Checks: every image oriented, the similarity's
    residuals at the level of a phone's GPS (metres), and pycolmap's own reconstruction of the same images in the
    same run agreeing with ours after a similarity far better than the GPS does.  Full-size figures:
    ``bench/orient_lund.py``."""
    from conftest import shared_path

    pytest.importorskip("pycolmap")
    from skyrig.cli import main
    from skyrig.match.features import FeatureConfig
    from skyrig.match.matching import MatchConfig
    from skyrig.pipeline.match import match_images

    src = shared_path("opensfm", "lund", "images")
    # full size (1024 px): at 640 px / 2000 features the walk's tie points thin out after image 15 (15 of 29
    # oriented; 1711 tie points against 2625 at 1024 px)
    size = 1024
    match_images([src], tmp_path / "match", FeatureConfig(method="pycolmap", max_size=size, max_features=4000),
                 MatchConfig(matcher="bruteforce"), pair_mode="exhaustive")
    r = CliRunner().invoke(main, ["adjust-uav", str(tmp_path), "--images", str(src), "--match", str(tmp_path / "match"),
                                  "--no-gps", "--datum", "gps-similarity", "--compare-pycolmap", "--pycolmap-size",
                                  str(size), "-o", str(tmp_path / "orient")])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "orient" / "report.json").read_text())
    s = rep["uav"]
    # the walk's last images connect to the rest by few triangulated points (25.jpg and 29.jpg see 8-18 of them):
    # they are tied in by their relative orientation to the previous image; all 29 at 1024 px (COLMAP's incremental
    # mapper on its own matches: 27-29, varying between runs)
    assert s["oriented"] >= 27, s["not_oriented"]
    d = s["datum"]
    # a phone's GPS: a few metres; a wrongly oriented image or a bent block would be tens of metres off
    assert d["positions_similarity_rms_3d_m"] < LUND_GPS_RMS_MAX_M, d
    # within the GPS's stated accuracy: EXIF GPSDOP (5 m, 10 m for the first two images; metres as OpenSfM reads
    # it) with our predicted centre sigma in quadrature (decimetres: the GPS dominates); at 1024 px the normalised
    # residuals' RMS is 0.89, max 1.91
    from PIL import Image

    sig_ours = {n: float(np.linalg.norm(v)) for n, v in s["centre_sigma_m"].items()}
    z = []
    for n, v in d["per_image_m"].items():
        with Image.open(src / n) as im:
            dop = float(im.getexif().get_ifd(0x8825)[11])
        z.append(v / np.hypot(dop, sig_ours[n]))
    z = np.array(z)
    assert np.sqrt(np.mean(z ** 2)) < 1.5 and z.max() < 3.0, z
    pc = rep["pycolmap"]
    assert pc["registered"] >= 15, pc
    c = pc["centre_differences"]
    # every image pycolmap registers is oriented by skyrig too
    assert c["common"] == pc["registered"], (c["common"], pc["registered"], s["not_oriented"])
    # the two reconstructions agree within their precision: 3 x the RMS predicted sigma of our centres, x sqrt(2)
    # for pycolmap's own error of the same size (1024 px: 0.38 m RMS against 0.19 m predicted), and far better than
    # either agrees with the GPS
    sig = np.array(list(s["centre_sigma_m"].values()))
    tol = 3.0 * np.sqrt(2.0) * float(np.sqrt(np.mean(np.sum(sig ** 2, axis=1))))
    assert c["rms_m"] < tol, (c["rms_m"], tol)
    assert c["rms_m"] < 0.25 * d["positions_similarity_rms_3d_m"], (c, d["positions_similarity_rms_3d_m"])


LUND_GPS_RMS_MAX_M = 8.0


def test_cli_scale_bar_writes_model_frame_tables(tmp_path):
    """``--scale-bar`` without control: plain EO / points tables in the arbitrary model frame (saying so), in metres:
    camera-to-camera distances as the truth's within 4 predicted sigma (sigma of a distance <= |sigma_i| + |sigma_j|)."""
    import csv

    from skyrig.cli import main

    s = _set()
    proj = _write_project(tmp_path, s)
    r = CliRunner().invoke(main, ["adjust-uav", str(proj), "--camera", str(proj / "camera.yaml"),
                                  "--scale-bar", str(proj / "bars.csv"), "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    for f in ("eo.csv", "points.csv", "report.json", "camera.yaml", "manifest.json"):
        assert (out / f).is_file(), f
    text = (out / "eo.csv").read_text()
    assert text.startswith("# frame: skyrig model frame") and "scale bars" in text.splitlines()[0]
    rows = list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))
    k = [list(s.names).index(r["image"]) for r in rows]
    C = np.array([[float(r[c]) for c in "xyz"] for r in rows])
    sig = np.array([[float(r[c]) for c in ("sx", "sy", "sz")] for r in rows])
    D = np.linalg.norm(C[:, None] - C[None], axis=2)
    Dt = np.linalg.norm(s.C[k][:, None] - s.C[k][None], axis=2)
    sd = np.linalg.norm(sig, axis=1)
    tol = 4 * (sd[:, None] + sd[None])
    assert np.all(np.abs(D - Dt) < tol + 1e-9), np.max(np.abs(D - Dt) / (tol + 1e-9))


def _weakly_tied(s, k: int, o: int, keep: int = 8, pair: int = 70, seed: int = 3):
    """The set with image ``k`` tied to the block as a walk turning a corner: of the tracks ``k`` shares with ``o``,
    ``keep`` stay as they are and ``pair`` are kept only in ``k`` and ``o`` (two-view tracks, which no oriented image
    but ``o`` sees); ``k``'s other observations are dropped.  ``k`` has too few triangulated points for a resection
    but enough tie points with ``o`` for a relative orientation (fewer than the best pairs: not a start pair)."""
    rng = np.random.default_rng(seed)
    tk = np.unique(s.obs_point[s.obs_image == k])
    to = np.unique(s.obs_point[s.obs_image == o])
    both = rng.permutation(np.intersect1d(tk, to))
    stay, weak = both[:keep], both[keep:keep + pair]
    drop = (np.isin(s.obs_point, weak) & ~np.isin(s.obs_image, [k, o])) | (
        (s.obs_image == k) & ~np.isin(s.obs_point, np.r_[stay, weak]))
    m = ~drop
    return s.obs_point[m], s.obs_image[m], s.obs_pixel[m]


def test_weakly_tied_image_oriented_by_relative_orientation():
    """An image sharing only 8 triangulated points with the block (fewer than a resection needs) but many tie points
    with one oriented image is oriented through the relative orientation of that pair (rotation and base direction
    from the essential matrix, base length from the 8 points); the block is the truth up to a similarity within 4
    predicted sigma, that image included."""
    s = _set()
    k, o = 11, 10  # last image of the upper row and its neighbour
    ot, oi, op = _weakly_tied(s, k, o)
    inp = OrientInput(s.names, _start_camera(s), ot, oi, op, s.point_name)
    res = orient_incremental(inp, OrientConfig(pixel_sigma_px=SIGMA_PX))
    assert res.oriented.all()
    assert res.summary["relative_tie_ins"] >= 1
    assert "relative orientation" in res.attitude_check[str(s.names[k])]["orientation"], res.attitude_check
    sc, Rs, ts = similarity_transform(res.centre, s.C)
    d = sc * res.centre @ Rs.T + ts - s.C
    ps = res.adjustment.pose_sigma[:, :3] * sc
    z = np.linalg.norm(d, axis=1) / np.linalg.norm(ps, axis=1)
    assert np.all(z < 4), z.max()
