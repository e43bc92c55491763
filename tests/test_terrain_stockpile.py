"""Stockpile volumes and cut / fill between epochs (issue 31) against the simulator's truth: a simulated town
(:func:`skyrig.simulate.world.make_scene`) with stockpiles of analytic volume (:class:`~skyrig.simulate.world.
Stockpiles`, truncated cones standing on the natural terrain), surveyed at three epochs by independent noisy
clouds of its top surface (what a dense image cloud sees, sigma 5 cm, 3 points per m^2), each gridded into a
surface COG on its own grid; ``skyrig terrain volume`` between two epochs inside polygons around the piles."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main

E0, N0 = 500000.0, 5800000.0
SIZE = 120.0
PILE_A = (24.0, 24.0, 14.0, 3.0, 5.0)  # cx, cy, toe radius R, top radius r, height h (local metres)
PILE_A_LOWERED = (24.0, 24.0, 14.0, 3.0, 3.0)  # 2 m taken off A's top
PILE_B = (96.0, 94.0, 12.0, 0.0, 4.0)  # a new cone
NOISE = 0.05


@pytest.fixture(scope="module")
def epochs(tmp_path_factory):
    """Surface COGs of three epochs of one simulated town: 0 without piles, 1 with pile A, 2 with A lowered and
    a new pile B; and the polygons (a circle 3 m beyond each toe; buildings are kept farther away by the
    simulator)."""
    import shapely

    from skyrig.dense.grid import GridSpec
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.gpkg import write_gpkg
    from skyrig.io.terrain_files import write_dtm_cog
    from skyrig.simulate.world import Stockpiles, make_scene
    from skyrig.terrain.dtm import make_dtm

    d = tmp_path_factory.mktemp("stockpile")
    frame = WorldFrame.map("EPSG:25832")
    site = make_scene(3, (0.0, 0.0, SIZE, SIZE), n_buildings=8, relief_m=6.0, building_size_m=(8.0, 22.0),
                      stockpiles=[PILE_A, PILE_B])
    scenes = [replace(site, stockpiles=None), replace(site, stockpiles=Stockpiles.of([PILE_A])),
              replace(site, stockpiles=Stockpiles.of([PILE_A_LOWERED, PILE_B]))]
    for k, scene in enumerate(scenes):
        rng = np.random.default_rng(10 + k)
        n = int(SIZE * SIZE * 3.0)
        x, y = rng.uniform(0, SIZE, n), rng.uniform(0, SIZE, n)
        xyz = np.column_stack([x + E0, y + N0, scene.surface_height(x, y) + rng.normal(0, NOISE, n)])
        shift = k / 3.0  # every epoch on its own grid (a third of a cell apart)
        grid = GridSpec(E0 - shift, N0 + SIZE + shift, 1.0, int(SIZE) + 1, int(SIZE) + 1)
        surface = make_dtm(xyz, np.full(n, 2), frame, grid=grid, sigma=np.full(n, NOISE))
        write_dtm_cog(d / f"epoch{k}.tif", surface)
    circles = {name: shapely.Point(E0 + p[0], N0 + p[1]).buffer(p[2] + 3.0, 128) for name, p in
               (("A", PILE_A), ("B", PILE_B))}
    write_gpkg(d / "pile_a.gpkg", {"pile": ([circles["A"]], {"name": ["A"]})}, "EPSG:25832")
    write_gpkg(d / "site.gpkg", {"piles": ([circles["A"], circles["B"]], {"name": ["A", "B"]})},
               "EPSG:25832")
    return d, scenes


def _volume(d, top, base, polygon):
    r = CliRunner().invoke(main, ["terrain", "volume", "--top", str(d / top), "--base", str(d / base), "--polygon",
                                  str(d / polygon), "-o", str(d / "v.json")], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return json.loads((d / "v.json").read_text())


def test_simulated_stockpile_volume_within_one_percent_and_two_sigma(epochs):
    """Pile A above the surface surveyed before it was tipped (epoch 0): the scene's analytic volume
    pi h (R^2 + R r + r^2) / 3 within 1 % and within 2 predicted sigmas; the scene's piles stand on its natural
    terrain (terrain - natural ground = the piles' height, whose mean over a lattice is the volume).  Measured:
    1295.0 m3 for 1293.3 m3 (+0.13 %, 0.33 sigma of 5.2 m3)."""
    d, scenes = epochs
    piles = scenes[1].stockpiles
    v_true = float(piles.volume()[0])
    # the scene's own truth, checked independently of the closed form: a 5 cm midpoint lattice
    g = np.arange(PILE_A[0] - 15, PILE_A[0] + 15, 0.05) + 0.025
    gx, gy = np.meshgrid(g, g)
    lattice = float(np.sum(scenes[1].terrain_height(gx, gy) - scenes[1].natural_ground_height(gx, gy)) * 0.0025)
    assert lattice == pytest.approx(v_true, rel=1e-3)
    v = _volume(d, "epoch1.tif", "epoch0.tif", "pile_a.gpkg")
    err = v["net_m3"] - v_true
    assert abs(err) / v_true < 0.01, (v["net_m3"], v_true)
    assert abs(err) < 2 * v["sigma_net_m3"], (err, v["sigma_net_m3"])
    # the prediction is informative: a sigma below 1 % of the volume (not a bound wide enough to pass anything)
    assert v["sigma_net_m3"] < 0.01 * v_true


def test_cut_fill_between_two_epochs_equals_the_truths_difference(epochs):
    """Epoch 1 -> epoch 2 inside both piles' circles: 2 m cut off pile A's top, pile B tipped.  The net change
    equals the scene's (vol(A lowered) + vol(B) - vol(A)) within its predicted sigma (measured: 84.6 m3 for 85.9 m3,
    sigma 6.7 m3); fill and cut each within 2.5 % of the truth's (measured +1.3 % / +1.7 %: they also collect the
    noise of the unchanged cells, one sign each)."""
    d, scenes = epochs
    va, va2, vb = (float(scenes[k].stockpiles.volume()[i]) for k, i in ((1, 0), (2, 0), (2, 1)))
    v = _volume(d, "epoch2.tif", "epoch1.tif", "site.gpkg")
    dv_true = va2 + vb - va
    assert abs(v["net_m3"] - dv_true) < v["sigma_net_m3"], (v["net_m3"], dv_true, v["sigma_net_m3"])
    assert v["fill_m3"] == pytest.approx(vb, rel=0.025) and v["cut_m3"] == pytest.approx(va - va2, rel=0.025), v
    # the same surfaces the other way round: cut and fill swap, the net changes sign
    w = _volume(d, "epoch1.tif", "epoch2.tif", "site.gpkg")
    assert w["net_m3"] == pytest.approx(-v["net_m3"], abs=0.02 * abs(dv_true))


def test_stockpiles_in_the_scene_and_its_renderer():
    """The stockpile is part of the scene's bare earth: the ray caster hits the pile's top at its height (its
    analytic path adds the piles), the gradient is the cone's slope, and a scene without piles
    is unchanged; bad piles are refused."""
    from skyrig.errors import SkyrigError
    from skyrig.simulate.render import intersect_terrain
    from skyrig.simulate.world import Stockpiles, make_scene

    plain = make_scene(3, (0.0, 0.0, SIZE, SIZE), n_buildings=8, relief_m=6.0, building_size_m=(8.0, 22.0))
    site = make_scene(3, (0.0, 0.0, SIZE, SIZE), n_buildings=8, relief_m=6.0, building_size_m=(8.0, 22.0),
                      stockpiles=[PILE_A])
    cx, cy, R, r, h = PILE_A
    z_nat = float(plain.terrain_height(cx, cy))
    assert float(site.terrain_height(cx, cy)) == pytest.approx(z_nat + h)
    assert float(site.natural_ground_height(cx, cy)) == pytest.approx(z_nat)
    down = np.array([[0.0, 0.0, -1.0]])
    t = intersect_terrain(site, np.array([cx, cy, 300.0]), down)
    assert t[0] == pytest.approx(300.0 - z_nat - h, abs=1e-4)
    # oblique rays over the pile: the analytic path (sines + piles) hits where the general one (any terrain_height)
    # does
    from dataclasses import fields

    from skyrig.simulate.world import Scene

    class General(Scene):
        def terrain_height(self, x, y):
            return Scene.terrain_height(self, x, y)

    general = General(**{f.name: getattr(site, f.name) for f in fields(site)})
    rng = np.random.default_rng(2)
    d = np.column_stack([rng.uniform(-0.4, 0.4, 200), rng.uniform(-0.4, 0.4, 200), -np.ones(200)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.array([cx, cy, 150.0])
    t_a, t_g = intersect_terrain(site, o, d), intersect_terrain(general, o, d)
    assert np.allclose(t_a, t_g, atol=1e-4)
    hit = o + t_a[:, None] * d
    assert np.any(site.stockpiles.height(hit[:, 0], hit[:, 1]) > 0.5)  # some rays hit the flanks or the top
    # half-way down the flank, the pile's slope h / (R - r) adds to the terrain's gradient
    gx0, gy0 = plain.terrain_gradient(cx + (r + R) / 2, cy)
    gx, gy = site.terrain_gradient(cx + (r + R) / 2, cy)
    assert float(gx - gx0) == pytest.approx(-h / (R - r)) and float(gy - gy0) == pytest.approx(0.0, abs=1e-12)
    far = np.array([SIZE - 5.0]), np.array([SIZE - 5.0])
    assert np.array_equal(site.terrain_height(*far), plain.terrain_height(*far))
    with pytest.raises(SkyrigError, match="0 <= r < R"):
        Stockpiles.of([(0, 0, 5.0, 6.0, 2.0)])


def test_scenario_spec_stockpiles_opt_in():
    """``ScenarioSpec.stockpiles`` puts piles into a flown scenario's scene (buildings kept off them); without them
    the scene is the scenario's usual one.  The CI ``midas-dsm`` town's opt-in pile is placed where the seed draws the
    same buildings, targets and flight as without it."""
    from skyrig.simulate.scenarios import MIDAS_DSM_STOCKPILE, build_survey, scenario_spec

    spec = scenario_spec("midas", "ci", 1)
    pile = (20.0, -20.0, 10.0, 2.0, 3.0)
    s = build_survey(replace(spec, stockpiles=(pile,))).scene
    assert float(s.terrain_height(20.0, -20.0) - s.natural_ground_height(20.0, -20.0)) == pytest.approx(3.0)
    b = s.buildings
    assert np.all(np.hypot(b.cx - 20.0, b.cy + 20.0) > 10.0 + np.hypot(b.hl, b.hw))
    assert build_survey(spec).scene.stockpiles is None
    plain = build_survey(scenario_spec("midas-dsm", "ci", 1))
    assert plain.scene.stockpiles is None  # opt-in
    dsm = build_survey(replace(plain.spec, stockpiles=(MIDAS_DSM_STOCKPILE,)))
    cx, cy, R, r, h = MIDAS_DSM_STOCKPILE
    assert float(dsm.scene.stockpiles.volume()[0]) == pytest.approx(np.pi * h * (R * R + R * r + r * r) / 3)
    for f in ("cx", "cy", "hl", "hw", "eave_z", "ridge_z"):
        assert np.array_equal(getattr(dsm.scene.buildings, f), getattr(plain.scene.buildings, f)), f
    assert np.array_equal(dsm.scene.targets.xyz, plain.scene.targets.xyz)
    assert np.array_equal(dsm.eo_true.centre, plain.eo_true.centre)
