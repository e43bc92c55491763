"""Walls up to the roof line and clipped buildings' walls, against the simulator's truth.

* A gabled house's end wall is one texture from the ground up to the roof line (``texture_facades``, default
  ``TextureConfig.to_roof``): images rendered by the simulator from the TRUE orientations of the midas-dsm flight,
  the scene's analytic DSM in EPSG:25832, the true buildings; the texture is judged against the scene's façade rule
  (:mod:`skyrig.simulate.judge_facades`: a gable end's true wall reaches its roof line).
* A building cut by the border of the surveyed area keeps the direction of its real walls
  (``extract_buildings(clip_border=True)``): every building of the scene, its analytic DSM cut by a ragged border
  (void beyond a line with bites of up to 3 cells, as a matched DSM's edge), against its true footprint.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.dense.buildings import ExtractionConfig, extract_buildings
from skyrig.dense.facades import TextureConfig, texture_facades
from skyrig.dense.grid import GridSpec
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.simulate.judge_facades import judge_facade, rule_texture, scene_dsm, true_buildings, walls_seen
from skyrig.simulate.render import render_image
from skyrig.simulate.scenarios import build_survey, scenario_spec

CRS = WorldFrame.map("EPSG:25832")
CELL = 0.3


def _grid(local, lo, hi, cell=CELL):
    c = CRS.from_ecef(local.to_ecef(np.array([[lo[0], hi[1], 80.0], [hi[0], lo[1], 80.0]])))
    x0, y0 = np.floor(c[0, 0] / cell) * cell, np.ceil(c[0, 1] / cell) * cell
    return GridSpec(float(x0), float(y0), cell, int(np.ceil((c[1, 0] - x0) / cell)),
                    int(np.ceil((y0 - c[1, 1]) / cell)))


@pytest.fixture(scope="module")
def survey():
    return build_survey(scenario_spec("midas-dsm", "ci", 1))


def test_a_gable_end_wall_is_textured_up_to_its_roof_line(survey, tmp_path):
    """The end wall of a gabled house seen by an oblique: one texture up to the roof line whose texels above the
    eaves lie on the true wall (none above the true roof line), whose rows below the eaves are those of the wall
    textured to the eaves only, and whose windows - at least those judged on the wall cut at the eaves - are
    all within 1 texel of the façade rule; the 3D model draws that wall as one textured pentagon."""
    from skyrig.dense.model import build_model

    s = survey
    eo = s.eo_true
    cams = {str(eo.camera[k]): s.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    bl = s.scene.buildings
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    seen = walls_seen(s.scene, eo, cams, oblique)
    # the gable ends an oblique sees (faces 0 / 1 of a gabled house: the ridge runs along its axis)
    ends = sorted((i, f) for i, f in seen if bl.gabled[i] and f < 2)
    assert ends, "no gable end seen by an oblique in the scene"
    i, face = ends[0]
    lo = np.array([bl.cx[i] - 30.0, bl.cy[i] - 30.0])
    dsm = scene_dsm(s.scene, _grid(s.frame, lo, lo + 60.0), CRS)
    block = [b for b in true_buildings(s.scene, CRS) if b.id == i]
    cache = {}

    def load(k):
        if k not in cache:
            cache[k] = render_image(s.scene, cams[str(eo.camera[k])],
                                    Pose(eo.rotation[k], eo.centre[k], "world", "camera"), noise_dn=1.0, seed=k)
        return cache[k]

    tex = texture_facades(block, eo, cams, load, dsm)
    plain = texture_facades(block, eo, cams, load, dsm, config=TextureConfig(to_roof=False))
    judged = [(t, p, judge_facade(s.scene, t, CRS), judge_facade(s.scene, p, CRS)) for t, p in zip(tex, plain)]
    mine = [x for x in judged if (x[2].true_building, x[2].true_face) == (i, face)]
    assert len(mine) == 1
    t, p, j, jp = mine[0]
    assert t.facade.outline is not None and p.facade.outline is None
    assert set(t.images) & oblique
    eave = float(block[0].eave_z)
    H, W = t.valid.shape
    k = H - p.valid.shape[0]  # rows above the eaves
    z = t.facade.corners[3, 2] - (np.arange(H) + 0.5) * t.texel_m
    assert k >= 1 and abs(z[k] - (eave - 0.5 * t.texel_m)) < 1e-6  # the plain wall's texel grid continues upwards
    _, on, *_ = rule_texture(s.scene, t, CRS)
    above = z > eave
    assert not (t.valid & ~on)[above].any(), "texels above the true roof line"
    # the gable triangle is covered (a one-texel band along the roof lines is left out: it straddles the roof)
    assert t.valid[above].sum() >= 0.6 * on[above].sum() > 0
    assert np.array_equal(t.rgb[k + 1:], p.rgb[1:]) and np.array_equal(t.valid[k + 1:], p.valid[1:])
    # every window judged on the wall cut at the eaves is judged here too (the judge needs one texel of wall around
    # a window, so the top row under the eaves is judged on both)
    assert j.windows >= jp.windows > 0, (j, jp)
    assert j.windows_found == j.windows and j.windows_within_1px == j.windows, j
    assert np.max(j.corner_err_px) <= 1.0 and j.offset_norm_px <= 1.0, j
    model = build_model(block, [x for x in tex if x.valid.any()], CRS)
    parts = {q.name: q for q in model.meshes[0].parts}
    wall = parts[f"wall {t.facade.index}"]
    assert len(wall.positions) == len(t.facade.outline) == 5 and wall.image is not None
    assert wall.uv.min() >= -1e-9 and wall.uv.max() <= 1 + 1e-9
    assert f"gable {t.facade.index}" not in parts
    from skyrig.io.gltf import glb_problems, write_glb, write_obj

    write_glb(tmp_path / "m.glb", model)
    write_obj(tmp_path / "m.obj", model)
    assert glb_problems(tmp_path / "m.glb") == []


def test_clipped_buildings_keep_the_direction_of_their_real_walls(survey):
    """Every building of the scene cut across by a ragged border of the surveyed area at 30 % and 50 % of its depth:
    the walls of the clipped footprint that are real (not on the border) run within 2 deg of the true walls (the
    accuracy of uncut extraction on this DSM, see tests/test_buildings.py), with a median within 0.5 deg, and lie
    within half a cell (+ 5 cm) of the true wall line at their middle."""
    s = survey
    bl = s.scene.buildings
    rng = np.random.default_rng(5)
    errs, offs = [], []
    for i in range(len(bl)):
        c = np.array([bl.cx[i], bl.cy[i]])
        grid = _grid(s.frame, c - 30.0, c + 30.0)
        dsm = scene_dsm(s.scene, grid, CRS)
        v = CRS.from_ecef(s.frame.to_ecef(bl.vertices(i)[4:8]))[:, :2]
        ctr = v.mean(axis=0)
        xx, yy = grid.cell_centres()
        for frac in (0.3, 0.5):
            cut = v[:, 1].min() + frac * np.ptp(v[:, 1]) + CELL * rng.integers(0, 4, size=xx.shape[1])[None]
            h = np.where(yy > cut, np.nan, np.asarray(dsm.height, np.float32)).astype(np.float32)
            out = extract_buildings(replace(dsm, height=h), config=ExtractionConfig(clip_border=True))
            b = min(out, key=lambda q: np.linalg.norm(np.asarray(q.footprint).mean(axis=0) - ctr))
            assert b.clipped and b.border_edges and np.linalg.norm(np.asarray(b.footprint).mean(axis=0) - ctr) < 12
            fp = np.asarray(b.footprint)
            for e in range(len(fp)):
                d = fp[(e + 1) % len(fp)] - fp[e]
                if e in b.border_edges or np.linalg.norm(d) < 3.0:
                    continue
                # the true wall with the nearest direction (mod 180 deg)
                best = None
                for q in range(4):
                    tq = v[(q + 1) % 4] - v[q]
                    ang = np.degrees(np.arctan2(d[0] * tq[1] - d[1] * tq[0], d @ tq))
                    ang = (ang + 90.0) % 180.0 - 90.0
                    nq = np.array([tq[1], -tq[0]]) / np.linalg.norm(tq)
                    off = abs((fp[e] + 0.5 * d - v[q]) @ nq)
                    if abs(ang) < 45 and (best is None or off < best[1]):
                        best = (ang, off)
                errs.append(best[0])
                offs.append(best[1])
    errs, offs = np.abs(np.array(errs)), np.array(offs)
    assert len(errs) >= 3 * len(bl)
    assert errs.max() <= 2.0 and np.median(errs) <= 0.5, (errs.max(), np.median(errs))
    assert np.percentile(offs, 90) <= 0.5 * CELL + 0.05, np.percentile(offs, 90)
