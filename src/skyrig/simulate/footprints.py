"""A simulated scene's building footprints as a cadastre would give them: a GeoPackage polygon layer with heights.

:func:`scene_footprints` gives the true footprint rectangles of a :class:`~skyrig.simulate.world.Scene`'s
buildings, converted rigorously (through ECEF) from the scene's local frame to a map CRS, with attributes

``id``            the scene's building index;
``eave_m``        eave height above the ground at the footprint (metres; the lowest terrain height at its
                  corners, where the walls' visible bottom is), plus a seeded normal error of
                  ``height_sigma_m`` (a cadastre's heights are measured, e.g. by LiDAR or photogrammetry, to
                  a few decimetres);
``ridge_m``       ridge height above the same ground, with the same error (equal to ``eave_m`` for a flat
                  roof);
``ground_h``      the ground height in the map CRS's own height reference (ellipsoidal for a 2D CRS).

Plan positions can be perturbed too (``plan_sigma_m``: every corner moved by the same seeded shift per
building; a cadastre's outline is a rigid survey of the walls).  The errors drawn are returned, so a judge can
compare what the pipeline makes of them.  :func:`skyrig.pipeline.simulate.write_scene_footprints` writes them as
a GeoPackage layer (formats live in :mod:`skyrig.io`, above this layer).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from skyrig.geodesy.frame import WorldFrame
from skyrig.simulate.world import Scene

__all__ = ["scene_footprints"]


def scene_footprints(scene: Scene, frame: WorldFrame, buildings: Sequence[int] | None = None, *,
                     height_sigma_m: float = 0.0, plan_sigma_m: float = 0.0, seed: int = 0) -> dict:
    """Footprints of ``buildings`` (default: all) in ``frame`` with perturbed heights (see the module docstring).

    Returns a dict: ``ids``, ``rings`` (``(4, 2)`` counter-clockwise, in ``frame``), ``eave_m``, ``ridge_m``,
    ``ground_h`` (arrays), ``height_error_m`` and ``plan_error_m`` (``(B, 2)``, local east / north) drawn."""
    loc = WorldFrame.local(*scene.origin)
    bl = scene.buildings
    ids = list(range(len(bl))) if buildings is None else [int(i) for i in buildings]
    rng = np.random.default_rng(seed)
    dh = rng.normal(0.0, height_sigma_m, len(ids)) if height_sigma_m > 0 else np.zeros(len(ids))
    dp = rng.normal(0.0, plan_sigma_m, (len(ids), 2)) if plan_sigma_m > 0 else np.zeros((len(ids), 2))
    rings, eave, ridge, ground = [], [], [], []
    for k, i in enumerate(ids):
        fp = bl.vertices(i)[:4, :2][::-1] + dp[k]  # vertices() lists the corners clockwise
        gz = float(scene.terrain_height(fp[:, 0], fp[:, 1]).min())
        pts = np.column_stack([fp, np.full(4, gz)])
        if frame == loc:
            m = pts
        else:
            m = frame.from_ecef(loc.to_ecef(pts))
        rings.append(np.asarray(m[:, :2], float))
        ground.append(float(np.mean(m[:, 2])))
        eave.append(float(bl.eave_z[i]) - gz + dh[k])
        ridge.append(float(bl.ridge_z[i]) - gz + dh[k])
    return {"ids": np.array(ids, np.int64), "rings": rings, "eave_m": np.array(eave), "ridge_m": np.array(ridge),
            "ground_h": np.array(ground), "height_error_m": dh, "plan_error_m": dp}
