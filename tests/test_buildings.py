"""Building extraction from a DSM (skyrig.dense.buildings) and footprints from a GeoPackage
(skyrig.io.footprints_gpkg) against the simulator's true buildings.

The DSM is the scene's analytic surface rasterised here in the map CRS EPSG:25832 (ellipsoidal heights) at
0.3 m; the truth is the scene's building parameters (corner vertices converted to the map CRS through ECEF by
PROJ).  A building cell is one whose centre lies inside the footprint, so a wall lies somewhere between the last
cell centre inside and the first outside: sides placed on the median of their rasterised staircase must come
back within half a cell (corners too); heights of flat roofs and of the ground are sampled exactly, so they must come back within a few cm
(gable eaves and ridges from plane fits on cell centres: within a quarter of a cell's height change).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrig.dense.buildings import buildings_from_footprints, extract_buildings
from skyrig.dense.grid import GridSpec
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.georef.eo import WorldFrame
from skyrig.simulate.judge_facades import scene_dsm
from skyrig.simulate.scenarios import build_survey, scenario_spec

CRS = WorldFrame.map("EPSG:25832")
CELL = 0.3


pytestmark = pytest.mark.filterwarnings("ignore:'crs' was not provided")  # the GeoPackage without a CRS, on purpose


@pytest.fixture(scope="module")
def town():
    s = build_survey(scenario_spec("midas-dsm", "ci", 1))
    local = s.frame
    c = CRS.from_ecef(local.to_ecef(np.array([[-140.0, 110.0, 80.0], [140.0, -110.0, 80.0]])))
    x0, y0 = np.floor(c[0, 0] / CELL) * CELL, np.ceil(c[0, 1] / CELL) * CELL
    grid = GridSpec(x0, y0, CELL, int((c[1, 0] - x0) / CELL), int((y0 - c[1, 1]) / CELL))
    dsm = scene_dsm(s.scene, grid, CRS)
    bl = s.scene.buildings
    truth = []
    for i in range(len(bl)):
        v = bl.vertices(i)
        corners = CRS.from_ecef(local.to_ecef(v[4:8]))  # footprint corners at the eaves
        ground = float(s.scene.terrain_height(v[:4, 0], v[:4, 1]).min())
        zz = CRS.from_ecef(local.to_ecef(np.array([[bl.cx[i], bl.cy[i], ground], [bl.cx[i], bl.cy[i], bl.eave_z[i]],
                                                   [bl.cx[i], bl.cy[i], bl.ridge_z[i]]])))[:, 2]
        truth.append(dict(corners=corners[:, :2], ground=zz[0], eave=zz[1], ridge=zz[2], gabled=bool(bl.gabled[i]),
                          terrain=s.scene.terrain_height(v[:4, 0], v[:4, 1])))
    return s, dsm, truth


def _match(blocks, truth):
    out = []
    for t in truth:
        c = t["corners"].mean(axis=0)
        d = [np.linalg.norm(np.asarray(b.footprint).mean(axis=0) - c) for b in blocks]
        k = int(np.argmin(d))
        out.append((blocks[k] if d[k] < 2.0 else None, t))
    return out


def test_extracted_buildings_match_the_scene(town):
    s, dsm, truth = town
    blocks = extract_buildings(dsm, min_height_m=2.5, min_area_m2=20.0)
    assert len(blocks) == len(truth)
    for b, t in _match(blocks, truth):
        assert b is not None
        fp = np.asarray(b.footprint)
        assert len(fp) == 4  # rectangles
        x, y = fp[:, 0], fp[:, 1]
        assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # counter-clockwise
        err = [np.min(np.linalg.norm(fp - p, axis=1)) for p in t["corners"]]
        assert max(err) <= 0.5 * CELL, (err, b)
        # the ground: 10th percentile of the ring; the terrain's relief under the footprint bounds it
        assert t["terrain"].min() - 0.1 <= b.ground_z <= t["terrain"].max() + 0.1
        assert (len(b.roof) == 2) == t["gabled"]
        if t["gabled"]:
            # eaves / ridge from two planes fitted on cell centres: the plane slope times a quarter cell
            slope = (t["ridge"] - t["eave"]) / (0.5 * min(np.linalg.norm(t["corners"][1] - t["corners"][0]),
                                                          np.linalg.norm(t["corners"][2] - t["corners"][1])))
            tol = 0.05 + slope * CELL
            assert abs(b.eave_z - t["eave"]) <= tol
            ridge = max(float(r[:, 2].max()) for r in b.roof)
            assert abs(ridge - t["ridge"]) <= tol
        else:
            assert abs(b.eave_z - t["eave"]) <= 0.02
        gables = b.gable_ends()
        assert len(gables) == (2 if t["gabled"] else 0)
        for _, tri in gables:  # apex at the ridge, above the middle of a short wall
            assert abs(tri[2, 2] - t["ridge"]) <= 0.1
            assert np.linalg.norm(tri[2, :2] - 0.5 * (tri[0, :2] + tri[1, :2])) < 0.1
        for f in b.facades():
            assert np.allclose(f.corners[0, :2], f.corners[3, :2]) and f.height_m > 0
            # the outward normal points away from the footprint's centre
            assert (f.corners[0, :2] - fp.mean(axis=0)) @ f.normal[:2] > 0


def test_extraction_in_a_local_frame_and_refusals(town):
    s, _, _ = town
    bl = s.scene.buildings
    i = int(np.argmax(bl.hl * bl.hw))
    g = GridSpec(float(bl.cx[i]) - 30, float(bl.cy[i]) + 30, 0.25, 240, 240)
    dsm = scene_dsm(s.scene, g)  # local ENU frame of the scene
    blocks = extract_buildings(dsm)
    assert len(blocks) >= 1
    b = min(blocks, key=lambda b: np.linalg.norm(np.asarray(b.footprint).mean(axis=0) - [bl.cx[i], bl.cy[i]]))
    v = bl.vertices(i)[:4, :2]
    assert max(np.min(np.linalg.norm(np.asarray(b.footprint) - p, axis=1)) for p in v) <= 0.25
    with pytest.raises(SkyrigError, match="positive"):
        extract_buildings(dsm, min_height_m=-1.0)
    with pytest.raises(SkyrigError, match="no measured cell"):
        extract_buildings(replace(dsm, height=np.full(dsm.grid.shape, np.nan, np.float32)))
    # holes in the DSM (NaN) next to the walls: buildings still come out, and from measured cells only
    h = dsm.height.copy()
    rng = np.random.default_rng(0)
    h[rng.uniform(size=h.shape) < 0.2] = np.nan
    holed = extract_buildings(replace(dsm, height=h))
    b2 = min(holed, key=lambda b: np.linalg.norm(np.asarray(b.footprint).mean(axis=0) - [bl.cx[i], bl.cy[i]]))
    assert max(np.min(np.linalg.norm(np.asarray(b2.footprint) - p, axis=1)) for p in v) <= 0.5


def test_footprints_from_a_geopackage_in_another_crs(town, tmp_path):
    import shapely

    from skyrig.io.footprints_gpkg import read_footprints
    from skyrig.io.gpkg import write_gpkg

    s, dsm, truth = town
    local = s.frame
    geo = WorldFrame.map("EPSG:4326")
    polys = []
    bl = s.scene.buildings
    for i in range(len(bl)):
        v = bl.vertices(i)[4:8]
        ll = geo.from_ecef(local.to_ecef(v))  # lon, lat (x, y order of skyrig's geographic frames)
        polys.append(shapely.Polygon(ll[:, :2]))
    path = tmp_path / "footprints.gpkg"
    write_gpkg(path, {"buildings": (polys, {"name": np.array([f"b{i}" for i in range(len(bl))])})}, "EPSG:4326")
    fps, labels = read_footprints(path, CRS)
    assert len(fps) == len(bl) and labels[0].startswith("buildings:")
    for fp, t in zip(fps, truth):
        assert np.abs(fp - t["corners"]).max() < 0.01  # reprojected by PROJ (the eaves' height: < 1 cm)
    blocks = buildings_from_footprints(fps, dsm, source=str(path))
    for b, t in zip(blocks, truth):
        x, y = b.footprint[:, 0], b.footprint[:, 1]
        assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0
        assert t["terrain"].min() - 0.1 <= b.ground_z <= t["terrain"].max() + 0.1
        assert (len(b.roof) == 2) == t["gabled"]
        if not t["gabled"]:
            assert abs(b.eave_z - t["eave"]) <= 0.02
        else:  # the gabled roof extraction fits: two planes on cell centres, the slope times a quarter cell
            slope = (t["ridge"] - t["eave"]) / (0.5 * min(np.linalg.norm(t["corners"][1] - t["corners"][0]),
                                                          np.linalg.norm(t["corners"][2] - t["corners"][1])))
            assert abs(b.eave_z - t["eave"]) <= 0.05 + slope * CELL
            assert abs(max(float(r[:, 2].max()) for r in b.roof) - t["ridge"]) <= 0.05 + slope * CELL
    # refused in words: another CRS without reprojection, no CRS, no such layer, a footprint outside the DSM
    with pytest.raises(InputFormatError, match="reproject"):
        read_footprints(path, CRS, reproject=False)
    nocrs = tmp_path / "nocrs.gpkg"
    write_gpkg(nocrs, {"b": (polys, {"name": np.array(["x"] * len(polys))})}, None)
    with pytest.raises(InputFormatError, match="no CRS"):
        read_footprints(nocrs, CRS)
    with pytest.raises(InputFormatError, match="no layer"):
        read_footprints(path, CRS, layer="roads")
    with pytest.raises(InputFormatError, match="no such"):
        read_footprints(tmp_path / "missing.gpkg", CRS)
    far = [fps[0] + 5000.0]
    with pytest.raises(SkyrigError, match="outside the DSM"):
        buildings_from_footprints(far, dsm)


@pytest.mark.slow
def test_chain_on_a_matched_dsm(town):
    """Nadir images rendered from the true orientations -> ``dense_surface`` -> extraction -> façade textures.

    The matched DSM's building edges are blurred / fattened by the matcher (on the midas-dsm block about 0.3 m
    median, see ``bench/facades.py``), so the tolerances here are the matched DSM's: corners within 3 cells
    (median), eaves within 0.3 m (median); textures of the extracted walls, whose texels are about a cell, within
    3 texels (median window corner)."""
    from skyrig.dense.facades import texture_facades
    from skyrig.dense.pairs import PairConfig
    from skyrig.dense.surface import DenseConfig, dense_surface
    from skyrig.geometry.pose import Pose
    from skyrig.simulate.judge_facades import judge_extraction, judge_facades
    from skyrig.simulate.render import render_image

    s, _, _ = town
    eo = s.eo_true
    cams = {str(eo.camera[k]): s.rig_true.head(str(eo.head[k])).camera for k in range(len(eo))}
    cache: dict[int, np.ndarray] = {}

    def loader(i):
        if i not in cache:
            cache[i] = render_image(s.scene, cams[str(eo.camera[i])], Pose(eo.rotation[i], eo.centre[i], "world", "camera"),
                                    noise_dn=1.0, seed=i)
        return cache[i]

    nadir = np.flatnonzero(eo.head == "nadir")
    c = CRS.from_ecef(s.frame.to_ecef(np.array([[-60.0, -80.0, 80.0], [60.0, 70.0, 80.0]])))
    dsm, _, _ = dense_surface(eo.subset(nadir), cams, lambda i: loader(int(nadir[i])), CRS, (70.0, 110.0),
                              area=(c[0, 0], c[0, 1], c[1, 0], c[1, 1]),
                              config=DenseConfig(cloud=False, block_px=384, pairs=PairConfig(pairs_per_image=2)))
    blocks = extract_buildings(dsm)
    ex = judge_extraction(s.scene, blocks, CRS)
    assert ex["matched"] == len(blocks) >= 5
    assert np.median(ex["corner_err_m"]) <= 3 * dsm.grid.cell_m
    assert abs(np.median(ex["eave_err_m"])) <= 0.3
    tex = texture_facades(blocks, eo, cams, loader, dsm)
    _, summ = judge_facades(s.scene, tex, CRS)
    # the walls stand where the matched DSM put them: texture offsets follow the corner errors (texel ~ cell)
    assert summ["windows_found"] >= 5, summ
    assert summ["corner_err_median_px"] <= 3.0, summ


def _cut_town(dsm, angle_deg: float, offset_m: float):
    """The DSM with every cell on one side of a line through the town void (beyond the surveyed area, connected to
    the grid's edge); returns the DSM and the line's point and normal (void where (p - p0) . n < 0)."""
    g = dsm.grid
    xx, yy = g.cell_centres()
    p0 = np.array([g.x0 + 0.5 * g.width * g.cell_m, g.y0 - 0.5 * g.height * g.cell_m])
    t = np.radians(angle_deg)
    n = np.array([np.cos(t), np.sin(t)])
    p0 = p0 + offset_m * n
    h = np.asarray(dsm.height, np.float32).copy()
    h[(xx - p0[0]) * n[0] + (yy - p0[1]) * n[1] < 0] = np.nan
    return replace(dsm, height=h), p0, n


@pytest.mark.parametrize("angle_deg, offset_m", [(90.0, -20.0), (30.0, 10.0)])
def test_buildings_cut_by_the_border_are_clipped(town, angle_deg, offset_m):
    """Buildings cut by the border of the surveyed area (a straight edge of void through the town, axis-parallel
    and oblique): with ``clip_border`` kept, flagged ``clipped``, their edges on the border
    listed in ``border_edges`` (within two cells of the cut line), and their real walls inside the DSM in place (the
    uncut walls' accuracy: within half a cell of the true wall line, 2 deg)."""
    import shapely

    from skyrig.dense.buildings import ExtractionConfig

    _, dsm, truth = town
    cut, p0, n = _cut_town(dsm, angle_deg, offset_m)
    plain = extract_buildings(cut)
    clipped = extract_buildings(cut, config=ExtractionConfig(clip_border=True))
    assert not any(b.clipped or b.border_edges for b in plain)
    half = shapely.Polygon(np.array([p0 - 1e4 * np.array([-n[1], n[0]]), p0 + 1e4 * np.array([-n[1], n[0]])])
                           .tolist() + [(p0 + 1e4 * np.array([-n[1], n[0]]) + 1e4 * n).tolist(),
                                        (p0 - 1e4 * np.array([-n[1], n[0]]) + 1e4 * n).tolist()])
    judged = 0
    for t in truth:
        poly = shapely.Polygon(t["corners"])
        part = poly.intersection(half)
        frac = part.area / poly.area
        if not 0.3 < frac < 0.95 or part.area < 40:
            continue
        c = np.array(part.centroid.coords[0])
        d = [np.linalg.norm(np.array(shapely.Polygon(b.footprint).centroid.coords[0]) - c) for b in clipped]
        assert d and min(d) < 2.0, f"a building cut by the border ({frac:.0%} inside) was not extracted"
        b = clipped[int(np.argmin(d))]
        assert b.clipped and b.border_edges
        fp = np.asarray(b.footprint)
        for i in b.border_edges:
            for q in (fp[i], fp[(i + 1) % len(fp)]):
                # the border is known to a cell (rasterised void), its polygon simplified by up to one more
                assert abs((q - p0) @ n) < 2 * CELL + 0.05, "a border edge off the cut line"
        walls = [i for i in range(len(fp)) if i not in b.border_edges]
        tc = t["corners"]
        for k in range(4):
            a, e = tc[k], tc[(k + 1) % 4]
            seg = shapely.LineString([a, e]).intersection(half)
            if seg.is_empty or seg.length < 3.0:
                continue
            m = np.array(seg.interpolate(0.5, normalized=True).coords[0])
            u = (e - a) / np.linalg.norm(e - a)
            best = np.inf
            for i in walls:
                v = fp[(i + 1) % len(fp)] - fp[i]
                v = v / np.linalg.norm(v)
                if abs(u[0] * v[1] - u[1] * v[0]) > np.sin(np.radians(2.0)):
                    continue
                best = min(best, abs((m - fp[i]) @ np.array([-v[1], v[0]])))
            assert best <= 0.5 * CELL + 0.05, f"real wall {k} of a clipped building {best:.2f} m off"
            judged += 1
    assert judged >= 2
