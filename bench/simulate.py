"""Render throughput (megapixels/s, one core) and generation time per CI scenario.

Run: .venv/bin/python bench/simulate.py [--size ci|full] [--workers N] [scenario ...]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np


def render_throughput() -> float:
    from skyrig.camera.frame import FrameCamera
    from skyrig.geometry.pose import Pose
    from skyrig.rig.rig import oblique_mounting
    from skyrig.simulate.render import camera_rays, render_image
    from skyrig.simulate.world import make_scene

    scene = make_scene(1, (-600, -600, 600, 600), texture_fine_m=0.05)
    cam = FrameCamera("bench-1mp", 1000, 1000, 0.005, 35.0)
    enu_from_body = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    camera_rays(cam)  # rays are cached per camera (as in a survey)
    times = []
    for tilt in (0.0, 45.0):
        pose = Pose(enu_from_body @ oblique_mounting(0, tilt), np.array([0.0, -150.0 * (tilt > 0), 230.0]), "w", "c")
        t = time.perf_counter()
        render_image(scene, cam, pose, noise_dn=1.0)
        times.append(time.perf_counter() - t)
        print(f"1 MP image, tilt {tilt:4.0f} deg: {times[-1]:.2f} s ({1.0 / times[-1]:.2f} MP/s, one core)")
    return 2.0 / sum(times)


def main() -> None:
    from skyrig.pipeline.simulate import simulate_scenario

    ap = argparse.ArgumentParser()
    ap.add_argument("scenarios", nargs="*", default=["tumblecam", "midas", "3k", "southeast"])
    ap.add_argument("--size", default="ci")
    ap.add_argument("--workers", type=int, default=None)
    a = ap.parse_args()
    print(f"render throughput: {render_throughput():.2f} MP/s per core")
    for name in a.scenarios:
        with tempfile.TemporaryDirectory() as d:
            info = simulate_scenario(name, d, a.size, 1, a.workers)
            print(f"{name:10s} {a.size}: {info.n_images:4d} images {info.megapixels:7.1f} MP, render {info.render_s:6.1f} s "
                  f"({info.megapixels / max(info.render_s, 1e-9):.2f} MP/s), total {info.total_s:6.1f} s")


if __name__ == "__main__":
    main()
