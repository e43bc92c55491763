"""A simulated town's top-surface cloud (what a nadir image cloud sees) with trees, and its truth, for the
terrain tests: the simulator's analytic scene (:func:`skyrig.simulate.world.make_scene`) gives the bare earth and
the building footprints."""

from __future__ import annotations

import numpy as np

from skyrig.simulate.world import make_scene


def _trees(rng, scene, k, extent):
    """``k`` trees: ellipsoidal crowns (radius 2-4 m, top 5-12 m above the terrain) away from the buildings."""
    out = []
    while len(out) < k:
        cx, cy = rng.uniform(extent[0] + 10, extent[2] - 10, 2)
        r = rng.uniform(2.0, 4.0)
        ring = np.linspace(0, 2 * np.pi, 16)
        _, b = scene.buildings.top_height(cx + (r + 2) * np.cos(ring), cy + (r + 2) * np.sin(ring))
        if (b >= 0).any() or any(np.hypot(cx - t[0], cy - t[1]) < t[2] + r + 2 for t in out):
            continue
        out.append((cx, cy, r, float(scene.terrain_height(cx, cy)) + rng.uniform(5.0, 12.0)))
    return out


def town_cloud(seed=3, size=120.0, density=3.0, noise=0.05, n_trees=6):
    """A cloud of the top surface of a simulated town (what a nadir image cloud sees) with trees, its true classes
    (2 ground, 6 building, 5 vegetation) and the scene."""
    rng = np.random.default_rng(seed)
    ext = (0.0, 0.0, size, size)
    scene = make_scene(seed, ext, n_buildings=8, relief_m=6.0, building_size_m=(8.0, 22.0))
    n = int(size * size * density)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    z = scene.surface_height(x, y)
    _, bidx = scene.buildings.top_height(x, y)
    truth = np.where(bidx >= 0, 6, 2)
    rgb = np.column_stack([rng.integers(90, 140, n)] * 3).astype(np.uint8)  # grey ground and roofs
    for cx, cy, r, top in _trees(rng, scene, n_trees, ext):
        d2 = ((x - cx) ** 2 + (y - cy) ** 2) / r ** 2
        crown = d2 < 1.0
        h = 0.5 * (top - scene.terrain_height(cx, cy))
        z = np.where(crown, top - h + h * np.sqrt(np.clip(1 - d2, 0, 1)) + rng.normal(0, 0.3, n), z)  # leafy
        truth = np.where(crown, 5, truth)
        rgb[crown] = np.column_stack([rng.integers(30, 70, crown.sum()), rng.integers(90, 150, crown.sum()),
                                      rng.integers(20, 60, crown.sum())])
    z = z + rng.normal(0, noise, n)
    return np.column_stack([x, y, z]), rgb, truth, scene
