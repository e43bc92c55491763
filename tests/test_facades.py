"""Façade textures (skyrig.dense.facades) against the simulator's façade rule.

Images are rendered by the simulator (``skyrig.simulate.render``) from the TRUE orientations of a simulated
MIDAS surface flight (penta rig, 4 obliques); the DSM is the scene's analytic surface rasterised in the map
CRS EPSG:25832 (the orientations stay in the scene's local ENU frame, so every texel goes through the frame
conversion).  The truth is the scene's façade rule :meth:`Scene.facade_rgb` rendered on each texture's own
texel grid (``skyrig.simulate.judge_facades``): window corners must lie within 1 texel.  The occlusion case
is a scene built here: a tall narrow block stands in front of a wall, and the simulator's own ray caster
says which image really sees each texel.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.dense.buildings import BuildingBlock
from skyrig.dense.facades import TextureConfig, texture_facades, texture_plane
from skyrig.dense.grid import GridSpec
from skyrig.errors import SkyrigError
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.simulate.judge_facades import judge_facades, rule_texture, scene_dsm, true_buildings
from skyrig.simulate.render import WALL, cast_rays, render_image
from skyrig.simulate.scenarios import build_survey, scenario_spec
from skyrig.simulate.world import Buildings, make_scene

CRS = WorldFrame.map("EPSG:25832")


class LazyImages:
    """Renders image ``i`` of the true orientations on first use (only the images the texturing reads)."""

    def __init__(self, scene, eo, cams):
        self.scene, self.eo, self.cams, self.cache = scene, eo, cams, {}

    def __call__(self, i):
        if i not in self.cache:
            cam = self.cams[str(self.eo.camera[i])]
            self.cache[i] = render_image(self.scene, cam, Pose(self.eo.rotation[i], self.eo.centre[i], "world", "camera"),
                                         noise_dn=1.0, seed=i)
        return self.cache[i]


def _grid_around(frame, local, xy_min, xy_max, cell):
    """A map grid (cell ``cell``) covering a local-frame rectangle."""
    c = frame.from_ecef(local.to_ecef(np.array([[xy_min[0], xy_max[1], 80.0], [xy_max[0], xy_min[1], 80.0]])))
    x0 = np.floor(c[0, 0] / cell) * cell
    y0 = np.ceil(c[0, 1] / cell) * cell
    return GridSpec(float(x0), float(y0), cell, int(np.ceil((c[1, 0] - x0) / cell)), int(np.ceil((y0 - c[1, 1]) / cell)))


@pytest.fixture(scope="module")
def midas():
    s = build_survey(scenario_spec("midas-dsm", "ci", 1))
    eo = s.eo_true
    cams = {str(eo.camera[k]): s.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    local = s.frame
    # the buildings on the east of the town: their west walls are seen by the east-looking obliques
    bl = s.scene.buildings
    keep = np.flatnonzero(bl.cx > 75)
    lo = np.array([bl.cx[keep].min() - 25, bl.cy[keep].min() - 25])
    hi = np.array([bl.cx[keep].max() + 25, bl.cy[keep].max() + 25])
    dsm = scene_dsm(s.scene, _grid_around(CRS, local, lo, hi, 0.3), CRS)
    blocks = [b for b in true_buildings(s.scene, CRS) if b.id in set(keep.tolist())]
    loader = LazyImages(s.scene, eo, cams)
    tex = texture_facades(blocks, eo, cams, loader, dsm)
    return s, eo, cams, dsm, blocks, tex, loader


def test_textures_match_the_facade_rule_within_one_texel(midas):
    s, eo, _, dsm, blocks, tex, _ = midas
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    judged, summ = judge_facades(s.scene, tex, CRS, oblique)
    seen = [j for j, t in zip(judged, tex) if j.windows and set(t.images) & oblique]
    assert len(seen) >= 5 and summ["seen"] == len(seen), summ
    for j in seen:
        assert j.coverage > 0 and j.windows_found == j.windows, j
        # whole-façade shift (phase correlation) and every façade's median window-corner error within 1 texel
        assert j.offset_norm_px <= 1.0, (j, summ)
        assert np.median(j.corner_err_px) <= 1.0, (j, summ)
    assert summ["within_1px"] == 1.0
    # per window: the edges are located to ~0.25 texel (1 sigma) on point-sampled renderings, so the largest of
    # 4 corner errors exceeds 1 texel on a few windows only
    assert summ["windows_found"] >= 0.95 * summ["windows"]
    assert summ["windows_within_1px"] >= 0.95 * summ["windows_found"], summ


def test_texel_size_is_the_best_images_footprint(midas):
    s, eo, cams, dsm, blocks, tex, _ = midas
    local = s.frame
    for t in tex:
        if not t.images or not t.valid.any():
            continue
        k = int(np.flatnonzero(eo.image == t.images[0])[0]) if len(t.images) == 1 else None
        if k is None:
            continue
        c = t.facade.corners.mean(axis=0)
        pl = local.from_ecef(CRS.to_ecef(np.array([c, c + t.facade.normal])))
        n = (pl[1] - pl[0]) / np.linalg.norm(pl[1] - pl[0])
        d = eo.centre[k] - pl[0]
        cam = cams[str(eo.camera[k])]
        expect = np.linalg.norm(d) / (cam.focal_px * (d @ n) / np.linalg.norm(d))
        assert t.texel_m == pytest.approx(expect, rel=0.2)


@pytest.fixture(scope="module")
def occlusion_case():
    """A wall (building 0, west face, normal -x) at x = 100 with a tall narrow block 10 m in front of it."""
    base = build_survey(scenario_spec("midas-dsm", "ci", 1))
    sc = make_scene(5, (-250.0, -250.0, 250.0, 250.0), origin=base.scene.origin, n_buildings=0, relief_m=2.0)
    cx = np.array([108.0, 89.0])
    cy = np.array([-12.0, -11.0])
    g = sc.terrain_height(cx, cy)
    sc = replace(sc, buildings=Buildings(cx, cy, np.array([10.0, 1.25]), np.array([8.0, 4.0]), np.array([np.pi / 2, 0.0]),
                                         g - 3.0, g + np.array([8.0, 22.0]), g + np.array([8.0, 22.0])))
    eo = base.eo_true
    cams = {str(eo.camera[k]): base.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    dsm = scene_dsm(sc, GridSpec(60.0, 20.0, 0.25, 240, 180), base.frame)  # local frame DSM
    return sc, eo, cams, dsm, base.frame


def test_occluded_texels_take_their_colour_from_an_image_that_sees_them(occlusion_case):
    sc, eo, cams, dsm, local = occlusion_case
    wall = [f for f in true_buildings(sc)[0].facades() if f.normal[0] < -0.99][0]
    loader = LazyImages(sc, eo, cams)
    res = texture_plane(wall.corners, eo, cams, loader, dsm, normal=wall.normal)
    st = res.stats
    assert st["occluded_in_best"] > 100, st
    assert st["occluded_filled"] >= 0.8 * st["occluded_in_best"], st
    # independent check with the simulator's ray caster: the image each texel took its colour from sees the wall
    H, W = res.valid.shape
    c = wall.corners
    u = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    P = c[3] + (jj.reshape(-1, 1) * res.texel_m) * u - (ii.reshape(-1, 1) * res.texel_m) * np.array([0, 0, 1.0])
    src = res.source.reshape(-1)
    ok = np.zeros(len(P), bool)
    for m, name in enumerate(res.images):
        k = int(np.flatnonzero(eo.image == name)[0])
        sel = np.flatnonzero(src == m)
        d = P[sel] - eo.centre[k]
        hits = cast_rays(sc, eo.centre[k], d)
        ok[sel] = (hits.kind == WALL) & (hits.building == 0) & (np.abs(hits.t - np.linalg.norm(d, axis=1)) < 0.05)
    valid = res.valid.reshape(-1)
    assert ok[valid].mean() >= 0.97
    # texels left without colour: the ray caster finds (almost) no image facing the wall that sees them
    missing = np.flatnonzero(~valid & (P[:, 2] > sc.terrain_height(P[:, 0], P[:, 1]) + 0.3))
    seen_somewhere = np.zeros(len(missing), bool)
    for k in range(len(eo)):
        cam = cams[str(eo.camera[k])]
        d = P[missing] - eo.centre[k]
        facing = (-d @ wall.normal) / np.linalg.norm(d, axis=1) > np.cos(np.radians(75))
        inside = cam.in_image(cam.project_pixels(d @ eo.rotation[k]), -1.0) & facing
        if inside.any():
            h = cast_rays(sc, eo.centre[k], d[inside])
            seen_somewhere[np.flatnonzero(inside)] |= (h.building == 0) & (np.abs(h.t - np.linalg.norm(d[inside], axis=1)) < 0.05)
    assert seen_somewhere.sum() <= 0.1 * max(st["occluded_in_best"], 1), (seen_somewhere.sum(), st)
    # and the colours there are the wall's: against the rule (shaded), texels hidden in the best image
    from skyrig.dense.buildings import FacadeTexture

    ft = FacadeTexture(wall, res.rgb, res.valid, res.texel_m, res.images, res.source, st)
    truth, on, *_ = rule_texture(sc, ft, local)
    err_on = np.abs(res.rgb / 255.0 - truth).mean(axis=2)
    # the same wall without the occlusion test (tolerance above any building): the block's colours come in
    blind = texture_plane(wall.corners, eo, cams, loader, dsm, normal=wall.normal,
                          config=TextureConfig(occlusion_tol_m=1e6))
    err_off = np.abs(blind.rgb / 255.0 - truth).mean(axis=2)
    hidden = (blind.source == 0) & res.valid & (res.source != 0) & on
    assert hidden.sum() > 100
    assert np.median(err_on[hidden]) < 0.5 * np.median(err_off[hidden])


def test_bad_inputs_are_refused(midas):
    s, eo, cams, dsm, blocks, _, loader = midas
    with pytest.raises(SkyrigError, match="no camera"):
        texture_facades(blocks[:1], eo, {}, loader, dsm)
    with pytest.raises(SkyrigError, match="max_images"):
        texture_facades(blocks[:1], eo, cams, loader, dsm, max_images=0)
    with pytest.raises(SkyrigError, match="texel"):
        texture_facades(blocks[:1], eo, cams, loader, dsm, texel_m=-1.0)
    geo = replace(dsm, frame=WorldFrame.map("EPSG:4326"))
    with pytest.raises(SkyrigError, match="projected"):
        texture_facades(blocks[:1], eo, cams, loader, geo)
    assert texture_facades([], eo, cams, loader, dsm) == []
    local_blocks = true_buildings(s.scene)[:1]  # the scene's local frame, not the DSM's map CRS
    with pytest.raises(SkyrigError, match="DSM's frame"):
        texture_facades(local_blocks, eo, cams, loader, dsm)
    x0, y0 = dsm.grid.x0 + 10.0, dsm.grid.y0 - 10.0
    tiny = BuildingBlock(0, np.array([[x0, y0], [x0 + 1.0, y0], [x0 + 1.0, y0 + 1.0]]), 90.0, 90.0)
    with pytest.raises(SkyrigError, match="degenerate"):
        texture_facades([tiny], eo, cams, loader, dsm)


def test_a_flat_roof_textured_as_a_plane_matches_the_scenes_roof(midas):
    import cv2

    s, eo, cams, dsm, blocks, _, loader = midas
    local = s.frame
    flat = [b for b in blocks if len(b.roof) == 1]
    assert flat
    b = flat[0]
    roof = b.roof[0]  # counter-clockwise from above: corners bottom-start, bottom-end, top-end, top-start; normal up
    res = texture_plane(roof, eo, cams, loader, dsm)
    assert res.valid.mean() > 0.95 and res.images
    H, W = res.valid.shape
    u = (roof[1] - roof[0]) / np.linalg.norm(roof[1] - roof[0])
    v = (roof[3] - roof[0]) / np.linalg.norm(roof[3] - roof[0])
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    P = roof[3] + (jj.reshape(-1, 1) * res.texel_m) * u - (ii.reshape(-1, 1) * res.texel_m) * v
    pl = local.from_ecef(CRS.to_ecef(P))
    truth = s.scene.roof_rgb(np.full(len(pl), b.id), pl[:, 0], pl[:, 1]).mean(axis=1).reshape(H, W)
    got = res.rgb.astype(float).mean(axis=2) / 255.0
    (dx, dy), resp = cv2.phaseCorrelate(truth, got, cv2.createHanningWindow((W, H), cv2.CV_64F))
    assert resp > 0.1 and np.hypot(dx, dy) <= 1.0, (dx, dy, resp)


def test_refine_walls_moves_displaced_walls_back_onto_the_roof_outline(midas):
    from skyrig.dense.facades import _moved, refine_walls

    s, eo, cams, dsm, blocks, _, loader = midas
    rng = np.random.default_rng(4)
    moved, shifts = [], []
    for b in blocks[:3]:
        d = rng.choice([-0.5, -0.3, 0.3, 0.5], size=len(b.footprint))
        moved.append(_moved(b, d))
        shifts.append(d)
    back = refine_walls(moved, eo, cams, loader, dsm)
    gsd = 0.28  # nadir GSD of the midas-dsm block at the roofs (the images that see the roofs best)
    errs = []
    for b, r in zip(blocks[:3], back):
        for f_true, f_new in zip(b.facades(), r.facades()):
            # signed distance of the refined wall's middle from the true wall, along the true outward normal
            errs.append((f_new.corners[:2, :2].mean(axis=0) - f_true.corners[:2, :2].mean(axis=0)) @ f_true.normal[:2])
    errs = np.abs(errs)
    before = np.abs(np.concatenate(shifts))
    # a wall comes back within a GSD, or stays where it was when the images do not agree on the outline
    back_ok = errs <= gsd
    stayed = np.abs(errs - before) < 1e-6
    assert np.all(back_ok | stayed), (errs, before)
    assert back_ok.mean() >= 0.8 and np.median(errs) <= 0.5 * gsd, (errs, before)



@pytest.mark.slow
def test_refine_walls_uses_steep_views_so_a_wrong_eave_height_does_not_move_the_walls(midas):
    """A DSM's eave height is off by tenths of a metre; in a 45 deg oblique the roof outline drawn at the wrong
    height moves one for one, in a nadir view by the tangent of a few degrees only."""
    from dataclasses import replace

    from skyrig.dense.facades import refine_walls

    s, eo, cams, dsm, blocks, _, loader = midas
    dz = 0.8
    high = [replace(b, eave_z=b.eave_z + dz, roof=tuple(np.asarray(r) + [0.0, 0.0, dz] for r in b.roof))
            for b in blocks[:3]]

    def wall_errors(refined):
        return np.abs([(f_new.corners[:2, :2].mean(axis=0) - f_true.corners[:2, :2].mean(axis=0)) @ f_true.normal[:2]
                       for b, r in zip(blocks[:3], refined) for f_true, f_new in zip(b.facades(), r.facades())])

    steep = wall_errors(refine_walls(high, eo, cams, loader, dsm))
    any_view = wall_errors(refine_walls(high, eo, cams, loader, dsm, max_view_deg=60.0))
    # the nadir images see these roofs within ~25 deg of the vertical: the outline moves by at most dz tan(25 deg)
    assert steep.max() <= dz * np.tan(np.radians(25.0)) + 0.05, steep
    # with the obliques (finer GSD, chosen first) walls go astray by most of dz, or stay where they were when the
    # views disagree
    assert (any_view > 0.4).sum() >= 2 and not (steep > 0.4).any(), (any_view, steep)


def test_the_judge_sees_a_texture_shifted_by_two_texels(midas):
    from skyrig.simulate.judge_facades import judge_facade

    s, eo, _, _, _, tex, _ = midas
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    t = max((t for t in tex if set(t.images) & oblique), key=lambda t: t.valid.sum())
    good = judge_facade(s.scene, t, CRS)
    assert good.windows_found >= 3 and good.offset_norm_px <= 1.0
    shifted = replace(t, rgb=np.roll(t.rgb, 2, axis=1))
    bad = judge_facade(s.scene, shifted, CRS)
    assert abs(bad.offset_px[0] - good.offset_px[0] - 2.0) < 0.5, (good, bad)
    assert bad.windows_within_1px == 0


def test_orthometric_dsm_gives_the_same_textures(midas):
    """The DSM in EPSG:25832 with EGM96 heights (geoid ~40 m here): buildings, occlusion and texturing in that frame;
    the texels must land on the same wall places (skips without the geoid grid)."""
    from skyrig.pipeline.simulate import find_geoid

    geoid = find_geoid()
    if geoid is None:
        pytest.skip("no EGM96 grid (../shared/data/geoid/egm96_15.gtx or $SKYRIG_GEOID)")
    s, eo, cams, dsm, blocks, tex, loader = midas
    ortho = WorldFrame.map("EPSG:25832", geoid)
    dsm_o = scene_dsm(s.scene, dsm.grid, ortho)
    assert 30.0 < float(np.nanmean(dsm.height - dsm_o.height)) < 50.0  # the geoid undulation near Hannover
    ids = {t.facade.building for t in tex if t.images}
    blocks_o = [b for b in true_buildings(s.scene, ortho) if b.id in ids][:2]
    tex_o = texture_facades(blocks_o, eo, cams, loader, dsm_o)
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    judged, summ = judge_facades(s.scene, tex_o, ortho, oblique)
    assert summ["seen"] >= 1 and summ["within_1px"] == 1.0, summ


@pytest.mark.slow
def test_lens_distortion_is_honoured(midas):
    """Images rendered through cameras with strong radial-tangential distortion (several pixels at the image
    edges): textures through the same camera model stay within 1 texel, those through a distortion-free model of
    the same cameras do not."""
    from skyrig.camera.opencv import OpenCVDistortion

    s, eo, cams, dsm, blocks, tex, _ = midas
    dist = OpenCVDistortion(k1=-0.25, k2=0.08, p1=0.002, p2=-0.0015)
    dcams = {n: c.with_(distortion=dist) for n, c in cams.items()}
    edge = dcams["midas-right-50mm"]
    corner = np.array([[0.0, 0.0]])
    shift = np.abs(edge.project_pixels(cams["midas-right-50mm"].rays_from_pixels(corner)) - corner).max()
    assert shift > 10.0  # pixels of distortion at the image corner
    loader = LazyImages(s.scene, eo, dcams)
    ids = [t.facade.building for t in tex if t.images and t.facade.building in {b.id for b in blocks}]
    sel = [b for b in blocks if b.id in set(ids[:4])][:2]
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    good = judge_facades(s.scene, texture_facades(sel, eo, dcams, loader, dsm), CRS, oblique)[1]
    plain = judge_facades(s.scene, texture_facades(sel, eo, cams, loader, dsm), CRS, oblique)[1]
    assert good["seen"] >= 2 and good["within_1px"] == 1.0, good
    assert plain["within_1px"] < 1.0 or plain["corner_err_median_px"] > 1.5 * good["corner_err_median_px"], plain


def test_roof_textures_match_the_scenes_roofs(midas):
    import cv2

    from skyrig.dense.facades import texture_roofs

    s, eo, cams, dsm, blocks, _, loader = midas
    local = s.frame
    roofs = texture_roofs(blocks[:3], eo, cams, loader, dsm)
    assert len(roofs) == sum(len(b.roof) for b in blocks[:3])
    checked = 0
    for r in roofs:
        t = r.texture
        if t.valid.mean() < 0.9:
            continue
        H, W = t.valid.shape
        q = r.corners
        u = (q[1] - q[0]) / np.linalg.norm(q[1] - q[0])
        v = (q[3] - q[0]) / np.linalg.norm(q[3] - q[0])
        assert np.cross(u, v)[2] > 0.5  # the roof's texture faces up
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        P = q[3] + (jj.reshape(-1, 1) * t.texel_m) * u - (ii.reshape(-1, 1) * t.texel_m) * v
        pl = local.from_ecef(CRS.to_ecef(P))
        truth = s.scene.roof_rgb(np.full(len(pl), r.building), pl[:, 0], pl[:, 1]).mean(axis=1).reshape(H, W)
        got = t.rgb.astype(float).mean(axis=2) / 255.0
        (dx, dy), resp = cv2.phaseCorrelate(truth, got, cv2.createHanningWindow((W, H), cv2.CV_64F))
        assert resp > 0.1 and np.hypot(dx, dy) <= 1.0, (r.building, r.index, dx, dy, resp)
        checked += 1
    assert checked >= 2


def test_a_building_clipped_at_the_dsm_border_textures_its_real_walls_only(midas):
    """A building cut by the DSM's border (its true footprint clipped by a line through it; the edge on the line
    listed in ``border_edges``): that edge gets no texture and is not moved by refine_walls; the real walls' pieces
    inside are textured and match the façade rule within 1 texel as whole walls do.  ``judge_facades`` with
    ``walls`` (:func:`walls_seen`, from the scene truth alone) counts the seen walls, textured or not."""
    from dataclasses import replace as dc_replace

    import shapely

    from skyrig.dense.buildings import BuildingBlock
    from skyrig.dense.facades import refine_walls
    from skyrig.simulate.judge_facades import walls_seen

    s, eo, cams, dsm, blocks, tex, loader = midas
    oblique = {str(n) for n, h in zip(eo.image, eo.head) if h != "nadir"}
    judged, _ = judge_facades(s.scene, tex, CRS, oblique)
    good = {(j.true_building, j.true_face) for j, t in zip(judged, tex)
            if j.windows and set(t.images) & oblique and j.offset_norm_px <= 1.0}
    # the building with the most walls passing: cut through its middle, across its longest wall
    b = max(blocks, key=lambda q: sum((q.id, f) in good for f in range(4)))
    fp = np.asarray(b.footprint)
    e = [np.linalg.norm(fp[(i + 1) % 4] - fp[i]) for i in range(4)]
    i0 = int(np.argmax(e))
    d = (fp[(i0 + 1) % 4] - fp[i0]) / e[i0]
    mid = fp.mean(axis=0)
    half = shapely.Polygon([mid - 100 * d + 100 * np.array([-d[1], d[0]]), mid - 100 * d - 100 * np.array([-d[1], d[0]]),
                            mid + 0.2 * e[i0] * d - 100 * np.array([-d[1], d[0]]),
                            mid + 0.2 * e[i0] * d + 100 * np.array([-d[1], d[0]])])
    cut = np.asarray(shapely.orient_polygons(shapely.Polygon(fp).intersection(half)).exterior.coords)[:-1]
    on_line = [i for i in range(len(cut)) if abs((cut[i] - mid) @ d - 0.2 * e[i0]) < 1e-6
               and abs((cut[(i + 1) % len(cut)] - mid) @ d - 0.2 * e[i0]) < 1e-6]
    assert len(on_line) == 1
    roof = (np.column_stack([cut, np.full(len(cut), b.eave_z)]),)
    cb = BuildingBlock(b.id, cut, b.ground_z, b.eave_z, roof, "dsm", True, tuple(on_line))
    t2 = texture_facades([cb], eo, cams, loader, dsm)
    assert len(t2) == len(cut) - 1 and all(t.facade.index != on_line[0] for t in t2)
    j2, summ = judge_facades(s.scene, t2, CRS, oblique, walls=walls_seen(s.scene, eo, cams, oblique))
    seen2 = [j for j, t in zip(j2, t2) if j.windows and set(t.images) & oblique]
    assert seen2, "no real wall of the clipped building is judged"
    for j in seen2:
        assert j.offset_norm_px <= 1.0 and np.median(j.corner_err_px) <= 1.0, j
    assert summ["walls_seen"] >= summ["walls_textured"] >= 1
    # the walls whose textures from the rendered obliques (any view up to texture_facades' 75 deg) pass are the
    # ones the truth says an oblique sees at up to 75 deg (independent paths: renderer + DSM occlusion march vs
    # the analytic scene); a texture is judged on a part of a wall, so a quarter of it in one view is enough here
    ws = walls_seen(s.scene, eo, cams, oblique, max_incidence_deg=75.0, min_fraction=0.25)
    assert len(good & ws) >= 0.9 * len(good), (sorted(good - ws), len(good))
    # refine_walls: the border edge stays on the border line
    moved = refine_walls([dc_replace(cb)], eo, cams, loader, dsm)[0]
    k = on_line[0]
    for q in (moved.footprint[k], moved.footprint[(k + 1) % len(cut)]):
        assert abs((np.asarray(q) - mid) @ d - 0.2 * e[i0]) < 1e-6


def test_image_cache_is_bounded_in_count_and_bytes():
    """The façade texturing's image cache keeps at most ``keep`` images and ``max_bytes`` bytes, newest first
    (large-format frames: sixteen whole images would not fit in memory)."""
    from skyrig.dense.facades import _Images

    reads: list[int] = []

    def loader(i):
        reads.append(i)
        return np.full((100, 100, 3), i, np.uint8)  # 30,000 bytes

    imgs = _Images(loader, keep=16, max_bytes=100_000)  # room for three
    for i in (0, 1, 2, 3, 1, 0):
        assert int(imgs(i)[0, 0, 0]) == i
    assert reads == [0, 1, 2, 3, 0]  # 1 was still cached (1, 2, 3), 0 had been dropped for 3
    assert len(imgs.cache) == 3 and sum(a.nbytes for a in imgs.cache.values()) <= 100_000
    big = _Images(lambda i: np.zeros((400, 400, 3), np.uint8), keep=16, max_bytes=100_000)
    assert big(5).shape == (400, 400, 3) and list(big.cache) == [5]  # the newest is kept even when alone too big
    few = _Images(loader, keep=2, max_bytes=10 ** 9)
    for i in range(5):
        few(i)
    assert list(few.cache) == [3, 4]
