"""A factor module declares its own unknowns (issue 30 item 1): an observation type and its parameter group in
one file, nothing in skyrig touched.

``Barometer`` observes each station's height through an altimeter with an unknown constant offset; the offset
is ``BaroOffset``, a :class:`~skyrig.adjust.factors.base.ParameterGroup` this file declares.  On a seeded
block (GNSS positions give the datum) the adjusted offset must agree with the simulated one within its own
predicted precision, the station heights must not be pulled off, and a ``"weighted"`` offset must follow its
prior as least squares predicts (an independent closed form for the weighted mean of two estimates).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.factors import register, register_group, unregister, unregister_group
from skyrig.adjust.factors.base import Factor, ObservationType, ParameterGroup, check_index, check_positive
from skyrig.adjust.synthetic import synthetic_block

OFFSET_M = 3.2  # the altimeter's true offset
SIGMA_M = 0.05  # its noise


@dataclass
class BaroData:
    """Barometric heights: ``station (B,)`` indices, ``h (B,)`` m, ``sigma (B, 1)`` m (required arrays)."""

    station: np.ndarray
    h: np.ndarray
    sigma: np.ndarray

    def __len__(self) -> int:
        return len(self.station)


class BaroOffset(ParameterGroup):
    name = "baro_offset"
    components = ("dz_m",)
    words = "altimeter offset"

    def estimated(self, block):
        return block.observations.get("baro") is not None


class Barometer(ObservationType):
    name = "baro"
    words = "barometric-height"
    components = ("Z",)
    units = "m"
    order = 46.0
    vce_split = ((0,),)

    def normalise(self, block):
        d = self.data(block)
        if d is not None:
            d.station = np.asarray(d.station, np.int64).reshape(-1)
            d.h = np.asarray(d.h, float).reshape(-1)
            d.sigma = np.broadcast_to(np.asarray(d.sigma, float).reshape(-1, 1), (len(d.station), 1)).copy()

    def validate(self, block):
        d = self.data(block)
        if d is not None:
            check_index("observations['baro'].station", d.station, block.n_stations, "station")
            check_positive("observations['baro'].sigma", d.sigma)

    def evaluate(self, model, s, jac):
        d, lay = self.data(model.block), model.layout
        off = s.groups["baro_offset"][0, 0]
        r = (s.C[d.station, 2] + off - d.h)[:, None] / d.sigma
        f = Factor(self.name, r, d.sigma, weight=model.weights[self.name])
        if jac:
            f.cols = np.column_stack([lay.pose[d.station, 2],
                                      np.full(len(d), lay.groups["baro_offset"][0, 0])])
            f.jc = np.broadcast_to(1.0 / d.sigma[:, :, None], (len(d), 1, 2)).copy()
        return [f]

    def label(self, block, i):
        return f"barometric height of station {block.station_name[self.data(block).station[i]]}"


@pytest.fixture
def baro():
    t, g = register(Barometer()), register_group(BaroOffset())
    yield t
    unregister(t.name)
    unregister_group(g.name)


def _block(seed=6):
    b, truth = synthetic_block(seed=seed, n_points=120)
    rng = np.random.default_rng(seed)
    h = truth.station_centre[:, 2] + OFFSET_M + rng.normal(0.0, SIGMA_M, b.n_stations)
    st = np.arange(b.n_stations)
    return dataclasses.replace(b, observations={**b.observations, "baro": BaroData(st, h, np.full(b.n_stations, SIGMA_M))}), truth


def test_an_observation_type_with_its_own_unknowns_is_one_file(baro):
    b, truth = _block()
    cfg = AdjustConfig(unknowns=Unknowns(groups=(("baro_offset", "free"),)))
    r = adjust(b, cfg)
    assert r.ok, r.failures
    assert ("baro_offset", "baro_offset", "dz_m") in r.layout.labels
    est = float(r.block.parameters["baro_offset"][0, 0])
    sig = r.sigma_reduced()[("baro_offset", "baro_offset", "dz_m")]
    assert 0 < sig < 0.1
    assert abs(est - OFFSET_M) < 4 * sig, (est, sig)
    # the stations stay where GNSS and the images put them
    dz = r.block.station_centre[:, 2] - truth.station_centre[:, 2]
    assert np.abs(dz).max() < 0.5
    # fixed (the default): no column, the offset stays at its start value (0) and the heights misfit
    r0 = adjust(b, AdjustConfig())
    assert not any(lab[0] == "baro_offset" for lab in r0.layout.labels)
    assert float(r0.block.parameters["baro_offset"][0, 0]) == 0.0
    assert r0.sigma0 > 2 * r.sigma0


def test_a_weighted_group_follows_its_prior_as_least_squares_says(baro):
    b, _ = _block()
    free = adjust(b, AdjustConfig(unknowns=Unknowns(groups=(("baro_offset", "free"),))))
    x_f = float(free.block.parameters["baro_offset"][0, 0])
    q_f = (free.sigma_reduced()[("baro_offset", "baro_offset", "dz_m")] / free.sigma0) ** 2  # cofactor
    prior0, sp = 2.0, 0.02
    bw = dataclasses.replace(b, parameters={"baro_offset": np.array([[prior0]])})
    w = adjust(bw, AdjustConfig(unknowns=Unknowns(groups=(("baro_offset", "weighted"),),
                                                  group_sigma=(("baro_offset", (sp,)),))))
    x_w = float(w.block.parameters["baro_offset"][0, 0])
    # the weighted mean of the free estimate and the prior (linear problem near the solution)
    want = (x_f / q_f + prior0 / sp**2) / (1 / q_f + 1 / sp**2)
    assert abs(x_w - want) < 0.05 * abs(x_f - prior0), (x_w, want, x_f)
    assert "prior:baro_offset" in w.groups
