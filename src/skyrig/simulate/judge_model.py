"""Judge a building model against the simulator's analytic town, and the town's truth as building blocks.

* :func:`true_buildings` (from :mod:`skyrig.simulate.judge_facades`): the scene's buildings as
  :class:`~skyrig.dense.buildings.BuildingBlock` prisms in any frame;
* :func:`true_facade_textures`: façade textures painted from the scene's façade rule (:meth:`Scene.facade_rgb`) at
  the texel centres of the :class:`~skyrig.dense.buildings.FacadeTexture` convention - what a perfect texturing
  would give (no shading);
* :func:`judge_model`: per true building, the nearest model building (footprint centroid), the distance of each true
  footprint corner to the model's footprint outline and to its nearest vertex, the eave and ridge height errors;
  summary figures (found / missed / extra, corner RMS and max, height bias and RMS).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.buildings import BuildingBlock, Facade, FacadeTexture
from skyrig.geodesy.frame import WorldFrame
from skyrig.simulate.judge_facades import true_buildings
from skyrig.simulate.world import Buildings, Scene

__all__ = ["scene_frame", "true_buildings", "true_facade_textures", "facade_rule_at", "judge_model", "scene_from_dict"]


def scene_frame(scene: Scene) -> WorldFrame:
    """The scene's local ENU frame."""
    return WorldFrame.local(*scene.origin)


def scene_from_dict(d: dict[str, Any]) -> Scene:
    """A :class:`Scene` from the ``scene/scene.json`` content a simulated project holds (terrain, buildings, texture
    parameters; targets are left out)."""
    t, b = d["terrain"], d["buildings"]
    bl = Buildings(*(np.asarray(b[k], float) for k in ("cx", "cy", "hl", "hw", "azimuth_rad", "base_z", "eave_z", "ridge_z")))
    tex = d.get("texture", {})
    return Scene(tuple(d["frame"]["origin"]), tuple(d["extent"]), int(d["seed"]), float(t["base_height_m"]),
                 np.asarray(t["amp_m"], float), np.asarray(t["kx"], float), np.asarray(t["ky"], float),
                 np.asarray(t["phase"], float), bl, None, texture_fine_m=float(tex.get("fine_m", 0.05)),
                 texture_coarse_m=float(tex.get("coarse_m", 40.0)),
                 window_spacing_m=float(tex.get("window_spacing_m", 3.0)), sun=np.asarray(d["sun"], float))


def true_facade_textures(scene: Scene, buildings: Sequence[BuildingBlock], frame: WorldFrame, texel_m: float = 0.1
                         ) -> list[FacadeTexture]:
    """Façade textures of ``buildings`` (in ``frame``, e.g. from :func:`true_buildings`) painted from the scene's
    façade rule at each texel centre (``(j + 0.5) texel_m`` along the wall from its start corner in ``frame``,
    ``eave_z - (i + 0.5) texel_m`` in height), converted to the scene frame; no shading."""
    loc = scene_frame(scene)
    out = []
    for b in buildings:
        for f in b.facades():
            w = max(1, int(np.ceil(f.width_m / texel_m - 1e-9)))
            h = max(1, int(np.ceil(f.height_m / texel_m - 1e-9)))
            jj, ii = np.meshgrid(np.arange(w), np.arange(h))
            s = (jj.ravel() + 0.5) * texel_m
            z = b.eave_z - (ii.ravel() + 0.5) * texel_m
            rgb = facade_rule_at(scene, f, s, z, frame, loc)
            out.append(FacadeTexture(f, (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8).reshape(h, w, 3),
                                     np.ones((h, w), bool), float(texel_m), ("scene facade rule",)))
    return out


def facade_rule_at(scene: Scene, f: Facade, s: NDArray[np.float64], z: NDArray[np.float64], frame: WorldFrame,
                   loc: WorldFrame | None = None) -> NDArray[np.float64]:
    """The scene's façade colour ``(N, 3)`` in [0, 1] at wall points given by the distance ``s`` from the start
    corner along the wall and the height ``z`` (both in ``frame``)."""
    loc = loc or scene_frame(scene)
    c = np.asarray(f.corners, float)
    d = (c[1] - c[0])[:2]
    t = d / np.linalg.norm(d)
    p = np.column_stack([c[0, 0] + s * t[0], c[0, 1] + s * t[1], z])
    q = p if frame == loc else frame.points_to(p, loc)
    # renderer convention (skyrig.simulate.render.shade): u = tangent . p with tangent = z x outward normal
    cl = c[:2] if frame == loc else frame.points_to(c[:2], loc)
    dl = (cl[1] - cl[0])[:2]
    tl = dl / np.linalg.norm(dl)
    u = q[:, 0] * tl[0] + q[:, 1] * tl[1]
    # the renderer's face index: the wall half-space whose normal is the wall's outward normal
    normals, _, kind = scene.buildings.planes(int(f.building))
    walls = np.flatnonzero(kind == 0)
    face = int(walls[np.argmax(normals[walls, :2] @ np.array([tl[1], -tl[0]]))])
    bidx = np.full(len(q), int(f.building), dtype=np.int64)
    return scene.facade_rgb(bidx, u, q[:, 2], np.full(len(q), face, dtype=np.int64))


