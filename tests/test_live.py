"""skyrig live (issue 35): XYZ tiles, image completeness, bad input in a live run, the live page (headless
Chromium), and - slow - the rate replay of a simulated 3K flight against the batch answer."""

from __future__ import annotations

import json
import math
import shutil
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from skyrig.io import xyz_tiles


# --------------------------------------------------------------------------------------------- tiles
def test_tile_grid_against_proj():
    """Tile edges are Web Mercator's (PROJ's EPSG:3857 of longitude +-180), a point lies in the tile computed for
    it, and the zoom matches the cell."""
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    edge, _ = tr.transform(180.0, 0.0)
    assert xyz_tiles.tile_bounds(0, 0, 0)[2] == pytest.approx(edge, abs=1e-6)
    lon, lat = 9.7320, 52.3759
    x, y = tr.transform(lon, lat)
    for z in (3, 12, 17):
        tx, ty, tx1, ty1 = xyz_tiles.tile_range(z, (x, y, x, y))
        assert (tx, ty) == (tx1, ty1)
        b = xyz_tiles.tile_bounds(z, tx, ty)
        assert b[0] <= x < b[2] and b[1] <= y < b[3]
    # the OSM wiki's formula for the tile of a lon/lat, an independent statement of the scheme
    n = 2 ** 16
    osm = (int((lon + 180) / 360 * n), int((1 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2 * n))
    assert xyz_tiles.tile_range(16, (x, y, x, y))[:2] == osm
    ground16 = 2 * math.pi * 6378137 * math.cos(math.radians(lat)) / 256 / 2 ** 16
    assert xyz_tiles.zoom_for_cell(ground16, lat) == 16
    assert xyz_tiles.zoom_for_cell(ground16 * 1.3, lat) == 16 and xyz_tiles.zoom_for_cell(ground16 * 1.5, lat) == 15


def test_paint_places_and_composites(tmp_path):
    """A square painted in UTM lands where PROJ puts it in the tiles, a second painting goes on top only where
    it has data, and no temporary file is left."""
    from pyproj import Transformer

    crs = "EPSG:25832"
    x0, y0, cell = 550000.0, 5803000.0, 2.0
    red = np.zeros((100, 100, 4), np.uint8)
    red[..., 0], red[..., 3] = 255, 255
    t = (cell, 0.0, x0, 0.0, -cell, y0)
    written = xyz_tiles.paint(tmp_path, "ortho", red, t, crs, [15])
    assert written
    blue = np.zeros((100, 100, 4), np.uint8)
    blue[:50, :, 2], blue[:50, :, 3] = 255, 255  # northern half only
    xyz_tiles.paint(tmp_path, "ortho", blue, t, crs, [15])
    tr = Transformer.from_crs(crs, "EPSG:3857", always_xy=True)

    def colour(e, n):
        mx, my = tr.transform(e, n)
        tx, ty, _, _ = xyz_tiles.tile_range(15, (mx, my, mx, my))
        b = xyz_tiles.tile_bounds(15, tx, ty)
        tile = xyz_tiles.read_tile(tmp_path / "ortho" / "15" / str(tx) / f"{ty}.png")
        c = int((mx - b[0]) / (b[2] - b[0]) * 256)
        r = int((b[3] - my) / (b[3] - b[1]) * 256)
        return tile[r, c]

    assert list(colour(x0 + 100, y0 - 150)) == [255, 0, 0, 255]  # southern half: red stays
    assert list(colour(x0 + 100, y0 - 40)) == [0, 0, 255, 255]  # northern half: blue on top
    assert not list(tmp_path.rglob("*.tmp")) and not [p for p in tmp_path.rglob("*") if p.name.startswith(".")]


def test_image_complete(tmp_path):
    from skyrig.pipeline.live import image_complete

    img = (np.random.default_rng(1).random((40, 60, 3)) * 255).astype(np.uint8)
    for ext, why in ((".png", "truncated PNG"), (".jpg", "truncated JPEG")):
        p = tmp_path / f"a{ext}"
        cv2.imwrite(str(p), img)
        assert image_complete(p) == (True, "")
        data = p.read_bytes()
        p.write_bytes(data[: len(data) // 2])
        ok, msg = image_complete(p)
        assert not ok and why in msg
    (tmp_path / "e.png").write_bytes(b"")
    assert image_complete(tmp_path / "e.png") == (False, "empty file")


# --------------------------------------------------------------------------------------------- live run
@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A short simulated 3K flight (two strips of 3 exposures, 640-pixel images)."""
    from skyrig.pipeline.live_check import simulate_3k_flight

    d = tmp_path_factory.mktemp("flight3k")
    info = simulate_3k_flight(d, half_length_m=100.0, workers=1)
    assert info["exposures"] >= 4
    return d


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines(keepends=True)


def test_bad_input_said_once_and_run_goes_on(flight, tmp_path):
    """An image that never completes, an event without an image and a trajectory that stops: one line each, the
    other exposures processed, every tile served whole."""
    from skyrig.pipeline.live import LiveConfig, LiveRun

    w = tmp_path / "watched"
    (w / "images").mkdir(parents=True)
    shutil.copyfile(flight / "rig.yaml", w / "rig.yaml")
    ev = _lines(flight / "events.csv")
    head = [ln for ln in ev if ln.startswith("#") or ln.startswith("image,")]
    rows = [ln for ln in ev if ln not in head and ",right," not in ln]  # two heads of three: a faster test
    times = sorted({float(r.split(",")[1]) for r in rows})
    t_stop = 0.5 * (times[2] + times[3])  # the trajectory stops between the third and fourth exposure
    tr = _lines(flight / "trajectory.csv")
    th = [ln for ln in tr if ln.startswith("#") or ln.startswith("time,")]
    (w / "trajectory.csv").write_text("".join(th + [ln for ln in tr if ln not in th and float(ln.split(",")[0]) <= t_stop]))
    first3 = [r for r in rows if float(r.split(",")[1]) <= times[3]]
    (w / "events.csv").write_text("".join(head + first3))
    names = [r.split(",")[0] for r in first3]
    truncated = next(n for n in names if "e0002_nadir" in n)
    missing = next(n for n in names if "e0003_left" in n)
    for n in names:
        data = (flight / "images" / n).read_bytes()
        if n == missing:
            continue
        (w / "images" / n).write_bytes(data[: len(data) // 2] if n == truncated else data)
    said: list[str] = []
    run = LiveRun(w, None, LiveConfig(crs="EPSG:25832", surface_height_m=80.0, window=0, dsm=False, settle_s=0.0,
                                      image_timeout_s=0.5, trajectory_timeout_s=0.5, poll_s=0.05), say=said.append)
    t0 = time.time()
    while time.time() - t0 < 60.0 and (not run.exposures or any(x.state == "waiting" for x in run.exposures.values())):
        run.poll()
        time.sleep(0.05)
    s = run.finish()
    assert sum(truncated in ln and "never completed" in ln and "truncated PNG" in ln for ln in said) == 1, said
    assert sum(missing in ln and "event without an image" in ln for ln in said) == 1, said
    assert sum("trajectory stopped" in ln and "exposure 4" in ln for ln in said) == 1, said
    assert len(said) == 3, said
    assert s["exposures_done"] == 3 and s["exposures_skipped"] == 1
    done = {r["exposure"]: r for r in map(json.loads, (run.out / "latency.jsonl").read_text().splitlines())}
    assert set(done) == {1, 2, 3}
    tiles = list((run.out / "tiles" / "ortho").rglob("*.png"))
    assert tiles and all(xyz_tiles.read_tile(p) is not None for p in tiles)
    assert not [p for p in (run.out / "tiles").rglob("*") if p.is_file() and p.suffix != ".png"]


def test_live_page_in_headless_chromium(flight, tmp_path):
    """The page (vendored Leaflet) shows the tiles the run wrote and the exposure count; no token, no tile."""
    from test_measure_web import _browser

    from skyrig.pipeline.live import LiveConfig, LiveRun
    from skyrig.web.live import LiveServer

    w = tmp_path / "w"
    shutil.copytree(flight, w, ignore=shutil.ignore_patterns("truth", "scene", "gcp", "plan.gpkg"))
    run = LiveRun(w, None, LiveConfig(crs="EPSG:25832", surface_height_m=80.0, window=0, dsm=False, settle_s=0.0))
    run._read_inputs(time.time())
    keep = sorted(run.exposures)[:2]
    run.exposures = {k: run.exposures[k] for k in keep}
    while any(x.state == "waiting" for x in run.exposures.values()):
        run.poll()
    run.finish()
    z = max(run._zooms)
    tile = next((run.out / "tiles" / "ortho" / str(z)).rglob("*.png"))
    with LiveServer(run.out) as srv:
        rel = tile.relative_to(run.out / "tiles")
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(f"{srv.base}/tiles/{rel.as_posix()}")
        assert e.value.code == 403
        body = urllib.request.urlopen(f"{srv.base}/tiles/{rel.as_posix()}?token={srv.token}").read()
        assert body == tile.read_bytes()
        drv = _browser()
        try:
            drv.get(srv.url)
            from selenium.webdriver.support.ui import WebDriverWait

            WebDriverWait(drv, 20).until(lambda d: d.execute_script(
                "return document.getElementById('summary').dataset.done === '2' && "
                "Array.from(document.querySelectorAll('img.leaflet-tile-loaded')).some("
                "i => i.src.includes('/tiles/ortho/') && i.naturalWidth === 256)"))
            assert drv.execute_script("return typeof L === 'object' && L.version") == "1.9.4"
        finally:
            drv.quit()


# --------------------------------------------------------------------------------------------- quick ortho
def test_rectify_lattice_against_exact_mapping(flight):
    """The live ortho's maps (exact on a lattice every 8 tile pixels, bilinear in between) against the exact
    mapping of every pixel (PROJ + camera model per pixel): under a tenth of a pixel at the 99th percentile for the
    nadir and an oblique head over the reference DEM; and a pixel's colour is the image's at the exact position."""
    from skyrig.dense.grid_rectify import grid_to_image, rectify_maps, rectify_onto_grid
    from skyrig.georef.direct import direct_georeference
    from skyrig.io.dem import read_dem
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.images import read_image
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv
    from skyrig.georef.eo import WorldFrame

    rig = read_rig(flight / "rig.yaml")
    ev = read_events_csv(flight / "events.csv")
    eo = direct_georeference(read_trajectory_csv(flight / "trajectory.csv"), rig, ev.subset([0, 1, 2]),
                             WorldFrame.map("EPSG:25832"))
    dem = read_dem(flight / "reference_dem.tif")

    def height_at(x, y):
        h = dem.sample(x, y)
        return np.where(np.isfinite(h), h, 80.0)

    cams = {h.camera.name: h.camera for h in rig}
    from pyproj import Transformer

    to_merc = Transformer.from_crs("EPSG:25832", "EPSG:3857", always_xy=True)
    for i in range(3):
        cam = cams[str(eo.camera[i])]
        d = cam.rays_from_pixels(np.array([[cam.width / 2, cam.height / 2]])) @ eo.rotation[i].T
        g = eo.centre[i] + (80.0 - eo.centre[i, 2]) / d[0, 2] * d[0]  # the image centre's ground point
        mx, my = to_merc.transform(g[0], g[1])
        px, w, h = 1.6, 300, 260
        x0, y1 = mx - w * px / 2, my + h * px / 2
        exact_u, exact_v = rectify_maps(eo, i, cam, "EPSG:3857", x0, y1, px, w, h, height_at, step=1)
        u, v = rectify_maps(eo, i, cam, "EPSG:3857", x0, y1, px, w, h, height_at, step=8)
        inside = (exact_u >= 0) & (exact_v >= 0) & (exact_u <= cam.width - 1) & (exact_v <= cam.height - 1)
        assert inside.mean() > 0.3
        err = np.hypot(u - exact_u, v - exact_v)[inside]
        assert np.percentile(err, 99) < 0.1 and err.max() < 1.0, (str(eo.head[i]), np.percentile(err, 99))
        # the exact mapping itself: one grid pixel's centre through pyproj and the camera model directly
        r, c = h // 3, w // 2
        gx, gy = x0 + (c + 0.5) * px, y1 - (r + 0.5) * px
        uu, vv = grid_to_image(eo, i, cam, "EPSG:3857", np.array([gx]), np.array([gy]), height_at)
        e, n = Transformer.from_crs("EPSG:3857", "EPSG:25832", always_xy=True).transform(gx, gy)
        from skyrig.geodesy.frame import local_frame_for

        local = local_frame_for(eo.frame.to_ecef(eo.centre[i:i + 1]))
        el = eo.subset([i]).to_frame(local)
        p = eo.frame.points_to(np.array([[e, n, float(height_at(np.array([e]), np.array([n]))[0])]]), local)
        pix = cam.project_pixels((p - el.centre[0]) @ el.rotation[0])[0]
        assert (uu[0], vv[0]) == pytest.approx((pix[0], pix[1]), abs=1e-6)
        assert (exact_u[r, c], exact_v[r, c]) == pytest.approx((pix[0], pix[1]), abs=1e-3)
        img = read_image(flight / "images" / str(eo.image[i]))
        rgba = rectify_onto_grid(img, eo, i, cam, "EPSG:3857", x0, y1, px, w, h, height_at, step=1)
        if rgba[r, c, 3]:
            ref = cv2.remap(img, np.float32([[pix[0]]]), np.float32([[pix[1]]]), cv2.INTER_LINEAR)[0, 0]
            assert np.abs(rgba[r, c, :3].astype(int) - ref.astype(int)).max() <= 1


# --------------------------------------------------------------------------------------------- live project mode
def test_live_project_mode_then_batch(flight, tmp_path):
    """skyrig run PROJECT --live --replay FLIGHT --then-batch on a project whose trajectory, events and images do
    not exist yet: the replayed flight processed live, published as OUTPUT/live (manifest last, consistent, no
    working folder left), then the batch stages, which find the live stage up to date."""
    from click.testing import CliRunner

    from skyrig.cli import main
    from skyrig.errors import InputFormatError
    from skyrig.io.stage import verify_folder
    from skyrig.pipeline.project import load_project

    proj = tmp_path / "proj"
    proj.mkdir()
    shutil.copyfile(flight / "rig.yaml", proj / "rig.yaml")
    (proj / "project.yaml").write_text(
        "format: skyrig-project\nversion: 1\ncrs: EPSG:25832\noutput: out\n"
        "inputs:\n  images: [images]\n  trajectory: trajectory.csv\n  events: events.csv\n  rig: rig.yaml\n"
        "stages:\n  live: {height: 80.0, window: 0, trajectory_timeout: 5.0}\n  georef: {}\n")
    with pytest.raises(InputFormatError, match="trajectory"):
        load_project(proj)  # batch: the flight is not recorded yet
    assert load_project(proj, live=True).stage("live").options["height"] == 80.0
    n_exp = len({ln.split(",")[3] for ln in _lines(flight / "events.csv") if ln[0] != "#" and
                 not ln.startswith("image,")})
    r = CliRunner().invoke(main, ["run", str(proj), "--live", "--replay", str(flight), "--speed", "20",
                                  "--no-serve", "--then-batch"])
    assert r.exit_code == 0, r.output
    out = proj / "out"
    assert (out / "live" / "manifest.json").is_file() and verify_folder(out / "live") == []
    assert not (out / ".live.running").exists()
    s = json.loads((out / "live" / "summary.json").read_text())
    assert s["exposures_done"] == n_exp and s["exposures_skipped"] == 0 and not s["reported"]
    assert s["dsm_latency_s"]["n"] >= n_exp - 2  # every consecutive pair of a strip
    tiles = list((out / "live" / "tiles" / "ortho").rglob("*.png"))
    assert tiles and all(xyz_tiles.read_tile(p) is not None for p in tiles)
    run = json.loads((out / "run.json").read_text())
    assert [(st["stage"], st["status"]) for st in run["stages"]] == [("live", "skipped"), ("georef", "done")]
    assert (out / "georef" / "eo.csv").is_file()
    # --live alone with batch-only options is refused
    r = CliRunner().invoke(main, ["run", str(proj), "--live", "--only", "georef"])
    assert r.exit_code != 0 and "--live" in r.output


# --------------------------------------------------------------------------------------------- slow: rate replay
@pytest.mark.slow
def test_rate_replay_against_batch(tmp_path):
    """16 exposures of a 3K flight replayed at the real exposure rate: every exposure's ortho work takes less CPU
    than the time between exposures (the wall-clock latency depends on the machine's load: bench/live.py), DSM tiles
    for the stereo pairs, the online boresight (two windows of 8) within 3 sigma of the batch adjustment of the same
    observations in one adjustment, in the sigma of their difference (the two share most observations:
    live_check.difference_sigma with the shared share of the windows' ties), and within 3 of its own sigma of the
    injected truth (the window's sigma is realistic: error / sigma RMS 1.04 over 5 seeds, bench/live_stats.py), the
    live mosaic within 0.5 GSD of the batch ortho."""
    from skyrig.pipeline import live_check as lc
    from skyrig.pipeline.live import LiveConfig, LiveRun
    from skyrig.pipeline.live_replay import replay_flight

    fl = tmp_path / "flight"
    lc.simulate_3k_flight(fl, half_length_m=700.0)
    dem = fl / "reference_dem.tif"
    w = tmp_path / "w"
    w.mkdir()
    shutil.copyfile(fl / "rig.yaml", w / "rig.yaml")
    rep = threading.Thread(target=replay_flight, args=(fl, w, 1.0), kwargs={"max_exposures": 16}, daemon=True)
    run = LiveRun(w, None, LiveConfig(crs="EPSG:25832", surface_height_m=80.0, dem_path=str(dem), surface_sigma_m=2.0,
                                      window=8))
    rep.start()
    s = run.run(max_wall_s=1800)
    assert s["exposures_done"] == 16 and not s["reported"], s["reported"]
    assert s["ortho_cpu_s"]["median"] < s["exposure_interval_flight_s"]
    assert s["dsm_latency_s"]["n"] >= 12
    batch = lc.batch_boresight(fl, "EPSG:25832", 16, dem, 2.0, LiveConfig().features)  # the same observations
    truth = lc.true_corrections(fl)
    est = run.estimate
    assert est.n_exposures == 16
    shared = lc.shared_observations([w.ties for w in run._windows if w.ties is not None], batch.ties)
    assert 0.5 < shared <= 1.0, shared
    for h in est.correction:
        so = est.sigma(h)
        sd = lc.difference_sigma(so, np.sqrt(np.diag(batch.covariance[h])), shared)
        assert np.all(np.abs(est.correction[h] - batch.correction[h]) <= 3 * sd), (h, shared, sd)
        assert np.all(np.abs(est.correction[h] - truth[h]) <= 3 * so), h
    cell = s["cell_m"]["median"]
    ortho = lc.batch_ortho(fl, "EPSG:25832", 80.0, batch.correction, cell, 16, dem)
    off = lc.mosaic_offsets(run.out / "tiles", max(s["zooms"]), ortho)
    assert off["patches"] >= 20
    assert off["median_offset_m"] <= 0.5 * cell
