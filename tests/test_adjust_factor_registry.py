"""The adjustment's observation types are modules (adjust/factors): a new one is one module.

``LevelledHeight`` below is an observation type defined outside the package (a levelled height of an object
point, one row each): it is registered, its rows ride in ``Block.observations``, and nothing in skyrig
changes.  Its adjustment is checked against an independent path - the same heights entered as control
points whose plan coordinates carry no weight - and data snooping finds a blunder injected into it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import ReliabilityOptions
from skyrig.adjust.block import BlockError
from skyrig.adjust.factors import observation_type, observation_types, register, unregister
from skyrig.adjust.factors.base import Factor, ObservationType, check_index, check_positive
from skyrig.adjust.synthetic import synthetic_block


@dataclass
class HeightData:
    """Levelled heights: ``point (L,)`` indices, ``z (L,)`` m, ``sigma (L, 1)`` m."""

    point: np.ndarray
    z: np.ndarray
    sigma: np.ndarray | float = 0.005

    def __len__(self) -> int:
        return len(np.atleast_1d(self.point))


class LevelledHeight(ObservationType):
    name = "height"
    words = "levelled-height"
    components = ("Z",)
    units = "m"
    order = 45.0
    hints = (("datum_shift", "a height datum difference"),)
    datum_words = "levelled heights"
    vce_split = ((0,),)

    def normalise(self, block):
        d = self.data(block)
        if d is None:
            return
        d.point = np.asarray(d.point, np.int64).reshape(-1)
        d.z = np.asarray(d.z, float).reshape(-1)
        d.sigma = np.broadcast_to(np.asarray(d.sigma, float).reshape(-1, 1), (len(d.point), 1)).copy()

    def validate(self, block):
        d = self.data(block)
        if d is not None:
            check_index("observations['height'].point", d.point, block.n_points, "point")
            check_positive("observations['height'].sigma", d.sigma)

    def evaluate(self, model, s, jac):
        d, lay = self.data(model.block), model.layout
        r = (s.X[d.point, 2] - d.z)[:, None] / d.sigma
        f = Factor(self.name, r, d.sigma, weight=model.weights[self.name])
        if jac:
            J = np.zeros((len(d), 1, 3))
            J[:, 0, 2] = 1.0 / d.sigma[:, 0]
            if lay.n_p:
                f.point, f.jp = lay.point[d.point], J
            if lay.has_rpoint:
                f.jc, f.cols = J, lay.rpoint[d.point]
        return [f]

    def varying(self, model, factor):
        return model.estimated_points()[self.data(model.block).point]

    def label(self, block, i):
        return f"levelled height of point {block.point_name[self.data(block).point[i]]}"


@pytest.fixture
def height_type():
    t = register(LevelledHeight())
    yield t
    unregister(t.name)


def _block_with_heights(seed=3, sigma=0.005, blunder=None):
    b, truth = synthetic_block(seed=seed, n_control=4, gnss_sigma_m=None, imu_sigma_rad=None)
    rng = np.random.default_rng(seed)
    pts = rng.choice(b.n_points, 40, replace=False)
    z = truth.point_xyz[pts, 2] + rng.normal(0.0, sigma, len(pts))
    if blunder is not None:
        z[blunder] += 20 * sigma
    return b, truth, pts, z


def test_builtin_types_are_registered_in_order():
    names = [t.name for t in observation_types()]
    assert names[:5] == ["image", "control", "gnss", "imu", "distance"]
    assert observation_type("prior:pose").name == "prior"


def test_a_new_observation_type_is_one_module(height_type):
    b, truth, pts, z = _block_with_heights()
    bh = dataclasses.replace(b, observations={**b.observations, "height": HeightData(pts, z, 0.005)})
    # the same heights as control points whose plan coordinates carry no weight (sigma 1e4 m)
    k = len(pts)
    bc = dataclasses.replace(
        b, control_point=np.concatenate([b.control_point, pts]),
        control_xyz=np.concatenate([b.control_xyz, np.c_[truth.point_xyz[pts, :2], z]]),
        control_sigma=np.concatenate([b.control_sigma, np.tile([1e4, 1e4, 0.005], (k, 1))]),
        control_check=np.concatenate([b.control_check, np.zeros(k, bool)]))
    rh, rc = adjust(bh, AdjustConfig()), adjust(bc, AdjustConfig())
    assert rh.ok and rc.ok
    np.testing.assert_allclose(rh.block.point_xyz, rc.block.point_xyz, rtol=0, atol=1e-6)
    np.testing.assert_allclose(rh.block.station_centre, rc.block.station_centre, rtol=0, atol=1e-6)
    v = rh.residuals["height"].residual[:, 0]
    np.testing.assert_allclose(v, rc.residuals["control"].residual[len(b.control_point):, 2], atol=1e-6)
    assert rh.groups["height"].n_rows == k
    # 2 fewer observations per point than the control path (no plan rows)
    assert rc.n_observations - rh.n_observations == 2 * k
    # the heights (5 mm) pull the points towards the truth in Z within their predicted precision
    err = rh.block.point_xyz[pts, 2] - truth.point_xyz[pts, 2]
    assert np.sqrt(np.mean(err**2)) < 3 * 0.005
    # Block.copy keeps the new group (a deep copy)
    c = bh.copy()
    c.observations["height"].z[0] += 1.0
    assert bh.observations["height"].z[0] == z[0]


def test_data_snooping_finds_a_blunder_in_the_new_type(height_type):
    # heights as precise as the photogrammetric Z (about 0.1 m here), so that the images check them
    b, _, pts, z = _block_with_heights(seed=5, sigma=0.1, blunder=7)
    bh = dataclasses.replace(b, observations={**b.observations, "height": HeightData(pts, z, 0.1)})
    r = adjust(bh, AdjustConfig(reliability=ReliabilityOptions(snooping=True)))
    assert [x.group for x in r.rejected] == ["height"]
    assert r.rejected[0].index == 7
    assert r.rejected[0].label == f"levelled height of point {b.point_name[pts[7]]}"


def test_unknown_or_bad_groups_are_named(height_type):
    b, _, pts, z = _block_with_heights()
    with pytest.raises(BlockError, match="unknown observation type"):
        dataclasses.replace(b, observations={**b.observations, "levelling": HeightData(pts, z)})
    bad = dataclasses.replace(b, observations={**b.observations, "height": HeightData(pts, z, -1.0)})
    with pytest.raises(BlockError, match=r"observations\['height'\].sigma\[0\] must be > 0"):
        bad.validate()


def test_a_row_coupling_cameras_and_an_eliminated_point_is_refused(height_type):
    # the solver couples cameras and eliminated points through the image rows only: a new type whose rows
    # touch both would be silently mis-solved, so the model refuses it in words
    from skyrig.adjust.model import Model, State

    class Coupled(LevelledHeight):
        name = "coupled"

        def evaluate(self, model, s, jac):
            (f,) = LevelledHeight.evaluate(self, model, s, jac)
            if jac:
                st = model.layout.pose[0]
                f.jc, f.cols = np.zeros((len(f), 1, 6)), np.broadcast_to(st, (len(f), 6))
            return [f]

    t = register(Coupled())
    try:
        b, _, pts, z = _block_with_heights()
        b = dataclasses.replace(b, observations={**b.observations, "coupled": HeightData(pts, z)})
        m = Model(b, AdjustConfig())
        with pytest.raises(ValueError, match="touches both reduced columns and an eliminated point"):
            m.evaluate(State.from_block(b))
    finally:
        unregister(t.name)