def _seg_dist(p: NDArray[np.float64], poly: NDArray[np.float64]) -> float:
    a = poly
    b = np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1)))


def judge_model(buildings: Sequence[BuildingBlock], frame: WorldFrame, scene: Scene, *,
                match_radius_m: float = 10.0) -> dict[str, Any]:
    """Compare model buildings (in ``frame``) with the scene's true buildings.

    Parameters
    ----------
    buildings
        The model's blocks (e.g. from building extraction on a DSM), in ``frame``.
    frame
        Their frame (a map CRS or a local frame).
    scene
        The simulator's scene (its truth).
    match_radius_m
        A true building matches the model building whose footprint centroid is nearest, if within this distance.

    Returns
    -------
    dict
        ``per_building`` (true id, model id, corner errors to the outline and to the nearest vertex in metres,
        eave and ridge errors: model - truth), ``found`` / ``missed`` / ``extra`` counts, ``corner_rms_m``,
        ``corner_max_m``, ``corner_vertex_rms_m``, ``eave_bias_m``, ``eave_rms_m``, ``ridge_rms_m``
        (all in the scene frame, metres; heights above the tangent plane).
    """
    loc = scene_frame(scene)
    truth = true_buildings(scene)
    model = []
    for b in buildings:
        fp = np.asarray(b.footprint, float)
        if frame == loc:
            fpl = fp
            eave = float(b.eave_z)
            top = max([float(np.max(np.asarray(r)[:, 2])) for r in b.roof] + [eave])
        else:
            fpl = frame.points_to(np.column_stack([fp, np.full(len(fp), b.eave_z)]), loc)[:, :2]
            c = fp.mean(axis=0)
            eave = float(frame.points_to(np.array([[c[0], c[1], b.eave_z]]), loc)[0, 2])
            roofs = [frame.points_to(np.asarray(r, float), loc) for r in b.roof]
            top = max([float(np.max(r[:, 2])) for r in roofs] + [eave])
        model.append((b.id, fpl, eave, top))
    rows = []
    used: set[int] = set()
    for t in truth:
        c = t.footprint.mean(axis=0)
        best, bd = None, np.inf
        for k, (_, fpl, _, _) in enumerate(model):
            d = float(np.linalg.norm(fpl.mean(axis=0) - c))
            if d < bd:
                best, bd = k, d
        ridge_true = max(float(np.max(np.asarray(r)[:, 2])) for r in t.roof)
        if best is None or bd > match_radius_m:
            rows.append({"true": t.id, "model": None, "centroid_m": None})
            continue
        used.add(best)
        mid, fpl, eave, top = model[best]
        corner_line = [_seg_dist(p, fpl) for p in t.footprint]
        corner_vertex = [float(np.min(np.linalg.norm(fpl - p, axis=1))) for p in t.footprint]
        rows.append({"true": t.id, "model": int(mid), "centroid_m": bd, "corner_outline_m": corner_line,
                     "corner_vertex_m": corner_vertex, "eave_error_m": eave - t.eave_z,
                     "ridge_error_m": top - ridge_true})
    found = [r for r in rows if r["model"] is not None]
    cl = np.array([e for r in found for e in r["corner_outline_m"]])
    cv = np.array([e for r in found for e in r["corner_vertex_m"]])
    ee = np.array([r["eave_error_m"] for r in found])
    re = np.array([r["ridge_error_m"] for r in found])

    def rms(a: NDArray) -> float | None:
        return float(np.sqrt(np.mean(a ** 2))) if len(a) else None

    return {"true_buildings": len(truth), "model_buildings": len(model), "found": len(found),
            "missed": len(rows) - len(found), "extra": len(model) - len(used),
            "corner_rms_m": rms(cl), "corner_max_m": float(cl.max()) if len(cl) else None,
            "corner_vertex_rms_m": rms(cv), "eave_bias_m": float(np.mean(ee)) if len(ee) else None,
            "eave_rms_m": rms(ee), "ridge_rms_m": rms(re), "per_building": rows}
