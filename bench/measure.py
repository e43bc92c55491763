"""``skyrig measure``: how fast the page opens on a large block and how fast a tile of a 100-MP frame comes.

    .venv/bin/python bench/measure.py                       # 2,000 images, 20 points, a 12,000 x 8,400 JPEG
    .venv/bin/python bench/measure.py --images 500 --width 6000 --height 4000

Block: a generated grid of nadir frames (``--images``, 100 MP camera, 80 % / 60 % overlap at 1 cm GSD) with
``--points`` ground points; timed: building the session (the lists of the page's first request:
:meth:`MeasureSession.points_summary`) and one point's state (:meth:`point_state`: every image's prediction,
ellipse, view quality).  Image: a generated RGB JPEG of ``--width x --height``; timed: single full-resolution
tiles: the first coarse one (builds the overview), the first full-resolution one right after the image is opened
(:meth:`TilePyramid.prepare` starts the tiled copy in the background; until it is written, fine tiles come from
one whole decode held in a small cache), random uncached full-resolution tiles while the copy is written, how long
the copy takes, then random uncached full-resolution tiles from the copy; next to one plain full decode of the
same file with OpenCV (the peer: what a viewer that loads the frame whole pays first).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def block(n_images: int, n_points: int):
    from skyrig.camera.frame import FrameCamera
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.georef.observations import GroundPoints

    cam = FrameCamera.from_pixels("cam100", 12000, 8400, 16000.0, 5999.5, 4199.5, pixel_size_mm=0.0036)
    gsd, h = 0.01, 160.0  # 1 cm at 160 m: f = h / gsd = 16,000 px
    side = int(np.ceil(np.sqrt(n_images)))
    dx, dy = 0.4 * 12000 * gsd, 0.2 * 8400 * gsd
    ij = np.array([(i, j) for j in range(side) for i in range(side)][:n_images], dtype=float)
    centre = np.c_[ij[:, 0] * dx, ij[:, 1] * dy, np.full(len(ij), h)] + [500000.0, 5800000.0, 0.0]
    rot = np.broadcast_to(np.eye(3), (len(ij), 3, 3))  # camera z up: looking down
    frame = WorldFrame.map("EPSG:25832")
    eo = ExteriorOrientations(np.array([f"img{k:05d}.jpg" for k in range(len(ij))]), "cam100", centre, rot, frame)
    rng = np.random.default_rng(1)
    lo, hi = centre[:, :2].min(axis=0), centre[:, :2].max(axis=0)
    xy = rng.uniform(lo, hi, (n_points, 2))
    pts = GroundPoints(np.array([f"GCP{k:02d}" for k in range(n_points)]), np.c_[xy, np.zeros(n_points)], frame)
    return eo, {"cam100": cam}, pts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=int, default=2000)
    ap.add_argument("--points", type=int, default=20)
    ap.add_argument("--width", type=int, default=12000)
    ap.add_argument("--height", type=int, default=8400)
    ap.add_argument("--tiles", type=int, default=5)
    a = ap.parse_args()
    import cv2

    from skyrig.io.image_windows import ImageWindows
    from skyrig.web.measure import MeasureSession
    from skyrig.web.tiles import TilePyramid

    with tempfile.TemporaryDirectory() as tmp:
        eo, cams, pts = block(a.images, a.points)
        t0 = time.perf_counter()
        s = MeasureSession(eo, cams, pts, {}, {}, Path(tmp) / "m.csv", lock=False)
        summary = s.points_summary()
        t_open = time.perf_counter() - t0
        t0 = time.perf_counter()
        st = s.point_state(summary[0]["name"])
        t_point = time.perf_counter() - t0
        print(f"block {len(eo)} images, {len(pts)} points: session + point list {t_open:.3f} s "
              f"(images per point: median {np.median([p['predicted_in'] for p in summary]):.0f}); "
              f"one point's state {t_point:.3f} s ({len(st['predictions'])} predictions)")

        rng = np.random.default_rng(0)
        img = cv2.resize(rng.integers(0, 255, (a.height // 16, a.width // 16, 3), dtype=np.uint8), (a.width, a.height),
                         interpolation=cv2.INTER_CUBIC)
        cv2.putText(img, "skyrig", (a.width // 4, a.height // 2), cv2.FONT_HERSHEY_SIMPLEX, 40, (255, 255, 255), 60)
        path = str(Path(tmp) / "frame.jpg")
        cv2.imwrite(path, img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        del img
        t0 = time.perf_counter()
        full = cv2.imread(path)
        t_full = time.perf_counter() - t0
        del full
        pyr = TilePyramid(ImageWindows(path), copy_to=str(Path(tmp) / "copy.tif"))
        t0 = time.perf_counter()
        pyr.tile_jpeg(pyr.max_level - 6, 0, 0)
        t_ov = time.perf_counter() - t0
        t_open = time.perf_counter()
        pyr.prepare()  # what the page's first request of the image starts
        t0 = time.perf_counter()
        pyr.tile_jpeg(pyr.max_level, 20, 20)
        t_first = time.perf_counter() - t0
        nx, ny = int(np.ceil(a.width / 256)), int(np.ceil(a.height / 256))
        tw = []
        while not pyr._copy_done.is_set() and len(tw) < 1000:  # while the copy is written: from the decode
            t0 = time.perf_counter()
            pyr.tile_jpeg(pyr.max_level, int(rng.integers(0, nx)), int(rng.integers(0, ny)))
            tw.append(time.perf_counter() - t0)
            time.sleep(0.05)  # a user panning, not a loop starving the copy
        pyr._copy_done.wait()
        t_copy = time.perf_counter() - t_open
        held = pyr._decoded is not None
        ts = []
        for k in range(a.tiles * 10):
            t0 = time.perf_counter()
            pyr.tile_jpeg(pyr.max_level, int(rng.integers(0, nx)), int(rng.integers(0, ny)))
            ts.append(time.perf_counter() - t0)
        pyr.close()
        mp = a.width * a.height / 1e6
        during = (f"{len(tw)} tiles while it was written: median {np.median(tw) * 1000:.1f} ms, max "
                  f"{max(tw) * 1000:.1f} ms" if tw else "no tile while it was written")
        print(f"image {a.width} x {a.height} ({mp:.0f} MP JPEG): OpenCV full decode {t_full:.2f} s; first overview "
              f"tile {t_ov:.2f} s; first full-resolution tile (one whole decode, held while the tiled copy is "
              f"written) {t_first:.2f} s; tiled copy written {t_copy:.2f} s after opening ({during}; decode "
              f"{'still held' if held else 'dropped'} after); then from the copy full-resolution tiles median "
              f"{np.median(ts) * 1000:.1f} ms, max {max(ts) * 1000:.1f} ms "
              f"({1 / np.median(ts):.0f} tiles/s, {t_full / np.median(ts):.0f} x a full decode)")


if __name__ == "__main__":
    main()
