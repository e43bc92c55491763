"""Render throughput (megapixels/s, one core) and generation time per scenario.

Run: .venv/bin/python bench/simulate.py [--size ci|full] [--workers N] [--repeat K] [scenario ...]

The render benchmark pins BLAS/OpenMP to one thread (set before numpy is imported) and reports the best and
the median of ``--repeat`` runs, wall clock and process CPU time, so that a loaded machine shows as a gap
between the two.  For a strict one-core figure also pin the process: ``taskset -c 0 .venv/bin/python ...``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def render_throughput(repeat: int = 3) -> float:
    from skyrig.camera.frame import FrameCamera
    from skyrig.geometry.pose import Pose
    from skyrig.rig.rig import oblique_mounting
    from skyrig.simulate.render import camera_rays, render_image
    from skyrig.simulate.world import make_scene

    scene = make_scene(1, (-600, -600, 600, 600), texture_fine_m=0.05)
    cam = FrameCamera("bench-1mp", 1000, 1000, 0.005, 35.0)
    enu_from_body = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    camera_rays(cam)  # rays are cached per camera (as in a survey)
    best = []
    for tilt in (0.0, 45.0):
        pose = Pose(enu_from_body @ oblique_mounting(0, tilt), np.array([0.0, -150.0 * (tilt > 0), 230.0]), "w", "c")
        render_image(scene, cam, pose, noise_dn=1.0)  # warm-up: the camera's ray tiles are built once
        wall, cpu = [], []
        for _ in range(repeat):
            w, c = time.perf_counter(), time.process_time()
            render_image(scene, cam, pose, noise_dn=1.0)
            wall.append(time.perf_counter() - w)
            cpu.append(time.process_time() - c)
        best.append(min(wall))
        print(f"1 MP image, tilt {tilt:4.0f} deg: wall best {min(wall):.2f} s median {np.median(wall):.2f} s, "
              f"CPU best {min(cpu):.2f} s ({1.0 / min(wall):.2f} MP/s, one thread)")
    return 2.0 / sum(best)


def main() -> None:
    from skyrig.pipeline.simulate import simulate_scenario

    ap = argparse.ArgumentParser()
    ap.add_argument("scenarios", nargs="*", default=["tumblecam", "midas", "3k", "southeast", "uav-bridge-lidar"])
    ap.add_argument("--size", default="ci")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    print(f"render throughput: {render_throughput(a.repeat):.2f} MP/s per core")
    for name in a.scenarios:
        with tempfile.TemporaryDirectory() as d:
            info = simulate_scenario(name, d, a.size, 1, a.workers)
            if info.n_images:
                print(f"{name:16s} {a.size}: {info.n_images:4d} images {info.megapixels:7.1f} MP, render {info.render_s:6.1f} s "
                      f"({info.megapixels / max(info.render_s, 1e-9):.2f} MP/s), total {info.total_s:6.1f} s")
            else:
                print(f"{name:16s} {a.size}: {info.summary}, total {info.total_s:6.1f} s")


if __name__ == "__main__":
    main()
